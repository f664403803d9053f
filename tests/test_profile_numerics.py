"""The edge-profile refinement on inputs of measure zero: the pixel model's
two projected widths at and around 0 and :data:`MIN_BOX_WIDTH`, in either
order; normals exactly on the axes and diagonals; a vertex on a pixel
centre; a straight edge (zero curvature); a zero-width strip; and every
numerical failure inside the refinement, which becomes a rejected
refinement with its cause, never an exception.

The randomised sweeps over illumination, vertex counts, phases, PSFs and
noise are ``test_profile_sweeps.py``; this file holds the exact corners.
"""

from __future__ import annotations

import math
import types

import numpy as np
import pytest

from dtalign import EdgeProfile, fit_polyline, sphere_edge_profile
from dtalign._kernels import profile as kp
from dtalign.pipeline import profile_fit
from dtalign.pipeline.status import describe
from dtalign.reference import profile as rp
from dtalign.scenes import render_sphere

MIN = kp.MIN_BOX_WIDTH


# -- the pixel model: one formula, continuous in both widths ----------------


def _tables(sigma=0.7):
    """The blurred tables of one smooth step row (contrast 1) and a kinked one."""
    h = 0.125
    off = (np.arange(-48, 48) + 0.5) * h
    rows = np.stack([0.5 * (1.0 + np.tanh(off / 0.8)), np.clip(off, 0.0, None) / 6.0])
    nb = rows.shape[1]
    b, c, d, t0, ht = kp.tables(np.ascontiguousarray(rows), float(off[0]), h, 0, nb, sigma)
    return b, c, d, t0, ht


def _box(b, c, d, k, x, h, wa, wb):
    return np.array(kp.box_model(b, c, d, k, x, h, wa, wb))


def _quadrature(b, k, x, h, wa, wb, n=600):
    """The blurred row averaged over ``box(wa) * box(wb)`` by midpoint quadrature
    (no antiderivative, no cancellation): what the model is meant to equal."""
    grid = h * np.arange(b.shape[1])
    ua = ((np.arange(n) + 0.5) / n - 0.5) * wa
    ub = ((np.arange(n) + 0.5) / n - 0.5) * wb
    pts = x + ua[:, None] + ub[None, :]
    return float(np.interp(pts, grid, b[k]).mean())


WIDTHS = [0.0, 1e-300, 1e-16, 0.5 * MIN, MIN * (1 - 1e-12), MIN, MIN * (1 + 1e-12), 2 * MIN,
          0.3, math.sqrt(0.5), 1.0]


@pytest.mark.parametrize("k", [0, 1])
def test_box_model_is_symmetric_finite_and_matches_the_reference(k):
    b, c, d, t0, ht = _tables()
    xs = np.linspace(-1.0, b.shape[1] * ht + 1.0, 37)
    for wa in WIDTHS:
        for wb in WIDTHS:
            for x in xs:
                m = _box(b, c, d, k, x, ht, wa, wb)
                assert np.isfinite(m).all(), (wa, wb, x)
                # either order: one formula (only the sums' order differs)
                np.testing.assert_allclose(m, _box(b, c, d, k, x, ht, wb, wa), rtol=0, atol=1e-12)
            ref = rp._box_model(b, c, d, np.full(xs.shape, k), xs, ht, np.full(xs.shape, wa),
                                np.full(xs.shape, wb))
            got = np.array([_box(b, c, d, k, x, ht, wa, wb) for x in xs]).T
            np.testing.assert_allclose(got, np.array(ref), rtol=0, atol=1e-12)


def test_box_model_is_continuous_at_zero_and_at_the_floor():
    b, c, d, t0, ht = _tables()
    for x in np.linspace(2.0, 10.0, 17):
        for wb in (0.0, 0.4, 1.0):
            at_floor = _box(b, c, d, 0, x, ht, MIN, wb)
            # every width below the floor is the floor: 0 and 1e-16 (an axis
            # normal computed as cos(pi / 2)) give the same model, not a
            # division by 0 or by 1e-16
            for w in (0.0, 1e-300, 1e-16, 0.5 * MIN):
                np.testing.assert_array_equal(_box(b, c, d, 0, x, ht, w, wb), at_floor)
            # just above the floor the model moves with the width: its value
            # and slope by O(the change), its curvature (a second difference
            # over the box) by at most 2 max|B'| / MIN**2 times the change
            # (plus the rounding of the four-term difference of second
            # antiderivatives, divided by the widths' product)
            lipschitz = 2.0 * (np.abs(np.diff(b[0])).max() / ht) / MIN**2
            rounding = 8.0 * np.finfo(float).eps * np.abs(d[0]).max() / (MIN * max(wb, MIN))
            for eps in (1e-12, 1e-9, 1e-6):
                step = np.abs(_box(b, c, d, 0, x, ht, MIN * (1 + eps), wb) - at_floor)
                assert step[:2].max() <= rounding + 10.0 * MIN * eps, (x, wb, eps)
                assert step[2] <= rounding + lipschitz * MIN * eps, (x, wb, eps)


