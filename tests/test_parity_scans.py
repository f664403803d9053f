"""Parity of the scans of :ref:`contract-today`: the compiled path against ``dtalign.reference``.

Seeded random scenes, at least 200 per function, over the families the
issue names: ties, flat edge masks, polylines mostly off-frame, the support
floor at its boundary, NaN gradients, float edge masks, zero normals, and an
exclusion radius that covers the whole window. Offsets and ``None`` results
must be equal in every case; scores and costs equal to 1e-12 relative (the
compiled sums follow NumPy's pairwise order, so they are in fact equal).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.lib import NumpyVersion

import dtalign
from dtalign import reference as ref
from dtalign import scenes
from dtalign._kernels import polarity_search as ps
from dtalign._kernels.pairwise import numpy_sum

N_CASES = 220
REL = 1e-12


def _close(a: float, b: float) -> bool:
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    return abs(a - b) <= REL * max(abs(a), abs(b), 1e-300)


def _disc_image(rng, shape):
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    cv = rng.uniform(0.3, 0.7) * h
    cu = rng.uniform(0.3, 0.7) * w
    r = rng.uniform(0.15, 0.35) * min(h, w)
    img = np.where((yy - cv) ** 2 + (xx - cu) ** 2 <= r * r, 100.0, 0.0)
    if rng.random() < 0.5:  # a second, dimmer disc: edges of both polarities nearby
        img += np.where((yy - cv - r) ** 2 + (xx - cu) ** 2 <= (0.5 * r) ** 2, -40.0, 0.0)
    img += rng.normal(0.0, rng.uniform(0.5, 3.0), size=shape)
    return img, (cv, cu, r)


def _limb(rng, geometry, n, spread):
    cv, cu, r = geometry
    t = np.sort(rng.uniform(0, 2 * np.pi, n)) if rng.random() < 0.5 else np.linspace(0, 2 * np.pi, n, endpoint=False)
    verts = np.stack([cv + r * np.sin(t), cu + r * np.cos(t)], axis=1)
    verts += rng.normal(0.0, spread, size=2) + rng.normal(0.0, 0.3, size=verts.shape)
    normals = -np.stack([np.sin(t), np.cos(t)], axis=1)  # into the disc: the bright side
    return verts, normals


def _scene(seed: int) -> dict:
    """One random scene and the keywords of all three scans."""
    rng = np.random.default_rng(seed)
    shape = (int(rng.integers(24, 72)), int(rng.integers(24, 72)))
    img, geometry = _disc_image(rng, shape)
    _, dt, grad = ref.compute_all_image_derivatives(img, 1.0)
    edge = dt <= 0.5
    n = int(rng.integers(1, 60))
    verts, normals = _limb(rng, geometry, n, rng.uniform(0.0, 4.0))
    family = seed % 11
    if family == 0:  # mostly off-frame
        verts += np.array([shape[0] * rng.choice([-0.8, 0.8]), shape[1] * rng.uniform(-0.6, 0.6)])
    if family == 1:  # flat edge masks
        edge = np.zeros(shape, bool) if rng.random() < 0.5 else np.ones(shape, bool)
    if family == 2:  # NaN gradients, some at edge pixels
        bad = rng.random(shape) < 0.05
        grad = grad.copy()
        grad[bad] = np.nan
    if family == 3:  # zero normals and duplicate vertices
        normals = normals.copy()
        normals[rng.random(n) < 0.3] = 0.0
        verts = np.concatenate([verts, verts[: n // 2]])
        normals = np.concatenate([normals, normals[: n // 2]])
    if family == 4:  # integer-valued gradients and DT: exact ties
        grad = np.round(grad / 50.0)
        dt = np.round(dt)
    if family == 5:  # float edge mask values
        edge = np.where(edge, rng.uniform(0.0, 2.0, size=shape), 0.0)
    if family == 6:  # vertices on exact pixel centres and half-pixels (rint ties)
        verts = np.round(verts * 2.0) / 2.0
    if family == 7:  # a constant DT: every cost ties
        dt = np.full(shape, float(rng.integers(0, 5)))
    n_total = verts.shape[0]
    # support floor: often exactly at a count of in-frame vertices
    if rng.random() < 0.4:
        fraction = int(rng.integers(0, n_total + 1)) / n_total
    else:
        fraction = float(rng.choice([0.0, 0.25, 0.5, 0.75, 1.0, rng.uniform()]))
    window = (int(rng.integers(0, 9)), int(rng.integers(0, 9)))
    converged = (float(rng.uniform(-3, 3)), float(rng.uniform(-3, 3)))
    if family == 8:  # exclusion radius covering the whole window
        radius = float(np.hypot(window[0] + 4, window[1] + 4))
    else:
        radius = float(rng.choice([0.0, 1.0, 2.5, rng.uniform(0, 6)]))
    if family == 9:  # negative margins scan nothing (the basin takes real margins)
        basin_window = (float(rng.uniform(-2, 2)), float(rng.uniform(-2, 9)))
    else:
        basin_window = (window[0] + 0.7, float(window[1]))
    return dict(
        edge=edge, grad=np.ascontiguousarray(grad), dt=dt, verts=verts, normals=normals,
        window=window, fraction=fraction, converged=converged, radius=radius,
        basin_window=basin_window, polyline_mask=dtalign.build_polyline_mask(
            np.clip(verts, -1e6, 1e6), shape
        ),
    )


SEEDS = list(range(N_CASES))


@pytest.mark.parametrize("seed", SEEDS)
def test_polarity_search_parity(seed):
    s = _scene(seed)
    args = (s["edge"], s["grad"], s["verts"], s["normals"], s["window"])
    got = dtalign.coarse_polarity_search_scored(*args, min_support_fraction=s["fraction"])
    want = ref.coarse_polarity_search_scored(*args, min_support_fraction=s["fraction"])
    assert got.offset_vu == want.offset_vu
    assert type(got.offset_vu[0]) is int and type(got.score) is float
    assert _close(got.score, want.score)


@pytest.mark.parametrize("seed", SEEDS)
def test_ncc_scored_parity(seed):
    s = _scene(seed)
    for fraction in (s["fraction"], 0.0):
        got = dtalign.coarse_ncc_search_scored(
            s["edge"], s["polyline_mask"], s["window"], min_support_fraction=fraction
        )
        want = ref.coarse_ncc_search_scored(
            s["edge"], s["polyline_mask"], s["window"], min_support_fraction=fraction
        )
        assert got.offset_vu == want.offset_vu
        assert _close(got.score, want.score)
        assert dtalign.coarse_ncc_search(
            s["edge"], s["polyline_mask"], s["window"], min_support_fraction=fraction
        ) == got.offset_vu


@pytest.mark.parametrize("seed", SEEDS)
def test_secondary_basin_parity(seed):
    s = _scene(seed)
    kw = dict(
        converged_offset_vu=s["converged"], search_window_vu=s["basin_window"],
        exclude_radius_px=s["radius"], min_support_fraction=s["fraction"],
    )
    got = dtalign.find_secondary_dt_minimum(s["dt"], s["verts"], **kw)
    want = ref.find_secondary_dt_minimum(s["dt"], s["verts"], **kw)
    assert (got is None) == (want is None)
    if got is not None:
        assert got.offset_vu == want.offset_vu
        for name in ("distance_px", "cost_px", "converged_cost_px"):
            assert _close(getattr(got, name), getattr(want, name)), name


def test_parity_sweep_covers_the_named_cases():
    """The sweep really meets the cases it claims: ties, None results,
    NaN gradients at edge pixels, eligible-at-equality support floors."""
    none_results = ties = nan_edge = 0
    for seed in SEEDS:
        s = _scene(seed)
        kw = dict(
            converged_offset_vu=s["converged"], search_window_vu=s["basin_window"],
            exclude_radius_px=s["radius"], min_support_fraction=s["fraction"],
        )
        none_results += ref.find_secondary_dt_minimum(s["dt"], s["verts"], **kw) is None
        if seed % 11 in (1, 4, 7):
            ties += 1
        nan_edge += bool((np.isnan(s["grad"][..., 0]) & (np.asarray(s["edge"]) != 0)).any())
    assert none_results >= 20
    assert ties >= 50
    assert nan_edge >= 10


def test_large_limb_polarity_and_basin_equal_the_reference():
    """The limb of :ref:`contract-scenes`: the sparse path of the polarity search (every vertex
    inside under every shift) and the basin's early drop on a real DT."""
    scene = scenes.disc_scene(shape=(384, 384), radius=90.0, n_vertices=300)
    _, dt, grad = ref.compute_all_image_derivatives(scene.image, scene.noise_sigma)
    p = scene.polyline
    args = (dt <= 0.5, grad, p.vertices_vu, p.normals_vu, (12, 12))
    got = dtalign.coarse_polarity_search_scored(*args)
    assert got == ref.coarse_polarity_search_scored(*args)
    assert got.offset_vu == (7, -5)
    kw = dict(converged_offset_vu=(7.3, -4.6), search_window_vu=(12, 12), exclude_radius_px=3.0)
    assert dtalign.find_secondary_dt_minimum(dt, p.vertices_vu, **kw) == ref.find_secondary_dt_minimum(
        dt, p.vertices_vu, **kw
    )


