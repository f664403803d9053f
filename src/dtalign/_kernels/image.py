"""Compiled kernels of the image side (:ref:`contract-image`).

The whole pipeline (Gaussian smoothing, Sobel, magnitude, Canny thinning,
first pass of the distance transform) streams over the image one row at a
time, so the only image-sized arrays are the three outputs; a second,
bottom-up sweep finishes the distance transform in place. Every per-pixel
operation is written in the order SciPy performs it, so the results are
bit-identical to :mod:`dtalign.reference.image`, not merely close:

* ``scipy.ndimage.correlate1d`` (C ``NI_Correlate1D``) evaluates an odd,
  symmetric kernel as ``out = x[c]*w[c]`` followed by
  ``out += (x[c-k] + x[c+k]) * w[c-k]`` for ``k = r, r-1, ..., 1`` and an
  antisymmetric one as ``out = x[c]*w[c]`` then
  ``out += (x[c-k] - x[c+k]) * w[c-k]``. The kernels below keep that
  per-pixel order but loop over the taps outside and the pixels inside,
  so every inner loop is contiguous and vectorisable.
* ``np.hypot`` is glibc's ``hypot``; :func:`hypot_row` ports its non-FMA
  code path (a vectorisable loop, several times faster than one libm
  call per pixel) and defers to libm for the rare inputs glibc rescales.

The kernels assume valid, C-contiguous float64 input and never validate:
:mod:`dtalign.api.image` checks and converts once.
"""

from __future__ import annotations

import math

import numpy as np

from .._jit import inline_kernel, kernel

# glibc e_hypot.c (2.35+): inputs outside [TINY, LARGE] are rescaled there;
# here they go to libm itself, so only the common path is reproduced.
_HYPOT_LARGE = 2.0**511
_HYPOT_TINY = 2.0**-511
_HYPOT_EPS = 2.0**-54


@kernel
def _reflect(i, n):
    """Index of ``i`` in a line of ``n`` under SciPy's ``reflect`` mode.

    ``d c b a | a b c d | d c b a`` repeats with period ``2n``, which also
    covers a kernel radius longer than the line (SciPy extends it the same
    way, period after period).
    """
    period = 2 * n
    m = i % period  # Python semantics: non-negative
    if m >= n:
        m = period - 1 - m
    return m


@inline_kernel
def _add_tap_pair(out, wa, left_a, right_a, wb, left_b, right_b):
    """Two symmetric taps of a Gaussian pass into ``out``: tap ``a`` (weight
    ``wa``, the lines ``left_a`` and ``right_a``), then tap ``b``, per pixel in
    that order (one load and store of ``out`` for both)."""
    for j in range(out.shape[0]):
        v = out[j] + (left_a[j] + right_a[j]) * wa
        out[j] = v + (left_b[j] + right_b[j]) * wb


@inline_kernel
def _add_tap(out, wa, left_a, right_a):
    """One symmetric tap of a Gaussian pass into ``out``."""
    for j in range(out.shape[0]):
        out[j] += (left_a[j] + right_a[j]) * wa


@kernel
def _smooth_row(img, row, weights, acc, pad, s_ring, slot):
    """Gaussian-smoothed ``row`` into ``s_ring[slot, 1:W+1]``.

    The axis-0 pass accumulates whole input rows into ``acc`` (the exact
    per-pixel sum SciPy forms along a column), which is copied into ``pad``
    and reflect-extended for the axis-1 pass. ``weights`` is SciPy's
    reversed, odd-length, symmetric Gaussian kernel of radius ``r``.

    Both passes apply the taps two at a time in one inner loop: the
    per-pixel sequence of roundings is unchanged, but the accumulator is
    loaded and stored half as often.
    """
    h, w = img.shape
    r = (weights.size - 1) // 2
    w0 = weights[r]
    src = img[row]
    for j in range(w):
        acc[j] = src[j] * w0
    k = r
    while k >= 2:
        _add_tap_pair(acc, weights[r - k], img[_reflect(row - k, h)], img[_reflect(row + k, h)],
                      weights[r - k + 1], img[_reflect(row - k + 1, h)],
                      img[_reflect(row + k - 1, h)])
        k -= 2
    if k == 1:
        _add_tap(acc, weights[r - 1], img[_reflect(row - 1, h)], img[_reflect(row + 1, h)])
    pad[r : r + w] = acc
    for k in range(1, r + 1):
        pad[r - k] = pad[r + _reflect(-k, w)]
        pad[r + w - 1 + k] = pad[r + _reflect(w - 1 + k, w)]
    out = s_ring[slot, 1 : w + 1]
    for j in range(w):
        out[j] = acc[j] * w0
    k = r
    while k >= 2:
        _add_tap_pair(out, weights[r - k], pad[r - k : r - k + w], pad[r + k : r + k + w],
                      weights[r - k + 1], pad[r - k + 1 : r - k + 1 + w],
                      pad[r + k - 1 : r + k - 1 + w])
        k -= 2
    if k == 1:
        _add_tap(out, weights[r - 1], pad[r - 1 : r - 1 + w], pad[r + 1 : r + 1 + w])


