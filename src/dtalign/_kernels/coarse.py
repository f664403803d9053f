"""Coarse integer search over the sparse polyline support (:ref:`contract-numerics`).

Instead of gathering edge pixels once per shift (what the reference does),
each polyline pixel scatters its contribution into the whole score table.
For windows up to :data:`DENSE_MAX_COLUMNS` shifts wide, it adds the edge
row under its window to a row of counters, 16 columns per vector add
(:func:`overlap_dense`); for wider ones it visits only the edge pixels that
can meet it (:func:`overlap_sparse`: work proportional to the pixel pairs
within the window). Masks are scanned a word at a time (:mod:`.lanes.bits`).
Scores are the same integer ratios as the reference, and the argmax uses
the same total order, so the result is identical.
"""

from __future__ import annotations

import numpy as np

from .._jit import inline_kernel, kernel
from .lanes import fill
from .pairwise import numpy_sum


@kernel
def rasterise(pts, h, w):
    """Round half to even (``np.rint``) and mark in-image vertices."""
    mask = np.zeros((h, w), dtype=np.bool_)
    for i in range(pts.shape[0]):
        iv = np.rint(pts[i, 0])
        iu = np.rint(pts[i, 1])
        if iv >= 0 and iv < h and iu >= 0 and iu < w:
            mask[int(iv), int(iu)] = True
    return mask


#: Pixels the first scan of :func:`nonzero_in_box` has room for.
FIRST_BUFFER = 1 << 13


@kernel
def nonzero_in_box(flat, words, width, r_lo, r_hi, c_lo, c_hi):
    """Row-major ``(rows, cols)`` of the nonzero bytes in rows ``r_lo..r_hi``
    and columns ``c_lo..c_hi`` of a flattened uint8 mask (typically sparse).

    Masks are sparse: the scan fills a buffer sized for a few thousand
    pixels, and only a denser mask (more pixels than that) is scanned a
    second time into a buffer of the exact size. No allocation scales with
    the box, which keeps threads out of the allocator. A box at least a
    quarter of the image wide is scanned as one contiguous run of whole
    rows, its pixels outside the columns dropped afterwards: long runs scan
    fastest, and masks are sparse outside the box too.
    """
    whole_rows = 4 * (c_hi - c_lo + 1) >= width
    n_runs = 1 if whole_rows else r_hi - r_lo + 1
    span = (r_hi - r_lo + 1) * width if whole_rows else c_hi - c_lo + 1
    first = r_lo * width + (0 if whole_rows else c_lo)
    step = 0 if whole_rows else width
    index = np.empty(min(n_runs * span, FIRST_BUFFER), dtype=np.int64)
    run_end = np.empty(n_runs, dtype=np.int64)
    for _attempt in range(2):  # the second pass only for a dense mask
        k = 0
        for run in range(n_runs):
            k = fill(flat, words, first + run * step, first + run * step + span, index, k)
            run_end[run] = k
        if k <= index.shape[0]:
            break
        index = np.empty(k, dtype=np.int64)
    rows = np.empty(k, dtype=np.int64)
    cols = np.empty(k, dtype=np.int64)
    n = 0
    if whole_rows:
        # indices ascend, so the row only ever steps forward (no division)
        r = r_lo
        row_start = r_lo * width
        for j in range(k):
            while index[j] >= row_start + width:
                r += 1
                row_start += width
            c = index[j] - row_start
            if c_lo <= c <= c_hi:
                rows[n] = r
                cols[n] = c
                n += 1
        return rows[:n], cols[:n]
    j = 0
    for run in range(n_runs):
        while j < run_end[run]:
            rows[j] = r_lo + run
            cols[j] = index[j] - (r_lo + run) * width
            j += 1
    return rows, cols


