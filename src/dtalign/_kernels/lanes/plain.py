"""The plain twin of :mod:`.vector`: the same kernels, one vertex (one byte) at a time.

Each function here gives exactly the bits of its namesake in :mod:`.vector`
(``tests/test_lanes*.py`` check it, whole fits included). Where the vector
code sums four lanes, the sums here are kept in four partial accumulators,
vertex ``i`` going to accumulator ``i % 4``, and combined as
``(s0 + s1) + (s2 + s3)``: the same additions in the same order. This is
the code that runs as Python under ``NUMBA_DISABLE_JIT=1`` and in the
bounds-checked pass, where every read is an ordinary indexed one.
"""

from __future__ import annotations

import math

import numpy as np

from ..._jit import inline_kernel, kernel
from ..robust import polarity, tukey
from ..sampling import bilinear, transform

__all__ = [
    "EPS_R", "EPS_T", "PENALTY", "fill", "lane_cost", "lane_sums", "polarity", "sample_state",
    "staging_buffers", "summary_lanes",
]

#: Mirrors of the constants in dtalign.api.constants, as compile-time literals.
PENALTY = 1.0e6
EPS_T = 0.25
EPS_R = 1.0e-3
#: The spans of the Jacobian's central differences (:ref:`contract-lm`).
TWO_EPS_T = 2 * EPS_T
TWO_EPS_R = 2 * EPS_R


@inline_kernel
def hsum(acc):
    """``(s0 + s1) + (s2 + s3)`` of four partial sums: how the vector code
    combines its lanes."""
    return (acc[0] + acc[1]) + (acc[2] + acc[3])


@inline_kernel
def turned(theta):
    """``(theta + EPS_R, its cos, its sin, theta - EPS_R, its cos, its sin)``:
    the two rotations the Jacobian's rotation column is differenced between."""
    tp, tm = theta + EPS_R, theta - EPS_R
    return tp, math.cos(tp), math.sin(tp), tm, math.cos(tm), math.sin(tm)


@kernel
def staging_buffers():
    """Empty scratch of :mod:`.vector`'s types: the plain code stages nothing."""
    return np.empty(0, np.int32), np.empty(0), np.empty(0, np.bool_)


@inline_kernel
def sample_range(dt, pts, pose, pivot, fit_rotation, samples, jac, start):
    """:func:`sample_state` of the vertices from ``start`` on; returns False if a
    sample read a NaN or inf."""
    dv, du, theta = pose[0], pose[1], pose[2]
    pv, pu = pivot[0], pivot[1]
    c0, s0 = math.cos(theta), math.sin(theta)
    tp, cp, sp, tm, cm, sm = turned(theta)
    ok = True
    for i in range(start, pts.shape[0]):
        v, u = transform(pts[i, 0], pts[i, 1], dv, du, theta, c0, s0, pv, pu)
        sample = bilinear(dt, v, u)
        j0 = (bilinear(dt, v + EPS_T, u) - bilinear(dt, v - EPS_T, u)) / TWO_EPS_T
        j1 = (bilinear(dt, v, u + EPS_T) - bilinear(dt, v, u - EPS_T)) / TWO_EPS_T
        ok &= math.isfinite(sample + j0 + j1)
        samples[i] = sample
        jac[0, i] = j0
        jac[1, i] = j1
        if fit_rotation:
            vp, up = transform(pts[i, 0], pts[i, 1], dv, du, tp, cp, sp, pv, pu)
            vm, um = transform(pts[i, 0], pts[i, 1], dv, du, tm, cm, sm, pv, pu)
            j2 = (bilinear(dt, vp, up) - bilinear(dt, vm, um)) / TWO_EPS_R
            ok &= math.isfinite(j2)
            jac[2, i] = j2
    return ok


@kernel
def sample_state(dt, pts, pose, pivot, fit_rotation, samples, jac, staging):
    """The DT at every vertex at ``pose`` into ``samples`` and the Jacobian's
    columns into ``jac`` (``(P, N)``); returns False if a sample read a NaN
    or inf. ``staging`` is unused (:func:`staging_buffers`)."""
    return sample_range(dt, pts, pose, pivot, fit_rotation, samples, jac, 0)


@kernel
def lane_sums(samples, pol, jac, inv_var, sig, r, w, tukey_c, n4):
    """Residuals and IRLS weights of vertices ``0..n4`` into ``r`` and ``w``,
    and their sums ``(positive, cost, total, g0, g1, g2, h00, h01, h02, h11,
    h12, h22)`` in four partial sums.

    Zero weights add exact zeros (the Jacobian is finite), so no vertex is
    skipped, as in the vector code.
    """
    rotation = jac.shape[0] == 3
    positive = False
    # rows: cost, total, g0, g1, g2, h00, h01, h02, h11, h12, h22
    acc = np.zeros((11, 4))
    for i in range(n4):
        k = i % 4
        p = pol[i]
        ri = samples[i] if p != 0.0 else PENALTY
        r[i] = ri
        wi = inv_var[i] * tukey(ri / sig[i], tukey_c) * p
        w[i] = wi
        positive |= wi > 0.0
        swi = np.sqrt(wi)
        acc[0, k] += wi * ri * ri
        acc[1, k] += wi
        swr = swi * ri
        a0 = swi * jac[0, i]
        a1 = swi * jac[1, i]
        acc[2, k] += a0 * swr
        acc[3, k] += a1 * swr
        acc[5, k] += a0 * a0
        acc[6, k] += a0 * a1
        acc[8, k] += a1 * a1
        if rotation:
            a2 = swi * jac[2, i]
            acc[4, k] += a2 * swr
            acc[7, k] += a0 * a2
            acc[9, k] += a1 * a2
            acc[10, k] += a2 * a2
    return (positive, hsum(acc[0]), hsum(acc[1]), hsum(acc[2]), hsum(acc[3]), hsum(acc[4]),
            hsum(acc[5]), hsum(acc[6]), hsum(acc[7]), hsum(acc[8]), hsum(acc[9]), hsum(acc[10]))


@kernel
def lane_cost(pol, w, samples, n4):
    """``sum(w * r * r)`` over vertices ``0..n4`` in four partial sums, the
    residuals being ``samples`` or the polarity penalty."""
    acc = np.zeros(4)
    for i in range(n4):
        ri = samples[i] if pol[i] != 0.0 else PENALTY
        acc[i % 4] += w[i] * ri * ri
    return hsum(acc)


@kernel
def summary_lanes(r, w, n4):
    """``(inliers, sum(w), sum(w r^2))`` over vertices ``0..n4`` in four
    partial sums (the inlier count as a sum of 1.0s, as the vector code
    counts)."""
    acc = np.zeros((3, 4))
    for i in range(n4):
        k = i % 4
        wi = w[i]
        acc[0, k] += 1.0 if wi > 0.0 else 0.0
        acc[1, k] += wi
        acc[2, k] += wi * r[i] * r[i]
    return int(hsum(acc[0])), hsum(acc[1]), hsum(acc[2])


@kernel
def fill(flat, words, start, stop, out, k):
    """Write the indices of the nonzero bytes of ``flat[start:stop]`` from ``out[k]``;
    returns the new count (indices past ``out``'s end are counted, not
    written). ``words`` is unused (:func:`.bits.fill` reads it, and calls this
    for the bytes outside its whole words)."""
    for i in range(start, stop):
        if flat[i] != 0:
            if k < out.shape[0]:
                out[k] = i
            k += 1
    return k
