"""The polarity-weighted coarse search (:ref:`contract-polarity-search`).

Each vertex scores ``max(n_hat . g / |g|, 0)`` where its shifted base pixel
is an edge pixel, and 0 elsewhere; a shift's score is NumPy's pairwise sum
of those weights in vertex order over the in-bounds vertices, divided by
their count. Two exact ways to the same sums:

* every vertex inside the image under every shift of the window (the
  usual case: a limb well inside the frame): the in-bounds set is all
  vertices for every shift, so a vertex's place in NumPy's summation tree
  is fixed. Only edge pixels add anything (adding 0.0 leaves a sum
  unchanged), so each vertex visits just the edge pixels of its window
  (a CSR index of the edge mask) and adds its weight to that shift's
  accumulator at its fixed place in the tree (:func:`_sparse_scores`);
* otherwise the in-bounds set changes with the shift: for each row shift
  the weights of every column shift are gathered in vertex order and
  summed (:func:`_dense_scores`).
"""

from __future__ import annotations

import numpy as np

from .._jit import inline_kernel, kernel
from .coarse import _first_at_least, flat_words, keep_better, nonzero_in_box, row_starts
from .pairwise import BLOCK, UNROLL, numpy_sum


@inline_kernel
def _weight(edge, grad, r, c, nhv, nhu):
    """A vertex's weight at pixel ``(r, c)``: NaN stays NaN, as ``np.maximum``."""
    if not edge[r, c]:
        return 0.0
    gv = grad[r, c, 0]
    gu = grad[r, c, 1]
    s = np.hypot(gv, gu)
    if s == 0.0:
        s = 1.0
    cos = (nhv * gv + nhu * gu) / s
    return 0.0 if cos <= 0.0 else cos


@kernel
def _dense_scores(edge, grad, bv, bu, nhv, nhu, mv, mu, min_support, surface):
    """The general scan: per row shift, each column shift's in-bounds weights
    gathered in vertex order, then summed. Each candidate's score is also
    written to ``surface`` unless it is empty."""
    h, w = edge.shape
    n = bv.shape[0]
    nu = 2 * mu + 1
    weights = np.empty((nu, n))
    counts = np.zeros(nu, dtype=np.int64)
    best = (0, 0, -1.0)
    for dv in range(-mv, mv + 1):
        counts[:] = 0
        for i in range(n):
            sv = bv[i] + dv
            if not (sv >= 0.0 and sv < h):
                continue
            r = int(sv)
            for b in range(nu):
                su = bu[i] + (b - mu)
                if su >= 0.0 and su < w:
                    weights[b, counts[b]] = _weight(edge, grad, r, int(su), nhv[i], nhu[i])
                    counts[b] += 1
        for b in range(nu):
            k = counts[b]
            if k == 0 or k < min_support:
                continue
            score = numpy_sum(weights[b], k) / k
            if surface.shape[0] > 0:
                surface[dv + mv, b] = score
            best = keep_better(best, score, dv, b - mu)
    return best


