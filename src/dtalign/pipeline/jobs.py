"""The pipeline's fits: checks once per call, compiled work, light result wrapping.

:func:`dtalign.pipeline.fit_polyline_products` and
:func:`dtalign.pipeline.batch.fit_many` share this. :func:`~dtalign.pipeline.jobs.plan` checks the
first polyline of a call exactly as the step-by-step pipeline checks it
(its own arrays, the window, the pivot, then every LM option, in that
order: that fixes which error a bad call raises) with the call's
:class:`~dtalign.api.options.FitOptions`. What it validated holds for
every further polyline of the call, which ``prepare`` then checks only
for its own arrays (one compiled pass) and, when rotating, its pivot
spread. The polylines run in one compiled loop with the GIL released
(``dtalign.api.loop.fit_polylines``: ``loop_inputs``,
``fit_polylines``), which :mod:`dtalign.pipeline.batch` runs on its threads;
``dtalign.pipeline.fit.wrap`` makes their results. The products of
:func:`~dtalign.pipeline.products.prepare_image` are trusted: their arrays
were checked when the products were made.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np

from ..api import checks as check
from ..api import loop
from ..api.checks import LMArgs
from ..api.constants import DEFAULT_COARSE_MIN_SUPPORT_FRACTION
from ..api.lm import raise_for_code
from ..api.options import (
    DEFAULT_SEARCH_WINDOW_VU,
    FitOptions,
    gradient_of,
    lm_kernel_options,
)
from ..api.options import n_params as _n_params
from .products import ImageProducts

__all__ = ["DEFAULT_SEARCH_WINDOW_VU", "Batch", "Item", "Plan", "plan", "prepare"]

FloatArray = check.FloatArray


class Plan(NamedTuple):
    """What every polyline of one call shares, validated once."""

    products: ImageProducts
    window: tuple[int, int]
    mv: int
    mu: int
    lm: LMArgs
    options: FitOptions


class Item(NamedTuple):
    """One polyline's checked arrays and its resolved pivot."""

    vertices: FloatArray
    normals: FloatArray
    sigmas: FloatArray
    pivot: tuple[float, float]
    distance: float


def broadcast_sigmas(vertices_vu: Any, sigmas: Any) -> Any:
    """A scalar ``sigmas`` applied to every vertex; anything else as given.

    A real number (not a bool) becomes ``np.full(N, sigmas)`` when
    ``vertices_vu`` has the shape ``(N, 2)``; the usual checks then judge
    it (a negative or non-finite scalar is refused as ``sigmas``). The
    drop-in :func:`dtalign.lm_subpixel_refine` keeps its per-vertex
    contract and does not do this.
    """
    if isinstance(sigmas, bool | np.bool_) or not (
            isinstance(sigmas, int | float | np.integer | np.floating)
            or (isinstance(sigmas, np.ndarray) and sigmas.ndim == 0
                and sigmas.dtype.kind in "iuf")):
        return sigmas
    shape = np.shape(vertices_vu)
    if len(shape) != 2:
        return sigmas
    return np.full(shape[0], float(sigmas))


def _distance(products: ImageProducts, pivot: tuple[float, float], fit_rotation: bool,
              pivot_distance_px: Any) -> float:
    """The pivot distance the pipeline passes to the LM (see ``fit_polyline_products``)."""
    if pivot_distance_px is None:
        if not fit_rotation:
            return 0.0
        h, w = products.shape
        return max(math.hypot(pivot[0] - (h - 1) / 2.0, pivot[1] - (w - 1) / 2.0), 1.0)
    distance = check.finite_real(pivot_distance_px, "pivot_distance_px")
    if fit_rotation and distance <= 0.0:
        raise ValueError(
            f"fit_rotation=True requires a finite pivot_distance_px > 0, got {distance!r}"
        )
    return distance


