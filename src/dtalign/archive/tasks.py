"""What one task does on a worker: read, prepare and fit one image.

:func:`fit_item` is the function Dask runs, once per manifest item. It
reads the image and its polylines on the worker (only the item's paths
travel from the client), computes the image's products once with
:func:`dtalign.pipeline.prepare_image`, fits its polylines as
:func:`dtalign.pipeline.batch.fit_images` fits an image's (with
:func:`~dtalign.pipeline.batch.fit_many`), and returns plain rows
for the store. An error of the item (a missing or corrupt file, a bad
option) is returned as a failure row, not raised, so the campaign goes on
and the message names the file. It imports no Dask: the same function is
the serial loop of the benchmark.
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime
import logging
import math
import os
import socket
import time
from typing import Any

import numpy as np

from .manifest import Item

__all__ = ["fit_item", "fit_items", "fit_rows", "warm_up"]


def _version() -> str:
    from .._version import __version__

    return __version__


def _worker_name() -> str:
    """``host:pid`` of this process, or the Dask worker's address when in one."""
    try:
        from distributed import get_worker  # only present where Dask is

        return str(get_worker().address)
    except (ImportError, ValueError):
        return f"{socket.gethostname()}:{os.getpid()}"


def _now() -> datetime.datetime:
    return datetime.datetime.now(datetime.UTC)


def _ambiguity(fit: Any) -> dict[str, float | None]:
    """The ambiguity columns of a fit examined against rival basins (its :class:`~dtalign.pipeline.hypotheses.Ambiguity`)."""
    amb = getattr(fit, "ambiguity", None)
    rival = None if amb is None else amb.rival
    return {
        "ambiguity_ratio": None if amb is None else _f(amb.ratio),
        "rival_offset_v": None if rival is None else _f(rival.offset_vu[0]),
        "rival_offset_u": None if rival is None else _f(rival.offset_vu[1]),
    }


def _profile(fit: Any) -> dict[str, Any]:
    """The DT-LM offset and the profile refinement's columns (null without a profile)."""
    prof = getattr(fit, "profile", None)
    dt = fit.lm.offset_vu
    return {
        "dt_offset_v": float(dt[0]), "dt_offset_u": float(dt[1]),
        "profile_accepted": None if prof is None else bool(prof.accepted),
        "profile_psf_sigma_px": None if prof is None else float(prof.psf_sigma_px),
        "profile_walk_px": None if prof is None else float(prof.walk_px),
        "edge_kind": getattr(fit, "edge_kind", None),
    }


def _status(fit: Any) -> tuple[str, list[str]]:
    """The fit's status and reasons, as the store's text columns."""
    return str(fit.status), [str(r) for r in fit.reasons]


