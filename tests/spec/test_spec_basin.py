""":ref:`contract-basin`: ``find_secondary_dt_minimum`` (the competing-basin second opinion).

Expected values come from the contract by hand or from ``_expected_basin``, a
brute-force NumPy transcription of §8.4 (costs with NumPy's ``.mean()``).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import dtalign

pytestmark = pytest.mark.filterwarnings("error")


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


def _cost(dt, verts, offset, fraction):
    h, w = dt.shape
    p = verts + np.asarray(offset, dtype=np.float64)
    inb = (p[:, 0] >= 0) & (p[:, 0] <= h - 1) & (p[:, 1] >= 0) & (p[:, 1] <= w - 1)
    if int(inb.sum()) < fraction * verts.shape[0]:
        return None
    return float(_bilinear(dt, p[inb]).mean())


def _expected_basin(dt, verts, conv, window, radius, fraction=0.5):
    dt = np.asarray(dt, dtype=np.float64)
    verts = np.asarray(verts, dtype=np.float64).reshape(-1, 2)
    if verts.shape[0] == 0:
        return None
    cc = _cost(dt, verts, conv, fraction)
    if cc is None:
        return None
    mv, mu = int(window[0]), int(window[1])
    best = None
    for dv in range(-mv, mv + 1):
        for du in range(-mu, mu + 1):
            d = math.hypot(dv - conv[0], du - conv[1])
            if d <= radius:
                continue
            c = _cost(dt, verts, (dv, du), fraction)
            if c is None:
                continue
            if best is None or (c, d) < (best[1], best[2]):
                best = ((dv, du), c, d)
    if best is None:
        return None
    return best[0], best[2], best[1], cc


def _find(dt, verts, conv, window, radius, **kw):
    r = dtalign.find_secondary_dt_minimum(dt, verts, converged_offset_vu=conv,
                                          search_window_vu=window, exclude_radius_px=radius,
                                          **kw)
    if r is None:
        return None
    assert isinstance(r, dtalign.SecondaryBasin)
    assert isinstance(r.offset_vu, tuple) and len(r.offset_vu) == 2
    assert all(type(x) is int for x in r.offset_vu)
    for name in ("distance_px", "cost_px", "converged_cost_px"):
        assert isinstance(getattr(r, name), float), name
    return r.offset_vu, r.distance_px, r.cost_px, r.converged_cost_px


def _bowl(h, w, centres):
    """DT-like field: distance to the nearest of ``centres`` (float64)."""
    vv, uu = np.mgrid[0:h, 0:w].astype(np.float64)
    d = np.full((h, w), np.inf)
    for cv, cu in centres:
        d = np.minimum(d, np.hypot(vv - cv, uu - cu))
    return d


# ---------------------------------------------------------------- None cases

def test_no_vertices_is_none():
    dt = np.ones((5, 5))
    assert _find(dt, np.zeros((0, 2)), (0.0, 0.0), (2, 2), 0.5) is None


def test_undefined_converged_cost_is_none():
    dt = np.ones((6, 6))
    verts = np.array([[2.0, 2.0], [3.0, 3.0]])
    # the converged offset pushes every vertex out of bounds
    assert _find(dt, verts, (10.0, 0.0), (2, 2), 0.5) is None
    # one of two in bounds: 1 >= 0.5 * 2, defined; with fraction 1.0, undefined
    assert _find(dt, verts, (2.5, 0.0), (2, 2), 0.5) is not None
    assert _find(dt, verts, (2.5, 0.0), (2, 2), 0.5, min_support_fraction=1.0) is None


def test_exclude_radius_covering_window_is_none():
    dt = _bowl(9, 9, [(4, 4)])
    verts = np.array([[4.0, 4.0], [4.0, 5.0]])
    assert _find(dt, verts, (0.0, 0.0), (2, 2), 100.0) is None
    # the farthest shift (2, 2) is at exactly 2*sqrt(2): distance <= radius is excluded
    assert _find(dt, verts, (0.0, 0.0), (2, 2), math.hypot(2, 2)) is None
    got = _find(dt, verts, (0.0, 0.0), (2, 2), math.hypot(2, 2) - 1e-9)
    assert got is not None and got[0] in {(-2, -2), (-2, 2), (2, -2), (2, 2)}


@pytest.mark.parametrize("window", [(-1, 3), (3, -1), (-2, -2)])
def test_negative_margin_scans_nothing(window):
    dt = _bowl(9, 9, [(4, 4), (1, 1)])
    verts = np.array([[4.0, 4.0]])
    assert _find(dt, verts, (0.0, 0.0), window, 0.5) is None


def test_zero_window_only_the_origin():
    dt = _bowl(9, 9, [(4, 4)])
    verts = np.array([[4.0, 4.0]])
    # the only shift (0, 0) is at distance 0 <= 0.0: excluded
    assert _find(dt, verts, (0.0, 0.0), (0, 0), 0.0) is None
    # converged elsewhere: (0, 0) is a candidate
    got = _find(dt, verts, (1.0, 0.0), (0, 0), 0.5)
    assert got == ((0, 0), 1.0, 0.0, 1.0)


def test_every_candidate_undefined_is_none():
    dt = np.ones((5, 5))
    verts = np.array([[0.0, 0.0], [0.0, 4.0]])
    # window (1, 0): shifts (-1, 0), (0, 0) (excluded: distance 0) and (1, 0). With fraction
    # 1.0 a shift that pushes a vertex out of bounds has an undefined cost and is skipped.
    assert _find(dt, verts, (0.0, 0.0), (1, 0), 0.5,
                 min_support_fraction=1.0) == ((1, 0), 1.0, 1.0, 1.0)
    verts_top = np.array([[4.0, 0.0], [4.0, 4.0]])
    assert _find(dt, verts_top, (0.0, 0.0), (1, 0), 0.5, min_support_fraction=1.0) == \
        ((-1, 0), 1.0, 1.0, 1.0)
    dt1 = np.ones((1, 5))
    verts_row = np.array([[0.0, 0.0], [0.0, 4.0]])
    assert _find(dt1, verts_row, (0.0, 0.0), (1, 1), 0.5, min_support_fraction=1.0) is None


# ---------------------------------------------------------------- the rule

def test_finds_the_second_basin():
    dt = _bowl(15, 15, [(7, 7), (7, 11)])
    verts = np.array([[7.0, 7.0], [7.0, 7.0]])
    got = _find(dt, verts, (0.0, 0.0), (5, 5), 1.5)
    assert got == ((0, 4), 4.0, 0.0, 0.0)
    assert got == _expected_basin(dt, verts, (0.0, 0.0), (5, 5), 1.5)


def test_rival_need_not_beat_converged_cost():
    dt = _bowl(11, 11, [(5, 5)])
    verts = np.array([[5.0, 5.0]])
    got = _find(dt, verts, (0.0, 0.0), (3, 3), 0.5)
    # nearest ring: cost 1 at the four axis shifts; (-1, 0) is scanned first
    assert got == ((-1, 0), 1.0, 1.0, 0.0)
    assert got[2] > got[3]


def test_exact_tie_keeps_first_scanned_dv_outer_du_inner():
    dt = np.zeros((9, 9))
    verts = np.array([[4.0, 4.0]])
    # every shift has cost 0; the distances from (0, 0): the smallest outside radius 0.5 is 1,
    # at (-1, 0), (0, -1), (0, 1), (1, 0); dv outer, du inner scans (-1, 0) first
    assert _find(dt, verts, (0.0, 0.0), (2, 2), 0.5) == ((-1, 0), 1.0, 0.0, 0.0)
    # with only du to scan, (0, -1) comes before (0, 1)
    assert _find(dt, verts, (0.0, 0.0), (0, 2), 0.5) == ((0, -1), 1.0, 0.0, 0.0)
    # radius 1: the next ring at sqrt(2): (-1, -1) first
    assert _find(dt, verts, (0.0, 0.0), (2, 2), 1.0) == ((-1, -1), math.hypot(1, 1), 0.0, 0.0)


def test_cost_then_distance():
    dt = np.full((11, 11), 2.0)
    dt[5, 8] = 0.5   # shift (0, 3): cheaper, farther
    dt[5, 6] = 1.0   # shift (0, 1)
    verts = np.array([[5.0, 5.0]])
    assert _find(dt, verts, (0.0, 0.0), (4, 4), 0.5) == ((0, 3), 3.0, 0.5, 2.0)
    # equal cost: the smaller distance wins, even when scanned later
    dt[2, 5] = 0.5   # shift (-3, 0), distance 3 scanned before (0, 3)
    dt[5, 7] = 0.5   # shift (0, 2), distance 2
    assert _find(dt, verts, (0.0, 0.0), (4, 4), 0.5) == ((0, 2), 2.0, 0.5, 2.0)


def test_fractional_converged_offset_bilinear_and_distance():
    rng = np.random.default_rng(8)
    dt = rng.random((12, 13)) * 5
    verts = np.array([[4.0, 5.0], [6.5, 6.25], [8.0, 3.0]])
    conv = (0.3, -0.45)
    got = _find(dt, verts, conv, (3, 3), 1.2)
    exp = _expected_basin(dt, verts, conv, (3, 3), 1.2)
    assert got[0] == exp[0]
    assert got[1] == pytest.approx(exp[1], rel=1e-15)
    assert got[2] == pytest.approx(exp[2], rel=1e-12)
    assert got[3] == pytest.approx(exp[3], rel=1e-12)
    assert got[1] == pytest.approx(math.hypot(got[0][0] - conv[0], got[0][1] - conv[1]),
                                   rel=1e-15)


def test_in_bounds_is_continuous_closed_interval():
    # vertices exactly on the last row / column are in bounds; half a pixel beyond is not
    dt = np.ones((4, 4))
    dt[3, 3] = 0.0
    verts = np.array([[3.0, 3.0], [0.0, 0.0]])
    # shift (0, 0): both in bounds (mean of 0 and 1) -> converged cost 0.5
    got = _find(dt, verts, (0.0, 0.0), (1, 1), 0.5, min_support_fraction=1.0)
    # with fraction 1.0 only shifts keeping both vertices in [0, 3]: none besides (0, 0)
    assert got is None
    got = _find(dt, verts, (0.0, 0.0), (1, 1), 0.5, min_support_fraction=0.5)
    # shift (1, 1): only (1, 1) in bounds, cost 1.0; (-1, -1): only (2, 2), cost 1.0 ...
    exp = _expected_basin(dt, verts, (0.0, 0.0), (1, 1), 0.5, 0.5)
    assert got == exp
    assert exp[3] == 0.5


def test_margins_are_int_of_window_entries():
    dt = _bowl(15, 15, [(7, 7), (7, 10)])
    verts = np.array([[7.0, 7.0]])
    # int(2.9) = 2: the rival at du = 3 is outside the scanned window
    a = _find(dt, verts, (0.0, 0.0), (2.9, 2.9), 0.5)
    b = _find(dt, verts, (0.0, 0.0), (2, 2), 0.5)
    assert a == b
    assert _find(dt, verts, (0.0, 0.0), (3.2, 3.7), 2.5) == ((0, 3), 3.0, 0.0, 0.0)


# ---------------------------------------------------------------- NumPy mean (pairwise)

# DT values for 16 vertices at shifts (0, -1) and (0, 1), permutations of one multiset;
# found by a seeded search so that NumPy's pairwise mean ranks (0, 1) strictly cheaper
# while a left-to-right mean ranks (0, -1) cheaper or equal.
_VALS = [0.1, 0.2, 0.3, 0.7, 1.1, 1.3, 2.9, 0.35, 0.45, 3.3]
_IA = [0, 9, 4, 8, 7, 2, 3, 6, 8, 9, 4, 1, 9, 8, 7, 3]
_IB = [9, 9, 8, 3, 9, 4, 8, 6, 0, 3, 1, 7, 4, 8, 2, 7]


def test_cost_is_numpy_mean():
    n = len(_IA)
    dt = np.full((1, 3 * n + 3), 9.0)
    verts = np.array([[0.0, 3.0 * i + 1.0] for i in range(n)])
    for i in range(n):
        dt[0, 3 * i] = _VALS[_IA[i]]        # shift (0, -1)
        dt[0, 3 * i + 2] = _VALS[_IB[i]]    # shift (0, +1)
        dt[0, 3 * i + 1] = 0.0              # converged (0, 0)
    a = np.array([_VALS[k] for k in _IA])
    b = np.array([_VALS[k] for k in _IB])
    assert b.mean() < a.mean()
    sa = sb = 0.0
    for x, y in zip(a, b, strict=True):
        sa += x
        sb += y
    assert sb / n >= sa / n
    exp = _expected_basin(dt, verts, (0.0, 0.0), (0, 1), 0.5)
    assert exp == ((0, 1), 1.0, float(b.mean()), 0.0)
    assert _find(dt, verts, (0.0, 0.0), (0, 1), 0.5) == exp


# ---------------------------------------------------------------- seeded random scenes

@pytest.mark.parametrize("fraction", [0.25, 0.5, 1.0])
def test_random_scenes_match_transcription(fraction):
    rng = np.random.default_rng(31)
    for _ in range(60):
        h, w = int(rng.integers(2, 12)), int(rng.integers(2, 12))
        dt = rng.random((h, w)) * rng.choice([1.0, 10.0])
        if rng.random() < 0.3:
            dt = np.round(dt)  # many exact ties
        n = int(rng.choice([1, 2, 5, 12, 30]))
        verts = np.stack([rng.uniform(-2, h + 1, n), rng.uniform(-2, w + 1, n)], axis=1)
        if rng.random() < 0.4:
            verts = np.round(verts)
        conv = (float(rng.uniform(-2, 2)), float(rng.uniform(-2, 2)))
        if rng.random() < 0.3:
            conv = (float(round(conv[0])), float(round(conv[1])))
        window = (int(rng.integers(-1, 4)), int(rng.integers(-1, 4)))
        radius = float(rng.choice([0.0, 0.5, 1.0, 1.5, 2.0, 10.0]))
        exp = _expected_basin(dt, verts, conv, window, radius, fraction)
        got = _find(dt, verts, conv, window, radius, min_support_fraction=fraction)
        if exp is None:
            assert got is None
            continue
        assert got is not None
        assert got[0] == exp[0]
        assert got[1] == pytest.approx(exp[1], rel=1e-15)
        assert got[2] == pytest.approx(exp[2], rel=1e-12)
        assert got[3] == pytest.approx(exp[3], rel=1e-12)


# ---------------------------------------------------------------- input handling

def test_lists_accepted_same_result():
    dt = _bowl(9, 9, [(4, 4), (4, 7)])
    verts = np.array([[4.0, 4.0], [5.0, 4.0]])
    a = _find(dt, verts, (0.0, 0.0), (3, 3), 1.0)
    b = _find(dt.tolist(), verts.tolist(), [0.0, 0.0], [3, 3], 1.0)
    assert a == b


def test_rotation_helper_pattern():
    # today's terminator technique: rotate the vertices by the fitted angle first
    dt = _bowl(15, 15, [(7, 7)])
    verts = np.array([[5.0, 7.0], [9.0, 7.0]])
    rotated = dtalign._rotate_vertices(verts, verts.mean(axis=0), 0.2)
    got = _find(dt, np.asarray(rotated), (0.0, 0.0), (2, 2), 0.5)
    assert got == _expected_basin(dt, np.asarray(rotated), (0.0, 0.0), (2, 2), 0.5)


@pytest.mark.parametrize("arg,value", [
    ("vertices_vu", np.array([[1.0, np.nan]])),
    ("vertices_vu", np.array([[1.0, np.inf]])),
    ("vertices_vu", np.zeros((3, 3))),
    ("image_edge_dt", np.full((5, 5), np.nan)),
    ("image_edge_dt", np.ones(5)),
    ("converged_offset_vu", (np.nan, 0.0)),
    ("converged_offset_vu", (0.0, 0.0, 0.0)),
])
def test_refuses_non_finite_or_misshaped(arg, value):
    kw = dict(image_edge_dt=np.ones((5, 5)), vertices_vu=np.array([[2.0, 2.0]]),
              converged_offset_vu=(0.0, 0.0), search_window_vu=(1, 1), exclude_radius_px=0.5)
    kw[arg] = value
    image_edge_dt = kw.pop("image_edge_dt")
    vertices_vu = kw.pop("vertices_vu")
    with pytest.raises(ValueError, match=arg):
        dtalign.find_secondary_dt_minimum(image_edge_dt, vertices_vu, **kw)
