"""The LM's per-vertex loops four vertices at a time, on :mod:`.simd`'s vector type.

Why this exists: the LM loop's cost is bilinear samples of the DT, five per
vertex per iteration, then weights and sums over the vertices; LLVM does
not vectorise these by itself (see :mod:`.simd`). Each kernel here has a
namesake in :mod:`.plain` that gives exactly the same bits; the last
``n % 4`` vertices are taken by the plain code (or by the caller, for the
sums, which continue in order after the lanes).
"""

from __future__ import annotations

import math

import numpy as np

from ..._jit import inline_kernel, kernel
from ..robust import _polarity_at
from .bits import fill
from .plain import EPS_R, EPS_T, PENALTY, TWO_EPS_R, TWO_EPS_T, sample_range, turned
from .simd import (
    MAX_ELEMENTS,
    all_finite,
    any_greater,
    hsum,
    load4,
    positive_ones,
    splat,
    sqrt4,
    store4,
    tukey4,
    where_nonzero,
)
from .simd_image import (
    CELLS_PER_SLOT,
    FRACS_PER_SLOT,
    bilinear4,
    finish_state,
    polarity4,
    positions4,
    stage_state,
    state4,
)

__all__ = [
    "EPS_R", "EPS_T", "PENALTY", "fill", "lane_cost", "lane_sums", "polarity", "sample_state",
    "staging_buffers", "summary_lanes",
]

#: Groups of four vertices whose cells are staged at a time (:mod:`.simd_image`):
#: enough to overlap the groups' loads, few enough for the buffers (6.4 KiB)
#: to stay in L1.
BLOCK = 16


@inline_kernel
def lanes_for(dt, n):
    """How many leading vertices are sampled four at a time: none when the DT
    has a single row or column (no cell is inside) or too many elements for
    32-bit cell indices."""
    if dt.shape[0] < 2 or dt.shape[1] < 2 or dt.size > MAX_ELEMENTS:
        return 0
    return n - n % 4


@kernel
def staging_buffers():
    """Scratch for :func:`sample_state`'s staged cells, allocated once per fit."""
    return (np.empty(BLOCK * CELLS_PER_SLOT, np.int32), np.empty(BLOCK * FRACS_PER_SLOT),
            np.empty(BLOCK, np.bool_))


@kernel
def sample_state(dt, pts, pose, pivot, fit_rotation, samples, jac, staging):
    """:func:`.plain.sample_state`, four vertices at a time.

    The groups' cells are staged a block at a time in ``staging``
    (:func:`staging_buffers`); the last ``n % 4`` vertices one by one.
    """
    dv, du, theta = pose[0], pose[1], pose[2]
    pv, pu = pivot[0], pivot[1]
    c0, s0 = math.cos(theta), math.sin(theta)
    tp, cp, sp, tm, cm, sm = turned(theta)
    n4 = lanes_for(dt, pts.shape[0])
    ok = True
    cells, fracs, staged = staging
    for i in range(0, n4, 4):
        g = (i >> 2) % BLOCK
        if g == 0:  # stage the cells of the next block of groups
            for h in range(min(BLOCK, (n4 - i) >> 2)):
                v, u = positions4(pts, i + 4 * h, dv, du, theta, c0, s0, pv, pu)
                staged[h] = stage_state(dt, v, u, EPS_T, cells, fracs, h)
        if staged[g]:
            sample, j_v, j_u = finish_state(dt, cells, fracs, g, TWO_EPS_T)
        else:
            v, u = positions4(pts, i, dv, du, theta, c0, s0, pv, pu)
            sample, j_v, j_u = state4(dt, v, u, EPS_T, TWO_EPS_T)
        # inf - inf and nan propagate, so one test covers all five samples
        ok &= all_finite(sample + j_v + j_u)
        store4(samples, i, sample)
        store4(jac[0], i, j_v)
        store4(jac[1], i, j_u)
        if fit_rotation:
            vp, up = positions4(pts, i, dv, du, tp, cp, sp, pv, pu)
            vm, um = positions4(pts, i, dv, du, tm, cm, sm, pv, pu)
            j_r = (bilinear4(dt, vp, up) - bilinear4(dt, vm, um)) / splat(TWO_EPS_R)
            ok &= all_finite(j_r)
            store4(jac[2], i, j_r)
    return ok & sample_range(dt, pts, pose, pivot, fit_rotation, samples, jac, n4)


@kernel
def lane_sums(samples, pol, jac, inv_var, sig, r, w, tukey_c, n4):
    """:func:`.plain.lane_sums`, four vertices at a time (``n4 % 4 == 0``)."""
    zero = splat(0.0)
    penalty = splat(PENALTY)
    rotation = jac.shape[0] == 3
    positive = False
    cost4 = total4 = g0_4 = g1_4 = g2_4 = zero
    h00_4 = h01_4 = h02_4 = h11_4 = h12_4 = h22_4 = zero
    for i in range(0, n4, 4):
        p = load4(pol, i)
        ri = where_nonzero(p, load4(samples, i), penalty)
        store4(r, i, ri)
        wi = load4(inv_var, i) * tukey4(ri / load4(sig, i), tukey_c) * p
        store4(w, i, wi)
        positive |= any_greater(wi, zero)
        swi = sqrt4(wi)
        cost4 += wi * ri * ri
        total4 += wi
        swr = swi * ri
        a0 = swi * load4(jac[0], i)
        a1 = swi * load4(jac[1], i)
        g0_4 += a0 * swr
        g1_4 += a1 * swr
        h00_4 += a0 * a0
        h01_4 += a0 * a1
        h11_4 += a1 * a1
        if rotation:
            a2 = swi * load4(jac[2], i)
            g2_4 += a2 * swr
            h02_4 += a0 * a2
            h12_4 += a1 * a2
            h22_4 += a2 * a2
    return (positive, hsum(cost4), hsum(total4), hsum(g0_4), hsum(g1_4), hsum(g2_4),
            hsum(h00_4), hsum(h01_4), hsum(h02_4), hsum(h11_4), hsum(h12_4), hsum(h22_4))


@kernel
def lane_cost(pol, w, samples, n4):
    """:func:`.plain.lane_cost`, four vertices at a time."""
    penalty = splat(PENALTY)
    total4 = splat(0.0)
    for i in range(0, n4, 4):
        ri = where_nonzero(load4(pol, i), load4(samples, i), penalty)
        total4 += load4(w, i) * ri * ri
    return hsum(total4)


@kernel
def summary_lanes(r, w, n4):
    """:func:`.plain.summary_lanes`, four vertices at a time."""
    zero = splat(0.0)
    count4 = total4 = weighted4 = zero
    for i in range(0, n4, 4):
        ri = load4(r, i)
        wi = load4(w, i)
        count4 += positive_ones(wi)
        total4 += wi
        weighted4 += wi * ri * ri
    # the count is exact: a sum of 1.0s below 2**53
    return int(hsum(count4)), hsum(total4), hsum(weighted4)


@kernel
def polarity(pts, nrm, grad, dv, du):
    """:func:`dtalign._kernels.robust.polarity`, four vertices at a time
    (:func:`.simd_image.polarity4`), the rest one by one."""
    n = pts.shape[0]
    out = np.zeros(n)
    n4 = n - n % 4 if grad.size <= MAX_ELEMENTS else 0
    for i in range(0, n4, 4):
        flags, bad = polarity4(pts, nrm, grad, i, dv, du)
        if bad:
            return out, True
        store4(out, i, flags)
    for i in range(n4, n):
        out[i], bad = _polarity_at(pts, nrm, grad, i, dv, du)
        if bad:
            return out, True
    return out, False
