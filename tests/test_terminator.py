"""The pipeline knows a terminator, and never reports a wrong one as ``ok``.

The target test fits a fixed seeded subset of the scenes of
``benchmarks/terminator_error.py`` (the same generator: Lambert, 300 x 300
at 8x oversampling, diameter 100-240 px, phase 35-150 deg, any light
direction, noise-free and noisy alternately, window (8, 8)).
"""

from __future__ import annotations

import dataclasses
import json
import logging

import numpy as np
import pytest

from dtalign import EdgeProfile, FitOptions, fit_polyline, sphere_edge_profile
from dtalign.api.profiles import EDGE_KINDS
from dtalign.pipeline import PolylineFit, prepare_image
from dtalign.pipeline.batch import fit_images, fit_many
from dtalign.pipeline.status import TERMINATOR_SIGMA_LIMIT_PX, FitReason
from dtalign.scenes import render_sphere

WINDOW = (8, 8)


def _draws(rng):
    # benchmarks/terminator_error.py's scene(), draw for draw
    diameter = rng.uniform(100.0, 240.0)
    phase = rng.uniform(35.0, 150.0)
    ill = rng.uniform(0.0, 360.0)
    offset = rng.uniform(-0.5, 0.5, 2) + rng.integers(-2, 3, 2)
    centre = np.array((300, 300)) / 2.0 + rng.uniform(-0.5, 0.5, 2)
    return diameter, phase, ill, offset, centre


def _scene(rng, noisy, seed):
    diameter, phase, ill, offset, centre = _draws(rng)
    noise = dict(poisson_gain=20.0, read_noise_dn=1.0) if noisy else {}
    return render_sphere(shape=(300, 300), center_vu=tuple(centre), radius_px=diameter / 2.0,
                         phase_deg=phase, illumination_deg=ill, offset_vu=tuple(offset),
                         albedo_dn=200.0, background_dn=10.0, seed=seed, **noise)


def _profile(sc):
    T = sc.terminator
    return sphere_edge_profile(T.vertices_vu, center_vu=sc.model_center_vu,
                               radius_px=sc.radius_px, phase_deg=sc.phase_deg,
                               illumination_deg=sc.illumination_deg, edge="terminator",
                               psf_sigma_px=0.0)


def _err(fit, sc):
    return float(np.hypot(*(np.asarray(fit.offset_vu) - sc.true_offset_vu)))


@pytest.fixture(scope="module")
def one():
    # phase 55 deg: the plain fit is 'ok' without a declared kind while pixels off
    return render_sphere(shape=(300, 300), center_vu=(150.3, 149.7), radius_px=80.0,
                         phase_deg=55.0, illumination_deg=80.0, offset_vu=(0.37, -1.21),
                         albedo_dn=200.0, background_dn=10.0)


def test_edge_kind_is_an_option_checked_and_taken_from_the_profile(one):
    T = one.terminator
    assert FitOptions().edge_kind is None
    with pytest.raises(ValueError, match="edge_kind"):
        fit_polyline(one.image, T.vertices_vu, T.normals_vu, T.sigmas, search_window_vu=WINDOW,
                     edge_kind="rim")
    prof = _profile(one)
    with pytest.raises(ValueError, match=r"edge_kind 'limb'.*edge_profile.edge 'terminator'"):
        fit_polyline(one.image, T.vertices_vu, T.normals_vu, T.sigmas, search_window_vu=WINDOW,
                     edge_profile=prof, edge_kind="limb")
    fit = fit_polyline(one.image, T.vertices_vu, T.normals_vu, T.sigmas, search_window_vu=WINDOW,
                       edge_profile=prof)
    assert fit.edge_kind == "terminator"
    assert FitReason.TERMINATOR_WITHOUT_PROFILE not in fit.reasons
    same = fit_polyline(one.image, T.vertices_vu, T.normals_vu, T.sigmas,
                        search_window_vu=WINDOW, edge_profile=prof, edge_kind="terminator")
    assert same.offset_vu == fit.offset_vu
    back = PolylineFit.from_dict(json.loads(json.dumps(fit.to_dict(arrays=True))))
    assert back.edge_kind == "terminator" and back.to_dict(arrays=True)["edge_kind"] == "terminator"
    assert back.profile is not None and back.profile.start_offset_vu == fit.profile.start_offset_vu