#: NumPy 2.3 and later sum a contiguous float64 array as one pairwise tree,
#: which the kernels follow; earlier releases add up the pairwise sums of
#: consecutive buffers of ``np.getbufsize()`` (8192) values, left to right.
ONE_TREE = NumpyVersion(np.__version__) >= "2.3.0"


def _one_tree(a):
    """NumPy >= 2.3's pairwise tree over ``a``, its nodes of up to 8192 values
    summed by this NumPy (one tree per buffer in every release)."""
    m = a.shape[0]
    if m <= 8192:
        return np.sum(a)
    half = m // 2
    half -= half % 8
    return _one_tree(a[:half]) + _one_tree(a[half:])


@pytest.mark.parametrize("n", [*range(0, 300), 1000, 4097, 8193, 20000])
def test_pairwise_sum_is_numpys(n):
    """The kernels' sums follow NumPy's own summation tree, bit for bit.

    Over more than ``np.getbufsize()`` values that holds with NumPy >= 2.3
    only (see :data:`ONE_TREE`): on an older NumPy the kernels keep the one
    tree, pinned here by :func:`_one_tree`, and ``np.sum`` is shown to be
    the buffered sum instead (``docs/limits.rst``).
    """
    rng = np.random.default_rng(n)
    a = rng.normal(size=n) * np.exp(rng.normal(size=n) * 8)
    if ONE_TREE or n <= np.getbufsize():
        assert numpy_sum(a, n) == np.sum(a)
        if n:
            assert numpy_sum(a, n) / n == a.mean()
    else:
        assert numpy_sum(a, n) == 0.0 + _one_tree(a)
        buffered = 0.0
        for i in range(0, n, np.getbufsize()):
            buffered = buffered + np.sum(a[i : i + np.getbufsize()])
        assert np.sum(a) == buffered


