"""Whole-call argument checks shared by the compiled path and the reference.

The LM and ridge fitters take many keywords; checking them in one place
keeps the order of the checks (which decides which message a caller sees)
identical in both implementations, and converts every array exactly once.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from . import checks as check
from .checks import FloatArray


def tukey_c_value(c: Any, name: str = "c") -> float:
    """The biweight cutoff: a finite number > 0."""
    value = check.real(c, name)
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"{name} must be a positive finite number; got {c!r}")
    return value


def _rcond(value: Any, name: str) -> float:
    out = check.real(value, name)
    if not (math.isfinite(out) and out >= 0.0):
        raise ValueError(f"{name} must be finite and >= 0, got {out!r}")
    return out


def _nonnegative_or_inf(value: Any, name: str) -> float:
    """A bound that may be +inf (no bound) but not NaN or negative."""
    out = check.real(value, name)
    if math.isnan(out) or out < 0.0:
        raise ValueError(f"{name} must be >= 0 (NaN refused), got {out!r}")
    return out


def no_information_covariance(n_params: int) -> FloatArray:
    """The all-``+inf`` covariance that marks an LM fit with no information
    (SPEC section 3 step 5; ``information_matrix_to_covariance`` itself
    returns zeros there, SPEC section 2)."""
    return np.full((n_params, n_params), np.inf)


def check_covariance_inputs(jacobian: Any, weights: Any, rcond: Any) -> tuple[FloatArray, FloatArray, float]:
    """Checks of :func:`information_matrix_to_covariance`."""
    jac = check._as_float_array(jacobian, "jacobian")
    if jac.ndim != 2:
        raise ValueError(f"jacobian must be 2-D; got ndim={jac.ndim}")
    w = check._as_float_array(weights, "weights")
    if w.ndim != 1 or w.shape[0] != jac.shape[0]:
        raise ValueError(
            "weights must be a 1-D vector matching the Jacobian rows; "
            f"got weights {w.shape}, jacobian {jac.shape}"
        )
    check.require_finite(jac, "jacobian")
    check.require_finite(w, "weights")
    if (w < 0.0).any():
        raise ValueError("weights must be non-negative")
    return jac, w, _rcond(rcond, "rcond")


def min_support_fraction_value(value: Any) -> float:
    """SPEC 8.2's support floor: a real number in ``[0, 1]`` (NaN refused)."""
    fraction = check.real(value, "min_support_fraction")
    if not 0.0 <= fraction <= 1.0:
        raise ValueError(f"min_support_fraction must be in [0, 1]; got {value!r}")
    return fraction


def _clip_window(mv: int, mu: int, shape: tuple[int, ...]) -> tuple[int, int]:
    """A shift of H or more rows moves every pixel of the image off it:
    margins beyond the image change no result of a mask search."""
    return min(mv, max(shape[0] - 1, 0)), min(mu, max(shape[1] - 1, 0))


def _clip_window_for(verts: FloatArray, mv: int, mu: int, shape: tuple[int, ...]) -> tuple[int, int]:
    """Margins beyond which no vertex (in the image or off it) can land in it:
    a shift larger than ``max |coordinate| + size`` changes no result."""
    if verts.shape[0] == 0:
        return min(mv, 0), min(mu, 0)
    reach = np.abs(verts).max(axis=0)
    return (min(mv, int(reach[0]) + shape[0] + 1), min(mu, int(reach[1]) + shape[1] + 1))


def check_coarse_inputs(
    edge_mask: Any, polyline_mask: Any, search_window_vu: Any, min_support_fraction: Any = 0.0
) -> tuple[np.ndarray, NDArray[np.bool_], int, int, float]:
    """Checks of ``coarse_ncc_search[_scored]`` in SPEC 8.2's order.

    Returns the edge mask (bool when its values are 0/1, else its float64
    values, which the overlap sums), the polyline mask as bool, the window
    clipped to the image, and the support fraction.
    """
    e = np.asarray(edge_mask)
    p = np.asarray(polyline_mask)
    if e.ndim != 2 or p.ndim != 2:
        raise ValueError(
            f"edge_mask and polyline_mask must be 2-D; got ndims {e.ndim}, {p.ndim}"
        )
    if e.shape != p.shape:
        raise ValueError(f"shape mismatch: edge_mask {e.shape} vs polyline_mask {p.shape}")
    mv, mu = check.search_window(search_window_vu)
    fraction = min_support_fraction_value(min_support_fraction)
    edge = check.mask_values(e, "edge_mask")
    poly = check.mask2d(p, "polyline_mask")
    mv, mu = _clip_window(mv, mu, e.shape)
    return edge, poly, mv, mu, fraction


#: Bounds on a vertex scan's work after its window is clipped: at most this
#: many shifts, and at most this many (shift row or column) x vertex table
#: entries (the basin scan's axis tables, ~17 bytes each). Far beyond any
#: real search (a +-50 window over 20,000 vertices is 2e6 entries); they keep
#: a polyline thrown far off the frame with a huge window from running for
#: hours or exhausting memory.
MAX_SCAN_SHIFTS = 1 << 26
MAX_SCAN_TABLE = 1 << 26


