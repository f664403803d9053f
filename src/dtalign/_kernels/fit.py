"""One compiled call for a whole ``lm_subpixel_refine``: polarity, LM, ridge, summary.

Each Numba dispatch costs about a microsecond of argument unboxing, and a
fit of 200 vertices takes ~100 us, so the stages run inside one kernel and
Python only validates before and wraps the result after.
"""

from __future__ import annotations

import math

import numpy as np

from .._jit import kernel
from .lm import evaluate_state, lm_loop
from .ridge import PATCH_MARGIN, magnitude_patch, ridge_loop
from .robust import normal_equations, polarity, symmetric_pinvh

#: Error codes returned by :func:`fit` (the wrapper raises for them).
OK = 0
BAD_GRADIENT = 1
BAD_DT = 2


@kernel
def fit(
    dt, grad, pts, nrm, sig, use_polarity, pose0, pivot, fit_rotation, pivot_distance,
    max_iterations, damping, step_tolerance, tukey_c, rcond, trust_region, tikhonov_alpha,
    ridge, ridge_half, ridge_sample_step, ridge_max_iterations, ridge_step_tolerance,
    ridge_max_displacement, use_libm,
):  # pragma: no cover - compiled
    """SPEC section 3, steps 1-5.

    Returns ``(error, pose, iterations, converged, r, w, jac, covariance,
    rms, raw_rms, inlier_count, degenerate)``; when ``error`` is not
    :data:`OK` the other values are meaningless.
    """
    n = pts.shape[0]
    n_params = 3 if fit_rotation else 2
    error = OK
    if use_polarity:
        pol, bad = polarity(pts, nrm, grad, pose0[0], pose0[1])
        if bad:
            error = BAD_GRADIENT
    else:
        pol = np.ones(n)
    pose = pose0.copy()
    iterations = 0
    converged = False
    r = np.zeros(n)
    w = np.zeros(n)
    jac = np.zeros((n, n_params))
    if error == OK:
        pose, iterations, converged, r, w, jac, bad = lm_loop(
            dt, pts, sig, pol, pose0, pivot, fit_rotation, pivot_distance, max_iterations,
            damping, step_tolerance, tukey_c, rcond, trust_region, tikhonov_alpha,
        )
        if bad:
            error = BAD_DT
    inlier_count = 0
    total_weight = 0.0
    for i in range(n):
        if w[i] > 0.0:
            inlier_count += 1
        total_weight += w[i]
    if error == OK and ridge and inlier_count > 0:
        patch, r0, c0 = magnitude_patch(
            grad, pts, pose[0], pose[1], ridge_half * ridge_sample_step + PATCH_MARGIN, use_libm
        )
        new_pose, ridge_iterations, _, bad = ridge_loop(
            patch, grad, r0, c0, pts, nrm, sig, pol, pose, pivot, fit_rotation, pivot_distance,
            ridge_max_iterations, ridge_step_tolerance, tukey_c, ridge_half, ridge_sample_step,
        )
        if bad:
            error = BAD_GRADIENT
        elif ridge_iterations > 0 and not (
            math.hypot(new_pose[0] - pose[0], new_pose[1] - pose[1]) > ridge_max_displacement
        ):
            pose = new_pose
            inv_var = np.empty(n)
            for i in range(n):
                inv_var[i] = 1.0 / (sig[i] * sig[i])
            scratch_h = np.zeros((n_params, n_params))
            scratch_g = np.zeros(n_params)
            status = evaluate_state(
                dt, pts, inv_var, sig, pol, pose, pivot, fit_rotation, tukey_c, r, w, jac,
                scratch_h, scratch_g,
            )[0]
            if status < 0:
                error = BAD_DT
            inlier_count = 0
            total_weight = 0.0
            for i in range(n):
                if w[i] > 0.0:
                    inlier_count += 1
                total_weight += w[i]
    degenerate = inlier_count == 0 or total_weight == 0.0
    weighted = 0.0
    raw = 0.0
    for i in range(n):
        weighted += w[i] * r[i] * r[i]
        raw += r[i] * r[i]
    raw_rms = math.sqrt(raw / n)
    if degenerate:
        rms = math.inf
        cov = np.full((n_params, n_params), np.inf)
    else:
        rms = math.sqrt(weighted / total_weight)
        info, _ = normal_equations(jac, w, r, n_params)
        cov = symmetric_pinvh(info, rcond)
    return error, pose, iterations, converged, r, w, jac, cov, rms, raw_rms, inlier_count, degenerate