@pytest.mark.parametrize("seed", SEEDS[:60])
def test_polarity_sparse_path_equals_the_dense_one(seed):
    """The two exact ways of :mod:`dtalign._kernels.polarity_search` agree bit
    for bit where both apply (every vertex inside under every shift)."""
    s = _scene(seed)
    edge = np.ascontiguousarray(np.asarray(s["edge"]) != 0)
    pts = np.ascontiguousarray(s["verts"])
    h, w = edge.shape
    mv, mu = s["window"]
    keep = ((np.rint(pts[:, 0]) - mv >= 0) & (np.rint(pts[:, 0]) + mv < h)
            & (np.rint(pts[:, 1]) - mu >= 0) & (np.rint(pts[:, 1]) + mu < w))
    if not keep.any():
        pytest.skip("no vertex stays inside under every shift")
    pts = np.ascontiguousarray(pts[keep])
    nrm = np.ascontiguousarray(s["normals"][keep])
    sparse = ps.polarity_search(edge, s["grad"], pts, nrm, mv, mu, 0.0)
    norm = np.hypot(nrm[:, 0], nrm[:, 1])
    norm = np.where(norm == 0.0, 1.0, norm)
    dense = ps._dense_scores(
        edge, s["grad"], np.rint(pts[:, 0]), np.rint(pts[:, 1]),
        nrm[:, 0] / norm, nrm[:, 1] / norm, mv, mu, 0.0, np.zeros((0, 0)),
    )
    assert sparse[:2] == dense[:2]
    assert sparse[2] == dense[2] or (math.isnan(sparse[2]) and math.isnan(dense[2]))