@kernel
def _first_at_least(cols, lo, hi, value):
    """First index in ``cols[lo:hi]`` (sorted) with ``cols[j] >= value``."""
    while lo < hi:
        mid = (lo + hi) // 2
        if cols[mid] < value:
            lo = mid + 1
        else:
            hi = mid
    return lo


@kernel
def row_starts(e_rows, h):
    """CSR row index of row-major pixels: row ``r`` is ``[starts[r], starts[r + 1])``."""
    row_start = np.zeros(h + 1, dtype=np.int64)
    for j in range(e_rows.shape[0]):
        row_start[e_rows[j] + 1] += 1
    for r in range(h):
        row_start[r + 1] += row_start[r]
    return row_start


@kernel
def edge_index(edge):
    """The edge pixels of the whole mask by row: ``(row_start, cols)`` (CSR).

    What a batch of polylines against one edge mask shares: one scan of the
    mask instead of one scan of a box per polyline.
    """
    h, w = edge.shape
    flat, words = flat_words(edge)
    e_rows, e_cols = nonzero_in_box(flat, words, w, 0, h - 1, 0, w - 1)
    return row_starts(e_rows, h), e_cols


@inline_kernel
def shifts_inside(r, c, h, w, mv, mu):
    """The shifts that keep pixel ``(r, c)`` in an ``h x w`` image:
    ``(dv_lo, dv_hi, du_lo, du_hi)``, inclusive, within the window."""
    return max(-mv, -r), min(mv, h - 1 - r), max(-mu, -c), min(mu, w - 1 - c)


@kernel
def in_image_counts(pv, pu, h, w, mv, mu):
    """How many polyline pixels each shift keeps inside the image, ``(nv, nu)``;
    empty when the window never pushes a pixel off it (every shift keeps all).

    Accumulated in a difference array: per pixel and row shift, one range of
    column shifts.
    """
    nv = 2 * mv + 1
    nu = 2 * mu + 1
    if pv.min() >= mv and pv.max() + mv <= h - 1 and pu.min() >= mu and pu.max() + mu <= w - 1:
        return np.zeros((0, 0), dtype=np.int64)
    diff = np.zeros((nv, nu + 1), dtype=np.int64)
    for i in range(pv.shape[0]):
        dv_lo, dv_hi, du_lo, du_hi = shifts_inside(pv[i], pu[i], h, w, mv, mu)
        for dv in range(dv_lo, dv_hi + 1):
            diff[dv + mv, du_lo + mu] += 1
            diff[dv + mv, du_hi + mu + 1] -= 1
    counts = np.empty((nv, nu), dtype=np.int64)
    for a in range(nv):
        run = 0
        for b in range(nu):
            run += diff[a, b]
            counts[a, b] = run
    return counts


@kernel
def overlap_sparse(pv, pu, row_start, e_cols, h, w, mv, mu):
    """Edge overlap of every shift in the window, ``(nv, nu)``.

    The polyline pixels come as row-major ``(pv, pu)``, the edge pixels by
    row (:func:`row_starts`; rows may hold pixels outside the window too:
    they are skipped). Both sets are sparse, so the overlap is a sparse
    correlation: for each polyline pixel and row shift, only the edge pixels
    of that row within the column window are visited (found by binary search
    in the row's sorted columns).
    """
    nv = 2 * mv + 1
    nu = 2 * mu + 1
    overlap = np.zeros((nv, nu), dtype=np.int64)
    for i in range(pv.shape[0]):
        r = pv[i]
        c = pu[i]
        dv_lo, dv_hi, du_lo, du_hi = shifts_inside(r, c, h, w, mv, mu)
        for dv in range(dv_lo, dv_hi + 1):
            a = dv + mv
            lo = row_start[r + dv]
            hi = row_start[r + dv + 1]
            j = _first_at_least(e_cols, lo, hi, c + du_lo) if hi - lo > 8 else lo
            while j < hi:
                col = e_cols[j]
                if col > c + du_hi:
                    break
                if col >= c + du_lo:
                    overlap[a, col - c + mu] += 1
                j += 1
    return overlap


