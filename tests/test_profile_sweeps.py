"""Property-based sweeps of the profile refinement: drawn scenes, not one fixed scene.

The profile fit once raised ``LinAlgError`` on 126 of 273 limb scenes of an
independent simulator: a vertex whose normal lay exactly on an image axis
gave a pixel a projected width of 0, and ``box_model`` divided by it. It
came and went with the vertex count (an odd count puts a limb vertex on the
sub-solar point, whose normal is then on an axis when the light is), and
the tests had only ever used 200 vertices. These sweeps draw the scene
instead of fixing it:

* the light direction over 0-360 deg, its multiples of 45 deg drawn
  explicitly often (normals exactly on the axes and diagonals);
* vertex counts 3-1000 (a list of awkward ones drawn often: odd counts,
  counts of the form 4k + 2, the reproducer's 163);
* phase 0-180 deg, the frame 160-240 px, the radius what the frame holds,
  the planted offset up to 2.5 px with its sub-pixel part drawn (0 and
  1/2 explicitly);
* the PSF: none, a Gaussian given to the fit, one estimated, a core with
  wings (the renderer's 20 % in a Gaussian 4 times wider) with the core
  given or estimated;
* noise from none to heavy (a few electrons per DN), the albedo and sky;
* limbs and terminators, every reflectance law of
  :func:`~dtalign.sphere_edge_profile` (Minnaert's exponent drawn), the
  shape basis on or off.

Properties, for :func:`~dtalign.fit_polyline` and for
:func:`~dtalign.pipeline.batch.fit_many` on the same scene:

* every call returns a fit: nothing raises on well-formed input;
* a rejected refinement says why (a non-empty ``reason``, the reason
  ``profile_rejected``, the DT-LM pose kept);
* a fit whose refinement is accepted and whose status is ``ok`` lies near
  the planted offset: within :func:`bound_px` (its justification there).

The README suite runs :data:`EXAMPLES` examples from a fixed seed (the same
draws on every run and in every environment). ``nox -s sweeps`` (or ``DTALIGN_SWEEP_EXAMPLES=3000``)
runs thousands; ``DTALIGN_SWEEP_SEED=n`` draws from seed ``n`` instead,
``DTALIGN_SWEEP_SHRINK=0`` reports a failing draw unshrunk;
``DTALIGN_SWEEP_LOG=path`` appends one JSON line per example (the draw,
each fit's status, error and sigma), and ``DTALIGN_SWEEP_COLLECT=1`` with
it records a violated property in that line instead of failing, so a long
run measures the whole distribution (never set it in CI).

Failures the sweeps found are fixed regressions below, not ``@example``
rows of the sweep: a sweep run against an old tree then counts how many
draws it takes to find a bug on its own.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import time
import traceback
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, given, seed, settings
from hypothesis import strategies as st

from dtalign import fit_polyline, sphere_edge_profile
from dtalign.pipeline import prepare_image
from dtalign.pipeline.batch import fit_many
from dtalign.scenes import render_sphere

#: Draws of the README suite's run: about 40 s on two shared cores (the file,
#: after compilation). On the tree before the width floor, seed 0 raises the
#: ``LinAlgError`` at draw 58 (a 3-vertex limb, the light at 90 deg).
EXAMPLES = int(os.environ.get("DTALIGN_SWEEP_EXAMPLES", "100"))
_SEED = os.environ.get("DTALIGN_SWEEP_SEED")
_LOG = os.environ.get("DTALIGN_SWEEP_LOG")
_COLLECT = bool(_LOG) and os.environ.get("DTALIGN_SWEEP_COLLECT") == "1"

#: ``DTALIGN_SWEEP_SHRINK=0``: report the first failing draw as drawn (counting
#: the draws to a failure, or a long run's first failure without the wait).
_PHASES = (tuple(Phase) if os.environ.get("DTALIGN_SWEEP_SHRINK", "1") != "0"
           else (Phase.explicit, Phase.generate))

SWEEP = settings(max_examples=EXAMPLES, deadline=None, database=None,
                 phases=_PHASES,
                 suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
#: The draws come from a fixed seed (0 unless ``DTALIGN_SWEEP_SEED``), not from
#: ``derandomize``: that one seeds from a digest of the test, which differed
#: between two environments of the same Hypothesis version (the suite drew
#: other scenes in CI's fresh virtual environment than in a developer's).
_seeded = seed(int(_SEED) if _SEED is not None else 0)

#: The search windows of the project's profile tests: a limb's DT lock is
#: within a pixel of the truth, a terminator's several pixels off it.
WINDOWS = {"limb": (6, 6), "terminator": (8, 8)}
PSFS = ("none", "given", "estimated", "wings-given", "wings-estimated")
NOISES = ("none", "light", "heavy")
LAWS = ("lambert", "minnaert", "lommel-seeliger")
#: Counts drawn often: odd (a limb vertex on the sub-solar point), 4k + 2
#: (vertices at +-45 deg from it), tiny, the reproducer's 163 and its subsets'.
AWKWARD_COUNTS = (3, 4, 5, 6, 7, 9, 10, 15, 40, 41, 60, 63, 100, 101, 162, 163, 199, 201, 398,
                  401, 999, 1000)


@dataclasses.dataclass(frozen=True)
class Case:
    """One drawn scene and the polyline fitted in it."""

    family: str  # "limb" or "terminator"
    shape: tuple[int, int]
    centre_shift_vu: tuple[float, float]  # the sphere's centre from the frame's
    radius_px: float
    phase_deg: float
    illumination_deg: float
    n_vertices: int
    offset_vu: tuple[float, float]
    law: str
    minnaert_k: float | None
    psf: str
    psf_sigma_px: float
    noise: str
    albedo_dn: float
    background_dn: float
    fit_law: bool
    noise_seed: int


def _subpixel(draw: Any) -> float:
    whole = draw(st.integers(-2, 2))
    frac = draw(st.one_of(st.sampled_from([0.0, 0.5, -0.5, 0.25]),
                          st.floats(-0.5, 0.5, allow_nan=False)))
    return float(whole + frac)


@st.composite
def cases(draw: Any) -> Case:
    shape = (draw(st.integers(160, 240)), draw(st.integers(160, 240)))
    # the polyline and the search window stay inside the frame
    radius = draw(st.floats(20.0, min(shape) / 2.0 - 16.0, allow_nan=False))
    phase = draw(st.one_of(st.sampled_from([0.0, 45.0, 90.0, 135.0]),
                           st.floats(0.0, 179.9, allow_nan=False)))
    family = draw(st.sampled_from(["limb", "terminator"])) if phase > 0.0 else "limb"
    # a third each: on an axis, on a diagonal, anywhere
    ill = draw(st.one_of(st.sampled_from([0.0, 90.0, 180.0, 270.0]),
                         st.sampled_from([45.0, 135.0, 225.0, 315.0]),
                         st.floats(0.0, 360.0, exclude_max=True, allow_nan=False)))
    n = draw(st.one_of(st.sampled_from(AWKWARD_COUNTS), st.integers(3, 1000)))
    law = draw(st.sampled_from(LAWS))
    k = draw(st.floats(0.5, 1.5)) if law == "minnaert" else None
    psf = draw(st.sampled_from(PSFS))
    psf_sigma = 0.0 if psf == "none" else draw(st.floats(0.3, 2.0))
    return Case(
        family=family, shape=shape,
        centre_shift_vu=(draw(st.floats(-0.5, 0.5)), draw(st.floats(-0.5, 0.5))),
        radius_px=radius, phase_deg=phase, illumination_deg=ill, n_vertices=n,
        offset_vu=(_subpixel(draw), _subpixel(draw)), law=law, minnaert_k=k, psf=psf,
        psf_sigma_px=psf_sigma, noise=draw(st.sampled_from(NOISES)),
        albedo_dn=draw(st.floats(100.0, 1500.0)), background_dn=draw(st.floats(0.0, 20.0)),
        fit_law=draw(st.booleans()), noise_seed=draw(st.integers(0, 2**31 - 1)))


def render(case: Case) -> Any:
    """The scene of ``case`` (:func:`dtalign.scenes.render_sphere`)."""
    noise: dict[str, Any] = {
        "none": {},
        "light": dict(poisson_gain=20.0, read_noise_dn=1.0),
        "heavy": dict(poisson_gain=1.0, read_noise_dn=5.0),
    }[case.noise]
    h, w = case.shape
    centre = (h / 2.0 + case.centre_shift_vu[0], w / 2.0 + case.centre_shift_vu[1])
    return render_sphere(
        shape=case.shape, center_vu=centre, radius_px=case.radius_px, phase_deg=case.phase_deg,
        illumination_deg=case.illumination_deg, offset_vu=case.offset_vu, law=case.law,
        minnaert_k=case.minnaert_k, albedo_dn=case.albedo_dn, background_dn=case.background_dn,
        psf_sigma_px=case.psf_sigma_px if case.psf != "none" else None,
        psf="core+wings" if case.psf.startswith("wings") else "gaussian",
        n_vertices=case.n_vertices, seed=case.noise_seed, **noise)


def profile_of(case: Case, sc: Any, family: str, vertices_vu: Any = None) -> Any:
    """The fit's model of ``family``'s edge: the rendered law; the PSF as the case gives it."""
    given = {"none": 0.0, "given": case.psf_sigma_px, "wings-given": case.psf_sigma_px}
    P = sc.limb if family == "limb" else sc.terminator
    return sphere_edge_profile(
        P.vertices_vu if vertices_vu is None else vertices_vu, center_vu=sc.model_center_vu,
        radius_px=sc.radius_px, phase_deg=sc.phase_deg, illumination_deg=sc.illumination_deg,
        edge=family, law=case.law, minnaert_k=case.minnaert_k,
        psf_sigma_px=given.get(case.psf), fit_law=case.fit_law)


def error_px(fit: Any, sc: Any) -> float:
    return float(np.hypot(*np.subtract(fit.offset_vu, sc.true_offset_vu)))


def sigma_max_px(fit: Any) -> float:
    """The fit's largest one-sigma of the offset (its covariance's, floors included)."""
    cov = np.asarray(fit.covariance, dtype=np.float64)[:2, :2]
    if not np.isfinite(cov).all():
        return math.inf
    return float(math.sqrt(max(np.linalg.eigvalsh(cov).max(), 0.0)))


def mahalanobis2(fit: Any, sc: Any) -> float:
    """The squared Mahalanobis distance of the error in the fit's covariance."""
    cov = np.asarray(fit.covariance, dtype=np.float64)[:2, :2]
    err = np.subtract(fit.offset_vu, sc.true_offset_vu)
    if not (np.isfinite(cov).all() and np.linalg.det(cov) > 0.0):
        return math.inf
    return float(err @ np.linalg.solve(cov, err))


