"""Validation of the photometric sphere renderer (:func:`dtalign.scenes.render_sphere`).

The renderer is the ground truth of the accuracy tables, so it is checked
against closed forms, not against the profile model the fit uses (which
it must not share code with: see ``test_renderer_is_independent_of_the_fit``).
"""

from __future__ import annotations

import ast
import math
from pathlib import Path

import numpy as np
import pytest

from dtalign.scenes import SPHERE_LAWS, render_sphere, sun_direction_vu

A = 200.0  # albedo in DN for every test scene


def _centroid(image: np.ndarray) -> tuple[float, float]:
    vv, uu = np.mgrid[: image.shape[0], : image.shape[1]]
    s = image.sum()
    return float((vv * image).sum() / s), float((uu * image).sum() / s)


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("psf_sigma", [None, 1.0])
def test_phase_zero_centroid_is_the_centre(seed: int, psf_sigma: float | None) -> None:
    """At phase 0 a Lambert sphere is radially symmetric: its brightness
    centroid is its centre, at any sub-pixel position, blurred or not."""
    rng = np.random.default_rng(seed)
    centre = (150.0 + rng.uniform(-0.5, 0.5), 150.0 + rng.uniform(-0.5, 0.5))
    sc = render_sphere(center_vu=centre, radius_px=float(rng.uniform(50, 110)), phase_deg=0.0,
                       albedo_dn=A, psf_sigma_px=psf_sigma)
    cv, cu = _centroid(sc.image)
    assert abs(cv - centre[0]) < 1e-4
    assert abs(cu - centre[1]) < 1e-4


@pytest.mark.parametrize("radius", [40.0, 85.3, 120.0])
def test_phase_zero_flux_puts_the_limb_at_the_radius(radius: float) -> None:
    """Lambert at phase 0: ``I = A sqrt(1 - rho^2)``, total ``2 pi R^2 A / 3``;
    Lommel-Seeliger at phase 0 is a flat disc of ``A / 2``, total
    ``pi R^2 A / 2``: a hard edge, so the flux measures where the limb is
    (a radius error ``dR`` moves it by ``2 dR / R``)."""
    centre = (150.21, 149.63)
    lam = render_sphere(center_vu=centre, radius_px=radius, phase_deg=0.0, albedo_dn=A)
    assert lam.image.sum() == pytest.approx(2.0 * math.pi * radius**2 * A / 3.0, rel=1e-5)
    ls = render_sphere(center_vu=centre, radius_px=radius, phase_deg=0.0, albedo_dn=A,
                       law="lommel-seeliger", oversample=16)
    # 2 dR / R < 2e-4 / R: the limb within 1e-4 px... of the radius on average
    assert ls.image.sum() == pytest.approx(math.pi * radius**2 * A / 2.0, rel=2e-4 / radius)
    inside = ls.image[int(centre[0]) - 5 : int(centre[0]) + 5, int(centre[1]) - 5 : int(centre[1]) + 5]
    np.testing.assert_allclose(inside, A / 2.0, rtol=1e-12)


def test_terminator_at_phase_ninety_is_the_kink_at_the_centre() -> None:
    """Sun along +u at phase 90: ``cos i = (u - c_u) / R`` on the disc, so
    along the centre row a pixel covering ``[x - 1/2, x + 1/2]`` of
    ``u - c_u`` holds ``A / R`` times the mean of ``max(t, 0)`` over it."""
    radius = 90.0
    centre = (150.0, 150.37)
    sc = render_sphere(center_vu=centre, radius_px=radius, phase_deg=90.0, illumination_deg=90.0,
                       albedo_dn=A, oversample=16)
    row = sc.image[150]
    for j in range(140, 161):
        x = j - centre[1]
        lo, hi = x - 0.5, x + 0.5
        exact = (max(hi, 0.0) ** 2 - max(lo, 0.0) ** 2) / 2.0 * A / radius
        assert row[j] == pytest.approx(exact, abs=2e-3 * A / radius), j


@pytest.mark.parametrize("phase", [30.0, 60.0, 120.0])
@pytest.mark.parametrize("ill", [0.0, 90.0, 215.0])
def test_terminator_lies_where_cos_i_vanishes(phase: float, ill: float) -> None:
    """Along the Sun's axis through the centre the terminator is at
    ``c - R cos(phase) s``: dark a pixel and more beyond it, lit before it."""
    radius = 80.0
    centre = (150.0, 150.0)
    sc = render_sphere(center_vu=centre, radius_px=radius, phase_deg=phase,
                       illumination_deg=ill, albedo_dn=A)
    s = np.asarray(sun_direction_vu(ill))
    x_t = -radius * math.cos(math.radians(phase))
    for x, dark in ((x_t - 2.0, True), (x_t + 2.0, False)):
        p = np.asarray(centre) + x * s
        i, j = int(round(p[0])), int(round(p[1]))
        # a pixel's own extent is at most sqrt(2)/2 from its centre
        assert (sc.image[i, j] == 0.0) == dark, (x, sc.image[i, j])