def test_a_terminator_without_a_profile_is_never_a_silent_ok(one, caplog):
    T = one.terminator
    plain = fit_polyline(one.image, T.vertices_vu, T.normals_vu, T.sigmas,
                         search_window_vu=WINDOW)
    # undeclared, the ramp along the normals says terminator: flagged all the same
    assert plain.edge_kind is None and plain.inferred_edge_kind == "terminator"
    assert FitReason.TERMINATOR_WITHOUT_PROFILE in plain.reasons
    assert plain.status == "suspect" and _err(plain, one) > 1.0
    with caplog.at_level(logging.WARNING, logger="dtalign"):
        fit = fit_polyline(one.image, T.vertices_vu, T.normals_vu, T.sigmas,
                           search_window_vu=WINDOW, edge_kind="terminator")
    assert fit.offset_vu == plain.offset_vu  # declaring the kind changes only the verdict
    assert FitReason.TERMINATOR_WITHOUT_PROFILE in fit.reasons
    assert fit.status == "suspect"
    assert "terminator without a profile" in fit.status_message
    assert "terminator without a profile" in caplog.text
    # a limb, a ring or another edge declared without a profile is not suspect for it:
    # a declared kind is taken over the one the image shows
    for kind in ("limb", "ring", "other"):
        other = dataclasses.replace(plain, edge_kind=kind)
        assert other.reasons == ()


def test_the_batch_takes_each_polylines_kind(one):
    T = one.terminator

    @dataclasses.dataclass
    class Poly:
        vertices_vu: np.ndarray
        normals_vu: np.ndarray
        sigmas: np.ndarray
        edge_kind: str | None = None
        edge_profile: EdgeProfile | None = None

    products = prepare_image(one.image)
    polys = [Poly(T.vertices_vu, T.normals_vu, T.sigmas),
             Poly(T.vertices_vu, T.normals_vu, T.sigmas, edge_kind="terminator"),
             Poly(T.vertices_vu, T.normals_vu, T.sigmas, edge_profile=_profile(one)),
             Poly(T.vertices_vu, T.normals_vu, T.sigmas, edge_kind="limb",
                  edge_profile=_profile(one))]
    fits = fit_many(products, polys, search_window_vu=WINDOW, workers=1, errors="collect")
    assert [getattr(f, "edge_kind", None) for f in fits[:3]] == [None, "terminator", "terminator"]
    assert FitReason.TERMINATOR_WITHOUT_PROFILE in fits[1].reasons
    assert FitReason.TERMINATOR_WITHOUT_PROFILE not in fits[2].reasons
    assert isinstance(fits[3], ValueError) and "conflicts" in str(fits[3])
    # the options' kind is every polyline's that declares none
    declared = fit_many(products, polys[:2], search_window_vu=WINDOW, workers=1,
                        edge_kind="terminator")
    assert [f.edge_kind for f in declared] == ["terminator", "terminator"]
    imaged = fit_images([(one.image, None, polys[:3])], search_window_vu=WINDOW, workers=1,
                        executor="thread")
    assert [f.edge_kind for f in imaged[0]] == [None, "terminator", "terminator"]


def test_cli_edge_kind(tmp_path, capsys):
    from dtalign.cli import build_parser, main
    from dtalign.io import save_polyline_csv

    fit_parser = next(a for a in build_parser()._subparsers._group_actions[0].choices.values()
                      if any(o.dest == "edge_kind" for o in a._actions))
    action = next(o for o in fit_parser._actions if o.dest == "edge_kind")
    assert tuple(action.choices) == EDGE_KINDS
    sc = _scene(np.random.default_rng(2028), False, 2028000)
    np.save(tmp_path / "s.npy", sc.image)
    save_polyline_csv(tmp_path / "s.csv", sc.terminator)
    main(["fit", str(tmp_path / "s.npy"), str(tmp_path / "s.csv"), "--window", "8",
          "--edge-kind", "terminator", "--json"])
    d = json.loads(capsys.readouterr().out)
    assert d["edge_kind"] == "terminator" and "terminator_without_profile" in d["reasons"]
    v, u = sc.model_center_vu
    main(["fit", str(tmp_path / "s.npy"), str(tmp_path / "s.csv"), "--window", "8",
          "--sphere", f"{v},{u},{sc.radius_px},{sc.phase_deg},{sc.illumination_deg}",
          "--edge", "terminator", "--psf-sigma", "0", "--json"])
    d = json.loads(capsys.readouterr().out)
    assert d["edge_kind"] == "terminator" and d["profile"]["accepted"]