#: The statistical part of :func:`bound_px`: five of the fit's largest one-sigmas.
#: For errors Gaussian in the reported covariance, the chance of a larger one is at
#: most ``exp(-25 / 2)`` = 4e-6 per fit, under 0.05 in the 10 000 fits of a
#: 3000-draw run.
SIGMAS = 5.0
#: What the covariance leaves out with the image's PSF the fit's model (none,
#: a Gaussian given or estimated): measured on 300 draws (seed 1), 0.005 px at
#: most beyond five sigmas (limbs with the PSF estimated); twice that.
MODEL_FLOOR_PX = 0.01
#: With wings (20 % of the light in a Gaussian 4 times wider, up to 8 px, than the
#: core) the covariance misses the wings' trade with the offset: a terminator is
#: fitted with the core alone, and a limb's wings wider than its +-3.5 px strips
#: are a ramp that trades with the background's slope. The same draws: up to
#: 0.25 px (limbs) and 0.40 px (terminators) beyond five sigmas, 0.90 and 0.94
#: px in all. No multiple of sigma holds them; what holds is what ``ok``
#: promises (``dtalign.pipeline.status``): never more than 1 px off.
OK_PROMISE_PX = 1.0


#: Bodies smaller than this radius (px) are a corner where the covariance does
#: not yet hold (:func:`open_corner`).
SMALL_BODY_PX = 25.0


