"""Tukey biweight, IRLS weights, polarity test and the normal equations."""

from __future__ import annotations

import math

import numpy as np

from .._jit import kernel


@kernel
def tukey(x, c):  # pragma: no cover - compiled
    """Biweight of one scaled residual: ``(1 - s^2)^2`` for ``|s| <= 1``."""
    s = x / c
    if abs(s) <= 1.0:
        t = 1.0 - s * s
        return t * t
    return 0.0


@kernel
def tukey_many(r, c):  # pragma: no cover - compiled
    out = np.empty(r.shape[0])
    for i in range(r.shape[0]):
        out[i] = tukey(r[i], c)
    return out


@kernel
def irls_weight(r, sigma, c, accepted):  # pragma: no cover - compiled
    """``(1 / sigma^2) * tukey(r / sigma) * polarity`` in the reference's order."""
    return (1.0 / (sigma * sigma)) * tukey(r / sigma, c) * accepted


@kernel
def polarity(pts, nrm, grad, dv, du):  # pragma: no cover - compiled
    """1.0 where the normal points up the gradient at the shifted pixel, else 0.0.

    Also returns True if a gradient value it read was NaN or inf.
    """
    h = grad.shape[0]
    w = grad.shape[1]
    out = np.zeros(pts.shape[0])
    for i in range(pts.shape[0]):
        iv = np.rint(pts[i, 0] + dv)
        iu = np.rint(pts[i, 1] + du)
        if iv >= 0 and iv < h and iu >= 0 and iu < w:
            gv = grad[int(iv), int(iu), 0]
            gu = grad[int(iv), int(iu), 1]
            if not (math.isfinite(gv) and math.isfinite(gu)):
                return out, True
            if nrm[i, 0] * gv + nrm[i, 1] * gu > 0.0:
                out[i] = 1.0
    return out, False


@kernel
def normal_equations(jac, w, r, n_params):  # pragma: no cover - compiled
    """``H = A^T A`` and ``g = A^T (sqrt(w) r)`` with ``A = sqrt(w) J``.

    Accumulated row by row (sequential sums) over the first ``n_params``
    columns; no N x P temporary is formed.
    """
    hess = np.zeros((n_params, n_params))
    grad = np.zeros(n_params)
    for i in range(jac.shape[0]):
        if w[i] == 0.0:
            continue  # contributes exact zeros
        sw = np.sqrt(w[i])
        swr = sw * r[i]
        for a in range(n_params):
            aa = sw * jac[i, a]
            grad[a] += aa * swr
            for b in range(a, n_params):
                hess[a, b] += aa * (sw * jac[i, b])
    for a in range(n_params):
        for b in range(a):
            hess[a, b] = hess[b, a]
    return hess, grad


@kernel
def solve_step(matrix, rhs, rcond):  # pragma: no cover - compiled
    """``-solve(matrix, rhs)``; the symmetric pseudoinverse when singular.

    The pseudoinverse follows ``scipy.linalg.pinvh``: eigenvalues with
    ``|s| <= max|s| * rcond`` are dropped.
    """
    n = matrix.shape[0]
    singular = False
    try:
        step = -np.linalg.solve(matrix, rhs)
    except Exception:
        singular = True
        step = np.zeros(n)
    if not singular:
        return step
    vals, vecs = np.linalg.eigh(matrix)
    cutoff = 0.0
    for k in range(n):
        cutoff = max(cutoff, abs(vals[k]))
    cutoff *= rcond
    out = np.zeros(n)
    for k in range(n):
        if abs(vals[k]) > cutoff:
            proj = 0.0
            for j in range(n):
                proj += vecs[j, k] * rhs[j]
            scale = proj / vals[k]
            for j in range(n):
                out[j] -= vecs[j, k] * scale
    return out
