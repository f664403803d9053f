"""Does the reported uncertainty cover the truth? Coverage on seeded scenes.

A navigation pipeline fuses techniques by their covariances, so a fit's
covariance is a claim: the planted offset should fall inside the reported
68 % ellipse about 68 % of the time and inside the 95 % ellipse about 95 %
of the time. This module measures that claim on scenes whose truth is
known: every family of :mod:`dtalign.robustness` and spheres rendered by
:func:`dtalign.scenes.render_sphere` (noisy limbs and terminators).

* A :class:`Case` is one scene ready to fit: image, polyline, truth, and
  the direction "correct" is measured along (a straight edge's normal) or
  None for the full 2-D error.
* :func:`evaluate` fits each case with a fit function and reads each named
  covariance of the result (a *reading*): among the fits whose status is
  ``ok``, the fraction inside the 68 % and 95 % ellipses, the median error
  and the median reported one-sigma; beside them the fraction flagged.
* :func:`format_table` renders the rows; ``python -m
  dtalign.benchmarking.coverage`` prints the table of the pipeline, plain
  (:func:`plain_fit`) and with the spheres' edge profiles
  (:func:`profile_fit`).

The ellipse test is the squared Mahalanobis distance of the error against
the reading's covariance restricted to the directions the fit observes:
for a 2-D error below 2.279 (68.27 %) and 5.991 (95 %), the chi-square
quantiles with 2 degrees of freedom; along one direction below 1 and
3.841 (1 degree of freedom).
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import statistics
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..robustness import FAMILIES as ROBUSTNESS_FAMILIES
from ..scenes import Polyline, render_sphere
from .timing import rst_table

__all__ = [
    "CHI2_1D",
    "CHI2_2D",
    "Case",
    "CoverageRow",
    "FAMILIES",
    "READINGS",
    "evaluate",
    "format_table",
    "main",
    "plain_fit",
    "profile_fit",
]

FloatArray = NDArray[np.float64]

#: Chi-square quantiles with 2 degrees of freedom at 68.27 % and 95 %.
CHI2_2D: tuple[float, float] = (2.2789, 5.9915)
#: ... and with 1 degree of freedom (an error measured along one direction).
CHI2_1D: tuple[float, float] = (1.0, 3.8415)

#: The readings of a :class:`dtalign.pipeline.PolylineFit` the table reports:
#: the pipeline's own covariance (:mod:`dtalign.pipeline.uncertainty`), the
#: M-estimator's prior one (from the vertex sigmas passed, as
#: :func:`dtalign.lm_subpixel_refine` reports it) and that one scaled by the
#: residuals (``curve_fit(absolute_sigma=False)``).
READINGS: dict[str, Callable[[Any], Any]] = {
    "pipeline": lambda fit: fit.covariance,
    "prior": lambda fit: fit.lm.covariance,
    "scaled": lambda fit: fit.uncertainty.covariance_scaled,
}

#: Rendered spheres: a 200 DN albedo over a 10 DN sky, with shot noise at 20
#: electrons per DN and 2 DN of read noise: a peak SNR of about 52, the noisy
#: regime of the accuracy issue (peak SNR >= 50).
_SPHERE_ALBEDO_DN = 200.0
_SPHERE_SKY_DN = 10.0
_SPHERE_GAIN = 20.0
_SPHERE_READ_DN = 2.0


@dataclass(frozen=True)
class Case:
    """One scene to fit, with its truth.

    Attributes
    ----------
    family : str
        The family name.
    seed : int
        The seed the scene was made from.
    image : ndarray, shape (H, W)
        The image.
    noise_sigma : float
        Its noise sigma (the fit is told it).
    polyline : Polyline
        The model polyline, displaced from the truth by ``true_offset_vu``.
    search_window_vu : tuple of int
        The coarse-search margin.
    use_polarity : bool
        Whether the fit uses the polarity test.
    true_offset_vu : tuple of float
        The planted offset.
    across_vu : tuple of float or None
        The unit direction the error is measured along, or None for 2-D.
    extra : dict
        Anything else a fit function may use (the sphere's geometry for a
        rendered scene).
    """

    family: str
    seed: int
    image: FloatArray
    noise_sigma: float
    polyline: Polyline
    search_window_vu: tuple[int, int]
    use_polarity: bool
    true_offset_vu: tuple[float, float]
    across_vu: tuple[float, float] | None
    extra: dict[str, Any]


def _robustness_family(name: str) -> Callable[[int], Case]:
    def make(seed: int) -> Case:
        s = ROBUSTNESS_FAMILIES[name](seed)
        return Case(name, seed, s.image, s.noise_sigma, s.polyline, s.search_window_vu,
                    s.use_polarity, s.true_offset_vu, s.across_vu, {"reachable": s.reachable})

    return make


def _sphere_family(edge: str) -> Callable[[int], Case]:
    def make(seed: int) -> Case:
        rng = np.random.default_rng(10_000 + seed)
        radius = float(rng.uniform(50.0, 120.0))
        phase = float(rng.uniform(20.0, 60.0) if edge == "limb" else rng.uniform(35.0, 150.0))
        ill = float(rng.uniform(0.0, 360.0))
        off = (float(rng.uniform(-2.0, 2.0)), float(rng.uniform(-2.0, 2.0)))
        psf = float(rng.uniform(0.0, 1.5))
        sc = render_sphere(radius_px=radius, phase_deg=phase, illumination_deg=ill, offset_vu=off,
                           psf_sigma_px=psf or None, seed=seed, albedo_dn=_SPHERE_ALBEDO_DN,
                           background_dn=_SPHERE_SKY_DN, poisson_gain=_SPHERE_GAIN,
                           read_noise_dn=_SPHERE_READ_DN)
        poly = sc.limb if edge == "limb" else sc.terminator
        assert poly is not None  # phase > 0
        extra = {"center_vu": sc.model_center_vu, "radius_px": radius, "phase_deg": phase,
                 "illumination_deg": ill, "psf_sigma_px": sc.psf_sigma_px, "edge": edge,
                 "reachable": True}
        return Case(f"sphere_{edge}", seed, sc.image, sc.noise_sigma, poly, (8, 8), True,
                    sc.true_offset_vu, None, extra)

    return make


#: Family name -> ``(seed) -> Case``, in table order.
FAMILIES: dict[str, Callable[[int], Case]] = {
    "sphere_limb": _sphere_family("limb"),
    "sphere_terminator": _sphere_family("terminator"),
    **{name: _robustness_family(name) for name in ROBUSTNESS_FAMILIES},
}


@dataclass(frozen=True)
class CoverageRow:
    """One family's coverage under one fit function.

    Attributes
    ----------
    family : str
        The family name.
    fits : int
        Scenes fitted.
    ok : int
        Fits whose status is ``ok`` (coverage is counted among these).
    flagged : float
        Fraction of the fits whose status is not ``ok``.
    median_error_px : float
        Median error of the ``ok`` fits (along ``across_vu`` or in 2-D).
    coverage : dict
        Reading name -> ``(inside 68 %, inside 95 %, median one-sigma)``
        over the ``ok`` fits (NaN when there are none); the one-sigma is
        along ``across_vu``, or the root mean of the two axis variances.
    """

    family: str
    fits: int
    ok: int
    flagged: float
    median_error_px: float
    coverage: dict[str, tuple[float, float, float]]


def _inside(err: FloatArray, cov: FloatArray, across: tuple[float, float] | None
            ) -> tuple[float, float]:
    """Squared Mahalanobis distance and one-sigma of ``err`` under ``cov``."""
    c = np.asarray(cov, dtype=np.float64)[:2, :2]
    if across is not None:
        a = np.asarray(across)
        var = float(a @ c @ a)
        x = float(err @ a)
        if var == math.inf:  # no claim along it: inside every ellipse
            return 0.0, math.inf
        if not var > 0.0:  # a zero (or NaN) variance claims the error is zero
            return math.inf, 0.0
        return x * x / var, math.sqrt(var)
    if not np.isfinite(c).all():
        return 0.0, math.inf
    w, v = np.linalg.eigh(0.5 * (c + c.T))
    top = float(w.max())
    if not top > 0.0:
        return math.inf, 0.0
    keep = w > 1e-9 * top
    y = v.T @ err
    # An unobserved direction (zero variance) carries no claim: left out.
    return float(np.sum(y[keep] ** 2 / w[keep])), math.sqrt(float(np.trace(c)) / 2.0)


def plain_fit(case: Case) -> Any:
    """The plain one-call pipeline (:func:`dtalign.pipeline.fit_polyline`); a
    rendered sphere's polyline declared as the limb or terminator it is."""
    from ..pipeline import fit_polyline

    p = case.polyline
    return fit_polyline(case.image, p.vertices_vu, p.normals_vu, p.sigmas,
                        search_window_vu=case.search_window_vu, noise_sigma=case.noise_sigma,
                        use_polarity=case.use_polarity, edge_kind=case.extra.get("edge"))