def open_corner(case: Case) -> str | None:
    """The corner of the draws, if any, where the reported covariance is known
    not to cover the error yet, so that only what ``ok`` promises is held.

    Measured, not assumed: in the two 1000-draw runs after the strips were
    capped (seeds 3 and 4, 5701 fits; docs/profiles.rst, "Property sweeps"),
    every one of the 17 accepted ``ok`` fits beyond five sigmas lay in one of
    these (heavy noise: small limbs with the PSF estimated 0.33-0.70 px off at
    0.055 px, terminators; the PSF's wings; small bodies, 0.09 px off at 0.009
    px), or had 3-4 vertices, which the refinement now refuses
    (``MIN_VERTICES``). They are open work (a blur or a noise the
    covariance does not carry, to be flagged or carried); the draws found in
    them are :data:`FOUND`'s strict xfails.
    """
    if case.psf.startswith("wings"):
        return "a PSF with wings"
    if case.noise == "heavy":
        return "heavy noise"
    if case.radius_px < SMALL_BODY_PX:
        return "a small body"
    if case.family == "limb" and case.law == "minnaert" and (case.minnaert_k or 1.0) < 1.0:
        return "a Minnaert limb with k < 1"
    return None


def bound_px(fit: Any, case: Case, corners: bool = True) -> float:
    """How far an accepted ``ok`` fit may lie from the planted offset, px: five
    sigmas and the model floor, or what ``ok`` promises with a PSF's wings
    and, unless ``corners`` is False (the found draws' xfails, which hold the
    open corners to the bound they are to meet), in an :func:`open_corner`."""
    if case.psf.startswith("wings") or (corners and open_corner(case) is not None):
        return OK_PROMISE_PX
    return min(OK_PROMISE_PX, SIGMAS * sigma_max_px(fit) + MODEL_FLOOR_PX)


