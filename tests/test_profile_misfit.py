"""The profile refinement's residual test (ProfileRefinement.misfit, profile_misfit)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from dtalign import scenes, sphere_edge_profile
from dtalign.pipeline import fit_polyline
from dtalign.pipeline import profile_fit as pf
from dtalign.pipeline.status import FitReason


def _fit(law: str, fit_law: str):
    sc = scenes.render_sphere(shape=(240, 240), center_vu=(120.3, 119.6), radius_px=70.0,
                              phase_deg=40.0, illumination_deg=30.0, offset_vu=(0.4, -0.7),
                              read_noise_dn=1.0, seed=1, law=law,
                              minnaert_k=0.7 if law == "minnaert" else None)
    P = sc.limb
    extra = {"minnaert_k": 0.7} if fit_law == "minnaert" else {}
    prof = sphere_edge_profile(P.vertices_vu, center_vu=sc.model_center_vu, radius_px=70.0,
                               phase_deg=40.0, illumination_deg=30.0, law=fit_law, **extra)
    return fit_polyline(sc.image, P.vertices_vu, P.normals_vu, P.sigmas,
                        search_window_vu=(8, 8), edge_profile=prof), sc


def test_a_minnaert_limb_fitted_as_lambert_is_flagged():
    fit, sc = _fit("minnaert", "lambert")
    assert fit.profile.accepted and fit.profile.misfit > pf.MISFIT_LIMIT
    assert FitReason.PROFILE_MISFIT in fit.reasons and fit.status == "suspect"
    assert "profile misfit" in fit.status_message


@pytest.mark.parametrize("law", ["minnaert", "lambert"])
def test_the_declared_law_leaves_no_flagged_residual(law):
    fit, sc = _fit(law, law)
    ref = fit.profile
    assert ref.accepted and ref.misfit < pf.MISFIT_LIMIT / 4
    assert not pf.misfitted(ref) and fit.status == "ok"
    assert 0.0 < ref.edge_noise_px and ref.edge_scatter_px < ref.edge_noise_px + pf.SCATTER_LIMIT_PX
    assert 0.0 < ref.gain_noise and ref.gain_scatter < ref.gain_noise + pf.GAIN_SCATTER_LIMIT
    assert math.hypot(*np.subtract(fit.offset_vu, sc.true_offset_vu)) < 0.01


def test_the_rule():
    fit, _ = _fit("lambert", "lambert")
    ref = fit.profile
    def with_(**kw):
        return pf.misfitted(dataclasses.replace(ref, **kw))
    assert with_(misfit=2 * pf.MISFIT_LIMIT)
    # a spread beyond the noise: both beyond SCATTER_LIMIT_PX and SCATTER_RATIO times the noise
    assert with_(misfit=0.0, edge_noise_px=0.01, edge_scatter_px=0.05)
    assert not with_(misfit=0.0, edge_noise_px=0.04, edge_scatter_px=0.06)  # within the ratio
    assert not with_(misfit=0.0, edge_noise_px=0.001, edge_scatter_px=0.02)  # below the limit
    # a terminator's horns moving its pose: beyond HORN_SHIFT_SIGMAS and HORN_SHIFT_MIN_PX
    assert with_(horn_shift_px=-0.5, horn_shift_sigma_px=0.1)
    assert not with_(horn_shift_px=0.2, horn_shift_sigma_px=0.1)  # within the sigmas
    assert not with_(horn_shift_px=0.09, horn_shift_sigma_px=0.001)  # below the minimum
    # the vertices' own gains spread: beyond GAIN_SCATTER_LIMIT and SCATTER_RATIO times the noise
    assert with_(gain_scatter=0.05, gain_noise=0.01)
    assert not with_(gain_scatter=0.06, gain_noise=0.04)  # within the ratio
    assert not with_(gain_scatter=0.012, gain_noise=0.001)  # below the limit
    assert not with_(gain_scatter=math.nan, gain_noise=math.nan)
    # not measured, or not accepted: nothing to flag
    assert not with_(misfit=math.nan, edge_noise_px=math.nan, edge_scatter_px=math.nan)
    assert not with_(horn_shift_px=math.nan, horn_shift_sigma_px=math.nan)
    assert not with_(accepted=False, misfit=1.0)


@pytest.mark.parametrize("amplitude, flagged", [(0.0, False), (0.05, True), (0.25, True)])
def test_an_albedo_that_varies_along_the_limb_is_flagged(amplitude, flagged):
    """A Lambert limb whose albedo varies by +-amplitude around the disc (three
    cycles): one gain fits none of it, and the vertices' own gains spread."""
    sc = scenes.render_sphere(shape=(240, 240), center_vu=(120.3, 119.6), radius_px=70.0,
                              phase_deg=40.0, illumination_deg=30.0, offset_vu=(0.4, -0.7),
                              background_dn=10.0, seed=1)
    v, u = np.mgrid[:240, :240]
    albedo = 1.0 + amplitude * np.sin(3.0 * np.arctan2(v - 120.3, u - 119.6))
    image = 10.0 + (sc.image - 10.0) * albedo
    image = image + np.random.default_rng(2).normal(0.0, 1.0, image.shape)
    P = sc.limb
    prof = sphere_edge_profile(P.vertices_vu, center_vu=sc.model_center_vu, radius_px=70.0,
                               phase_deg=40.0, illumination_deg=30.0)
    fit = fit_polyline(image, P.vertices_vu, P.normals_vu, P.sigmas, search_window_vu=(8, 8),
                       edge_profile=prof)
    ref = fit.profile
    assert ref.accepted
    excess = math.sqrt(max(ref.gain_scatter**2 - ref.gain_noise**2, 0.0))
    assert (excess > pf.GAIN_SCATTER_LIMIT) is flagged
    assert (fit.status == "suspect" and FitReason.PROFILE_MISFIT in fit.reasons) is flagged
    if flagged:
        assert "their gains" in fit.status_message


