"""The competing-basin scan of ``find_secondary_dt_minimum`` (SPEC section 8.4).

Costs are means of bilinear DT samples computed exactly as the reference
computes them (the same operations in the same order, and NumPy's pairwise
sum), so equal costs compare equal and the winner is the reference's.

Only the winner's cost matters, so most shifts need not be summed to the
end: with a non-negative DT (checked over the scanned region first) a
running sum that already exceeds the best cost so far, with a margin far
wider than any rounding difference between the running and the pairwise
sum, cannot win or tie, and that shift is dropped. Shifts are visited ring
by ring outward from the converged offset, where the low costs are, so a
good best is found early; the winner is still chosen by the exact rule
``(cost, distance, scan order)``, whatever the visiting order.
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
def _samples_at(dt, pts, ov, ou, out):  # pragma: no cover - compiled
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
#: Samples between two drop tests.
DROP_EVERY = 8


@kernel
def _in_bounds_ranges(coord, low, high, m):  # pragma: no cover - compiled
    """For each vertex coordinate, the shifts ``k`` in ``[-m, m]`` with
    ``low <= coord + k <= high`` (as computed in float64): a range ``[lo, hi]``
    (empty when ``lo > hi``). The test is monotone in ``k``, so it is one range."""
    n = coord.shape[0]
    lo = np.empty(n, dtype=np.int64)
    hi = np.empty(n, dtype=np.int64)
    for i in range(n):
        lo[i] = m + 1
        hi[i] = -m - 1
        for k in range(-m, m + 1):
            x = coord[i] + k
            if x >= low and x <= high:
                if k < lo[i]:
                    lo[i] = k
                hi[i] = k
    return lo, hi


@kernel
def _region_ok(dt, pts, mv, mu):  # pragma: no cover - compiled
    """``(finite, non_negative)`` of the DT pixels any scanned sample can read."""
    h, w = dt.shape
    r0 = max(int(math.floor(max(pts[:, 0].min() - mv, 0.0))), 0)
    r1 = min(int(math.floor(min(pts[:, 0].max() + mv, h - 1.0))) + 1, h - 1)
    c0 = max(int(math.floor(max(pts[:, 1].min() - mu, 0.0))), 0)
    c1 = min(int(math.floor(min(pts[:, 1].max() + mu, w - 1.0))) + 1, w - 1)
    finite = True
    non_negative = True
    for r in range(r0, r1 + 1):
        for c in range(c0, c1 + 1):
            x = dt[r, c]
            finite &= math.isfinite(x)
            non_negative &= x >= 0.0
    return finite, non_negative


@kernel
def secondary_basin(dt, pts, cdv, cdu, mv, mu, radius, min_support):  # pragma: no cover - compiled
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
    finite, prunable = _region_ok(dt, pts, mv, mu)
    if not finite:
        return NONFINITE, 0, 0, 0.0, 0.0, 0.0
    v_lo, v_hi = _in_bounds_ranges(pts[:, 0], 0.0, h - 1.0, mv)
    u_lo, u_hi = _in_bounds_ranges(pts[:, 1], 0.0, w - 1.0, mu)
    nv = 2 * mv + 1
    nu = 2 * mu + 1
    # in-bounds count of every shift: per vertex, one rectangle of shifts
    diff = np.zeros((nv + 1, nu + 1), dtype=np.int64)
    for i in range(n):
        if v_lo[i] <= v_hi[i] and u_lo[i] <= u_hi[i]:
            a0 = v_lo[i] + mv
            a1 = v_hi[i] + mv + 1
            b0 = u_lo[i] + mu
            b1 = u_hi[i] + mu + 1
            diff[a0, b0] += 1
            diff[a0, b1] -= 1
            diff[a1, b0] -= 1
            diff[a1, b1] += 1
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
    found = False
    best_dv = 0
    best_du = 0
    best_cost = math.inf
    best_distance = math.inf
    # rings of growing Chebyshev radius about the converged offset's pixel
    centre_a = min(max(int(round(cdv)) + mv, 0), nv - 1)
    centre_b = min(max(int(round(cdu)) + mu, 0), nu - 1)
    rings = max(centre_a, nv - 1 - centre_a, centre_b, nu - 1 - centre_b)
    for ring in range(rings + 1):
        for a in range(max(centre_a - ring, 0), min(centre_a + ring, nv - 1) + 1):
            edge_row = a == centre_a - ring or a == centre_a + ring
            step = 1 if edge_row else 2 * ring
            b = centre_b - ring
            while b <= centre_b + ring:
                if b < 0 or b >= nu:
                    b += step if step > 0 else 1
                    continue
                dv = a - mv
                du = b - mu
                kb = counts[a, b]
                distance = math.hypot(dv - cdv, du - cdu)
                b += step if step > 0 else 1
                if distance <= radius or kb == 0 or kb < min_support:
                    continue
                bound = best_cost * kb * (1.0 + DROP_MARGIN) if prunable else math.inf
                running = 0.0
                k = 0
                dropped = False
                for i in range(n):
                    if dv < v_lo[i] or dv > v_hi[i] or du < u_lo[i] or du > u_hi[i]:
                        continue
                    v = pts[i, 0] + dv
                    u = pts[i, 1] + du
                    v0 = int(math.floor(v))
                    u0 = int(math.floor(u))
                    v1 = min(v0 + 1, h - 1)
                    u1 = min(u0 + 1, w - 1)
                    x = blend(dt[v0, u0], dt[v0, u1], dt[v1, u0], dt[v1, u1], v - v0, u - u0)
                    buf[k] = x
                    k += 1
                    running += x
                    if k % DROP_EVERY == 0 and running > bound:
                        dropped = True
                        break
                if dropped:
                    continue
                cost = numpy_sum(buf, k) / k
                if (not found or cost < best_cost
                        or (cost == best_cost and (distance < best_distance
                            or (distance == best_distance and (dv < best_dv
                                or (dv == best_dv and du < best_du)))))):
                    found = True
                    best_dv = dv
                    best_du = du
                    best_cost = cost
                    best_distance = distance
    if not found:
        return NO_CANDIDATE, 0, 0, 0.0, 0.0, converged_cost
    return FOUND, best_dv, best_du, best_distance, best_cost, converged_cost
