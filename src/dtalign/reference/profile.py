"""The NumPy specification of the edge-profile refinement kernels.

Same names and arguments as ``dtalign._kernels.profile`` (whose module
docstring states the model), written with array operations: the compiled
kernels are held against these to 1e-9 by ``tests/test_profiles.py``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy.special import erf

from .._kernels.profile import (
    COARSEN_SIGMAS,
    MAX_HALVINGS,
    MAX_WING_FRACTION,
    MAX_WING_SIGMA_PX,
    MIN_BOX_WIDTH,
    MIN_WING_RATIO,
    MIN_WING_SIGMA_PX,
    SCALE_FLOOR,
    SCALE_ITERATIONS,
    TAPS_SIGMAS,
)

FloatArray = np.ndarray


def hat_gauss_taps(sigma: float, h: float) -> FloatArray:
    """``(hat_h * G_sigma)(m h)`` from the Gaussian's second antiderivative."""
    if sigma <= 0.0:
        return np.ones(1)
    half = int(math.ceil(TAPS_SIGMAS * sigma / h)) + 1
    m = np.arange(-half, half + 1, dtype=np.float64)

    def f2(x: FloatArray) -> FloatArray:
        return x * 0.5 * (1.0 + erf(x / (sigma * math.sqrt(2.0)))) + sigma / math.sqrt(
            2.0 * math.pi) * np.exp(-(x / (sigma * math.sqrt(2.0))) ** 2)

    return np.asarray((f2((m - 1) * h) - 2.0 * f2(m * h) + f2((m + 1) * h)) / h)


def _blur(values: FloatArray, j0: int, nb: int, sigma: float, h: float) -> FloatArray:
    taps = hat_gauss_taps(sigma, h)
    half = (taps.shape[0] - 1) // 2
    cols = j0 + np.arange(nb)[:, None] + half - np.arange(taps.shape[0])[None, :]
    cols = np.clip(cols, 0, values.shape[1] - 1)
    return np.asarray((values[:, cols] * taps[None, None, :]).sum(axis=2))


def tables(values: FloatArray, o0: float, h: float, j0: int, nb: int, sigma: float
           ) -> tuple[FloatArray, FloatArray, FloatArray, float, float]:
    f = max(1, int(sigma / (COARSEN_SIGMAS * h))) if sigma > 0.0 else 1
    if f == 1:
        b, t0, ht = _blur(values, j0, nb, sigma, h), o0 + j0 * h, h
    else:
        mc = values.shape[1] // f
        coarse = values[:, : mc * f].reshape(values.shape[0], mc, f).mean(axis=2)
        ht = f * h
        jc0, jc1 = j0 // f, min(mc - 1, (j0 + nb - 1) // f + 1)
        s2 = sigma * sigma - 0.25 * (ht * ht - h * h)
        b = _blur(coarse, jc0, jc1 - jc0 + 1, math.sqrt(max(s2, 0.0)), ht)
        t0 = o0 + 0.5 * (f - 1) * h + jc0 * ht
    slope = np.diff(b, axis=1)
    c = np.concatenate([np.zeros((b.shape[0], 1)),
                        np.cumsum(ht * (b[:, :-1] + b[:, 1:]) * 0.5, axis=1)], axis=1)
    inc = c[:, :-1] * ht + b[:, :-1] * ht * ht * 0.5 + slope * ht * ht / 6.0
    d = np.concatenate([np.zeros((b.shape[0], 1)), np.cumsum(inc, axis=1)], axis=1)
    return b, c, d, t0, ht


