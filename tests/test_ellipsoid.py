"""A triaxial ellipsoid's limb, terminator and edge profiles (dtalign.api.ellipsoid).

* over axes, attitudes, light directions, phases and vertex counts drawn
  by hypothesis: the limb's vertices lie on the outline (the Schur
  complement of the surface's matrix, computed here independently) and its
  unit normals point into the disc, over the sunlit half; the
  terminator's vertices lie on ``cos i = 0`` on the visible side and its
  unit normals point up the gradient of ``cos i``;
* equal axes at any attitude give the sphere builders' and the sphere
  profile's results, to rounding;
* a triaxial profile's normals are its polyline's and its curvature the
  polyline's own (finite differences of a dense polyline);
* a bad argument raises ValueError or TypeError naming it;
* the names are exported lazily from the package root.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import dtalign
from dtalign import (
    ellipsoid_edge_profile,
    ellipsoid_limb_polyline,
    ellipsoid_terminator_polyline,
    sphere_edge_profile,
    sphere_limb_polyline,
    sphere_terminator_polyline,
)

CENTER = (101.3, 98.6)


def _rotation(q) -> np.ndarray:
    """The rotation of a (not necessarily unit) quaternion ``(w, x, y, z)``."""
    w, x, y, z = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _surface(axes, rotation) -> np.ndarray:
    """``M`` with ``x^T M x = 1`` on the surface, camera frame ``(v, u, w)``."""
    return rotation @ np.diag(np.asarray(axes, dtype=float) ** -2.0) @ rotation.T


def _light(phase_deg: float, ill: float) -> np.ndarray:
    p, a = math.radians(phase_deg), math.radians(ill)
    return np.array([-math.sin(p) * math.cos(a), math.sin(p) * math.sin(a), math.cos(p)])


def _front(m: np.ndarray, rel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The front surface point over image offsets ``rel`` and whether the ray hits."""
    dv, du = rel[:, 0], rel[:, 1]
    b = m[0, 2] * dv + m[1, 2] * du
    c = m[0, 0] * dv**2 + 2 * m[0, 1] * dv * du + m[1, 1] * du**2 - 1.0
    disc = b * b - m[2, 2] * c
    w = (-b + np.sqrt(np.maximum(disc, 0.0))) / m[2, 2]
    return np.stack([dv, du, w], axis=1), disc > 0.0


def _cos_i(m, light, rel):
    x, hit = _front(m, rel)
    n = x @ m
    return np.where(hit, (n @ light) / np.linalg.norm(n, axis=1), np.nan)


def _unit(normals):
    np.testing.assert_allclose(np.hypot(normals[:, 0], normals[:, 1]), 1.0, rtol=0, atol=1e-12)


bodies = st.fixed_dictionaries(dict(
    axes=st.tuples(*[st.floats(5.0, 200.0)] * 3),
    quaternion=st.tuples(*[st.floats(-1.0, 1.0)] * 4).filter(lambda q: np.linalg.norm(q) > 0.1),
    ill=st.floats(-360.0, 720.0),
    phase=st.floats(0.5, 179.5),
    n=st.integers(2, 400),
))


@settings(max_examples=60, deadline=None)
@given(bodies)
def test_limb_on_the_outline_normals_into_the_disc(d):
    rot = _rotation(d["quaternion"])
    limb = ellipsoid_limb_polyline(CENTER, d["axes"], rotation=rot, illumination_deg=d["ill"],
                                   phase_deg=d["phase"], n_vertices=d["n"])
    assert len(limb) == d["n"] and limb.edge_kind == "limb"
    m = _surface(d["axes"], rot)
    outline = m[:2, :2] - np.outer(m[:2, 2], m[:2, 2]) / m[2, 2]
    rel = limb.vertices_vu - np.asarray(CENTER)
    np.testing.assert_allclose(np.einsum("ni,ij,nj->n", rel, outline, rel), 1.0, rtol=0,
                               atol=1e-9)
    _unit(limb.normals_vu)
    grad = rel @ outline  # outward
    grad /= np.linalg.norm(grad, axis=1)[:, None]
    np.testing.assert_allclose(limb.normals_vu, -grad, rtol=0, atol=1e-9)
    # the sunlit half: cos i = sin(phase) n . s > 0 on the limb
    light = _light(d["phase"], d["ill"])
    assert (grad @ light[:2] > 0.0).all()
    np.testing.assert_array_equal(limb.sigmas, 1.0)