@pytest.mark.parametrize("wa, wb", [(0.0, 1.0), (1e-16, 1.0), (1.0, 0.0), (MIN, MIN),
                                    (math.sqrt(0.5), math.sqrt(0.5)), (0.6, 0.8), (0.0, 0.0)])
def test_box_model_is_the_box_average_it_claims(wa, wb):
    """Against quadrature of the blurred row over the pixel's projected
    trapezoid: exact for the floored widths; for the true widths within what
    the floor adds: the row is piecewise linear, and a box of width ``w``
    moves a kink's value by at most its slope change times ``w / 8``."""
    b, c, d, t0, ht = _tables()
    kink = np.abs(np.diff(b[0], 2)).max() / ht
    added = kink * (max(MIN - wa, 0.0) + max(MIN - wb, 0.0)) / 8.0
    for x in np.linspace(3.0, 9.0, 13):
        got = _box(b, c, d, 0, x, ht, wa, wb)[0]
        want = _quadrature(b, 0, x, ht, max(wa, MIN), max(wb, MIN))
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-6)
        unfloored = _quadrature(b, 0, x, ht, wa, wb)
        assert abs(got - unfloored) <= added + 1e-6


def test_antiderivatives_form_no_index_from_a_nan():
    b, c, d, t0, ht = _tables()
    out = kp.antiderivs(b, c, d, 0, math.nan, ht)
    assert len(out) == 4  # returned (NaN values), no out-of-range read


def test_small_solver_reports_singular_and_non_finite_systems():
    x, ok = kp.solve_small(np.eye(2), np.array([1.0, 2.0]))
    assert ok and np.array_equal(x, [1.0, 2.0])
    assert not kp.solve_small(np.zeros((2, 2)), np.ones(2))[1]
    assert not kp.solve_small(np.array([[1e-300, 0.0], [0.0, 1.0]]), np.array([1e300, 1.0]))[1]
    assert not kp.solve_small(np.array([[1.0, 0.0], [0.0, 1.0]]), np.array([np.nan, 1.0]))[1]


# -- whole fits at the exact corners ------------------------------------------


def _sphere(ill, n, *, center=None, off=(0.37, -0.61), phase=35.0, radius=70.0):
    return render_sphere(shape=(240, 240), center_vu=center, radius_px=radius, phase_deg=phase,
                         illumination_deg=ill, offset_vu=off, n_vertices=n, background_dn=20.0,
                         albedo_dn=1500.0)


def _fit(sc, poly=None, edge="limb"):
    p = poly if poly is not None else (sc.limb if edge == "limb" else sc.terminator)
    prof = sphere_edge_profile(p.vertices_vu, center_vu=sc.model_center_vu,
                               radius_px=sc.radius_px, phase_deg=sc.phase_deg,
                               illumination_deg=sc.illumination_deg, edge=edge)
    return fit_polyline(sc.image, p.vertices_vu, prof.normals_vu, np.ones(len(p.vertices_vu)),
                        search_window_vu=(6, 6), edge_profile=prof)


def _err(fit, sc):
    return float(np.hypot(*(np.asarray(fit.offset_vu) - sc.true_offset_vu)))


#: Noise-free Lambert limbs at phase 35 deg: the refinement's error there is
#: below 0.009 px at every count from 4 and direction measured (axis and
#: diagonal normals included); 0.02 px holds that with room for another
#: CPU's sums.
NOISE_FREE_LIMB_PX = 0.02


