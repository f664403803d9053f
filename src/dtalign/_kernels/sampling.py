"""Bilinear sampling and the rigid pose transform, one point at a time.

The arithmetic is written in exactly the order of SPEC section 2 (and of
:mod:`dtalign.reference`), so a sample here is bit-identical to the NumPy
specification's.
"""

from __future__ import annotations

import math

import numpy as np

from .._jit import kernel


@kernel
def bilinear(dt, v, u):  # pragma: no cover - compiled
    """``dt`` sampled at ``(v, u)``, clamped to the image."""
    h, w = dt.shape
    v = min(max(v, 0.0), h - 1.0)
    u = min(max(u, 0.0), w - 1.0)
    v0 = int(math.floor(v))
    u0 = int(math.floor(u))
    v1 = min(v0 + 1, h - 1)
    u1 = min(u0 + 1, w - 1)
    fv = v - v0
    fu = u - u0
    return (
        dt[v0, u0] * (1 - fv) * (1 - fu)
        + dt[v0, u1] * (1 - fv) * fu
        + dt[v1, u0] * fv * (1 - fu)
        + dt[v1, u1] * fv * fu
    )


#: Slots of the direct-mapped magnitude cache of :func:`bilinear_magnitude`
#: (a power of two): 16384 slots hold the few thousand pixels a ridge polish
#: touches, in 256 kB that stay in L2.
MAGNITUDE_CACHE_SLOTS = 1 << 14


@kernel
def new_magnitude_cache():  # pragma: no cover - compiled
    """Empty ``(keys, values)`` cache for :func:`bilinear_magnitude`."""
    return np.full(MAGNITUDE_CACHE_SLOTS, -1, dtype=np.int64), np.empty(MAGNITUDE_CACHE_SLOTS)


@kernel
def _magnitude_at(field, iv, iu, keys, values):  # pragma: no cover - compiled
    if field.shape[2] == 1:
        return field[iv, iu, 0]
    # hypot is the expensive part of a ridge profile and neighbouring
    # samples share corners: remember each pixel's magnitude. Entries never
    # go stale (the field does not change during a call), so a collision
    # only costs a recomputation.
    index = iv * field.shape[1] + iu
    slot = index & (MAGNITUDE_CACHE_SLOTS - 1)
    if keys[slot] == index:
        return values[slot]
    m = math.hypot(field[iv, iu, 0], field[iv, iu, 1])
    keys[slot] = index
    values[slot] = m
    return m


@kernel
def bilinear_magnitude(field, v, u, keys, values):  # pragma: no cover - compiled
    """Bilinear sample of a magnitude image given as ``(H, W, C)``.

    ``C == 1``: the magnitude itself. ``C == 2``: a gradient-vector image,
    whose magnitude ``hypot(g_v, g_u)`` is formed (and cached in
    ``keys``/``values``) only at the pixels sampled, so the ridge polish
    never builds an image-sized magnitude array. The values are
    bit-identical to ``np.hypot`` of the whole image.
    """
    h = field.shape[0]
    w = field.shape[1]
    v = min(max(v, 0.0), h - 1.0)
    u = min(max(u, 0.0), w - 1.0)
    v0 = int(math.floor(v))
    u0 = int(math.floor(u))
    v1 = min(v0 + 1, h - 1)
    u1 = min(u0 + 1, w - 1)
    fv = v - v0
    fu = u - u0
    a = _magnitude_at(field, v0, u0, keys, values)
    b = _magnitude_at(field, v0, u1, keys, values)
    c = _magnitude_at(field, v1, u0, keys, values)
    d = _magnitude_at(field, v1, u1, keys, values)
    return a * (1 - fv) * (1 - fu) + b * (1 - fv) * fu + c * fv * (1 - fu) + d * fv * fu


@kernel
def transform(v, u, dv, du, theta, cos_t, sin_t, pv, pu):  # pragma: no cover - compiled
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
def sample_many(dt, pts):  # pragma: no cover - compiled
    """``dt`` sampled at every row of ``pts``."""
    n = pts.shape[0]
    out = np.empty(n)
    for i in range(n):
        out[i] = bilinear(dt, pts[i, 0], pts[i, 1])
    return out
