"""Tukey biweight, IRLS weights, polarity test and the normal equations."""

from __future__ import annotations

import math

import numpy as np

from .._jit import inline_kernel, kernel


@inline_kernel
def tukey(x, c):
    """Biweight of one scaled residual: ``(1 - s^2)^2`` for ``|s| <= 1``, else 0.

    A select rather than a branch (``t * t`` is formed either way and
    dropped outside), so that loops over many residuals vectorise.
    """
    s = x / c
    t = 1.0 - s * s
    return t * t if abs(s) <= 1.0 else 0.0


@kernel
def tukey_many(r, c):
    out = np.empty(r.shape[0])
    for i in range(r.shape[0]):
        out[i] = tukey(r[i], c)
    return out


@kernel
def irls_weight(r, sigma, c, accepted):
    """``(1 / sigma^2) * tukey(r / sigma) * polarity`` in the reference's order."""
    return (1.0 / (sigma * sigma)) * tukey(r / sigma, c) * accepted


@inline_kernel
def _polarity_at(pts, nrm, grad, i, dv, du):
    """Vertex ``i``'s polarity flag (1.0 or 0.0), and whether the gradient
    vector it read is not finite."""
    iv = np.rint(pts[i, 0] + dv)
    iu = np.rint(pts[i, 1] + du)
    if iv >= 0 and iv < grad.shape[0] and iu >= 0 and iu < grad.shape[1]:
        gv = grad[int(iv), int(iu), 0]
        gu = grad[int(iv), int(iu), 1]
        if not (math.isfinite(gv) and math.isfinite(gu)):
            return 0.0, True
        if nrm[i, 0] * gv + nrm[i, 1] * gu > 0.0:
            return 1.0, False
    return 0.0, False


@kernel
def polarity(pts, nrm, grad, dv, du):
    """1.0 where the normal points up the gradient at the shifted pixel, else 0.0.

    Also returns True if a gradient value it read was NaN or inf (the flags
    are then incomplete). Vertex by vertex: the plain twin of
    :func:`dtalign._kernels.lanes.vector.polarity`.
    """
    out = np.zeros(pts.shape[0])
    for i in range(pts.shape[0]):
        out[i], bad = _polarity_at(pts, nrm, grad, i, dv, du)
        if bad:
            return out, True
    return out, False


@kernel
def normal_equations(jac, w, r, n_params):
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
def pinvh(matrix, rcond):
    """Symmetric pseudoinverse, following ``scipy.linalg.pinvh(a, rtol=rcond)``.

    Eigenvalues with ``|s| <= rcond * max|s|`` are dropped and the result is
    ``(u * (1/s)) @ u.T`` summed in the same order. Compiled because SciPy's
    call overhead on a 2x2 matrix is a large share of a whole compiled LM
    fit; the eigensolver here is LAPACK's too (``syevd`` rather than SciPy's
    ``syevr``), so the two agree to rounding (tested to 1e-12 relative).
    """
    n = matrix.shape[0]
    vals, vecs = np.linalg.eigh(matrix)
    top = 0.0
    for k in range(n):
        top = max(top, abs(vals[k]))
    cutoff = top * rcond
    out = np.zeros((n, n))
    for k in range(n):
        if abs(vals[k]) > cutoff:
            inv = 1.0 / vals[k]
            for i in range(n):
                scaled = vecs[i, k] * inv
                for j in range(n):
                    out[i, j] += scaled * vecs[j, k]
    return out


@kernel
def symmetric_pinvh(matrix, rcond):
    """``0.5 * (P + P^T)`` with ``P = pinvh(matrix, rcond)``: the covariance map.

    Returns ``(covariance, ok)``; ``ok`` is False (and the covariance all
    ``inf``) when the matrix overflowed to a non-finite value, which the
    eigensolver would refuse.
    """
    n = matrix.shape[0]
    for a in range(n):
        for b in range(n):
            if not math.isfinite(matrix[a, b]):
                return np.full((n, n), np.inf), False
    p = pinvh(matrix, rcond)
    return 0.5 * (p + p.T), True


@kernel
def solve_step(matrix, rhs, rcond):
    """``-solve(matrix, rhs)``; ``-pinvh(matrix) @ rhs`` when singular.

    Gaussian elimination with partial pivoting (first largest pivot and
    reciprocal-pivot scaling, as LAPACK's ``getrf``) on the 2x2 or 3x3
    system: calling LAPACK costs more than the arithmetic here. "Singular" means an exactly zero pivot, which
    is when ``numpy.linalg.solve`` raises.
    """
    n = matrix.shape[0]
    for i in range(n):
        ok = math.isfinite(rhs[i])
        for j in range(n):
            ok = ok and math.isfinite(matrix[i, j])
        if not ok:  # overflowed normal equations: a NaN step the caller refuses
            return np.full(n, np.nan)
    a = matrix.copy()
    b = rhs.copy()
    for k in range(n):
        p = k
        for i in range(k + 1, n):
            if abs(a[i, k]) > abs(a[p, k]):
                p = i
        if a[p, k] == 0.0:
            inv = pinvh(matrix, rcond)
            out = np.zeros(n)
            for i in range(n):
                acc = 0.0
                for j in range(n):
                    acc += inv[i, j] * rhs[j]
                out[i] = -acc
            return out
        if p != k:
            for j in range(n):
                a[k, j], a[p, j] = a[p, j], a[k, j]
            b[k], b[p] = b[p], b[k]
        # LAPACK's getrf scales the column by the reciprocal pivot rather
        # than dividing: the same rounding decides, as in numpy.linalg.solve,
        # whether a nearly rank-1 system is exactly singular.
        inv_pivot = 1.0 / a[k, k]
        for i in range(k + 1, n):
            factor = a[i, k] * inv_pivot
            for j in range(k + 1, n):
                a[i, j] -= factor * a[k, j]
            b[i] -= factor * b[k]
    x = np.empty(n)
    for i in range(n - 1, -1, -1):
        acc = b[i]
        for j in range(i + 1, n):
            acc -= a[i, j] * x[j]
        x[i] = acc / a[i, i]
    return -x
