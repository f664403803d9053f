"""Gradient-ridge polish of :ref:`contract-ridge`, compiled whole.

The magnitude comes either as a gradient-magnitude image or, from the LM
driver, as the gradient-vector image, whose magnitude is formed only in a
box around the polyline (see :func:`magnitude_patch` and
:func:`sample_magnitude`).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

from .._jit import kernel
from .lanes import EPS_R
from .lm import step_norm
from .params import n_params as _n_params
from .robust import irls_weight, normal_equations, solve_step
from .sampling import TILE, bilinear, fill_tiles, sample_magnitude, transform

#: Status of :func:`ridge_loop`.
RIDGE_OK = 0
RIDGE_BAD_FIELD = 1  # a profile sample read a NaN or inf
RIDGE_DIVERGED = 2  # a Gauss-Newton step overflowed

CURVATURE_EPS = 1.0e-12
PINVH_RCOND = 1.0e-9
#: Largest magnitude patch (pixels) built for a gradient-vector image;
#: beyond it the magnitude is formed at every sampled corner instead.
MAX_PATCH = 1 << 20
#: Margin of the patch beyond the profiles at the starting pose, px: room
#: for the polish to move (it is discarded beyond 1.5 px anyway).
PATCH_MARGIN = 8


class MagnitudeField(NamedTuple):
    """Where the polish reads the gradient magnitude (:func:`sample_magnitude`):
    a magnitude image (the public polish: empty patch and gradient), or the
    gradient-vector image with its patch (the LM driver: empty magnitude)."""

    magnitude: Any  #: (H, W) magnitude image, or (0, 0)
    patch: Any  #: the patch of :func:`magnitude_patch`, or (0, 0)
    tiles: Any  #: its filled-tile flags (uint8)
    grad: Any  #: (H, W, 2) gradient vectors, or (0, 0, 2)
    r0: int  #: the patch's first row and column in the image
    c0: int
    use_libm: bool  #: magnitudes through libm's ``hypot``


class RidgeSettings(NamedTuple):
    """The polish's iteration settings."""

    max_iterations: int
    step_tolerance: float
    tukey_c: float
    half: int  #: ``round(half_width / sample_step)`` (Python's rounding: the caller's)
    sample_step: float