def _crescent(law: str, radius_px: float, phase_deg: float, psf_sigma_px: float):
    """A noise-free terminator, its PSF estimated by the fit."""
    sc = scenes.render_sphere(shape=(200, 200), center_vu=(100.0, 100.0), radius_px=radius_px,
                              phase_deg=phase_deg, illumination_deg=0.0, law=law,
                              psf_sigma_px=psf_sigma_px, n_vertices=58)
    P = sc.terminator
    prof = sphere_edge_profile(P.vertices_vu, center_vu=sc.model_center_vu, radius_px=radius_px,
                               phase_deg=phase_deg, illumination_deg=0.0, edge="terminator",
                               law=law)
    fit = fit_polyline(sc.image, P.vertices_vu, P.normals_vu, P.sigmas,
                       search_window_vu=(8, 8), edge_profile=prof)
    return fit, math.hypot(*np.subtract(fit.offset_vu, sc.true_offset_vu))


def test_a_crescent_whose_horns_move_the_pose_is_flagged():
    # Lommel-Seeliger's horns are bright: fitted with them, this crescent's
    # pose lies 1.6 px off at 8 of its sigmas; without them, 0.3 px
    fit, err = _crescent("lommel-seeliger", 40.0, 106.0, 2.0)
    ref = fit.profile
    assert ref.accepted and err > 1.0
    assert abs(ref.horn_shift_px) > pf.HORN_SHIFT_SIGMAS * ref.horn_shift_sigma_px
    assert pf.horns_disagree(ref) and FitReason.PROFILE_MISFIT in fit.reasons
    assert fit.status == "suspect" and "horns" in fit.status_message


@pytest.mark.parametrize("law, phase_deg", [("lambert", 135.0), ("lommel-seeliger", 45.0),
                                            ("lambert", 106.0)])
def test_a_crescent_whose_horns_agree_is_not_flagged(law, phase_deg):
    fit, err = _crescent(law, 60.0, phase_deg, 0.8)
    ref = fit.profile
    assert ref.accepted and fit.status == "ok" and not pf.horns_disagree(ref)
    assert err < 0.05