#: The fixed subset: the first scenes of the benchmark's seed 2028 (its table
#: in docs/profiles.rst holds all 48).
SUBSET_SEED = 2028
SUBSET_SCENES = 16


def test_terminator_target_on_a_seeded_subset():
    rng = np.random.default_rng(SUBSET_SEED)
    plain_err, prof_err = [], []
    for i in range(SUBSET_SCENES):
        sc = _scene(rng, i % 2 == 1, SUBSET_SEED * 1000 + i)
        T = sc.terminator
        plain = fit_polyline(sc.image, T.vertices_vu, T.normals_vu, T.sigmas,
                             search_window_vu=WINDOW, edge_kind="terminator")
        fit = fit_polyline(sc.image, T.vertices_vu, T.normals_vu, T.sigmas,
                           search_window_vu=WINDOW, edge_profile=_profile(sc))
        # no confidently wrong terminator, with or without a profile
        assert not (_err(plain, sc) > 1.0 and plain.status == "ok"), i
        assert not (_err(fit, sc) > 1.0 and fit.status == "ok"), i
        plain_err.append(_err(plain, sc))
        prof_err.append(_err(fit, sc))
    # the target with the profile; the plain fit is pixels off (what the reason says)
    assert np.median(prof_err) <= 0.2
    assert np.percentile(prof_err, 90) <= 0.5
    assert np.median(plain_err) > 2.0


def test_campaign_records_the_edge_kind(tmp_path, one):
    from dtalign.archive import fit_item, read_manifest
    from dtalign.archive.store import RESULT_COLUMNS
    from dtalign.io import save_polyline_csv

    assert "edge_kind" in [name for name, _, _ in RESULT_COLUMNS]
    np.save(tmp_path / "s.npy", one.image)
    save_polyline_csv(tmp_path / "s.csv", one.terminator)
    sphere = {"center_vu": list(one.model_center_vu), "radius_px": one.radius_px,
              "phase_deg": one.phase_deg, "illumination_deg": one.illumination_deg,
              "edge": "terminator", "psf_sigma_px": 0.0}
    (tmp_path / "m.jsonl").write_text(
        json.dumps({"id": "plain", "image": "s.npy", "polylines": ["s.csv"], "window": 8,
                    "options": {"edge_kind": "terminator"}}) + "\n"
        + json.dumps({"id": "sphere", "image": "s.npy", "polylines": ["s.csv"], "window": 8,
                      "spheres": [sphere]}) + "\n"
        + json.dumps({"id": "none", "image": "s.npy", "polylines": ["s.csv"], "window": 8})
        + "\n")
    plain, sphere_row, none = (fit_item(it)["results"][0]
                               for it in read_manifest(tmp_path / "m.jsonl"))
    assert plain["edge_kind"] == "terminator" and plain["status"] == "suspect"
    assert "terminator_without_profile" in plain["reasons"]
    assert sphere_row["edge_kind"] == "terminator" and sphere_row["profile_accepted"] is True
    assert none["edge_kind"] is None


def test_a_barely_measured_terminator_is_not_ok():
    # scene 33 of the benchmark's seed 2028 (noisy, phase 91 deg): the terminator is
    # nearly straight, the refinement 2.4 px off along it, with a one-sigma of 1.56 px
    rng = np.random.default_rng(SUBSET_SEED)
    for _ in range(33):
        _draws(rng)
    sc = _scene(rng, True, SUBSET_SEED * 1000 + 33)
    T = sc.terminator
    fit = fit_polyline(sc.image, T.vertices_vu, T.normals_vu, T.sigmas, search_window_vu=WINDOW,
                       edge_profile=_profile(sc))
    assert fit.profile.accepted and _err(fit, sc) > 1.0
    assert FitReason.TERMINATOR_IMPRECISE in fit.reasons and fit.status != "ok"
    assert "terminator imprecise" in fit.status_message
    # the reason is a terminator's: the same refinement on a polyline of another kind has none
    assert FitReason.TERMINATOR_IMPRECISE not in dataclasses.replace(fit, edge_kind=None).reasons


