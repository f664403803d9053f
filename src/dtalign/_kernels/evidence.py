"""The search for a second edge along each vertex's normal, compiled.

Its specification is :mod:`dtalign.reference.evidence`: the same samples
(:func:`~dtalign._kernels.sampling.bilinear`, the gradient's two
components each as the magnitude) in the same order, so the distances,
ratios and sides are bit-identical to it (``tests/test_pose_uncertainty.py``).
It runs once per fit, after the LM, and releases the GIL, so a threaded
batch concludes its fits in parallel. Kernels assume valid C-contiguous
float64 input and never validate.
"""

from __future__ import annotations

import numpy as np

from .._jit import kernel
from .sampling import bilinear


@kernel
def second_edge_search(magnitude, gradient_vu, pts, normals, steps, step, threshold, own_px):
    """Each vertex's nearest edge of the opposite polarity along its normal:
    ``(dist, ratio, side)``, each ``(N,)``, as
    :func:`dtalign.reference.evidence.second_edge_search` defines them, one
    vertex at a time (its profile read into one buffer, the candidates
    visited in order, so the first of equal distances wins as ``argmin``'s)."""
    n = pts.shape[0]
    m = steps.shape[0]
    grad_v = gradient_vu[:, :, 0]
    grad_u = gradient_vu[:, :, 1]
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
            # its polarity: the gradient along the vertex's normal
            at_v, at_u = pv + steps[k] * nv, pu + steps[k] * nu
            if not (bilinear(grad_v, at_v, at_u) * nv + bilinear(grad_u, at_v, at_u) * nu) < 0.0:
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