def _antiderivs(b: FloatArray, c: FloatArray, d: FloatArray, k: FloatArray, x: FloatArray,
                h: float) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    nb = b.shape[1]
    end = (nb - 1) * h
    i = np.clip((np.clip(x, 0.0, end) / h).astype(np.int64), 0, nb - 2)
    t = x - i * h
    b0, b1 = b[k, i], b[k, i + 1]
    slope = (b1 - b0) / h
    bv = b0 + slope * t
    cv = c[k, i] + b0 * t + slope * t * t * 0.5
    dv = d[k, i] + c[k, i] * t + b0 * t * t * 0.5 + slope * t ** 3 / 6.0
    lo, hi = x <= 0.0, x >= end
    v0, te = b[k, 0], x - end
    vn = b[k, nb - 1]
    dv = np.where(lo, v0 * x * x * 0.5,
                  np.where(hi, d[k, nb - 1] + c[k, nb - 1] * te + vn * te * te * 0.5, dv))
    cv = np.where(lo, v0 * x, np.where(hi, c[k, nb - 1] + vn * te, cv))
    bv = np.where(lo, v0, np.where(hi, vn, bv))
    slope = np.where(lo | hi, 0.0, slope)
    return dv, cv, bv, slope


def _box_model(b: FloatArray, c: FloatArray, d: FloatArray, k: FloatArray, x: FloatArray,
               h: float, wa: FloatArray, wb: FloatArray) -> tuple[FloatArray, ...]:
    wa, wb = np.maximum(wa, MIN_BOX_WIDTH), np.maximum(wb, MIN_BOX_WIDTH)
    c1, c2 = 0.5 * (wa + wb), 0.5 * (wa - wb)
    p1 = _antiderivs(b, c, d, k, x + c1, h)
    p2 = _antiderivs(b, c, d, k, x + c2, h)
    p3 = _antiderivs(b, c, d, k, x - c2, h)
    p4 = _antiderivs(b, c, d, k, x - c1, h)
    return tuple((p1[i] - p2[i] - p3[i] + p4[i]) / (wa * wb) for i in range(3))