@pytest.mark.parametrize("seed", range(24))
def test_secondary_basin_pruning_parity(seed):
    """Wide windows over a real DT, where the early drop and the neighbours'
    bounds decide most shifts: the result is still the reference's. Some DTs are
    scaled (neighbour steps above 1) or shifted negative (no drop at all)."""
    rng = np.random.default_rng(1000 + seed)
    img, geometry = _disc_image(rng, (160, 160))
    _, dt, _ = ref.compute_all_image_derivatives(img, 1.0)
    dt = dt * [1.0, 3.0, 0.25, 1.0][seed % 4] - (2.0 if seed % 6 == 5 else 0.0)
    verts, _ = _limb(rng, geometry, int(rng.integers(20, 150)), rng.uniform(0.0, 3.0))
    kw = dict(
        converged_offset_vu=(float(rng.uniform(-2, 2)), float(rng.uniform(-2, 2))),
        search_window_vu=(int(rng.integers(10, 22)), int(rng.integers(10, 22))),
        exclude_radius_px=float(rng.uniform(0.0, 5.0)),
        min_support_fraction=float(rng.choice([0.0, 0.5, 0.9])),
    )
    got = dtalign.find_secondary_dt_minimum(dt, verts, **kw)
    want = ref.find_secondary_dt_minimum(dt, verts, **kw)
    assert got == want


def _edt(edge, sampling=(1.0, 1.0)):
    from scipy import ndimage

    return ndimage.distance_transform_edt(~edge, sampling=sampling)


@pytest.mark.parametrize("seed", range(48))
def test_secondary_basin_bounds_parity(seed):
    """The situations the scan's bounds treat apart, over wide windows: a
    vertical or horizontal step above 1 (each axis its own largest step), a
    steep cliff inside the read pixels, integer and constant DTs (exact ties
    broken in scan order whatever the visiting order), a limb partly off the
    frame (shifts that lose vertices take no neighbour's bound), and NaN or
    negative values only where no vertex can read (nothing refused, drops
    still on), and a converged offset off the window (no shift next to it)."""
    rng = np.random.default_rng(5000 + seed)
    family = seed % 8
    # (a NaN is refused up front in a DT of up to 2**16 pixels)
    shape = (260, 270) if family == 6 else (150, 170)
    img, geometry = _disc_image(rng, shape)
    edge = ref.compute_all_image_derivatives(img, 1.0)[1] <= 0.5
    sampling = {0: (2.0, 1.0), 1: (1.0, 3.0), 2: (1.0, 0.5)}.get(family, (1.0, 1.0))
    dt = _edt(edge, sampling)
    window = (int(rng.integers(8, 16)), int(rng.integers(8, 16)))
    verts, _ = _limb(rng, geometry, int(rng.integers(20, 120)), rng.uniform(0.0, 3.0))
    if family == 2:
        dt = np.round(dt)
    if family == 3:
        dt = np.full(shape, float(rng.integers(0, 3)))
    if family == 4:  # a cliff: one block of pixels raised well above its neighbours
        v, u = np.rint(verts[int(rng.integers(len(verts)))]).astype(int)
        dt[max(v - 3, 0):v + 3, max(u - 3, 0):u + 3] += 25.0
    if family == 5:  # limb pushed against the frame
        verts = verts + np.array([rng.choice([-1, 1]) * geometry[2] * 0.9, 0.0])
    if family == 6:  # values no shifted vertex reads: far from the limb, at the disc centre
        cv, cu, r = geometry
        window = (min(window[0], int(r / 3)), min(window[1], int(r / 3)))
        verts = np.stack([cv + r * np.sin(t := np.linspace(0, 2 * np.pi, 80, endpoint=False)),
                          cu + r * np.cos(t)], axis=1)
        centre = (int(cv), int(cu))
        dt[centre] = np.nan if seed % 2 else -5.0
    converged = (float(rng.uniform(-2, 2)), float(rng.uniform(-2, 2)))
    if family == 7:
        converged = tuple(float(rng.choice([-1, 1]) * rng.uniform(1.2, 3.0) * m) for m in window)
    kw = dict(
        converged_offset_vu=converged,
        search_window_vu=window, exclude_radius_px=float(rng.uniform(0.0, 4.0)),
        min_support_fraction=float(rng.choice([0.0, 0.5, 0.9])),
    )
    got = dtalign.find_secondary_dt_minimum(dt, verts, **kw)
    want = ref.find_secondary_dt_minimum(dt, verts, **kw)
    assert got == want
    if family == 6:
        assert want is not None and math.isfinite(want.cost_px)