#: Terminators of the coverage harness ``ok`` and more than 1 px off under the
#: old limit of two sigmas (0.5 px), along nearly straight terminators: seed
#: 245 (phase 86 deg), 1.25 px off with a one-sigma of 0.35 px, and seed 650
#: (phase 83 deg, among the seeds drawn after the limit was set), 1.08 px
#: off with 0.36 px.
BARELY_MEASURED_SEEDS = (245, 650)


@pytest.mark.parametrize("seed", BARELY_MEASURED_SEEDS)
def test_a_terminator_within_three_sigmas_of_a_pixel_is_the_limit(seed):
    # ok promises the error within 1 px: at the limit, 1 px is three one-sigmas
    assert TERMINATOR_SIGMA_LIMIT_PX == pytest.approx(1.0 / 3.0)
    from dtalign.benchmarking import coverage as cov

    log = logging.getLogger("dtalign")
    level = log.level
    log.setLevel(logging.ERROR)
    try:
        case = cov.FAMILIES["sphere_terminator"](seed)
        fit = cov.profile_fit(case)
    finally:
        log.setLevel(level)
    err = float(np.hypot(*np.subtract(fit.offset_vu, case.true_offset_vu)))
    sigma = float(np.sqrt(np.linalg.eigvalsh(np.asarray(fit.profile.covariance)).max()))
    assert fit.profile.accepted and err > 1.0 and TERMINATOR_SIGMA_LIMIT_PX < sigma < 0.5
    assert FitReason.TERMINATOR_IMPRECISE in fit.reasons and fit.status == "suspect"


#: Rendered terminators of the coverage harness (radius 50-120 px, phase
#: 35-150 deg, the PSF's sigma 0-1.5 px left to be estimated, noisy): the
#: fits that were ``ok`` and more than 1 px off before the refinement
#: stopped fitting a background slope, recentred its strips on the kink
#: and fitted the sigma on every vertex (seeds 114 of the calibration set
#: 0-199, and 282, 291, 337, 395 of the held-out 200-399), two that an
#: intermediate version of the fix put 1.2 px off (0, 93), and three that
#: were right already (7, 205).
HARNESS_SEEDS = (0, 7, 93, 114, 205, 282, 291, 337, 395)


def test_no_confidently_wrong_terminator_with_an_estimated_psf():
    from dtalign.benchmarking import coverage as cov

    log = logging.getLogger("dtalign")
    level = log.level
    log.setLevel(logging.ERROR)
    try:
        errors = {}
        for seed in HARNESS_SEEDS:
            case = cov.FAMILIES["sphere_terminator"](seed)
            fit = cov.profile_fit(case)
            err = float(np.hypot(*np.subtract(fit.offset_vu, case.true_offset_vu)))
            assert not (err > 1.0 and fit.status == "ok"), (seed, err)
            if fit.profile.accepted:
                errors[seed] = err
                # a terminator's lit side is a ramp: no background slope is fitted
                assert fit.profile.background_slope == 0.0
                assert fit.profile.psf_estimated
    finally:
        log.setLevel(level)
    # the refinement lands on the kink: none of them is more than 0.6 px off
    assert len(errors) == len(HARNESS_SEEDS)
    assert max(errors.values()) < 0.6, errors


#: The harness's ``ok`` terminators farthest outside their ellipses while a
#: free sigma that stopped at 0 was held there (docs/profiles.rst, "A blur
#: trapped at 0"): 0.74, 0.76 and 0.87 px off, squared distances 24-33,
#: where the true PSF was 1.36, 1.06 and 1.45 px.
TRAPPED_SEEDS = (139, 344, 404)