@kernel
def _advance(img, row, weights, acc, pad, s_ring, e_ring):
    """Fill ring slot ``row % 3`` with smoothed row ``row`` and its u-derivative.

    ``s_ring`` rows carry one zero on each side (Sobel's ``cval = 0``);
    a row beyond the image is all zeros for the same reason.
    ``e = S[c]*0 + (S[c-1] - S[c+1]) * -1`` is the first (derivative) pass
    of ``sobel(axis=1)``; the ``*0`` term is kept because it fixes the sign
    of a zero result exactly as SciPy does.
    """
    h, w = img.shape
    slot = row % 3
    if row >= h:
        s_ring[slot, :] = 0.0
        e_ring[slot, :] = 0.0
        return
    _smooth_row(img, row, weights, acc, pad, s_ring, slot)
    s = s_ring[slot]
    e = e_ring[slot]
    for j in range(w):
        e[j] = s[1 + j] * 0.0 + (s[j] - s[2 + j]) * -1.0


@kernel
def _gradient_row(row, s_ring, e_ring, d, gv, gu):
    """Sobel ``g_v`` and ``g_u`` of ``row`` from the three ring slots around it.

    ``g_v``: derivative ``[-1, 0, 1]`` along v, then ``[1, 2, 1]`` along u
    (``d`` has a zero at each end: ``cval = 0``). ``g_u``: the derivative
    rows ``e`` combined ``[1, 2, 1]`` along v. Slot ``(row + 2) % 3`` holds
    row ``row - 1`` (zeros before the first row).
    """
    w = gv.size
    sp = s_ring[(row + 2) % 3]
    sc = s_ring[row % 3]
    sn = s_ring[(row + 1) % 3]
    for j in range(w):
        d[1 + j] = sc[1 + j] * 0.0 + (sp[1 + j] - sn[1 + j]) * -1.0
    for j in range(w):
        gv[j] = d[1 + j] * 2.0 + (d[j] + d[2 + j])
    ep = e_ring[(row + 2) % 3]
    ec = e_ring[row % 3]
    en = e_ring[(row + 1) % 3]
    for j in range(w):
        gu[j] = ec[j] * 2.0 + (ep[j] + en[j])


@kernel
def hypot_row(x, y, out, use_libm):
    """``out = hypot(x, y)`` bit-identical to glibc (and so to ``np.hypot``).

    glibc's non-FMA kernel (Borges, "An improved algorithm for hypot(a, b)")
    on the common range, in a branch-free loop LLVM vectorises; only if
    that loop met an input glibc would rescale (or a NaN/inf), a second
    pass hands those to libm itself.
    ``use_libm`` forces libm everywhere, for platforms whose ``np.hypot``
    is not this algorithm (the wrapper probes that once per process).
    """
    n = x.size
    if use_libm:
        for j in range(n):
            out[j] = np.hypot(x[j], y[j])
        return
    rare = False
    for j in range(n):
        ax = abs(x[j])
        ay = abs(y[j])
        if ax < ay:
            ax, ay = ay, ax
        h = math.sqrt(ax * ax + ay * ay)
        if h <= 2.0 * ay:
            delta = h - ay
            t1 = ax * (2.0 * delta - ax)
            t2 = (delta - 2.0 * (ax - ay)) * delta
        else:
            delta = h - ax
            t1 = 2.0 * delta * (ax - 2.0 * ay)
            t2 = (4.0 * delta - ay) * ay + delta * delta
        h -= (t1 + t2) / (2.0 * h)
        if ay <= ax * _HYPOT_EPS:  # also covers ay == 0 (glibc: ax + ay)
            h = ax + ay
        out[j] = h
        rare |= not (ax <= _HYPOT_LARGE and (ay >= _HYPOT_TINY or ay == 0.0))
    if rare:
        for j in range(n):
            ax = abs(x[j])
            ay = abs(y[j])
            if ax < ay:
                ax, ay = ay, ax
            if not (ax <= _HYPOT_LARGE and (ay >= _HYPOT_TINY or ay == 0.0)):
                out[j] = np.hypot(x[j], y[j])


@kernel
def _new_buffers(w, r):
    """Row scratch of the streaming sweep (``r``: Gaussian radius)."""
    acc = np.empty(w)
    pad = np.empty(w + 2 * r)
    s_ring = np.zeros((3, w + 2))
    e_ring = np.zeros((3, w))
    d = np.zeros(w + 2)
    return acc, pad, s_ring, e_ring, d