@pytest.mark.parametrize("converged", [(3.0, 0.0), (2.6, 0.7), (3.3, 0.0), (6.8, 0.7), (-2.4, 0.0)])
@pytest.mark.parametrize("radius", [0.0, 0.5, 1.0])
@pytest.mark.parametrize("window", [(8, 4), (9, 3), (3, 3)])
def test_secondary_basin_partial_shift_takes_no_neighbour_bound(converged, radius, window):
    """The winner is a shift that pushes the two costly vertices off the
    frame (cost 0 over the ten left); its neighbours that keep all twelve
    sum high, but bound only shifts that keep all twelve too. The lattice
    visits a cost-0 shift first, so the drop bound is 0 when the winner's
    neighbours are summed."""
    vv = np.mgrid[0:40, 0:40][0].astype(float)
    dt = np.maximum(0.0, 10.0 - vv)  # steps of 1, 0 from row 10 down
    verts = np.array([[20.0, 10.0 + i] for i in range(10)] + [[1.0, 20.0], [1.3, 22.0]])
    kw = dict(converged_offset_vu=converged, search_window_vu=window, exclude_radius_px=radius,
              min_support_fraction=0.5)
    got = dtalign.find_secondary_dt_minimum(dt, verts, **kw)
    assert got == ref.find_secondary_dt_minimum(dt, verts, **kw)
    assert got is not None and got.cost_px == 0.0


@pytest.mark.parametrize("seed", range(60))
def test_secondary_basin_tight_bounds_parity(seed):
    """DTs along which the samples change by the full largest step per shift
    (L1 cones with their own vertical and horizontal slopes, their minimum,
    monotone ramps), so the neighbours' bounds are as tight as they may be:
    any bound too high by a little drops the true winner."""
    rng = np.random.default_rng(9000 + seed)
    vv, uu = np.mgrid[0:50, 0:50].astype(float)
    kind = seed % 3
    if kind == 0:
        sv, su = rng.choice([0.5, 1.0, 2.0], 2)
        dt = sv * np.abs(vv - rng.uniform(15, 35)) + su * np.abs(uu - rng.uniform(15, 35))
    elif kind == 1:
        dt = np.minimum.reduce([
            rng.uniform(0.5, 2) * np.abs(vv - rng.uniform(15, 35))
            + rng.uniform(0.5, 2) * np.abs(uu - rng.uniform(15, 35)) + rng.uniform(0, 3)
            for _ in range(3)
        ])
    else:
        dt = rng.uniform(0, 1, (50, 50)).cumsum(0) / 5 + rng.uniform(0, 1, (50, 50)).cumsum(1) / 5
    if seed % 2:
        dt = np.round(dt)  # ties
    verts = rng.uniform(18, 32, (int(rng.integers(1, 30)), 2))
    kw = dict(
        converged_offset_vu=(float(rng.uniform(-4, 4)), float(rng.uniform(-4, 4))),
        search_window_vu=(int(rng.integers(3, 10)), int(rng.integers(3, 10))),
        exclude_radius_px=float(rng.uniform(0, 3)),
    )
    assert dtalign.find_secondary_dt_minimum(dt, verts, **kw) == ref.find_secondary_dt_minimum(
        dt, verts, **kw
    )


