"""Coarse integer search over the sparse polyline support (SPEC section 2).

Instead of gathering edge pixels once per shift (what the reference does),
each polyline pixel scatters its contribution into the whole score table:
for a fixed row shift the pixel's overlap with every column shift is a
contiguous slice of one edge-mask row, so the inner loop is a plain
vectorisable add. The in-bounds counts are accumulated the same way with a
difference array. Scores are the same integer ratios as the reference, and
the argmax uses the same total order, so the result is identical.
"""

from __future__ import annotations

import numpy as np

from .._jit import kernel


@kernel
def rasterise(pts, h, w):  # pragma: no cover - compiled
    """Round half to even (``np.rint``) and mark in-image vertices."""
    mask = np.zeros((h, w), dtype=np.bool_)
    for i in range(pts.shape[0]):
        iv = np.rint(pts[i, 0])
        iu = np.rint(pts[i, 1])
        if iv >= 0 and iv < h and iu >= 0 and iu < w:
            mask[int(iv), int(iu)] = True
    return mask


@kernel
def support(mask):  # pragma: no cover - compiled
    """Row and column indices of the nonzero pixels of a uint8 mask, row-major."""
    h, w = mask.shape
    n = 0
    for a in range(h):
        row = mask[a]
        for b in range(w):
            n += row[b] != 0
    pv = np.empty(n, dtype=np.int64)
    pu = np.empty(n, dtype=np.int64)
    k = 0
    for a in range(h):
        row = mask[a]
        for b in range(w):
            if row[b] != 0:
                pv[k] = a
                pu[k] = b
                k += 1
    return pv, pu


@kernel
def overlap_and_counts(edge, pv, pu, mv, mu):  # pragma: no cover - compiled
    """Edge overlap and in-bounds counts of every shift in the window."""
    h, w = edge.shape
    nv = 2 * mv + 1
    nu = 2 * mu + 1
    overlap = np.zeros((nv, nu), dtype=np.int32)
    # counts[a, b] - counts[a, b-1] accumulated as a difference array.
    diff = np.zeros((nv, nu + 1), dtype=np.int32)
    for i in range(pv.shape[0]):
        r = pv[i]
        c = pu[i]
        dv_lo = max(-mv, -r)
        dv_hi = min(mv, h - 1 - r)
        du_lo = max(-mu, -c)
        du_hi = min(mu, w - 1 - c)
        if du_lo > du_hi:
            continue
        for dv in range(dv_lo, dv_hi + 1):
            row = edge[r + dv]
            acc = overlap[dv + mv]
            base = c + du_lo
            off = du_lo + mu
            for k in range(du_hi - du_lo + 1):
                acc[off + k] += row[base + k]
            diff[dv + mv, du_lo + mu] += 1
            diff[dv + mv, du_hi + mu + 1] -= 1
    counts = np.zeros((nv, nu), dtype=np.int32)
    for a in range(nv):
        run = 0
        for b in range(nu):
            run += diff[a, b]
            counts[a, b] = run
    return overlap, counts


@kernel
def best_shift(overlap, counts, mv, mu):  # pragma: no cover - compiled
    """Highest ``overlap / n``; ties go to the smallest ``(|dv|+|du|, |dv|, dv, du)``."""
    found = False
    best_score = 0.0
    best_dv = 0
    best_du = 0
    for a in range(2 * mv + 1):
        dv = a - mv
        for b in range(2 * mu + 1):
            n = counts[a, b]
            if n == 0:
                continue
            du = b - mu
            score = overlap[a, b] / n
            if not found or score > best_score:
                better = True
            elif score < best_score:
                better = False
            else:
                k1 = abs(dv) + abs(du)
                k0 = abs(best_dv) + abs(best_du)
                if k1 != k0:
                    better = k1 < k0
                elif abs(dv) != abs(best_dv):
                    better = abs(dv) < abs(best_dv)
                elif dv != best_dv:
                    better = dv < best_dv
                else:
                    better = du < best_du
            if better:
                found = True
                best_score = score
                best_dv = dv
                best_du = du
    return best_dv, best_du


@kernel
def coarse_search(edge, pv, pu, mv, mu):  # pragma: no cover - compiled
    """``(dv, du)`` of the best shift; ``(0, 0)`` when no shift keeps a pixel."""
    overlap, counts = overlap_and_counts(edge, pv, pu, mv, mu)
    return best_shift(overlap, counts, mv, mu)
