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

from . import _validation as check
from ._validation import FloatArray


def tukey_c_value(c: Any, name: str = "c") -> float:
    """The biweight cutoff: a finite number > 0."""
    value = check.real(c, name)
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"{name} must be a positive finite number, got {value!r}")
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
    """The all-``+inf`` covariance that marks a fit with no information."""
    return np.full((n_params, n_params), np.inf)


def check_covariance_inputs(jacobian: Any, weights: Any, rcond: Any) -> tuple[FloatArray, FloatArray, float]:
    """Checks of :func:`information_matrix_to_covariance`."""
    jac = check._as_float_array(jacobian, "jacobian")
    if jac.ndim != 2:
        raise ValueError(f"jacobian must be 2-D, got {jac.ndim}-D")
    w = check._as_float_array(weights, "weights")
    if w.ndim != 1 or w.shape[0] != jac.shape[0]:
        raise ValueError(
            f"weights must be a 1-D vector of length {jac.shape[0]} (jacobian rows), "
            f"got shape {w.shape}"
        )
    check.require_finite(jac, "jacobian")
    check.require_finite(w, "weights")
    if (w < 0.0).any():
        raise ValueError("weights must be non-negative")
    return jac, w, _rcond(rcond, "rcond")


def check_coarse_inputs(edge_mask: Any, polyline_mask: Any, search_window_vu: Any) -> tuple[Any, Any, int, int]:
    """Shared checks of the coarse search; the window is clipped to the image."""
    edge = check.mask2d(edge_mask, "edge_mask")
    poly = check.mask2d(polyline_mask, "polyline_mask")
    if edge.shape != poly.shape:
        raise ValueError(
            f"edge_mask and polyline_mask shape mismatch: {edge.shape} vs {poly.shape}"
        )
    mv, mu = check.search_window(search_window_vu)
    # A shift of H or more rows moves every polyline pixel off the image.
    mv = min(mv, max(edge.shape[0] - 1, 0))
    mu = min(mu, max(edge.shape[1] - 1, 0))
    return edge, poly, mv, mu


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
    stands for that check (~5 us warm).
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
        max_iterations=check.count(kw["max_iterations"], "max_iterations"),
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
    if round(half_width / sample_step) < 1:
        raise ValueError(
            "half_width_px / sample_step_px must round to at least 1: the profile "
            f"needs three samples (got {half_width!r} and {sample_step!r})"
        )
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
        max_iterations=check.count(kw["max_iterations"], "max_iterations"),
        step_tolerance=check.nonnegative_real(kw["step_tolerance_px"], "step_tolerance_px"),
        tukey_c=tukey_c_value(kw["tukey_c"], "tukey_c"),
        half_width=half_width,
        sample_step=sample_step,
        max_total_displacement=_nonnegative_or_inf(
            kw["max_total_displacement_px"], "max_total_displacement_px"
        ),
    )
