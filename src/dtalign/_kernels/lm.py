"""The Levenberg-Marquardt / Tukey IRLS loop of SPEC section 3, compiled whole.

A pure-NumPy iteration spends most of its time in interpreter overhead on
arrays of a few hundred vertices; compiling the whole loop removes that.
A trial step costs one pass over the vertices for its cost (keeping the
DT samples), and a 2x2 or 3x3 solve; an accepted step then costs the
Jacobian's samples, the weights and the normal equations (no N x 5
temporaries). The state arrays are allocated once per fit and overwritten.
"""

from __future__ import annotations

import math

import numpy as np

from .._jit import kernel
from .robust import solve_step, tukey
from .sampling import bilinear, transform

#: Mirrors of the constants in dtalign._constants, as compile-time literals.
PENALTY = 1.0e6
EPS_T = 0.25
EPS_R = 1.0e-3
LAMBDA_MIN = 1.0e-12
LAMBDA_MAX = 1.0e6

#: Status of :func:`lm_loop`.
LOOP_OK = 0
LOOP_BAD_DT = 1  # a sample read a NaN or inf from the DT
LOOP_DIVERGED = 2  # the normal equations or a step overflowed


@kernel
def evaluate_state(
    dt, pts, inv_var, sig, pol, pose, pivot, fit_rotation, tukey_c, r, w, jac, hess, grad, sw,
    samples, sampled,
):  # pragma: no cover - compiled
    """State at ``pose``: residuals, IRLS weights and Jacobian into ``r, w, jac``,
    and ``H = A^T A``, ``g = A^T (sqrt(w) r)`` (``A = sqrt(w) J``) into
    ``hess, grad``.

    Rejected-polarity vertices get the penalty residual; their Jacobian row
    is still the DT's (it carries zero weight). ``inv_var`` is
    ``1 / sigma^2``; ``sw`` is scratch for ``sqrt(w)``. With ``sampled``,
    ``samples`` already holds the DT at every vertex at this pose (the trial
    cost of the step that led here sampled it: :func:`weighted_cost`).
    Returns ``(status, cost, total_weight)``: status 1 if any weight is
    positive, 0 if none is, -1 if a sample read a NaN or inf from ``dt``
    (the caller refuses the DT: the image is too large to scan on every
    call, but no non-finite value reaches a result unnoticed).

    Three passes: the samples; the weights, branch-free so that LLVM
    vectorises their two divisions and square root (a third of the time
    when computed vertex by vertex); the sums, over the vertices in order
    as SPEC's formulas read. Every value is computed exactly as in one pass.
    """
    dv, du, theta = pose[0], pose[1], pose[2]
    pv, pu = pivot[0], pivot[1]
    c0, s0 = math.cos(theta), math.sin(theta)
    tp, tm = theta + EPS_R, theta - EPS_R
    cp, sp = math.cos(tp), math.sin(tp)
    cm, sm = math.cos(tm), math.sin(tm)
    two_eps_t = 2 * EPS_T
    two_eps_r = 2 * EPS_R
    n = pts.shape[0]
    for i in range(n):
        v, u = transform(pts[i, 0], pts[i, 1], dv, du, theta, c0, s0, pv, pu)
        sample = samples[i] if sampled else bilinear(dt, v, u)
        j0 = (bilinear(dt, v + EPS_T, u) - bilinear(dt, v - EPS_T, u)) / two_eps_t
        j1 = (bilinear(dt, v, u + EPS_T) - bilinear(dt, v, u - EPS_T)) / two_eps_t
        # inf - inf and nan propagate, so one test covers all five samples
        if not math.isfinite(sample + j0 + j1):
            return -1, 0.0, 0.0
        jac[i, 0] = j0
        jac[i, 1] = j1
        if fit_rotation:
            vp, up = transform(pts[i, 0], pts[i, 1], dv, du, tp, cp, sp, pv, pu)
            vm, um = transform(pts[i, 0], pts[i, 1], dv, du, tm, cm, sm, pv, pu)
            j2 = (bilinear(dt, vp, up) - bilinear(dt, vm, um)) / two_eps_r
            if not math.isfinite(j2):
                return -1, 0.0, 0.0
            jac[i, 2] = j2
        r[i] = sample if pol[i] != 0.0 else PENALTY
    for i in range(n):
        wi = inv_var[i] * tukey(r[i] / sig[i], tukey_c) * pol[i]
        w[i] = wi
        sw[i] = np.sqrt(wi)
    status = 0
    cost = 0.0
    total = 0.0
    # scalar accumulators (kept in registers) for H and g, P = 2 or 3
    h00 = h01 = h02 = h11 = h12 = h22 = 0.0
    g0 = g1 = g2 = 0.0
    for i in range(n):
        ri = r[i]
        wi = w[i]
        cost += wi * ri * ri
        total += wi
        if wi > 0.0:
            status = 1
            swr = sw[i] * ri
            a0 = sw[i] * jac[i, 0]
            a1 = sw[i] * jac[i, 1]
            g0 += a0 * swr
            g1 += a1 * swr
            h00 += a0 * a0
            h01 += a0 * a1
            h11 += a1 * a1
            if fit_rotation:
                a2 = sw[i] * jac[i, 2]
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
def weighted_cost(dt, pts, pol, w, pose, pivot, samples):  # pragma: no cover - compiled
    """``sum(w * r * r)`` with residuals at ``pose`` and fixed weights ``w``.

    Non-finite when a sample read a NaN or inf (``0 * inf`` is NaN too).
    The DT at every vertex (rejected-polarity ones included) is kept in
    ``samples``: if the step is accepted, :func:`evaluate_state` at this
    pose starts from them.
    """
    dv, du, theta = pose[0], pose[1], pose[2]
    c0, s0 = math.cos(theta), math.sin(theta)
    total = 0.0
    for i in range(pts.shape[0]):
        v, u = transform(pts[i, 0], pts[i, 1], dv, du, theta, c0, s0, pivot[0], pivot[1])
        sample = bilinear(dt, v, u)
        samples[i] = sample
        ri = sample if pol[i] != 0.0 else PENALTY
        total += w[i] * ri * ri
    return total


