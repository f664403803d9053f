"""Value checks of the per-vertex arrays in one pass (the wrappers raise)."""

from __future__ import annotations

import math

import numpy as np

from .._jit import kernel

#: Status codes of :func:`polyline_status`, in the check order of :ref:`contract-errors`.
OK = 0
BAD_VERTICES = 1
BAD_NORMALS = 2
BAD_SIGMAS = 3
BAD_CENTROID = 4


@kernel
def polyline_status(pts, nrm, sig):
    """First failing check and the vertex centroid.

    Vertices and normals must be finite (and the vertices' sum too, so the
    centroid pivot is); sigmas finite, > 0 and with a finite
    ``1 / sigma^2``. The centroid is the sequential sum divided by
    N, bit-identical to ``pts.mean(axis=0)`` for an ``(N, 2)`` C array.
    """
    n = pts.shape[0]
    # one pass: the centroid sums are a chain of dependent adds (they must
    # stay sequential), and the checks, flags rather than early exits, run
    # in its shadow
    ok_v = ok_n = ok_s = True
    s0 = 0.0
    s1 = 0.0
    for i in range(n):
        a = pts[i, 0]
        b = pts[i, 1]
        s0 += a
        s1 += b
        ok_v &= math.isfinite(a) & math.isfinite(b)
        ok_n &= math.isfinite(nrm[i, 0]) & math.isfinite(nrm[i, 1])
        s = sig[i]
        ok_s &= math.isfinite(s) & (s > 0.0) & math.isfinite(1.0 / (s * s))
    if not ok_v:
        return BAD_VERTICES, 0.0, 0.0
    if not ok_n:
        return BAD_NORMALS, 0.0, 0.0
    if not ok_s:
        return BAD_SIGMAS, 0.0, 0.0
    c_v = s0 / n
    c_u = s1 / n
    if not (math.isfinite(c_v) and math.isfinite(c_u)):
        return BAD_CENTROID, 0.0, 0.0
    return OK, c_v, c_u


@kernel
def polylines_status(pts, nrm, sig, starts):
    """:func:`polyline_status` of each polyline ``starts[j]:starts[j+1]`` of
    the concatenated arrays, up to the first that fails.

    Returns ``(j, status, centroids)``: ``j`` is the first failing
    polyline (or the count), ``status`` its code, ``centroids[:j]`` valid.
    """
    k = starts.shape[0] - 1
    centroids = np.zeros((k, 2))
    for j in range(k):
        a = starts[j]
        b = starts[j + 1]
        status, c_v, c_u = polyline_status(pts[a:b], nrm[a:b], sig[a:b])
        if status != OK:
            return j, status, centroids
        centroids[j, 0] = c_v
        centroids[j, 1] = c_u
    return k, OK, centroids
