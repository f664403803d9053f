"""Stage 3 (optional): Gauss-Newton polish onto the gradient-magnitude ridge."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .._kernels import ridge as _k
from .checks import check_ridge_inputs, nonfinite_read
from .constants import (
    DEFAULT_LM_STEP_TOLERANCE,
    DEFAULT_RIDGE_HALF_WIDTH_PX,
    DEFAULT_RIDGE_MAX_ITERATIONS,
    DEFAULT_RIDGE_MAX_TOTAL_DISPLACEMENT_PX,
    DEFAULT_RIDGE_SAMPLE_STEP_PX,
    DEFAULT_TUKEY_C,
)
from .results import RidgeRefineResult

__all__ = ["RidgeRefineResult", "gradient_ridge_refine"]

#: An empty gradient tells the kernel to sample the magnitude image itself.
_NO_GRADIENT = np.zeros((0, 0, 2))
_NO_TILES = np.zeros((0, 0), dtype=np.uint8)
_NO_PATCH = np.zeros((0, 0))


def gradient_ridge_refine(
    *,
    vertices_vu: ArrayLike,
    normals_vu: ArrayLike,
    sigma_normal_per_vertex_px: ArrayLike,
    gradient_magnitude: ArrayLike,
    initial_offset_vu: Any,
    weight_mask: ArrayLike | None = None,
    initial_rotation_rad: float = 0.0,
    fit_rotation: bool = False,
    pivot_vu: Any = None,
    pivot_distance_px: float = 0.0,
    max_iterations: int = DEFAULT_RIDGE_MAX_ITERATIONS,
    step_tolerance_px: float = DEFAULT_LM_STEP_TOLERANCE,
    tukey_c: float = DEFAULT_TUKEY_C,
    half_width_px: float = DEFAULT_RIDGE_HALF_WIDTH_PX,
    sample_step_px: float = DEFAULT_RIDGE_SAMPLE_STEP_PX,
    max_total_displacement_px: float = DEFAULT_RIDGE_MAX_TOTAL_DISPLACEMENT_PX,
) -> RidgeRefineResult:
    """Polish a pose onto the continuous gradient-magnitude ridge.

    Each vertex samples ``gradient_magnitude`` along its (rotated) normal at
    ``t = -n*step .. n*step`` (``n = round(half_width_px / sample_step_px)``),
    locates the peak with a parabola, and Gauss-Newton drives the signed
    peak distances to zero under Tukey weights (:ref:`contract-ridge`).

    Parameters
    ----------
    vertices_vu, normals_vu : array_like, shape (N, 2)
        Model vertices (N > 0) and unit normals pointing to the bright side
        of each edge (into the disc for a limb).
    sigma_normal_per_vertex_px : array_like, shape (N,)
        Finite, positive prior sigmas along the normals.
    gradient_magnitude : array_like, shape (H, W)
        ``hypot(g_v, g_u)`` of the image.
    initial_offset_vu : tuple of float
        Starting translation (typically the LM result).
    weight_mask : array_like of bool, shape (N,), optional
        Vertices allowed to carry weight (e.g. the polarity mask).
    initial_rotation_rad, fit_rotation, pivot_vu, pivot_distance_px
        Rotation about the pivot (vertex centroid by default); fitting it
        needs ``pivot_distance_px > 0``.
    max_iterations, step_tolerance_px, tukey_c
        Iteration cap (an int, 0 to ``2**63 - 1``), pixel-equivalent step
        tolerance, biweight cutoff.
    half_width_px, sample_step_px : float
        Profile half-width and spacing, pixels: the profile's
        ``2 * round(half_width_px / sample_step_px) + 1`` samples per
        vertex must number 3 to 10,001 (docs/limits.rst).
    max_total_displacement_px : float
        The polish is discarded if the translation moves farther than this.

    Returns
    -------
    RidgeRefineResult
        The refined pose with ``applied=True``, or the inputs with
        ``applied=False`` if no iteration ran or the cap was exceeded.
    """
    a = check_ridge_inputs(locals())
    pose0 = np.array([a.offset[0], a.offset[1], a.rotation])
    pose, iterations, converged, status = _k.ridge_loop(
        _k.MagnitudeField(a.magnitude, _NO_PATCH, _NO_TILES, _NO_GRADIENT, 0, 0, False),
        a.vertices, a.normals, a.sigmas, a.weight_mask, pose0, np.array(a.pivot), a.fit_rotation,
        a.pivot_distance,
        _k.RidgeSettings(a.max_iterations, a.step_tolerance, a.tukey_c,
                         round(a.half_width / a.sample_step), a.sample_step),
    )
    if status == _k.RIDGE_BAD_FIELD:
        raise nonfinite_read("gradient_magnitude")
    if status == _k.RIDGE_DIVERGED or not np.isfinite(pose).all():
        raise ValueError(
            "the ridge polish diverged to non-finite values: gradient_magnitude or "
            "normals_vu too large for the normal equations"
        )
    moved = math.hypot(pose[0] - pose0[0], pose[1] - pose0[1])
    applied = iterations > 0 and not moved > a.max_total_displacement
    final = pose if applied else pose0
    return RidgeRefineResult(
        offset_vu=(float(final[0]), float(final[1])),
        rotation_rad=float(final[2]),
        iterations=int(iterations),
        converged=bool(converged),
        applied=bool(applied),
    )
