"""dtalign on renders it did not write (Mitsuba 3 and GalSim), from cached fixtures.

The fixtures in ``tests/data/validation/`` are renders of
``benchmarks/validate`` (``python -m benchmarks.validate.fixtures`` rewrites
them; docs/validation.rst): the renderer's own checks and a fixed subset of
seed 0's scenes. Mitsuba and GalSim are not needed here: the renders are
read from the files, fitted with dtalign and scored with the harness's own
code (:mod:`benchmarks.validate.fitting`, NumPy and dtalign only).

What holds today is asserted; the validation targets that do not hold yet are
strict xfails, so they pass loudly (XPASS fails the run) when the
pipeline's changes (items 3-5) land.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # benchmarks/ is not installed: import it from the checkout
    sys.path.insert(0, str(ROOT))

from benchmarks.validate import checks, fitting  # noqa: E402
from benchmarks.validate.fixtures import SUBSET, SUBSET_SEED1  # noqa: E402

DATA = ROOT / "tests" / "data" / "validation"


def _load(name: str) -> tuple[np.ndarray, dict]:
    with np.load(DATA / f"{name}.npz") as f:
        return f["image"].astype(np.float64), json.loads(str(f["meta"]))


def test_fixtures_small_and_complete():
    files = sorted(DATA.glob("*.npz"))
    assert len(files) == len(checks.CHECKS) + len(SUBSET) + len(SUBSET_SEED1)
    assert sum(f.stat().st_size for f in files) < 3e6
    _, meta = _load("scene_model_right_limb_0")
    for key in ("mitsuba", "galsim", "drjit"):
        assert meta[key]
    scene = meta["scene"]
    assert np.allclose(np.subtract(scene["center_vu"], scene["offset_vu"]),
                       scene["model_center_vu"])


@pytest.mark.parametrize("name", list(checks.CHECKS))
def test_renderer_check(name):
    """The renders reproduce the closed forms: centroid, flux, centre radiance, terminator."""
    image, meta = _load(f"check_{name}")
    assert meta["check"] == name
    result = checks.measure(name, image)
    assert result["ok"], result


@pytest.fixture(scope="module")
def fits():
    """Every fit of every fixture scene, by (family, edge): lists of records per method."""
    out: dict[tuple[str, str], dict[str, list[dict]]] = {}
    for family, edge, index in SUBSET:
        image, meta = _load(f"scene_{family}_{edge}_{index}")
        by_method = out.setdefault((family, edge), {m: [] for m in fitting.METHODS})
        for rec in fitting.fit_scene(meta["scene"], image):
            by_method[rec["method"]].append({**rec, "index": index})
    return out


def _errors(records):
    return np.array([r["error_px"] for r in records])


def test_nothing_raised(fits):
    raised = [(k, r["method"], r["exception"]) for k, methods in fits.items()
              for recs in methods.values() for r in recs if r.get("exception")]
    assert raised == []


def test_model_right_limb_profile(fits):
    """The validation target, met: median <= 0.003 px, p95 <= 0.01 px, all accepted and ok."""
    recs = fits[("model_right", "limb")]["profile"]
    err = _errors(recs)
    assert np.median(err) <= 0.003
    assert np.percentile(err, 95) <= 0.01
    assert all(r["accepted"] and r["status"] == "ok" for r in recs)
    assert not any(fitting.confidently_wrong(r) for r in recs)


def test_model_right_terminator_profile(fits):
    """The validation target of at least 95 % accepted and ok, met: every refinement accepted
    and ok, within 0.1 px (the median target is the strict xfail below)."""
    recs = fits[("model_right", "terminator")]["profile"]
    assert all(r["accepted"] and r["status"] == "ok" for r in recs)
    assert _errors(recs).max() <= 0.1


def test_limb_declared_plain_fit_covered(fits):
    """A plain limb fit declared a limb (``edge_kind="limb"``) is within its 99.9 % ellipse."""
    recs = fits[("model_right", "limb")]["plain_kind"]
    assert all(r["status"] == "ok" and r["d2"] <= fitting.CHI2_999 for r in recs)


def test_triaxial_limb_profile(fits):
    """An ellipsoid's limb and profile (dtalign.api.ellipsoid): as accurate as a sphere's, and
    closer than a sphere's profile of the mean radius on the same outline."""
    recs = fits[("triaxial", "limb")]["profile"]
    assert all(r["accepted"] and r["status"] == "ok" for r in recs)
    assert _errors(recs).max() <= 0.01
    assert (_errors(recs) < _errors(fits[("triaxial", "limb")]["sphere_profile"])).all()


def test_triaxial_terminator_profile(fits):
    """An ellipsoid's terminator and its profile, at phase under 90 deg: accepted, ok, within
    0.05 px, and closer than a sphere's profile of the mean radius."""
    recs = fits[("triaxial", "terminator")]["profile"]
    assert all(r["accepted"] and r["status"] == "ok" for r in recs)
    assert _errors(recs).max() <= 0.05
    assert (_errors(recs) < _errors(fits[("triaxial", "terminator")]["sphere_profile"])).all()


