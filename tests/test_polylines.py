"""The public polyline builders: a sphere's limb and terminator.

* they are the scenes' polylines: :func:`dtalign.scenes.render_sphere`'s
  ``limb`` and ``terminator`` are the builders' output for its model
  sphere, bit for bit (one implementation);
* their normals are unit vectors pointing to the bright side (into the
  disc for a limb, toward the day side for a terminator) for every light
  direction, the multiples of 45 deg among them, and every vertex lies
  where it should (on the circle; on ``cos i = 0`` on the visible side);
* any count of vertices from 2 (3 .. 1000 tested) is built;
* a plain fit of a rendered sphere with the builder's limb recovers the
  planted offset;
* a bad argument raises ValueError or TypeError naming it;
* :class:`dtalign.Polyline` is the one record (``dtalign.scenes.Polyline``
  is the same class) and checks its kind.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

import dtalign
from dtalign import Polyline, scenes, sphere_limb_polyline, sphere_terminator_polyline
from dtalign.api.polylines import DEFAULT_POLYLINE_SIGMA_PX, DEFAULT_POLYLINE_VERTICES

#: Every 15 deg (the multiples of 45 among them) and a few awkward ones.
ILLUMINATIONS = [*range(0, 360, 15), -45.0, 359.999, 405.0, 12.34]
PHASES = [0.5, 20.0, 35.0, 89.9, 90.0, 90.1, 135.0, 179.5]


def _sun(ill: float) -> np.ndarray:
    a = math.radians(ill)
    return np.array([-math.cos(a), math.sin(a)])


def _cos_i(points: np.ndarray, center, radius: float, phase_deg: float, ill: float) -> np.ndarray:
    """``cos i`` of the sphere's surface seen at image ``points`` (the profiles page's)."""
    q = (points - np.asarray(center)) / radius
    cos_e = np.sqrt(np.clip(1.0 - (q**2).sum(axis=1), 0.0, None))
    p = math.radians(phase_deg)
    return math.sin(p) * (q @ _sun(ill)) + math.cos(p) * cos_e


# --------------------------------------------------------------------------- one implementation


@pytest.mark.parametrize("ill, phase, n", [(0.0, 35.0, 200), (30.0, 0.0, 57), (225.0, 120.0, 3),
                                           (-45.0, 90.0, 1000), (137.5, 12.0, 2)])
def test_render_sphere_polylines_are_the_builders(ill, phase, n):
    sc = scenes.render_sphere(shape=(64, 64), radius_px=20.0, phase_deg=phase,
                              illumination_deg=ill, offset_vu=(0.7, -1.3), oversample=1,
                              n_vertices=n)
    sphere = dict(center_vu=sc.model_center_vu, radius_px=sc.radius_px, illumination_deg=ill,
                  n_vertices=n)
    built = [sphere_limb_polyline(**sphere, phase_deg=phase)]
    got = [sc.limb]
    if phase > 0.0:
        built.append(sphere_terminator_polyline(**sphere, phase_deg=phase))
        got.append(sc.terminator)
    else:
        assert sc.terminator is None
    for mine, theirs in zip(built, got, strict=True):
        assert type(theirs) is Polyline and theirs.edge_kind == mine.edge_kind == mine.name
        for field in ("vertices_vu", "normals_vu", "sigmas"):
            np.testing.assert_array_equal(getattr(mine, field), getattr(theirs, field))


def test_one_record_and_one_sun_direction():
    assert scenes.Polyline is dtalign.Polyline is dtalign.api.polylines.Polyline
    assert scenes.sun_direction_vu is dtalign.api.polylines.sun_direction_vu
    for name in ("Polyline", "sphere_limb_polyline", "sphere_terminator_polyline"):
        assert name in dtalign.__all__
        ns: dict = {}
        exec(f"from dtalign import {name}", ns)
        assert ns[name] is getattr(dtalign.api.polylines, name)


# --------------------------------------------------------------------------- geometry, normals


@pytest.mark.parametrize("ill", ILLUMINATIONS)
def test_limb_normals_are_unit_and_point_into_the_disc(ill):
    c, r = (101.3, 87.9), 42.5
    limb = sphere_limb_polyline(c, r, illumination_deg=ill, phase_deg=35.0)
    v, n = limb.vertices_vu, limb.normals_vu
    assert v.shape == n.shape == (DEFAULT_POLYLINE_VERTICES, 2)
    np.testing.assert_allclose(np.hypot(n[:, 0], n[:, 1]), 1.0, rtol=0, atol=1e-14)
    radial = (v - np.asarray(c)) / r
    np.testing.assert_allclose(np.hypot(radial[:, 0], radial[:, 1]), 1.0, atol=1e-13)
    np.testing.assert_allclose(n, -radial, atol=1e-13)  # toward the centre
    # the sunlit half: every vertex faces the Sun, and the arc spans it symmetrically
    facing = radial @ _sun(ill)
    assert facing.min() > 0.0
    np.testing.assert_allclose(radial.mean(axis=0) / np.hypot(*radial.mean(axis=0)), _sun(ill),
                               atol=1e-12)
    # a step along the normal lands inside the disc and lit; a step against it, outside
    inside, outside = v + 0.5 * n, v - 0.5 * n
    assert (np.hypot(*(inside - c).T) < r).all() and (np.hypot(*(outside - c).T) > r).all()
    assert (_cos_i(inside, c, r, 35.0, ill) > 0.0).all()
    np.testing.assert_array_equal(limb.sigmas, np.full(len(limb), DEFAULT_POLYLINE_SIGMA_PX))


@pytest.mark.parametrize("ill", ILLUMINATIONS)
def test_the_whole_limb_when_asked(ill):
    limb = sphere_limb_polyline((0.0, 0.0), 10.0, illumination_deg=ill, sunlit_only=False,
                                n_vertices=360)
    radial = limb.vertices_vu / 10.0
    np.testing.assert_allclose(limb.normals_vu, -radial, atol=1e-14)
    angles = np.sort(np.arctan2(radial[:, 1], radial[:, 0]))
    gaps = np.diff(np.concatenate([angles, angles[:1] + 2 * math.pi]))
    np.testing.assert_allclose(gaps, 2 * math.pi / 360, atol=1e-12)  # evenly round the circle
    half = sphere_limb_polyline((0.0, 0.0), 10.0, illumination_deg=ill, n_vertices=180)
    # the lit half's vertices are the whole circle's middle half, sampled twice as finely
    assert (radial @ _sun(ill) > 0).sum() == 180
    assert half.vertices_vu.shape == (180, 2)
    none = sphere_limb_polyline((0.0, 0.0), 10.0, sunlit_only=False, n_vertices=4)
    assert none.vertices_vu.shape == (4, 2)


@pytest.mark.parametrize("phase", PHASES)
@pytest.mark.parametrize("ill", ILLUMINATIONS)
def test_terminator_lies_on_cos_i_0_and_its_normals_point_to_the_day_side(ill, phase):
    c, r = (60.2, 75.4), 33.0
    term = sphere_terminator_polyline(c, r, illumination_deg=ill, phase_deg=phase)
    v, n = term.vertices_vu, term.normals_vu
    assert v.shape == n.shape == (DEFAULT_POLYLINE_VERTICES, 2)
    assert term.name == term.edge_kind == "terminator"
    np.testing.assert_allclose(np.hypot(n[:, 0], n[:, 1]), 1.0, rtol=0, atol=1e-14)
    # on the visible side: inside the disc
    q = (v - np.asarray(c)) / r
    assert ((q**2).sum(axis=1) <= 1.0 + 1e-12).all()
    # toward the day side: the normal is the direction of the gradient of cos i,
    # by central differences small beside each vertex's distance to the limb
    # (near phase 0 or 180 the terminator runs along it)
    h = np.minimum(1e-5 * r, 1e-3 * r * (1.0 - np.sqrt((q**2).sum(axis=1))))[:, None]
    grad = np.stack([(_cos_i(v + h * e, c, r, phase, ill) - _cos_i(v - h * e, c, r, phase, ill))
                     for e in np.eye(2)], axis=1) / (2.0 * h)
    np.testing.assert_allclose(grad / np.hypot(*grad.T)[:, None], n, atol=1e-4)
    # on cos i = 0: within 1e-9 px of it (cos i / |grad cos i|, its distance)
    assert (np.abs(_cos_i(v, c, r, phase, ill)) / np.hypot(*grad.T) < 1e-9).all()
    ahead, behind = _cos_i(v + h * n, c, r, phase, ill), _cos_i(v - h * n, c, r, phase, ill)
    assert (ahead > 0.0).all() and (behind < 0.0).all()


@pytest.mark.parametrize("n", [3, 4, 5, 7, 10, 33, 100, 200, 511, 1000])
def test_any_vertex_count(n):
    limb = sphere_limb_polyline((50.0, 50.0), 20.0, illumination_deg=45.0, n_vertices=n)
    term = sphere_terminator_polyline((50.0, 50.0), 20.0, illumination_deg=45.0, phase_deg=60.0,
                                      n_vertices=np.int64(n))
    for p in (limb, term):
        assert len(p) == n and p.vertices_vu.shape == p.normals_vu.shape == (n, 2)
        assert p.sigmas.shape == (n,)
        assert all(a.dtype == np.float64 and a.flags.c_contiguous
                   for a in (p.vertices_vu, p.normals_vu, p.sigmas))
        assert np.isfinite(p.vertices_vu).all() and np.isfinite(p.normals_vu).all()
        # equal steps: the vertices are evenly spaced in angle, none repeated
        assert np.unique(p.vertices_vu.round(9), axis=0).shape[0] == n
    seg = np.hypot(*np.diff(limb.vertices_vu, axis=0).T)
    np.testing.assert_allclose(seg, seg[0], rtol=1e-9)
    assert seg[0] == pytest.approx(2 * 20.0 * math.sin(math.pi / (2 * n)))


def test_sigma_keyword():
    limb = sphere_limb_polyline((0.0, 0.0), 5.0, illumination_deg=0.0, n_vertices=6, sigma=0.25)
    np.testing.assert_array_equal(limb.sigmas, np.full(6, 0.25))


# --------------------------------------------------------------------------- a fit


def test_a_fit_with_the_builders_limb_recovers_the_planted_offset():
    offset = (2.4, -1.7)
    sc = scenes.render_sphere(radius_px=60.0, phase_deg=40.0, illumination_deg=135.0,
                              offset_vu=offset, shape=(200, 200), read_noise_dn=2.0, seed=3)
    limb = sphere_limb_polyline(sc.model_center_vu, 60.0, illumination_deg=135.0)
    fit = dtalign.fit_polyline(sc.image, limb.vertices_vu, limb.normals_vu, limb.sigmas,
                               search_window_vu=(8, 8))
    assert fit.status == "ok"
    # the plain fit's bias: a few tenths of a pixel toward the centre (docs/profiles.rst)
    assert math.dist(fit.offset_vu, offset) < 0.6
    # flipped normals are what the polarity test refuses
    flipped = dtalign.fit_polyline(sc.image, limb.vertices_vu, -limb.normals_vu, limb.sigmas,
                                   search_window_vu=(8, 8))
    assert flipped.status == "failed"


# --------------------------------------------------------------------------- bad arguments


GOOD_LIMB = dict(center_vu=(10.0, 10.0), radius_px=5.0, illumination_deg=0.0)
GOOD_TERM = dict(GOOD_LIMB, phase_deg=40.0)


@pytest.mark.parametrize("builder, good", [(sphere_limb_polyline, GOOD_LIMB),
                                           (sphere_terminator_polyline, GOOD_TERM)])
@pytest.mark.parametrize("name, value, error", [
    ("center_vu", (1.0, 2.0, 3.0), ValueError),
    ("center_vu", (np.nan, 2.0), ValueError),
    ("center_vu", "ab", ValueError),
    ("radius_px", 0.0, ValueError),
    ("radius_px", -3.0, ValueError),
    ("radius_px", math.inf, ValueError),
    ("radius_px", "5", TypeError),
    ("radius_px", True, TypeError),
    ("illumination_deg", math.nan, ValueError),
    ("illumination_deg", "north", TypeError),
    ("phase_deg", -1.0, ValueError),
    ("phase_deg", 180.0, ValueError),
    ("phase_deg", math.nan, ValueError),
    ("phase_deg", [30.0], TypeError),
    ("n_vertices", 1, ValueError),
    ("n_vertices", 0, ValueError),
    ("n_vertices", -5, ValueError),
    ("n_vertices", 20.0, TypeError),
    ("n_vertices", True, TypeError),
    ("sigma", 0.0, ValueError),
    ("sigma", -1.0, ValueError),
    ("sigma", math.nan, ValueError),
    ("sigma", np.ones(3), TypeError),
])
def test_bad_arguments_raise_naming_them(builder, good, name, value, error):
    with pytest.raises(error, match=name):
        builder(**{**good, name: value})


def test_builder_specific_refusals():
    with pytest.raises(ValueError, match="illumination_deg is required"):
        sphere_limb_polyline((0.0, 0.0), 5.0)
    with pytest.raises(TypeError, match="sunlit_only"):
        sphere_limb_polyline((0.0, 0.0), 5.0, illumination_deg=0.0, sunlit_only="yes")
    with pytest.raises(ValueError, match="phase_deg must be > 0"):
        sphere_terminator_polyline((0.0, 0.0), 5.0, illumination_deg=0.0, phase_deg=0.0)
    with pytest.raises(TypeError):  # keyword-only: no positional light direction
        sphere_limb_polyline((0.0, 0.0), 5.0, 30.0)  # type: ignore[misc]
    with pytest.raises(TypeError, match="phase_deg"):
        sphere_terminator_polyline((0.0, 0.0), 5.0, illumination_deg=0.0)  # type: ignore[call-arg]


def test_the_record_checks_its_kind_and_profile():
    limb = sphere_limb_polyline((50.0, 50.0), 20.0, illumination_deg=0.0, n_vertices=12)
    with pytest.raises(ValueError, match="edge_kind"):
        dataclasses.replace(limb, edge_kind="rim")
    with pytest.raises(TypeError, match="edge_profile"):
        dataclasses.replace(limb, edge_profile="profile")
    profile = dtalign.sphere_edge_profile(limb.vertices_vu, center_vu=(50.0, 50.0),
                                          radius_px=20.0, phase_deg=30.0, illumination_deg=0.0)
    with_profile = dataclasses.replace(limb, edge_profile=profile)
    assert with_profile.edge_profile is profile and with_profile.edge_kind == "limb"
    # the old four-field form still builds a record of an undeclared kind
    plain = Polyline("p", limb.vertices_vu, limb.normals_vu, limb.sigmas)
    assert plain.edge_kind is None and plain.edge_profile is None and len(plain) == 12