class _ErrorsOnly(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        return record.levelno >= logging.ERROR


@contextlib.contextmanager
def _fits_not_logged() -> Any:
    """No per-fit warnings from the ``dtalign`` logger while a task fits.

    In a campaign each fit's status and reasons go to the store (the
    ``status`` and ``reasons`` columns) and the run's summary counts the
    flagged ones; a warning line per suspect fit from every worker would
    only flood the terminal and the progress bar. Errors still pass.
    """
    logger = logging.getLogger("dtalign")
    quiet = _ErrorsOnly()
    logger.addFilter(quiet)
    try:
        yield
    finally:
        logger.removeFilter(quiet)


def _f(x: Any) -> float:
    return float(x)


def fit_rows(item: Item, fits: list[Any], timings: dict[str, Any], *, run_id: str) -> list[dict[str, Any]]:
    """Store rows for an item's fits (one per polyline), in polyline order.

    Parameters
    ----------
    item : Item
        The manifest item.
    fits : list of PolylineFit
        One per polyline of ``item``.
    timings : dict
        ``read_s``, ``prepare_s``, ``item_s``, ``fit_s`` (a list, one per
        fit), ``worker``, ``noise_sigma_estimated``, ``region_fraction``,
        ``finished_at``.
    run_id : str
        The run writing the rows.
    """
    version = _version()
    rows = []
    for k, (path, fit) in enumerate(zip(item.polylines, fits, strict=True)):
        cov = np.asarray(fit.covariance, dtype=np.float64)
        rot = cov.shape[0] == 3
        status, reasons = _status(fit)
        rows.append({
            "item_id": item.id, "image": item.image, "polyline": path, "polyline_index": k,
            "offset_v": _f(fit.offset_vu[0]), "offset_u": _f(fit.offset_vu[1]),
            "rotation_rad": _f(fit.rotation_rad),
            "sigma_v": _f(fit.sigma_vu[0]), "sigma_u": _f(fit.sigma_vu[1]),
            "sigma_rotation_rad": None if fit.sigma_rotation_rad is None
            else _f(fit.sigma_rotation_rad),
            "cov_vv": _f(cov[0, 0]), "cov_vu": _f(cov[0, 1]), "cov_uu": _f(cov[1, 1]),
            "cov_vr": _f(cov[0, 2]) if rot else None, "cov_ur": _f(cov[1, 2]) if rot else None,
            "cov_rr": _f(cov[2, 2]) if rot else None,
            "coarse_dv": int(fit.coarse_offset_vu[0]), "coarse_du": int(fit.coarse_offset_vu[1]),
            "at_window_edge": bool(fit.at_window_edge), "converged": bool(fit.lm.converged),
            "degenerate": bool(fit.lm.degenerate), "iterations": int(fit.lm.iterations),
            "rms_px": _f(fit.lm.rms_px), "raw_rms_px": _f(fit.lm.raw_rms_px),
            "inlier_count": int(fit.lm.inlier_count),
            "n_vertices": int(np.asarray(fit.lm.residuals_px).shape[0]),
            "polarity_rejected_count": int(getattr(fit.lm, "polarity_rejected_count", 0)),
            "observable_rank": int(fit.observable_rank),
            "status": status, "reasons": reasons,
            **_ambiguity(fit),
            **_profile(fit),
            "noise_sigma": _f(fit.noise_sigma),
            "noise_sigma_estimated": bool(timings.get("noise_sigma_estimated", False)),
            "fit_rotation": bool(fit.fit_rotation),
            "window_v": int(item.window[0]), "window_u": int(item.window[1]),
            "read_s": timings.get("read_s"), "prepare_s": timings.get("prepare_s"),
            "fit_s": timings["fit_s"][k] if "fit_s" in timings else None,
            "item_s": timings.get("item_s"),
            "polyline_s": _share(timings, len(fits), k),
            "region_fraction": timings.get("region_fraction"), "worker": timings.get("worker"),
            "dtalign_version": version, "item_fingerprint": item.fingerprint,
            "run_id": run_id, "finished_at": timings.get("finished_at"),
        })
    return rows


def _fraction(region: Any) -> float:
    """The fraction of the frame ``region`` covers (1 for the whole frame, None)."""
    if region is None:
        return 1.0
    (h, w), (fh, fw) = region.shape, region.frame_shape
    return h * w / (fh * fw)


def _share(timings: dict[str, Any], n: int, k: int) -> float | None:
    """Polyline ``k``'s cost of its item: ``fit_s[k]`` plus its ``1/n`` share of
    ``read_s + prepare_s`` (None when a part is missing)."""
    read, prepare = timings.get("read_s"), timings.get("prepare_s")
    fit = timings["fit_s"][k] if "fit_s" in timings else None
    if read is None or prepare is None or fit is None:
        return None
    return float((read + prepare) / n + fit)


def _failure(item: Item, stage: str, exc: BaseException, run_id: str, worker: str | None,
             version: str | None) -> dict[str, Any]:
    message = str(exc).strip().replace("\n", " ") or type(exc).__name__
    return {
        "item_id": item.id, "image": item.image, "polylines": list(item.polylines),
        "stage": stage, "error_type": type(exc).__name__, "error": message,
        "worker": worker, "dtalign_version": version, "item_fingerprint": item.fingerprint,
        "run_id": run_id, "failed_at": _now(),
    }


def fit_item(item: Item, run_id: str = "") -> dict[str, Any]:
    """Read, prepare and fit one manifest item; never raises for the item's own errors.

    Parameters
    ----------
    item : Item
        The image, its polylines and options.
    run_id : str, optional
        Recorded in the rows.

    Returns
    -------
    dict
        ``{"item_id", "results": [rows], "failure": row or None}``: either
        one result row per polyline, or one failure row whose ``stage``
        says where it failed (``read``, ``prepare`` or ``fit``) and whose
        ``error`` names the file or polyline.
    """
    import dtalign.io as io

    from ..api.results import ImageDerivativesConfig
    from ..pipeline.products import products_of
    from ..pipeline.region import image_region, refit_outside

    worker = _worker_name()
    t0 = time.perf_counter()
    stage = "read"
    try:
        masked = item.mask_path is not None or item.mask_nonfinite
        image = io.load_image(item.image_path, nonfinite=masked)
        mask = None
        if item.mask_path is not None:
            from ..pipeline.masked import load_mask

            mask = load_mask(item.mask_path)
        elif masked:  # the NaN and inf pixels only
            mask = np.zeros(image.shape, dtype=bool)
        polylines = [io.load_polyline_csv(p) for p in item.polyline_paths]
        t1 = time.perf_counter()
        stage = "prepare"
        config = ImageDerivativesConfig(**item.config) if item.config else None
        # the products of the region the polylines reach (dtalign.pipeline.region)
        region = image_region(image, [p.vertices_vu for p in polylines],
                              _options(item), config)
        products = products_of(image, item.noise_sigma, config, region, mask)
        t2 = time.perf_counter()
        stage = "fit"
        fits = refit_outside(products.region, _fit_polylines(item, products, polylines),
                             lambda redo: _refit(item, image, products, polylines, redo, mask))
        t3 = time.perf_counter()
    except Exception as exc:  # the item's own error: recorded, the campaign goes on
        return {"item_id": item.id, "results": [],
                "failure": _failure(item, stage, exc, run_id, worker, _version())}
    timings = {
        "read_s": t1 - t0, "prepare_s": t2 - t1,
        "fit_s": [_fit_seconds(fit, products) for fit in fits], "item_s": t3 - t0,
        "worker": worker, "noise_sigma_estimated": products.noise_sigma_estimated,
        "region_fraction": _fraction(products.region),
        "finished_at": _now(),
    }
    return {"item_id": item.id, "results": fit_rows(item, fits, timings, run_id=run_id),
            "failure": None}


def _fit_polylines(item: Item, products: Any, polylines: list[Any]) -> list[Any]:
    """The item's polylines fitted on its image's products by the batch's path
    (:func:`dtalign.pipeline.batch.fit_many` on one worker: the work of an
    image of :func:`~dtalign.pipeline.batch.fit_images`); an error names
    the polyline's file."""
    from ..pipeline.batch import fit_many

    spheres = item.spheres or (None,) * len(polylines)
    parts = []
    for path, poly, sphere in zip(item.polylines, polylines, spheres, strict=True):
        profile = None
        if sphere is not None:
            from ..api.profiles import sphere_edge_profile

            try:
                profile = sphere_edge_profile(poly.vertices_vu, **sphere)
            except (TypeError, ValueError) as exc:
                raise type(exc)(f"polyline {path}: {exc}") from None
        parts.append(poly if profile is None else dataclasses.replace(poly, edge_profile=profile))
    try:
        with _fits_not_logged():
            return fit_many(products, parts, search_window_vu=item.window, workers=1,
                            **item.options)
    except (TypeError, ValueError) as exc:
        # a polyline's error (its index the batch's), or the call's (a bad option)
        k = getattr(exc, "index", 0)
        raise type(exc)(f"polyline {item.polylines[k]}: {exc}") from None


def _options(item: Item) -> Any:
    """The item's fit options as a :class:`~dtalign.FitOptions` (None when
    malformed: its fit then says why)."""
    from ..api.options import resolve

    try:
        return resolve(None, {"search_window_vu": item.window, **item.options})
    except (TypeError, ValueError):
        return None


def _refit(item: Item, image: Any, products: Any, polylines: list[Any],
           redo: list[int], mask: Any) -> list[Any]:
    """Polylines ``redo`` fitted again on the frame's products, with the
    noise their region's fits used (their fits left the region)."""
    import dtalign.pipeline as pipeline

    full = pipeline.prepare_image(image, products.noise_sigma, config=products.config,
                                  mask=mask)
    sub = dataclasses.replace(item, polylines=tuple(item.polylines[i] for i in redo),
                              spheres=tuple(item.spheres[i] for i in redo) if item.spheres
                              else ())
    return _fit_polylines(sub, full, [polylines[i] for i in redo])


def _fit_seconds(fit: Any, products: Any) -> float:
    """A fit's own seconds: its timings but the image's (noise, derivatives)."""
    return sum(v for k, v in fit.timings_s.items() if k not in products.timings_s)


def fit_items(items: list[Item], run_id: str = "") -> list[dict[str, Any]]:
    """:func:`fit_item` on each of ``items`` in turn: the task of several items.

    Dask's own cost per task is a few milliseconds of CPU, a noticeable part
    of a small frame's fit; a task of several frames pays it once.
    """
    return [fit_item(item, run_id) for item in items]


def failure_row(item: Item, exc: BaseException, run_id: str) -> dict[str, Any]:
    """A failure row for an item whose task never returned (its worker died, ...)."""
    return _failure(item, "worker", exc, run_id, None, None)


#: A small scene the warm-up fits: big enough for every code path, quick once compiled.
_WARM_SHAPE = (96, 96)


def warm_up() -> float:
    """Compile, or load from Numba's on-disk cache, the kernels a task uses.

    Runs a few fits on a small synthetic disc: translation, trust region,
    rotation with the ridge polish. Returns the seconds it took.
    """
    import dtalign.pipeline as pipeline
    import dtalign.scenes as scenes

    t0 = time.perf_counter()
    scene = scenes.disc_scene(shape=_WARM_SHAPE, radius=30.0, n_vertices=32, search_window=3)
    p = scene.polyline
    with _fits_not_logged():  # the small scene's fits may be flagged: not worth a word
        _warm_fits(pipeline, scene, p)
    return time.perf_counter() - t0


def _warm_fits(pipeline: Any, scene: Any, p: Any) -> None:
    for noise in (scene.noise_sigma, None):
        products = pipeline.prepare_image(scene.image, noise)
        for options in ({}, {"trust_region_px": 1.0},
                        {"fit_rotation": True, "final_gradient_ridge": True}):
            fit = pipeline.fit_polyline_products(
                products, p.vertices_vu, p.normals_vu, p.sigmas, search_window_vu=(3, 3),
                **options,
            )
            if not math.isfinite(fit.offset_vu[0]):  # pragma: no cover - a broken build
                raise RuntimeError("warm-up fit returned a non-finite offset")