def test_plain_limb_fit_not_confidently_wrong(fits):
    """A plain limb fit given no ``edge_kind`` reads the kind off the image (a step into a
    surface that keeps brightening inward), so its floor is the limb's."""
    recs = fits[("model_right", "limb")]["plain"]
    assert not any(fitting.confidently_wrong(r) for r in recs)
    assert all(r["uncertainty_source"] == "dt_limb" for r in recs)
    assert all(r["status"] == "ok" for r in recs)


def test_plain_terminator_fit_flagged(fits):
    """A plain terminator fit given no ``edge_kind`` is read as a terminator: suspect."""
    for family in ("model_right", "night_floor"):
        recs = fits[(family, "terminator")]["plain"]
        assert all(r["reasons"] == ["terminator_without_profile"] for r in recs)


def test_lit_night_side_terminator_covered(fits):
    """A night side floored at 1 % of the albedo (phase 70 deg) moves the kink 0.56 px; an
    additive glow of 2 % (phase 80 deg) does not: the image cannot tell them apart, so both
    carry ``night_side_lit`` and a covariance that holds the floor's shift, and neither is
    confidently wrong. The model-right terminators' night sides do not read lit."""
    floor = [r for r in fits[("night_floor", "terminator")]["profile"]
             if r["index"] == 2]
    glow = fits[("night_additive", "terminator")]["profile"]
    assert len(floor) == 1 and len(glow) == 1
    for rec in floor + glow:
        assert rec["status"] == "ok" and "night_side_lit" in rec["reasons"], rec["reasons"]
        assert rec["d2"] <= fitting.CHI2_95
    assert floor[0]["error_px"] > 0.3  # the floor did move the kink: the sigma is what holds it
    assert all("night_side_lit" not in r["reasons"]
               for r in fits[("model_right", "terminator")]["profile"])


@pytest.mark.parametrize("family, edge, index", SUBSET_SEED1)
def test_weakly_measured_mismatched_terminator_flagged(family, edge, index):
    """Seed 1's PSF-mismatch and crater terminators 0: the pixels fix the pose weakly and
    leave residuals far below the Tukey scale's floor (the model's per-pixel accuracy), while
    the pose is 0.25 and 0.70 px off. Through that floor the covariance says how far a model
    error that leaves no residual moves such a pose: the fit is ``terminator_imprecise``, the
    error inside its 99.9 % ellipse (squared distances 0.15 and 6.1). At the residuals' own
    scale it read 0.046-0.06 px, ``ok``, at 29 and 150 (docs/validation.rst)."""
    image, meta = _load(f"scene_s1_{family}_{edge}_{index}")
    rec = next(r for r in fitting.fit_scene(meta["scene"], image) if r["method"] == "profile")
    assert rec["accepted"] and rec["error_px"] > 0.2
    assert rec["status"] == "suspect" and "terminator_imprecise" in rec["reasons"]
    assert rec["d2"] <= fitting.CHI2_999


@pytest.mark.xfail(strict=True, reason="issue 45 targets: model-right terminator median <= 0.02 "
                   "px with the profile; seed 0's scenes read more")
def test_model_right_terminator_median(fits):
    assert np.median(_errors(fits[("model_right", "terminator")]["profile"])) <= 0.02


def test_psf_mismatch_limb_profile(fits):
    """The PSF-mismatch validation target, met on these scenes (the NAC-like obscured Airy with
    jitter, anisotropic jitter, a smear; the PSF estimated): median <= 0.02 px and none
    confidently wrong."""
    recs = fits[("psf_mismatch", "limb")]["profile"]
    assert np.median(_errors(recs)) <= 0.02
    assert all(r["status"] == "ok" for r in recs)
    assert not any(fitting.confidently_wrong(r) for r in recs)


@pytest.mark.parametrize("family", ["law_mismatch", "craters", "capped_limb", "albedo_texture"])
def test_mismatched_limb_not_confidently_wrong(fits, family):
    """A Minnaert surface fitted as Lambert, craters and relief, a capped brightening declared
    Minnaert, an albedo map (its vertices' own gains spread: ``gain_scatter``): the profile fit
    leaves residuals its model does not explain, and says so."""
    recs = fits[(family, "limb")]["profile"]
    assert not any(fitting.confidently_wrong(r) for r in recs)
    assert all("profile_misfit" in r["reasons"] for r in recs)


def test_model_right_profile_fits_pass_the_residual_test(fits):
    """What the profile's model holds leaves no residual it flags."""
    for key in (("model_right", "limb"), ("model_right", "terminator"), ("triaxial", "limb"),
                ("psf_mismatch", "limb")):
        assert all("profile_misfit" not in r["reasons"] for r in fits[key]["profile"]), key