def plan(products: Any, vertices_vu: Any, normals_vu: Any, sigmas: Any,
         options: FitOptions) -> tuple[Plan, Item]:
    """Check the first polyline and everything shared, in the pipeline's order."""
    if not isinstance(products, ImageProducts):
        raise TypeError(f"products must be an ImageProducts, got {type(products).__name__}")
    # The polyline's values in one compiled pass; on any fault, the NumPy
    # checks in their order, which raise the pipeline's error.
    try:
        verts = check.vertex_shape(vertices_vu, "vertices_vu", allow_empty=False)
        norms = check.normals_shape(normals_vu, verts.shape[0])
        sig = check.sigmas_shape(sigmas, verts.shape[0], "sigmas")
        status, c_v, c_u = loop.polyline_status(verts, norms, sig)
    except (TypeError, ValueError):
        status = -1
    if status != loop.OK:
        verts = check.vertices(vertices_vu, "vertices_vu", allow_empty=False)
        norms = check.normals(normals_vu, verts.shape[0])
        sig = check.sigmas(sigmas, verts.shape[0], "sigmas")
    window = check.search_window(options.search_window_vu)
    fit_rotation = bool(options.fit_rotation)
    # the centroid of polyline_status is bit-identical to resolve_pivot's mean
    pivot = ((c_v, c_u) if status == loop.OK and options.pivot_vu is None
             else check.resolve_pivot(verts, options.pivot_vu))
    distance = _distance(products, pivot, fit_rotation, options.pivot_distance_px)
    # The LM's own checks, as lm_subpixel_refine runs them, on the products'
    # arrays as they are (checked when the products were made); any finite
    # offset stands for the coarse seed (always a pair of ints). A polyline
    # that passed the compiled pass above passes the LM's polyline check,
    # which is then not run again.
    lm = check.check_lm_inputs({
        "vertices_vu": verts, "normals_vu": norms, "sigma_normal_per_vertex_px": sig,
        "image_edge_dt": products.edge_dt, "image_gradient_vu": products.gradient_vu,
        "initial_offset_vu": (0.0, 0.0), "fit_rotation": fit_rotation, "pivot_vu": pivot,
        "pivot_distance_px": distance, **options.lm_keywords(),
    }, (verts, norms, sig, (c_v, c_u)) if status == loop.OK else None,
        trusted_images=True)
    h, w = products.shape
    shared = Plan(products=products, window=window, mv=min(window[0], max(h - 1, 0)),
                  mu=min(window[1], max(w - 1, 0)), lm=lm, options=options)
    return shared, Item(lm.vertices, lm.normals, lm.sigmas, pivot, distance)


def recheck(shared: Plan, vertices_vu: Any, normals_vu: Any, sigmas: Any) -> None:
    """Raise what fitting this polyline alone would raise (it failed a bulk check):
    :func:`plan`'s exact sequence with the call's options."""
    plan(shared.products, vertices_vu, normals_vu, sigmas, shared.options)
    raise AssertionError("unreachable: the bulk checks and plan() disagree")  # pragma: no cover


class Batch(NamedTuple):
    """Checked polylines of one call, concatenated for the compiled loop."""

    n: int
    pts: FloatArray
    nrm: FloatArray
    sig: FloatArray
    starts: np.ndarray
    pivots: FloatArray
    distances: FloatArray


def _plain(v: Any, n: Any, s: Any) -> bool:
    """Whether a polyline is float64 arrays of the right shapes (no conversion
    needed; ``np.concatenate`` copies any layout)."""
    if not (type(v) is np.ndarray and type(n) is np.ndarray and type(s) is np.ndarray):
        return False
    shape = v.shape
    # native float64 is one dtype instance: identity, no dtype comparison
    return (
        v.dtype is _F8 and n.dtype is _F8 and s.dtype is _F8 and len(shape) == 2
        and shape[1] == 2 and shape[0] > 0 and n.shape == shape and s.shape == (shape[0],)
    )


_F8 = np.dtype(np.float64)


def _concatenated(
    vs: list[Any], ns: list[Any], ss: list[Any]
) -> tuple[FloatArray, FloatArray, FloatArray, list[int]] | None:
    """``np.concatenate`` of each list, and the polylines' lengths, if every
    ``(vs[i], ns[i], ss[i])`` passes :func:`_plain`; None otherwise.

    Checked per list, not per polyline: the casting rule ``"no"`` refuses
    any dtype but native float64, the concatenation any mix of dimensions,
    and the results' shapes and the lengths do the rest: a few calls per
    list rather than :func:`_plain`'s six attribute reads per polyline.
    """
    if set(map(type, vs + ns + ss)) != {np.ndarray}:
        return None
    try:
        pts = np.concatenate(vs, dtype=_F8, casting="no")
        nrm = np.concatenate(ns, dtype=_F8, casting="no")
        sig = np.concatenate(ss, dtype=_F8, casting="no")
    except (TypeError, ValueError):
        return None
    lens = list(map(len, vs))
    if (pts.ndim != 2 or pts.shape[1] != 2 or nrm.ndim != 2 or nrm.shape[1] != 2
            or sig.ndim != 1 or list(map(len, ns)) != lens or list(map(len, ss)) != lens
            or min(lens) == 0):
        return None
    return pts, nrm, sig, lens