@kernel
def gradient_vu(img, weights, grad):
    """Sobel-of-Gaussian gradient of ``img`` into ``grad`` (H, W, 2).

    Parameters
    ----------
    img : (H, W) C-contiguous float64
    weights : 1-D float64, odd length
        SciPy's reversed Gaussian kernel (``[1.0]`` for no smoothing).
    grad : (H, W, 2) float64, written
    """
    h, w = img.shape
    r = (weights.size - 1) // 2
    acc, pad, s_ring, e_ring, d = _new_buffers(w, r)
    gv = np.empty(w)
    gu = np.empty(w)
    _advance(img, 0, weights, acc, pad, s_ring, e_ring)
    for i in range(h):
        _advance(img, i + 1, weights, acc, pad, s_ring, e_ring)
        _gradient_row(i, s_ring, e_ring, d, gv, gu)
        for j in range(w):
            grad[i, j, 0] = gv[j]
            grad[i, j, 1] = gu[j]


@kernel
def _suppress_row(mp, mc, mn, gv, gu, threshold, sector_k, cap, col, out):
    """Thin one row and run the downward pass of the column distances.

    ``mp``, ``mc``, ``mn``: magnitude of the rows above, at and below,
    each padded with one ``-inf`` per side (a row outside the image is all
    ``-inf``), so the eight neighbours load unconditionally and the sector
    choice is a select: the loop is branch-free and vectorises, which
    matters on textured frames where most pixels pass the threshold.
    ``col`` carries the distance to the nearest edge above in each column,
    capped at ``cap`` (exact integers in float64): 0 on an edge pixel,
    else ``min(col + 1, cap)``; it is copied to ``out``. Returns the number
    of edge pixels in the row.
    """
    w = gv.size
    count = 0
    for j in range(w):
        m = mc[1 + j]
        g_v = gv[j]
        g_u = gu[j]
        av = abs(g_v)
        au = abs(g_u)
        horizontal = au >= av * sector_k
        vertical = av >= au * sector_k
        main_diag = g_v * g_u >= 0.0
        left = mc[j]
        right = mc[2 + j]
        up = mp[1 + j]
        down = mn[1 + j]
        up_left = mp[j]
        up_right = mp[2 + j]
        down_left = mn[j]
        down_right = mn[2 + j]
        diag_a = down_right if main_diag else down_left
        diag_b = up_left if main_diag else up_right
        a = right if horizontal else (down if vertical else diag_a)
        b = left if horizontal else (up if vertical else diag_b)
        keep = (m > threshold) & (m >= a) & (m >= b)
        nxt = col[j] + 1.0
        if nxt > cap:
            nxt = cap
        if keep:
            nxt = 0.0
        col[j] = nxt
        out[j] = nxt
        count += keep
    return count


@kernel
def _row_edt(pos, height, n, s, t, ramp, icap, half_width, out):
    """Meijster's second phase on one row, over its ``n`` uncapped columns.

    ``pos[:n]`` (increasing) are the columns whose column distance
    ``height`` is below the cap. A capped column can only give a squared
    distance ``>= cap_sq``, i.e. beyond the clip, so leaving it out of the
    lower envelope changes no clipped value. The envelope of the parabolas
    ``(x - pos)**2 + height**2`` is built in exact integers (``s``: stack
    of site numbers, ``t``: first column of each site's segment);
    ``Sep`` is a floor division done in float64, exact because its
    numerator stays far below 2**52. A squared distance ``>= cap_sq`` maps
    to ``half_width``, anything else to ``min(sqrt, half_width)`` as
    ``np.minimum(distance_transform_edt(...), hw)``.
    """
    w = out.size
    cap_sq = float(icap * icap)
    q = 0
    s[0] = 0
    t[0] = 0
    for k in range(1, n):
        u = pos[k]
        hu2 = height[k] * height[k]
        while q >= 0:
            sq = s[q]
            dq = t[q] - pos[sq]
            du = t[q] - u
            if dq * dq + height[sq] * height[sq] > du * du + hu2:
                q -= 1
            else:
                break
        if q < 0:
            q = 0
            s[0] = k
        else:
            sq = s[q]
            p = pos[sq]
            num = u * u - p * p + hu2 - height[sq] * height[sq]
            sep = 1 + int(math.floor(float(num) / float(2 * (u - p))))
            if sep < w:
                q += 1
                s[q] = k
                t[q] = sep
    # Segment by segment (right to left) so the inner loop is branch-free
    # and vectorises; ``ramp[u] == u`` keeps it in exact float64 integers.
    # Only columns closer than ``cap`` to the segment's site can fall below
    # the clip: the rest of the segment is ``half_width`` outright.
    end = w
    for qq in range(q, -1, -1):
        sq = s[qq]
        start = t[qq]
        # [start, lo) and [hi, end) are >= cap from the site (clamped: a
        # segment may lie entirely on one side of its site).
        lo = min(max(start, pos[sq] - icap + 1), end)
        hi = max(min(end, pos[sq] + icap), lo)
        for u in range(start, lo):
            out[u] = half_width
        for u in range(hi, end):
            out[u] = half_width
        p = float(pos[sq])
        h2 = float(height[sq] * height[sq])
        for u in range(lo, hi):
            du = ramp[u] - p
            dsq = du * du + h2
            dist = math.sqrt(dsq)
            if dist > half_width:
                dist = half_width
            out[u] = half_width if dsq >= cap_sq else dist
        end = start


