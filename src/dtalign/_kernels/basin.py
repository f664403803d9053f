"""The competing-basin scan of ``find_secondary_dt_minimum`` (:ref:`contract-basin`).

Costs are means of bilinear DT samples computed exactly as the reference
computes them (the same operations in the same order, and NumPy's pairwise
sum), so equal costs compare equal and the winner is the reference's.

Only the winner's cost matters, so most shifts need not be summed to the
end: with a non-negative DT (checked first over the pixels the scan can
read) a running sum that already exceeds the best cost so far, with a
margin wider than any rounding difference between the running and the
pairwise sum, cannot win or tie, and that shift is dropped. The shifts next
to the converged offset, where the low rival costs are, are visited first
(nearest first), then a coarse lattice of shifts, then the rest, so a good best is found
early and each visited shift can rule out the unvisited ones around it; the
winner is still chosen by the exact rule ``(cost, distance, scan order)``,
whatever the visiting order.

A vertex's bilinear sample changes by at most ``Lv`` per row step and
``Lh`` per column step of the shift, ``Lv`` and ``Lh`` the largest
differences between vertical and horizontal neighbours of the DT (at most 1
for a distance transform, measured over the same pixels). A shift whose
first ``k`` samples sum to ``S`` (dropped or summed in full) therefore
bounds every shift ``(da, db)`` steps away that keeps all vertices in
bounds: the same ``k`` vertices there sum to at least
``S - k (|da| Lv + |db| Lh)``, and the others add no less than 0. These
bounds are kept per shift, and a shift whose bound already exceeds the
drop bound is dropped without a sample. A drop therefore samples on a
little past the bound, to buy the margin for its neighbours.
"""

from __future__ import annotations

import math

import numpy as np

from .._jit import inline_kernel, kernel
from .pairwise import numpy_sum
from .sampling import blend

#: Status codes of :func:`secondary_basin`.
FOUND = 0
NO_CANDIDATE = 1
CONVERGED_UNDEFINED = 2
NONFINITE = 3  # a sample read a NaN or inf from the DT


@kernel
def _samples_at(dt, pts, ov, ou, out):
    """In-bounds bilinear samples of the vertices shifted by ``(ov, ou)``,
    written to ``out`` in vertex order; returns their count."""
    h, w = dt.shape
    k = 0
    for i in range(pts.shape[0]):
        v = pts[i, 0] + ov
        u = pts[i, 1] + ou
        if v >= 0.0 and v <= h - 1 and u >= 0.0 and u <= w - 1:
            v0 = int(math.floor(v))
            u0 = int(math.floor(u))
            v1 = min(v0 + 1, h - 1)
            u1 = min(u0 + 1, w - 1)
            out[k] = blend(dt[v0, u0], dt[v0, u1], dt[v1, u0], dt[v1, u1], v - v0, u - u0)
            k += 1
    return k


#: Relative margin of the early drop: a shift is dropped only when its
#: running sum exceeds ``best * count * (1 + margin)``, with ``margin`` this
#: plus ``2 n`` units of rounding (:data:`ROUNDING`). The running and the
#: pairwise sum of ``n`` non-negative values differ by less than
#: ``(n + log2 n)`` units relative, so a dropped shift's exact cost is
#: strictly greater than the best.
DROP_MARGIN = 1.0e-9
#: The unit roundoff of float64.
ROUNDING = 2.0**-53
#: Samples between two drop tests (a power of two).
DROP_EVERY = 8
#: A dropped shift samples on until its running sum exceeds the bound by
#: ``CARRY_STEPS`` shift steps' worth of change (``k L`` each), so that the
#: shifts that many steps away can be dropped unsampled.
CARRY_STEPS = 8
#: Relative slack on the neighbours' bounds, with ``2 n + 16`` units of
#: rounding for the running sum and the samples' own rounding, and
#: ``4 max(H, W)`` for the rounding of the shifted positions (their distance
#: differs from the integer shift by that much at most, relative).
CARRY_SLACK = 1.0e-9
#: Chebyshev radius, beyond the exclusion radius, of the shifts about the
#: converged offset visited first: the low rival costs lie next to the
#: basin, and a low best makes the drop test bite everywhere else.
NEAR_RING = 2
#: Spacing of the lattice of shifts visited second: each bounds the shifts
#: around it, most of which are then dropped unsampled.
LATTICE = 4
#: Side of the square pixel tiles in which the pixels the scan can read are
#: marked: a vertex reads a ``(2 mv + 2) x (2 mu + 2)`` block of the DT, and
#: the blocks of a limb cover a band, often half its bounding box.
TILE = 8


