""":ref:`contract-numerics` (covariance), §3 and §8.1: ``lm_subpixel_refine`` and its ridge stage.

The scene: a DT that is the distance to a circle of radius 6 centred at (12, 12)
on a 25 x 25 grid; the image gradient points radially outward with a
magnitude peaked on the circle; the vertices lie on the circle, displaced by a
known offset; outward normals are accepted by polarity, flipped ones rejected.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import dtalign
import dtalign.ridge

pytestmark = pytest.mark.filterwarnings("error")

H = W = 25
CV = CU = 12.0
R = 6.0
TRUE_OFFSET = (0.6, -0.4)


def _scene(n=24):
    vv, uu = np.mgrid[0:H, 0:W].astype(np.float64)
    rr = np.hypot(vv - CV, uu - CU)
    dt = np.abs(rr - R)
    mag = np.exp(-0.5 * (rr - R) ** 2)
    with np.errstate(invalid="ignore", divide="ignore"):
        gv = np.where(rr > 0, (vv - CV) / rr, 0.0) * mag
        gu = np.where(rr > 0, (uu - CU) / rr, 0.0) * mag
    grad = np.stack([gv, gu], axis=-1)
    t = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    normals = np.stack([np.cos(t), np.sin(t)], axis=1)
    verts = np.stack([CV + R * np.cos(t), CU + R * np.sin(t)], axis=1)
    verts = verts - np.array(TRUE_OFFSET)  # the fit must return TRUE_OFFSET
    return dt, grad, verts, normals


def _refine(**kw):
    dt, grad, verts, normals = _scene()
    base = dict(vertices_vu=verts, normals_vu=normals,
                sigma_normal_per_vertex_px=np.ones(len(verts)), image_edge_dt=dt,
                image_gradient_vu=grad)
    base.update(kw)
    r = dtalign.lm_subpixel_refine(**base)
    assert isinstance(r, dtalign.LMRefineResult)
    return r


def _tukey(r, c):
    s = r / c
    return np.where(np.abs(s) <= 1.0, (1.0 - s * s) ** 2, 0.0)


# ---------------------------------------------------------------- §2 covariance

@pytest.mark.parametrize("p", [1, 2, 3])
def test_covariance_no_rows_is_zero(p):
    cov = dtalign.information_matrix_to_covariance(np.zeros((0, p)), np.zeros(0))
    assert cov.shape == (p, p) and cov.dtype == np.float64
    np.testing.assert_array_equal(cov, np.zeros((p, p)))


@pytest.mark.parametrize("p", [2, 3])
def test_covariance_no_positive_weight_is_zero(p):
    j = np.arange(5.0 * p).reshape(5, p) + 1.0
    cov = dtalign.information_matrix_to_covariance(j, np.zeros(5))
    assert cov.shape == (p, p)
    np.testing.assert_array_equal(cov, np.zeros((p, p)))
    # a caller's s2 * cov with s2 == 0 stays 0 (no 0 * inf)
    np.testing.assert_array_equal(0.0 * cov, np.zeros((p, p)))


def test_covariance_full_rank():
    rng = np.random.default_rng(2)
    j = rng.normal(size=(12, 3))
    w = rng.random(12)
    a = np.sqrt(w)[:, None] * j
    expected = np.linalg.inv(a.T @ a)
    cov = dtalign.information_matrix_to_covariance(j, w)
    np.testing.assert_allclose(cov, expected, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(cov, cov.T)


def test_covariance_rank_deficient_is_zero_along_null_direction():
    j = np.zeros((6, 2))
    j[:, 0] = [1.0, -2.0, 0.5, 1.0, 3.0, -1.0]
    w = np.array([1.0, 0.5, 2.0, 0.0, 1.0, 0.25])
    cov = dtalign.information_matrix_to_covariance(j, w)
    info = float(np.sum(w * j[:, 0] ** 2))
    np.testing.assert_allclose(cov, [[1.0 / info, 0.0], [0.0, 0.0]], rtol=1e-12, atol=1e-15)


# ---------------------------------------------------------------- §3 / §8.1 results

# the bilinear |r - 6| field has kinks on the grid lines: the LM zig-zags to ~1e-3 px,
# so the convergence tests use a 0.03 px step tolerance
TOL = 0.03


def test_converges_to_known_offset():
    r = _refine(initial_offset_vu=(1.0, 0.0), use_polarity=False, step_tolerance_px=TOL)
    assert r.converged
    assert not r.degenerate
    assert r.offset_vu[0] == pytest.approx(TRUE_OFFSET[0], abs=0.1)
    assert r.offset_vu[1] == pytest.approx(TRUE_OFFSET[1], abs=0.1)
    assert isinstance(r.offset_vu, tuple) and all(isinstance(x, float) for x in r.offset_vu)
    assert r.polarity_rejected_count == 0
    assert r.covariance.shape == (2, 2)


def test_polarity_rejected_count_and_raw_rms_over_accepted():
    dt, grad, verts, normals = _scene()
    flipped = np.zeros(len(verts), dtype=bool)
    flipped[[1, 5, 6, 13]] = True
    norms = np.where(flipped[:, None], -normals, normals)
    seed = (1.0, 0.0)
    accepted = dtalign.polarity_filter(verts, norms, grad, offset_vu=seed)
    np.testing.assert_array_equal(accepted, ~flipped)  # the premise
    r = _refine(normals_vu=norms, initial_offset_vu=seed)
    assert r.polarity_rejected_count == 4
    assert type(r.polarity_rejected_count) is int
    res = np.asarray(r.residuals_px)
    # §3: rejected residuals are the 1e6 penalty, with zero weight
    np.testing.assert_array_equal(res[flipped], np.full(4, dtalign._INFINITY_DT_PENALTY_PX))
    np.testing.assert_array_equal(np.asarray(r.weights)[flipped], np.zeros(4))
    # §8.1: raw RMS over the polarity-accepted vertices only
    assert r.raw_rms_px == pytest.approx(math.sqrt(np.mean(res[accepted] ** 2)), rel=1e-12)
    assert r.raw_rms_px < 1.0
    assert r.offset_vu[0] == pytest.approx(TRUE_OFFSET[0], abs=0.1)


def test_polarity_rejected_count_matches_seed_filter():
    dt, grad, verts, normals = _scene()
    # flip the gradient on the right of the disc: some outward vertices are rejected
    grad2 = grad.copy()
    grad2[:, 17:, :] *= -1.0
    seed = (0.0, 0.0)
    accepted = dtalign.polarity_filter(verts, normals, grad2, offset_vu=seed)
    r = _refine(image_gradient_vu=grad2, initial_offset_vu=seed)
    assert r.polarity_rejected_count == int((~accepted).sum())
    assert r.polarity_rejected_count > 0
    res = np.asarray(r.residuals_px)
    np.testing.assert_array_equal(res[~accepted], dtalign._INFINITY_DT_PENALTY_PX)
    assert r.raw_rms_px == pytest.approx(math.sqrt(np.mean(res[accepted] ** 2)), rel=1e-12)


def test_raw_rms_without_polarity_is_over_all():
    r = _refine(use_polarity=False, initial_offset_vu=(0.0, 0.0))
    res = np.asarray(r.residuals_px)
    assert r.polarity_rejected_count == 0
    assert r.raw_rms_px == pytest.approx(math.sqrt(np.mean(res ** 2)), rel=1e-12)
    r2 = _refine(use_polarity=True, initial_offset_vu=(0.0, 0.0))
    assert r2.polarity_rejected_count == 0
    res2 = np.asarray(r2.residuals_px)
    assert r2.raw_rms_px == pytest.approx(math.sqrt(np.mean(res2 ** 2)), rel=1e-12)


def test_all_rejected_raw_rms_inf_and_degenerate():
    dt, grad, verts, normals = _scene()
    r = _refine(normals_vu=-normals)
    assert r.polarity_rejected_count == len(verts)
    assert r.raw_rms_px == math.inf
    assert r.degenerate
    assert r.inlier_count == 0
    assert r.rms_px == math.inf
    assert r.covariance.shape == (2, 2)
    assert np.all(np.isposinf(r.covariance))
    assert not r.converged


@pytest.mark.parametrize("fit_rotation", [False, True])
def test_degenerate_keeps_inf_covariance(fit_rotation):
    _, grad, verts, normals = _scene()
    flat = np.full((H, W), 64.0)  # every residual 64 sigma: Tukey weight 0
    kw = dict(image_edge_dt=flat, use_polarity=False, fit_rotation=fit_rotation)
    if fit_rotation:
        kw["pivot_distance_px"] = 10.0
    r = _refine(**kw)
    p = 3 if fit_rotation else 2
    assert r.degenerate and r.inlier_count == 0
    assert r.covariance.shape == (p, p)
    assert np.all(np.isposinf(r.covariance))
    assert r.rms_px == math.inf
    assert r.raw_rms_px == pytest.approx(64.0, rel=1e-15)
    assert r.iterations == 0
    assert r.offset_vu == (0.0, 0.0)
    assert not r.converged
    assert r.polarity_rejected_count == 0


def test_polyline_outside_image_is_legal_degenerate():
    r = _refine(initial_offset_vu=(200.0, -300.0))
    assert r.degenerate
    assert r.polarity_rejected_count == 24  # outside the image: rejected by polarity
    assert r.raw_rms_px == math.inf
    assert np.all(np.isposinf(r.covariance))
    r = _refine(initial_offset_vu=(200.0, -300.0), use_polarity=False)
    assert r.degenerate
    assert r.polarity_rejected_count == 0
    assert math.isfinite(r.raw_rms_px)


def test_result_arrays_read_only():
    r = _refine()
    for name in ("covariance", "residuals_px", "weights"):
        arr = getattr(r, name)
        assert isinstance(arr, np.ndarray) and not arr.flags.writeable


# ---------------------------------------------------------------- §8.1 replaceable ridge stage

RIDGE_KEYWORDS = {"vertices_vu", "normals_vu", "sigma_normal_per_vertex_px", "gradient_magnitude",
                  "initial_offset_vu", "weight_mask", "initial_rotation_rad", "fit_rotation",
                  "pivot_vu", "pivot_distance_px", "tukey_c"}


class _FakeRidge:
    def __init__(self, offset=(1.25, -0.75), rotation=0.0, converged=True, applied=True):
        self.calls = []
        self.result = dtalign.RidgeRefineResult(offset_vu=offset, rotation_rad=rotation,
                                                iterations=3, converged=converged,
                                                applied=applied)

    def __call__(self, *args, **kwargs):
        self.calls.append((args, kwargs))
        return self.result


def _check_float64_array(x, expected):
    assert isinstance(x, np.ndarray)
    assert x.dtype == np.float64
    np.testing.assert_array_equal(x, expected)


def test_ridge_replacement_called_with_spec_keywords(monkeypatch):
    dt, grad, verts, normals = _scene()
    flipped = np.zeros(len(verts), dtype=bool)
    flipped[[2, 9]] = True
    norms = np.where(flipped[:, None], -normals, normals)
    sigmas = np.full(len(verts), 0.8)
    fake = _FakeRidge()
    monkeypatch.setattr(dtalign.ridge, "gradient_ridge_refine", fake)
    r = dtalign.lm_subpixel_refine(
        vertices_vu=verts, normals_vu=norms, sigma_normal_per_vertex_px=sigmas,
        image_edge_dt=dt, image_gradient_vu=grad, initial_offset_vu=(1, 0), max_iterations=0,
        final_gradient_ridge=True, tukey_c=4.0)
    assert len(fake.calls) == 1
    args, kw = fake.calls[0]
    assert args == ()
    assert set(kw) == RIDGE_KEYWORDS
    _check_float64_array(kw["vertices_vu"], verts)
    _check_float64_array(kw["normals_vu"], norms)
    _check_float64_array(kw["sigma_normal_per_vertex_px"], sigmas)
    gm = kw["gradient_magnitude"]
    assert isinstance(gm, np.ndarray) and gm.dtype == np.float64 and gm.shape == (H, W)
    np.testing.assert_allclose(gm, np.hypot(grad[..., 0], grad[..., 1]), rtol=1e-15, atol=0)
    off = kw["initial_offset_vu"]
    assert isinstance(off, tuple) and len(off) == 2
    assert all(type(x) is float for x in off)
    assert off == (1.0, 0.0)  # max_iterations=0: the LM pose is the seed
    accepted = dtalign.polarity_filter(verts, norms, grad, offset_vu=(1.0, 0.0))
    np.testing.assert_array_equal(accepted, ~flipped)
    _check_float64_array(kw["weight_mask"], accepted.astype(np.float64))
    assert kw["initial_rotation_rad"] == 0.0
    assert kw["fit_rotation"] is False
    np.testing.assert_allclose(np.asarray(kw["pivot_vu"], dtype=np.float64), verts.mean(axis=0),
                               rtol=1e-14)
    assert kw["pivot_distance_px"] == 0.0
    assert kw["tukey_c"] == 4.0
    # its result is used: the new pose, residuals and weights recomputed there
    assert r.offset_vu == (1.25, -0.75)
    assert r.iterations == 0
    assert bool(r.converged) is True  # LM (no iteration) False OR ridge True
    moved = dtalign.apply_translation(verts, 1.25, -0.75)
    expected_r = np.where(flipped, dtalign._INFINITY_DT_PENALTY_PX,
                          dtalign.sample_dt_bilinear(dt, moved))
    np.testing.assert_allclose(np.asarray(r.residuals_px), expected_r, rtol=1e-12, atol=1e-12)
    expected_w = (1.0 / sigmas ** 2) * _tukey(expected_r / sigmas, 4.0) * accepted
    np.testing.assert_allclose(np.asarray(r.weights), expected_w, rtol=1e-12, atol=1e-15)
    assert r.polarity_rejected_count == 2


def test_ridge_replacement_not_applied_keeps_lm_pose(monkeypatch):
    fake = _FakeRidge(applied=False, converged=True)
    monkeypatch.setattr(dtalign.ridge, "gradient_ridge_refine", fake)
    r = _refine(initial_offset_vu=(1.0, 0.0), max_iterations=0, final_gradient_ridge=True)
    assert len(fake.calls) == 1
    assert r.offset_vu == (1.0, 0.0)
    assert not r.converged  # the ridge result was not applied


def test_ridge_applied_unconverged_keeps_lm_flag(monkeypatch):
    fake = _FakeRidge(applied=True, converged=False)
    monkeypatch.setattr(dtalign.ridge, "gradient_ridge_refine", fake)
    r = _refine(initial_offset_vu=(1.0, 0.0), max_iterations=0, final_gradient_ridge=True)
    assert r.offset_vu == (1.25, -0.75)
    assert not r.converged


def test_ridge_or_with_converged_lm(monkeypatch):
    base = _refine(initial_offset_vu=(1.0, 0.0), use_polarity=False, step_tolerance_px=TOL)
    assert base.converged  # the premise: this LM converges on its own
    lm_pose = base.offset_vu
    fake = _FakeRidge(offset=(lm_pose[0] + 0.1, lm_pose[1]), applied=True, converged=False)
    monkeypatch.setattr(dtalign.ridge, "gradient_ridge_refine", fake)
    r = _refine(initial_offset_vu=(1.0, 0.0), use_polarity=False, final_gradient_ridge=True,
                step_tolerance_px=TOL)
    assert r.converged
    assert r.iterations == base.iterations
    _, kw = fake.calls[0]
    assert kw["initial_offset_vu"] == lm_pose
    np.testing.assert_array_equal(kw["weight_mask"], np.ones(24))
    assert kw["weight_mask"].dtype == np.float64
    assert r.offset_vu == (lm_pose[0] + 0.1, lm_pose[1])


def test_ridge_replacement_with_rotation(monkeypatch):
    fake = _FakeRidge(offset=(1.1, 0.1), rotation=0.03, applied=True, converged=True)
    monkeypatch.setattr(dtalign.ridge, "gradient_ridge_refine", fake)
    r = _refine(initial_offset_vu=(1.0, 0.0), initial_rotation_rad=0.02, fit_rotation=True,
                pivot_vu=(5.0, 6.0), pivot_distance_px=10.0, max_iterations=0,
                final_gradient_ridge=True)
    _, kw = fake.calls[0]
    assert kw["fit_rotation"] is True
    assert kw["initial_rotation_rad"] == 0.02
    assert kw["pivot_distance_px"] == 10.0
    np.testing.assert_array_equal(np.asarray(kw["pivot_vu"], dtype=np.float64), [5.0, 6.0])
    assert r.offset_vu == (1.1, 0.1)
    assert r.rotation_rad == 0.03
    assert r.converged
    assert r.covariance.shape == (3, 3)


def test_ridge_not_called_without_positive_weight(monkeypatch):
    fake = _FakeRidge()
    monkeypatch.setattr(dtalign.ridge, "gradient_ridge_refine", fake)
    r = _refine(image_edge_dt=np.full((H, W), 64.0), final_gradient_ridge=True)
    assert fake.calls == []
    assert r.degenerate


def test_ridge_not_called_when_off(monkeypatch):
    fake = _FakeRidge()
    monkeypatch.setattr(dtalign.ridge, "gradient_ridge_refine", fake)
    _refine(initial_offset_vu=(1.0, 0.0))
    assert fake.calls == []


def test_unreplaced_ridge_stage_composes_as_spec():
    # §3 step 3 with the compiled ridge: the same as running the LM, then
    # gradient_ridge_refine from its pose with the §8.1 keywords
    dt, grad, verts, normals = _scene()
    sig = np.ones(len(verts))
    base = _refine(initial_offset_vu=(1.0, 0.0))
    full = _refine(initial_offset_vu=(1.0, 0.0), final_gradient_ridge=True)
    mask = dtalign.polarity_filter(verts, normals, grad, offset_vu=(1.0, 0.0))
    ridge = dtalign.gradient_ridge_refine(
        vertices_vu=verts, normals_vu=normals, sigma_normal_per_vertex_px=sig,
        gradient_magnitude=np.hypot(grad[..., 0], grad[..., 1]),
        initial_offset_vu=base.offset_vu, weight_mask=mask.astype(np.float64),
        initial_rotation_rad=0.0, fit_rotation=False, pivot_vu=tuple(verts.mean(axis=0)),
        pivot_distance_px=0.0, tukey_c=dtalign.DEFAULT_TUKEY_C)
    assert full.iterations == base.iterations
    if ridge.applied:
        np.testing.assert_allclose(full.offset_vu, ridge.offset_vu, rtol=1e-12, atol=1e-12)
        assert bool(full.converged) == (bool(base.converged) or bool(ridge.converged))
    else:
        assert full.offset_vu == base.offset_vu
        assert bool(full.converged) == bool(base.converged)


# ---------------------------------------------------------------- §3 details

def test_zero_iterations_state_at_seed():
    dt, grad, verts, normals = _scene()
    r = _refine(initial_offset_vu=(1.0, 0.0), max_iterations=0, use_polarity=False)
    assert r.iterations == 0
    assert r.offset_vu == (1.0, 0.0)
    assert not r.converged
    expected = dtalign.sample_dt_bilinear(dt, dtalign.apply_translation(verts, 1.0, 0.0))
    np.testing.assert_allclose(np.asarray(r.residuals_px), expected, rtol=1e-12, atol=1e-12)
    expected_w = _tukey(expected, dtalign.DEFAULT_TUKEY_C)
    np.testing.assert_allclose(np.asarray(r.weights), expected_w, rtol=1e-12, atol=1e-15)
    assert r.inlier_count == int((expected_w > 0).sum())
    assert r.rms_px == pytest.approx(
        math.sqrt(np.sum(expected_w * expected ** 2) / np.sum(expected_w)), rel=1e-12)


def test_trust_region_bounds_the_offset():
    r = _refine(initial_offset_vu=(1.0, 0.0), trust_region_px=0.1, use_polarity=False)
    assert math.hypot(r.offset_vu[0] - 1.0, r.offset_vu[1]) <= 0.1
    assert r.offset_vu != (1.0, 0.0)  # it did move towards the optimum


def test_single_vertex_and_straight_line_are_silent():
    dt, grad, verts, normals = _scene()
    r = _refine(vertices_vu=verts[:1], normals_vu=normals[:1],
                sigma_normal_per_vertex_px=np.ones(1), use_polarity=False)
    assert r.covariance.shape == (2, 2)
    line_dt = np.abs(np.arange(W, dtype=np.float64) - 10.0)[None, :].repeat(H, axis=0)
    line = np.stack([np.arange(5.0, 20.0), np.full(15, 10.3)], axis=1)
    ln = np.tile([0.0, 1.0], (15, 1))
    r = dtalign.lm_subpixel_refine(vertices_vu=line, normals_vu=ln,
                                   sigma_normal_per_vertex_px=np.ones(15), image_edge_dt=line_dt,
                                   use_polarity=False, step_tolerance_px=TOL)
    assert r.offset_vu[1] == pytest.approx(-0.3, abs=0.05)
    assert r.offset_vu[0] == 0.0  # the unobservable direction does not move
    # the covariance is zero along the null (v) direction
    assert r.covariance[0, 0] == pytest.approx(0.0, abs=1e-12)
    assert r.covariance[1, 1] > 0


# ---------------------------------------------------------------- §4 gradient_ridge_refine

def _ridge_field(u_peak):
    uu = np.arange(W, dtype=np.float64)
    prof = np.exp(-0.5 * ((uu - u_peak) / 0.8) ** 2)
    return np.repeat(prof[None, :], H, axis=0)


def _line():
    verts = np.stack([np.arange(6.0, 19.0), np.full(13, 10.0)], axis=1)
    return verts, np.tile([0.0, 1.0], (13, 1)), np.ones(13)


def test_ridge_moves_onto_the_peak():
    verts, norms, sig = _line()
    r = dtalign.gradient_ridge_refine(vertices_vu=verts, normals_vu=norms,
                                      sigma_normal_per_vertex_px=sig,
                                      gradient_magnitude=_ridge_field(11.0),
                                      initial_offset_vu=(0.0, 0.0))
    assert isinstance(r, dtalign.RidgeRefineResult)
    assert r.applied
    assert r.iterations >= 1
    assert r.converged
    # the peak on a pixel node: the sampled profile is symmetric about it, delta = 0
    assert r.offset_vu[1] == pytest.approx(1.0, abs=1e-9)
    assert r.offset_vu[0] == pytest.approx(0.0, abs=1e-12)


def test_ridge_displacement_cap_returns_inputs():
    verts, norms, sig = _line()
    r = dtalign.gradient_ridge_refine(vertices_vu=verts, normals_vu=norms,
                                      sigma_normal_per_vertex_px=sig,
                                      gradient_magnitude=_ridge_field(12.0),
                                      initial_offset_vu=(0.25, 0.0), initial_rotation_rad=0.0)
    # the peak is 2 px away: beyond the 1.5 px cap, the inputs come back
    assert not r.applied
    assert r.offset_vu == (0.25, 0.0)
    assert r.rotation_rad == 0.0
    r2 = dtalign.gradient_ridge_refine(vertices_vu=verts, normals_vu=norms,
                                       sigma_normal_per_vertex_px=sig,
                                       gradient_magnitude=_ridge_field(12.0),
                                       initial_offset_vu=(0.25, 0.0),
                                       max_total_displacement_px=2.5)
    assert r2.applied
    assert r2.offset_vu[1] == pytest.approx(2.0, abs=0.05)


def test_ridge_flat_magnitude_no_iteration():
    verts, norms, sig = _line()
    r = dtalign.gradient_ridge_refine(vertices_vu=verts, normals_vu=norms,
                                      sigma_normal_per_vertex_px=sig,
                                      gradient_magnitude=np.ones((H, W)),
                                      initial_offset_vu=(1.0, -1.0))
    # k* = 0 (first maximum) for every vertex: none valid, no iteration ran
    assert not r.applied
    assert r.iterations == 0
    assert r.offset_vu == (1.0, -1.0)


def test_ridge_weight_mask_zero_no_iteration():
    verts, norms, sig = _line()
    r = dtalign.gradient_ridge_refine(vertices_vu=verts, normals_vu=norms,
                                      sigma_normal_per_vertex_px=sig,
                                      gradient_magnitude=_ridge_field(10.3),
                                      initial_offset_vu=(0.0, 0.0), weight_mask=np.zeros(13))
    assert not r.applied and r.iterations == 0 and r.offset_vu == (0.0, 0.0)


# ---------------------------------------------------------------- §2 Jacobian and §3 step 4

def _pose(verts, pivot, dv, du, theta):
    rot = verts if theta == 0.0 else np.asarray(dtalign._rotate_vertices(verts, pivot, theta))
    return rot + np.array([dv, du])


@pytest.mark.parametrize("fit_rotation", [False, True])
def test_covariance_from_section2_jacobian_at_the_seed(fit_rotation):
    dt, grad, verts, normals = _scene()
    flipped = np.zeros(len(verts), dtype=bool)
    flipped[[3, 4]] = True
    norms = np.where(flipped[:, None], -normals, normals)
    seed, theta = (1.0, 0.0), (0.01 if fit_rotation else 0.0)
    kw = dict(normals_vu=norms, initial_offset_vu=seed, max_iterations=0)
    if fit_rotation:
        kw.update(fit_rotation=True, initial_rotation_rad=theta, pivot_distance_px=10.0)
    r = _refine(**kw)
    pivot = tuple(verts.mean(axis=0))
    pos = _pose(verts, pivot, seed[0], seed[1], theta)
    cols = [
        (dtalign.sample_dt_bilinear(dt, pos + [0.25, 0.0])
         - dtalign.sample_dt_bilinear(dt, pos - [0.25, 0.0])) / 0.5,
        (dtalign.sample_dt_bilinear(dt, pos + [0.0, 0.25])
         - dtalign.sample_dt_bilinear(dt, pos - [0.0, 0.25])) / 0.5,
    ]
    if fit_rotation:
        cols.append((dtalign.sample_dt_bilinear(dt, _pose(verts, pivot, *seed, theta + 1e-3))
                     - dtalign.sample_dt_bilinear(dt, _pose(verts, pivot, *seed, theta - 1e-3)))
                    / 2e-3)
    jac = np.stack(cols, axis=1)
    res = np.where(flipped, dtalign._INFINITY_DT_PENALTY_PX, dtalign.sample_dt_bilinear(dt, pos))
    np.testing.assert_allclose(np.asarray(r.residuals_px), res, rtol=1e-12, atol=1e-12)
    w = _tukey(res, dtalign.DEFAULT_TUKEY_C) * ~flipped
    np.testing.assert_allclose(np.asarray(r.weights), w, rtol=1e-12, atol=1e-15)
    expected = dtalign.information_matrix_to_covariance(jac, w)
    assert r.covariance.shape == (jac.shape[1],) * 2
    np.testing.assert_allclose(r.covariance, expected, rtol=1e-8, atol=1e-12)
    assert r.rotation_rad == theta