@pytest.mark.parametrize("ill", range(0, 360, 45))
@pytest.mark.parametrize("n", [5, 6, 41, 163])
def test_axis_and_diagonal_normals_fit_at_any_vertex_count(ill, n):
    """An odd count puts the middle vertex's normal exactly on the light's
    axis (an even one of the form 4k + 2 puts two at 45 deg from it): on a coordinate axis at 0, 90, 180, 270 deg, on a diagonal at the
    others (the normals ``(-0.0, -1.0)`` that once gave NaN residuals)."""
    sc = _sphere(ill, n)
    fit = _fit(sc)
    assert fit.profile.accepted, fit.profile.reason
    assert fit.status == "ok", fit.summary()
    assert _err(fit, sc) <= NOISE_FREE_LIMB_PX


def test_vertices_on_pixel_centres_fit():
    sc = _sphere(0.0, 41, center=(120.0, 120.0), off=(0.0, 0.0))
    verts = sc.limb.vertices_vu.copy()
    # the axis vertex, at an integer radius from an integer centre (to 1e-14:
    # its angle is a sum of multiples of pi), put exactly on the pixel centre
    near = np.abs(verts - np.round(verts)).max(axis=1) < 1e-9
    assert near.sum() >= 1
    verts[near] = np.round(verts[near])
    fit = _fit(sc, types.SimpleNamespace(vertices_vu=verts))
    assert fit.profile.accepted and fit.status == "ok"
    assert _err(fit, sc) <= NOISE_FREE_LIMB_PX


def _half_plane(edge_u=20.37, shape=(48, 48)):
    """A straight vertical edge, dark left of ``edge_u``, bright (1000 DN) right of
    it, each pixel the exact area fraction."""
    u = np.arange(shape[1], dtype=float)
    frac = np.clip(u + 0.5 - edge_u, 0.0, 1.0)
    return np.tile(10.0 + 1000.0 * frac, (shape[0], 1))


def _straight_profile(n, normal=(0.0, 1.0)):
    off = (np.arange(-48, 48) + 0.5) * 0.125
    return EdgeProfile(offsets_px=off, values=np.tile((off > 0).astype(float), (n, 1)),
                       normals_vu=np.tile(normal, (n, 1)), curvature_px=np.zeros(n),
                       psf_sigma_px=0.0, edge="ring")


def test_a_straight_edge_measures_across_and_says_along():
    """Zero curvature, axis normals: the offset along the edge is not fixed by
    any pixel, so the refinement either fits the offset across the edge (and
    reports the along-edge direction unmeasured) or is rejected with that cause."""
    image = _half_plane()
    verts = np.stack([np.linspace(8.0, 40.0, 17), np.full(17, 20.0)], axis=1)
    ref = profile_fit.refine_with_profile(image, _straight_profile(17), verts, (0.0, 0.3))
    if ref.accepted:
        assert abs(ref.offset_vu[1] - 0.37) <= 0.01
    else:
        assert ref.reason
    fit = fit_polyline(image, verts, np.tile([0.0, 1.0], (17, 1)), np.ones(17),
                       search_window_vu=(3, 3), edge_profile=_straight_profile(17))
    assert fit.status != "ok" or abs(fit.offset_vu[1] - 0.37) <= 0.01


def test_a_zero_width_strip_is_refined_or_rejected_not_raised():
    """Coincident vertices: every strip has zero width along the edge."""
    image = _half_plane()
    verts = np.tile([24.0, 20.0], (9, 1))
    ref = profile_fit.refine_with_profile(image, _straight_profile(9), verts, (0.0, 0.3))
    assert ref.accepted or ref.reason
    fit = fit_polyline(image, verts, np.tile([0.0, 1.0], (9, 1)), np.ones(9),
                       search_window_vu=(3, 3), edge_profile=_straight_profile(9))
    assert fit.status in ("ok", "suspect", "ambiguous", "failed")


def test_a_terminator_at_exactly_90_deg_with_its_horns_returns():
    """Phase 90 deg makes the terminator a straight segment whose horns have
    a curvature of ~1e30 /px: the fit returns, and is not ok and off."""
    sc = _sphere(0.0, 41, phase=90.0)
    c = np.asarray(sc.model_center_vu)
    t = np.linspace(-math.pi, 0.0, 41)
    perp = np.array([0.0, 1.0])  # the light along -v (0 deg): the terminator runs along u
    pts = c + sc.radius_px * np.cos(t)[:, None] * perp[None, :]
    prof = sphere_edge_profile(pts, center_vu=sc.model_center_vu, radius_px=sc.radius_px,
                               phase_deg=90.0, illumination_deg=0.0, edge="terminator")
    assert np.abs(prof.curvature_px).max() > 1e20
    fit = fit_polyline(sc.image, pts, prof.normals_vu, np.ones(41), search_window_vu=(6, 6),
                       edge_profile=prof)
    assert fit.status != "ok" or _err(fit, sc) <= 0.1