def _check_scan_size(mv: int, mu: int, n_vertices: int) -> None:
    shifts = (2 * mv + 1) * (2 * mu + 1)
    table = (2 * mv + 2 * mu + 2) * n_vertices
    if shifts > MAX_SCAN_SHIFTS or table > MAX_SCAN_TABLE:
        raise ValueError(
            f"search_window_vu is too large for this polyline: {shifts} shifts of "
            f"{n_vertices} vertices (at most {MAX_SCAN_SHIFTS} shifts and "
            f"{MAX_SCAN_TABLE} shift-vertex pairs per axis)"
        )


class PolaritySearchArgs(NamedTuple):
    """Validated arguments of ``coarse_polarity_search_scored``."""

    edge: NDArray[np.bool_]
    gradient: FloatArray
    vertices: FloatArray
    normals: FloatArray
    mv: int
    mu: int
    fraction: float


def check_polarity_search_inputs(
    edge_mask: Any, image_gradient_vu: Any, vertices_vu: Any, normals_vu: Any,
    search_window_vu: Any, min_support_fraction: Any,
) -> PolaritySearchArgs:
    """Checks of ``coarse_polarity_search_scored`` in SPEC 8.3's order.

    The gradient may hold NaN (such a vertex's weight, and its shift's
    score, is NaN, which never wins); vertices and normals must be finite.
    """
    e = np.asarray(edge_mask)
    if e.ndim != 2:
        raise ValueError(f"edge_mask must be 2-D; got ndim={e.ndim}")
    grad = check._as_float_array(image_gradient_vu, "image_gradient_vu")
    if grad.ndim != 3 or grad.shape[2] != 2:
        raise ValueError(f"image_gradient_vu must have shape (H, W, 2); got {grad.shape}")
    if grad.shape[:2] != e.shape:
        raise ValueError(
            f"shape mismatch: edge_mask {e.shape} vs image_gradient_vu {grad.shape[:2]}"
        )
    verts = check.vertices(vertices_vu, "vertices_vu")
    norms = check.normals(normals_vu, verts.shape[0])
    mv, mu = check.search_window(search_window_vu)
    fraction = min_support_fraction_value(min_support_fraction)
    mv, mu = _clip_window_for(verts, mv, mu, e.shape)
    _check_scan_size(mv, mu, verts.shape[0])
    return PolaritySearchArgs(check.mask2d(e, "edge_mask"), grad, verts, norms, mv, mu, fraction)


class BasinArgs(NamedTuple):
    """Validated arguments of ``find_secondary_dt_minimum``."""

    dt: FloatArray
    vertices: FloatArray
    converged: tuple[float, float]
    mv: int
    mu: int
    exclude_radius: float
    fraction: float


def check_basin_inputs(
    image_edge_dt: Any, vertices_vu: Any, converged_offset_vu: Any, search_window_vu: Any,
    exclude_radius_px: Any, min_support_fraction: Any,
) -> BasinArgs:
    """Checks of ``find_secondary_dt_minimum`` (the reference checks nothing:
    what it accepts gives the same result here; non-finite or mis-shaped input
    is refused naming the argument). Margins are ``int()`` of the window
    entries, as SPEC 8.4 says; a negative one scans nothing."""
    dt = check.image2d(image_edge_dt, "image_edge_dt")
    verts = check.vertices(vertices_vu, "vertices_vu")
    converged = check.pair(converged_offset_vu, "converged_offset_vu")
    wv, wu = check.pair(search_window_vu, "search_window_vu")
    radius = check.finite_real(exclude_radius_px, "exclude_radius_px")
    fraction = min_support_fraction_value(min_support_fraction)
    # int() as the reference takes it, after bounding what no vertex can use
    mv, mu = (int(max(min(m, float(1 << 53)), -1.0)) for m in (wv, wu))
    if mv >= 0 and mu >= 0:
        mv, mu = _clip_window_for(verts, mv, mu, dt.shape)
        _check_scan_size(mv, mu, verts.shape[0])
    return BasinArgs(dt, verts, converged, mv, mu, radius, fraction)


class LMArgs(NamedTuple):
    """Validated, converted arguments of ``lm_subpixel_refine``."""

    vertices: FloatArray
    normals: FloatArray
    sigmas: FloatArray
    dt: FloatArray
    gradient: FloatArray | None
    offset: tuple[float, float]
    rotation: float
    fit_rotation: bool
    pivot: tuple[float, float]
    pivot_distance: float
    use_polarity: bool
    max_iterations: int
    damping: float
    step_tolerance: float
    tukey_c: float
    pinvh_rcond: float
    trust_region_px: float | None
    tikhonov_alpha: float
    final_gradient_ridge: bool