@kernel
def _axis_tables(coord, m, size):
    """For shift ``k = a - m`` and vertex ``i``: whether ``coord[i] + k`` lies in
    ``[0, size - 1]`` (as computed in float64), its floor and its fraction --
    what every sample of that row (or column) shift reads, formed once
    (floor and fraction are meaningless where it is out of bounds) -- and
    each vertex's first and last in-bounds ``a`` (``-1`` for none; the test
    is monotone in ``a``, so its in-bounds shifts are that range)."""
    n = coord.shape[0]
    count = 2 * m + 1
    inside = np.empty((count, n), dtype=np.bool_)
    low = np.empty((count, n), dtype=np.int64)
    frac = np.empty((count, n))
    for a in range(count):
        k = a - m
        for i in range(n):  # branch-free, so that LLVM vectorises it
            x = coord[i] + k
            ok = (x >= 0.0) & (x <= size - 1)
            f = math.floor(x) if ok else 0
            inside[a, i] = ok
            low[a, i] = f
            frac[a, i] = x - f
    first = np.full(n, -1, dtype=np.int64)
    last = np.full(n, -1, dtype=np.int64)
    for i in range(n):
        for a in range(count):
            if inside[a, i]:
                first[i] = a
                break
        for a in range(count - 1, -1, -1):
            if inside[a, i]:
                last[i] = a
                break
    return inside, low, frac, first, last


@inline_kernel
def _add_rectangle(diff, a0, a1, b0, b1):
    """Add 1 over rows ``a0..a1`` and columns ``b0..b1`` of the 2-D difference
    array ``diff`` (its prefix sums carry it over the rectangle)."""
    diff[a0, b0] += 1
    diff[a0, b1 + 1] -= 1
    diff[a1 + 1, b0] -= 1
    diff[a1 + 1, b1 + 1] += 1


@kernel
def _in_bounds_counts(v_first, v_last, u_first, u_last, nv, nu):
    """How many vertices each shift keeps in bounds, ``(nv, nu)``. A vertex's
    in-bounds shifts form one rectangle, added through a 2-D difference
    array."""
    diff = np.zeros((nv + 1, nu + 1), dtype=np.int64)
    for i in range(v_first.shape[0]):
        a0 = v_first[i]
        a1 = v_last[i]
        b0 = u_first[i]
        b1 = u_last[i]
        if a0 >= 0 and b0 >= 0:
            _add_rectangle(diff, a0, a1, b0, b1)
    counts = np.zeros((nv, nu), dtype=np.int64)
    for a in range(nv):
        for b in range(nu):
            x = diff[a, b]
            if a > 0:
                x += counts[a - 1, b]
            if b > 0:
                x += counts[a, b - 1]
            if a > 0 and b > 0:
                x -= counts[a - 1, b - 1]
            counts[a, b] = x
    return counts


