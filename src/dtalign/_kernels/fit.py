"""One compiled call for a whole ``lm_subpixel_refine``: polarity, LM, ridge, summary.

Each Numba dispatch's argument unboxing costs about a hundredth of a fit of
200 vertices, so the stages run inside one kernel and Python only validates
before and wraps the result after.
"""

from __future__ import annotations

import math

import numpy as np

from .._jit import kernel
from .lanes import polarity, staging_buffers, summary_lanes
from .lm import LOOP_BAD_DT, LOOP_DIVERGED, evaluate_state, lm_loop
from .pairwise import numpy_sum
from .params import n_params as _n_params
from .ridge import (
    PATCH_MARGIN,
    RIDGE_BAD_FIELD,
    RIDGE_DIVERGED,
    MagnitudeField,
    RidgeSettings,
    magnitude_patch,
    ridge_loop,
)
from .robust import symmetric_pinvh

#: The LM driver's polish samples its gradient vectors, not a magnitude image.
_NO_MAGNITUDE = np.zeros((0, 0))

#: Error codes returned by :func:`fit` (the wrapper raises for them).
OK = 0
BAD_GRADIENT = 1
BAD_DT = 2
DIVERGED = 3  # a step or the normal equations overflowed to non-finite values


@kernel
def _failed(error, pose0, n, n_params):
    """The tuple :func:`fit` returns with an error code (the rest is unused)."""
    empty = np.zeros(n)
    return (error, pose0.copy(), 0, False, empty, empty.copy(), np.zeros((n_params, n)),
            np.full((n_params, n_params), np.inf), math.inf, math.inf, 0, True, 0)


@kernel
def accepted_raw_rms(r, pol):
    """``raw_rms_px`` as :ref:`contract-changes` defines it: ``sqrt(mean(r**2))`` over the vertices the
    seed polarity mask accepted, summed as NumPy's ``mean`` sums (pairwise),
    so it equals the reference's bit for bit; ``+inf`` when none is."""
    squares = np.empty(r.shape[0])
    k = 0
    for i in range(r.shape[0]):
        if pol[i] > 0.0:
            squares[k] = r[i] * r[i]
            k += 1
    if k == 0:
        return math.inf
    return math.sqrt(numpy_sum(squares, k) / k)


@kernel
def _summary(r, w):
    """``(inliers, sum(w), sum(w r^2))``, summed lane-wise as the LM's sums."""
    n = r.shape[0]
    n4 = n - n % 4
    inliers, total, weighted = summary_lanes(r, w, n4)
    for i in range(n4, n):
        if w[i] > 0.0:
            inliers += 1
        total += w[i]
        weighted += w[i] * r[i] * r[i]
    return inliers, total, weighted


@kernel
def fit(dt, grad, pts, nrm, sig, pose0, pivot, pivot_distance, opts):
    """:ref:`contract-lm`, steps 1-4.

    ``opts`` is the one record of LM / ridge options
    (:class:`dtalign.api.options.LMKernelOptions`, a named tuple: Numba
    compiles one specialisation for its field types and caches it).

    Returns ``(error, pose, iterations, converged, r, w, jac, covariance,
    rms, raw_rms, inlier_count, degenerate, polarity_rejected_count)``
    (``jac`` as columns, ``(P, N)``); when ``error`` is not :data:`OK` the
    other values are placeholders.
    """
    n = pts.shape[0]
    n_params = _n_params(opts.fit_rotation)
    if opts.use_polarity:
        pol, bad = polarity(pts, nrm, grad, pose0[0], pose0[1])
        if bad:
            return _failed(BAD_GRADIENT, pose0, n, n_params)
    else:
        pol = np.ones(n)
    return fit_with_mask(dt, grad, pts, nrm, sig, pose0, pivot, pivot_distance, opts, pol)