def test_secondary_basin_step_on_a_tile_seam():
    """The DT's one step above 1 (a cliff of 5 between rows 19 and 20) falls
    between two rows of the scan's 8 x 8 pixel tiles (its readable pixels
    start at row 12); missed, the vertical step would count as 1 and the
    cost-2.5 shift at dv = 1 would wrongly rule out the cost-0 winner at
    dv = 0 (the lattice visits a cost-0 shift first)."""
    dt = np.zeros((40, 40))
    dt[20:] = 5.0
    verts = np.array([[18.5, 10.0 + i] for i in range(8)])
    kw = dict(converged_offset_vu=(5.3, 0.0), search_window_vu=(6, 2), exclude_radius_px=0.5)
    got = dtalign.find_secondary_dt_minimum(dt, verts, **kw)
    assert got == ref.find_secondary_dt_minimum(dt, verts, **kw)
    assert got.offset_vu == (0, 0) and got.cost_px == 0.0


def test_secondary_basin_refuses_a_nan_it_reads():
    """A NaN in a pixel that a shifted vertex samples is refused, naming the
    DT (too large for the up-front scan, so the kernel finds it)."""
    scene = scenes.disc_scene(shape=(300, 300), radius=80.0, n_vertices=100)
    dt = _edt(ref.compute_all_image_derivatives(scene.image, scene.noise_sigma)[1] <= 0.5)
    verts = scene.polyline.vertices_vu
    kw = dict(converged_offset_vu=(0.0, 0.0), search_window_vu=(6, 6), exclude_radius_px=2.0)
    for corner in (4, 7):  # read under the shift (4, 4); the far corner under (6, 6)
        bad = dt.copy()
        v, u = np.floor(verts[17] + 6.0).astype(int) + corner - 6
        bad[v, u] = np.nan
        with pytest.raises(ValueError, match="image_edge_dt"):
            dtalign.find_secondary_dt_minimum(bad, verts, **kw)


def test_huge_windows_over_far_flung_vertices_are_refused_not_run():
    """A polyline thrown far off the frame with a huge window would scan
    ~1e12 shifts: refused up front, naming the argument."""
    dt = np.zeros((32, 32))
    verts = np.array([[5.0, 5.0], [-1e6, 1e6]])
    with pytest.raises(ValueError, match="search_window_vu is too large"):
        dtalign.find_secondary_dt_minimum(
            dt, verts, converged_offset_vu=(0, 0), search_window_vu=(10**7, 10**7),
            exclude_radius_px=1.0,
        )
    with pytest.raises(ValueError, match="search_window_vu is too large"):
        dtalign.coarse_polarity_search_scored(
            dt <= 0.5, np.zeros((32, 32, 2)), verts, np.ones((2, 2)), (10**7, 10**7)
        )
    # a window far beyond the frame but with the vertices in it is clipped, not refused
    assert dtalign.coarse_polarity_search_scored(
        dt <= 0.5, np.ones((32, 32, 2)), verts[:1], np.ones((1, 2)), (10**7, 10**7)
    ).offset_vu == (0, 0)


def test_scan_cap_message_names_the_figure_over_its_cap():
    """The refusal names what exceeded its cap (shifts, or
    shift-vertex pairs), not a figure within it."""
    from dtalign.api.checks import MAX_SCAN_SHIFTS, MAX_SCAN_TABLE

    edge = np.zeros((64, 64), dtype=bool)
    grad = np.ones((64, 64, 2))
    # a million vertices, a +-30 window: 3721 shifts (fine), 122 x 1e6 pairs (not)
    many = np.full((1_000_000, 2), 20.0)
    with pytest.raises(ValueError) as info:
        dtalign.coarse_polarity_search_scored(edge, grad, many, np.ones_like(many), (30, 30))
    msg = str(info.value)
    assert f"122000000 shift-vertex pairs per axis (122 shift rows and columns x 1000000 " \
           f"vertices; at most {MAX_SCAN_TABLE})" in msg
    assert "shifts (at most" not in msg and "3721" not in msg
    # two far-flung vertices, a +-5000 window: 1e8 shifts (not), 40002 x 2 pairs (fine)
    far = np.array([[5.0, 5.0], [-1e6, 1e6]])
    with pytest.raises(ValueError) as info:
        dtalign.coarse_polarity_search_scored(edge, grad, far, np.ones((2, 2)), (5000, 5000))
    msg = str(info.value)
    assert f"{10001 * 10001} shifts (at most {MAX_SCAN_SHIFTS})" in msg
    assert "shift-vertex pairs" not in msg