@kernel
def _touched_tiles(v_low, v_first, v_last, u_low, u_first, u_last, h, w):
    """The DT pixels the scan can read, as ``(mask, r0, c0, r1, c1)``: the
    ``TILE x TILE`` tiles (from ``(r0, c0)``) that meet a vertex's block, the
    rows and columns of its in-bounds samples with their second corner, and
    the bounding rows ``r0..r1`` and columns ``c0..c1`` (an empty mask when
    no vertex is ever in bounds)."""
    n = v_first.shape[0]
    rlo = np.empty(n, dtype=np.int64)
    rhi = np.empty(n, dtype=np.int64)
    clo = np.empty(n, dtype=np.int64)
    chi = np.empty(n, dtype=np.int64)
    r0 = h
    r1 = -1
    c0 = w
    c1 = -1
    for i in range(n):
        if v_first[i] < 0 or u_first[i] < 0:
            rlo[i] = -1
            continue
        rlo[i] = v_low[v_first[i], i]
        rhi[i] = min(v_low[v_last[i], i] + 1, h - 1)
        clo[i] = u_low[u_first[i], i]
        chi[i] = min(u_low[u_last[i], i] + 1, w - 1)
        r0 = min(r0, rlo[i])
        r1 = max(r1, rhi[i])
        c0 = min(c0, clo[i])
        c1 = max(c1, chi[i])
    if r1 < 0:
        return np.zeros((0, 0), dtype=np.bool_), 0, 0, -1, -1
    ntr = (r1 - r0) // TILE + 1
    ntc = (c1 - c0) // TILE + 1
    diff = np.zeros((ntr + 1, ntc + 1), dtype=np.int64)
    for i in range(n):
        if rlo[i] < 0:
            continue
        t0 = (rlo[i] - r0) // TILE
        t1 = (rhi[i] - r0) // TILE
        s0 = (clo[i] - c0) // TILE
        s1 = (chi[i] - c0) // TILE
        _add_rectangle(diff, t0, t1, s0, s1)
    mask = np.zeros((ntr, ntc), dtype=np.bool_)
    for t in range(ntr):
        run = 0
        for s in range(ntc):
            if t > 0:
                diff[t, s] += diff[t - 1, s]  # column prefix, in place
            run += diff[t, s]
            mask[t, s] = run > 0
    return mask, r0, c0, r1, c1


