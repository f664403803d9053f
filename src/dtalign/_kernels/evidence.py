"""The search for a second edge along each vertex's normal, compiled.

Its specification is :mod:`dtalign.reference.evidence`, the NumPy code it
replaced in :mod:`dtalign.pipeline.uncertainty` (the second edges of
``evidence``): the same samples in the same order, so the distances, ratios
and sides are bit-identical to it (``tests/test_pose_uncertainty.py``). It runs once per fit, after the LM, and releases the
GIL, so a threaded batch concludes its fits in parallel. Kernels assume
valid C-contiguous float64 input and never validate.
"""

from __future__ import annotations

import numpy as np

from .._jit import inline_kernel, kernel
from .sampling import bilinear


@inline_kernel
def _vector_dot(grid, v, u, nv, nu):
    """The bilinear sample of the ``(H, W, 2)`` vector ``grid`` at ``(v, u)``,
    dotted with ``(nv, nu)``.

    Edge-clamped, the low corner at most the second-to-last row (column),
    each corner weighted as ``(1 - fv) ((1 - fu) a + fu b) + fv ((1 - fu) c
    + fu d)``: the NumPy specification's cell and order, not
    :func:`~dtalign._kernels.sampling.bilinear`'s.
    """
    h, w = grid.shape[0], grid.shape[1]
    v = min(max(v, 0.0), h - 1.0)
    u = min(max(u, 0.0), w - 1.0)
    v0 = min(int(np.floor(v)), max(h - 2, 0))
    u0 = min(int(np.floor(u)), max(w - 2, 0))
    fv = v - v0
    fu = u - u0
    v1 = min(v0 + 1, h - 1)
    u1 = min(u0 + 1, w - 1)
    gv = ((1 - fv) * ((1 - fu) * grid[v0, u0, 0] + fu * grid[v0, u1, 0])
          + fv * ((1 - fu) * grid[v1, u0, 0] + fu * grid[v1, u1, 0]))
    gu = ((1 - fv) * ((1 - fu) * grid[v0, u0, 1] + fu * grid[v0, u1, 1])
          + fv * ((1 - fu) * grid[v1, u0, 1] + fu * grid[v1, u1, 1]))
    return gv * nv + gu * nu


@kernel
def second_edge_search(magnitude, gradient_vu, pts, normals, steps, step, threshold, own_px):
    """Each vertex's nearest edge of the opposite polarity along its normal:
    ``(dist, ratio, side)``, each ``(N,)``, as
    :func:`dtalign.reference.evidence.second_edge_search` defines them, one
    vertex at a time (its profile read into one buffer, the candidates
    visited in order, so the first of equal distances wins as ``argmin``'s)."""
    n = pts.shape[0]
    m = steps.shape[0]
    dist = np.empty(n)
    ratio = np.empty(n)
    side = np.empty(n)
    prof = np.empty(m)
    for i in range(n):
        pv, pu = pts[i, 0], pts[i, 1]
        nv, nu = normals[i, 0], normals[i, 1]
        own_at = -1
        for k in range(m):
            prof[k] = bilinear(magnitude, pv + steps[k] * nv, pu + steps[k] * nu)
            if abs(steps[k]) <= own_px and (own_at < 0 or prof[k] > prof[own_at]):
                own_at = k
        own = prof[own_at]
        best = np.inf
        j = 0
        for k in range(1, m - 1):
            top = prof[k]
            if not (top > threshold and top >= prof[k - 1] and top > prof[k + 1]) or k == own_at:
                continue
            if not _vector_dot(gradient_vu, pv + steps[k] * nv, pu + steps[k] * nu, nv, nu) < 0.0:
                continue
            lo, hi = prof[k - 1], prof[k + 1]
            bend = lo - 2.0 * top + hi
            t = 0.5 * (lo - hi) / bend if bend < 0.0 else 0.0
            d = abs(steps[k] + step * t)
            if d < best:  # the first of equal distances, as argmin
                best = d
                j = k - 1
        found = best < np.inf and own > threshold
        dist[i] = best if found else np.inf
        ratio[i] = min(prof[j + 1] / (own if own > 0.0 else 1.0), 1.0) if found else 0.0
        side[i] = np.sign(steps[j + 1])
    return dist, ratio, side