# -- every failure inside is a rejected refinement with its cause -------------


class _Kernels(types.SimpleNamespace):
    """The compiled kernels with some replaced."""

    def __getattr__(self, name):
        return getattr(kp, name)


def _limb_case():
    sc = _sphere(30.0, 60)
    prof = sphere_edge_profile(sc.limb.vertices_vu, center_vu=sc.model_center_vu,
                               radius_px=sc.radius_px, phase_deg=sc.phase_deg,
                               illumination_deg=sc.illumination_deg, edge="limb")
    return sc, prof


def _rejected_because(ref, text):
    assert not ref.accepted
    assert text in ref.reason, ref.reason
    assert math.isnan(ref.gain) and np.isnan(ref.covariance).all()
    assert ref.to_dict()["accepted"] is False


def test_a_model_that_is_not_finite_is_a_rejection():
    sc, prof = _limb_case()

    def evaluate(obs, *args):
        r, jac = kp.evaluate(obs, *args)
        r[::7] = np.nan
        return r, jac

    ref = profile_fit.refine_with_profile(sc.image, prof, sc.limb.vertices_vu, (0.4, -0.6),
                                          kernels=_Kernels(evaluate=evaluate))
    _rejected_because(ref, "model is not finite at")


def test_a_gauss_newton_that_leaves_the_finite_numbers_is_a_rejection():
    sc, prof = _limb_case()

    def refine(*args):
        out = list(kp.refine(*args))
        out[0] = np.full_like(out[0], np.nan)
        return tuple(out)

    ref = profile_fit.refine_with_profile(sc.image, prof, sc.limb.vertices_vu, (0.4, -0.6),
                                          kernels=_Kernels(refine=refine))
    _rejected_because(ref, "not finite")


def test_a_singular_information_matrix_is_a_rejection():
    sc, prof = _limb_case()

    def refine(*args):
        out = list(kp.refine(*args))
        out[3] = np.full_like(out[3], np.inf)  # the inverse of a singular information matrix
        return tuple(out)

    ref = profile_fit.refine_with_profile(sc.image, prof, sc.limb.vertices_vu, (0.4, -0.6),
                                          kernels=_Kernels(refine=refine))
    assert not ref.accepted
    assert ref.reason == ("its information matrix is singular: the strips' pixels do not fix "
                          "the offset")


def test_too_few_pixels_is_a_rejection():
    """Five coincident vertices (zero-width strips) in a one-pixel image: one
    pixel each, fewer than the parameters."""
    n = profile_fit.MIN_VERTICES
    ref = profile_fit.refine_with_profile(np.full((1, 1), 5.0),
                                          _straight_profile(n, normal=(1.0, 0.0)),
                                          np.zeros((n, 2)), (0.0, 0.0))
    _rejected_because(ref, f"too few pixels in the strips ({n} for")


@pytest.mark.parametrize("n", [3, 4])
def test_too_few_vertices_is_a_rejection(n):
    """3-4 vertices: a few short strips carry the whole pose (the sweeps found
    such fits ok and 1-2.4 px off); refused, the pose the DT-LM's, suspect."""
    sc = _sphere(30.0, n)
    fit = _fit(sc)
    _rejected_because(fit.profile, f"too few vertices for the photometric fit ({n}, at least 5)")
    assert fit.status == "suspect" and "profile_rejected" in fit.reasons


def test_a_profile_without_contrast_is_a_rejection():
    sc, prof = _limb_case()
    flat = EdgeProfile(offsets_px=prof.offsets_px, values=np.full(prof.values.shape, 0.3),
                       normals_vu=prof.normals_vu, curvature_px=prof.curvature_px, edge="limb")
    ref = profile_fit.refine_with_profile(sc.image, flat, sc.limb.vertices_vu, (0.4, -0.6))
    _rejected_because(ref, "no vertex's profile has any contrast")
    assert ref.n_flat_vertices == 60
    fit = fit_polyline(sc.image, sc.limb.vertices_vu, sc.limb.normals_vu, np.ones(60),
                       search_window_vu=(6, 6), edge_profile=flat)
    assert fit.status == "suspect" and "profile_rejected" in fit.reasons


