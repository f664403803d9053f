"""The pipeline's covariance (:mod:`dtalign.pipeline.uncertainty`): its parts,
where every fit path gets it, and its coverage on a fixed seeded subset."""

from __future__ import annotations

import json
import logging
import math

import numpy as np
import pytest

from dtalign import robustness, scenes
from dtalign.api.image import edge_threshold
from dtalign.api.loop import second_edge_search
from dtalign.benchmarking import coverage as cov
from dtalign.pipeline import PolylineFit, fit_polyline, fit_polyline_products, prepare_image
from dtalign.pipeline import uncertainty as unc
from dtalign.pipeline.batch import fit_many
from dtalign.reference.evidence import second_edge_search as reference_search


@pytest.fixture(scope="module")
def nav():
    return scenes.navigation_scene(shape=(512, 512), radius=80.0)


@pytest.fixture(scope="module")
def nav_products(nav):
    return prepare_image(nav.image, nav.noise_sigma)


def _straight(n: int, spacing: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    pts = np.column_stack([np.zeros(n), spacing * np.arange(n, dtype=float)])
    jac = np.tile([1.0, 0.0], (n, 1))  # each vertex measures v only
    return pts, jac


# --------------------------------------------------------------------------- parts


def test_far_apart_vertices_give_the_classical_robust_covariance() -> None:
    rng = np.random.default_rng(0)
    n = 50
    pts = np.column_stack([100.0 * np.arange(n), np.zeros(n)])  # no pair within reach
    jac = rng.normal(size=(n, 2))
    r = rng.normal(size=n)
    w = np.ones(n)
    got = unc.sandwich_covariance(jac, r, w, pts)
    h = np.linalg.inv(jac.T @ jac)
    psi = r[:, None] * jac
    want = h @ (psi.T @ psi) @ h * n / (n - 2)
    np.testing.assert_allclose(got, want, rtol=1e-10)


def test_neighbours_reading_the_same_pixels_count_as_fewer_samples() -> None:
    # the same residual on every vertex of a 1-px spaced run: one measurement
    # repeated, not n; the sandwich must see it, an independent sum does not
    n = 64
    pts, jac = _straight(n)
    r = np.repeat(np.array([0.3, -0.3]), n // 2)
    w = np.ones(n)
    near = unc.sandwich_covariance(jac, r, w, pts)
    far = unc.sandwich_covariance(jac, r, w, pts * 100.0)
    assert near[0, 0] > 5.0 * far[0, 0]
    assert near[1, 1] == 0.0 and near[0, 1] == 0.0  # u is not observed


def test_too_few_weighted_vertices_give_inf() -> None:
    pts, jac = _straight(5)
    w = np.array([1.0, 1.0, 0.0, 0.0, 0.0])
    assert np.isinf(unc.sandwich_covariance(jac, np.ones(5), w, pts)).all()


def test_the_floor_lies_along_observed_directions_only() -> None:
    pts, jac = _straight(10)
    f = unc.floor_covariance(jac, np.ones(10), 0.2)
    np.testing.assert_allclose(f, [[0.04, 0.0], [0.0, 0.0]], atol=1e-15)
    assert (unc.floor_covariance(jac, np.zeros(10), 0.2) == 0.0).all()


def test_a_rotation_floor_moves_the_vertices_by_the_floor() -> None:
    # a circle of radius 50 about its centre: the rotation's lever arm is 50
    t = np.linspace(0, 2 * np.pi, 200, endpoint=False)
    normals = np.column_stack([np.cos(t), np.sin(t)])
    tangents = np.column_stack([-np.sin(t), np.cos(t)])
    # a DT gradient with some tangential part, so the rotation is observed
    g = normals + 0.5 * tangents
    rot = 50.0 * (g * tangents).sum(axis=1)
    jac = np.column_stack([g, rot])
    f = unc.floor_covariance(jac, np.ones(200), 0.1)
    lever2 = np.sum(rot**2) / np.sum(g[:, 0] ** 2 + g[:, 1] ** 2)
    assert f[2, 2] == pytest.approx(0.01 / lever2)


def test_a_cone_of_the_dt_is_stiff_along_the_edge_too() -> None:
    # vertices whose DT gradient is along v: Gauss-Newton sees nothing along
    # u; the cone of an isolated edge pixel (r c = 1) adds w r c along u
    n = 10
    _, jac = _straight(n)
    r = np.full(n, 0.5)
    w = np.ones(n)
    gn = unc.information(jac, r, w)
    np.testing.assert_allclose(gn, [[n, 0.0], [0.0, 0.0]], atol=1e-12)
    cone = unc.information(jac, r, w, curvature=np.full(n, 2.0))
    np.testing.assert_allclose(cone, [[n, 0.0], [0.0, n * 0.5 * 2.0]], atol=1e-12)
    # a flat DT (a dense line) adds nothing; the sandwich takes the bread given
    np.testing.assert_allclose(unc.information(jac, r, w, curvature=np.zeros(n)), gn)
    pts = np.column_stack([np.zeros(n), 100.0 * np.arange(n)])
    plain = unc.sandwich_covariance(jac, r, w, pts)
    bent = unc.sandwich_covariance(jac, r, w, pts, information=gn)
    np.testing.assert_allclose(bent, plain, atol=1e-15)


def test_the_second_edge_shift_is_the_measured_curve() -> None:
    got = unc.second_edge_shift(np.array([3.0, 3.0 + unc.SECOND_EDGE_DECAY_PX, 1.0, np.inf]),
                                np.array([1.0, 1.0, 1.0, 1.0]))
    np.testing.assert_allclose(got[:2], [unc.SECOND_EDGE_SHIFT_PX,
                                         unc.SECOND_EDGE_SHIFT_PX / math.e])
    assert got[2] == unc.SECOND_EDGE_MAX_SHIFT_PX and got[3] == 0.0
    # linear in the other edge's gradient relative to the vertex's own
    half = unc.second_edge_shift(np.array([3.5]), np.array([0.5]))
    assert half[0] == pytest.approx(0.5 * unc.second_edge_shift(np.array([3.5]),
                                                                np.array([1.0]))[0])


def _search_inputs(products, pts: np.ndarray, normals: np.ndarray) -> tuple:
    unit = normals / np.hypot(normals[:, 0], normals[:, 1])[:, None]
    threshold = edge_threshold(products.config, products.noise_sigma)
    return (products.gradient_magnitude, np.asarray(products.gradient_vu),
            np.ascontiguousarray(pts, dtype=np.float64), np.ascontiguousarray(unit),
            unc._PROFILE_STEPS, unc._PROFILE_STEP_PX, threshold, unc._OWN_EDGE_PX)


@pytest.mark.parametrize("family", ["terminator_limb", "crater_rim", "outliers"])
def test_the_compiled_second_edge_search_is_its_specification_bit_for_bit(family: str) -> None:
    # on each scene's polyline at the truth, where second edges are, and at
    # random places and directions, the image's borders included (clamped reads)
    draw = np.random.default_rng(7)
    found = 0
    for seed in range(6):
        sc = cov.FAMILIES[family](seed)
        products = prepare_image(sc.image, sc.noise_sigma)
        p = sc.polyline
        h, w = sc.image.shape
        k = 300
        anywhere = np.column_stack([draw.uniform(-3.0, h + 2.0, k), draw.uniform(-3.0, w + 2.0, k)])
        for pts, normals in [(p.vertices_vu + sc.true_offset_vu, p.normals_vu),
                             (anywhere, draw.normal(size=(k, 2)))]:
            args = _search_inputs(products, pts, normals)
            got = second_edge_search(*args)
            want = reference_search(*args)
            for a, b in zip(got, want, strict=True):
                assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
            found += int(np.isfinite(got[0]).sum())
    assert found > 0  # the scenes do have second edges to find


@pytest.mark.parametrize(("seed", "near"), [(25, True), (55, False)])
def test_a_crescent_s_other_edge_s_pull_is_corrected(seed: int, near: bool) -> None:
    # terminator_limb seed 25: a limb 3.0 px from the crescent's terminator,
    # which pushes the DT-LM pose 0.34 px away from it (an error no residual
    # shows); seed 55: a crescent 7.4 px wide, no pull
    case = cov.FAMILIES["terminator_limb"](seed)
    fit = cov.plain_fit(case)
    u, ev = fit.uncertainty, fit.evidence
    along = np.einsum("nk,nk->n", ev.second_edge_vu, fit.normals_vu)
    beta = unc.second_edge_pull(fit, ev)
    # the pose is the DT-LM's less the pull; the pull's size stays in the covariance
    np.testing.assert_array_equal(fit.offset_vu, np.subtract(fit.lm.offset_vu, beta))
    np.testing.assert_allclose(u.bias, np.outer(beta, beta), atol=1e-15)
    np.testing.assert_allclose(u.covariance, u.noise + np.asarray(u.bias) + unc.floor_covariance(
        ev.jacobian, fit.lm.weights, u.floor_px), atol=1e-15)
    dt_err = np.subtract(fit.lm.offset_vu, case.true_offset_vu)
    err = np.subtract(fit.offset_vu, case.true_offset_vu)
    if near:
        # the other edge is on the bright side: every vertex is pushed along
        # -n, more where the crescent narrows toward its ends
        assert (along < -0.05).all() and np.median(along) < -0.2
        assert math.hypot(*dt_err) > 0.3
        assert math.hypot(*err) < 0.5 * math.hypot(*dt_err)
        assert err @ np.linalg.solve(np.asarray(fit.covariance), err) < cov.CHI2_2D[1]
    else:
        assert np.abs(along).max() < 0.03 and np.abs(beta).max() < 0.02
        if not beta.any():
            assert fit.offset_vu == fit.lm.offset_vu


def _crescents(turned: bool) -> tuple[np.ndarray, np.ndarray]:
    """Squared Mahalanobis distances and errors of the ``ok`` plain fits of
    ``terminator_limb`` seeds 200-249, as built or turned by a seeded angle,
    which breaks its mirror symmetry (benchmarks/crescent_symmetry.py's
    "turned" row)."""
    d2, err = [], []
    for seed in range(200, 250):
        draw = np.random.default_rng(seed + 99_991)
        angle = draw.uniform(0.0, 2.0 * math.pi) if turned else 0.0
        sc = robustness.terminator_limb(seed, rotation_rad=angle)
        p = sc.polyline
        fit = fit_polyline(sc.image, p.vertices_vu, p.normals_vu, p.sigmas,
                           search_window_vu=sc.search_window_vu, noise_sigma=sc.noise_sigma)
        if str(fit.status) != "ok":
            continue
        e = np.subtract(fit.offset_vu, sc.true_offset_vu)
        d2.append(e @ np.linalg.pinv(np.asarray(fit.covariance)) @ e)
        err.append(math.hypot(*e))
    return np.asarray(d2), np.asarray(err)


def test_a_crescent_is_over_covered_only_where_its_quantisation_cancels() -> None:
    # the family builds every crescent mirror-symmetric about a line between
    # pixel rows: its edges' quantisation cancels between the halves, which
    # the noise term (the quantisation read as noise) cannot know; turned,
    # the same crescents are fitted less well and the 68 % ellipse is no
    # longer far too large (as built 1.00 here, turned 0.78: the bound
    # separates the two, it is not the target's band)
    d2_built, err_built = _crescents(turned=False)
    d2_turned, err_turned = _crescents(turned=True)
    assert len(d2_built) == len(d2_turned) == 50
    assert np.mean(d2_built <= cov.CHI2_2D[0]) >= 0.9
    assert np.mean(d2_turned <= cov.CHI2_2D[0]) < 0.85
    assert np.mean(d2_turned <= cov.CHI2_2D[1]) >= 0.9
    assert np.median(err_turned) > 1.4 * np.median(err_built)


# --------------------------------------------------------------------------- in the fit


def test_every_fit_path_reports_the_same_covariance(nav, nav_products) -> None:
    limb = nav.polylines[0]
    one = fit_polyline_products(nav_products, limb.vertices_vu, limb.normals_vu, limb.sigmas,
                                search_window_vu=(12, 12))
    call = fit_polyline(nav.image, limb.vertices_vu, limb.normals_vu, limb.sigmas,
                        search_window_vu=(12, 12), noise_sigma=nav.noise_sigma)
    (many,) = fit_many(nav_products, [limb], search_window_vu=(12, 12), workers=1)
    assert one.uncertainty is not None and one.uncertainty.source == "dt"
    np.testing.assert_array_equal(many.covariance, one.covariance)
    # the one-call fit reads the region its polyline reaches, in the crop's
    # pixels (tests/test_region.py: the frame's pose within 1e-9 px), so its
    # samples round differently in the last bits: the same covariance to 1e-9
    np.testing.assert_allclose(call.covariance, one.covariance, rtol=1e-9, atol=0.0)
    # the M-estimator's is the drop-in's, unchanged
    np.testing.assert_array_equal(one.uncertainty.covariance_mestimator, one.lm.covariance)
    assert one.sigma_vu == tuple(math.sqrt(x) for x in np.diag(one.covariance))
    # noise plus the floor: never below the floor along an observed axis
    assert min(one.sigma_vu) >= unc.FLOORS_PX["dt"]


def test_the_declared_edge_picks_the_floor(nav, nav_products) -> None:
    limb = nav.polylines[0]
    fits = {kind: fit_polyline_products(nav_products, limb.vertices_vu, limb.normals_vu,
                                        limb.sigmas, search_window_vu=(12, 12), edge_kind=kind)
            for kind in (None, "limb", "terminator", "ring")}
    assert {k: f.uncertainty.source for k, f in fits.items()} == {
        None: "dt", "limb": "dt_limb", "terminator": "dt_terminator", "ring": "dt"}
    # the same pose, the same noise: only the floor differs
    base = fits[None].uncertainty
    for f in fits.values():
        assert f.offset_vu == fits[None].offset_vu
        np.testing.assert_array_equal(f.uncertainty.noise, base.noise)
    assert fits["limb"].sigma_vu[0] > unc.FLOORS_PX["dt_limb"] > fits[None].sigma_vu[0]


def test_a_straight_edge_claims_nothing_along_it(nav, nav_products) -> None:
    ring = nav.polylines[2]
    fit = fit_polyline_products(nav_products, ring.vertices_vu, ring.normals_vu, ring.sigmas,
                                search_window_vu=(12, 12), trust_region_px=1.0)
    sv, su = fit.sigma_vu
    assert math.isfinite(sv) and su == math.inf
    assert fit.sigma_along((0.0, 1.0)) == math.inf
    assert fit.sigma_along((1.0, 0.0)) == pytest.approx(sv)


def test_an_accepted_profile_reports_its_own_covariance_plus_the_profile_floor() -> None:
    sc = scenes.render_sphere(radius_px=60.0, phase_deg=40.0, illumination_deg=30.0,
                              offset_vu=(0.4, -0.7), seed=3, shape=(200, 200))
    p = sc.limb
    from dtalign import sphere_edge_profile

    prof = sphere_edge_profile(p.vertices_vu, center_vu=sc.model_center_vu, radius_px=60.0,
                               phase_deg=40.0, illumination_deg=30.0)
    fit = fit_polyline(sc.image, p.vertices_vu, p.normals_vu, p.sigmas,
                       search_window_vu=(6, 6), edge_profile=prof)
    assert fit.profile is not None and fit.profile.accepted
    u = fit.uncertainty
    assert u.source == "profile"
    # the profile floor grows with the PSF's sigma the refinement held
    psf = fit.profile.psf_sigma_px
    assert u.floor_px == pytest.approx(math.hypot(unc.FLOORS_PX["profile"],
                                                  unc.PROFILE_FLOOR_PER_PSF * psf))
    np.testing.assert_allclose(u.noise, np.asarray(fit.profile.covariance))
    np.testing.assert_allclose(u.covariance, u.noise + u.floor_px**2 * np.eye(2), atol=1e-15)


def test_the_covariance_survives_the_dict_round_trip(nav, nav_products) -> None:
    limb = nav.polylines[0]
    fit = fit_polyline_products(nav_products, limb.vertices_vu, limb.normals_vu, limb.sigmas,
                                search_window_vu=(12, 12), edge_kind="limb")
    d = json.loads(json.dumps(fit.to_dict(arrays=True)))
    back = PolylineFit.from_dict(d)
    np.testing.assert_allclose(back.covariance, fit.covariance, rtol=1e-15)
    np.testing.assert_array_equal(back.uncertainty.covariance_mestimator, fit.uncertainty.covariance_mestimator)
    assert d["uncertainty_source"] == "dt_limb"
    np.testing.assert_array_equal(back.evidence.curvature, fit.evidence.curvature)
    np.testing.assert_array_equal(back.evidence.second_edge_vu, fit.evidence.second_edge_vu)
    # evidence saved before the curvature and the second edges: the
    # Gauss-Newton bread and no pull
    for k in ("curvature", "second_edge_vu"):
        del d["evidence"][k]
    older = PolylineFit.from_dict(d)
    assert older.evidence.curvature is None and older.evidence.second_edge_vu is None
    ev = fit.evidence
    w = np.asarray(fit.lm.weights)
    inlier = w >= unc.INLIER_WEIGHT_FRACTION * w.max()
    want = unc.sandwich_covariance(ev.jacobian, np.where(inlier, ev.residuals, 0.0),
                                   np.where(inlier, w, 0.0), ev.points_vu)
    np.testing.assert_allclose(older.uncertainty.noise, want, rtol=1e-12)
    assert not np.asarray(older.uncertainty.bias).any()
    # a dict written before the pipeline had its own covariance: the LM's is read
    del d["covariance_mestimator"], d["evidence"]
    d["covariance"] = np.asarray(fit.lm.covariance).tolist()
    old = PolylineFit.from_dict(d)
    assert old.uncertainty.parts is None
    np.testing.assert_array_equal(old.covariance, fit.lm.covariance)


def test_a_degenerate_fit_has_an_infinite_covariance(nav, nav_products) -> None:
    limb = nav.polylines[0]
    fit = fit_polyline_products(nav_products, limb.vertices_vu, 0 * limb.normals_vu, limb.sigmas,
                                search_window_vu=(12, 12))
    assert fit.lm.degenerate
    assert np.isinf(fit.covariance).all() and fit.sigma_vu == (math.inf, math.inf)


# --------------------------------------------------------------------------- coverage


#: A fixed seeded subset of the docs' coverage table (its first 50 seeds), on
#: the families whose target the full run meets: plain, then the rendered
#: terminator with its profile.
COVERAGE_SEEDS = range(200, 250)
COVERAGE_FAMILIES = ["sphere_limb", "crater_rim", "outliers", "heavy_noise",
                     "sphere_terminator + profile"]


@pytest.fixture(scope="module")
def coverage_rows():
    log = logging.getLogger("dtalign")
    level = log.level
    log.setLevel(logging.ERROR)
    try:
        rows = cov.evaluate(cov.plain_fit, COVERAGE_FAMILIES[:-1], COVERAGE_SEEDS)
        rows += cov.evaluate(cov.profile_fit, ["sphere_terminator"], COVERAGE_SEEDS)
    finally:
        log.setLevel(level)
    return rows


@pytest.mark.parametrize("index", range(len(COVERAGE_FAMILIES)), ids=COVERAGE_FAMILIES)
def test_the_reported_ellipses_cover_the_truth(coverage_rows, index) -> None:
    row = coverage_rows[index]
    assert row.flagged <= 0.5, row
    c68, c95, _ = row.coverage["pipeline"]
    assert 0.60 <= c68 <= 0.78, row
    assert 0.90 <= c95 <= 0.98, row
    # the M-estimator's scaled reading, on the same fits, does not
    s68, s95, _ = row.coverage["scaled"]
    assert not (0.60 <= s68 <= 0.78 and 0.90 <= s95 <= 0.98), row


def test_a_rotation_fit_gets_a_rotation_row(nav, nav_products) -> None:
    # the limb and the terminator together: a rotation the geometry observes
    limb, term = nav.polylines[0], nav.polylines[1]
    verts = np.vstack([limb.vertices_vu, term.vertices_vu])
    normals = np.vstack([limb.normals_vu, term.normals_vu])
    sigmas = np.concatenate([limb.sigmas, term.sigmas])
    fit = fit_polyline_products(nav_products, verts, normals, sigmas, search_window_vu=(12, 12),
                                fit_rotation=True, pivot_vu=nav.pivot_vu,
                                pivot_distance_px=nav.pivot_distance_px)
    assert fit.covariance.shape == (3, 3) and fit.evidence.jacobian.shape == (len(verts), 3)
    # the columns as documented: 0.25 px central differences of the DT along
    # v and u, and the rotation's through each vertex's lever arm (the chain
    # rule: d/dtheta moves a vertex along perp(p - pivot))
    from dtalign.api.sampling import sample_dt_bilinear

    pts = fit.evidence.points_vu
    jac = fit.evidence.jacobian

    def diff(step: tuple[float, float]) -> np.ndarray:
        return (sample_dt_bilinear(nav_products.edge_dt, pts + step)
                - sample_dt_bilinear(nav_products.edge_dt, pts - np.asarray(step))) / 0.5

    np.testing.assert_allclose(jac[:, 0], diff((0.25, 0.0)), atol=1e-12)
    np.testing.assert_allclose(jac[:, 1], diff((0.0, 0.25)), atol=1e-12)
    lever = pts - np.asarray(fit.lm.offset_vu) - np.asarray(fit.pivot_vu)
    np.testing.assert_allclose(jac[:, 2], -lever[:, 1] * jac[:, 0] + lever[:, 0] * jac[:, 1],
                               atol=1e-9)
    np.testing.assert_allclose(sample_dt_bilinear(nav_products.edge_dt, pts),
                               fit.evidence.residuals, atol=1e-12)
    assert math.isfinite(fit.sigma_rotation_rad) and fit.sigma_rotation_rad > 0.0
    # the points are the LM's final pose: its residuals are the DT there
    kept = ~fit.polarity_rejected
    np.testing.assert_allclose(fit.evidence.residuals[kept],
                               np.asarray(fit.lm.residuals_px)[kept], atol=1e-9)


# --------------------------------------------------------------------------- rival basins


@pytest.mark.parametrize(("seed", "agrees"), [(4, True), (36, False)])
def test_a_profile_that_lands_on_the_same_pose_from_the_rival_clears_the_ambiguity(
        seed: int, agrees: bool) -> None:
    # rendered terminators whose DT lock has a rival basin (the ramp has no
    # edge); seed 36's refinement (phase 91 deg) is 2.7 px off and lands
    # elsewhere from the rival's start: it stays ambiguous
    case = cov.FAMILIES["sphere_terminator"](seed)
    fit = cov.profile_fit(case)
    assert fit.ambiguity is not None and fit.ambiguity.ambiguous
    assert fit.profile.accepted and fit.profile.rival_agrees is agrees
    error = math.hypot(*np.subtract(fit.offset_vu, case.true_offset_vu))
    if agrees:
        assert str(fit.status) == "ok" and error < 0.2
    else:
        assert str(fit.status) == "ambiguous" and error > 1.0
    back = PolylineFit.from_dict(json.loads(json.dumps(fit.to_dict(arrays=True))))
    assert back.profile.rival_agrees is agrees and back.status == fit.status