#: Column shifts one vector add covers in :func:`overlap_dense` (int16 lanes
#: of a 256-bit register); its window rows are padded to a multiple of this.
LANES16 = 16
#: :func:`overlap_dense` serves windows up to this many column shifts, and
#: polylines of at most this many pixels (int16 counts cannot overflow).
DENSE_MAX_COLUMNS = 128
DENSE_MAX_PIXELS = 32767


@inline_kernel
def dense_ok(n_pixels, mu):
    """Whether :func:`overlap_dense` serves this search (else :func:`overlap_sparse`).

    The dense path costs in proportion to the window's width (a row of
    counters per column shift), the sparse one to the edge pixels within
    the window, plus the scan of the edge mask that indexes them; on the
    benchmark's limb the dense path is the faster at +-30 and +-50 px
    (docs/benchmarks.rst, "What was tried"), hence DENSE_MAX_COLUMNS.
    """
    return n_pixels <= DENSE_MAX_PIXELS and 2 * mu + 1 <= DENSE_MAX_COLUMNS


@kernel
def overlap_dense(pv, pu, flat, h, w, mv, mu):
    """:func:`overlap_sparse` computed from the edge mask's bytes ``flat``.

    For each polyline pixel and row shift, the edge row under the window
    (one byte per column shift) is added to that row of int16 counters, 16
    at a time: no branch per edge pixel, no index of the edge mask. A pixel
    whose padded window would leave its image row is added column by column
    over its in-image shifts instead.
    """
    nv = 2 * mv + 1
    nu = 2 * mu + 1
    width = (nu + LANES16 - 1) // LANES16 * LANES16
    acc = np.zeros(nv * width, dtype=np.int16)
    for i in range(pv.shape[0]):
        r = pv[i]
        c = pu[i]
        left = c - mu
        dv_lo, dv_hi, du_lo, du_hi = shifts_inside(r, c, h, w, mv, mu)
        for dv in range(dv_lo, dv_hi + 1):
            row = np.uint64((dv + mv) * width)
            if left >= 0 and left + width <= w:  # the padded window lies in the row
                src = np.uint64((r + dv) * w + left)
                for k in range(np.uint64(width)):
                    acc[row + k] = np.int16(acc[row + k] + np.int16(flat[src + k]))
            else:
                for b in range(du_lo + mu, du_hi + mu + 1):
                    acc[row + np.uint64(b)] += flat[(r + dv) * w + left + b]
    overlap = np.empty((nv, nu), dtype=np.int64)
    for a in range(nv):
        for b in range(nu):
            overlap[a, b] = acc[a * width + b]
    return overlap


@inline_kernel
def better(score, dv, du, best_score, best_dv, best_du):
    """The contract's order of shifts (:ref:`contract-numerics`): a higher
    score, or an equal one with the smaller ``(|dv| + |du|, |dv|, dv, du)``.
    A NaN score never wins."""
    if score > best_score:
        return True
    if score != best_score:
        return False
    k1 = abs(dv) + abs(du)
    k0 = abs(best_dv) + abs(best_du)
    if k1 != k0:
        return k1 < k0
    if abs(dv) != abs(best_dv):
        return abs(dv) < abs(best_dv)
    if dv != best_dv:
        return dv < best_dv
    return du < best_du


@inline_kernel
def keep_better(best, score, dv, du):
    """The better of ``best``, a ``(dv, du, score)``, and the shift ``(dv, du, score)``
    in the order of :func:`better` (``best`` on a tie of all three)."""
    if better(score, dv, du, best[2], best[0], best[1]):
        return dv, du, score
    return best


