""":ref:`contract-numerics` (coarse search, polyline mask, polarity, Tukey, sampler) and §8.1/§8.2.

Expected values come from the contract by hand, or from a tiny brute-force NumPy
transcription of §2/§8.2 inside this file (``_expected_ncc``) on small arrays.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import dtalign

pytestmark = pytest.mark.filterwarnings("error")


# ---------------------------------------------------------------- §8.2 transcription

def _expected_ncc(edge, poly, window, fraction):
    """§2 + §8.2 on small arrays, written from the contract's text."""
    edge = np.asarray(edge)
    poly = np.asarray(poly)
    h, w = edge.shape
    pv, pu = np.nonzero(poly)
    m = pv.size
    if m == 0:
        return (0, 0), 0.0
    min_support = fraction * m
    e = edge.astype(np.float64)
    best, best_key, best_off = -1.0, None, (0, 0)
    mv, mu = window
    for dv in range(-mv, mv + 1):
        for du in range(-mu, mu + 1):
            v, u = pv + dv, pu + du
            inb = (v >= 0) & (v < h) & (u >= 0) & (u < w)
            n = int(inb.sum())
            if n == 0 or n < min_support:
                continue
            score = float(e[v[inb], u[inb]].sum()) / n
            key = (abs(dv) + abs(du), abs(dv), dv, du)
            if score > best or (score == best and (best_key is None or key < best_key)):
                best, best_key, best_off = score, key, (dv, du)
    return best_off, max(best, 0.0)


def _scored(edge, poly, window, **kw):
    r = dtalign.coarse_ncc_search_scored(edge, poly, window, **kw)
    assert isinstance(r, dtalign.CoarseSearchResult)
    assert isinstance(r.offset_vu, tuple) and len(r.offset_vu) == 2
    assert all(type(x) is int for x in r.offset_vu)
    assert isinstance(r.score, float)
    return r.offset_vu, r.score


def _row_scene():
    """Polyline pixels (2, 0..3) on a 5 x 10 image (M = 4)."""
    poly = np.zeros((5, 10), dtype=bool)
    poly[2, 0:4] = True
    return poly


# ---------------------------------------------------------------- simple cases

def test_single_pixel_shift():
    edge = np.zeros((9, 9), dtype=bool)
    poly = np.zeros((9, 9), dtype=bool)
    poly[5, 5] = True
    edge[7, 4] = True
    off = dtalign.coarse_ncc_search(edge, poly, (3, 3))
    assert off == (2, -1)
    assert all(type(x) is int for x in off)
    assert _scored(edge, poly, (3, 3)) == ((2, -1), 1.0)


def test_shift_outside_window_not_found():
    edge = np.zeros((9, 9), dtype=bool)
    poly = np.zeros((9, 9), dtype=bool)
    poly[5, 5] = True
    edge[8, 5] = True  # needs dv = 3
    assert _scored(edge, poly, (2, 2)) == ((0, 0), 0.0)
    assert _scored(edge, poly, (3, 0)) == ((3, 0), 1.0)


def test_empty_polyline_mask():
    edge = np.ones((6, 6), dtype=bool)
    poly = np.zeros((6, 6), dtype=bool)
    assert dtalign.coarse_ncc_search(edge, poly, (2, 2)) == (0, 0)
    assert _scored(edge, poly, (2, 2)) == ((0, 0), 0.0)
    assert _scored(edge, poly, (2, 2), min_support_fraction=0.0) == ((0, 0), 0.0)


def test_flat_edge_masks_choose_zero_shift():
    poly = np.zeros((7, 7), dtype=bool)
    poly[3, 2:5] = True
    for value in (False, True):
        edge = np.full((7, 7), value)
        off, score = _scored(edge, poly, (3, 3), min_support_fraction=0.0)
        assert off == (0, 0)
        assert score == (1.0 if value else 0.0)


def test_window_larger_than_arrays_is_clipped():
    edge = np.zeros((4, 5), dtype=bool)
    poly = np.zeros((4, 5), dtype=bool)
    poly[0, 0] = True
    edge[3, 4] = True
    assert _scored(edge, poly, (50, 60)) == ((3, 4), 1.0)
    assert dtalign.coarse_ncc_search(edge, poly, [50, 60]) == (3, 4)


