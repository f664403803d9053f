"""The competing-basin scan of ``find_secondary_dt_minimum`` (SPEC section 8.4).

Costs are means of bilinear DT samples computed exactly as the reference
computes them (the same operations in the same order, and NumPy's pairwise
sum), so equal costs compare equal and the winner is the reference's.

Only the winner's cost matters, so most shifts need not be summed to the
end: with a non-negative DT (checked over the scanned region first) a
running sum that already exceeds the best cost so far, with a margin far
wider than any rounding difference between the running and the pairwise
sum, cannot win or tie, and that shift is dropped. The shifts next to
the converged offset, where the low rival costs are, are visited first, so
a good best is found early; the winner is still chosen by the exact rule
``(cost, distance, scan order)``, whatever the visiting order.

Along a row of shifts, the samples of a vertex change by at most ``L``
per column step, ``L`` the largest difference between horizontal
neighbours of the DT (at most 1 for a distance transform, measured over the
scanned region). A dropped shift's first ``k`` samples summed to more than
the bound by some margin; the next shift's same ``k`` samples then sum to at
least that sum less ``k L``, so while that stays above the bound the next
shifts are dropped without a sample. A drop therefore samples on a little
past the bound, to buy the margin for its neighbours.
"""

from __future__ import annotations

import math

import numpy as np

from .._jit import kernel
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
#: running sum exceeds ``best * count * (1 + DROP_MARGIN)``. The running and
#: the pairwise sum of ``n`` non-negative values differ by at most about
#: ``2 log2(n) * 2**-53`` relative, far below this, so a dropped shift's
#: exact cost is strictly greater than the best.
DROP_MARGIN = 1.0e-9
#: Samples between two drop tests (a power of two).
DROP_EVERY = 8
#: A dropped shift samples on until its running sum exceeds the bound by
#: ``CARRY_STEPS`` column steps' worth of change (``k L`` each), so that
#: many of the following shifts in its row can be dropped unsampled.
CARRY_STEPS = 8
#: Relative slack on the carried bound, for the rounding of the samples.
CARRY_SLACK = 1.0e-9
#: Chebyshev radius, beyond the exclusion radius, of the shifts about the
#: converged offset visited first: the low rival costs lie next to the
#: basin, and a low best makes the drop test bite everywhere else.
NEAR_RING = 2


@kernel
def _axis_tables(coord, m, size):
    """For shift ``k = a - m`` and vertex ``i``: whether ``coord[i] + k`` lies in
    ``[0, size - 1]`` (as computed in float64), its floor and its fraction --
    what every sample of that row (or column) shift reads, formed once."""
    n = coord.shape[0]
    count = 2 * m + 1
    inside = np.zeros((count, n), dtype=np.bool_)
    low = np.zeros((count, n), dtype=np.int64)
    frac = np.zeros((count, n))
    for a in range(count):
        for i in range(n):
            x = coord[i] + (a - m)
            if x >= 0.0 and x <= size - 1:
                f = math.floor(x)
                inside[a, i] = True
                low[a, i] = int(f)
                frac[a, i] = x - f
    return inside, low, frac