@kernel
def best_scored(overlap, counts, n_pixels, mv, mu, min_support):
    """``(dv, du, score)`` of the best shift with ``n >= 1`` and ``n >= min_support``
    in-image pixels; ``score`` is ``overlap / n``, and -1 when none is eligible.

    An empty ``counts`` means every shift keeps all ``n_pixels`` inside (and
    so is eligible): the overlap alone then orders the scores (dividing by
    one positive ``n`` keeps their order and their ties), so only the
    winner's score is divided.
    """
    uniform = counts.shape[0] == 0
    best = (0, 0, -1.0)
    for a in range(2 * mv + 1):
        dv = a - mv
        for b in range(2 * mu + 1):
            n = n_pixels if uniform else counts[a, b]
            if n == 0 or n < min_support:
                continue
            score = float(overlap[a, b]) if uniform else overlap[a, b] / n
            best = keep_better(best, score, dv, b - mu)
    best_dv, best_du, best_score = best
    if uniform and best_score >= 0.0:
        best_score = best_score / n_pixels
    return best_dv, best_du, best_score


@kernel
def support_of_vertices(pts, h, w):
    """Row-major unique ``(rows, cols)`` of the pixels :func:`rasterise` would set."""
    flat = np.empty(pts.shape[0], dtype=np.int64)
    n = 0
    for i in range(pts.shape[0]):
        iv = np.rint(pts[i, 0])
        iu = np.rint(pts[i, 1])
        if iv >= 0 and iv < h and iu >= 0 and iu < w:
            flat[n] = int(iv) * w + int(iu)
            n += 1
    flat = np.unique(flat[:n])
    rows = np.empty(flat.shape[0], dtype=np.int64)
    cols = np.empty(flat.shape[0], dtype=np.int64)
    for j in range(flat.shape[0]):
        rows[j] = flat[j] // w
        cols[j] = flat[j] - rows[j] * w
    return rows, cols