@settings(max_examples=60, deadline=None)
@given(bodies)
def test_terminator_on_cos_i_0_normals_to_the_day_side(d):
    rot = _rotation(d["quaternion"])
    term = ellipsoid_terminator_polyline(CENTER, d["axes"], rotation=rot,
                                         illumination_deg=d["ill"], phase_deg=d["phase"],
                                         n_vertices=d["n"])
    assert len(term) == d["n"] and term.edge_kind == "terminator"
    m, light = _surface(d["axes"], rot), _light(d["phase"], d["ill"])
    rel = term.vertices_vu - np.asarray(CENTER)
    x, hit = _front(m, rel)
    n3 = x @ m
    # the vertices' front surface points (the visible side) have cos i = 0
    scale = float(np.max(d["axes"]))
    np.testing.assert_allclose(n3 @ light / np.linalg.norm(n3, axis=1), 0.0, rtol=0,
                               atol=1e-9 * scale)
    _unit(term.normals_vu)
    # up the gradient of cos i, where it is smooth (away from the cusps on the outline)
    inner = n3[:, 2] / np.linalg.norm(n3, axis=1) > 0.1
    h = 1e-7 * min(d["axes"])
    for k in np.flatnonzero(inner):
        g = np.array([_cos_i(m, light, rel[k:k + 1] + h * e)[0]
                      - _cos_i(m, light, rel[k:k + 1] - h * e)[0] for e in np.eye(2)])
        np.testing.assert_allclose(term.normals_vu[k], g / np.linalg.norm(g), rtol=0, atol=1e-4)
    # everywhere: brighter a little way along the normal than against it
    eps = 1e-4 * min(d["axes"])
    ahead = _cos_i(m, light, rel + eps * term.normals_vu)
    behind = _cos_i(m, light, rel - eps * term.normals_vu)
    both = np.isfinite(ahead) & np.isfinite(behind)
    assert (ahead[both] > behind[both]).all()


@settings(max_examples=30, deadline=None)
@given(radius=st.floats(5.0, 200.0),
       quaternion=st.tuples(*[st.floats(-1.0, 1.0)] * 4).filter(lambda q: np.linalg.norm(q) > 0.1),
       ill=st.floats(-360.0, 720.0), phase=st.floats(0.5, 179.5), n=st.integers(2, 400),
       whole=st.booleans())
def test_equal_axes_are_the_sphere(radius, quaternion, ill, phase, n, whole):
    body = dict(rotation=_rotation(quaternion))
    kw = dict(illumination_deg=ill, phase_deg=phase, n_vertices=n)
    tol = 1e-12 * radius
    for mine, theirs in (
        (ellipsoid_limb_polyline(CENTER, (radius,) * 3, **body, **kw, sunlit_only=not whole),
         sphere_limb_polyline(CENTER, radius, **kw, sunlit_only=not whole)),
        (ellipsoid_terminator_polyline(CENTER, (radius,) * 3, **body, **kw),
         sphere_terminator_polyline(CENTER, radius, **kw)),
    ):
        np.testing.assert_allclose(mine.vertices_vu, theirs.vertices_vu, rtol=0, atol=tol)
        np.testing.assert_allclose(mine.normals_vu, theirs.normals_vu, rtol=0, atol=1e-11)
        np.testing.assert_array_equal(mine.sigmas, theirs.sigmas)
        assert (mine.name, mine.edge_kind) == (theirs.name, theirs.edge_kind)