def test_polyline_pixels_are_nonzero_pixels():
    edge = np.zeros((8, 8), dtype=bool)
    edge[4, 1:4] = True
    poly_b = np.zeros((8, 8), dtype=bool)
    poly_b[2, 2:5] = True
    poly_f = poly_b.astype(np.float64) * 0.3
    poly_f[2, 3] = 7.0
    poly_i = poly_b.astype(np.int32)
    ref = _scored(edge, poly_b, (3, 3))
    assert ref == ((2, -1), 1.0)
    assert _scored(edge, poly_f, (3, 3)) == ref
    assert _scored(edge, poly_i, (3, 3)) == ref


# ---------------------------------------------------------------- tie-breaks

def _one_pixel_with_edges(offsets, size=11):
    c = size // 2
    edge = np.zeros((size, size), dtype=bool)
    poly = np.zeros((size, size), dtype=bool)
    poly[c, c] = True
    for dv, du in offsets:
        edge[c + dv, c + du] = True
    return edge, poly


@pytest.mark.parametrize("offsets,winner", [
    # Manhattan distance first
    ([(2, 0), (1, 1), (0, -1)], (0, -1)),
    # equal Manhattan: smaller |dv| first
    ([(1, 0), (-1, 0), (0, 1), (0, -1)], (0, -1)),
    ([(1, 0), (-1, 0), (0, 1)], (0, 1)),
    ([(1, 1), (-1, -1), (1, -1), (-1, 1), (2, 0), (0, 2)], (0, 2)),
    # equal Manhattan and |dv|: smaller dv, then smaller du
    ([(1, 1), (-1, -1), (1, -1), (-1, 1), (2, 0)], (-1, -1)),
    ([(1, 1), (1, -1), (-1, 1)], (-1, 1)),
    ([(1, 1), (1, -1)], (1, -1)),
    ([(2, 0), (-2, 0)], (-2, 0)),
    ([(0, 3), (0, -3), (3, 0), (-3, 0), (2, 1), (1, 2), (-2, 1), (1, -2)], (0, -3)),
    ([(3, 0), (-3, 0), (2, 1), (1, 2), (-2, 1), (1, -2)], (1, -2)),
    ([(3, 0), (-3, 0), (2, 1), (-2, 1)], (-2, 1)),
])
def test_tie_break_key(offsets, winner):
    edge, poly = _one_pixel_with_edges(offsets)
    assert _scored(edge, poly, (3, 3)) == (winner, 1.0)
    assert _scored(edge, poly, (3, 3), min_support_fraction=0.0) == (winner, 1.0)
    assert dtalign.coarse_ncc_search(edge, poly, (3, 3)) == winner


def test_higher_score_beats_nearer_shift():
    poly = np.zeros((9, 9), dtype=bool)
    poly[4, 3:6] = True
    edge = np.zeros((9, 9), dtype=bool)
    edge[4, 3:5] = True  # zero shift: 2/3
    edge[7, 2:5] = True  # shift (3, -1): 3/3
    assert _scored(edge, poly, (3, 3)) == ((3, -1), 1.0)


# ---------------------------------------------------------------- min-support eligibility

def test_min_support_equality_is_eligible():
    poly = _row_scene()
    edge = np.zeros((5, 10), dtype=bool)
    edge[2, 0:2] = True
    # du=-2 keeps n=2 == 0.5*4 pixels, both on edges: 2/2; du=-1 scores 2/3
    assert 0.5 * 4 == 2
    assert _scored(edge, poly, (0, 5)) == ((0, -2), 1.0)
    assert _scored(edge, poly, (0, 5), min_support_fraction=0.5) == ((0, -2), 1.0)
    assert dtalign.coarse_ncc_search(edge, poly, (0, 5)) == (0, -2)


