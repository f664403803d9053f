"""The Levenberg-Marquardt / Tukey IRLS loop of :ref:`contract-lm`, compiled whole.

A pure-NumPy iteration spends most of its time in interpreter overhead on
arrays of a few hundred vertices; compiling the whole loop removes that.
A step costs a 2x2 or 3x3 solve and one pass over the vertices at the
trial pose: the DT and its central differences, and the trial cost. If
the step is accepted, those samples are the new state's, and the weights
and normal equations follow in one more pass (no N x 5 temporaries). The
state arrays are allocated once per fit and overwritten.
"""

from __future__ import annotations

import math

import numpy as np

from .._jit import kernel
from .lanes import PENALTY, lane_cost, lane_sums, sample_state, staging_buffers
from .params import n_params as _n_params
from .robust import solve_step, tukey

#: Mirrors of the constants in dtalign.api.constants, as compile-time literals.
LAMBDA_MIN = 1.0e-12
LAMBDA_MAX = 1.0e6

#: Status of :func:`lm_loop`.
LOOP_OK = 0
LOOP_BAD_DT = 1  # a sample read a NaN or inf from the DT
LOOP_DIVERGED = 2  # the normal equations or a step overflowed


@kernel
def evaluate_state(
    dt, pts, inv_var, sig, pol, pose, pivot, fit_rotation, tukey_c, r, w, jac, hess, grad,
    samples, sampled, staging,
):
    """State at ``pose``: residuals, IRLS weights and Jacobian into ``r, w, jac``,
    and ``H = A^T A``, ``g = A^T (sqrt(w) r)`` (``A = sqrt(w) J``) into
    ``hess, grad``.

    ``jac`` holds the Jacobian's columns as rows, ``(P, N)``. Rejected-polarity
    vertices get the penalty residual; their Jacobian entries are still the
    DT's (they carry zero weight). ``inv_var`` is ``1 / sigma^2``. With
    ``sampled``, ``samples`` and ``jac`` already hold the DT and the
    Jacobian at this pose, all finite (:func:`trial_cost` of the step that
    led here took them); else :func:`sample_state` takes them. Returns
    ``(status, cost, total_weight)``: status 1 if any weight is positive, 0
    if none is, -1 if a sample read a NaN or inf from ``dt`` (the caller
    refuses the DT: the image is too large to scan on every call, but no
    non-finite value reaches a result unnoticed).

    The sums are lane-wise: four partial sums over every fourth vertex,
    combined as ``(s0 + s1) + (s2 + s3)``, then the last ``n % 4`` vertices
    in order (:func:`trial_cost` sums its cost the same way, so a trial
    cost compares like with like). Every residual, weight and product is
    computed exactly as the one-by-one code computes it.
    """
    if not sampled and not sample_state(dt, pts, pose, pivot, fit_rotation, samples, jac,
                                        staging):
        return -1, 0.0, 0.0
    n = pts.shape[0]
    n4 = n - n % 4
    (positive, cost, total, g0, g1, g2, h00, h01, h02, h11, h12, h22) = lane_sums(
        samples, pol, jac, inv_var, sig, r, w, tukey_c, n4
    )
    status = 1 if positive else 0
    for i in range(n4, n):
        ri = samples[i] if pol[i] != 0.0 else PENALTY
        r[i] = ri
        wi = inv_var[i] * tukey(ri / sig[i], tukey_c) * pol[i]
        w[i] = wi
        cost += wi * ri * ri
        total += wi
        if wi > 0.0:
            status = 1
            sw = np.sqrt(wi)
            swr = sw * ri
            a0 = sw * jac[0, i]
            a1 = sw * jac[1, i]
            g0 += a0 * swr
            g1 += a1 * swr
            h00 += a0 * a0
            h01 += a0 * a1
            h11 += a1 * a1
            if fit_rotation:
                a2 = sw * jac[2, i]
                g2 += a2 * swr
                h02 += a0 * a2
                h12 += a1 * a2
                h22 += a2 * a2
    hess[0, 0] = h00
    hess[0, 1] = hess[1, 0] = h01
    hess[1, 1] = h11
    grad[0] = g0
    grad[1] = g1
    if fit_rotation:
        hess[0, 2] = hess[2, 0] = h02
        hess[1, 2] = hess[2, 1] = h12
        hess[2, 2] = h22
        grad[2] = g2
    return status, cost, total


@kernel
def trial_cost(dt, pts, pol, w, pose, pivot, fit_rotation, samples, jac, staging):
    """``sum(w * r * r)`` with residuals at ``pose`` and fixed weights ``w``,
    summed lane-wise as :func:`evaluate_state` sums its cost; and whether
    the state at ``pose`` is readable.

    Returns ``(cost, ok)``. The cost is non-finite when a residual's sample
    read a NaN or inf (``0 * inf`` is NaN too). The samples and the
    Jacobian at ``pose`` are taken too, into ``samples`` and ``jac``
    (:func:`sample_state`): most trial steps are accepted, and then
    :func:`evaluate_state` starts from them; taking all five samples of a
    vertex in one pass costs less than the one for the cost now and the
    four for the Jacobian after. ``ok`` is False if any of them read a NaN
    or inf (an error only if the step is accepted).
    """
    ok = sample_state(dt, pts, pose, pivot, fit_rotation, samples, jac, staging)
    n = pts.shape[0]
    n4 = n - n % 4
    total = lane_cost(pol, w, samples, n4)
    for i in range(n4, n):
        ri = samples[i] if pol[i] != 0.0 else PENALTY
        total += w[i] * ri * ri
    return total, ok