@pytest.mark.parametrize("edge", ["limb", "terminator"])
@pytest.mark.parametrize("law, k", [("lambert", None), ("minnaert", 0.7),
                                    ("lommel-seeliger", None)])
@pytest.mark.parametrize("phase, ill", [(20.0, 0.0), (65.0, 217.0), (90.0, 33.0),
                                        (140.0, 301.5)])
def test_equal_axes_profile_is_the_sphere_profile(edge, law, k, phase, ill):
    radius = 57.0
    kw = dict(center_vu=CENTER, phase_deg=phase, illumination_deg=ill)
    build = sphere_limb_polyline if edge == "limb" else sphere_terminator_polyline
    poly = build(CENTER, radius, illumination_deg=ill, phase_deg=phase, n_vertices=64)
    theirs = sphere_edge_profile(poly.vertices_vu, **kw, radius_px=radius, edge=edge, law=law,
                                 minnaert_k=k, psf_sigma_px=0.8)
    mine = ellipsoid_edge_profile(poly.vertices_vu, **kw, axes_px=(radius,) * 3,
                                  rotation=_rotation((0.3, -0.5, 0.7, 0.2)), edge=edge, law=law,
                                  minnaert_k=k, psf_sigma_px=0.8)
    np.testing.assert_array_equal(mine.offsets_px, theirs.offsets_px)
    np.testing.assert_allclose(mine.values, theirs.values, rtol=0, atol=1e-11)
    np.testing.assert_allclose(mine.shape_values, theirs.shape_values, rtol=0, atol=1e-9)
    np.testing.assert_allclose(mine.normals_vu, theirs.normals_vu, rtol=0, atol=1e-12)
    np.testing.assert_allclose(mine.curvature_px, theirs.curvature_px, rtol=1e-10, atol=1e-12)
    assert (mine.edge, mine.psf_sigma_px) == (theirs.edge, theirs.psf_sigma_px)