@pytest.mark.parametrize("fraction,expected", [
    (0.0, ((0, -3), 1.0)),          # n=1 at du=-3: 1/1
    (0.25, ((0, -3), 1.0)),         # min_support = 1.0: n=1 eligible (equality)
    (0.5, ((0, -2), 0.5)),          # min_support = 2.0: du=-3 (n=1) ineligible
    (0.75, ((0, -1), 1.0 / 3.0)),   # min_support = 3.0: du=-1 (n=3) eligible (equality)
    (1.0, ((0, 0), 0.25)),          # only n == M: the zero shift
])
def test_min_support_fraction_boundaries(fraction, expected):
    poly = _row_scene()
    edge = np.zeros((5, 10), dtype=bool)
    edge[2, 0] = True
    assert _scored(edge, poly, (0, 5), min_support_fraction=fraction) == expected
    assert dtalign.coarse_ncc_search(edge, poly, (0, 5),
                                     min_support_fraction=fraction) == expected[0]
    assert expected == _expected_ncc(edge, poly, (0, 5), fraction)


def test_min_support_is_the_float_product():
    # min_support = fraction * M literally: 0.28 * 25 = 7.000000000000001 > 7,
    # so a shift keeping 7 of 25 pixels is NOT eligible at fraction 0.28.
    assert 0.28 * 25 > 7
    poly = np.zeros((3, 30), dtype=bool)
    poly[1, 0:25] = True
    edge = np.zeros((3, 30), dtype=bool)
    edge[1, 0:7] = True
    # du=-18 keeps columns 0..6 (n=7, all on edges: 7/7); du=-17 keeps 8 (7/8)
    assert _scored(edge, poly, (0, 18), min_support_fraction=0.28) == ((0, -17), 0.875)
    # 0.27 * 25 = 6.75 <= 7: eligible
    assert _scored(edge, poly, (0, 18), min_support_fraction=0.27) == ((0, -18), 1.0)
    assert _expected_ncc(edge, poly, (0, 18), 0.28) == ((0, -17), 0.875)


def test_zero_fraction_is_section2_search():
    # §8.1: min_support_fraction=0.0 is exactly §2's search (every n >= 1 shift)
    poly = np.zeros((6, 6), dtype=bool)
    poly[0:4, 2] = True
    edge = np.zeros((6, 6), dtype=bool)
    edge[0, 5] = True
    # only shift (-3, 3) puts a pixel on the edge with n=1 -> 1.0 under §2
    assert dtalign.coarse_ncc_search(edge, poly, (3, 3), min_support_fraction=0.0) == (-3, 3)
    # the default (0.5) needs n >= 2: (-2, 3) scores 1/2
    assert dtalign.coarse_ncc_search(edge, poly, (3, 3)) == (-2, 3)
    assert _scored(edge, poly, (3, 3)) == ((-2, 3), 0.5)


# ---------------------------------------------------------------- float masks and max(best, 0.0)

def test_float_edge_mask_sums_values_and_can_exceed_one():
    edge, poly = _one_pixel_with_edges([])
    edge = edge.astype(np.float64)
    edge[5 + 1, 5 - 2] = 2.5
    edge[5, 5 + 1] = 1.0
    assert _scored(edge, poly, (3, 3)) == ((1, -2), 2.5)


def test_negative_float_scores_return_zero_with_the_argmax():
    edge, poly = _one_pixel_with_edges([])
    edge = np.full(edge.shape, -0.75)
    edge[5 - 2, 5 + 1] = -0.25
    # best score -0.25 at (-2, 1); the returned score is max(best, 0.0)
    assert _scored(edge, poly, (3, 3)) == ((-2, 1), 0.0)
    assert dtalign.coarse_ncc_search(edge, poly, (3, 3)) == (-2, 1)


def test_float_edge_mask_row_scene():
    poly = _row_scene()
    edge = np.zeros((5, 10))
    edge[2, 0] = 0.5
    edge[2, 1] = 1.5
    edge[2, 6] = 3.0
    for fraction in (0.0, 0.25, 0.5, 0.75, 1.0):
        assert _scored(edge, poly, (1, 6), min_support_fraction=fraction) == \
            _expected_ncc(edge, poly, (1, 6), fraction)


# ---------------------------------------------------------------- seeded random scenes vs the transcription

