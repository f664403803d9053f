"""Stage 2: robust sub-pixel Levenberg-Marquardt fit (SPEC section 3).

The Python layer validates once, computes the fixed polarity mask, runs the
compiled loop (:mod:`dtalign._kernels.lm`), optionally the compiled ridge
polish, and turns the final state into an :class:`LMRefineResult` with the
SciPy ``pinvh`` covariance.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ._args import LMArgs, check_lm_inputs, no_information_covariance
from ._constants import (
    DEFAULT_LM_DAMPING,
    DEFAULT_LM_MAX_ITERATIONS,
    DEFAULT_LM_STEP_TOLERANCE,
    DEFAULT_PINVH_RCOND,
    DEFAULT_TUKEY_C,
)
from ._kernels import lm as _k
from ._kernels import robust as _robust
from ._results import LMRefineResult
from ._validation import nonfinite_read
from .ridge import run_ridge
from .weights import pinvh_covariance

__all__ = ["LMRefineResult", "lm_subpixel_refine"]


def lm_subpixel_refine(
    *,
    vertices_vu: Any,
    normals_vu: Any,
    sigma_normal_per_vertex_px: Any,
    image_edge_dt: Any,
    image_gradient_vu: Any = None,
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
    ``w_i = tukey(r_i / sigma_i) / sigma_i^2`` (SPEC section 3).

    Parameters
    ----------
    vertices_vu, normals_vu : array_like, shape (N, 2)
        Model vertices (N > 0) and outward normals (toward the bright side).
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
        LM iteration cap, initial damping, pixel-equivalent step tolerance.
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
        For any invalid argument; the messages are listed in SPEC section 1.
    """
    a = check_lm_inputs(locals())
    return _fit(a)


def _fit(a: LMArgs) -> LMRefineResult:
    pts, sig = a.vertices, a.sigmas
    if a.use_polarity:
        assert a.gradient is not None  # guaranteed by check_lm_inputs
        pol, bad = _robust.polarity(pts, a.normals, a.gradient, a.offset[0], a.offset[1])
        if bad:
            raise nonfinite_read("image_gradient_vu")
    else:
        pol = np.ones(pts.shape[0])
    pivot = np.array(a.pivot)
    pose0 = np.array([a.offset[0], a.offset[1], a.rotation])
    trust = -1.0 if a.trust_region_px is None else a.trust_region_px
    pose, iterations, converged, r, w, jac, bad = _k.lm_loop(
        a.dt, pts, sig, pol, pose0, pivot, a.fit_rotation, a.pivot_distance,
        a.max_iterations, a.damping, a.step_tolerance, a.tukey_c, a.pinvh_rcond,
        trust, a.tikhonov_alpha,
    )
    if bad:
        raise nonfinite_read("image_edge_dt")
    if a.final_gradient_ridge and (w > 0).any():
        assert a.gradient is not None
        ridge = run_ridge(
            a.gradient, pts, a.normals, sig, pol, pose, pivot, a.fit_rotation,
            a.pivot_distance, field_name="image_gradient_vu", tukey_c=a.tukey_c,
        )
        if ridge.applied:
            pose = np.array([ridge.offset_vu[0], ridge.offset_vu[1], ridge.rotation_rad])
            status = _k.evaluate_state(
                a.dt, pts, sig, pol, pose, pivot, a.fit_rotation, a.tukey_c, r, w, jac
            )
            if status < 0:
                raise nonfinite_read("image_edge_dt")
    return _summarise(pose, int(iterations), bool(converged), r, w, jac, a.pinvh_rcond)


def _summarise(
    pose: np.ndarray, iterations: int, converged: bool, r: np.ndarray, w: np.ndarray,
    jac: np.ndarray, rcond: float,
) -> LMRefineResult:
    """SPEC section 3 step 5: counts, RMS values and the covariance."""
    inlier_count = int(np.count_nonzero(w > 0))
    total_weight = float(w.sum())
    degenerate = inlier_count == 0 or total_weight == 0.0
    if degenerate:
        rms = math.inf
        cov = no_information_covariance(jac.shape[1])
    else:
        rms = math.sqrt(float(np.dot(w * r, r)) / total_weight)
        info, _ = _robust.normal_equations(jac, w, r, jac.shape[1])
        cov = pinvh_covariance(info, rcond)
    raw_rms = math.sqrt(float(np.dot(r, r)) / r.shape[0])
    return LMRefineResult(
        offset_vu=(float(pose[0]), float(pose[1])),
        rotation_rad=float(pose[2]),
        covariance=cov,
        residuals_px=r,
        weights=w,
        rms_px=rms,
        raw_rms_px=raw_rms,
        iterations=iterations,
        converged=converged,
        inlier_count=inlier_count,
        degenerate=degenerate,
    )