@kernel
def fit_with_mask(dt, grad, pts, nrm, sig, pose0, pivot, pivot_distance, opts, pol):
    """:func:`fit` from a given seed polarity mask ``pol`` (1.0 accepted, 0.0
    not; ``opts.use_polarity`` is not read).

    With ``opts.max_iterations == 0`` and no ridge it is the result of
    :ref:`contract-lm` (step 4) at ``pose0`` alone: the state and summary there, what
    ``lm_subpixel_refine`` needs after a replaced ridge stage moved the pose
    (:ref:`contract-changes`).
    """
    fit_rotation = opts.fit_rotation
    tukey_c = opts.tukey_c
    ridge_half = opts.ridge_half
    ridge_sample_step = opts.ridge_sample_step
    n = pts.shape[0]
    n_params = _n_params(fit_rotation)
    rejected = 0
    for i in range(n):
        if not pol[i] > 0.0:
            rejected += 1
    pose, iterations, converged, r, w, jac, info, status = lm_loop(
        dt, pts, sig, pol, pose0, pivot, fit_rotation, pivot_distance, opts.max_iterations,
        opts.damping, opts.step_tolerance_px, tukey_c, opts.pinvh_rcond, opts.trust_region_px,
        opts.tikhonov_alpha,
    )
    if status == LOOP_BAD_DT:
        return _failed(BAD_DT, pose0, n, n_params)
    if status == LOOP_DIVERGED:
        return _failed(DIVERGED, pose0, n, n_params)
    inlier_count, total_weight, weighted = _summary(r, w)
    if opts.ridge and inlier_count > 0:
        patch, tiles, r0, c0 = magnitude_patch(
            grad, pts, pose[0], pose[1], ridge_half * ridge_sample_step + PATCH_MARGIN
        )
        new_pose, ridge_iterations, ridge_converged, ridge_status = ridge_loop(
            MagnitudeField(_NO_MAGNITUDE, patch, tiles, grad, r0, c0, opts.use_libm), pts, nrm,
            sig, pol, pose, pivot, fit_rotation, pivot_distance,
            RidgeSettings(opts.ridge_max_iterations, opts.ridge_step_tolerance, tukey_c,
                          ridge_half, ridge_sample_step),
        )
        if ridge_status == RIDGE_BAD_FIELD:
            return _failed(BAD_GRADIENT, pose0, n, n_params)
        if ridge_status == RIDGE_DIVERGED:
            return _failed(DIVERGED, pose0, n, n_params)
        moved = np.hypot(new_pose[0] - pose[0], new_pose[1] - pose[1])
        if not (math.isfinite(new_pose[0]) and math.isfinite(new_pose[1])
                and math.isfinite(new_pose[2])):
            return _failed(DIVERGED, pose0, n, n_params)
        if ridge_iterations > 0 and not moved > opts.ridge_max_displacement:
            pose = new_pose
            converged = converged or ridge_converged  # :ref:`contract-changes`
            inv_var = np.empty(n)
            for i in range(n):
                inv_var[i] = 1.0 / (sig[i] * sig[i])
            info = np.zeros((n_params, n_params))
            status = evaluate_state(
                dt, pts, inv_var, sig, pol, pose, pivot, fit_rotation, tukey_c, r, w, jac,
                info, np.zeros(n_params), np.zeros(n), False, staging_buffers(),
            )[0]
            if status < 0:
                return _failed(BAD_DT, pose0, n, n_params)
            inlier_count, total_weight, weighted = _summary(r, w)
    degenerate = inlier_count == 0 or total_weight == 0.0
    raw_rms = accepted_raw_rms(r, pol)
    if degenerate:
        rms = math.inf
        cov = np.full((n_params, n_params), np.inf)
    else:
        rms = math.sqrt(weighted / total_weight)
        # info: the final state's J^T W J as evaluate_state summed it (the
        # products of normal_equations(jac.T, w, r), summed lane-wise)
        cov, ok = symmetric_pinvh(info, opts.pinvh_rcond)
        if not ok:
            return _failed(DIVERGED, pose0, n, n_params)
    return (OK, pose, iterations, converged, r, w, jac, cov, rms, raw_rms, inlier_count,
            degenerate, rejected)