def _random_scenes(seed, count):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        h, w = int(rng.integers(3, 12)), int(rng.integers(3, 12))
        density_e = rng.choice([0.0, 0.05, 0.3, 0.7, 1.0])
        density_p = rng.choice([0.0, 0.05, 0.2, 0.5, 1.0])
        edge = rng.random((h, w)) < density_e
        poly = rng.random((h, w)) < density_p
        window = (int(rng.integers(0, 6)), int(rng.integers(0, 6)))
        yield edge, poly, window


@pytest.mark.parametrize("fraction", [0.0, 0.2, 0.25, 0.5, 0.75, 1.0, 1.0 / 3.0])
def test_random_bool_scenes_match_transcription(fraction):
    for edge, poly, window in _random_scenes(1234, 60):
        exp = _expected_ncc(edge, poly, window, fraction)
        assert _scored(edge, poly, window, min_support_fraction=fraction) == exp
        assert dtalign.coarse_ncc_search(edge, poly, window,
                                         min_support_fraction=fraction) == exp[0]


def test_random_default_fraction_is_half():
    for edge, poly, window in _random_scenes(99, 40):
        assert dtalign.coarse_ncc_search(edge, poly, window) == \
            dtalign.coarse_ncc_search_scored(edge, poly, window).offset_vu == \
            _expected_ncc(edge, poly, window, 0.5)[0]
        assert _scored(edge, poly, window) == _expected_ncc(edge, poly, window, 0.5)


def test_random_float_edge_masks_match_transcription():
    rng = np.random.default_rng(7)
    values = np.array([0.0, 0.0, 0.0, 0.5, 1.0, 2.5, -0.25, -0.5])  # scores stay > -1
    for edge_b, poly, window in _random_scenes(4321, 40):
        edge = rng.choice(values, size=edge_b.shape)
        for fraction in (0.0, 0.5, 1.0):
            assert _scored(edge, poly, window, min_support_fraction=fraction) == \
                _expected_ncc(edge, poly, window, fraction)


# ---------------------------------------------------------------- build_polyline_mask

def test_polyline_mask_rounds_half_to_even_and_drops_outside():
    verts = np.array([[2.5, 3.5], [0.4, 0.6], [-0.5, 1.0], [4.5, 6.5], [5.5, 0.0],
                      [1.0, -0.6], [-3.0, 2.0], [1.49, 6.51]])
    m = dtalign.build_polyline_mask(verts, (5, 7))
    assert m.shape == (5, 7) and m.dtype == np.bool_
    expected = np.zeros((5, 7), dtype=bool)
    for v, u in [(2, 4), (0, 1), (0, 1), (4, 6)]:  # rint(-0.5) = -0 -> row 0
        expected[v, u] = True
    np.testing.assert_array_equal(m, expected)


def test_polyline_mask_empty():
    m = dtalign.build_polyline_mask(np.zeros((0, 2)), (3, 4))
    assert m.shape == (3, 4) and not m.any()


# ---------------------------------------------------------------- polarity_filter

def test_polarity_filter_rule():
    grad = np.zeros((5, 6, 2))
    grad[..., 0] = 1.0  # g_v = 1 everywhere
    grad[1, 1] = (-2.0, 0.5)
    verts = np.array([[2.0, 2.0], [2.0, 2.0], [2.0, 2.0], [1.2, 0.6], [4.6, 1.0], [2.0, -0.6],
                      [0.5, 3.0]])
    norms = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [1.0, 0.0], [1.0, 0.0], [1.0, 0.0],
                      [1e-300, 0.0]])
    out = dtalign.polarity_filter(verts, norms, grad)
    assert out.shape == (7,) and out.dtype == np.bool_
    # (1.2, 0.6) -> pixel (1, 1) with g = (-2, 0.5): dot -2 rejected; (4.6, 1) -> row 5 outside;
    # (2, -0.6) -> column -1 outside; (0.5, 3) -> rint(0.5) = 0 inside, tiny positive dot accepted
    np.testing.assert_array_equal(out, [True, False, False, False, False, False, True])