@kernel
def magnitude_patch(grad, pts, dv, du, reach):
    """An unfilled magnitude patch over the box the profiles can reach.

    Returns ``(patch, tiles, r0, c0)``: the patch is filled tile by tile as
    samples need it (see :func:`sample_magnitude`). The LM driver polishes
    against the magnitude of its gradient-vector image; forming it only
    where the profiles go costs a fraction of the whole image's. A box over
    ``MAX_PATCH`` pixels is not built (empty patch: every sample falls back
    to per-pixel hypot).
    """
    h = grad.shape[0]
    w = grad.shape[1]
    r_lo, r_hi, c_lo, c_hi = h, -1, w, -1
    for i in range(pts.shape[0]):
        v = pts[i, 0] + dv
        u = pts[i, 1] + du
        r_lo = min(r_lo, int(math.floor(max(min(v - reach, h - 1.0), 0.0))))
        r_hi = max(r_hi, int(math.ceil(max(min(v + reach, h - 1.0), 0.0))))
        c_lo = min(c_lo, int(math.floor(max(min(u - reach, w - 1.0), 0.0))))
        c_hi = max(c_hi, int(math.ceil(max(min(u + reach, w - 1.0), 0.0))))
    rows = r_hi - r_lo + 1
    cols = c_hi - c_lo + 1
    if rows * cols > MAX_PATCH:
        rows = cols = 0
    tiles = np.zeros((rows // TILE + 1, cols // TILE + 1), dtype=np.uint8)
    return np.empty((rows, cols)), tiles, r_lo, c_lo


@kernel
def peak_offsets(field, pts, nrm, dv, du, theta, pivot, t, step, prof, out, valid, n_rot):
    """Sub-pixel signed distance ``t*`` to the magnitude peak along each normal.

    Writes ``t*`` into ``out``, 1.0/0.0 validity into ``valid`` and the
    normals rotated by ``theta`` into ``n_rot``; ``prof`` is scratch of
    length ``K``. The field (a :class:`MagnitudeField`) is sampled by
    :func:`sample_magnitude`. Returns False if a sample read a NaN or inf.
    """
    magnitude, patch, tiles, grad = field.magnitude, field.patch, field.tiles, field.grad
    r0, c0, use_libm = field.r0, field.c0, field.use_libm
    k_count = t.shape[0]
    cos_t, sin_t = math.cos(theta), math.sin(theta)
    for i in range(pts.shape[0]):
        if theta == 0.0:
            nv, nu = nrm[i, 0], nrm[i, 1]
        else:
            nv = cos_t * nrm[i, 0] - sin_t * nrm[i, 1]
            nu = sin_t * nrm[i, 0] + cos_t * nrm[i, 1]
        n_rot[i, 0] = nv
        n_rot[i, 1] = nu
        v, u = transform(pts[i, 0], pts[i, 1], dv, du, theta, cos_t, sin_t, pivot[0], pivot[1])
        # Rounding is monotonic, so every sample v + t[k] * nv lies between the
        # two ends': when their box is inside the patch, its tiles are filled
        # once and each sample is a plain bilinear read of the patch (what
        # sample_magnitude would return, without its per-sample tile test).
        va, vb = v + t[0] * nv, v + t[k_count - 1] * nv
        ua, ub = u + t[0] * nu, u + t[k_count - 1] * nu
        lo_v, hi_v = min(va, vb) - r0, max(va, vb) - r0
        lo_u, hi_u = min(ua, ub) - c0, max(ua, ub) - c0
        if (grad.shape[0] != 0 and 0.0 <= lo_v and hi_v < patch.shape[0] - 1
                and 0.0 <= lo_u and hi_u < patch.shape[1] - 1):
            fill_tiles(patch, tiles, grad, r0, c0, use_libm, int(lo_v), int(hi_v) + 1,
                       int(lo_u), int(hi_u) + 1)
            for k in range(k_count):
                prof[k] = bilinear(patch, (v + t[k] * nv) - r0, (u + t[k] * nu) - c0)
        else:
            for k in range(k_count):
                prof[k] = sample_magnitude(
                    magnitude, patch, tiles, grad, r0, c0, use_libm, v + t[k] * nv, u + t[k] * nu
                )
        k_star = 0
        for k in range(k_count):
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
def ridge_loop(field, pts, nrm, sig, weight_mask, pose0, pivot, fit_rotation, pivot_distance,
               settings):
    """Gauss-Newton on ``t*``; returns the final pose, iterations, converged
    and a status (:data:`RIDGE_OK`, :data:`RIDGE_BAD_FIELD`, :data:`RIDGE_DIVERGED`).

    ``field`` is a :class:`MagnitudeField`, ``settings`` a
    :class:`RidgeSettings`. Whether the result is applied (moved less than
    the displacement cap) is decided by the caller.

    Each iteration is a function of the pose alone, so a pose that comes
    back (bit for bit) means the loop cycles for ever; it is found with
    Brent's cycle detection (:func:`same_pose`, one saved pose) and the
    loop then runs only the ``(max_iterations - iterations) % period``
    iterations that select the pose the full count would end on: the same
    result, iterations (``max_iterations``) and ``converged`` (False) as
    the plain loop, in a number of iterations bounded by the cycle, not by
    ``max_iterations`` (:ref:`contract-ridge`).
    """
    max_iterations, step_tolerance = settings.max_iterations, settings.step_tolerance
    tukey_c, half, sample_step = settings.tukey_c, settings.half, settings.sample_step
    n = pts.shape[0]
    n_params = _n_params(fit_rotation)
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
    pose = pose0.copy()
    iterations = 0
    converged = False
    # Brent's cycle detection: the pose saved when `since` reached `power`
    # (doubling), compared with each new pose.
    saved = pose0.copy()
    power = 1
    since = 0
    cycling = False
    limit = max_iterations
    while iterations < limit:
        theta = pose[2]
        if not peak_offsets(field, pts, nrm, pose[0], pose[1], theta, pivot, t, sample_step,
                            prof, r, valid, n_rot):
            return pose, iterations, converged, RIDGE_BAD_FIELD
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
                                sample_step, prof, r_p, scratch_valid, scratch_n)
            ok_m = peak_offsets(field, pts, nrm, pose[0], pose[1], theta - EPS_R, pivot, t,
                                sample_step, prof, r_m, scratch_valid, scratch_n)
            if not (ok_p and ok_m):
                return pose, iterations, converged, RIDGE_BAD_FIELD
            for i in range(n):
                jac[i, 2] = (r_p[i] - r_m[i]) / (2 * EPS_R)
        hess, g_vec = normal_equations(jac, w, r, n_params)
        step = solve_step(hess, g_vec, PINVH_RCOND)
        for a in range(n_params):
            if not math.isfinite(step[a]):
                return pose, iterations, converged, RIDGE_DIVERGED
        for a in range(n_params):
            pose[a] = pose[a] + step[a]
        iterations += 1
        if step_norm(step, pivot_distance) < step_tolerance:
            converged = True
            break
        if not cycling:
            since += 1
            if same_pose(pose, saved):
                # `since` iterations lead from this pose back to itself.
                cycling = True
                limit = iterations + (max_iterations - iterations) % since
            elif since == power:
                saved[:] = pose
                power *= 2
                since = 0
    if cycling:
        iterations = max_iterations
    return pose, iterations, converged, RIDGE_OK


@kernel
def same_pose(a, b):
    """Whether two poses are the same bit for bit (a NaN never is; +0 is not -0)."""
    for i in range(a.shape[0]):
        if a[i] != b[i] or math.copysign(1.0, a[i]) != math.copysign(1.0, b[i]):
            return False
    return True