@kernel
def _finish_dt(dt, cap, half_width):
    """Upward pass of the column distances fused with the row transform.

    Sweeps bottom-up keeping the finished column distances of the row
    below in ``below`` (``dt`` rows are overwritten by final values as the
    sweep goes). A row whose column distances all reached ``cap`` is
    beyond the clip everywhere: filled with ``half_width`` directly.
    """
    h, w = dt.shape
    below = np.full(w, cap)
    pos = np.empty(w, dtype=np.int64)
    height = np.empty(w, dtype=np.int64)
    s = np.empty(w, dtype=np.int64)
    t = np.empty(w, dtype=np.int64)
    ramp = np.arange(w).astype(np.float64)
    icap = int(cap)
    for row in range(h - 1, -1, -1):
        cur = dt[row]
        for j in range(w):
            b = below[j] + 1.0
            v = cur[j]
            below[j] = b if b < v else v
        n = 0
        for j in range(w):
            if below[j] < cap:
                pos[n] = j
                height[n] = int(below[j])
                n += 1
        if n == 0:
            cur[:] = half_width
        else:
            _row_edt(pos, height, n, s, t, ramp, icap, half_width, cur)


@kernel
def _thin_row(row, m_ring, gv, gu, threshold, sector_k, cap, col, dt):
    """:func:`_suppress_row` on ``row`` from the three-row rings."""
    return _suppress_row(
        m_ring[(row + 2) % 3],
        m_ring[row % 3],
        m_ring[(row + 1) % 3],
        gv[row % 3],
        gu[row % 3],
        threshold,
        sector_k,
        cap,
        col,
        dt[row],
    )


@kernel
def all_derivatives(img, weights, threshold, sector_k, half_width, cap, use_libm, grad, mag, dt):
    """Gradient, magnitude and clipped edge DT of ``img`` in two sweeps.

    Parameters
    ----------
    img : (H, W) C-contiguous float64
    weights : 1-D float64, odd length
        SciPy's reversed Gaussian kernel (``[1.0]`` for no smoothing).
    threshold : float
        Strict lower bound of an edge pixel's magnitude.
    sector_k : float
        ``1 + sqrt(2)``, the sector test of the thinning.
    half_width : float
        Clip of the distance transform.
    cap : float
        Integer-valued cap of the column distances, ``> half_width`` or
        ``H + W`` (beyond every in-image distance); see the wrapper.
    use_libm : bool
        Passed to :func:`hypot_row`.
    grad, mag, dt : float64 outputs of shapes (H, W, 2), (H, W), (H, W)

    Returns
    -------
    bool
        Whether any edge pixel was found (``dt`` is all ``half_width`` if not).
    """
    h, w = img.shape
    acc, pad, s_ring, e_ring, d = _new_buffers(w, (weights.size - 1) // 2)
    # Rings of three rows (slot = row % 3): gradient components and the
    # -inf-padded magnitude that the thinning, one row behind, reads.
    gv = np.empty((3, w))
    gu = np.empty((3, w))
    m_ring = np.full((3, w + 2), -np.inf)
    col = np.full(w, cap)
    edges = 0
    _advance(img, 0, weights, acc, pad, s_ring, e_ring)
    for i in range(h):
        slot = i % 3
        _advance(img, i + 1, weights, acc, pad, s_ring, e_ring)
        gv_i = gv[slot]
        gu_i = gu[slot]
        _gradient_row(i, s_ring, e_ring, d, gv_i, gu_i)
        for j in range(w):
            grad[i, j, 0] = gv_i[j]
            grad[i, j, 1] = gu_i[j]
        m_i = m_ring[slot, 1 : w + 1]
        hypot_row(gv_i, gu_i, m_i, use_libm)
        mag[i, :] = m_i
        if i >= 1:
            edges += _thin_row(i - 1, m_ring, gv, gu, threshold, sector_k, cap, col, dt)
    m_ring[h % 3, :] = -np.inf  # the row below the last one
    edges += _thin_row(h - 1, m_ring, gv, gu, threshold, sector_k, cap, col, dt)
    if edges == 0:
        dt[:, :] = half_width
        return False
    _finish_dt(dt, cap, half_width)
    return True