@kernel
def _runs(mask):
    """The runs of marked tiles of each tile row: rows ``(t, s, e)``, tiles
    ``s..e`` of tile row ``t``."""
    ntr, ntc = mask.shape
    out = np.empty((ntr * ((ntc + 1) // 2), 3), dtype=np.int64)
    k = 0
    for t in range(ntr):
        s = 0
        while s < ntc:
            if not mask[t, s]:
                s += 1
                continue
            e = s
            while e + 1 < ntc and mask[t, e + 1]:
                e += 1
            out[k, 0] = t
            out[k, 1] = s
            out[k, 2] = e
            k += 1
            s = e + 1
    return out[:k]


@kernel
def _region_counts(dt, runs, seams, r0, c0, r1, c1):
    """``(bad, negative, steep)`` over the marked pixels: how many are not
    finite, how many are negative, and how many differ by more than 1 from
    their left or upper neighbour, where both are marked (``seams``: the
    runs marked in both a tile row and the one above, whose first row pairs
    with the row above).

    Counting vectorises (float max/min reductions without fast math do not).
    The columns are unsigned: Numba's wraparound test of a possibly negative
    index would turn the loads into gathers.
    """
    bad = 0
    negative = 0
    steep = 0
    one = np.uint64(1)
    for q in range(runs.shape[0]):
        top = r0 + runs[q, 0] * TILE
        lo = c0 + runs[q, 1] * TILE
        hi = min(c0 + runs[q, 2] * TILE + TILE - 1, c1) + 1
        for r in range(top, min(top + TILE - 1, r1) + 1):
            row = dt[r]
            x = row[lo]
            bad += not (x - x == 0.0)  # NaN or inf
            negative += x < 0.0
            if r > top:
                up = dt[r - 1]
                steep += abs(x - up[lo]) > 1.0
                for c in range(lo + 1, hi):
                    j = np.uint64(c)
                    x = row[j]
                    bad += not (x - x == 0.0)
                    negative += x < 0.0
                    steep += (abs(x - row[j - one]) > 1.0) | (abs(x - up[j]) > 1.0)
            else:
                for c in range(lo + 1, hi):
                    j = np.uint64(c)
                    x = row[j]
                    bad += not (x - x == 0.0)
                    negative += x < 0.0
                    steep += abs(x - row[j - one]) > 1.0
    for q in range(seams.shape[0]):
        top = r0 + (seams[q, 0] + 1) * TILE
        lo = c0 + seams[q, 1] * TILE
        hi = min(c0 + seams[q, 2] * TILE + TILE - 1, c1) + 1
        row = dt[top]
        up = dt[top - 1]
        for c in range(lo, hi):
            j = np.uint64(c)
            steep += abs(row[j] - up[j]) > 1.0
    return bad, negative, steep


@kernel
def _region_steps(dt, runs, seams, r0, c0, r1, c1):
    """The largest vertical and horizontal difference between marked
    neighbours, ``(step_v, step_h)``, over the pixels of
    :func:`_region_counts`."""
    step_v = 0.0
    step_h = 0.0
    for q in range(runs.shape[0]):
        top = r0 + runs[q, 0] * TILE
        lo = c0 + runs[q, 1] * TILE
        hi = min(c0 + runs[q, 2] * TILE + TILE - 1, c1) + 1
        for r in range(top, min(top + TILE - 1, r1) + 1):
            for c in range(lo, hi):
                if c > lo:
                    step_h = max(step_h, abs(dt[r, c] - dt[r, c - 1]))
                if r > top:
                    step_v = max(step_v, abs(dt[r, c] - dt[r - 1, c]))
    for q in range(seams.shape[0]):
        top = r0 + (seams[q, 0] + 1) * TILE
        lo = c0 + seams[q, 1] * TILE
        hi = min(c0 + seams[q, 2] * TILE + TILE - 1, c1) + 1
        for c in range(lo, hi):
            step_v = max(step_v, abs(dt[top, c] - dt[top - 1, c]))
    return step_v, step_h


@kernel
def _region_ok(dt, mask, r0, c0, r1, c1):
    """``(finite, non_negative, step_v, step_h)`` of the DT pixels the scan can
    read; ``step_v`` and ``step_h`` bound the differences between vertical
    and horizontal neighbours there. A distance transform's steps are at
    most 1, so only a DT with a larger one pays for the exact steps."""
    runs = _runs(mask)
    seams = _runs(mask[1:] & mask[:-1])
    bad, negative, steep = _region_counts(dt, runs, seams, r0, c0, r1, c1)
    step_v = 1.0
    step_h = 1.0
    if steep > 0 and bad == 0:
        step_v, step_h = _region_steps(dt, runs, seams, r0, c0, r1, c1)
    return bad == 0, negative == 0, step_v, step_h


@kernel
def _shift_cost(dt, v_in, v_low, v_frac, u_in, u_low, u_frac, a, b, count, bound, carry,
                buf):
    """The cost at row shift ``a`` and column shift ``b`` with ``count`` vertices
    in bounds: ``(cost, k, running)``. Once its running sum exceeds ``bound``
    the shift cannot win: it stops when the sum also exceeds
    ``bound + carry * k`` (or at the last vertex) and returns ``inf`` with the
    ``k`` samples taken and their running sum."""
    h, w = dt.shape
    n = v_in.shape[1]
    vi = v_in[a]
    vl = v_low[a]
    vf = v_frac[a]
    ui = u_in[b]
    ul = u_low[b]
    uf = u_frac[b]
    every = count == n  # no vertex to skip
    running = 0.0
    k = 0
    over = False
    for i in range(n):
        if not (every or (vi[i] and ui[i])):
            continue
        # an in-bounds sample's corners are never negative: as unsigned
        # indices they skip Numba's wraparound test of negative ones
        v0 = np.uint64(vl[i])
        u0 = np.uint64(ul[i])
        v1 = np.uint64(min(vl[i] + 1, h - 1))
        u1 = np.uint64(min(ul[i] + 1, w - 1))
        x = blend(dt[v0, u0], dt[v0, u1], dt[v1, u0], dt[v1, u1], vf[i], uf[i])
        buf[k] = x
        k += 1
        running += x
        if k % DROP_EVERY == 0 and running > bound:
            over = True
            if running > bound + carry * k:
                break
    if over or running > bound:
        return math.inf, k, running
    return numpy_sum(buf, count) / count, k, running


@kernel
def _spread(lower, a, b, running, k, bound, step_v, step_h, slack):
    """Raise the bounds ``lower`` of the shifts around ``(a, b)`` by what its
    first ``k`` samples (summing to ``running``) say of them, where that
    already exceeds ``bound``; ``slack`` is the relative allowance for
    rounding."""
    nv, nu = lower.shape
    base = running * (1.0 - slack)
    per = k * (1.0 + slack)  # k vertices, each changing by at most one step
    reach = base - bound
    if not reach > 0.0:
        return
    rows = nv if step_v == 0.0 else int(min(reach / (per * step_v), float(nv)))
    for a2 in range(max(a - rows, 0), min(a + rows, nv - 1) + 1):
        left = reach - per * abs(a2 - a) * step_v if a2 != a else reach
        if not left > 0.0:
            continue
        ib = nu if step_h == 0.0 else int(min(left / (per * step_h), float(nu)))
        start = base - per * abs(a2 - a) * step_v if a2 != a else base
        row = lower[a2]
        for b2 in range(max(b - ib, 0), min(b + ib, nu - 1) + 1):
            x = start - per * abs(b2 - b) * step_h if b2 != b else start
            if x > row[b2]:
                row[b2] = x


@kernel
def _visit_order(nv, nu, a_lo, a_hi, b_lo, b_hi, a_c, b_c, cdv, cdu, mv, mu):
    """Row and column shift indices of every shift, in visiting order: those
    in rows ``a_lo..a_hi`` and columns ``b_lo..b_hi`` (next to the basin),
    nearest the converged offset ``(cdv, cdu)`` first, then the lattice of
    spacing :data:`LATTICE` through ``(a_c, b_c)``, then all others, rows
    outer."""
    order_a = np.empty(nv * nu, dtype=np.int64)
    order_b = np.empty(nv * nu, dtype=np.int64)
    seen = np.zeros((nv, nu), dtype=np.bool_)
    box = max(a_hi - a_lo + 1, 0) * max(b_hi - b_lo + 1, 0)  # empty when the basin is off the window
    distance = np.empty(box)
    k = 0
    for a in range(a_lo, a_hi + 1):
        for b in range(b_lo, b_hi + 1):
            order_a[k] = a
            order_b[k] = b
            distance[k] = np.hypot(a - mv - cdv, b - mu - cdu)
            seen[a, b] = True
            k += 1
    by_distance = np.argsort(distance)
    order_a[:box] = order_a[:box][by_distance]
    order_b[:box] = order_b[:box][by_distance]
    for a in range(a_c % LATTICE, nv, LATTICE):
        for b in range(b_c % LATTICE, nu, LATTICE):
            if not seen[a, b]:
                order_a[k] = a
                order_b[k] = b
                seen[a, b] = True
                k += 1
    for a in range(nv):
        for b in range(nu):
            if not seen[a, b]:
                order_a[k] = a
                order_b[k] = b
                k += 1
    return order_a, order_b


@kernel
def secondary_basin(dt, pts, cdv, cdu, mv, mu, radius, min_support):
    """Best integer shift outside the converged basin.

    Returns ``(status, dv, du, distance, cost, converged_cost)``; ``status``
    is :data:`FOUND` or says why there is no result. ``mv`` and ``mu`` are
    the integer margins (a negative one scans nothing).
    """
    n = pts.shape[0]
    h, w = dt.shape
    buf = np.empty(n)
    k = _samples_at(dt, pts, cdv, cdu, buf)
    if k == 0 or k < min_support:
        return CONVERGED_UNDEFINED, 0, 0, 0.0, 0.0, 0.0
    converged_cost = numpy_sum(buf, k) / k
    if not math.isfinite(converged_cost):
        return NONFINITE, 0, 0, 0.0, 0.0, 0.0
    if mv < 0 or mu < 0:
        return NO_CANDIDATE, 0, 0, 0.0, 0.0, converged_cost
    nv = 2 * mv + 1
    nu = 2 * mu + 1
    v_in, v_low, v_frac, v_first, v_last = _axis_tables(pts[:, 0].copy(), mv, h)
    u_in, u_low, u_frac, u_first, u_last = _axis_tables(pts[:, 1].copy(), mu, w)
    mask, r0, c0, r1, c1 = _touched_tiles(v_low, v_first, v_last, u_low, u_first, u_last, h, w)
    finite, prunable, step_v, step_h = _region_ok(dt, mask, r0, c0, r1, c1)
    if not finite:
        return NONFINITE, 0, 0, 0.0, 0.0, 0.0
    counts = _in_bounds_counts(v_first, v_last, u_first, u_last, nv, nu)
    # lower bounds on the sums of the shifts that keep every vertex in bounds
    lower = np.zeros((nv, nu))
    spread = prunable and step_v < math.inf and step_h < math.inf
    margin = 1.0 + DROP_MARGIN + 2 * n * ROUNDING
    slack = CARRY_SLACK + (2 * n + 16 + 4 * max(h, w)) * ROUNDING
    carry = CARRY_STEPS * max(step_v, step_h) * (1.0 + slack)
    found = False
    best = (math.inf, math.inf, 0, 0)  # (cost, distance, dv, du): the order of :ref:`contract-basin`
    near = int(math.ceil(radius)) + NEAR_RING if radius < nv + nu else nv + nu
    a_c = int(round(cdv)) + mv
    b_c = int(round(cdu)) + mu
    a_lo = max(a_c - near, 0)
    a_hi = min(a_c + near, nv - 1)
    b_lo = max(b_c - near, 0)
    b_hi = min(b_c + near, nu - 1)
    order_a, order_b = _visit_order(nv, nu, a_lo, a_hi, b_lo, b_hi, a_c, b_c, cdv, cdu,
                                    mv, mu)
    for j in range(nv * nu):
        a = order_a[j]
        b = order_b[j]
        count = counts[a, b]
        if count == 0 or count < min_support:
            continue
        bound = best[0] * count * margin if prunable else math.inf
        if count == n and lower[a, b] > bound:
            continue  # dropped unsampled: a neighbour's samples already exceed the bound
        dv = a - mv
        du = b - mu
        distance = np.hypot(dv - cdv, du - cdu)
        if distance <= radius:
            continue
        cost, k, running = _shift_cost(
            dt, v_in, v_low, v_frac, u_in, u_low, u_frac, a, b, count, bound, carry, buf,
        )
        if cost == math.inf and bound < math.inf:
            # dropped: strictly worse than the best
            if spread:
                _spread(lower, a, b, running, k, bound, step_v, step_h, slack)
            continue
        if not math.isfinite(cost):
            return NONFINITE, 0, 0, 0.0, 0.0, 0.0
        candidate = (cost, distance, dv, du)
        if not found or candidate < best:
            found = True
            best = candidate
        if spread:
            _spread(lower, a, b, running, k, best[0] * n * margin, step_v, step_h, slack)
    if not found:
        return NO_CANDIDATE, 0, 0, 0.0, 0.0, converged_cost
    return FOUND, best[2], best[3], best[1], best[0], converged_cost