def _numeric_curvature(vertices: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Signed curvature of a dense polyline, positive where it bends toward the normals."""
    d1 = np.gradient(vertices, axis=0)
    d2 = np.gradient(d1, axis=0)
    return (d2 * normals).sum(axis=1) / (d1 * d1).sum(axis=1)


@pytest.mark.parametrize("edge", ["limb", "terminator"])
@pytest.mark.parametrize("phase, ill", [(35.0, 10.0), (90.0, 200.0), (150.0, 77.0)])
def test_triaxial_profile_follows_its_polyline(edge, phase, ill):
    body = dict(center_vu=CENTER, axes_px=(70.0, 52.0, 61.0),
                rotation=_rotation((0.9, 0.2, -0.4, 0.3)))
    light = dict(phase_deg=phase, illumination_deg=ill)
    build = ellipsoid_limb_polyline if edge == "limb" else ellipsoid_terminator_polyline
    poly = build(**body, **light, n_vertices=20001)
    prof = ellipsoid_edge_profile(poly.vertices_vu, **body, **light, edge=edge,
                                  fit_law=False)
    np.testing.assert_allclose(prof.normals_vu, poly.normals_vu, rtol=0, atol=1e-9)
    inner = slice(100, -100)
    np.testing.assert_allclose(prof.curvature_px[inner],
                               _numeric_curvature(poly.vertices_vu, poly.normals_vu)[inner],
                               rtol=1e-5, atol=1e-9)
    assert prof.shape_values is None and prof.edge == edge
    if edge == "limb":  # sky outside, the lit disc (at phase 150 a crescent) inside
        assert (prof.values[:, prof.offsets_px < -0.1] == 0.0).all()
        mid = prof.values[len(poly) // 2]
        assert (mid[(prof.offsets_px > 0.1) & (prof.offsets_px < 3.0)] > 0.0).all()
    else:  # night behind the normal, day ahead of it
        assert (prof.values[:, prof.offsets_px < -0.1] == 0.0).all()
        assert (prof.values[5000:15000, prof.offsets_px > 0.1][:, :20] > 0.0).all()


def test_names_are_exported_lazily():
    for name in ("ellipsoid_limb_polyline", "ellipsoid_terminator_polyline",
                 "ellipsoid_edge_profile"):
        assert name in dtalign.__all__
        assert getattr(dtalign, name) is getattr(dtalign.api.ellipsoid, name)


def test_the_docstring_examples_hold():
    import doctest

    import dtalign.api.ellipsoid as module

    result = doctest.testmod(module)
    assert result.attempted >= 6 and result.failed == 0


GOOD = dict(center_vu=CENTER, axes_px=(50.0, 40.0, 30.0), illumination_deg=20.0,
            phase_deg=40.0)


@pytest.mark.parametrize("builder", [ellipsoid_limb_polyline, ellipsoid_terminator_polyline,
                                     ellipsoid_edge_profile])
@pytest.mark.parametrize("name, value, error", [
    ("axes_px", (50.0, 40.0), ValueError),
    ("axes_px", (50.0, -1.0, 30.0), ValueError),
    ("axes_px", (50.0, math.nan, 30.0), ValueError),
    ("axes_px", "abc", ValueError),
    ("rotation", np.eye(2), ValueError),
    ("rotation", np.diag([1.0, 1.0, 1.001]), ValueError),
    ("rotation", np.full((3, 3), math.nan), ValueError),
    ("rotation", [["a"] * 3] * 3, ValueError),
    ("center_vu", (1.0, math.inf), ValueError),
    ("center_vu", (1.0, 2.0, 3.0), ValueError),
    ("illumination_deg", math.nan, ValueError),
    ("illumination_deg", "up", TypeError),
    ("phase_deg", 180.0, ValueError),
    ("phase_deg", -1.0, ValueError),
])
def test_bad_arguments_raise_naming_them(builder, name, value, error):
    kw = dict(GOOD)
    if builder is ellipsoid_edge_profile:
        args = (ellipsoid_limb_polyline(**GOOD).vertices_vu,)
    else:
        args = (kw.pop("center_vu"), kw.pop("axes_px"))
        if name in ("center_vu", "axes_px"):
            args = (value, args[1]) if name == "center_vu" else (args[0], value)
    if name not in ("center_vu", "axes_px") or builder is ellipsoid_edge_profile:
        kw[name] = value
    with pytest.raises(error, match=name):
        builder(*args, **kw)


@pytest.mark.parametrize("call, name, error", [
    (lambda: ellipsoid_limb_polyline(CENTER, (5.0, 4.0, 3.0)), "illumination_deg", ValueError),
    (lambda: ellipsoid_limb_polyline(CENTER, (5.0, 4.0, 3.0), illumination_deg=0.0,
                                     sunlit_only=1), "sunlit_only", TypeError),
    (lambda: ellipsoid_limb_polyline(CENTER, (5.0, 4.0, 3.0), illumination_deg=0.0,
                                     n_vertices=1), "n_vertices", ValueError),
    (lambda: ellipsoid_limb_polyline(CENTER, (5.0, 4.0, 3.0), illumination_deg=0.0,
                                     n_vertices=True), "n_vertices", TypeError),
    (lambda: ellipsoid_limb_polyline(CENTER, (5.0, 4.0, 3.0), illumination_deg=0.0,
                                     sigma=0.0), "sigma", ValueError),
    (lambda: ellipsoid_terminator_polyline(CENTER, (5.0, 4.0, 3.0), illumination_deg=0.0,
                                           phase_deg=0.0), "phase_deg", ValueError),
    (lambda: ellipsoid_terminator_polyline(CENTER, (5.0, 4.0, 3.0), illumination_deg=0.0,
                                           phase_deg=30.0, n_vertices=2.5), "n_vertices",
     TypeError),
    (lambda: ellipsoid_edge_profile([CENTER], **GOOD), "center_vu", ValueError),
    (lambda: ellipsoid_edge_profile([(0.0, 0.0)], **GOOD, edge="ring"), "edge", ValueError),
    (lambda: ellipsoid_edge_profile([(0.0, 0.0)], **GOOD, law="hapke"), "law", ValueError),
    (lambda: ellipsoid_edge_profile([(0.0, 0.0)], **GOOD, law="minnaert"), "minnaert_k",
     ValueError),
    (lambda: ellipsoid_edge_profile([(0.0, 0.0)], **GOOD, psf_sigma_px=-1.0), "psf_sigma_px",
     ValueError),
    (lambda: ellipsoid_edge_profile([(0.0, 0.0)], **GOOD, step_px=0.0), "step_px", ValueError),
    (lambda: ellipsoid_edge_profile(np.zeros((0, 2)), **GOOD), "vertices_vu", ValueError),
    (lambda: ellipsoid_edge_profile([(0.0, 0.0)], **{**GOOD, "phase_deg": 0.0},
                                    edge="terminator"), "phase 0", ValueError),
])
def test_specific_refusals(call, name, error):
    with pytest.raises(error, match=name):
        call()


def _render(center_vu, axes, rotation, phase_deg, ill, shape=(200, 200), sub=4) -> np.ndarray:
    """A noise-free Lambert image of the ellipsoid, ``sub x sub`` samples a pixel: 10 DN of sky,
    200 DN of albedo."""
    m, light = _surface(axes, rotation), _light(phase_deg, ill)
    fv = (np.arange(shape[0] * sub) + 0.5) / sub - 0.5
    fu = (np.arange(shape[1] * sub) + 0.5) / sub - 0.5
    dv, du = np.meshgrid(fv - center_vu[0], fu - center_vu[1], indexing="ij")
    ci = _cos_i(m, light, np.stack([dv.ravel(), du.ravel()], axis=1))
    ci = np.nan_to_num(np.clip(ci, 0.0, None)).reshape(shape[0], sub, shape[1], sub)
    return 10.0 + 200.0 * ci.mean(axis=(1, 3))


def test_cli_fit_with_an_ellipsoid_model(tmp_path, capsys):
    import json

    from dtalign.cli import main
    from dtalign.io import save_polyline_csv

    rot = _rotation((0.8, 0.3, -0.2, 0.5))
    axes, truth = (62.0, 50.0, 44.0), (0.6, -1.3)
    np.save(tmp_path / "e.npy", _render((100.6, 98.7), axes, rot, 50.0, 200.0))
    model = (100.0, 100.0)
    save_polyline_csv(tmp_path / "e.csv", ellipsoid_limb_polyline(
        model, axes, rotation=rot, illumination_deg=200.0, phase_deg=50.0))
    files = [str(tmp_path / "e.npy"), str(tmp_path / "e.csv"), "--window", "6"]
    ellipsoid = ",".join(str(x) for x in (*model, *axes, 50.0, 200.0, *rot.ravel()))
    assert main(["fit", *files, "--ellipsoid", ellipsoid, "--psf-sigma", "0", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["profile"]["accepted"]
    assert math.dist(d["offset_vu"], truth) < 0.01
    for argv, message in (
        (["--ellipsoid", "1,2,3"], "--ellipsoid takes 7 or 16 numbers"),
        (["--ellipsoid", "1,2,x,4,5,6,7"], "--ellipsoid takes numbers"),
        (["--ellipsoid", ellipsoid, "--sphere", "1,2,3,4,5"], "exclude each other"),
        (["--edge", "terminator"], "--edge needs --sphere, --ellipsoid or --model-render"),
        (["--ellipsoid", ",".join(["100"] * 7 + ["1"] * 9)], "rotation"),
    ):
        assert main(["fit", *files, *argv]) != 0
        assert message in capsys.readouterr().err