def test_polylines_follow_the_geometry() -> None:
    sc = render_sphere(center_vu=(151.2, 148.9), radius_px=70.0, phase_deg=50.0,
                       illumination_deg=120.0, offset_vu=(0.4, -0.3), n_vertices=64)
    mc = np.asarray(sc.model_center_vu)
    np.testing.assert_allclose(mc, np.asarray(sc.center_vu) - (0.4, -0.3))
    s = np.asarray(sun_direction_vu(120.0))
    d = sc.limb.vertices_vu - mc
    np.testing.assert_allclose(np.hypot(d[:, 0], d[:, 1]), 70.0)
    assert (d @ s > 0).all()  # the sunlit half
    np.testing.assert_allclose(sc.limb.normals_vu, -d / 70.0)  # into the disc
    # the terminator: N . L = 0 with N_z >= 0, normals up grad(cos i)
    t = sc.terminator
    assert t is not None
    nv = (t.vertices_vu - mc) / 70.0
    nz = np.sqrt(1.0 - (nv**2).sum(axis=1))
    ph = math.radians(50.0)
    cos_i = math.sin(ph) * (nv @ s) + math.cos(ph) * nz
    np.testing.assert_allclose(cos_i, 0.0, atol=1e-12)
    step = 1e-3
    p = t.vertices_vu + step * t.normals_vu
    q = (p - mc) / 70.0
    assert (math.sin(ph) * (q @ s) + math.cos(ph) * np.sqrt(1.0 - (q**2).sum(axis=1)) > 0).all()
    assert render_sphere(phase_deg=0.0).terminator is None


def test_minnaert_one_is_lambert_and_the_laws_differ() -> None:
    kw = dict(center_vu=(150.4, 149.8), radius_px=60.0, phase_deg=40.0, illumination_deg=30.0)
    lam = render_sphere(law="lambert", **kw)
    np.testing.assert_array_equal(render_sphere(law="minnaert", minnaert_k=1.0, **kw).image,
                                  lam.image)
    for law, k in (("minnaert", 0.7), ("lommel-seeliger", None)):
        other = render_sphere(law=law, minnaert_k=k, **kw).image
        assert np.isfinite(other).all()
        assert not np.allclose(other, lam.image)
    assert set(SPHERE_LAWS) == {"lambert", "minnaert", "lommel-seeliger"}


def test_blur_keeps_the_light_and_wings_are_not_gaussian() -> None:
    kw = dict(center_vu=(150.0, 150.0), radius_px=60.0, phase_deg=30.0)
    sharp = render_sphere(**kw).image
    gauss = render_sphere(psf_sigma_px=1.2, **kw).image
    wings = render_sphere(psf_sigma_px=1.2, psf="core+wings", **kw).image
    assert gauss.sum() == pytest.approx(sharp.sum(), rel=1e-9)
    assert wings.sum() == pytest.approx(sharp.sum(), rel=1e-9)
    # wings carry light farther off the limb than the core alone
    far = np.s_[150, 150 + 60 + 8 : 150 + 60 + 14]
    assert wings[far].sum() > 10.0 * gauss[far].sum()


def test_noise_is_seeded_and_reported() -> None:
    kw = dict(radius_px=50.0, background_dn=20.0, poisson_gain=4.0, read_noise_dn=1.5, seed=7)
    a, b = render_sphere(**kw), render_sphere(**kw)
    np.testing.assert_array_equal(a.image, b.image)
    assert not np.array_equal(a.image, render_sphere(**{**kw, "seed": 8}).image)
    assert a.noise_sigma == pytest.approx(math.sqrt(1.5**2 + 20.0 / 4.0))
    sky = a.image[:40, :40]
    assert sky.std() == pytest.approx(a.noise_sigma, rel=0.1)
    assert math.isinf(render_sphere(radius_px=50.0).peak_snr)
    assert 10.0 < a.peak_snr < 100.0


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"law": "hapke"}, "law"),
        ({"law": "minnaert"}, "minnaert_k"),
        ({"minnaert_k": 0.7}, "minnaert_k"),
        ({"phase_deg": 180.0}, "phase_deg"),
        ({"radius_px": 0.0}, "radius_px"),
        ({"psf": "airy"}, "psf"),
        ({"oversample": 0}, "oversample"),
        ({"n_vertices": 1}, "n_vertices"),
        ({"illumination_deg": math.nan}, "illumination_deg"),
    ],
)
def test_bad_arguments_are_named(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        render_sphere(**kwargs)


#: What scenes.py may import of dtalign: the model polylines' record and
#: builders (geometry, the model's own input: the scenes' polylines are the
#: ones a user builds), nothing that computes a brightness.
POLYLINE_NAMES = {"Polyline", "sphere_limb_polyline", "sphere_terminator_polyline",
                  "sun_direction_vu"}


def test_renderer_is_independent_of_the_fit() -> None:
    """The renderer shares no code with the fit's model: a renderer that
    shared the profile fit's model would only show that the model agrees
    with itself. scenes.py imports of dtalign only the polyline builders
    (``dtalign.api.polylines``), which compute no radiance, and its
    shading uses none of them."""
    src = Path(__file__).parents[1] / "src" / "dtalign"
    tree = ast.parse((src / "scenes.py").read_text())
    imported = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level == 0 and not (node.module or "").startswith("dtalign"):
                continue
            assert node.level == 1 and node.module == "api.polylines", node.module
            imported |= {a.asname or a.name for a in node.names}
        elif isinstance(node, ast.Import):
            assert all(not a.name.startswith("dtalign") for a in node.names)
    assert imported <= POLYLINE_NAMES
    shading = {"_shade", "_sphere_signal", "_blur_fine", "_gaussian_kernel_1d", "_camera"}
    for node in tree.body:
        if isinstance(node, ast.FunctionDef) and node.name in shading:
            used = {n.id for n in ast.walk(node) if isinstance(n, ast.Name)}
            assert not used & imported, node.name
    # the builders take of the profile module only its record and edge kinds
    builders = ast.parse((src / "api" / "polylines.py").read_text())
    for node in ast.walk(builders):
        if isinstance(node, ast.ImportFrom) and node.level == 1:
            names = frozenset(a.name for a in node.names)
            assert (node.module, names) in {("profiles", frozenset({"EDGE_KINDS", "EdgeProfile"})),
                                            (None, frozenset({"checks"}))}, (node.module, names)
