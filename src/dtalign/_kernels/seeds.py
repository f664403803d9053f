"""The K best distinct seeds of a coarse score surface: the starts of a multi-start fit."""

from __future__ import annotations

import numpy as np

from .._jit import kernel
from .coarse import better


@kernel
def top_k(surface, mv, mu, k, separation):
    """Up to ``k`` local maxima of ``surface`` (rows ``dv + mv``, columns
    ``du + mu``; NaN marks a shift that is no candidate), best first in the
    coarse searches' order, each at least ``separation`` from those before.

    A local maximum scores at least as high as each of its candidate
    8-neighbours. The global best (by the searches' own order) is one, so
    the first seed is the search's result. Later seeds must score above 0:
    a shift that meets no edge is a plateau, not a basin worth a fit.
    Returns ``(count, dv, du, score)``.
    """
    nv, nu = surface.shape
    peak = np.zeros((nv, nu), dtype=np.bool_)
    for a in range(nv):
        for b in range(nu):
            s = surface[a, b]
            if s != s:
                continue
            is_peak = True
            for da in range(-1, 2):
                for db in range(-1, 2):
                    x = a + da
                    y = b + db
                    if 0 <= x < nv and 0 <= y < nu and surface[x, y] > s:
                        is_peak = False
            peak[a, b] = is_peak
    dv_out = np.zeros(k, dtype=np.int64)
    du_out = np.zeros(k, dtype=np.int64)
    score_out = np.zeros(k)
    count = 0
    while count < k:
        found = False
        best_s = 0.0
        best_dv = 0
        best_du = 0
        for a in range(nv):
            for b in range(nu):
                if peak[a, b] and (not found or better(
                        surface[a, b], a - mv, b - mu, best_s, best_dv, best_du)):
                    found = True
                    best_s = surface[a, b]
                    best_dv = a - mv
                    best_du = b - mu
        if not found or (count > 0 and not best_s > 0.0):
            break
        dv_out[count] = best_dv
        du_out[count] = best_du
        score_out[count] = best_s
        count += 1
        for a in range(nv):
            for b in range(nu):
                if peak[a, b] and np.hypot(a - mv - best_dv, b - mu - best_du) < separation:
                    peak[a, b] = False
    return count, dv_out, du_out, score_out