def _stacked(parts: Sequence[tuple[Any, Any, Any]], first: Item | None
             ) -> tuple[FloatArray, FloatArray, FloatArray, list[int], int]:
    """The polylines' arrays concatenated, their lengths, and the first whose
    shapes are wrong (``len(parts)`` if none): in bulk when every polyline is
    float64 arrays (:func:`_concatenated`), else one by one."""
    verts: list[FloatArray] = []
    norms: list[FloatArray] = []
    sigs: list[FloatArray] = []
    if first is not None:
        verts, norms, sigs = [first.vertices], [first.normals], [first.sigmas]
    start = len(verts)
    if len(parts) > start:
        vs, ns, ss = zip(*parts[start:], strict=True)
        bulk = _concatenated(verts + list(vs), norms + list(ns), sigs + list(ss))
        if bulk is not None:
            return (*bulk, len(parts))
    bad = len(parts)
    for k in range(start, len(parts)):
        v, n, s = parts[k]
        if not _plain(v, n, s):
            try:
                v = check.vertex_shape(v, "vertices_vu", allow_empty=False)
                n = check.normals_shape(n, v.shape[0])
                s = check.sigmas_shape(s, v.shape[0], "sigmas")
            except (TypeError, ValueError):
                bad = k
                break
        verts.append(v)
        norms.append(n)
        sigs.append(s)
    empty = np.zeros((0, 2))
    pts = np.concatenate(verts) if verts else empty
    nrm = np.concatenate(norms) if norms else empty
    sig = np.concatenate(sigs) if sigs else empty[:, 0]
    return pts, nrm, sig, list(map(len, verts)), bad


def _pivots(shared: Plan, pts: FloatArray, starts: np.ndarray, centroids: FloatArray,
            first: Item | None, bad: int) -> tuple[FloatArray, FloatArray, int]:
    """The polylines' pivots and pivot distances, and the first bad one
    (``bad`` if none): with rotation, each pivot's spread is checked."""
    lm = shared.lm
    options = shared.options
    pivots = centroids[:bad]
    if options.pivot_vu is not None:
        pivots[:] = lm.pivot  # the given pivot, checked
    elif first is not None:
        pivots[0] = first.pivot
    # Without rotation the distance is the same for every polyline (0, or
    # the one given), and no pivot spread can overflow.
    distances = np.full(bad, _distance(shared.products, (0.0, 0.0), False,
                                       options.pivot_distance_px))
    if lm.fit_rotation or lm.rotation != 0.0:
        for k, pivot in enumerate(map(tuple, pivots.tolist())):
            distances[k] = _distance(shared.products, pivot, lm.fit_rotation,
                                     options.pivot_distance_px)
            if k == 0 and first is not None:
                continue  # checked by plan()
            try:  # the pivot-spread check of a rotating fit
                check.pose(pts[starts[k] : starts[k + 1]], fit_rotation=lm.fit_rotation,
                           pivot_vu=pivot, pivot_distance_px=distances[k],
                           initial_offset_vu=(0.0, 0.0), initial_rotation_rad=lm.rotation)
            except (TypeError, ValueError):
                return pivots, distances, k
    return pivots, distances, bad