def profile_fit(case: Case) -> Any:
    """The one-call pipeline with the edge profile of a rendered sphere
    (:func:`dtalign.sphere_edge_profile` of the right law and geometry, the
    PSF's sigma left to be estimated from the image).

    Raises
    ------
    ValueError
        If ``case`` is not a rendered sphere (it has no profile).
    """
    from ..api.profiles import sphere_edge_profile
    from ..pipeline import fit_polyline

    x = case.extra
    if "edge" not in x:
        raise ValueError(f"case: family {case.family!r} has no edge profile")
    p = case.polyline
    prof = sphere_edge_profile(p.vertices_vu, center_vu=x["center_vu"], radius_px=x["radius_px"],
                               phase_deg=x["phase_deg"], illumination_deg=x["illumination_deg"],
                               edge=x["edge"], psf_sigma_px=None)
    return fit_polyline(case.image, p.vertices_vu, p.normals_vu, p.sigmas,
                        search_window_vu=case.search_window_vu, noise_sigma=case.noise_sigma,
                        use_polarity=case.use_polarity, edge_profile=prof)


def evaluate(
    fit_fn: Callable[[Case], Any],
    families: Iterable[str] | None = None,
    seeds: Iterable[int] = range(20),
    readings: dict[str, Callable[[Any], Any]] | None = None,
) -> list[CoverageRow]:
    """Coverage of each reading of ``fit_fn``'s results, family by family.

    Parameters
    ----------
    fit_fn : callable
        ``fit_fn(case) -> result`` with ``offset_vu`` and ``status``.
    families : iterable of str, optional
        Keys of :data:`FAMILIES`; all when None.
    seeds : iterable of int
        Seeds of each family.
    readings : dict, optional
        Name -> ``(result) -> covariance``; :data:`READINGS` when None.

    Returns
    -------
    list of CoverageRow

    Raises
    ------
    ValueError
        If a family name is unknown.
    """
    names = list(FAMILIES) if families is None else list(families)
    for name in names:
        if name not in FAMILIES:
            raise ValueError(f"families: unknown family {name!r}; expected one of {list(FAMILIES)}")
    reads = READINGS if readings is None else readings
    seed_list = [int(s) for s in seeds]
    rows = []
    for name in names:
        errors: list[float] = []
        marks: dict[str, list[tuple[float, float]]] = {k: [] for k in reads}
        fits = 0
        for seed in seed_list:
            case = FAMILIES[name](seed)
            result = fit_fn(case)
            fits += 1
            if str(result.status) != "ok":
                continue
            err = np.subtract(result.offset_vu, case.true_offset_vu)
            across = case.across_vu
            errors.append(abs(float(err @ np.asarray(across))) if across is not None
                          else math.hypot(err[0], err[1]))
            for key, read in reads.items():
                marks[key].append(_inside(err, np.asarray(read(result)), across))
        ok = len(errors)
        quant = CHI2_2D if FAMILIES[name](0).across_vu is None else CHI2_1D
        coverage = {}
        for key, vals in marks.items():
            if vals:
                d2 = np.array([v[0] for v in vals])
                coverage[key] = (float(np.mean(d2 <= quant[0])), float(np.mean(d2 <= quant[1])),
                                 float(statistics.median(v[1] for v in vals)))
            else:
                coverage[key] = (math.nan, math.nan, math.nan)
        rows.append(CoverageRow(
            family=name, fits=fits, ok=ok, flagged=(fits - ok) / fits if fits else math.nan,
            median_error_px=float(statistics.median(errors)) if errors else math.nan,
            coverage=coverage,
        ))
    return rows