def test_polarity_filter_offset():
    grad = np.zeros((5, 6, 2))
    grad[..., 1] = -1.0
    grad[:, 4:, 1] = 1.0  # columns 4, 5 point +u
    verts = np.array([[2.0, 2.0], [2.0, 3.4]])
    norms = np.array([[0.0, 1.0], [0.0, 1.0]])
    np.testing.assert_array_equal(dtalign.polarity_filter(verts, norms, grad), [False, False])
    np.testing.assert_array_equal(
        dtalign.polarity_filter(verts, norms, grad, offset_vu=(0.0, 1.0)), [False, True])
    np.testing.assert_array_equal(
        dtalign.polarity_filter(verts, norms, grad, offset_vu=(0.3, 2.0)), [True, True])
    np.testing.assert_array_equal(
        dtalign.polarity_filter(verts, norms, grad, offset_vu=(0.0, 2.7)), [True, False])


# ---------------------------------------------------------------- Tukey

def test_tukey_weights():
    r = np.array([0.0, 1.0, -2.0, 4.685, -4.685, 4.6850000001, 10.0, 2.3])
    w = dtalign.tukey_biweight_weights(r)
    assert w.shape == r.shape and w.dtype == np.float64
    s = r / 4.685
    expected = np.where(np.abs(s) <= 1.0, (1.0 - s * s) ** 2, 0.0)
    np.testing.assert_allclose(w, expected, rtol=1e-15, atol=0)
    assert w[0] == 1.0 and w[3] == 0.0 and w[4] == 0.0 and w[5] == 0.0 and w[6] == 0.0


def test_tukey_custom_c():
    r = np.array([0.5, 1.0, 1.5])
    w = dtalign.tukey_biweight_weights(r, c=1.0)
    np.testing.assert_allclose(w, [(1 - 0.25) ** 2, 0.0, 0.0], rtol=1e-15)


def test_tukey_empty():
    w = dtalign.tukey_biweight_weights(np.zeros(0))
    assert w.shape == (0,)


# ---------------------------------------------------------------- sampler and translation

def _bilinear(dt, verts):
    h, w = dt.shape
    v = np.clip(verts[:, 0], 0, h - 1)
    u = np.clip(verts[:, 1], 0, w - 1)
    v0 = np.floor(v).astype(int)
    u0 = np.floor(u).astype(int)
    v1 = np.minimum(v0 + 1, h - 1)
    u1 = np.minimum(u0 + 1, w - 1)
    fv = v - v0
    fu = u - u0
    a, b, c, d = dt[v0, u0], dt[v0, u1], dt[v1, u0], dt[v1, u1]
    return a * (1 - fv) * (1 - fu) + b * (1 - fv) * fu + c * fv * (1 - fu) + d * fv * fu


def test_sample_dt_bilinear():
    rng = np.random.default_rng(3)
    dt = rng.random((5, 7)) * 10
    verts = np.array([[0.0, 0.0], [4.0, 6.0], [1.25, 2.5], [3.9, 0.1], [-3.0, 2.2],
                      [2.2, 40.0], [4.0, 5.5], [100.0, -100.0]])
    out = dtalign.sample_dt_bilinear(dt, verts)
    assert out.shape == (8,) and out.dtype == np.float64
    np.testing.assert_allclose(out, _bilinear(dt, verts), rtol=1e-15, atol=0)
    assert out[0] == dt[0, 0] and out[1] == dt[4, 6] and out[7] == dt[4, 0]


def test_apply_translation_copy():
    verts = np.array([[1.0, 2.0], [3.0, 4.0]])
    out = dtalign.apply_translation(verts, 0.5, -1.0)
    np.testing.assert_array_equal(out, [[1.5, 1.0], [3.5, 3.0]])
    assert out is not verts
    np.testing.assert_array_equal(verts, [[1.0, 2.0], [3.0, 4.0]])
    assert math.isclose(out[0, 0], 1.5)


def test_tukey_non_finite_residuals_weight_zero_silently():
    w = dtalign.tukey_biweight_weights(np.array([np.inf, -np.inf, np.nan, 0.0]))
    np.testing.assert_array_equal(w, [0.0, 0.0, 0.0, 1.0])