@kernel
def _in_bounds_counts(v_in, u_in):
    """How many vertices each shift keeps in bounds, ``(nv, nu)``. A vertex's
    in-bounds shifts form one rectangle (the test is monotone in each shift),
    added through a 2-D difference array."""
    nv, n = v_in.shape
    nu = u_in.shape[0]
    diff = np.zeros((nv + 1, nu + 1), dtype=np.int64)
    for i in range(n):
        a0 = nv
        a1 = -1
        for a in range(nv):
            if v_in[a, i]:
                a0 = min(a0, a)
                a1 = a
        b0 = nu
        b1 = -1
        for b in range(nu):
            if u_in[b, i]:
                b0 = min(b0, b)
                b1 = b
        if a1 >= 0 and b1 >= 0:
            diff[a0, b0] += 1
            diff[a0, b1 + 1] -= 1
            diff[a1 + 1, b0] -= 1
            diff[a1 + 1, b1 + 1] += 1
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
def _region_ok(dt, v_low, u_low):
    """``(finite, non_negative, step)`` of the DT pixels the scan can read;
    ``step`` bounds the difference between horizontal neighbours there.

    A distance transform's steps are at most 1, so the common case is
    settled by counting (loops LLVM vectorises, unlike float max/min
    reductions without fast math): the pixels that are not finite, that are
    negative, and the steps above 1. Only a DT with a larger step pays for
    the exact largest step, in a second pass.
    """
    h, w = dt.shape
    r0 = v_low.min()
    r1 = min(v_low.max() + 1, h - 1)
    c0 = u_low.min()
    c1 = min(u_low.max() + 1, w - 1)
    bad = 0
    negative = 0
    steep = 0
    for r in range(r0, r1 + 1):
        row = dt[r]
        for c in range(c0, c1 + 1):
            x = row[c]
            bad += not (x - x == 0.0)  # NaN or inf
            negative += x < 0.0
        for c in range(c0 + 1, c1 + 1):
            steep += abs(row[c] - row[c - 1]) > 1.0
    step = 1.0
    if steep > 0 and bad == 0:
        step = 0.0
        for r in range(r0, r1 + 1):
            for c in range(c0 + 1, c1 + 1):
                step = max(step, abs(dt[r, c] - dt[r, c - 1]))
    return bad == 0, negative == 0, step


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
    running = 0.0
    k = 0
    over = False
    for i in range(n):
        if not (v_in[a, i] and u_in[b, i]):
            continue
        v0 = v_low[a, i]
        u0 = u_low[b, i]
        v1 = min(v0 + 1, h - 1)
        u1 = min(u0 + 1, w - 1)
        x = blend(dt[v0, u0], dt[v0, u1], dt[v1, u0], dt[v1, u1], v_frac[a, i], u_frac[b, i])
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
    v_in, v_low, v_frac = _axis_tables(pts[:, 0].copy(), mv, h)
    u_in, u_low, u_frac = _axis_tables(pts[:, 1].copy(), mu, w)
    finite, prunable, step = _region_ok(dt, v_low, u_low)
    if not finite:
        return NONFINITE, 0, 0, 0.0, 0.0, 0.0
    nv = 2 * mv + 1
    nu = 2 * mu + 1
    counts = _in_bounds_counts(v_in, u_in)
    found = False
    best = (math.inf, math.inf, 0, 0)  # (cost, distance, dv, du): the SPEC order
    near = int(math.ceil(radius)) + NEAR_RING if radius < nv + nu else nv + nu
    a_lo = max(int(round(cdv)) + mv - near, 0)
    a_hi = min(int(round(cdv)) + mv + near, nv - 1)
    b_lo = max(int(round(cdu)) + mu - near, 0)
    b_hi = min(int(round(cdu)) + mu + near, nu - 1)
    # per column step, the most a vertex's sample can change (with slack)
    carry_step = step * (1.0 + CARRY_SLACK)
    for sweep in range(2):  # the shifts next to the basin, then all others
        for a in range(nv):
            near_row = a_lo <= a <= a_hi
            if sweep == 0 and not near_row:
                continue
            carried_k = 0  # a dropped shift of this row: its k samples' running sum
            carried_sum = 0.0
            carried_steps = 0
            for b in range(nu):
                is_near = near_row and b_lo <= b <= b_hi
                if is_near != (sweep == 0):
                    carried_k = 0
                    continue
                carried_steps += 1
                dv = a - mv
                du = b - mu
                distance = np.hypot(dv - cdv, du - cdu)
                if distance <= radius:
                    continue
                count = counts[a, b]
                if count == 0 or count < min_support:
                    continue
                bound = best[0] * count * (1.0 + DROP_MARGIN) if prunable else math.inf
                if (carried_k > 0 and count == n
                        and carried_sum * (1.0 - CARRY_SLACK) - carried_steps * carried_k * carry_step
                        > bound):
                    continue  # dropped unsampled: its first samples already exceed the bound
                cost, k, running = _shift_cost(
                    dt, v_in, v_low, v_frac, u_in, u_low, u_frac, a, b, count, bound,
                    CARRY_STEPS * carry_step, buf,
                )
                if cost == math.inf and bound < math.inf:
                    # dropped: strictly worse than the best; its samples carry on
                    # along the row when every vertex is in bounds (the same ones)
                    carried_k = k if count == n else 0
                    carried_sum = running
                    carried_steps = 0
                    continue
                if not math.isfinite(cost):
                    return NONFINITE, 0, 0, 0.0, 0.0, 0.0
                candidate = (cost, distance, dv, du)
                if not found or candidate < best:
                    found = True
                    best = candidate
    if not found:
        return NO_CANDIDATE, 0, 0, 0.0, 0.0, converged_cost
    return FOUND, best[2], best[3], best[1], best[0], converged_cost