def check_fit(fit: Any, sc: Any, case: Case, family: str, corners: bool = True
              ) -> dict[str, Any]:
    """The properties of one fit; what was measured, for the log (collecting, a
    violated property is recorded in it as ``violation`` instead of raised);
    ``corners`` as :func:`bound_px`."""
    rec: dict[str, Any] = {"family": family, "status": str(fit.status),
                           "reasons": [str(r) for r in fit.reasons],
                           "error_px": error_px(fit, sc)}
    ref = fit.profile
    if ref is None:
        rec["accepted"] = None
    else:
        rec.update(accepted=bool(ref.accepted), reason=ref.reason, sigma_px=sigma_max_px(fit),
                   psf_estimated=bool(ref.psf_estimated), d2=mahalanobis2(fit, sc))
        if ref.accepted and rec["status"] == "ok":
            rec["bound_px"] = bound_px(fit, case, corners)
            rec["corner"] = open_corner(case)
    try:
        if ref is None:  # nothing locked, nothing refined: said by the status
            assert fit.lm.degenerate and rec["status"] == "failed", "a refinement is lost"
        elif not ref.accepted:
            assert isinstance(ref.reason, str) and ref.reason.strip(), "rejected without a reason"
            # the pose is the DT-LM's (less a second edge's pull), never ok
            assert "profile_rejected" in rec["reasons"] and rec["status"] != "ok"
        elif rec["status"] == "ok":
            assert rec["error_px"] <= rec["bound_px"], (
                f"accepted ok {family} fit {rec['error_px']:.3f} px off, sigma "
                f"{rec['sigma_px']:.3f} px, bound {rec['bound_px']:.3f} px")
    except AssertionError as exc:
        if not _COLLECT:
            raise
        rec["violation"] = str(exc)
    return rec


def _finite(x: Any) -> Any:
    if isinstance(x, float) and not math.isfinite(x):
        return str(x)
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_finite(v) for v in x]
    return x