@kernel
def step_norm(step, pivot_distance):  # pragma: no cover - compiled
    if step.shape[0] == 2:
        return math.hypot(step[0], step[1])
    return math.sqrt(step[0] ** 2 + step[1] ** 2 + (step[2] * pivot_distance) ** 2)


@kernel
def lm_loop(
    dt, pts, sig, pol, pose0, pivot, fit_rotation, pivot_distance, max_iterations,
    damping, step_tolerance, tukey_c, rcond, trust_region, tikhonov_alpha,
):  # pragma: no cover - compiled
    """The fit of SPEC section 3 steps 2-3.

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
    n_params = 3 if fit_rotation else 2
    r = np.zeros(n)
    w = np.zeros(n)
    jac = np.zeros((n, n_params))
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
    sw = np.zeros(n)
    samples = np.zeros(n)
    sampled = False  # samples holds the DT at `pose` (set by the accepted trial)
    while iterations < max_iterations:
        if not fresh:
            status, cost, total_w = evaluate_state(
                dt, pts, inv_var, sig, pol, pose, pivot, fit_rotation, tukey_c, r, w, jac, hess,
                grad, sw, samples, sampled,
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
        if trust_region >= 0.0 and math.hypot(trial[0] - dv0, trial[1] - du0) > trust_region:
            lam = min(2 * lam, LAMBDA_MAX)
            iterations += 1
            if lam >= LAMBDA_MAX:
                break
            continue
        trial_cost = weighted_cost(dt, pts, pol, w, trial, pivot, samples)
        if not math.isfinite(trial_cost):
            return pose, iterations, converged, r, w, jac, info, LOOP_BAD_DT
        if tikhonov_alpha > 0:
            trial_cost += t * ((trial[0] - dv0) ** 2 + (trial[1] - du0) ** 2)
        if trial_cost < cost:
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
            sw, samples, sampled,
        )[0]
    return pose, iterations, converged, r, w, jac, info, LOOP_BAD_DT if status < 0 else LOOP_OK
