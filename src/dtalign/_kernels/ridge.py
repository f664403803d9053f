"""Gradient-ridge polish of SPEC section 4, compiled whole.

The magnitude field is ``(H, W, C)``: ``C == 1`` is a gradient-magnitude
image, ``C == 2`` a gradient-vector image whose magnitude is formed only at
the pixels the profiles touch (see :func:`bilinear_magnitude`).
"""

from __future__ import annotations

import math

import numpy as np

from .._jit import kernel
from .lm import EPS_R, step_norm
from .robust import irls_weight, normal_equations, solve_step
from .sampling import bilinear_magnitude, new_magnitude_cache, transform

CURVATURE_EPS = 1.0e-12
PINVH_RCOND = 1.0e-9


@kernel
def peak_offsets(field, pts, nrm, dv, du, theta, pivot, t, step, prof, out, valid, n_rot, cache):  # pragma: no cover
    """Sub-pixel signed distance ``t*`` to the magnitude peak along each normal.

    Writes ``t*`` into ``out``, 1.0/0.0 validity into ``valid`` and the
    normals rotated by ``theta`` into ``n_rot``; ``prof`` is scratch of
    length ``K``; ``cache`` is :func:`new_magnitude_cache`'s pair. Returns
    False if a sample read a NaN or inf.
    """
    k_count = t.shape[0]
    c0, s0 = math.cos(theta), math.sin(theta)
    for i in range(pts.shape[0]):
        if theta == 0.0:
            nv, nu = nrm[i, 0], nrm[i, 1]
        else:
            nv = c0 * nrm[i, 0] - s0 * nrm[i, 1]
            nu = s0 * nrm[i, 0] + c0 * nrm[i, 1]
        n_rot[i, 0] = nv
        n_rot[i, 1] = nu
        v, u = transform(pts[i, 0], pts[i, 1], dv, du, theta, c0, s0, pivot[0], pivot[1])
        k_star = 0
        for k in range(k_count):
            prof[k] = bilinear_magnitude(field, v + t[k] * nv, u + t[k] * nu, cache[0], cache[1])
            if not math.isfinite(prof[k]):
                return False
            if prof[k] > prof[k_star]:
                k_star = k
        valid[i] = 1.0 if 0 < k_star < k_count - 1 else 0.0
        kc = min(max(k_star, 1), k_count - 2)
        y_minus = prof[kc - 1]
        y0 = prof[kc]
        y_plus = prof[kc + 1]
        d = y_minus - 2 * y0 + y_plus
        delta = 0.5 * (y_minus - y_plus) / d if d < -CURVATURE_EPS else 0.0
        delta = min(max(delta, -0.5), 0.5)
        out[i] = t[kc] + delta * step
    return True


@kernel
def ridge_loop(
    field, pts, nrm, sig, weight_mask, pose0, pivot, fit_rotation, pivot_distance,
    max_iterations, step_tolerance, tukey_c, half, sample_step,
):  # pragma: no cover - compiled
    """Gauss-Newton on ``t*``; returns the final pose, iterations, converged
    and ``bad`` (True if the field was found non-finite where sampled).

    ``half`` is ``round(half_width / sample_step)`` (Python's rounding, so
    computed by the caller). Whether the result is applied (moved less
    than the displacement cap) is decided by the caller too.
    """
    n = pts.shape[0]
    n_params = 3 if fit_rotation else 2
    t = np.empty(2 * half + 1)
    for k in range(t.shape[0]):
        t[k] = (k - half) * sample_step
    prof = np.empty(t.shape[0])
    r = np.empty(n)
    valid = np.empty(n)
    n_rot = np.empty((n, 2))
    w = np.empty(n)
    jac = np.empty((n, n_params))
    r_p = np.empty(n)
    r_m = np.empty(n)
    scratch_valid = np.empty(n)
    scratch_n = np.empty((n, 2))
    cache = new_magnitude_cache()
    pose = pose0.copy()
    iterations = 0
    converged = False
    for _ in range(max_iterations):
        theta = pose[2]
        if not peak_offsets(field, pts, nrm, pose[0], pose[1], theta, pivot, t, sample_step,
                            prof, r, valid, n_rot, cache):
            return pose, iterations, converged, True
        any_positive = False
        for i in range(n):
            w[i] = irls_weight(r[i], sig[i], tukey_c, valid[i]) * weight_mask[i]
            if w[i] > 0.0:
                any_positive = True
            jac[i, 0] = -n_rot[i, 0]
            jac[i, 1] = -n_rot[i, 1]
        if not any_positive:
            break
        if fit_rotation:
            ok_p = peak_offsets(field, pts, nrm, pose[0], pose[1], theta + EPS_R, pivot, t,
                                sample_step, prof, r_p, scratch_valid, scratch_n, cache)
            ok_m = peak_offsets(field, pts, nrm, pose[0], pose[1], theta - EPS_R, pivot, t,
                                sample_step, prof, r_m, scratch_valid, scratch_n, cache)
            if not (ok_p and ok_m):
                return pose, iterations, converged, True
            for i in range(n):
                jac[i, 2] = (r_p[i] - r_m[i]) / (2 * EPS_R)
        hess, grad = normal_equations(jac, w, r, n_params)
        step = solve_step(hess, grad, PINVH_RCOND)
        for a in range(n_params):
            pose[a] = pose[a] + step[a]
        iterations += 1
        if step_norm(step, pivot_distance) < step_tolerance:
            converged = True
            break
    return pose, iterations, converged, False
