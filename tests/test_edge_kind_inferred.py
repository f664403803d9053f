"""A plain fit with no declared kind reads the kind off the image (dtalign.pipeline.edge_kind)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from dtalign import scenes
from dtalign.pipeline import PolylineFit, fit_polyline
from dtalign.pipeline import uncertainty as unc
from dtalign.pipeline.edge_kind import (
    LIMB_DRIFT,
    MIN_VERTICES,
    RAMP_DRIFT,
    edge_drift,
    infer_edge_kind,
)


@pytest.fixture(scope="module")
def sphere():
    return scenes.render_sphere(shape=(240, 240), center_vu=(120.3, 119.6), radius_px=70.0,
                                phase_deg=40.0, illumination_deg=30.0, offset_vu=(0.4, -0.7),
                                read_noise_dn=1.0, seed=2)


def _plain(image, poly, **kw):
    return fit_polyline(image, poly.vertices_vu, poly.normals_vu, poly.sigmas,
                        search_window_vu=(8, 8), **kw)


def test_a_rendered_limb_is_read_as_a_limb_and_gets_the_limb_floor(sphere):
    fit = _plain(sphere.image, sphere.limb)
    assert fit.edge_kind is None and fit.inferred_edge_kind == "limb"
    assert fit.uncertainty.source == "dt_limb"
    assert fit.uncertainty.floor_px == unc.FLOORS_PX["dt_limb"]
    declared = _plain(sphere.image, sphere.limb, edge_kind="limb")
    assert declared.inferred_edge_kind is None
    np.testing.assert_array_equal(fit.covariance, declared.covariance)
    # the limb's photometric bias is inside the ellipse the floor gives
    err = np.subtract(fit.offset_vu, sphere.true_offset_vu)
    assert float(err @ np.linalg.inv(fit.covariance) @ err) < 13.8155


def test_a_rendered_terminator_is_read_as_one_and_is_suspect(sphere):
    fit = _plain(sphere.image, sphere.terminator)
    assert fit.inferred_edge_kind == "terminator"
    assert fit.uncertainty.source == "dt_terminator"
    assert [str(r) for r in fit.reasons] == ["terminator_without_profile"]
    assert str(fit.status) == "suspect"


@pytest.mark.parametrize("seed", [7, 13, 46])
def test_heavy_noise_does_not_hide_a_terminator(seed):
    """A faint, noisy terminator on few vertices: the noise moves its median profile
    between neighbouring samples by more than MAX_INNER_STEP of the step, which once read
    as a second edge inside (no kind, the plain step's floor). Steps the noise explains do
    not count, and the ramp is read for what it is."""
    rng = np.random.default_rng(seed)
    sc = scenes.render_sphere(radius_px=float(rng.uniform(50, 90)),
                              phase_deg=float(rng.uniform(25, 60)),
                              illumination_deg=float(rng.uniform(0, 360)), offset_vu=(0.4, -0.3),
                              albedo_dn=60.0, background_dn=10.0, read_noise_dn=4.0,
                              poisson_gain=2.0, seed=seed, n_vertices=70, psf_sigma_px=1.0)
    fit = _plain(sc.image, sc.terminator)
    assert fit.inferred_edge_kind == "terminator"
    assert fit.uncertainty.source == "dt_terminator"
    assert fit.status != "ok"


def test_the_drift_is_the_one_the_kind_is_read_from(sphere):
    for poly, kind in ((sphere.limb, "limb"), (sphere.terminator, "terminator")):
        fit = _plain(sphere.image, poly)
        drift = edge_drift(sphere.image, fit.evidence.points_vu, fit.normals_vu, fit.lm.weights)
        assert fit.inferred_edge_kind == kind
        assert (drift > RAMP_DRIFT) if kind == "terminator" else (LIMB_DRIFT <= drift <= RAMP_DRIFT)


def test_a_uniform_disc_is_a_plain_step():
    sc = scenes.disc_scene()
    p = sc.polyline
    fit = fit_polyline(sc.image, p.vertices_vu, p.normals_vu, p.sigmas, search_window_vu=(30, 30))
    assert fit.inferred_edge_kind is None and fit.uncertainty.source == "dt"


def test_the_navigation_scene_edges_are_plain_steps():
    nav = scenes.navigation_scene()
    for poly in nav.polylines:
        fit = fit_polyline(nav.image, poly.vertices_vu, poly.normals_vu, poly.sigmas,
                           search_window_vu=(30, 30))
        assert fit.inferred_edge_kind is None


def test_the_shapes_on_synthetic_strips():
    """Profiles along +u of a straight edge at u = 50: a step, a step whose bright side keeps
    brightening, a ramp, a step with a second, darker step 5 px inside, and too few
    vertices."""
    u = np.arange(120, dtype=float)[None, :].repeat(80, axis=0)
    pts = np.stack([np.arange(10.0, 70.0), np.full(60, 50.0)], axis=1)
    normals = np.tile([0.0, 1.0], (60, 1))
    w = np.ones(60)
    step = np.where(u >= 50, 100.0, 5.0)
    limb = np.where(u >= 50, 80.0 + 2.0 * (u - 50), 5.0)
    ramp = np.where(u >= 47, 5.0 + 4.0 * (u - 47), 5.0)
    rim = np.where(u >= 50, np.where(u >= 55, 40.0, 100.0), 5.0)
    assert infer_edge_kind(step, pts, normals, w) is None
    assert infer_edge_kind(limb, pts, normals, w) == "limb"
    assert infer_edge_kind(ramp, pts, normals, w) == "terminator"
    assert infer_edge_kind(rim, pts, normals, w) is None  # a second edge 5 px in
    # the normals away from the bright side: no step up, no kind
    assert infer_edge_kind(limb, pts, -normals, w) is None
    few = np.zeros(60)
    few[: MIN_VERTICES - 1] = 1.0
    assert infer_edge_kind(limb, pts, normals, few) is None


def test_the_inferred_kind_survives_the_dict_round_trip(sphere):
    fit = _plain(sphere.image, sphere.limb)
    d = json.loads(json.dumps(fit.to_dict(arrays=True)))
    assert d["inferred_edge_kind"] == "limb"
    back = PolylineFit.from_dict(d)
    assert back.inferred_edge_kind == "limb"
    np.testing.assert_allclose(back.covariance, fit.covariance, rtol=1e-15)
