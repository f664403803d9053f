"""The LM changes of :ref:`contract-changes`, compiled against the reference.

``polarity_rejected_count``, ``raw_rms_px`` over the polarity-accepted
vertices, ``converged`` that counts an applied, converged ridge stage, and
the ridge stage reached through ``dtalign.ridge.gradient_ridge_refine`` (a
caller's replacement gets exactly the keywords :ref:`contract-changes` lists, and the compiled path
is unchanged when nothing is replaced).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import dtalign
import dtalign.ridge
from _parity_cases import build_cases, make_image
from dtalign import reference as ref
from dtalign import scenes
from dtalign.reference import fitting as ref_fitting

CASES = [c for c in build_cases() if c.image.shape[0] * c.image.shape[1] <= 256 * 256]
_DERIVATIVES: dict[str, tuple] = {}


def _derivatives(spec):
    if spec.key not in _DERIVATIVES:
        img = make_image(spec)
        _DERIVATIVES[spec.key] = ref.compute_all_image_derivatives(img, spec.noise_sigma)
    return _DERIVATIVES[spec.key]


def _kwargs(case):
    _, dt, grad = _derivatives(case.image)
    seed = ref.coarse_ncc_search(
        dt <= 0.5, ref.build_polyline_mask(case.vertices, dt.shape), case.window
    )
    return dict(
        vertices_vu=case.vertices, normals_vu=case.normals,
        sigma_normal_per_vertex_px=case.sigmas, image_edge_dt=dt, image_gradient_vu=grad,
        initial_offset_vu=(seed[0] + case.jitter[0], seed[1] + case.jitter[1]),
        **case.lm_kwargs,
    )


@pytest.mark.parametrize("case", CASES, ids=[c.case_id for c in CASES])
def test_new_lm_fields_match_the_reference(case):
    kw = _kwargs(case)
    got = dtalign.lm_subpixel_refine(**kw)
    want = ref.lm_subpixel_refine(**kw)
    assert got.polarity_rejected_count == want.polarity_rejected_count
    assert got.converged == want.converged
    # raw_rms_px: the :ref:`contract-changes` formula of the compiled path's own residuals
    # (the poses may differ by the parity bar's 1e-9 px, not the formula)
    if kw.get("use_polarity", True):
        accepted = dtalign.polarity_filter(
            kw["vertices_vu"], kw["normals_vu"], kw["image_gradient_vu"],
            offset_vu=kw["initial_offset_vu"],
        )
    else:
        accepted = np.ones(len(case.vertices), dtype=bool)
    assert got.polarity_rejected_count == int(np.count_nonzero(~accepted))
    r = got.residuals_px[accepted]
    expected_raw = float(np.sqrt(np.mean(r * r))) if r.size else math.inf
    assert got.raw_rms_px == expected_raw
    if got.offset_vu == want.offset_vu and got.rotation_rad == want.rotation_rad:
        assert got.raw_rms_px == want.raw_rms_px


def _limb_kwargs(**extra):
    s = scenes.disc_scene(shape=(256, 256), radius=70.0, n_vertices=120)
    _, dt, grad = ref.compute_all_image_derivatives(s.image, s.noise_sigma)
    p = s.polyline
    return dict(
        vertices_vu=p.vertices_vu, normals_vu=p.normals_vu, sigma_normal_per_vertex_px=p.sigmas,
        image_edge_dt=dt, image_gradient_vu=grad, initial_offset_vu=(7.0, -5.0), **extra,
    )


def test_rejected_vertices_do_not_blow_up_raw_rms():
    kw = _limb_kwargs()
    normals = kw["normals_vu"].copy()
    normals[:30] *= -1.0  # a quarter of the limb flipped: rejected at the seed
    kw["normals_vu"] = normals
    got = dtalign.lm_subpixel_refine(**kw)
    want = ref.lm_subpixel_refine(**kw)
    assert got.polarity_rejected_count == want.polarity_rejected_count == 30
    assert got.raw_rms_px < 5.0  # not ~1e6 * sqrt(30 / 120)
    assert got.raw_rms_px == pytest.approx(want.raw_rms_px, rel=1e-9)


def test_every_vertex_rejected_gives_infinite_raw_rms():
    kw = _limb_kwargs()
    kw["normals_vu"] = -kw["normals_vu"]
    for fit in (dtalign.lm_subpixel_refine(**kw), ref.lm_subpixel_refine(**kw)):
        assert fit.polarity_rejected_count == 120
        assert fit.raw_rms_px == math.inf
        assert fit.degenerate
        assert np.isinf(fit.covariance).all()


def test_no_polarity_counts_nothing_rejected():
    kw = _limb_kwargs(use_polarity=False)
    assert dtalign.lm_subpixel_refine(**kw).polarity_rejected_count == 0


_RIDGE_KEYWORDS = {
    "vertices_vu", "normals_vu", "sigma_normal_per_vertex_px", "gradient_magnitude",
    "initial_offset_vu", "weight_mask", "initial_rotation_rad", "fit_rotation", "pivot_vu",
    "pivot_distance_px", "tukey_c",
}


@pytest.mark.parametrize("module", [dtalign.ridge, ref_fitting], ids=["compiled", "reference"])
@pytest.mark.parametrize("fit_rotation", [False, True])
def test_a_replaced_ridge_stage_gets_the_spec_keywords(monkeypatch, module, fit_rotation):
    original = module.gradient_ridge_refine
    calls = []

    def recorder(**kw):
        calls.append(kw)
        return original(**kw)

    extra = dict(final_gradient_ridge=True)
    if fit_rotation:
        extra.update(fit_rotation=True, pivot_distance_px=80.0)
    kw = _limb_kwargs(**extra)
    fit = (dtalign if module is dtalign.ridge else ref).lm_subpixel_refine
    unpatched = fit(**kw)
    monkeypatch.setattr(module, "gradient_ridge_refine", recorder)
    patched = fit(**kw)
    assert len(calls) == 1
    call = calls[0]
    assert set(call) == _RIDGE_KEYWORDS
    for name in ("vertices_vu", "normals_vu", "sigma_normal_per_vertex_px", "gradient_magnitude",
                 "weight_mask"):
        assert isinstance(call[name], np.ndarray) and call[name].dtype == np.float64, name
    grad = kw["image_gradient_vu"]
    np.testing.assert_array_equal(call["gradient_magnitude"], np.hypot(grad[..., 0], grad[..., 1]))
    assert type(call["initial_offset_vu"]) is tuple and len(call["initial_offset_vu"]) == 2
    assert all(type(x) is float for x in call["initial_offset_vu"])
    seed_mask = dtalign.polarity_filter(
        kw["vertices_vu"], kw["normals_vu"], grad, offset_vu=kw["initial_offset_vu"]
    )
    np.testing.assert_array_equal(call["weight_mask"], seed_mask.astype(np.float64))
    assert call["fit_rotation"] is fit_rotation
    assert call["pivot_vu"] == pytest.approx(tuple(kw["vertices_vu"].mean(axis=0)), abs=1e-9)
    # a pass-through replacement changes nothing
    assert patched.offset_vu == unpatched.offset_vu
    assert patched.rotation_rad == unpatched.rotation_rad
    assert (patched.iterations, patched.converged) == (unpatched.iterations, unpatched.converged)
    np.testing.assert_array_equal(patched.residuals_px, unpatched.residuals_px)
    np.testing.assert_array_equal(patched.weights, unpatched.weights)
    np.testing.assert_allclose(patched.covariance, unpatched.covariance, rtol=1e-12, atol=0)


@pytest.mark.parametrize("module", [dtalign.ridge, ref_fitting], ids=["compiled", "reference"])
@pytest.mark.parametrize("applied", [False, True])
def test_a_replaced_ridge_stage_result_is_used(monkeypatch, module, applied):
    fit = (dtalign if module is dtalign.ridge else ref).lm_subpixel_refine
    kw = _limb_kwargs(final_gradient_ridge=True, max_iterations=1)  # the LM stops unconverged
    plain = fit(**{**kw, "final_gradient_ridge": False})
    assert not plain.converged

    def replacement(**call):
        dv, du = call["initial_offset_vu"]
        return dtalign.RidgeRefineResult(
            offset_vu=(dv + 0.25, du - 0.125), rotation_rad=call["initial_rotation_rad"],
            iterations=3, converged=True, applied=applied,
        )

    monkeypatch.setattr(module, "gradient_ridge_refine", replacement)
    got = fit(**kw)
    assert got.iterations == plain.iterations  # the LM's count
    if applied:
        assert got.offset_vu == (plain.offset_vu[0] + 0.25, plain.offset_vu[1] - 0.125)
        assert got.converged  # :ref:`contract-changes`: LM's or the applied ridge's
        state = fit(**{**kw, "final_gradient_ridge": False, "max_iterations": 0,
                       "initial_offset_vu": got.offset_vu})
        # the state is recomputed at the ridge pose, with the seed's polarity mask
        assert got.polarity_rejected_count == plain.polarity_rejected_count
        assert got.inlier_count > 0 and np.isfinite(got.rms_px)
        if state.polarity_rejected_count == plain.polarity_rejected_count:
            np.testing.assert_array_equal(got.residuals_px, state.residuals_px)
    else:
        assert got.offset_vu == plain.offset_vu
        assert got.converged == plain.converged
        np.testing.assert_array_equal(got.residuals_px, plain.residuals_px)


def _square_kwargs(**extra):
    """A bright square whose edges sit on half-pixels: its ridge polish
    converges in one step from the true pose."""
    img = np.zeros((80, 80))
    img[20:60, 20:60] = 100.0
    _, dt, grad = ref.compute_all_image_derivatives(img, 0.5)
    t = np.arange(24.0, 56.0, 2.0)
    side = np.full_like(t, 19.5)
    far = np.full_like(t, 59.5)
    pts = np.concatenate([np.stack(p, axis=1) for p in ((side, t), (far, t), (t, side), (t, far))])
    one = np.ones((t.size, 1))
    nrm = np.concatenate([one * [1.0, 0.0], one * [-1.0, 0.0], one * [0.0, 1.0], one * [0.0, -1.0]])
    return dict(
        vertices_vu=pts, normals_vu=nrm, sigma_normal_per_vertex_px=np.ones(len(pts)),
        image_edge_dt=dt, image_gradient_vu=grad, initial_offset_vu=(0.0, 0.0), **extra,
    )


def test_converged_counts_an_applied_converged_ridge_stage():
    """:ref:`contract-changes`: an LM stopped by its iteration cap, then an applied ridge
    stage that converged: the fit is converged, in both paths."""
    kw = _square_kwargs(final_gradient_ridge=True, max_iterations=1)
    lm_only = ref.lm_subpixel_refine(**{**kw, "final_gradient_ridge": False})
    ridge = ref.gradient_ridge_refine(
        vertices_vu=kw["vertices_vu"], normals_vu=kw["normals_vu"],
        sigma_normal_per_vertex_px=kw["sigma_normal_per_vertex_px"],
        gradient_magnitude=np.hypot(kw["image_gradient_vu"][..., 0], kw["image_gradient_vu"][..., 1]),
        initial_offset_vu=lm_only.offset_vu,
    )
    assert not lm_only.converged and ridge.applied and ridge.converged
    got = dtalign.lm_subpixel_refine(**kw)
    want = ref.lm_subpixel_refine(**kw)
    assert got.converged and want.converged
    assert got.iterations == want.iterations == lm_only.iterations