@kernel
def flat_words(mask):
    """A C-contiguous bool mask as flat uint8 bytes and a uint64 view of its
    whole words (views, made here: two arrays fewer to pass from Python)."""
    flat = mask.reshape(-1).view(np.uint8)
    return flat, flat[: flat.shape[0] // 8 * 8].view(np.uint64)


@kernel
def search_support(edge, pv, pu, mv, mu):
    """Best shift for a polyline support given as row-major ``(pv, pu)``."""
    dv, du, _ = search_support_scored(edge, pv, pu, mv, mu, 0.0)
    return dv, du


@kernel
def overlap_tables(edge, pv, pu, mv, mu):
    """``(overlap, counts)`` of every shift for a row-major support ``(pv, pu)``
    (``counts`` empty when every shift keeps every pixel inside).

    Dense correlation (:func:`overlap_dense`) where it serves; else only the
    edge pixels within the window around the polyline's bounding box can
    score, so only that box of the edge mask is scanned.
    """
    h, w = edge.shape
    edge_flat, edge_words = flat_words(edge)
    if dense_ok(pv.shape[0], mu):
        overlap = overlap_dense(pv, pu, edge_flat, h, w, mv, mu)
    else:
        e_rows, e_cols = nonzero_in_box(
            edge_flat, edge_words, w, max(pv[0] - mv, 0), min(pv[-1] + mv, h - 1),
            max(pu.min() - mu, 0), min(pu.max() + mu, w - 1),
        )
        overlap = overlap_sparse(pv, pu, row_starts(e_rows, h), e_cols, h, w, mv, mu)
    return overlap, in_image_counts(pv, pu, h, w, mv, mu)


@kernel
def search_support_scored(edge, pv, pu, mv, mu, min_support):
    """``(dv, du, score)`` of the best shift for a row-major support ``(pv, pu)``."""
    if pv.shape[0] == 0:
        return 0, 0, 0.0
    overlap, counts = overlap_tables(edge, pv, pu, mv, mu)
    return best_scored(overlap, counts, pv.shape[0], mv, mu, min_support)


@kernel
def overlap_surface(edge, pv, pu, mv, mu, min_support):
    """Every shift's score ``overlap / n`` as :func:`best_scored` forms it,
    ``(2 mv + 1, 2 mu + 1)``; NaN where the shift is not a candidate."""
    if pv.shape[0] == 0:
        return np.full((2 * mv + 1, 2 * mu + 1), np.nan)
    overlap, counts = overlap_tables(edge, pv, pu, mv, mu)
    return scored_surface(overlap, counts, pv, mv, mu, min_support)


@kernel
def scored_surface(overlap, counts, pv, mv, mu, min_support):
    """:func:`overlap_surface` of the tables :func:`overlap_tables` made."""
    nv = 2 * mv + 1
    nu = 2 * mu + 1
    surface = np.full((nv, nu), np.nan)
    uniform = counts.shape[0] == 0
    for a in range(nv):
        for b in range(nu):
            n = pv.shape[0] if uniform else counts[a, b]
            if n > 0 and n >= min_support:
                surface[a, b] = overlap[a, b] / n
    return surface


@kernel
def float_overlap_search(values, pv, pu, mv, mu, min_support):
    """:func:`search_support_scored` for an edge mask of arbitrary float values.

    The overlap is then the float64 sum of the values under the in-image
    polyline pixels, in row-major pixel order, as NumPy's pairwise sum adds
    them (the reference's ``values[rows, cols].sum()``): per row shift, the
    values of every column shift are gathered in that order, then summed.
    """
    h, w = values.shape
    m = pv.shape[0]
    nu = 2 * mu + 1
    gathered = np.empty((nu, m))
    counts = np.zeros(nu, dtype=np.int64)
    best = (0, 0, -1.0)
    for dv in range(-mv, mv + 1):
        counts[:] = 0
        for i in range(m):
            r = pv[i] + dv
            if r < 0 or r >= h:
                continue
            for b in range(nu):
                c = pu[i] + b - mu
                if c >= 0 and c < w:
                    gathered[b, counts[b]] = values[r, c]
                    counts[b] += 1
        for b in range(nu):
            n = counts[b]
            if n == 0 or n < min_support:
                continue
            best = keep_better(best, numpy_sum(gathered[b], n) / n, dv, b - mu)
    return best


@kernel
def search_index_scored(row_start, e_cols, pv, pu, h, w, mv, mu, min_support):
    """Best shift ``(dv, du, score)`` for a polyline support against edge pixels
    indexed by row (:func:`row_starts`), with a support floor."""
    if pv.shape[0] == 0:
        return 0, 0, 0.0
    overlap = overlap_sparse(pv, pu, row_start, e_cols, h, w, mv, mu)
    return best_scored(overlap, in_image_counts(pv, pu, h, w, mv, mu), pv.shape[0], mv, mu,
                       min_support)


@kernel
def polyline_support(poly):
    """Row-major ``(rows, cols)`` of a C-contiguous bool polyline mask's pixels."""
    h, w = poly.shape
    poly_flat, poly_words = flat_words(poly)
    return nonzero_in_box(poly_flat, poly_words, w, 0, h - 1, 0, w - 1)


@kernel
def coarse_search_scored(edge, poly, mv, mu, fraction):
    """:ref:`contract-coarse-scored`: ``(dv, du, score)``, ``score`` before the ``max(score, 0)``.

    ``edge`` and ``poly`` are bool masks of the same, non-empty shape.
    """
    pv, pu = polyline_support(poly)
    if pv.shape[0] == 0:
        return 0, 0, 0.0
    return search_support_scored(edge, pv, pu, mv, mu, fraction * pv.shape[0])


@kernel
def coarse_search_values(values, poly, mv, mu, fraction):
    """:func:`coarse_search_scored` for an edge mask of float64 values (summed)."""
    pv, pu = polyline_support(poly)
    if pv.shape[0] == 0:
        return 0, 0, 0.0
    return float_overlap_search(values, pv, pu, mv, mu, fraction * pv.shape[0])