_COUNTER = [0]


def run_case(case: Case) -> list[dict[str, Any]]:
    """Render ``case``, fit its polyline alone and, in one batch, every polyline of
    the scene; check each fit. Returns the fits' records."""
    sc = render(case)
    P = sc.limb if case.family == "limb" else sc.terminator
    prof = profile_of(case, sc, case.family)
    window = WINDOWS[case.family]
    one = fit_polyline(sc.image, P.vertices_vu, P.normals_vu, P.sigmas, search_window_vu=window,
                       edge_profile=prof)
    records = [check_fit(one, sc, case, case.family)]
    # the batch path, the drawn polyline among the scene's others (each with its window)
    families = ["limb"] + (["terminator"] if sc.terminator is not None else [])
    products = prepare_image(sc.image)
    for family in families:
        Q = sc.limb if family == "limb" else sc.terminator
        q_prof = prof if family == case.family else profile_of(case, sc, family)
        (many,) = fit_many(products, [(Q.vertices_vu, Q.normals_vu, Q.sigmas, q_prof)],
                           search_window_vu=WINDOWS[family], workers=1)
        rec = check_fit(many, sc, case, family)
        rec["batch"] = True
        if family == case.family:
            assert tuple(many.offset_vu) == tuple(one.offset_vu), "batch and one-call fits differ"
        records.append(rec)
    return records


def _logged(case: Case) -> None:
    _COUNTER[0] += 1
    entry: dict[str, Any] = {"seq": _COUNTER[0], "case": dataclasses.asdict(case)}
    t0 = time.perf_counter()
    try:
        entry["fits"] = run_case(case)
    except Exception as exc:  # recorded, then raised (or, collecting, only recorded)
        entry["failure"] = f"{type(exc).__name__}: {exc}"
        entry["traceback"] = traceback.format_exc(limit=-4)
        if not _COLLECT:
            raise
    finally:
        entry["time_s"] = time.perf_counter() - t0
        if _LOG:
            with open(_LOG, "a", encoding="utf-8") as fh:
                fh.write(json.dumps(_finite(entry)) + "\n")


@SWEEP
@_seeded
@given(cases())
def test_profile_sweep(case: Case) -> None:
    if _LOG:
        _logged(case)
    else:
        run_case(case)


def _axis_normal_scene() -> Any:
    # the reproducer: 163 vertices put vertex 81 on the sub-solar point,
    # whose normal is then exactly (-0.0, -1.0) with the light at 90 deg
    return render_sphere(shape=(320, 320), radius_px=90.0, phase_deg=35.0,
                         illumination_deg=90.0, offset_vu=(0.37, -0.61), n_vertices=163,
                         background_dn=20.0, albedo_dn=1500.0)


#: The reproducer as a draw (its PSF none, the profile's 0; the bound's input).
AXIS_NORMAL_CASE = Case(family="limb", shape=(320, 320), centre_shift_vu=(0.0, 0.0), radius_px=90.0,
                  phase_deg=35.0, illumination_deg=90.0, n_vertices=163, offset_vu=(0.37, -0.61),
                  law="lambert", minnaert_k=None, psf="none", psf_sigma_px=0.0, noise="none",
                  albedo_dn=1500.0, background_dn=20.0, fit_law=True, noise_seed=0)

#: Subsets of the reproducer's limb: ``n`` vertices ``163 // n`` apart, vertex
#: 81 (the one on the axis) among them.
AXIS_NORMAL_SUBSETS = (40, 60, 100, 163)