def test_a_blur_trapped_at_zero_is_fitted_again():
    from dtalign.benchmarking import coverage as cov

    log = logging.getLogger("dtalign")
    level = log.level
    log.setLevel(logging.ERROR)
    try:
        for seed in TRAPPED_SEEDS:
            case = cov.FAMILIES["sphere_terminator"](seed)
            fit = cov.profile_fit(case)
            err = np.subtract(fit.offset_vu, case.true_offset_vu)
            # 344 is barely measured along its nearly straight terminator (one-sigma
            # 0.38 px, above the limit of a third of a pixel): suspect for that alone
            assert set(fit.reasons) <= {FitReason.TERMINATOR_IMPRECISE}, (seed, fit.reasons)
            assert (FitReason.TERMINATOR_IMPRECISE in fit.reasons) == (seed == 344), seed
            assert fit.profile.accepted and fit.profile.psf_estimated, seed
            assert fit.profile.psf_sigma_px > 0.5, (seed, fit.profile.psf_sigma_px)
            d2 = float(err @ np.linalg.solve(np.asarray(fit.covariance)[:2, :2], err))
            assert d2 < cov.CHI2_2D[1], (seed, d2)  # inside its 95 % ellipse now
    finally:
        log.setLevel(level)


@pytest.mark.parametrize(("phase", "light"), [(140.0, 200.0), (150.0, 100.0)])
def test_a_scan_started_terminator_is_not_failed_for_its_seed_at_the_window_edge(phase, light):
    """The DT lock on a high-phase terminator's ramp sits on the window's edge; the profile's
    own scan finds the kink from there, accurately: the status follows that, not the seed."""
    sc = render_sphere(shape=(240, 240), center_vu=(120.3, 119.6), radius_px=70.0,
                       phase_deg=phase, illumination_deg=light, offset_vu=(0.4, -0.7),
                       read_noise_dn=1.0, seed=1)
    T = sc.terminator
    prof = sphere_edge_profile(T.vertices_vu, center_vu=sc.model_center_vu, radius_px=70.0,
                               phase_deg=phase, illumination_deg=light, edge="terminator")
    fit = fit_polyline(sc.image, T.vertices_vu, T.normals_vu, T.sigmas, search_window_vu=(4, 4),
                       edge_profile=prof)
    assert fit.at_window_edge and fit.profile.accepted and fit.profile.start_offset_vu is not None
    assert FitReason.AT_WINDOW_EDGE not in fit.reasons and fit.status == "ok"
    assert _err(fit, sc) < 0.05
    # the same seed without the profile: the pose is the window-edge DT lock's, failed
    plain = fit_polyline(sc.image, T.vertices_vu, T.normals_vu, T.sigmas,
                         search_window_vu=(4, 4), edge_kind="terminator")
    assert FitReason.AT_WINDOW_EDGE in plain.reasons and plain.status == "failed"
    # a pose within WINDOW_EDGE_CLEARANCE_PX of the window's edge keeps the reason
    near = dataclasses.replace(fit, offset_vu=(3.5, fit.offset_vu[1]))
    assert FitReason.AT_WINDOW_EDGE in near.reasons


@pytest.mark.xfail(strict=True, reason="issue 45: the blur's curvature shift (kap sigma^2 / 2, a "
                   "step's) does not hold for a kink in a smooth shading (docs/profiles.rst, "
                   "'A blurred kink')")
def test_a_blurred_terminator_with_its_psf_known_lies_on_its_kink():
    """A noise-free Lambert terminator (radius 60 px, phase 68 deg) blurred by a Gaussian of
    2 px, the profile given that PSF: the model is the render's but for the blur's curvature
    term, and the fit reads 0.19 px off (0.035 px at 1 px of blur; the limb of the same
    sphere 0.004 px)."""
    sc = render_sphere(shape=(200, 200), center_vu=(100.3, 99.6), radius_px=60.0,
                       phase_deg=68.0, illumination_deg=207.7, offset_vu=(-1.2, 0.7),
                       albedo_dn=200.0, background_dn=10.0, psf_sigma_px=2.0, oversample=16)
    T = sc.terminator
    prof = sphere_edge_profile(T.vertices_vu, center_vu=sc.model_center_vu,
                               radius_px=sc.radius_px, phase_deg=sc.phase_deg,
                               illumination_deg=sc.illumination_deg, edge="terminator",
                               psf_sigma_px=2.0)
    fit = fit_polyline(sc.image, T.vertices_vu, T.normals_vu, T.sigmas, search_window_vu=WINDOW,
                       edge_profile=prof)
    assert fit.profile.accepted
    assert _err(fit, sc) < 0.02
