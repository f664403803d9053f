"""Bilinear sampling and the rigid pose transform, one point at a time.

The arithmetic is written in exactly the order of :ref:`contract-numerics` (and of
:mod:`dtalign.reference`), so a sample here is bit-identical to the NumPy
specification's.
"""

from __future__ import annotations

import math

import numpy as np

from .._jit import inline_kernel, kernel
from .image import hypot_row


@inline_kernel
def clamp(x, hi):
    """``np.clip(x, 0, hi)`` for finite ``x``; NaN maps to 0.

    A NaN position (a diverged pose) must never become an index: the
    callers detect non-finite poses and refuse them, this only keeps the
    read in bounds until they do.
    """
    x = x if x > 0.0 else 0.0
    return x if x < hi else hi


@inline_kernel
def cell(h, w, v, u):
    """Corner rows/columns ``v0, u0, v1, u1`` and fractions ``fv, fu`` of the
    bilinear cell at ``(v, u)``, clamped to an ``h x w`` image."""
    v = clamp(v, h - 1.0)
    u = clamp(u, w - 1.0)
    v0 = int(math.floor(v))
    u0 = int(math.floor(u))
    return v0, u0, min(v0 + 1, h - 1), min(u0 + 1, w - 1), v - v0, u - u0


@inline_kernel
def blend(a, b, c, d, fv, fu):
    """Corners ``a = (v0, u0)``, ``b = (v0, u1)``, ``c = (v1, u0)``,
    ``d = (v1, u1)`` weighted in the order of :ref:`contract-numerics`."""
    return a * (1 - fv) * (1 - fu) + b * (1 - fv) * fu + c * fv * (1 - fu) + d * fv * fu


@inline_kernel
def bilinear(dt, v, u):
    """``dt`` sampled at ``(v, u)``, clamped to the image."""
    v0, u0, v1, u1, fv, fu = cell(dt.shape[0], dt.shape[1], v, u)
    return blend(dt[v0, u0], dt[v0, u1], dt[v1, u0], dt[v1, u1], fv, fu)


@kernel
def _bilinear_hypot(grad, v, u):
    """:func:`bilinear` of ``hypot(g_v, g_u)`` straight from the gradient vectors."""
    v0, u0, v1, u1, fv, fu = cell(grad.shape[0], grad.shape[1], v, u)
    return blend(
        np.hypot(grad[v0, u0, 0], grad[v0, u0, 1]), np.hypot(grad[v0, u1, 0], grad[v0, u1, 1]),
        np.hypot(grad[v1, u0, 0], grad[v1, u0, 1]), np.hypot(grad[v1, u1, 0], grad[v1, u1, 1]),
        fv, fu,
    )


#: Side of the square tiles in which the ridge polish forms magnitudes.
TILE = 16


@kernel
def fill_tiles(patch, tiles, grad, r0, c0, use_libm, pr0, pr1, pc0, pc1):
    """Form ``hypot(g_v, g_u)`` in every unfilled tile covering rows ``pr0..pr1``
    and columns ``pc0..pc1`` of the patch (out of line: it runs once per tile)."""
    for tr in range(pr0 // TILE, pr1 // TILE + 1):
        for tc in range(pc0 // TILE, pc1 // TILE + 1):
            if tiles[tr, tc]:
                continue
            lo = tc * TILE
            hi = min(lo + TILE, patch.shape[1])
            g_v = np.empty(hi - lo)
            g_u = np.empty(hi - lo)
            for r in range(tr * TILE, min(tr * TILE + TILE, patch.shape[0])):
                for j in range(lo, hi):
                    g_v[j - lo] = grad[r0 + r, c0 + j, 0]
                    g_u[j - lo] = grad[r0 + r, c0 + j, 1]
                hypot_row(g_v, g_u, patch[r, lo:hi], use_libm)
            tiles[tr, tc] = 1


@inline_kernel
def sample_magnitude(magnitude, patch, tiles, grad, r0, c0, use_libm, v, u):
    """Bilinear gradient magnitude at ``(v, u)``.

    With an empty ``grad``, this samples the magnitude image ``magnitude``.
    Else ``patch`` holds ``hypot(g_v, g_u)`` of ``grad`` over a box at
    ``(r0, c0)``, formed tile by tile (``tiles`` flags the filled ones) the
    first time a sample needs it: the profiles of a limb touch an annulus,
    a fifth of its bounding box. A sample whose cell lies inside the box is
    :func:`bilinear` of the patch at ``(v - r0, u - c0)``: bit-identical to
    sampling the whole magnitude image (an integer shift of ``v`` is exact,
    so the cell and its fractions are the same, and no clamping applies;
    the magnitudes are bit-identical to ``np.hypot``). Any other sample is
    formed from ``grad`` directly.
    """
    if grad.shape[0] == 0:
        return bilinear(magnitude, v, u)
    pv = v - r0
    pu = u - c0
    if 0.0 <= pv < patch.shape[0] - 1 and 0.0 <= pu < patch.shape[1] - 1:
        pr = int(pv)
        pc = int(pu)
        a = pr // TILE
        c = (pr + 1) // TILE
        b = pc // TILE
        d = (pc + 1) // TILE
        if not (tiles[a, b] & tiles[a, d] & tiles[c, b] & tiles[c, d]):
            fill_tiles(patch, tiles, grad, r0, c0, use_libm, pr, pr + 1, pc, pc + 1)
        return bilinear(patch, pv, pu)
    return _bilinear_hypot(grad, v, u)


@inline_kernel
def transform(v, u, dv, du, theta, cos_t, sin_t, pv, pu):
    """Rotate ``(v, u)`` about the pivot, then translate.

    ``cos_t``/``sin_t`` are ``cos(theta)``/``sin(theta)``, computed once per
    pose by the caller; at exactly ``theta == 0`` no trigonometry is used.
    """
    if theta == 0.0:
        return v + dv, u + du
    rv = pv + cos_t * (v - pv) - sin_t * (u - pu)
    ru = pu + sin_t * (v - pv) + cos_t * (u - pu)
    return rv + dv, ru + du


@kernel
def sample_many(dt, pts):
    """``dt`` sampled at every row of ``pts``."""
    n = pts.shape[0]
    out = np.empty(n)
    for i in range(n):
        out[i] = bilinear(dt, pts[i, 0], pts[i, 1])
    return out