def prepare(
    shared: Plan, parts: Sequence[tuple[Any, Any, Any]], first: Item | None = None
) -> tuple[Batch, Exception | None]:
    """Check polylines of a call whose first polyline passed :func:`plan`.

    ``first``, when given, is that polyline, already checked: it stands
    for ``parts[0]``. Shapes are checked in bulk when every polyline is
    float64 arrays, else per polyline; values in one compiled pass over all
    of them. Returns the polylines up to the first bad one, and the error
    that one raises alone (None if all pass).
    """
    pts, nrm, sig, lens, bad = _stacked(parts, first)
    pts, nrm, sig = check.readonly(pts), check.readonly(nrm), check.readonly(sig)
    # (np.cumsum of the list converts it first: twice the time)
    starts = np.fromiter(itertools.accumulate(lens, initial=0), np.int64, len(lens) + 1)
    n_ok, _, centroids = loop.polylines_status(pts, nrm, sig, starts)
    pivots, distances, bad = _pivots(shared, pts, starts, centroids, first, min(bad, int(n_ok)))
    error: Exception | None = None
    if bad < len(parts):
        try:
            recheck(shared, *parts[bad])
        except (TypeError, ValueError) as exc:  # raised by the caller after the fits before it
            error = exc  # (anything else, e.g. a signal handler's exception, propagates now)
    end = int(starts[bad])
    return Batch(bad, pts[:end], nrm[:end], sig[:end], starts[: bad + 1], pivots[:bad],
                 distances[:bad]), error


def at_window_edge(dv: int, du: int, window: tuple[int, int]) -> bool:
    """Whether the coarse seed lies on the boundary of a non-zero search margin."""
    return (window[0] > 0 and abs(dv) >= window[0]) or (window[1] > 0 and abs(du) >= window[1])


def seed_of(shared: Plan, it: Item, *, surface: bool = False
            ) -> tuple[tuple[int, int], np.ndarray | None]:
    """The pipeline's integer seed (:func:`dtalign.api.loop.pipeline_seed`):
    polarity-weighted where polarity is on, with the support floor
    ``DEFAULT_COARSE_MIN_SUPPORT_FRACTION`` and the window clipped to the
    image; and, with ``surface``, the score surface it is the best of."""
    # (plan() refused an empty image: the LM checks need a non-empty DT)
    return loop.pipeline_seed(
        shared.products.edge_mask, shared.lm.gradient if shared.lm.use_polarity else None,
        it.vertices, it.normals, shared.mv, shared.mu, DEFAULT_COARSE_MIN_SUPPORT_FRACTION,
        surface=surface,
    )


def loop_inputs(shared: Plan, batch: Batch) -> tuple[loop.LoopInputs, np.ndarray, loop.LoopOutputs]:
    """The compiled loop's inputs for ``batch`` with fresh outputs:
    ``(inputs, errors, outputs)``; the call for polylines ``lo:hi`` is
    :data:`fit_polylines` ``(inputs, lo, hi, errors, outputs)``."""
    k = batch.n
    a = shared.lm
    n_params = int(_n_params(a.fit_rotation))
    n_pts = batch.pts.shape[0]
    errors = np.zeros(k, dtype=np.int64)
    out = loop.LoopOutputs(
        coarse=np.zeros((k, 2), dtype=np.int64), poses=np.zeros((k, 3)),
        iterations=np.zeros(k, dtype=np.int64), converged=np.zeros(k, dtype=np.bool_),
        covs=np.zeros((k, n_params, n_params)), rms=np.zeros(k), raw_rms=np.zeros(k),
        inliers=np.zeros(k, dtype=np.int64), degenerate=np.zeros(k, dtype=np.bool_),
        r_all=np.zeros(n_pts), w_all=np.zeros(n_pts),
    )
    inputs = loop.LoopInputs(
        edge=shared.products.edge_mask, mv=shared.mv, mu=shared.mu, dt=a.dt,
        grad=gradient_of(a), pts=batch.pts, nrm=batch.nrm, sig=batch.sig, starts=batch.starts,
        pivots=batch.pivots, distances=batch.distances, rotation0=a.rotation,
        seed_support=DEFAULT_COARSE_MIN_SUPPORT_FRACTION, opts=lm_kernel_options(a),
    )
    return inputs, errors, out


#: The compiled loop's code of a polyline that fitted (any other is an error:
#: :func:`raise_for`).
OK = loop.OK


#: The compiled loop the batch calls (a module attribute, so that a test can
#: wrap it to watch or gate the batch's compiled calls).
fit_polylines = loop.fit_polylines


def readonly_views(out: loop.LoopOutputs) -> loop.LoopOutputs:
    """Read-only views of :func:`loop_inputs`' outputs, for the fits to keep
    slices of (the caller then locks the outputs themselves, so that no
    view can be made writable again)."""
    views = [arr.view() for arr in out]
    for view in views:
        view.flags.writeable = False
    return loop.LoopOutputs(*views)


def raise_for(error: int) -> None:
    """Raise the ValueError of a compiled loop's error code."""
    raise_for_code(error)
