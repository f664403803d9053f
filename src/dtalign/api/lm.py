"""Stage 2: robust sub-pixel Levenberg-Marquardt fit (:ref:`contract-lm`).

The Python layer validates once and wraps the result; one compiled call
(:mod:`dtalign._kernels.fit`) computes the fixed polarity mask, runs the LM
loop, the optional ridge polish, and the summary with the pseudoinverse
covariance.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .._kernels import fit as _k
from .._kernels import lanes as _lanes
from . import ridge as _ridge_module
from .checks import LMArgs, check_lm_inputs, nonfinite_read
from .constants import (
    DEFAULT_LM_DAMPING,
    DEFAULT_LM_MAX_ITERATIONS,
    DEFAULT_LM_STEP_TOLERANCE,
    DEFAULT_PINVH_RCOND,
    DEFAULT_TUKEY_C,
)
from .options import fit_arguments
from .results import LMRefineResult

#: The ridge stage as shipped; :ref:`contract-changes` lets a caller replace the module
#: attribute, and only then does the LM call out to Python for it.
_compiled_ridge = _ridge_module.gradient_ridge_refine

__all__ = ["LMRefineResult", "lm_subpixel_refine"]


def lm_subpixel_refine(
    *,
    vertices_vu: ArrayLike,
    normals_vu: ArrayLike,
    sigma_normal_per_vertex_px: ArrayLike,
    image_edge_dt: ArrayLike,
    image_gradient_vu: ArrayLike | None = None,
    initial_offset_vu: Any = (0.0, 0.0),
    initial_rotation_rad: float = 0.0,
    fit_rotation: bool = False,
    pivot_vu: Any = None,
    pivot_distance_px: float = 0.0,
    use_polarity: bool = True,
    max_iterations: int = DEFAULT_LM_MAX_ITERATIONS,
    damping: float = DEFAULT_LM_DAMPING,
    step_tolerance_px: float = DEFAULT_LM_STEP_TOLERANCE,
    tukey_c: float = DEFAULT_TUKEY_C,
    pinvh_rcond: float = DEFAULT_PINVH_RCOND,
    trust_region_px: float | None = None,
    tikhonov_alpha: float = 0.0,
    final_gradient_ridge: bool = False,
) -> LMRefineResult:
    """Fit a translation (and optionally a rotation) of the polyline to the DT.

    Minimises ``sum_i w_i DT(R(theta)(x_i - p) + p + t)^2`` by
    Levenberg-Marquardt with Tukey IRLS weights
    ``w_i = tukey(r_i / sigma_i) / sigma_i^2`` (:ref:`contract-lm`).

    Parameters
    ----------
    vertices_vu, normals_vu : array_like, shape (N, 2)
        Model vertices (N > 0) and unit normals pointing to the bright side
        of each edge (into the disc for a limb; see the guide's *Normals*).
    sigma_normal_per_vertex_px : array_like, shape (N,)
        Finite, positive prior sigmas along the normals, pixels.
    image_edge_dt : array_like, shape (H, W)
        Edge distance transform (:func:`build_image_edge_dt`).
    image_gradient_vu : array_like, shape (H, W, 2), optional
        Signed gradient; required by ``use_polarity`` and
        ``final_gradient_ridge``.
    initial_offset_vu : tuple of float
        Starting translation, usually the coarse-search seed.
    initial_rotation_rad : float
        Starting rotation (held fixed unless ``fit_rotation``).
    fit_rotation : bool
        Also fit the rotation about ``pivot_vu``.
    pivot_vu : tuple of float, optional
        Rotation pivot; the vertex centroid by default.
    pivot_distance_px : float
        Pivot-to-image-centre distance converting a rotation step into
        pixels for the convergence test; must be > 0 with ``fit_rotation``.
    use_polarity : bool
        Drop vertices whose normal opposes the gradient at the seed.
    max_iterations, damping, step_tolerance_px
        LM iteration cap (an int, 0 to ``2**63 - 1``), initial damping,
        pixel-equivalent step tolerance (both finite, >= 0).
    tukey_c, pinvh_rcond
        Biweight cutoff (sigma units) and pseudoinverse cutoff.
    trust_region_px : float, optional
        Reject steps that move the translation farther than this from
        ``initial_offset_vu``.
    tikhonov_alpha : float
        Strength of a pull toward ``initial_offset_vu`` (0 disables).
    final_gradient_ridge : bool
        Polish with :func:`gradient_ridge_refine` and report the state there.

    Returns
    -------
    LMRefineResult

    Raises
    ------
    ValueError
        For any invalid argument; the messages are listed in :ref:`contract-errors`.
    """
    a = check_lm_inputs(locals())
    return fit_checked(a)


def _ridge_replaced() -> bool:
    """Whether a caller replaced ``dtalign.ridge.gradient_ridge_refine`` (:ref:`contract-changes`)."""
    return _ridge_module.gradient_ridge_refine is not _compiled_ridge


def fit_checked(a: LMArgs) -> LMRefineResult:
    if a.final_gradient_ridge and _ridge_replaced():
        return _fit_with_replaced_ridge(a)
    out = _k.fit(*fit_arguments(a))
    return _result(out)


def _result(out: tuple[Any, ...]) -> LMRefineResult:
    (error, pose, iterations, converged, r, w, _jac, cov, rms, raw_rms, inliers,
     degenerate, rejected) = out
    if error != _k.OK:
        raise_for_code(int(error))
    # Locked at their base, not only through the result's views: nobody else
    # holds these fresh kernel arrays, and a view cannot be made writable again.
    for arr in (cov, r, w):
        arr.flags.writeable = False
    return LMRefineResult(
        offset_vu=(float(pose[0]), float(pose[1])), rotation_rad=float(pose[2]),
        covariance=cov, residuals_px=r, weights=w, rms_px=float(rms),
        raw_rms_px=float(raw_rms), iterations=int(iterations), converged=bool(converged),
        inlier_count=int(inliers), degenerate=bool(degenerate),
        polarity_rejected_count=int(rejected),
    )


def _fit_with_replaced_ridge(a: LMArgs) -> LMRefineResult:
    """:ref:`contract-changes`: the LM compiled, then the caller's ridge stage, called with
    exactly the keywords the spec lists, then the state at its pose."""
    args = fit_arguments(a, ridge=False)
    grad = args[1]
    n = a.vertices.shape[0]
    if a.use_polarity:
        pol, bad = _lanes.polarity(a.vertices, a.normals, grad, a.offset[0], a.offset[1])
        if bad:
            raise_for_code(_k.BAD_GRADIENT)
    else:
        pol = np.ones(n)
    lm = _result(_k.fit_with_mask(*args, pol))
    if lm.inlier_count == 0:
        return lm
    ridge = _ridge_module.gradient_ridge_refine(
        vertices_vu=a.vertices,
        normals_vu=a.normals,
        sigma_normal_per_vertex_px=a.sigmas,
        gradient_magnitude=np.hypot(grad[:, :, 0], grad[:, :, 1]),
        initial_offset_vu=lm.offset_vu,
        weight_mask=np.array(pol, dtype=np.float64),
        initial_rotation_rad=lm.rotation_rad,
        fit_rotation=a.fit_rotation,
        pivot_vu=a.pivot,
        pivot_distance_px=a.pivot_distance,
        tukey_c=a.tukey_c,
    )
    if not ridge.applied:
        return lm
    moved = a._replace(
        offset=(float(ridge.offset_vu[0]), float(ridge.offset_vu[1])),
        rotation=float(ridge.rotation_rad), max_iterations=0,
    )
    at_ridge = _result(_k.fit_with_mask(*fit_arguments(moved, ridge=False), pol))
    return dataclasses.replace(
        at_ridge, iterations=lm.iterations, converged=bool(lm.converged or ridge.converged)
    )


def raise_for_code(error: int) -> None:
    """Raise the ValueError of a :mod:`dtalign._kernels.fit` error code."""
    if error == _k.BAD_GRADIENT:
        raise nonfinite_read("image_gradient_vu")
    if error == _k.BAD_DT:
        raise nonfinite_read("image_edge_dt")
    if error == _k.DIVERGED:
        raise ValueError(
            "the fit diverged to non-finite values: image_edge_dt (or the sigmas' "
            "1/sigma^2 weights) too large for the normal equations"
        )
    raise AssertionError(f"unknown fit error code {error}")  # pragma: no cover