def test_a_closed_limb_leaves_its_unlit_half_out_and_says_so():
    sc = _sphere(30.0, 60)
    c = np.asarray(sc.model_center_vu)
    th = 2.0 * math.pi * np.arange(120) / 120
    radial = np.stack([np.cos(th), np.sin(th)], axis=1)
    verts = c + sc.radius_px * radial
    prof = sphere_edge_profile(verts, center_vu=sc.model_center_vu, radius_px=sc.radius_px,
                               phase_deg=sc.phase_deg, illumination_deg=sc.illumination_deg,
                               edge="limb")
    fit = fit_polyline(sc.image, verts, -radial, np.ones(120), search_window_vu=(6, 6),
                       edge_profile=prof)
    assert fit.profile.n_flat_vertices > 0
    if fit.profile.accepted:
        assert _err(fit, sc) <= NOISE_FREE_LIMB_PX
        assert "flat_profile_vertices" in fit.reasons
        assert f"{fit.profile.n_flat_vertices} of 120 vertices' profiles have no contrast" in (
            describe(fit))


# -- the reported crash ---------------------------------------------------------


@pytest.mark.parametrize("first", [None, 40, 60, 100])
def test_the_163_vertex_limb_that_raised_fits(first):
    """The reproducer of a ``LinAlgError`` (from a NaN residual at the
    vertex whose normal was ``(-0.0, -1.0)``), and the subsets of its
    vertices that raised and fitted in turn on the independent renders."""
    sc = render_sphere(shape=(320, 320), radius_px=90.0, phase_deg=35.0, illumination_deg=90.0,
                       offset_vu=(0.37, -0.61), n_vertices=163, background_dn=20.0,
                       albedo_dn=1500.0)
    p = sc.limb
    sel = slice(None) if first is None else slice(0, first)
    prof = sphere_edge_profile(p.vertices_vu[sel], center_vu=sc.model_center_vu,
                               radius_px=90.0, phase_deg=35.0, illumination_deg=90.0,
                               edge="limb")
    fit = fit_polyline(sc.image, p.vertices_vu[sel], p.normals_vu[sel], p.sigmas[sel],
                       search_window_vu=(6, 6), edge_profile=prof)
    assert fit.profile.accepted, fit.profile.reason
    assert _err(fit, sc) <= NOISE_FREE_LIMB_PX


def test_the_reference_refines_axis_normals_as_the_kernels_do():
    """The NumPy specification on the same corner (an axis normal, a closed
    limb's flat vertices left out): the same offset and iterations."""
    sc = render_sphere(shape=(320, 320), radius_px=90.0, phase_deg=35.0, illumination_deg=90.0,
                       offset_vu=(0.37, -0.61), n_vertices=163, background_dn=20.0,
                       albedo_dn=1500.0)
    p = sc.limb
    prof = sphere_edge_profile(p.vertices_vu, center_vu=sc.model_center_vu, radius_px=90.0,
                               phase_deg=35.0, illumination_deg=90.0, edge="limb")
    a = profile_fit.refine_with_profile(sc.image, prof, p.vertices_vu, (0.3, -0.5))
    b = profile_fit.refine_with_profile(sc.image, prof, p.vertices_vu, (0.3, -0.5), kernels=rp)
    assert a.accepted and b.accepted
    np.testing.assert_allclose(a.offset_vu, b.offset_vu, atol=1e-9)
    assert a.iterations == b.iterations and a.n_pixels == b.n_pixels


def test_a_vertex_where_the_sphere_defines_no_normal_is_refused():
    """The two points where a sphere's profile has no normal: a limb vertex
    at the centre, a terminator vertex at the sub-solar point (where
    ``grad cos i`` is exactly 0); a ValueError each, not NaN normals."""
    kw = dict(center_vu=(100.0, 100.0), radius_px=50.0, phase_deg=60.0, illumination_deg=0.0)
    with pytest.raises(ValueError, match="lies at center_vu"):
        sphere_edge_profile(np.array([[100.0, 100.0], [60.0, 100.0]]), edge="limb", **kw)
    sub_solar = 100.0 - 50.0 * math.sin(math.radians(60.0))  # the light along -v at 0 deg
    with pytest.raises(ValueError, match="sub-solar point"):
        sphere_edge_profile(np.array([[sub_solar, 100.0]]), edge="terminator", **kw)
