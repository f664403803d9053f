"""``model_image_edge_profile``: an edge profile sampled from a model render.

* the pixel convention, exactly: a render that is linear in position is
  sampled to rounding error, for any oversample, origin, direction and
  vertex count (a wrong render-pixel centre would shift every value);
* a step's position is kept: the render's box average and the bilinear
  interpolation are symmetric about the edge, so the profile's integral
  puts the step where it is, to the sub-samples' midpoint-rule error;
* on a smooth Lambert sphere the profile is the analytic one away from
  the edge (to the blur of the render pixel and the interpolation), and the
  refinement with it lands within 0.005 px of the refinement with
  :func:`~dtalign.sphere_edge_profile`;
* where the body is not the sphere (an albedo pattern at the limb), the
  render's profile finds the pose the sphere's misses;
* bad inputs are refused with the argument's name;
* the worked example of docs/profiles.rst (``tests/test_docs_examples.py``
  runs it as written) agrees with the sphere profile's fit.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, seed, settings
from hypothesis import strategies as st

import dtalign
from dtalign import fit_polyline, model_image_edge_profile, sphere_edge_profile
from dtalign.api import model_profile
from dtalign.api.model_profile import polyline_curvature
from dtalign.scenes import render_sphere

SWEEP = settings(max_examples=60, deadline=None, database=None,
                 suppress_health_check=[HealthCheck.too_slow])


def _fine_sphere(center_vu, radius_px, phase_deg, illumination_deg, k, frame, inner=4):
    """A noise-free Lambert render ``k`` times finer than ``frame`` (the default origin)."""
    centre = (k * (center_vu[0] + 0.5) - 0.5, k * (center_vu[1] + 0.5) - 0.5)
    return render_sphere(shape=(frame[0] * k, frame[1] * k), center_vu=centre,
                         radius_px=radius_px * k, phase_deg=phase_deg,
                         illumination_deg=illumination_deg, albedo_dn=1.0, oversample=inner,
                         n_vertices=2).image


def test_the_package_root_exports_it():
    assert "model_image_edge_profile" in dtalign.__all__
    assert dtalign.model_image_edge_profile is model_profile.model_image_edge_profile


# --------------------------------------------------------------------------- the convention


@seed(0)
@SWEEP
@given(k=st.integers(1, 8), n=st.integers(1, 40), angle=st.floats(0.0, 2 * math.pi),
       spread=st.floats(0.0, 2 * math.pi), origin=st.none() | st.tuples(
           st.floats(-3.0, 3.0), st.floats(-3.0, 3.0)),
       gv=st.floats(-5.0, 5.0), gu=st.floats(-5.0, 5.0), data=st.data())
def test_a_linear_render_is_sampled_exactly(k, n, angle, spread, origin, gv, gu, data):
    """Render pixel ``(a, b)`` is centred at ``origin + (a, b) / k``: a render linear in the
    image point is its own box average, bilinear interpolation and cell means keep it, so
    each profile value is the linear function at its cell's centre."""
    half, step = 2.0, 0.25
    shape = (12 * k, 14 * k)
    o = (0.5 / k - 0.5,) * 2 if origin is None else origin
    av = o[0] + np.arange(shape[0]) / k
    au = o[1] + np.arange(shape[1]) / k
    render = 3.0 + gv * av[:, None] + gu * au[None, :]
    theta = angle + spread * np.arange(n) / max(n, 1)
    normals = np.stack([np.cos(theta), np.sin(theta)], axis=1)
    lo = np.array(o) + half + 0.01
    hi = np.array(o) + (np.array(shape) - 1) / k - half - 0.01
    frac = np.array(data.draw(st.lists(st.tuples(st.floats(0, 1), st.floats(0, 1)),
                                       min_size=n, max_size=n)))
    verts = lo + frac * (hi - lo)
    prof = model_image_edge_profile(render, verts, normals, oversample=k, origin_vu=origin,
                                    step_px=step, half_range_px=half,
                                    curvature_px=np.zeros(n))
    s = prof.offsets_px
    pv = verts[:, 0:1] + s[None, :] * normals[:, 0:1]
    pu = verts[:, 1:2] + s[None, :] * normals[:, 1:2]
    np.testing.assert_allclose(prof.values, 3.0 + gv * pv + gu * pu, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(prof.normals_vu, normals)


def test_the_offsets_grid_is_the_sphere_profiles():
    k, frame = 2, (40, 40)
    render = _fine_sphere((20.0, 20.0), 10.0, 30.0, 0.0, k, frame)
    verts = np.array([[10.0, 20.0], [20.0, 10.0]])
    normals = np.array([[1.0, 0.0], [0.0, 1.0]])
    sph = sphere_edge_profile(verts, center_vu=(20.0, 20.0), radius_px=10.0, phase_deg=30.0,
                              illumination_deg=0.0, step_px=0.2, half_range_px=5.0)
    mod = model_image_edge_profile(render, verts, normals, oversample=k, step_px=0.2,
                                   half_range_px=5.0, psf_sigma_px=0.5)
    np.testing.assert_array_equal(mod.offsets_px, sph.offsets_px)
    assert mod.psf_sigma_px == 0.5 and mod.edge == "limb" and mod.shape_values is None


@seed(0)
@SWEEP
@given(k=st.integers(1, 8), axis=st.integers(0, 1), sign=st.sampled_from([-1.0, 1.0]),
       edge_at=st.floats(0.0, 1.0), vertex_at=st.floats(-0.5, 0.5))
def test_a_step_keeps_its_position(k, axis, sign, edge_at, vertex_at):
    """A straight step along a render axis, each render pixel its exact area fraction:
    the profile's integral puts the step where it is, to the midpoint rule's error on
    the interpolant's kinks (at most three, slope changes of ``k`` each)."""
    n_pix = 30
    x0 = 14.0 + edge_at  # the edge, image pixels along the axis
    a = np.arange(n_pix * k)
    lo = (0.5 / k - 0.5) + (a - 0.5) / k  # each render pixel's extent
    bright = np.clip((lo + 1.0 / k - x0) * k, 0.0, 1.0) if sign > 0 else np.clip(
        (x0 - lo) * k, 0.0, 1.0)
    render = np.repeat(bright[:, None], n_pix * k, axis=1)
    if axis == 1:
        render = render.T.copy()
    vertex = np.full((1, 2), 15.0)
    vertex[0, axis] = x0 + vertex_at
    normal = np.zeros((1, 2))
    normal[0, axis] = sign  # toward the bright side
    half, step = 6.0, 0.1
    prof = model_image_edge_profile(render, vertex, normal, oversample=k, step_px=step,
                                    half_range_px=half)
    # a step from 0 to 1 at offset e: the integral over [-half, half] is half - e
    e = half - step * prof.values[0].sum()
    n_sub = max(model_profile.MIN_SUBSAMPLES, math.ceil(2.0 * step * k))
    h_sub = step / n_sub
    assert abs(e - sign * (x0 - vertex[0, axis])) <= 3 * k * h_sub**2 / 8 + 1e-12


# --------------------------------------------------------------------------- the sphere


@seed(0)
@settings(max_examples=12, deadline=None, database=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(k=st.integers(2, 8), ill=st.floats(0.0, 360.0), phase=st.floats(20.0, 70.0),
       frac=st.tuples(st.floats(-0.5, 0.5), st.floats(-0.5, 0.5)))
def test_the_sphere_render_gives_the_analytic_profile_off_the_edge(k, ill, phase, frac):
    """Away from the edge (past ``2 / k + step``) the render's pixel box and the
    interpolation blur the profile by a variance of at most ``1 / (4 k^2)``, so the
    profile is the analytic one to ``max |P''| / (8 k^2)`` over a render pixel around
    each sample, plus 2e-4 of the albedo for the render's own 4 x 4 samples a pixel."""
    centre = (60.0 + frac[0], 60.0 + frac[1])
    sph = dict(center_vu=centre, radius_px=45.0, phase_deg=phase, illumination_deg=ill)
    render = _fine_sphere(centre, 45.0, phase, ill, k, (120, 120))
    limb = dtalign.sphere_limb_polyline(**sph, n_vertices=60)
    ana = sphere_edge_profile(limb.vertices_vu, **sph, fit_law=False)
    mod = model_image_edge_profile(render, limb.vertices_vu, limb.normals_vu, oversample=k)
    h = ana.step_px
    curv = np.abs(np.gradient(np.gradient(ana.values, h, axis=1), h, axis=1))
    reach = int(np.ceil(1.0 / (k * h))) + 1
    window = np.lib.stride_tricks.sliding_window_view(
        np.pad(curv, ((0, 0), (reach, reach)), mode="edge"), 2 * reach + 1, axis=1)
    bound = window.max(axis=2) / (8 * k * k) + 2e-4
    far = np.abs(ana.offsets_px) > 2.0 / k + h
    assert (np.abs(mod.values - ana.values)[:, far] <= bound[:, far]).all()
    np.testing.assert_allclose(mod.curvature_px, 1.0 / 45.0, rtol=1e-9)
    np.testing.assert_allclose(mod.normals_vu, ana.normals_vu, atol=1e-12)


@pytest.mark.parametrize("psf", [None, 0.7])
def test_the_refinement_agrees_with_the_sphere_profiles(psf):
    k, frame = 4, (160, 160)
    scene = render_sphere(shape=frame, center_vu=(80.2, 79.7), radius_px=55.0, phase_deg=40.0,
                          illumination_deg=250.0, offset_vu=(1.3, -0.6), albedo_dn=200.0,
                          background_dn=10.0, psf_sigma_px=psf)
    sph = dict(center_vu=scene.model_center_vu, radius_px=55.0, phase_deg=40.0,
               illumination_deg=250.0)
    limb = scene.limb
    render = _fine_sphere(scene.model_center_vu, 55.0, 40.0, 250.0, k, frame)
    fits = [fit_polyline(scene.image, limb.vertices_vu, limb.normals_vu, limb.sigmas,
                         search_window_vu=(6, 6), edge_profile=prof)
            for prof in (sphere_edge_profile(limb.vertices_vu, **sph, fit_law=False),
                         model_image_edge_profile(render, limb.vertices_vu, limb.normals_vu,
                                                  oversample=k))]
    assert all(f.profile.accepted for f in fits)
    assert math.dist(fits[0].offset_vu, fits[1].offset_vu) < 0.005


def test_a_render_that_knows_the_albedo_beats_the_sphere():
    """A limb darkened by an albedo pattern (up to 60 % darker at the limb, three lobes
    around it) that the sphere's formula does not know: the observed frame is the
    pattern's fine render binned to the frame's pixels, with noise; the model render
    is the same body at the model's pose."""
    k, frame, radius, phase, ill = 4, (160, 160), 55.0, 40.0, 250.0
    offset = (1.3, -0.6)
    true_c = (80.2, 79.7)
    model_c = (true_c[0] - offset[0], true_c[1] - offset[1])

    def patterned(c):
        img = _fine_sphere(c, radius, phase, ill, k, frame)
        x = (np.arange(frame[0] * k) + 0.5) / k - 0.5
        dv, du = x[:, None] - c[0], x[None, :] - c[1]
        rho2 = np.clip((dv**2 + du**2) / radius**2, 0.0, 1.0)
        return img * (1.0 - 0.6 * rho2**8 * (0.5 + 0.5 * np.cos(3.0 * np.arctan2(du, dv))))

    observed = patterned(true_c).reshape(frame[0], k, frame[1], k).mean(axis=(1, 3))
    image = 200.0 * observed + 10.0 + np.random.default_rng(0).normal(0.0, 1.0, frame)
    sph = dict(center_vu=model_c, radius_px=radius, phase_deg=phase, illumination_deg=ill)
    limb = dtalign.sphere_limb_polyline(**sph)

    def error(profile):
        fit = fit_polyline(image, limb.vertices_vu, limb.normals_vu, limb.sigmas,
                           search_window_vu=(6, 6), edge_profile=profile)
        assert fit.profile.accepted
        return math.dist(fit.offset_vu, offset)

    model = model_image_edge_profile(patterned(model_c), limb.vertices_vu, limb.normals_vu,
                                     oversample=k)
    assert error(model) < 0.01
    for fit_law in (True, False):
        assert error(sphere_edge_profile(limb.vertices_vu, **sph, fit_law=fit_law)) > 0.05


def test_the_worked_example_agrees_with_the_sphere_profile():
    text = (Path(__file__).resolve().parents[1] / "docs" / "profiles.rst").read_text()
    from test_docs_examples import python_blocks

    blocks = [b for b in python_blocks(text) if "model_image_edge_profile" in b]
    assert len(blocks) == 1
    ns: dict = {}
    exec(compile(blocks[0], "profiles.rst (model image example)", "exec"), ns)
    scene, fit = ns["scene"], ns["fit"]
    sphere = sphere_edge_profile(scene.limb.vertices_vu, center_vu=scene.model_center_vu,
                                 radius_px=scene.radius_px, phase_deg=scene.phase_deg,
                                 illumination_deg=scene.illumination_deg, fit_law=False)
    ref = fit_polyline(scene.image, scene.limb.vertices_vu, scene.limb.normals_vu,
                       scene.limb.sigmas, search_window_vu=(6, 6), edge_profile=sphere)
    assert fit.profile.accepted and ref.profile.accepted
    assert math.dist(fit.offset_vu, ref.offset_vu) < 0.005


# --------------------------------------------------------------------------- curvature


@seed(0)
@SWEEP
@given(n=st.integers(3, 200), radius=st.floats(3.0, 500.0), start=st.floats(0.0, 6.3),
       arc=st.floats(0.5, 6.2), inward=st.booleans())
def test_polyline_curvature_of_a_circle(n, radius, start, arc, inward):
    t = start + arc * np.arange(n) / (n - 1)
    verts = np.stack([10.0 + radius * np.cos(t), -4.0 + radius * np.sin(t)], axis=1)
    out = np.stack([np.cos(t), np.sin(t)], axis=1)
    kappa = polyline_curvature(verts, -out if inward else out)
    np.testing.assert_allclose(kappa, (1.0 if inward else -1.0) / radius, rtol=1e-6)


def test_polyline_curvature_of_a_line_and_of_short_polylines():
    verts = np.stack([np.linspace(0, 9, 10), np.linspace(3, -6, 10)], axis=1)
    normals = np.tile([[1.0, 1.0]], (10, 1)) / math.sqrt(2.0)
    np.testing.assert_allclose(polyline_curvature(verts, normals), 0.0, atol=1e-12)
    assert polyline_curvature(verts[:2], normals[:2]).tolist() == [0.0, 0.0]
    with pytest.raises(ValueError, match="vertices_vu 1 and 2 coincide"):
        polyline_curvature(verts[[0, 1, 1, 2]], normals[:4])


# --------------------------------------------------------------------------- bad inputs

_RENDER = np.zeros((40, 40))
_V = np.array([[10.0, 10.0], [10.5, 11.0]])
_N = np.array([[1.0, 0.0], [0.0, 1.0]])
_OK = dict(oversample=2, half_range_px=2.0, step_px=0.25)


def _call(**changes):
    args = dict(model_image=_RENDER, vertices_vu=_V, normals_vu=_N, **_OK)
    args.update(changes)
    return model_image_edge_profile(args.pop("model_image"), args.pop("vertices_vu"),
                                    args.pop("normals_vu"), **args)


def test_the_good_call_works():
    assert _call().n_vertices == 2


@pytest.mark.parametrize("changes, error, match", [
    (dict(model_image=np.zeros(40)), ValueError, "model_image must be 2-D"),
    (dict(model_image=np.zeros((4, 4, 3))), ValueError, "model_image must be 2-D"),
    (dict(model_image=np.zeros((1, 40))), ValueError, "model_image must be at least 2 x 2"),
    (dict(model_image=np.where(np.eye(40) > 0, np.nan, 0.0)), ValueError,
     r"model_image must be finite"),
    (dict(model_image=np.full((40, 40), np.inf)), ValueError, r"model_image must be finite"),
    (dict(model_image=np.full((40, 40), "a")), TypeError, "model_image"),
    (dict(vertices_vu=np.zeros((2, 3))), ValueError, "vertices_vu must have shape"),
    (dict(vertices_vu=np.zeros((0, 2))), ValueError, "vertices_vu must have shape"),
    (dict(vertices_vu=np.array([[np.nan, 1.0], [2.0, 2.0]])), ValueError, "vertices_vu"),
    (dict(normals_vu=np.zeros((3, 2))), ValueError, "normals_vu must match"),
    (dict(normals_vu=np.array([[1.0, 0.0], [0.0, 1.1]])), ValueError,
     "normals_vu must be unit vectors; normal 1"),
    (dict(normals_vu=np.array([[0.0, 0.0], [0.0, 1.0]])), ValueError, "normals_vu must be unit"),
    (dict(normals_vu=np.array([[np.nan, 0.0], [0.0, 1.0]])), ValueError, "normals_vu"),
    (dict(oversample=2.0), TypeError, "oversample must be a positive int"),
    (dict(oversample=True), TypeError, "oversample must be a positive int"),
    (dict(oversample="2"), TypeError, "oversample must be a positive int"),
    (dict(oversample=None), TypeError, "oversample must be a positive int"),
    (dict(oversample=0), ValueError, "oversample must be a positive int"),
    (dict(oversample=-3), ValueError, "oversample must be a positive int"),
    (dict(origin_vu=(1.0,)), ValueError, "origin_vu"),
    (dict(origin_vu=(np.nan, 0.0)), ValueError, "origin_vu"),
    (dict(curvature_px=np.zeros(3)), ValueError, r"curvature_px must have shape \(2,\)"),
    (dict(curvature_px=np.array([0.0, np.inf])), ValueError, "curvature_px"),
    (dict(edge="crater"), ValueError, "edge must be one of"),
    (dict(psf_sigma_px=-0.1), ValueError, "psf_sigma_px"),
    (dict(step_px=0.0), ValueError, "step_px"),
    (dict(half_range_px=0.5), ValueError, "half_range_px must be at least 4 \\* step_px"),
    (dict(vertices_vu=np.array([[10.0, 10.0], [30.0, 10.0]])), ValueError,
     r"vertices_vu 1 \(30, 10\) lies outside model_image"),
    (dict(vertices_vu=np.array([[10.0, -0.9], [10.0, 10.0]])), ValueError,
     r"vertices_vu 0 .* lies outside model_image"),
    (dict(vertices_vu=np.array([[10.0, 10.0], [10.0, 18.5]])), ValueError,
     r"the profile of vertices_vu 1 .* reaches outside model_image.*half_range_px"),
])
def test_bad_inputs_are_refused_by_name(changes, error, match):
    with pytest.raises(error, match=match):
        _call(**changes)


def test_a_window_render_takes_its_origin():
    """A render of a window: the origin places it, and a vertex outside the window is
    refused even where it would lie inside a frame-tiling render."""
    k = 2
    window = np.ones((20, 20))
    verts = np.array([[55.0, 75.0]])
    normals = np.array([[0.0, 1.0]])
    prof = model_image_edge_profile(window, verts, normals, oversample=k, origin_vu=(50.0, 70.0),
                                    half_range_px=2.0, step_px=0.25)
    np.testing.assert_allclose(prof.values, 1.0)
    with pytest.raises(ValueError, match="outside model_image"):
        model_image_edge_profile(window, verts, normals, oversample=k, half_range_px=2.0,
                                 step_px=0.25)
    assert re.search("origin_vu", model_image_edge_profile.__doc__ or "")


def test_cli_fit_with_a_model_render(tmp_path, capsys):
    """``dtalign fit --model-render FILE,K``: the technique's render refines the fit as
    the analytic sphere profile does (``--sphere``), within 0.005 px."""
    import json

    from dtalign.cli import main
    from dtalign.io import save_polyline_csv

    k, frame = 4, (160, 160)
    scene = render_sphere(shape=frame, center_vu=(80.2, 79.7), radius_px=55.0, phase_deg=40.0,
                          illumination_deg=250.0, offset_vu=(1.3, -0.6), albedo_dn=200.0,
                          background_dn=10.0, read_noise_dn=1.0, seed=2)
    np.save(tmp_path / "frame.npy", scene.image)
    np.save(tmp_path / "render.npy", _fine_sphere(scene.model_center_vu, 55.0, 40.0, 250.0, k,
                                                  frame))
    save_polyline_csv(tmp_path / "limb.csv", scene.limb)
    files = [str(tmp_path / "frame.npy"), str(tmp_path / "limb.csv"), "--window", "6", "--json"]
    sphere = ",".join(str(x) for x in (*scene.model_center_vu, 55.0, 40.0, 250.0))
    offsets = []
    for argv in (["--model-render", f"{tmp_path / 'render.npy'},{k}"], ["--sphere", sphere]):
        assert main(["fit", *files, *argv]) == 0
        d = json.loads(capsys.readouterr().out)
        assert d["profile"]["accepted"]
        offsets.append(d["offset_vu"])
    assert math.dist(*offsets) < 0.005
    assert math.dist(offsets[0], scene.true_offset_vu) < 0.02
    for argv, message in (
        (["--model-render", str(tmp_path / "render.npy")], "--model-render takes FILE,K"),
        (["--model-render", f"{tmp_path / 'render.npy'},0"], "--model-render takes FILE,K"),
        (["--model-render", f"{tmp_path / 'none.npy'},4"], "--model-render"),
        (["--model-render", f"{tmp_path / 'render.npy'},4", "--law", "minnaert,0.7"],
         "a render carries its own law"),
        (["--model-render", f"{tmp_path / 'render.npy'},4", "--sphere", sphere],
         "exclude each other"),
    ):
        assert main(["fit", *files, *argv]) != 0
        assert message in capsys.readouterr().err
