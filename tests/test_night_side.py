"""A terminator whose night side is brighter than the sky: the covariance holds the kink's doubt.

A glow added over the disc leaves the kink where it is; a night side floored at
a level moves it toward the lit side, to where the shading reaches the floor.
Near the kink the two give the same strips, so the fit cannot tell them apart,
and an accepted terminator refinement carries the difference in its covariance
with the note ``night_side_lit`` (docs/profiles.rst, "A night side above the
sky"). The validation renders (tests/test_validation_renders.py) hold the same
on images this project did not make.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from dtalign import fit_polyline, sphere_edge_profile
from dtalign.pipeline.profile_fit import ProfileRefinement, horns_disagree
from dtalign.pipeline.status import FitReason
from dtalign.scenes import render_sphere

ALBEDO, SKY = 200.0, 10.0
CHI2_95 = 5.991


@pytest.fixture(scope="module", params=[55.0, 120.0], ids=["phase55", "phase120"])
def scene(request):
    return render_sphere(shape=(240, 240), center_vu=(120.3, 119.6), radius_px=60.0,
                         phase_deg=request.param, illumination_deg=30.0, offset_vu=(1.3, -0.7),
                         albedo_dn=ALBEDO, background_dn=SKY)


def _disc(sc):
    """Each pixel's share of the disc (its area inside the limb, to first order)."""
    v, u = np.mgrid[: sc.image.shape[0], : sc.image.shape[1]]
    return np.clip(sc.radius_px + 0.5 - np.hypot(v - sc.center_vu[0], u - sc.center_vu[1]),
                   0.0, 1.0)


def _fit(sc, image):
    T = sc.terminator
    prof = sphere_edge_profile(T.vertices_vu, center_vu=sc.model_center_vu,
                               radius_px=sc.radius_px, phase_deg=sc.phase_deg,
                               illumination_deg=sc.illumination_deg, edge="terminator",
                               psf_sigma_px=0.0)
    return fit_polyline(image, T.vertices_vu, T.normals_vu, T.sigmas, search_window_vu=(8, 8),
                        edge_profile=prof)


def _err(fit, sc):
    return np.asarray(fit.offset_vu) - np.asarray(sc.true_offset_vu)


def _d2(fit, sc):
    e = _err(fit, sc)
    return float(e @ np.linalg.pinv(np.asarray(fit.covariance)[:2, :2]) @ e)


def _mean_normal(sc):
    n = np.asarray(sc.terminator.normals_vu).sum(axis=0)
    return n / np.hypot(*n)


def test_a_dark_night_side_is_not_lit(scene):
    fit = _fit(scene, scene.image)
    assert fit.profile.accepted and fit.status == "ok"
    assert FitReason.NIGHT_SIDE_LIT not in fit.reasons
    assert fit.profile.night_shift_vu is None
    assert abs(fit.profile.night_level) < 1e-3 * ALBEDO
    assert not np.asarray(fit.uncertainty.bias).any()


def _lit_and_honest(fit):
    """Accepted, the note given, and ``ok`` unless the horns moved the pose (the
    sky beyond the limb in their strips is not the night side's level)."""
    assert fit.profile.accepted
    assert FitReason.NIGHT_SIDE_LIT in fit.reasons
    assert "night side lit" in fit.status_message
    assert fit.status == "ok" or (fit.status == "suspect" and horns_disagree(fit.profile)), \
        fit.status_message


def test_a_glow_barely_moves_the_kink_and_widens_the_sigma(scene):
    dark = _fit(scene, scene.image)
    glow = 0.02 * ALBEDO
    fit = _fit(scene, scene.image + glow * _disc(scene))
    _lit_and_honest(fit)
    # the horns' strips reach the sky beyond the limb, which pulls the fitted
    # background (the night side's level) down a little: 0.87-0.90 of the glow here
    assert 0.8 * glow < fit.profile.night_level < 1.05 * glow
    shift = np.asarray(fit.profile.night_shift_vu)
    n = _mean_normal(scene)
    assert shift @ n > 0.2 and abs(shift @ np.array((-n[1], n[0]))) < 1e-9
    # the glow moves the pose less than the floor would, and the covariance holds the floor's
    assert abs(float((_err(fit, scene) - _err(dark, scene)) @ n)) < shift @ n
    cov = np.asarray(fit.covariance)[:2, :2]
    assert n @ cov @ n >= (shift @ n) ** 2
    assert _d2(fit, scene) < CHI2_95


def test_a_floored_night_side_is_covered(scene):
    floor = 0.01 * ALBEDO
    fit = _fit(scene, np.maximum(scene.image, SKY + floor * _disc(scene)))
    _lit_and_honest(fit)
    along = float(_err(fit, scene) @ _mean_normal(scene))
    shift = float(np.hypot(*fit.profile.night_shift_vu))
    # the floor moves the kink toward the lit side, as the shift says, and the ellipse holds it
    assert along > 0.1 and shift > 0.2
    assert _d2(fit, scene) < CHI2_95


def test_the_night_fields_round_trip(scene):
    fit = _fit(scene, scene.image + 0.02 * ALBEDO * _disc(scene))
    back = ProfileRefinement.from_dict(fit.profile.to_dict())
    assert back.night_shift_vu == fit.profile.night_shift_vu
    assert back.night_level == fit.profile.night_level
    none = ProfileRefinement.from_dict(
        dataclasses.replace(fit.profile, night_shift_vu=None).to_dict())
    assert none.night_shift_vu is None
