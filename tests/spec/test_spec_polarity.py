""":ref:`contract-polarity-search`: ``coarse_polarity_search_scored``.

Expected values come from the contract by hand or from ``_expected_polarity``, a
brute-force NumPy transcription of §8.3 on small arrays (the score summed with
``np.sum`` exactly as §8.3 says).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import dtalign

pytestmark = pytest.mark.filterwarnings("error")


def _expected_polarity(edge, grad, verts, norms, window, fraction):
    edge = np.asarray(edge)
    grad = np.asarray(grad, dtype=np.float64)
    verts = np.asarray(verts, dtype=np.float64).reshape(-1, 2)
    norms = np.asarray(norms, dtype=np.float64).reshape(-1, 2)
    n_all = verts.shape[0]
    if n_all == 0:
        return (0, 0), 0.0
    h, w = edge.shape
    bv = np.rint(verts[:, 0]).astype(np.int64)
    bu = np.rint(verts[:, 1]).astype(np.int64)
    nn = np.hypot(norms[:, 0], norms[:, 1])
    nn = np.where(nn == 0.0, 1.0, nn)
    nhat = norms / nn[:, None]
    min_support = fraction * n_all
    best, best_key, best_off = -1.0, None, (0, 0)
    mv, mu = window
    for dv in range(-mv, mv + 1):
        for du in range(-mu, mu + 1):
            v, u = bv + dv, bu + du
            inb = (v >= 0) & (v < h) & (u >= 0) & (u < w)
            n = int(inb.sum())
            if n == 0 or n < min_support:
                continue
            idx = np.nonzero(inb)[0]
            g = grad[v[idx], u[idx]]
            s = np.hypot(g[:, 0], g[:, 1])
            s = np.where(s == 0.0, 1.0, s)
            c = (nhat[idx, 0] * g[:, 0] + nhat[idx, 1] * g[:, 1]) / s
            wts = np.where(edge[v[idx], u[idx]] != 0, np.maximum(c, 0.0), 0.0)
            score = np.sum(wts) / n
            key = (abs(dv) + abs(du), abs(dv), dv, du)
            if score > best or (score == best and (best_key is None or key < best_key)):
                best, best_key, best_off = float(score), key, (dv, du)
    return best_off, max(best, 0.0)


def _search(edge, grad, verts, norms, window, **kw):
    r = dtalign.coarse_polarity_search_scored(edge, grad, verts, norms, window, **kw)
    assert isinstance(r, dtalign.CoarseSearchResult)
    assert isinstance(r.offset_vu, tuple) and len(r.offset_vu) == 2
    assert all(type(x) is int for x in r.offset_vu)
    assert isinstance(r.score, float)
    return r.offset_vu, r.score


def _unit_grad(h, w, gv, gu):
    g = np.zeros((h, w, 2))
    g[..., 0] = gv
    g[..., 1] = gu
    return g


# ---------------------------------------------------------------- empty / simple

def test_no_vertices():
    edge = np.ones((5, 5), dtype=bool)
    grad = _unit_grad(5, 5, 1.0, 0.0)
    empty = np.zeros((0, 2))
    assert _search(edge, grad, empty, empty, (2, 2)) == ((0, 0), 0.0)
    assert _search(edge, grad, empty, empty, (2, 2), min_support_fraction=0.0) == ((0, 0), 0.0)


def test_single_vertex_aligned_edge():
    edge = np.zeros((9, 9), dtype=bool)
    edge[6, 2] = True
    grad = _unit_grad(9, 9, 0.0, 1.0)
    verts = np.array([[4.2, 3.6]])  # base pixel (4, 4)
    norms = np.array([[0.0, 2.0]])
    assert _search(edge, grad, verts, norms, (3, 3)) == ((2, -2), 1.0)


def test_wrong_polarity_edge_never_counts():
    # two vertices; a dense wrong-polarity edge at the zero shift, a right-polarity one farther
    h, w = 9, 12
    edge = np.zeros((h, w), dtype=bool)
    grad = _unit_grad(h, w, 0.0, -1.0)
    verts = np.array([[4.0, 3.0], [5.0, 3.0]])
    norms = np.array([[0.0, 1.0], [0.0, 1.0]])
    edge[4:6, 3] = True  # zero shift: both on edges but gradient anti-parallel
    edge[4:6, 7] = True
    grad[4:6, 7] = (0.0, 5.0)  # shift (0, 4): aligned
    assert _search(edge, grad, verts, norms, (0, 4)) == ((0, 4), 1.0)
    # the polarity-blind search prefers the zero shift
    poly = dtalign.build_polyline_mask(verts, (h, w))
    assert dtalign.coarse_ncc_search_scored(edge, poly, (0, 4)).offset_vu == (0, 0)


def test_weight_is_clipped_cosine():
    edge = np.ones((5, 5), dtype=bool)
    grad = np.zeros((5, 5, 2))
    grad[2, 2] = (3.0, 4.0)  # s = 5
    verts = np.array([[2.0, 2.0]])
    norms = np.array([[1.0, 0.0]])
    off, score = _search(edge, grad, verts, norms, (0, 0))
    assert off == (0, 0)
    assert score == 3.0 / 5.0
    # anti-parallel component -> clipped to 0
    grad[2, 2] = (-3.0, 4.0)
    assert _search(edge, grad, verts, norms, (0, 0)) == ((0, 0), 0.0)


def test_only_direction_matters():
    rng = np.random.default_rng(11)
    h, w = 10, 11
    edge = rng.random((h, w)) < 0.5
    grad = rng.normal(size=(h, w, 2))
    verts = rng.uniform(-1, 11, size=(15, 2))
    norms = rng.normal(size=(15, 2))
    off1, s1 = _search(edge, grad, verts, norms, (2, 3))
    off2, s2 = _search(edge, grad * 1000.0, verts, norms * 0.001, (2, 3))
    assert off1 == off2
    assert s2 == pytest.approx(s1, rel=1e-12)


def test_float_edge_mask_only_nonzero_matters():
    rng = np.random.default_rng(5)
    h, w = 8, 9
    edge_b = rng.random((h, w)) < 0.4
    edge_f = np.where(edge_b, rng.choice([2.5, -3.0, 0.25], size=(h, w)), 0.0)
    grad = rng.normal(size=(h, w, 2))
    verts = rng.uniform(0, 8, size=(12, 2))
    norms = rng.normal(size=(12, 2))
    r_b = _search(edge_b, grad, verts, norms, (2, 2))
    r_f = _search(edge_f, grad, verts, norms, (2, 2))
    assert r_b[0] == r_f[0]
    assert r_f[1] == pytest.approx(r_b[1], rel=1e-12)


# ---------------------------------------------------------------- per-vertex rules

def test_duplicates_count_separately():
    edge = np.zeros((5, 8), dtype=bool)
    edge[2, 2] = True
    grad = _unit_grad(5, 8, 0.0, 1.0)
    verts = np.array([[2.0, 2.0], [2.0, 2.0], [2.0, 5.0]])
    norms = np.array([[0.0, 1.0]] * 3)
    # zero shift: weights [1, 1, 0] over n = 3 (not 1/2 as a rasterised mask would give)
    assert _search(edge, grad, verts, norms, (0, 0)) == ((0, 0), 2.0 / 3.0)
    # shift (0, -3) puts the third vertex on the edge, but keeps only n = 1 < 1.5 in bounds
    assert _search(edge, grad, verts, norms, (0, 3)) == ((0, 0), 2.0 / 3.0)


def test_duplicates_change_the_winner():
    # vertices (2, 1) twice and (2, 3), one edge pixel at (2, 3): shift (0, 2) puts the
    # duplicates on it (2/3), the zero shift the third vertex (1/3). A rasterised mask
    # would score both 1/2 and keep the zero shift.
    h, w = 5, 12
    edge = np.zeros((h, w), dtype=bool)
    edge[2, 3] = True
    grad = _unit_grad(h, w, 0.0, 1.0)
    verts = np.array([[2.0, 1.0], [2.0, 1.0], [2.0, 3.0]])
    norms = np.array([[0.0, 1.0]] * 3)
    assert _search(edge, grad, verts, norms, (0, 5)) == ((0, 2), 2.0 / 3.0)
    poly = dtalign.build_polyline_mask(verts, (h, w))
    assert dtalign.coarse_ncc_search_scored(edge, poly, (0, 5)) == \
        dtalign.CoarseSearchResult((0, 0), 0.5)


def test_off_frame_vertices_count_in_n_for_min_support():
    h, w = 6, 6
    edge = np.zeros((h, w), dtype=bool)
    grad = _unit_grad(h, w, 1.0, 0.0)
    verts = np.array([[2.0, 2.0], [2.0, 3.0], [-20.0, 2.0], [-20.0, 3.0]])
    norms = np.array([[1.0, 0.0]] * 4)
    edge[3, 2:4] = True  # shift (1, 0): both in-frame vertices on aligned edges
    # N = 4, fraction 0.5 -> min_support 2 == n: eligible; score divides by n = 2
    assert _search(edge, grad, verts, norms, (1, 1)) == ((1, 0), 1.0)
    # fraction 0.75 -> min_support 3 > n = 2 at every shift: nothing eligible
    assert _search(edge, grad, verts, norms, (1, 1), min_support_fraction=0.75) == ((0, 0), 0.0)
    assert _search(edge, grad, verts, norms, (1, 1), min_support_fraction=0.0) == ((1, 0), 1.0)


def test_min_support_equality_is_eligible():
    # 4 vertices in a row; shifting left by 2 keeps n = 2 == 0.5 * 4 in bounds
    h, w = 3, 8
    edge = np.zeros((h, w), dtype=bool)
    edge[1, 0:2] = True
    grad = _unit_grad(h, w, 0.0, 1.0)
    verts = np.array([[1.0, 0.0], [1.0, 1.0], [1.0, 2.0], [1.0, 3.0]])
    norms = np.array([[0.0, 1.0]] * 4)
    assert _search(edge, grad, verts, norms, (0, 4)) == ((0, -2), 1.0)
    # with fraction 0.75 (min 3) the best is du = -1: 2/3
    assert _search(edge, grad, verts, norms, (0, 4), min_support_fraction=0.75) == \
        ((0, -1), 2.0 / 3.0)
    # min_support is the float product: 0.28 * 25 > 7
    verts25 = np.stack([np.ones(25), np.arange(25.0)], axis=1)
    norms25 = np.array([[0.0, 1.0]] * 25)
    edge25 = np.zeros((3, 30), dtype=bool)
    edge25[1, 0:7] = True
    grad25 = _unit_grad(3, 30, 0.0, 1.0)
    assert _search(edge25, grad25, verts25, norms25, (0, 18), min_support_fraction=0.28) == \
        ((0, -17), 0.875)
    assert _search(edge25, grad25, verts25, norms25, (0, 18), min_support_fraction=0.27) == \
        ((0, -18), 1.0)


def test_zero_normal_never_matches():
    h, w = 7, 9
    edge = np.zeros((h, w), dtype=bool)
    grad = _unit_grad(h, w, 1.0, 1.0)
    verts = np.array([[3.0, 2.0], [3.0, 6.0]])
    norms = np.array([[0.0, 0.0], [1.0, 1.0]])
    edge[3, 2 + 1] = True  # shift (0, 1): the zero-normal vertex on an edge
    edge[3 + 1, 6 + 2] = True  # shift (1, 2): the real vertex on an aligned edge
    off, score = _search(edge, grad, verts, norms, (2, 2))
    assert off == (1, 2)
    assert score == pytest.approx(0.5, rel=1e-12)
    # with only the zero-normal vertex, every shift scores 0: the zero shift, score 0.0
    assert _search(edge, grad, verts[:1], norms[:1], (2, 2)) == ((0, 0), 0.0)


def test_zero_gradient_on_edge_is_weight_zero():
    edge = np.ones((5, 5), dtype=bool)
    grad = np.zeros((5, 5, 2))
    verts = np.array([[2.0, 2.0]])
    norms = np.array([[1.0, 0.0]])
    assert _search(edge, grad, verts, norms, (1, 1)) == ((0, 0), 0.0)


def test_nan_gradient_never_wins():
    h, w = 7, 9
    edge = np.zeros((h, w), dtype=bool)
    grad = _unit_grad(h, w, 0.0, 1.0)
    verts = np.array([[3.0, 3.0], [4.0, 3.0]])
    norms = np.array([[0.0, 1.0]] * 2)
    # zero shift would score 2/2, but one of its pixels has a NaN gradient
    edge[3:5, 3] = True
    grad[4, 3] = (np.nan, 1.0)
    # shift (0, 2): one of two on an aligned edge -> 1/2
    edge[3, 5] = True
    assert _search(edge, grad, verts, norms, (0, 2)) == ((0, 2), 0.5)
    assert _expected_polarity(edge, grad, verts, norms, (0, 2), 0.5) == ((0, 2), 0.5)
    # a NaN in the other channel too
    grad[4, 3] = (0.0, np.nan)
    assert _search(edge, grad, verts, norms, (0, 2)) == ((0, 2), 0.5)


def test_rint_half_to_even_base_pixel():
    edge = np.zeros((6, 6), dtype=bool)
    grad = _unit_grad(6, 6, 1.0, 0.0)
    verts = np.array([[2.5, 3.5]])  # base pixel (2, 4)
    norms = np.array([[1.0, 0.0]])
    edge[2, 4] = True
    assert _search(edge, grad, verts, norms, (1, 1)) == ((0, 0), 1.0)


# ---------------------------------------------------------------- tie-breaks

@pytest.mark.parametrize("offsets,winner", [
    ([(1, 0), (-1, 0), (0, 1), (0, -1)], (0, -1)),
    ([(1, 1), (-1, -1), (1, -1), (-1, 1), (2, 0)], (-1, -1)),
    ([(2, 0), (-2, 0)], (-2, 0)),
    ([(1, 1), (1, -1)], (1, -1)),
    ([(3, 0), (-3, 0), (2, 1), (-2, 1)], (-2, 1)),
])
def test_tie_break_key(offsets, winner):
    size, c = 11, 5
    edge = np.zeros((size, size), dtype=bool)
    for dv, du in offsets:
        edge[c + dv, c + du] = True
    grad = _unit_grad(size, size, 1.0, 0.0)
    verts = np.array([[float(c), float(c)]])
    norms = np.array([[1.0, 0.0]])
    assert _search(edge, grad, verts, norms, (3, 3)) == (winner, 1.0)


# ---------------------------------------------------------------- pairwise summation (np.sum)

# Pythagorean gradients (g_v, g_u) with integer magnitude, so each weight is g_v / s,
# correctly rounded, whatever the order of the dot product.
_TRIPLES = [(3, 4), (4, 3), (5, 12), (12, 5), (8, 15), (15, 8), (7, 24), (24, 7), (20, 21),
            (21, 20), (9, 40), (40, 9), (1, 0)]
# 16 vertices; the zero shift sees _TRIPLES[A[i]], the shift (0, 1) sees _TRIPLES[B[i]]
# (a permutation of the same weights). Found by a seeded search so that NumPy's pairwise
# np.sum ranks (0, 1) strictly higher while a left-to-right sum ranks them equal.
_A = [10, 11, 5, 0, 9, 6, 11, 5, 4, 0, 5, 8, 10, 11, 2, 7]
_B = [6, 8, 0, 0, 2, 11, 7, 4, 5, 11, 5, 10, 9, 10, 11, 5]


def test_score_is_numpy_pairwise_sum():
    n = len(_A)
    h, w = 3, 3 * n + 3
    edge = np.zeros((h, w), dtype=bool)
    grad = np.zeros((h, w, 2))
    verts = np.array([[1.0, 3.0 * i + 1.0] for i in range(n)])
    norms = np.array([[1.0, 0.0]] * n)
    for i in range(n):
        edge[1, 3 * i + 1] = True
        grad[1, 3 * i + 1] = _TRIPLES[_A[i]]
        edge[1, 3 * i + 2] = True
        grad[1, 3 * i + 2] = _TRIPLES[_B[i]]
        # columns 3i (the shift (0, -1)) stay off the edge mask
    wa = np.array([_TRIPLES[k][0] / math.hypot(*_TRIPLES[k]) for k in _A])
    wb = np.array([_TRIPLES[k][0] / math.hypot(*_TRIPLES[k]) for k in _B])
    # the premise: pairwise and left-to-right summation disagree on the ranking
    assert np.sum(wb) / n > np.sum(wa) / n
    seq_a = seq_b = 0.0
    for x, y in zip(wa, wb, strict=True):
        seq_a += x
        seq_b += y
    assert seq_a / n >= seq_b / n
    expected = _expected_polarity(edge, grad, verts, norms, (0, 1), 0.5)
    assert expected == ((0, 1), float(np.sum(wb) / n))
    off, score = _search(edge, grad, verts, norms, (0, 1))
    assert off == (0, 1)
    assert score == np.sum(wb) / n


# ---------------------------------------------------------------- seeded random scenes vs the transcription

def _random_polarity_scenes(seed, count):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        h, w = int(rng.integers(3, 12)), int(rng.integers(3, 12))
        edge = rng.random((h, w)) < rng.choice([0.0, 0.1, 0.4, 1.0])
        grad = rng.normal(size=(h, w, 2))
        grad[rng.random((h, w)) < 0.1] = 0.0
        n = int(rng.choice([1, 2, 5, 9, 17, 40]))
        verts = np.stack([rng.uniform(-3, h + 3, n), rng.uniform(-3, w + 3, n)], axis=1)
        if rng.random() < 0.3:
            verts = np.round(verts)  # exact duplicates and half-way points
        norms = rng.normal(size=(n, 2))
        norms[rng.random(n) < 0.1] = 0.0
        window = (int(rng.integers(0, 5)), int(rng.integers(0, 5)))
        yield edge, grad, verts, norms, window


@pytest.mark.parametrize("fraction", [0.0, 0.25, 0.5, 0.75, 1.0])
def test_random_scenes_match_transcription(fraction):
    for edge, grad, verts, norms, window in _random_polarity_scenes(2026, 50):
        exp_off, exp_score = _expected_polarity(edge, grad, verts, norms, window, fraction)
        off, score = _search(edge, grad, verts, norms, window, min_support_fraction=fraction)
        assert off == exp_off
        assert score == pytest.approx(exp_score, rel=1e-12, abs=0)


def test_random_scenes_axis_aligned_exact():
    # normals and gradients along the axes: every weight is 0 or 1, scores exact, many ties
    rng = np.random.default_rng(77)
    dirs = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0], [0.0, 0.0]])
    for _ in range(60):
        h, w = int(rng.integers(3, 10)), int(rng.integers(3, 10))
        edge = rng.random((h, w)) < 0.5
        grad = dirs[rng.integers(0, 5, size=(h, w))] * rng.choice([1.0, 3.0])
        n = int(rng.integers(1, 20))
        verts = rng.integers(-2, max(h, w) + 2, size=(n, 2)).astype(float)
        norms = dirs[rng.integers(0, 5, size=n)]
        window = (int(rng.integers(0, 4)), int(rng.integers(0, 4)))
        for fraction in (0.0, 0.5, 1.0):
            assert _search(edge, grad, verts, norms, window, min_support_fraction=fraction) == \
                _expected_polarity(edge, grad, verts, norms, window, fraction)


def test_lists_accepted():
    edge = np.zeros((6, 6), dtype=bool)
    edge[3, 3] = True
    grad = _unit_grad(6, 6, 1.0, 0.0)
    r = dtalign.coarse_polarity_search_scored(edge, grad, [[2.0, 2.0]], [[1.0, 0.0]], [1, 1])
    assert r.offset_vu == (1, 1) and r.score == 1.0
