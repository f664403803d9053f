"""Behaviours of :ref:`contract-numerics` to :ref:`contract-ridge`, worked out by hand on tiny inputs.

Each test builds an input whose answer follows from the contract's text alone
(a linear or V-shaped DT, a one-row coarse search, a Gaussian ridge, ...),
so these tests do not depend on ``dtalign.reference``. The last ones check
whole fits on the scenes of :ref:`contract-scenes`.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

import dtalign
from dtalign import reference as ref
from dtalign.scenes import disc_scene, navigation_scene

C = dtalign.DEFAULT_TUKEY_C


def row_line(n, v=18.0, u0=5.0):
    """``n`` vertices on row ``v`` with normals +v and unit sigmas."""
    return (np.column_stack([np.full(n, v), np.arange(n) + u0]), np.tile([1.0, 0.0], (n, 1)), np.ones(n))


V_DT = np.abs(np.arange(40.0)[:, None] - 20.0) * np.ones((1, 40))  # V-shaped DT, minimum on row 20


def fit(verts, normals, sigmas, dt, **kw):
    kw.setdefault("use_polarity", False)
    return dtalign.lm_subpixel_refine(vertices_vu=verts, normals_vu=normals,
                                      sigma_normal_per_vertex_px=sigmas, image_edge_dt=dt, **kw)


# --------------------------------------------------------------------------
# Bilinear sampler
# --------------------------------------------------------------------------


def test_bilinear_hand_values():
    dt = np.array([[0.0, 1.0, 4.0], [2.0, 3.0, 8.0]])
    pts = [[0.5, 0.5], [0.25, 0.75], [1.0, 2.0], [0.0, 1.5], [1.0, 0.0]]
    want = [1.5, 0.75 * 0.75 + 2 * 0.25 * 0.25 + 3 * 0.25 * 0.75, 8.0, 2.5, 2.0]
    np.testing.assert_array_equal(dtalign.sample_dt_bilinear(dt, pts), want)


def test_bilinear_clamps_to_the_image():
    dt = np.arange(12.0).reshape(3, 4)
    pts = [[-5.0, -5.0], [10.0, 1.0], [1.0, 99.0], [-0.5, 2.5], [2.0, 3.0], [1e9, -1e9]]
    want = [dt[0, 0], dt[2, 1], dt[1, 3], 0.5 * dt[0, 2] + 0.5 * dt[0, 3], dt[2, 3], dt[2, 0]]
    np.testing.assert_array_equal(dtalign.sample_dt_bilinear(dt, pts), want)
    assert dtalign.sample_dt_bilinear(np.array([[7.0]]), [[3.3, -2.0]])[0] == 7.0  # 1 x 1 image


def test_bilinear_formula_order_bit_for_bit():
    rng = np.random.default_rng(3)
    dt = rng.normal(0.0, 30.0, (9, 13))
    pts = np.column_stack([rng.uniform(-1, 10, 400), rng.uniform(-1, 14, 400)])
    v = np.clip(pts[:, 0], 0, 8)
    u = np.clip(pts[:, 1], 0, 12)
    v0, u0 = np.floor(v).astype(int), np.floor(u).astype(int)
    v1, u1 = np.minimum(v0 + 1, 8), np.minimum(u0 + 1, 12)
    fv, fu = v - v0, u - u0
    want = (dt[v0, u0] * (1 - fv) * (1 - fu) + dt[v0, u1] * (1 - fv) * fu
            + dt[v1, u0] * fv * (1 - fu) + dt[v1, u1] * fv * fu)
    np.testing.assert_array_equal(dtalign.sample_dt_bilinear(dt, pts), want)


def test_apply_translation_returns_a_shifted_copy():
    verts = np.array([[1.0, 2.0], [3.0, 4.0]])
    out = dtalign.apply_translation(verts, 0.5, -1.0)
    np.testing.assert_array_equal(out, [[1.5, 1.0], [3.5, 3.0]])
    np.testing.assert_array_equal(verts, [[1.0, 2.0], [3.0, 4.0]])


# --------------------------------------------------------------------------
# Polyline mask and coarse search
# --------------------------------------------------------------------------


def test_polyline_mask_rounds_half_to_even_and_drops_outside():
    verts = [[0.5, 1.5], [2.5, 0.5], [-0.5, 3.5], [-0.51, 0.0], [3.5, 0.0], [1.0, 4.5], [1.2, 2.7]]
    mask = dtalign.build_polyline_mask(verts, (4, 5))
    # 0.5 -> 0, 1.5 -> 2, 2.5 -> 2, -0.5 -> -0 (row 0), 4.5 -> 4; -0.51 -> -1 and 3.5 -> 4 are outside
    want = np.zeros((4, 5), dtype=bool)
    for v, u in [(0, 2), (2, 0), (0, 4), (1, 4), (1, 3)]:
        want[v, u] = True
    np.testing.assert_array_equal(mask, want)


def _one_row(poly_u, edge_u, width):
    poly = np.zeros((1, width), dtype=bool)
    edge = np.zeros((1, width), dtype=bool)
    poly[0, poly_u] = True
    edge[0, edge_u] = True
    return edge, poly


def test_coarse_score_is_the_in_bounds_fraction_not_the_count():
    # du=-2 keeps one pixel inside, on an edge: 1/1; du=+2 and +3 overlap twice: 2/3.
    edge, poly = _one_row([0, 1, 2], [0, 3, 4], 10)
    assert dtalign.coarse_ncc_search(edge, poly, (0, 3), min_support_fraction=0.0) == (0, -2)
    # the default floor of :ref:`contract-changes`: one pixel of three inside (< 0.5 * 3) is no candidate
    assert dtalign.coarse_ncc_search(edge, poly, (0, 3)) == (0, 2)


def test_coarse_exact_ties_between_different_counts_use_the_key():
    # du=-2: 1 of 2 in-bounds pixels on an edge; du=+4: 2 of 4. Both exactly 0.5,
    # every other shift lower: the nearer shift wins although it overlaps less.
    edge, poly = _one_row([0, 1, 2, 3], [1, 6, 7], 12)
    assert dtalign.coarse_ncc_search(edge, poly, (0, 4)) == (0, -2)


def test_coarse_tie_break_key_order():
    poly = np.zeros((11, 11), dtype=bool)
    poly[5, 5] = True
    edge = np.zeros_like(poly)

    def add_and_search(*shifts):
        for dv, du in shifts:
            edge[5 + dv, 5 + du] = True
        return dtalign.coarse_ncc_search(edge, poly, (4, 4))

    # every candidate scores exactly 1.0; key = (|dv|+|du|, |dv|, dv, du)
    assert add_and_search((2, 2), (0, 3)) == (0, 3)  # Manhattan, not Euclidean
    assert add_and_search((1, 1), (-1, 1), (2, 0), (-2, 0)) == (-1, 1)
    assert add_and_search((0, 2), (0, -2)) == (0, -2)
    assert add_and_search((1, 0)) == (1, 0)
    assert add_and_search((-1, 0)) == (-1, 0)
    assert add_and_search((0, 1)) == (0, 1)
    assert add_and_search((0, 0)) == (0, 0)


def test_coarse_finds_a_planted_shift():
    rng = np.random.default_rng(5)
    poly = rng.random((40, 50)) < 0.05
    edge = np.roll(poly, (3, -7), axis=(0, 1))
    assert dtalign.coarse_ncc_search(edge, poly, (10, 10)) == (3, -7)
    assert dtalign.coarse_ncc_search(edge.astype(float), poly.astype(np.uint8), (10, 10)) == (3, -7)


def test_coarse_empty_polyline_gives_zero():
    edge = np.ones((6, 6), dtype=bool)
    assert dtalign.coarse_ncc_search(edge, np.zeros((6, 6), dtype=bool), (3, 3)) == (0, 0)


def test_coarse_skips_shifts_that_leave_no_pixel_inside():
    poly = np.zeros((3, 3), dtype=bool)
    poly[0, 0] = True
    edge = np.ones((3, 3), dtype=bool)
    edge[0, 0] = False
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no 0/0 along the way
        # Negative shifts move the only pixel off the image: skipped, so they
        # cannot win the tie (key of (0, -1) would beat (0, 1)).
        assert dtalign.coarse_ncc_search(edge, poly, (2, 2)) == (0, 1)


# --------------------------------------------------------------------------
# Polarity, Tukey, covariance
# --------------------------------------------------------------------------

SIGNED_ROWS = np.zeros((3, 3, 2))
SIGNED_ROWS[:, :, 0] = np.array([1.0, -1.0, 1.0])[:, None]  # g_v = +1, -1, +1 on rows 0, 1, 2


def test_polarity_strictly_positive_dot_product():
    verts = np.ones((4, 2)) * 2.0
    normals = [[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [1e-300, 0.0]]  # +1, -1, 0, tiny positive
    np.testing.assert_array_equal(dtalign.polarity_filter(verts, normals, SIGNED_ROWS),
                                  [True, False, False, True])


def test_polarity_rounds_half_to_even_and_rejects_outside():
    verts = [[0.5, 1.0], [1.5, 1.0], [2.5, 1.0], [-0.5, 1.0], [-0.51, 1.0], [1.0, 3.5], [1.0, 1.0]]
    normals = np.tile([1.0, 0.0], (7, 1))
    # rows read: 0, 2, 2, -0 (inside), -1 (outside), column 4 (outside), row 1 (g_v < 0)
    np.testing.assert_array_equal(dtalign.polarity_filter(verts, normals, SIGNED_ROWS),
                                  [True, True, True, True, False, False, False])


def test_polarity_applies_the_offset_before_rounding():
    verts, normals = [[0.2, 1.0]], [[1.0, 0.0]]
    assert dtalign.polarity_filter(verts, normals, SIGNED_ROWS, offset_vu=(1.3, 0.0))[0]  # 1.5 -> 2
    assert not dtalign.polarity_filter(verts, normals, SIGNED_ROWS, offset_vu=(1.0, 0.0))[0]  # -> 1
    assert not dtalign.polarity_filter(verts, normals, SIGNED_ROWS, offset_vu=(0.0, 2.4))[0]  # u -> 3


def test_tukey_values():
    r = np.array([0.0, C / 2, -C / 2, C, -C, np.nextafter(C, 10.0), 10 * C, np.inf, np.nan])
    np.testing.assert_array_equal(dtalign.tukey_biweight_weights(r),
                                  [1.0, 0.5625, 0.5625, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    w = dtalign.tukey_biweight_weights(np.array([1.0, 1.5]), c=2.0)
    np.testing.assert_array_equal(w, [(1 - 0.25) ** 2, (1 - 0.5625) ** 2])


def test_covariance_is_the_inverse_information_matrix():
    jac = np.array([[1.0, 0.0], [0.0, 2.0], [1.0, 1.0]])
    w = np.array([1.0, 0.5, 2.0])
    # I = [[3, 2], [2, 4]] by hand; its inverse is [[4, -2], [-2, 3]] / 8
    cov = dtalign.information_matrix_to_covariance(jac, w)
    np.testing.assert_allclose(cov, [[0.5, -0.25], [-0.25, 0.375]], rtol=1e-14)
    assert np.array_equal(cov, cov.T)


def test_covariance_matches_a_hand_pinvh():
    rng = np.random.default_rng(8)
    jac, w = rng.normal(size=(20, 3)), rng.uniform(0.0, 2.0, 20)
    a = np.sqrt(w)[:, None] * jac
    vals, vecs = np.linalg.eigh(a.T @ a)
    keep = np.abs(vals) > 1e-9 * np.abs(vals).max()
    hand = (vecs[:, keep] / vals[keep]) @ vecs[:, keep].T
    np.testing.assert_allclose(dtalign.information_matrix_to_covariance(jac, w), hand, rtol=1e-10)


def test_covariance_of_a_straight_edge_is_rank_one():
    n = np.array([0.6, 0.8])  # every row the same normal: only n is observable
    w = np.array([1.0, 2.0, 0.5, 0.5])
    cov = dtalign.information_matrix_to_covariance(np.tile(n, (4, 1)), w)
    np.testing.assert_allclose(cov, np.outer(n, n) / w.sum(), atol=1e-15)
    along = np.array([-0.8, 0.6])
    assert abs(along @ cov @ along) <= 1e-15  # zero variance along the edge, not inf
    axis = dtalign.information_matrix_to_covariance(np.tile([1.0, 0.0], (3, 1)), np.ones(3))
    assert axis[1, 1] == 0.0 and axis[0, 0] == pytest.approx(1 / 3, rel=1e-15)


def test_covariance_rcond_cutoff():
    jac, w = np.diag([1.0, 1e-5]), np.ones(2)  # eigenvalues 1 and 1e-10
    np.testing.assert_allclose(dtalign.information_matrix_to_covariance(jac, w), np.diag([1.0, 0.0]))
    np.testing.assert_allclose(dtalign.information_matrix_to_covariance(jac, w, rcond=1e-12),
                               np.diag([1.0, 1e10]), rtol=1e-9)


def test_covariance_without_information_is_zero():
    # the design's guard cases, no positive weight and no rows: :ref:`contract-numerics` gives the
    # zero matrix (a caller's s2 * cov with s2 == 0 must stay 0, not 0 * inf)
    for jac, w in ((np.ones((3, 2)), np.zeros(3)), (np.ones((0, 3)), np.ones(0))):
        cov = dtalign.information_matrix_to_covariance(jac, w)
        assert cov.shape == (jac.shape[1],) * 2 and cov.dtype == np.float64
        assert np.array_equal(cov, np.zeros_like(cov))
        np.testing.assert_array_equal(cov, ref.information_matrix_to_covariance(jac, w))


# --------------------------------------------------------------------------
# Pose transform, residuals, Jacobian (seen through max_iterations=0)
# --------------------------------------------------------------------------

RAMP = 2.0 * np.arange(60.0)[:, None] + 3.0 * np.arange(60.0)[None, :] + 1.0  # DT = 2v + 3u + 1
RNG = np.random.default_rng(1)
RAMP_VERTS = RNG.uniform(20.0, 40.0, (10, 2))
BIG_SIGMAS = np.full(10, 1000.0)  # r / sigma < 0.35: every weight positive
RAMP_NORMALS = np.tile([1.0, 0.0], (10, 1))


def ramp_fit(**kw):
    return fit(RAMP_VERTS, RAMP_NORMALS, BIG_SIGMAS, RAMP, max_iterations=0, **kw)


def spec_weights(r, sigma, c=C):
    s = r / sigma / c
    return (1.0 / sigma**2) * np.where(np.abs(s) <= 1, (1 - s * s) ** 2, 0.0)


def test_pose_transform_rotates_about_the_pivot_then_translates():
    pv, pu, th, dv, du = 30.0, 28.0, 0.3, 1.25, -2.5
    res = ramp_fit(initial_offset_vu=(dv, du), initial_rotation_rad=th, pivot_vu=(pv, pu))
    v, u = RAMP_VERTS[:, 0], RAMP_VERTS[:, 1]
    v2 = pv + math.cos(th) * (v - pv) - math.sin(th) * (u - pu) + dv
    u2 = pu + math.sin(th) * (v - pv) + math.cos(th) * (u - pu) + du
    np.testing.assert_allclose(res.residuals_px, 2 * v2 + 3 * u2 + 1, rtol=1e-12)
    assert res.offset_vu == (dv, du) and res.rotation_rad == th  # no iteration: the initial pose


def test_default_pivot_is_the_vertex_centroid():
    centroid = tuple(RAMP_VERTS.mean(axis=0))
    a = ramp_fit(initial_rotation_rad=-0.2)
    b = ramp_fit(initial_rotation_rad=-0.2, pivot_vu=centroid)
    np.testing.assert_array_equal(a.residuals_px, b.residuals_px)


def test_zero_rotation_uses_the_vertices_unrotated():
    # With a far pivot, pv + 1.0 * (v - pv) != v in floating point: an exact
    # match with the plain translated samples shows no rotation arithmetic ran.
    far = (1.0e7 + 0.3, -1.0e7 - 0.7)
    res = ramp_fit(initial_offset_vu=(0.1, 0.2), pivot_vu=far, fit_rotation=True, pivot_distance_px=5.0)
    plain = dtalign.sample_dt_bilinear(RAMP, dtalign.apply_translation(RAMP_VERTS, 0.1, 0.2))
    np.testing.assert_array_equal(res.residuals_px, plain)


def test_max_iterations_zero_reports_the_state_at_the_initial_pose():
    res = ramp_fit(initial_offset_vu=(0.5, -0.25))
    r = 2 * (RAMP_VERTS[:, 0] + 0.5) + 3 * (RAMP_VERTS[:, 1] - 0.25) + 1
    np.testing.assert_allclose(res.residuals_px, r, rtol=1e-13)
    np.testing.assert_allclose(res.weights, spec_weights(r, BIG_SIGMAS), rtol=1e-12)
    assert (res.iterations, res.converged, res.degenerate, res.inlier_count) == (0, False, False, 10)
    w = res.weights
    assert res.rms_px == pytest.approx(math.sqrt(np.sum(w * r * r) / np.sum(w)), rel=1e-12)
    assert res.raw_rms_px == pytest.approx(math.sqrt(np.mean(r * r)), rel=1e-12)
    # central differences of a linear DT: every Jacobian row is (2, 3), a rank-1 information
    a = np.array([2.0, 3.0])
    np.testing.assert_allclose(res.covariance, np.outer(a, a) / (13.0**2 * w.sum()), rtol=1e-9)


def test_covariance_uses_the_spec_jacobian_with_rotation():
    # DT = v u / 8 + 2 v + 3 u + 1 is reproduced exactly by bilinear interpolation,
    # so the translation columns are exact: (u / 8 + 2, v / 8 + 3) at the moved vertex.
    vv, uu = np.mgrid[0:60, 0:60].astype(float)
    dt = vv * uu / 8 + 2 * vv + 3 * uu + 1
    pivot, th = (30.0, 30.0), 0.1
    res = fit(RAMP_VERTS, RAMP_NORMALS, BIG_SIGMAS, dt, max_iterations=0, initial_rotation_rad=th,
              fit_rotation=True, pivot_vu=pivot, pivot_distance_px=40.0)
    d = RAMP_VERTS - pivot
    c, s = math.cos(th), math.sin(th)
    v, u = pivot[0] + c * d[:, 0] - s * d[:, 1], pivot[1] + s * d[:, 0] + c * d[:, 1]
    jv, ju = u / 8 + 2, v / 8 + 3
    # d/dtheta analytically; the 1e-3 central difference agrees to ~1e-7 relative
    jr = jv * (-s * d[:, 0] - c * d[:, 1]) + ju * (c * d[:, 0] - s * d[:, 1])
    jac = np.column_stack([jv, ju, jr])
    info = (jac * res.weights[:, None]).T @ jac
    np.testing.assert_allclose(res.covariance, np.linalg.inv(info), rtol=1e-5)


# --------------------------------------------------------------------------
# LM behaviours
# --------------------------------------------------------------------------


def test_all_vertices_rejected_by_polarity_is_degenerate():
    verts, normals, sig = row_line(6)
    grad = np.zeros((40, 40, 2))
    grad[..., 0] = 1.0
    for kw, p in [({}, 2), ({"fit_rotation": True, "pivot_distance_px": 10.0}, 3)]:
        res = fit(verts, -normals, sig, V_DT, image_gradient_vu=grad, use_polarity=True,
                  initial_offset_vu=(0.5, 0.0), **kw)
        assert res.degenerate and res.inlier_count == 0 and res.iterations == 0
        assert res.offset_vu == (0.5, 0.0) and not res.converged
        assert res.rms_px == math.inf and res.covariance.shape == (p, p)
        assert np.all(res.covariance == np.inf)
        np.testing.assert_array_equal(res.residuals_px, np.full(6, 1.0e6))  # the penalty
        np.testing.assert_array_equal(res.weights, np.zeros(6))
        # :ref:`contract-changes`: raw RMS over the polarity-accepted vertices, of which there are none
        assert res.raw_rms_px == math.inf and res.polarity_rejected_count == 6


def test_all_vertices_rejected_by_tukey_is_degenerate():
    verts, normals, _ = row_line(6, v=10.0)  # DT = 10 there
    res = fit(verts, normals, np.full(6, 0.5), V_DT)  # 10 / 0.5 = 20 > c
    assert res.degenerate and res.inlier_count == 0 and res.rms_px == math.inf
    assert res.raw_rms_px == pytest.approx(10.0, rel=1e-15)


def test_flat_dt_never_moves_and_exhausts_the_damping():
    verts, normals, sig = row_line(8)
    flat = np.full((40, 40), 5.0)
    res = fit(verts, normals, 10 * sig, flat, damping=1.0, max_iterations=100, initial_offset_vu=(0.3, 0.1))
    # zero Jacobian: zero step, equal cost, rejected; 2**20 >= 1e6 stops the loop
    assert res.offset_vu == (0.3, 0.1) and res.iterations == 20 and not res.converged
    assert not res.degenerate and res.inlier_count == 8 and res.rms_px == pytest.approx(5.0)
    np.testing.assert_array_equal(res.covariance, np.zeros((2, 2)))  # pinvh of a zero matrix
    assert fit(verts, normals, 10 * sig, flat, max_iterations=100).iterations == 30  # 1e-3 * 2**30


def test_polarity_mask_is_fixed_at_the_initial_offset():
    # g_v > 0 on rows <= 18 and < 0 below: the 10 vertices on row 18 pass at the
    # seed and keep passing on row 20; the 5 on row 22 are rejected for good.
    grad = np.zeros((40, 40, 2))
    grad[:19, :, 0], grad[19:, :, 0] = 1.0, -1.0
    good, bad = row_line(10, v=18.0), row_line(5, v=22.0, u0=20.0)
    verts, normals, sig = (np.concatenate([a, b]) for a, b in zip(good, bad, strict=True))
    res = fit(verts, normals, sig, V_DT, image_gradient_vu=grad, use_polarity=True)
    assert abs(res.offset_vu[0] - 2.0) < 1e-3 and res.inlier_count == 10
    assert np.all(res.weights[:10] > 0) and np.all(res.residuals_px[:10] < 1e-3)
    np.testing.assert_array_equal(res.residuals_px[10:], np.full(5, 1.0e6))
    np.testing.assert_array_equal(res.weights[10:], np.zeros(5))


def test_translation_jacobian_uses_a_quarter_pixel_step():
    # On row 19.9 of the V-shaped DT: (|20.15 - 20| - |19.65 - 20|) / 0.5 = -0.4
    # (a half-pixel step would give -0.2); the u column is 0: rank 1.
    verts, normals, sig = row_line(4, v=19.9)
    res = fit(verts, normals, sig, V_DT, max_iterations=0)
    w = res.weights
    np.testing.assert_allclose(w, spec_weights(np.full(4, 0.1), sig), rtol=1e-12)
    assert res.covariance[0, 0] == pytest.approx(1.0 / (np.sum(w) * 0.16), rel=1e-12)
    assert res.covariance[1, 1] == 0.0


def test_lm_moves_onto_the_edge():
    verts, normals, sig = row_line(30)
    res = fit(verts, normals, sig, V_DT)
    assert res.converged and abs(res.offset_vu[0] - 2.0) < 1e-3 and res.offset_vu[1] == 0.0


@pytest.mark.parametrize("alpha", [1.0, 3.0, 0.25])
def test_tikhonov_pulls_toward_the_seed(alpha):
    # cost sum(w) (2 - d)^2 + alpha sum(w) d^2 is minimal at d = 2 / (1 + alpha)
    verts, normals, sig = row_line(30)
    res = fit(verts, normals, sig, V_DT, tikhonov_alpha=alpha, step_tolerance_px=1e-10)
    assert res.offset_vu[0] == pytest.approx(2.0 / (1.0 + alpha), abs=1e-8)
    assert res.offset_vu[1] == 0.0


@pytest.mark.parametrize("trust", [0.5, 1.2])
def test_trust_region_bounds_the_translation(trust):
    verts, normals, sig = row_line(30)
    res = fit(verts, normals, sig, V_DT, trust_region_px=trust, initial_offset_vu=(0.0, 0.3))
    moved = math.hypot(res.offset_vu[0], res.offset_vu[1] - 0.3)
    assert trust - 0.05 < moved <= trust


def test_zero_trust_region_rejects_every_step():
    verts, normals, sig = row_line(30)
    res = fit(verts, normals, sig, V_DT, trust_region_px=0.0, damping=1.0)
    assert res.offset_vu == (0.0, 0.0) and res.iterations == 20 and not res.converged


# --------------------------------------------------------------------------
# Gradient-ridge polish
# --------------------------------------------------------------------------


def ridge_image(peak_v, width=1.5, size=40):
    return 100.0 * np.exp(-0.5 * ((np.arange(size, dtype=float)[:, None] - peak_v) / width) ** 2) * np.ones((1, size))


def polish(mag, verts=None, **kw):
    if verts is None:
        verts = row_line(20, v=19.0)[0]
    n = verts.shape[0]
    kw.setdefault("initial_offset_vu", (0.0, 0.0))
    return dtalign.gradient_ridge_refine(vertices_vu=verts, normals_vu=np.tile([1.0, 0.0], (n, 1)),
                                         sigma_normal_per_vertex_px=np.ones(n), gradient_magnitude=mag, **kw)


def test_ridge_moves_onto_the_peak():
    res = polish(ridge_image(20.3))
    assert res.applied and res.iterations >= 1
    assert abs(res.offset_vu[0] - 1.3) < 0.1 and res.offset_vu[1] == 0.0
    assert res.rotation_rad == 0.0


def test_ridge_displacement_cap_returns_the_inputs():
    start = (0.125, -0.375)
    res = polish(ridge_image(21.6), initial_offset_vu=start, initial_rotation_rad=0.0)
    assert res.iterations >= 1 and not res.applied
    assert res.offset_vu == start and res.rotation_rad == 0.0
    far = polish(ridge_image(21.6), initial_offset_vu=start, max_total_displacement_px=3.0)
    assert far.applied and far.offset_vu[0] > start[0] + 2.0


@pytest.mark.parametrize("kw", [{"max_iterations": 0}, {"weight_mask": np.zeros(20, dtype=bool)}],
                         ids=["no-iterations", "all-masked"])
def test_ridge_without_iterations_is_not_applied(kw):
    start, theta = (0.5, 2.0), 0.01
    res = polish(ridge_image(20.3), initial_offset_vu=start, initial_rotation_rad=theta, **kw)
    assert (res.iterations, res.converged, res.applied) == (0, False, False)
    assert res.offset_vu == start and res.rotation_rad == theta


def test_ridge_peak_at_the_profile_end_is_invalid():
    ramp = np.arange(40.0)[:, None] * np.ones((1, 40))  # magnitude grows along +v: no interior peak
    res = polish(ramp)
    assert res.iterations == 0 and not res.applied


def test_ridge_profile_half_count_uses_python_round():
    # The peak is 2.2 px away. round(2.5 / 1.0) == 2: samples t = -2..2, the
    # maximum is the last sample, so no vertex is valid. With 3.0, t = 3 is
    # the last sample and t = 2 an interior maximum.
    mag = ridge_image(21.2)
    short = polish(mag, half_width_px=2.5, sample_step_px=1.0, max_total_displacement_px=np.inf)
    assert short.iterations == 0 and not short.applied
    wide = polish(mag, half_width_px=3.0, sample_step_px=1.0, max_total_displacement_px=np.inf)
    assert wide.applied and wide.offset_vu[0] > 1.5


def test_lm_final_ridge_is_the_polish_from_the_lm_pose():
    verts, normals, sig = row_line(20)
    grad = np.zeros((40, 40, 2))
    grad[..., 0] = ridge_image(20.3)  # g_v > 0: polarity accepts; the DT edge is row 20
    plain = fit(verts, normals, sig, V_DT, image_gradient_vu=grad, use_polarity=True)
    polished = fit(verts, normals, sig, V_DT, image_gradient_vu=grad, use_polarity=True,
                   final_gradient_ridge=True)
    alone = dtalign.gradient_ridge_refine(
        vertices_vu=verts, normals_vu=normals, sigma_normal_per_vertex_px=sig,
        gradient_magnitude=np.hypot(grad[..., 0], grad[..., 1]), initial_offset_vu=plain.offset_vu,
        weight_mask=np.ones(20, dtype=bool))
    assert alone.applied and polished.offset_vu == alone.offset_vu
    assert polished.iterations == plain.iterations  # the count is the LM's
    # the state is recomputed at the polished pose
    moved = dtalign.apply_translation(verts, *polished.offset_vu)
    np.testing.assert_allclose(polished.residuals_px, dtalign.sample_dt_bilinear(V_DT, moved), rtol=1e-15)
    np.testing.assert_allclose(polished.weights, spec_weights(polished.residuals_px, sig), rtol=1e-14)


def test_lm_final_ridge_not_applied_changes_nothing():
    verts, normals, sig = row_line(20)
    zero_grad = np.zeros((40, 40, 2))  # flat profiles: no valid peak, nothing to polish
    a = fit(verts, normals, sig, V_DT, image_gradient_vu=zero_grad)
    b = fit(verts, normals, sig, V_DT, image_gradient_vu=zero_grad, final_gradient_ridge=True)
    assert (a.offset_vu, a.rotation_rad, a.iterations, a.converged, a.rms_px) == (
        b.offset_vu, b.rotation_rad, b.iterations, b.converged, b.rms_px)
    np.testing.assert_array_equal(a.covariance, b.covariance)


# --------------------------------------------------------------------------
# Whole fits on the scenes of :ref:`contract-scenes`
# --------------------------------------------------------------------------


def _pipeline(scene, derivatives, polylines=1, window=None, **kw):
    mag, dt, grad = derivatives.get(scene.image, scene.noise_sigma, reference=False)
    polys = scene.polylines[:polylines]
    verts = np.concatenate([p.vertices_vu for p in polys])
    normals = np.concatenate([p.normals_vu for p in polys])
    sig = np.concatenate([p.sigmas for p in polys])
    mask = dtalign.build_polyline_mask(verts, dt.shape)
    seed = dtalign.coarse_ncc_search(dt <= 0.5, mask, window or scene.search_window_vu)
    return seed, dtalign.lm_subpixel_refine(
        vertices_vu=verts, normals_vu=normals, sigma_normal_per_vertex_px=sig, image_edge_dt=dt,
        image_gradient_vu=grad, initial_offset_vu=seed, **kw)


@pytest.mark.parametrize("variant", ["base", "window50", "trust1", "outliers", "n2000"])
def test_disc_scene_offset_recovered(variant, derivatives):
    scene = disc_scene(outlier_fraction=0.1 if variant == "outliers" else 0.0,
                       n_vertices=2000 if variant == "n2000" else 200)
    seed, res = _pipeline(scene, derivatives, window=(50, 50) if variant == "window50" else None,
                          trust_region_px=1.0 if variant == "trust1" else None)
    assert seed == (7, -5)
    err = np.subtract(res.offset_vu, scene.true_offset_vu)
    assert np.hypot(*err) < 0.05 and not res.degenerate
    if variant == "outliers":  # the 20 displaced vertices carry no weight
        assert res.inlier_count <= 180 and np.all(res.weights[list(scene.outlier_indices)] == 0)


def test_navigation_scene_rotation_recovered(derivatives):
    scene = navigation_scene(rotation_rad=0.01)
    _, res = _pipeline(scene, derivatives, polylines=2, fit_rotation=True, pivot_vu=scene.pivot_vu,
                       pivot_distance_px=scene.pivot_distance_px)
    sd = np.sqrt(np.diag(res.covariance))
    assert abs(res.rotation_rad - 0.01) < min(3 * sd[2], 2e-3)
    err = np.subtract(res.offset_vu, scene.true_offset_vu)
    assert np.all(np.abs(err) < np.minimum(3 * sd[:2], 0.15))


def test_navigation_scene_all_three_polylines_recovered(derivatives):
    scene = navigation_scene(rotation_rad=0.01)
    _, res = _pipeline(scene, derivatives, polylines=3, fit_rotation=True, pivot_vu=scene.pivot_vu,
                       pivot_distance_px=scene.pivot_distance_px)
    sd = np.sqrt(np.diag(res.covariance))
    err = np.subtract(res.offset_vu, scene.true_offset_vu)
    assert abs(res.rotation_rad - 0.01) < 3 * sd[2]
    assert np.all(np.abs(err) < 3 * sd[:2])


@pytest.mark.parametrize("diag", [
    [4.0, -1.0, np.nan], [-0.0, np.inf, 0.0], [1e-300, 5e-324, -5e-324], [-np.inf, 2.0],
    [np.nan, np.nan], [2.0, 3.0],
])
def test_single_fit_sigmas_equal_the_vectorised_ones(diag):
    from dtalign.pipeline.observability import _sigma_list, _sigmas_from_cov

    rng = np.random.default_rng(len(diag))
    cov = rng.normal(size=(len(diag), len(diag)))
    np.fill_diagonal(cov, diag)
    got, want = _sigma_list(cov), _sigmas_from_cov(cov).tolist()
    assert [x.hex() for x in got] == [x.hex() for x in want]
    assert all(type(x) is float for x in got)