@pytest.mark.parametrize("n", AXIS_NORMAL_SUBSETS)
def test_a_limb_vertex_with_an_axis_normal_is_refined(n):
    sc = _axis_normal_scene()
    L = sc.limb
    step = 163 // n
    idx = 81 + step * (np.arange(n) - n // 2)
    assert idx.min() >= 0 and idx.max() < 163 and 81 in idx
    verts, normals, sigmas = L.vertices_vu[idx], L.normals_vu[idx], L.sigmas[idx]
    prof = sphere_edge_profile(verts, center_vu=sc.model_center_vu, radius_px=90.0,
                               phase_deg=35.0, illumination_deg=90.0, edge="limb")
    # the case of the bug: a pixel's projected width |n_v| exactly 0
    assert (prof.normals_vu[:, 0] == 0.0).any()
    one = fit_polyline(sc.image, verts, normals, sigmas, search_window_vu=(6, 6),
                       edge_profile=prof)
    (many,) = fit_many(prepare_image(sc.image), [(verts, normals, sigmas, prof)],
                       search_window_vu=(6, 6), workers=1)
    for fit in (one, many):
        check_fit(fit, sc, AXIS_NORMAL_CASE, "limb")
        assert fit.profile.accepted and fit.status == "ok"


def _fit_one(case: Case, family: str) -> dict[str, Any]:
    sc = render(case)
    P = sc.limb if family == "limb" else sc.terminator
    fit = fit_polyline(sc.image, P.vertices_vu, P.normals_vu, P.sigmas,
                       search_window_vu=WINDOWS[family],
                       edge_profile=profile_of(case, sc, family))
    return check_fit(fit, sc, case, family, corners=False)


#: Confident wrong answers the long runs found on the fixed tree (seeds 2, 3 and
#: 5; the draw's number, the family whose fit failed, what it was). Those of
#: sparse polylines (3-4 vertices, whose strips reached half the vertex
#: spacing, tens of pixels, along the edge, where the pixel model's circle
#: of the vertex's curvature is off) are fixed by ``MAX_TAU_PX`` and listed
#: in :data:`FIXED`; the others, terminators whose blur the covariance does
#: not carry (wings fitted with the core alone, heavy noise, a blur estimated
#: at half the true one), stay open:
#: each fails :func:`check_fit` and is marked so (strict: a fix shows as
#: XPASS).
FOUND = {
    "ci-limb-3-vertices-heavy-noise": ("limb", Case(
        family='limb', shape=(168, 222), centre_shift_vu=(-0.171875, 0.0),
        radius_px=37.50390625, phase_deg=75.1328125, illumination_deg=0.0, n_vertices=3,
        offset_vu=(0.0, 0.0), law='lambert', minnaert_k=None, psf='none', psf_sigma_px=0.0,
        noise='heavy', albedo_dn=322.5, background_dn=4.0625, fit_law=True, noise_seed=30)),
    "967-limb-3-vertices": ("limb", Case(
        family='terminator', shape=(216, 176), centre_shift_vu=(0.0, 0.0), radius_px=20.0,
        phase_deg=135.0, illumination_deg=135.0, n_vertices=3, offset_vu=(1.5, -0.5),
        law='lambert', minnaert_k=None, psf='none', psf_sigma_px=0.0, noise='light',
        albedo_dn=675.8043838233363, background_dn=0.0, fit_law=False,
        noise_seed=2198765)),
    "9-terminator-4-vertices": ("terminator", Case(
        family='terminator', shape=(200, 239), centre_shift_vu=(-6.656381525602429e-124,
        0.4653497567954723), radius_px=84.0, phase_deg=135.0,
        illumination_deg=280.846793756531, n_vertices=4, offset_vu=(-9.617578425308307e-61,
        -0.30422321700518234), law='lambert', minnaert_k=None, psf='given',
        psf_sigma_px=1.9087307872910073, noise='none', albedo_dn=1161.640714517534,
        background_dn=5.5267489977502935, fit_law=True, noise_seed=2369646)),
    "1080-terminator-3-vertices-psf-estimated": ("terminator", Case(
        family='limb', shape=(185, 162), centre_shift_vu=(0.17546312737120207,
        0.003936242295440651), radius_px=55.06857811996664, phase_deg=45.0,
        illumination_deg=0.0, n_vertices=3, offset_vu=(2.5, 1.0), law='lommel-seeliger',
        minnaert_k=None, psf='estimated', psf_sigma_px=1.457010265873738, noise='none',
        albedo_dn=620.6666137181088, background_dn=4.878206061899989, fit_law=False,
        noise_seed=29050264)),
    "19-terminator-wings-estimated-heavy-noise": ("terminator", Case(
        family='terminator', shape=(172, 197), centre_shift_vu=(-0.5,
        -0.12668298752479984), radius_px=40.0, phase_deg=102.7662379648184,
        illumination_deg=90.0, n_vertices=405, offset_vu=(-0.5, -0.5), law='minnaert',
        minnaert_k=1.138253048520109, psf='wings-estimated',
        psf_sigma_px=1.2365086851527416, noise='heavy', albedo_dn=637.7498137394699,
        background_dn=8.275429857103449e-73, fit_law=False, noise_seed=562282)),
    "938-terminator-wings-given": ("terminator", Case(
        family='limb', shape=(210, 192), centre_shift_vu=(1.7781228460453248e-141,
        -0.08744572723883326), radius_px=38.45965469732607, phase_deg=131.34316814432347,
        illumination_deg=45.0, n_vertices=100, offset_vu=(1.5, 0.25), law='minnaert',
        minnaert_k=1.4564183065121956, psf='wings-given', psf_sigma_px=1.2731333246652121,
        noise='light', albedo_dn=100.0, background_dn=1.0429298141554299e-293,
        fit_law=True, noise_seed=672)),
    "ci93-terminator-wings-given-heavy-noise": ("terminator", Case(
        family='terminator', shape=(172, 160), centre_shift_vu=(-0.4078554138972499, 0.0),
        radius_px=26.052428729787366, phase_deg=120.059170324266,
        illumination_deg=290.45616714591864, n_vertices=398,
        offset_vu=(-1.7760136621198006, 1.362401048553832), law='minnaert',
        minnaert_k=0.9333649134894088, psf='wings-given', psf_sigma_px=1.3, noise='heavy',
        albedo_dn=180.0, background_dn=0.25439288856142556, fit_law=True, noise_seed=0)),
    "904-terminator-heavy-noise": ("terminator", Case(
        family='limb', shape=(171, 164), centre_shift_vu=(-0.3441501791092698, 0.2),
        radius_px=35.18662047916236, phase_deg=85.0, illumination_deg=2.225073858507e-311,
        n_vertices=294, offset_vu=(0.0, 0.5), law='minnaert', minnaert_k=0.5, psf='none',
        psf_sigma_px=0.0, noise='heavy', albedo_dn=409.0119530834447,
        background_dn=2.225073858507e-311, fit_law=True, noise_seed=123547)),
    # the suite's run on a fresh clone: a Minnaert limb with k < 1, whose
    # brightness diverges at the limb (mu ** (k - 1)), noise-free
    "ci-limb-minnaert-k0.5-5-vertices": ("limb", Case(
        family='limb', shape=(160, 160), centre_shift_vu=(0.0, 0.0), radius_px=32.0,
        phase_deg=90.0, illumination_deg=0.0, n_vertices=5, offset_vu=(0.0, 0.0),
        law='minnaert', minnaert_k=0.5, psf='none', psf_sigma_px=0.0, noise='none',
        albedo_dn=100.0, background_dn=0.0, fit_law=False, noise_seed=0)),
    "ci-limb-minnaert-k0.5-10-vertices": ("limb", Case(
        family='limb', shape=(160, 160), centre_shift_vu=(0.0, 0.0), radius_px=47.0,
        phase_deg=45.0, illumination_deg=0.0, n_vertices=10, offset_vu=(0.0, 0.0),
        law='minnaert', minnaert_k=0.5, psf='none', psf_sigma_px=0.0, noise='none',
        albedo_dn=100.0, background_dn=0.0, fit_law=False, noise_seed=0)),
    # the suite's run on a fresh clone: a Lommel-Seeliger crescent whose bright
    # horns, fitted with the rest, pulled the pose 0.9 px (5.1 sigma)
    "ci-terminator-lommel-seeliger-horns": ("terminator", Case(
        family='limb', shape=(160, 160), centre_shift_vu=(0.0, 0.0), radius_px=27.0,
        phase_deg=106.0, illumination_deg=0.0, n_vertices=58, offset_vu=(0.0, 0.0),
        law='lommel-seeliger', minnaert_k=None, psf='estimated', psf_sigma_px=2.0,
        noise='none', albedo_dn=100.0, background_dn=0.0, fit_law=True, noise_seed=0)),
    # seed 5 (500 draws), draw 286: a Minnaert terminator at phase 134 deg whose
    # blur is estimated at half the true one; its horns agree (0.8 sigma)
    "s5-286-terminator-minnaert-psf-estimated": ("terminator", Case(
        family='terminator', shape=(204, 211), centre_shift_vu=(-0.49497195973881136,
        -0.2769648630199854), radius_px=49.4515958467677, phase_deg=133.88582216230353,
        illumination_deg=135.0, n_vertices=145, offset_vu=(-0.75, 1.0), law='minnaert',
        minnaert_k=1.4243183568128859, psf='estimated', psf_sigma_px=1.22381839892555,
        noise='light', albedo_dn=150.0, background_dn=13.97183535118381, fit_law=False,
        noise_seed=1)),
    # seed 3 (1000 draws), draw 115
    "s3-115-terminator-3-vertices-wings-estimated": ("terminator", Case(
        family='limb', shape=(174, 174), centre_shift_vu=(0.3662719424602656,
        -6.103515625e-05), radius_px=20.0, phase_deg=45.0, illumination_deg=135.0,
        n_vertices=3, offset_vu=(0.1701053867715262, -0.8298946132284738),
        law='lommel-seeliger', minnaert_k=None, psf='wings-estimated',
        psf_sigma_px=1.9737292990631239, noise='heavy', albedo_dn=742.0818127067764,
        background_dn=0.0, fit_law=True, noise_seed=296779)),
}


#: The found draws the strip cap (``MAX_TAU_PX``) and the vertex minimum
#: (``MIN_VERTICES``) fixed: each passes :func:`check_fit` (an ``ok`` fit
#: within its bound, or not ``ok``).
FIXED = ("1080-terminator-3-vertices-psf-estimated", "9-terminator-4-vertices",
         "967-limb-3-vertices", "s3-115-terminator-3-vertices-wings-estimated",
         "ci-limb-3-vertices-heavy-noise")


#: The found draws the profile refinement's residual test flags
#: (``profile_misfit``): a Minnaert limb with k < 1 whose diverging
#: brightness the pixel model leaves as a residual shape, and a heavy-noise
#: terminator whose vertices' edges spread twice as far as its noise explains,
#: a crescent whose horns move its pose (``ProfileRefinement.horn_shift_px``),
#: and a heavy-noise Minnaert terminator with the PSF's wings estimated (1.32 px
#: off at a sigma of 0.19 px) whose vertices' own gains spread 1.7 times as
#: far as its noise explains (``ProfileRefinement.gain_scatter``).
FLAGGED = ("904-terminator-heavy-noise", "ci-limb-minnaert-k0.5-10-vertices",
           "ci-limb-minnaert-k0.5-5-vertices", "ci-terminator-lommel-seeliger-horns",
           "19-terminator-wings-estimated-heavy-noise")


@pytest.mark.parametrize("name", FIXED)
def test_sparse_polylines_found_by_the_sweeps_are_not_confidently_wrong(name):
    family, case = FOUND[name]
    _fit_one(case, family)


@pytest.mark.parametrize("name", FLAGGED)
def test_found_wrong_answers_the_residual_test_flags(name):
    family, case = FOUND[name]
    rec = _fit_one(case, family)
    assert rec["status"] == "suspect" and "profile_misfit" in rec["reasons"], rec


@pytest.mark.xfail(strict=True, raises=AssertionError,
                   reason="confident wrong answers found by the sweeps, not fixed")
@pytest.mark.parametrize("name", sorted(set(FOUND) - set(FIXED) - set(FLAGGED)))
def test_found_confident_wrong_answers(name):
    family, case = FOUND[name]
    _fit_one(case, family)