def select_pixels(shape_h: int, shape_w: int, verts: FloatArray, normals: FloatArray,
                  tau_max: FloatArray, half_width: float
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    kk, ii, jj = [], [], []
    for k in range(verts.shape[0]):
        r = math.sqrt(half_width**2 + tau_max[k] ** 2) + 1.0
        i0, i1 = max(0, math.floor(verts[k, 0] - r)), min(shape_h - 1, math.ceil(verts[k, 0] + r))
        j0, j1 = max(0, math.floor(verts[k, 1] - r)), min(shape_w - 1, math.ceil(verts[k, 1] + r))
        gi, gj = np.meshgrid(np.arange(i0, i1 + 1), np.arange(j0, j1 + 1), indexing="ij")
        dv, du = gi - verts[k, 0], gj - verts[k, 1]
        s = dv * normals[k, 0] + du * normals[k, 1]
        t = -dv * normals[k, 1] + du * normals[k, 0]
        keep = (np.abs(s) <= half_width) & (np.abs(t) <= tau_max[k])
        kk.append(np.full(int(keep.sum()), k))
        ii.append(gi[keep])
        jj.append(gj[keep])
    return (np.concatenate(kk).astype(np.int64), np.concatenate(ii).astype(np.int64),
            np.concatenate(jj).astype(np.int64))


def _component(b: FloatArray, c: FloatArray, d: FloatArray, bs: FloatArray, cs: FloatArray,
               ds: FloatArray, use_shape: bool, k: np.ndarray, s: FloatArray, tau: FloatArray,
               kap: FloatArray, sigma: float, t0: float, h: float, wa: FloatArray,
               wb: FloatArray, amp: float) -> tuple[FloatArray, ...]:
    s_eff = s - 0.5 * kap * (tau * tau + (sigma * sigma + 1.0 / 12.0))
    m0, m1, m2 = _box_model(b, c, d, k, s_eff - t0, h, wa, wb)
    a0 = np.zeros_like(m0)
    if use_shape:
        a0, a1, a2 = _box_model(bs, cs, ds, k, s_eff - t0, h, wa, wb)
        m0, m1, m2 = m0 + amp * a0, m1 + amp * a1, m2 + amp * a2
    return m0, m1, sigma * m2 - kap * sigma * m1, a0


def evaluate(obs: FloatArray, pix_k: np.ndarray, pix_v: FloatArray, pix_u: FloatArray,
             verts: FloatArray, normals: FloatArray, curv: FloatArray, b: FloatArray,
             c: FloatArray, d: FloatArray, bs: FloatArray, cs: FloatArray, ds: FloatArray,
             use_shape: bool, t0: float, h: float, bw: FloatArray, cw: FloatArray,
             dw: FloatArray, bws: FloatArray, cws: FloatArray, dws: FloatArray, use_wings: bool,
             tw0: float, hw: float, params: FloatArray) -> tuple[FloatArray, FloatArray]:
    dv0, du0, gain, bg, sigma, amp, slope, frac, sigma_w = params
    nv, nu = normals[pix_k, 0], normals[pix_k, 1]
    ev = pix_v - verts[pix_k, 0] - dv0
    eu = pix_u - verts[pix_k, 1] - du0
    s = ev * nv + eu * nu
    tau = -ev * nu + eu * nv
    kap = curv[pix_k]
    wa, wb = np.abs(nv), np.abs(nu)
    m0, m1, ms, a0 = _component(b, c, d, bs, cs, ds, use_shape, pix_k, s, tau, kap, sigma, t0,
                                h, wa, wb, amp)
    jf = np.zeros_like(m0)
    jw = np.zeros_like(m0)
    if use_wings:
        w0, w1, ws, aw = _component(bw, cw, dw, bws, cws, dws, use_shape, pix_k, s, tau, kap,
                                    sigma_w, tw0, hw, wa, wb, amp)
        jf, jw = gain * (w0 - m0), gain * frac * ws
        m0 = (1.0 - frac) * m0 + frac * w0
        m1 = (1.0 - frac) * m1 + frac * w1
        ms = (1.0 - frac) * ms
        a0 = (1.0 - frac) * a0 + frac * aw
    r = obs - (bg + slope * s + gain * m0)
    cols = [gain * m1 * (-nv - kap * tau * nu) - slope * nv,
            gain * m1 * (-nu + kap * tau * nv) - slope * nu, m0, np.ones_like(m0),
            gain * ms, gain * a0, s, jf, jw]
    return r, np.stack(cols, axis=1)


def wing_mixed(rows: FloatArray, o0: float, h: float, frac: float, sigma_extra: float,
               shift: FloatArray) -> FloatArray:
    m = rows.shape[1]
    b, _, _, t0, ht = tables(rows, o0, h, 0, m, sigma_extra)
    nb = b.shape[1]
    if nb == 1:
        wing = np.repeat(b[:, :1], m, axis=1)
    else:
        pos = np.clip((o0 + h * np.arange(m)[None, :] - shift[:, None] - t0) / ht, 0.0, nb - 1.0)
        i = np.minimum(pos.astype(np.int64), nb - 2)
        t = pos - i
        wing = (np.take_along_axis(b, i, axis=1) * (1.0 - t)
                + np.take_along_axis(b, i + 1, axis=1) * t)
    return np.asarray((1.0 - frac) * rows + frac * wing)


def all_tables(values: FloatArray, shape: FloatArray, o0: float, h: float, j0: int, nb: int,
               sigma: float) -> tuple[Any, ...]:
    t = tables(values, o0, h, j0, nb, sigma)
    u = tables(shape, o0, h, j0, nb, sigma) if shape.shape[1] > 0 else t
    return (t[0], t[1], t[2], u[0], u[1], u[2], t[3], t[4])


def _rho(x: FloatArray) -> FloatArray:
    return np.where(np.abs(x) >= 1.0, 1.0 / 6.0, (1.0 - (1.0 - x * x) ** 3) / 6.0)


def refine(obs: FloatArray, pix_k: np.ndarray, pix_v: FloatArray, pix_u: FloatArray,
           verts: FloatArray, normals: FloatArray, curv: FloatArray, values: FloatArray,
           shape: FloatArray, o0: float, h: float, j0: int, nb: int, params0: FloatArray,
           active: np.ndarray, use_wings: bool, max_iterations: int, tolerance_px: float,
           tukey_c: float) -> tuple[FloatArray, int, bool, FloatArray, float, float]:
    use_shape = shape.shape[1] > 0
    params = params0.copy()
    tab = all_tables(values, shape, o0, h, j0, nb, params[4])
    wtab = all_tables(values, shape, o0, h, j0, nb, params[8]) if use_wings else tab

    def residuals(p: FloatArray, t: tuple[Any, ...], w: tuple[Any, ...]
                  ) -> tuple[FloatArray, FloatArray]:
        return evaluate(obs, pix_k, pix_v, pix_u, verts, normals, curv, t[0], t[1], t[2], t[3],
                        t[4], t[5], use_shape, t[6], t[7], w[0], w[1], w[2], w[3], w[4], w[5],
                        use_wings, w[6], w[7], p)

    r, jac = residuals(params, tab, wtab)
    converged, iterations, scale, cost = False, 0, 0.0, 0.0
    n_act = active.shape[0]
    info = np.zeros((n_act, n_act))
    for it in range(max_iterations):
        iterations = it + 1
        if it < SCALE_ITERATIONS:
            scale = max(1.4826 * float(np.median(np.abs(r))),
                        SCALE_FLOOR * max(abs(params[2]), 1e-300))
        cut = tukey_c * scale
        cost = float(_rho(r / cut).sum())
        x = r / cut
        w = np.where(np.abs(x) >= 1.0, 0.0, (1.0 - x * x) ** 2)
        ja = jac[:, active]
        info = (ja * w[:, None]).T @ ja
        grad = (ja * w[:, None]).T @ r
        free = (active == 8) & (np.diag(info) == 0.0)
        info[free, free] = 1.0
        try:
            step = np.linalg.solve(info, grad)
            if use_wings:
                least = max(MIN_WING_RATIO * params[4], MIN_WING_SIGMA_PX)
                f = params[7]
                out = (((active == 7) & (((f <= 0.0) & (step < 0.0))
                                         | ((f >= MAX_WING_FRACTION) & (step > 0.0))))
                       | ((active == 8) & (((params[8] <= least) & (step < 0.0))
                                          | ((params[8] >= MAX_WING_SIGMA_PX) & (step > 0.0)))))
                if out.any():
                    info[out, :] = 0.0
                    info[:, out] = 0.0
                    info[out, out] = 1.0
                    grad[out] = 0.0
                    step = np.linalg.solve(info, grad)
        except np.linalg.LinAlgError:
            break
        if not np.isfinite(step).all():
            break
        full = float(np.abs(step[np.isin(active, (0, 1, 4))]).max())
        accepted = False
        for _ in range(MAX_HALVINGS):
            trial = params.copy()
            trial[active] += step
            trial[4] = max(trial[4], 0.0)
            if use_wings:
                trial[7] = min(max(trial[7], 0.0), MAX_WING_FRACTION)
                trial[8] = min(max(trial[8], MIN_WING_RATIO * trial[4], MIN_WING_SIGMA_PX),
                               MAX_WING_SIGMA_PX)
            tt = all_tables(values, shape, o0, h, j0, nb, trial[4]) if trial[4] != params[4] else tab
            wt = (all_tables(values, shape, o0, h, j0, nb, trial[8])
                  if use_wings and trial[8] != params[8] else wtab)
            rt, jt = residuals(trial, tt, wt)
            if float(_rho(rt / cut).sum()) <= cost:
                params, tab, wtab, r, jac = trial, tt, wt, rt, jt
                accepted = True
                converged = full < tolerance_px
                break
            step = step * 0.5
        if not accepted:
            converged = max(abs(step[0]), abs(step[1])) < tolerance_px
            break
        if converged:
            break
    try:
        inv = np.linalg.inv(info)
    except np.linalg.LinAlgError:
        inv = np.full((n_act, n_act), np.inf)
    if not np.isfinite(inv).all():
        inv = np.full((n_act, n_act), np.inf)
    return params, iterations, converged, inv, scale, cost
