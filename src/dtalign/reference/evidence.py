"""The NumPy specification of the second-edge search.

Same name and arguments as ``dtalign._kernels.evidence.second_edge_search``,
written with array operations: the compiled kernel is held against it bit
for bit by ``tests/test_pose_uncertainty.py``. What the search is for (a
thin crescent's other edge pushing the detected edge away) is in
:mod:`dtalign.pipeline.uncertainty`.
"""

from __future__ import annotations

import numpy as np

from ..api.sampling import sample_dt_bilinear

FloatArray = np.ndarray


def second_edge_search(magnitude: FloatArray, gradient_vu: FloatArray, pts: FloatArray,
                       normals: FloatArray, steps: FloatArray, step: float, threshold: float,
                       own_px: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Each vertex's nearest edge of the opposite polarity along its normal.

    The gradient magnitude is read at ``pts[i] + steps[k] * normals[i]``
    (``steps`` ascending, ``step`` apart, symmetric about 0). The vertex's
    own edge is the first largest sample with ``|steps[k]| <= own_px``. A
    candidate is an inner sample above ``threshold``, at least its left
    neighbour and above its right one, not the own edge, whose gradient
    points against the normal. Its distance is ``|steps[k] + step * t|``,
    ``t`` the vertex of the parabola through its three samples (0 where
    they do not bend down).

    Returns
    -------
    dist, ratio, side : ndarray, shape (N,)
        The nearest candidate's distance (``inf`` where there is none or
        the own edge is not above ``threshold``), its peak over the own
        edge's (at most 1; 0 where ``dist`` is ``inf``), and the sign of
        its step (the sign of ``steps[1]`` where there is none).
    """
    n = pts.shape[0]
    s = steps
    at = pts[:, None, :] + s[None, :, None] * normals[:, None, :]
    prof = sample_dt_bilinear(magnitude, at.reshape(-1, 2)).reshape(n, s.size)
    near = np.abs(s) <= own_px
    own_at = np.flatnonzero(near)[np.argmax(prof[:, near], axis=1)]
    rows = np.arange(n)
    own = prof[rows, own_at]
    mid = prof[:, 1:-1]
    peak = (mid > threshold) & (mid >= prof[:, :-2]) & (mid > prof[:, 2:])
    peak[rows, own_at - 1] = False  # the vertex's own edge (never at the ends)
    vi, si = np.nonzero(peak)
    # the polarity of each candidate: its gradient along the vertex's normal
    on = at[vi, si + 1]
    opposite = (sample_dt_bilinear(gradient_vu[..., 0], on) * normals[vi, 0]
                + sample_dt_bilinear(gradient_vu[..., 1], on) * normals[vi, 1]) < 0.0
    # each peak's place refined by the parabola through its three samples
    vo, so = vi[opposite], si[opposite] + 1
    lo, top, hi = prof[vo, so - 1], prof[vo, so], prof[vo, so + 1]
    bend = lo - 2.0 * top + hi
    shift_at = np.where(bend < 0.0, 0.5 * (lo - hi) / np.where(bend < 0.0, bend, -1.0), 0.0)
    dist = np.full((n, s.size - 2), np.inf)
    dist[vo, so - 1] = np.abs(s[so] + step * shift_at)
    j = np.argmin(dist, axis=1)
    d = dist[rows, j]
    found = np.isfinite(d) & (own > threshold)
    ratio = np.where(found, np.minimum(mid[rows, j] / np.where(own > 0.0, own, 1.0), 1.0), 0.0)
    return np.where(found, d, np.inf), ratio, np.sign(s[1:-1][j])