@kernel
def step_norm(step, pivot_distance):
    if step.shape[0] == 2:
        return np.hypot(step[0], step[1])
    return math.sqrt(step[0] ** 2 + step[1] ** 2 + (step[2] * pivot_distance) ** 2)


@kernel
def lm_loop(
    dt, pts, sig, pol, pose0, pivot, fit_rotation, pivot_distance, max_iterations,
    damping, step_tolerance, tukey_c, rcond, trust_region, tikhonov_alpha,
):
    """The fit of :ref:`contract-lm` step 2 (the state at the seed when no step is taken).

    ``trust_region < 0`` means no trust region. Returns the final pose
    ``(dv, du, theta)``, the iteration count, the converged flag, the
    state ``r, w, J`` at the final pose, its ``H = J^T W J`` (no Tikhonov
    term: the covariance's information matrix), and a status: :data:`LOOP_OK`,
    :data:`LOOP_BAD_DT` (the DT was found non-finite where the fit sampled
    it) or :data:`LOOP_DIVERGED` (a non-finite step: the normal equations
    overflowed); with a bad status the rest is invalid.

    After a rejected step the state, and so ``H``, ``g`` and the cost, are
    unchanged: they are kept rather than recomputed (same values exactly).
    """
    n = pts.shape[0]
    n_params = _n_params(fit_rotation)
    r = np.zeros(n)
    w = np.zeros(n)
    jac = np.zeros((n_params, n))  # the Jacobian's columns
    inv_var = np.empty(n)
    for i in range(n):
        inv_var[i] = 1.0 / (sig[i] * sig[i])
    pose = pose0.copy()
    trial = pose0.copy()
    dv0, du0 = pose0[0], pose0[1]
    lam = damping
    iterations = 0
    converged = False
    fresh = False  # r, w, jac, hess, grad, cost describe `pose`
    status = 0
    cost = 0.0
    t = 0.0
    hess = np.zeros((n_params, n_params))
    grad = np.zeros(n_params)
    damped = np.zeros((n_params, n_params))
    info = np.zeros((n_params, n_params))  # H of the state, without the Tikhonov term
    samples = np.zeros(n)
    sampled = False  # samples, jac hold the DT and Jacobian at `pose` (an accepted trial's)
    trial_samples = np.zeros(n)  # the same at `trial`, swapped in when it is accepted
    trial_jac = np.zeros((n_params, n))
    staging = staging_buffers()
    while iterations < max_iterations:
        if not fresh:
            status, cost, total_w = evaluate_state(
                dt, pts, inv_var, sig, pol, pose, pivot, fit_rotation, tukey_c, r, w, jac, hess,
                grad, samples, sampled, staging,
            )
            if status < 0:
                return pose, iterations, converged, r, w, jac, info, LOOP_BAD_DT
            info[:, :] = hess
            fresh = True
            if status == 0:
                break
            t = 0.0
            if tikhonov_alpha > 0:
                t = tikhonov_alpha * total_w
                hess[0, 0] += t
                hess[1, 1] += t
                grad[0] += t * (pose[0] - dv0)
                grad[1] += t * (pose[1] - du0)
                cost += t * ((pose[0] - dv0) ** 2 + (pose[1] - du0) ** 2)
        damped[:, :] = hess
        for a in range(n_params):
            damped[a, a] = hess[a, a] + lam * hess[a, a]
        step = solve_step(damped, grad, rcond)
        for a in range(n_params):
            if not math.isfinite(step[a]):
                return pose, iterations, converged, r, w, jac, info, LOOP_DIVERGED
        for a in range(3):
            trial[a] = pose[a]
        for a in range(n_params):
            trial[a] = pose[a] + step[a]
        if trust_region >= 0.0 and np.hypot(trial[0] - dv0, trial[1] - du0) > trust_region:
            lam = min(2 * lam, LAMBDA_MAX)
            iterations += 1
            if lam >= LAMBDA_MAX:
                break
            continue
        cost_t, readable = trial_cost(
            dt, pts, pol, w, trial, pivot, fit_rotation, trial_samples, trial_jac, staging
        )
        if not math.isfinite(cost_t):
            return pose, iterations, converged, r, w, jac, info, LOOP_BAD_DT
        if tikhonov_alpha > 0:
            cost_t += t * ((trial[0] - dv0) ** 2 + (trial[1] - du0) ** 2)
        if cost_t < cost:
            if not readable:  # the new state's Jacobian read a NaN or inf
                return pose, iterations, converged, r, w, jac, info, LOOP_BAD_DT
            samples, trial_samples = trial_samples, samples
            jac, trial_jac = trial_jac, jac
            for a in range(3):
                pose[a] = trial[a]
            lam = max(lam / 2, LAMBDA_MIN)
            iterations += 1
            fresh = False
            sampled = True
            if step_norm(step, pivot_distance) < step_tolerance:
                converged = True
                break
        else:
            lam = min(2 * lam, LAMBDA_MAX)
            iterations += 1
            if lam >= LAMBDA_MAX:
                break
    if not fresh:
        status = evaluate_state(
            dt, pts, inv_var, sig, pol, pose, pivot, fit_rotation, tukey_c, r, w, jac, info, grad,
            samples, sampled, staging,
        )[0]
    return pose, iterations, converged, r, w, jac, info, LOOP_BAD_DT if status < 0 else LOOP_OK