def check_lm_inputs(
    kw: Mapping[str, Any],
    polyline: tuple[FloatArray, FloatArray, FloatArray, tuple[float, float]] | None = None,
) -> LMArgs:
    """Check ``lm_subpixel_refine``'s keywords in SPEC section 1's order.

    ``polyline``, when given, is :func:`dtalign._validation.polyline`'s
    result for the three per-vertex keywords, which a caller has already
    checked (the pipeline checks them first, for its own messages): it
    stands for that check, which is then not run twice.
    """
    if polyline is None:
        polyline = check.polyline(
            kw["vertices_vu"], kw["normals_vu"], kw["sigma_normal_per_vertex_px"]
        )
    verts, norms, sig, centroid = polyline
    dt = check.image2d(kw["image_edge_dt"], "image_edge_dt")
    fit_rotation = bool(kw["fit_rotation"])
    offset, rotation, pivot, distance = check.pose(
        verts,
        fit_rotation=fit_rotation,
        pivot_vu=kw["pivot_vu"],
        pivot_distance_px=kw["pivot_distance_px"],
        initial_offset_vu=kw["initial_offset_vu"],
        initial_rotation_rad=kw["initial_rotation_rad"],
        centroid=centroid,
    )
    has_gradient = kw["image_gradient_vu"] is not None
    if kw["final_gradient_ridge"] and not has_gradient:
        raise ValueError("final_gradient_ridge=True requires image_gradient_vu")
    if kw["use_polarity"] and not has_gradient:
        raise ValueError("use_polarity=True requires image_gradient_vu")
    grad = check.gradient(kw["image_gradient_vu"]) if has_gradient else None
    trust = kw["trust_region_px"]
    return LMArgs(
        vertices=verts,
        normals=norms,
        sigmas=sig,
        dt=dt,
        gradient=grad,
        offset=offset,
        rotation=rotation,
        fit_rotation=fit_rotation,
        pivot=pivot,
        pivot_distance=distance,
        use_polarity=bool(kw["use_polarity"]),
        max_iterations=check.iteration_count(kw["max_iterations"], "max_iterations"),
        damping=check.nonnegative_real(kw["damping"], "damping"),
        step_tolerance=check.nonnegative_real(kw["step_tolerance_px"], "step_tolerance_px"),
        tukey_c=tukey_c_value(kw["tukey_c"], "tukey_c"),
        pinvh_rcond=_rcond(kw["pinvh_rcond"], "pinvh_rcond"),
        trust_region_px=None if trust is None else _nonnegative_or_inf(trust, "trust_region_px"),
        tikhonov_alpha=check.nonnegative_real(kw["tikhonov_alpha"], "tikhonov_alpha"),
        final_gradient_ridge=bool(kw["final_gradient_ridge"]),
    )


class RidgeArgs(NamedTuple):
    """Validated, converted arguments of ``gradient_ridge_refine``."""

    vertices: FloatArray
    normals: FloatArray
    sigmas: FloatArray
    magnitude: FloatArray
    offset: tuple[float, float]
    rotation: float
    fit_rotation: bool
    pivot: tuple[float, float]
    pivot_distance: float
    weight_mask: FloatArray
    max_iterations: int
    step_tolerance: float
    tukey_c: float
    half_width: float
    sample_step: float
    max_total_displacement: float


def check_ridge_inputs(kw: Mapping[str, Any]) -> RidgeArgs:
    """Check ``gradient_ridge_refine``'s keywords (LM's order for the shared ones)."""
    verts, norms, sig, centroid = check.polyline(
        kw["vertices_vu"], kw["normals_vu"], kw["sigma_normal_per_vertex_px"]
    )
    magnitude = check.image2d(kw["gradient_magnitude"], "gradient_magnitude")
    fit_rotation = bool(kw["fit_rotation"])
    offset, rotation, pivot, distance = check.pose(
        verts,
        fit_rotation=fit_rotation,
        pivot_vu=kw["pivot_vu"],
        pivot_distance_px=kw["pivot_distance_px"],
        initial_offset_vu=kw["initial_offset_vu"],
        initial_rotation_rad=kw["initial_rotation_rad"],
        centroid=centroid,
    )
    half_width = check.positive_real(kw["half_width_px"], "half_width_px")
    sample_step = check.positive_real(kw["sample_step_px"], "sample_step_px")
    ratio = half_width / sample_step
    if math.isfinite(ratio) and round(ratio) < 1:
        raise ValueError(
            "half_width_px / sample_step_px must round to at least 1: the profile "
            f"needs three samples (got {half_width!r} and {sample_step!r})"
        )
    check.ridge_profile_size(half_width, sample_step)
    return RidgeArgs(
        vertices=verts,
        normals=norms,
        sigmas=sig,
        magnitude=magnitude,
        offset=offset,
        rotation=rotation,
        fit_rotation=fit_rotation,
        pivot=pivot,
        pivot_distance=distance,
        weight_mask=check.weight_mask(kw["weight_mask"], verts.shape[0]),
        max_iterations=check.iteration_count(kw["max_iterations"], "max_iterations"),
        step_tolerance=check.nonnegative_real(kw["step_tolerance_px"], "step_tolerance_px"),
        tukey_c=tukey_c_value(kw["tukey_c"], "tukey_c"),
        half_width=half_width,
        sample_step=sample_step,
        max_total_displacement=_nonnegative_or_inf(
            kw["max_total_displacement_px"], "max_total_displacement_px"
        ),
    )