def format_table(rows: Sequence[CoverageRow], *, rst: bool = False) -> str:
    """A table: per family, flagged, median error, and per reading the 68 % /
    95 % coverage and the median one-sigma; markdown, or with ``rst=True`` an
    RST simple table (the docs' uncertainty page)."""
    keys = list(rows[0].coverage) if rows else []
    head = ["family", "fits", "flagged", "median error px"]
    for k in keys:
        head += [f"{k} 68 %", f"{k} 95 %", f"{k} median sigma px"]
    body = []
    for r in rows:
        cells = [r.family, str(r.fits), f"{r.flagged:.2f}", f"{r.median_error_px:.3f}"]
        for k in keys:
            c68, c95, sig = r.coverage[k]
            cells += [f"{c68:.2f}", f"{c95:.2f}", f"{sig:.3f}"]
        body.append(cells)
    if rst:
        return rst_table(head, body)
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(cells) + " |" for cells in body]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    """Print the coverage table of :func:`plain_fit` on every family and of
    :func:`profile_fit` on the rendered spheres
    (``python -m dtalign.benchmarking.coverage``)."""
    parser = argparse.ArgumentParser(
        prog="python -m dtalign.benchmarking.coverage",
        description="Coverage of the pipeline's reported ellipses on seeded scenes.",
    )
    parser.add_argument("--seeds", type=int, default=40, help="scenes per family")
    parser.add_argument("--first-seed", type=int, default=0,
                        help="the first seed (seeds FIRST..FIRST+N-1)")
    parser.add_argument("--families", nargs="+", choices=list(FAMILIES), default=None)
    parser.add_argument("--rst", action="store_true", help="an RST table (the docs') instead of markdown")
    args = parser.parse_args(argv)
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    names = list(FAMILIES) if args.families is None else args.families
    # The per-fit warnings of the pipeline are what the "flagged" column counts.
    log = logging.getLogger("dtalign")
    level = log.level
    log.setLevel(logging.ERROR)
    try:
        rows = evaluate(plain_fit, names, seeds)
        spheres = [n for n in names if n.startswith("sphere_")]
        rows += [dataclasses.replace(r, family=f"{r.family} + profile")
                 for r in evaluate(profile_fit, spheres, seeds)] if spheres else []
    finally:
        log.setLevel(level)
    print(format_table(rows, rst=args.rst))
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