@kernel
def _tree_plan(n):
    """NumPy's summation tree of ``n`` values (:mod:`.pairwise`) as data.

    Returns the leaf blocks ``(start, length)`` left to right and the tree
    in postfix form (``k >= 0``: push leaf ``k``; ``-1``: add the two on top).
    """
    starts = np.empty(max(n // 32, 1) + 2, dtype=np.int64)
    lengths = np.empty_like(starts)
    program = np.empty(2 * starts.shape[0], dtype=np.int64)
    stack_start = np.empty(64, dtype=np.int64)
    stack_len = np.empty(64, dtype=np.int64)
    stack_state = np.zeros(64, dtype=np.int64)
    top = 0
    stack_start[0] = 0
    stack_len[0] = n
    leaves = 0
    ops = 0
    while top >= 0:
        s = stack_start[top]
        m = stack_len[top]
        if m <= BLOCK:
            starts[leaves] = s
            lengths[leaves] = m
            program[ops] = leaves
            leaves += 1
            ops += 1
            top -= 1
        elif stack_state[top] == 0:  # expand: left child first
            stack_state[top] = 1
            half = m // 2
            half -= half % UNROLL
            top += 1
            stack_start[top] = s
            stack_len[top] = half
            stack_state[top] = 0
        elif stack_state[top] == 1:  # left done: the right child
            stack_state[top] = 2
            half = m // 2
            half -= half % UNROLL
            top += 1
            stack_start[top] = s + half
            stack_len[top] = m - half
            stack_state[top] = 0
        else:  # both done: add them
            program[ops] = -1
            ops += 1
            stack_state[top] = 0
            top -= 1
    return starts[:leaves], lengths[:leaves], program[:ops]


@kernel
def _edge_gradients(grad, row_start, e_cols, r_lo, r_hi):
    """``(g_v, g_u, s)`` of every indexed edge pixel, ``s = hypot(g)`` (1 where
    it is 0): formed once per pixel, not once per vertex that meets it."""
    m = e_cols.shape[0]
    gv = np.empty(m)
    gu = np.empty(m)
    norm = np.empty(m)
    for r in range(r_lo, r_hi + 1):
        for j in range(row_start[r], row_start[r + 1]):
            a = grad[r, e_cols[j], 0]
            b = grad[r, e_cols[j], 1]
            gv[j] = a
            gu[j] = b
            s = np.hypot(a, b)
            norm[j] = 1.0 if s == 0.0 else s
    return gv, gu, norm


@kernel
def _sparse_scores(grad, edge, row_start, e_cols, bv, bu, nhv, nhu, mv, mu, surface):
    """Scores when every vertex stays inside the image under every shift.

    Vertex ``i`` sits at place ``i`` of NumPy's tree for every shift: in its
    leaf block's accumulator ``(i - start) % 8``, or in the block's
    remainder, added after the accumulators are combined. Each shift keeps
    those slots; a vertex adds its weight only where it meets an edge pixel,
    in vertex order, as the dense sum adds it (the zeros it skips change
    nothing).
    """
    n = bv.shape[0]
    nv = 2 * mv + 1
    nu = 2 * mu + 1
    starts, lengths, program = _tree_plan(n)
    n_leaves = starts.shape[0]
    leaf_of = np.empty(n, dtype=np.int64)
    slot_of = np.empty(n, dtype=np.int64)  # 0..7 accumulators, 8..14 remainder
    for k in range(n_leaves):
        s = starts[k]
        m = lengths[k]
        limit = m - m % UNROLL if m >= UNROLL else 0
        for j in range(m):
            leaf_of[s + j] = k
            slot_of[s + j] = j % UNROLL if j < limit else UNROLL + (j - limit)
    slots = 2 * UNROLL - 1
    acc = np.zeros((nu, n_leaves, slots))
    leaf_sum = np.empty(n_leaves)
    e_gv, e_gu, e_norm = _edge_gradients(
        grad, row_start, e_cols, int(bv.min()) - mv, int(bv.max()) + mv
    )
    stack = np.empty(n_leaves + 1)
    best = (0, 0, -1.0)
    for a in range(nv):
        dv = a - mv
        acc[:] = 0.0
        for i in range(n):
            r = int(bv[i]) + dv
            c_lo = int(bu[i]) - mu
            lo = row_start[r]
            hi = row_start[r + 1]
            j = _first_at_least(e_cols, lo, hi, c_lo) if hi - lo > 8 else lo
            while j < hi:
                col = e_cols[j]
                j += 1
                if col < c_lo:
                    continue
                if col > c_lo + 2 * mu:
                    break
                cos = (nhv[i] * e_gv[j - 1] + nhu[i] * e_gu[j - 1]) / e_norm[j - 1]
                wgt = 0.0 if cos <= 0.0 else cos  # as _weight: NaN stays NaN
                if wgt != 0.0 or wgt != wgt:
                    acc[col - c_lo, leaf_of[i], slot_of[i]] += wgt
        for b in range(nu):
            for k in range(n_leaves):
                m = lengths[k]
                x = acc[b, k]
                if m < UNROLL:  # a whole polyline of fewer than 8: left to right from 0
                    total = 0.0
                    for j in range(m):
                        total += x[UNROLL + j]
                    leaf_sum[k] = total
                    continue
                total = ((x[0] + x[1]) + (x[2] + x[3])) + ((x[4] + x[5]) + (x[6] + x[7]))
                for j in range(m % UNROLL):
                    total += x[UNROLL + j]
                leaf_sum[k] = total
            top = 0
            for op in program:
                if op >= 0:
                    stack[top] = leaf_sum[op]
                    top += 1
                else:
                    top -= 1
                    stack[top - 1] = stack[top - 1] + stack[top]
            score = (0.0 + stack[0]) / n
            if surface.shape[0] > 0:
                surface[a, b] = score
            best = keep_better(best, score, dv, b - mu)
    return best


@kernel
def polarity_search(edge, grad, pts, nrm, mv, mu, min_support):
    """``(dv, du, best_score)``; ``best_score`` is -1 when no shift is eligible.

    ``edge`` is a C-contiguous bool mask, ``grad`` its ``(H, W, 2)``
    gradient, ``pts``/``nrm`` finite ``(N, 2)`` with ``N > 0``; ``mv`` and
    ``mu`` are already clipped.
    """
    return polarity_scan(edge, grad, pts, nrm, mv, mu, min_support, np.zeros((0, 0)))


@kernel
def polarity_surface(edge, grad, pts, nrm, mv, mu, min_support):
    """Every shift's score as :func:`polarity_search` forms it,
    ``(2 mv + 1, 2 mu + 1)``; NaN where the shift is not a candidate."""
    surface = np.full((2 * mv + 1, 2 * mu + 1), np.nan)
    polarity_scan(edge, grad, pts, nrm, mv, mu, min_support, surface)
    return surface


@kernel
def polarity_scan(edge, grad, pts, nrm, mv, mu, min_support, surface):
    """:func:`polarity_search`, also writing each candidate's score to
    ``surface`` unless it is empty."""
    h, w = edge.shape
    n = pts.shape[0]
    bv = np.empty(n)
    bu = np.empty(n)
    nhv = np.empty(n)
    nhu = np.empty(n)
    inside = True
    for i in range(n):
        bv[i] = np.rint(pts[i, 0])
        bu[i] = np.rint(pts[i, 1])
        norm = np.hypot(nrm[i, 0], nrm[i, 1])
        if norm == 0.0:
            norm = 1.0
        nhv[i] = nrm[i, 0] / norm
        nhu[i] = nrm[i, 1] / norm
        inside &= bv[i] - mv >= 0.0 and bv[i] + mv < h and bu[i] - mu >= 0.0 and bu[i] + mu < w
    if not inside:
        return _dense_scores(edge, grad, bv, bu, nhv, nhu, mv, mu, min_support, surface)
    # every vertex in bounds for every shift: n >= min_support everywhere
    r_lo = int(bv.min()) - mv
    r_hi = int(bv.max()) + mv
    flat, words = flat_words(edge)
    e_rows, e_cols = nonzero_in_box(
        flat, words, w, r_lo, r_hi, int(bu.min()) - mu, int(bu.max()) + mu
    )
    return _sparse_scores(grad, edge, row_starts(e_rows, h), e_cols, bv, bu, nhv, nhu, mv, mu,
                          surface)
