"""Parity of the compiled path with the NumPy specification.

Every LM case of ``_parity_cases`` runs the reference and the compiled
``build_polyline_mask -> coarse_ncc_search -> lm_subpixel_refine`` on the
same inputs; the image derivatives come from the reference, once per image,
so the image side (tested on its own) cannot confound the fit.

The bar:

* coarse offsets, ``iterations``, ``converged``, ``degenerate``,
  ``inlier_count`` equal in every case;
* the fitted pose (offset, and rotation times the pivot distance) within
  1e-9 px in at least 99 % of cases and within 1e-6 px in all;
* covariances with the identical ``inf`` pattern and, where finite, within
  1e-9 relative (``max|C - C_ref| / max|C_ref|``).

The two paths sum the normal equations in different orders (BLAS versus
four lane-wise partial sums), and how the BLAS rounds depends on the CPU
(OpenBLAS picks a kernel per CPU: SkylakeX, Haswell, Sandybridge, ...), so
the reference itself moves by rounding from one machine to the next. A
well-conditioned fit carries those ulps along without growing them; an
ill-conditioned one does not. Each case is therefore
classified from the compiled path's fits, whose sums do not go through the
BLAS (the classification is the same under the three kernels), by

* its *amplification*: how far its result moves, per px, when its start
  moves by 1e-9 px (an unconverged, chaotic fit multiplies it); and
* the Jacobi-scaled condition number of its information matrix ``J^T W J``
  at the final pose, the worst case over the damping of the damped normal
  matrix ``H + lambda diag(H)`` (scaled: ``S + lambda I``).

A *well-conditioned* case (amplification <= :data:`AMPLIFICATION_MAX`,
condition number <= :data:`KAPPA_MAX`) is held to the exact bar in every
case: pose within 1e-9 px and covariance within 1e-9 relative of the
reference. An ill-conditioned case keeps everything that holds whichever
way rounding went: the discrete outcome, the pose within 1e-6 px, the inf
pattern, and a covariance, residuals and weights that are the contract's formulas
at the compiled path's own final pose (``test_exact_parity_set`` prints
and bounds the set). In every case the compiled covariance must equal, to
1e-9 relative, the contract's covariance at the compiled path's own final pose.

Residuals and weights are compared with bounds derived from the pose
difference, not with a fixed number: the clipped Euclidean DT changes by at
most 1 per pixel along each axis, so its bilinear interpolant is
sqrt(2)-Lipschitz, and a vertex moves by at most ``|dt| + |dtheta| *
|x - pivot|``; the IRLS weight ``tukey(r / s, c) / s^2`` is Lipschitz in ``r``
with constant ``1.54 / (c s^3)``. A 1e-12 relative floor covers rounding.
``rms_px`` / ``raw_rms_px`` are checked to be the contract's formulas of the
(checked) residuals and weights.

Run with ``-s`` to see the measured figures.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest

import dtalign
from _parity_cases import (
    AMPLIFICATION_MAX,
    KAPPA_MAX,
    ParityCase,
    build_cases,
    make_image,
    scaled_condition,
    spec_state,
)
from dtalign import reference as ref

CASES = build_cases()
LIPSCHITZ_DT = math.sqrt(2.0)
TUKEY_SLOPE = 8.0 / (3.0 * math.sqrt(3.0))  # max over |x| <= 1 of |d/dx (1 - x^2)^2|

#: The exact bar: pose (px) and covariance (relative) against the reference.
POSE_EXACT_PX = 1e-9
COV_EXACT_REL = 1e-9
#: The bar every case meets, whatever the conditioning: a different accepted
#: step moves the pose by ~1e-3 px or more, so this still catches a real divergence.
POSE_ANY_PX = 1e-6
#: The start is moved by the exact bar itself to measure the amplification.
PROBE_PX = POSE_EXACT_PX
#: The share of the sweep allowed to leave the exact set (measured: 6 of 322).
ILL_CONDITIONED_SHARE_MAX = 0.03
#: The discrete outcome that must be equal in every case (add new result flags here).
DISCRETE_FIELDS = ("iterations", "converged", "degenerate", "inlier_count")


@dataclass
class Outcome:
    case: ParityCase
    coarse: tuple[tuple[int, int], tuple[int, int]]
    masks_equal: bool
    seed: tuple[float, float]
    expected: Any  # reference LMRefineResult
    actual: Any  # compiled LMRefineResult
    pose_dev: float
    cov_dev: float  # vs reference, max-norm relative
    self_cov_dev: float  # vs the contract's covariance at the compiled pose
    self_state_dev: float  # residuals / weights vs the contract's state at the compiled pose
    amplification: float  # result movement per px of start movement (compiled path)
    kappa: float  # Jacobi-scaled condition number of J^T W J at the compiled final pose

    @property
    def well_conditioned(self) -> bool:
        """In the exact-parity set (see the module docstring)."""
        return self.amplification <= AMPLIFICATION_MAX and self.kappa <= KAPPA_MAX


def _rel_dev(a: np.ndarray, b: np.ndarray) -> float:
    """``max|a - b| / max|b|`` over the finite entries (absolute if b is 0)."""
    fin = np.isfinite(b)
    if not fin.any():
        return 0.0
    diff = float(np.max(np.abs(a[fin] - b[fin])))
    scale = float(np.max(np.abs(b[fin])))
    return diff / scale if scale > 0 else diff


def _pose_dev(a: Any, b: Any, case: ParityCase) -> float:
    """Max-norm pose difference in px (rotation times the pivot distance)."""
    return max(abs(a.offset_vu[0] - b.offset_vu[0]), abs(a.offset_vu[1] - b.offset_vu[1]),
               abs(a.rotation_rad - b.rotation_rad) * case.rotation_scale)


class _Runner:
    """Runs each case once per module and remembers the outcome."""

    def __init__(self, derivatives: Any) -> None:
        self.derivatives = derivatives
        self.done: dict[str, Outcome] = {}
        self.images: dict[str, np.ndarray] = {}
        self.ridge_devs: dict[str, float] = {}

    def products(self, case: ParityCase):
        spec = case.image
        if spec.key not in self.images:
            self.images[spec.key] = make_image(spec)
        return self.derivatives.get(self.images[spec.key], spec.noise_sigma)

    def __call__(self, case: ParityCase) -> Outcome:
        if case.case_id not in self.done:
            self.done[case.case_id] = self._run(case)
        return self.done[case.case_id]

    def _run(self, case: ParityCase) -> Outcome:
        mag, dt, grad = self.products(case)
        edge = dt <= 0.5
        mask_r = ref.build_polyline_mask(case.vertices, dt.shape)
        mask_c = dtalign.build_polyline_mask(case.vertices, dt.shape)
        coarse_r = ref.coarse_ncc_search(edge, mask_r, case.window)
        coarse_c = dtalign.coarse_ncc_search(edge, mask_c, case.window)
        seed = (coarse_r[0] + case.jitter[0], coarse_r[1] + case.jitter[1])
        kw = dict(vertices_vu=case.vertices, normals_vu=case.normals,
                  sigma_normal_per_vertex_px=case.sigmas, image_edge_dt=dt,
                  image_gradient_vu=grad, initial_offset_vu=seed, **case.lm_kwargs)
        expected = ref.lm_subpixel_refine(**kw)
        actual = dtalign.lm_subpixel_refine(**kw)
        pose_dev = _pose_dev(expected, actual, case)
        # The amplification: the compiled fit from starts moved by PROBE_PX.
        amplification = 0.0
        for ev, eu in ((1, 0), (0, 1), (-1, 0), (0, -1)):
            probe = dtalign.lm_subpixel_refine(
                **{**kw, "initial_offset_vu": (seed[0] + ev * PROBE_PX, seed[1] + eu * PROBE_PX)})
            amplification = max(amplification, _pose_dev(probe, actual, case) / PROBE_PX)
        # The contract's state at the compiled path's own final pose.
        fit_rotation = bool(case.lm_kwargs.get("fit_rotation", False))
        pivot = case.lm_kwargs.get("pivot_vu")
        if pivot is None:
            pivot = tuple(case.vertices.mean(axis=0))
        if case.lm_kwargs.get("use_polarity", True):
            pol = ref.polarity_filter(case.vertices, case.normals, grad, offset_vu=seed)
        else:
            pol = np.ones(case.vertices.shape[0], dtype=bool)
        pose = (*actual.offset_vu, actual.rotation_rad)
        c = case.lm_kwargs.get("tukey_c", dtalign.DEFAULT_TUKEY_C)
        r, w, jac = spec_state(dt, case.vertices, case.sigmas, pol, pose, pivot, fit_rotation, c)
        self_state = max(_rel_dev(actual.residuals_px, r), _rel_dev(actual.weights, w))
        if actual.degenerate:
            self_cov = 0.0 if np.isposinf(actual.covariance).all() else math.inf
        else:
            rcond = case.lm_kwargs.get("pinvh_rcond", dtalign.DEFAULT_PINVH_RCOND)
            spec_cov = ref.information_matrix_to_covariance(jac, w, rcond=rcond)
            self_cov = _rel_dev(actual.covariance, spec_cov)
        return Outcome(case, (coarse_r, coarse_c), bool(np.array_equal(mask_r, mask_c)), seed,
                       expected, actual, pose_dev, _rel_dev(actual.covariance, expected.covariance),
                       self_cov, self_state, amplification, scaled_condition(jac, w))


@pytest.fixture(scope="module")
def run(derivatives) -> _Runner:
    return _Runner(derivatives)


def assert_lm_parity(out: Outcome) -> None:
    """The per-case bar of the module docstring (one place to extend)."""
    case, exp, act = out.case, out.expected, out.actual
    assert out.masks_equal
    assert out.coarse[1] == out.coarse[0]
    assert tuple(getattr(act, f) for f in DISCRETE_FIELDS) == tuple(getattr(exp, f) for f in DISCRETE_FIELDS)
    assert out.pose_dev <= POSE_ANY_PX
    assert np.array_equal(np.isfinite(act.covariance), np.isfinite(exp.covariance))
    assert np.array_equal(np.isposinf(act.covariance), np.isposinf(exp.covariance))
    if out.well_conditioned:  # the exact set
        assert out.pose_dev <= POSE_EXACT_PX
        assert out.cov_dev <= COV_EXACT_REL
    # whatever the conditioning: the contract's formulas at the compiled path's own pose
    assert out.self_cov_dev <= COV_EXACT_REL
    assert out.self_state_dev <= 1e-12

    # residuals and weights: bounds derived from the pose difference
    pivot = case.lm_kwargs.get("pivot_vu") or tuple(case.vertices.mean(axis=0))
    lever = np.hypot(case.vertices[:, 0] - pivot[0], case.vertices[:, 1] - pivot[1])
    move = (math.hypot(exp.offset_vu[0] - act.offset_vu[0], exp.offset_vu[1] - act.offset_vu[1])
            + abs(exp.rotation_rad - act.rotation_rad) * lever)
    r_tol = LIPSCHITZ_DT * move + 1e-12 * (1.0 + np.abs(exp.residuals_px))
    assert np.all(np.abs(act.residuals_px - exp.residuals_px) <= r_tol)
    assert np.array_equal(act.residuals_px == 1.0e6, exp.residuals_px == 1.0e6)
    c = case.lm_kwargs.get("tukey_c", dtalign.DEFAULT_TUKEY_C)
    sig = case.sigmas
    w_tol = TUKEY_SLOPE / (c * sig**3) * r_tol + 1e-12 / sig**2
    assert np.all(np.abs(act.weights - exp.weights) <= w_tol)

    # rms values are the contract's formulas of the reported arrays
    r, w = act.residuals_px, act.weights
    accepted = r != 1.0e6  # :ref:`contract-changes`: over the polarity-accepted vertices
    raw = math.sqrt(np.mean(r[accepted] ** 2)) if accepted.any() else math.inf
    assert act.raw_rms_px == pytest.approx(raw, rel=1e-12)
    if act.degenerate:
        assert act.rms_px == math.inf and exp.rms_px == math.inf
    else:
        assert act.rms_px == pytest.approx(math.sqrt(np.sum(w * r * r) / np.sum(w)), rel=1e-12)


@pytest.mark.parametrize("case", CASES, ids=[c.case_id for c in CASES])
def test_lm_parity(case: ParityCase, run: _Runner) -> None:
    assert_lm_parity(run(case))


def test_lm_parity_summary(run: _Runner) -> None:
    """The aggregate bar, and the measured figures (printed with ``-s``)."""
    outs = [run(c) for c in CASES]
    devs = np.array([o.pose_dev for o in outs])
    within = devs <= POSE_EXACT_PX
    well = np.array([o.well_conditioned for o in outs])
    cov_all = max(o.cov_dev for o in outs)
    cov_well = max(o.cov_dev for o, ok in zip(outs, well, strict=True) if ok)
    families = sorted({o.case.family for o in outs})
    rms_dev = max(abs(o.actual.rms_px - o.expected.rms_px) for o in outs if not o.expected.degenerate)
    lines = [
        f"LM parity: {len(outs)} cases, {len(families)} families "
        f"({sum(o.expected.degenerate for o in outs)} degenerate, {int(well.sum())} well-conditioned)",
        f"  pose within 1e-9 px: {within.sum()}/{len(outs)} = {100 * within.mean():.2f} %"
        f"  (bit-identical: {100 * np.mean(devs == 0):.1f} %)",
        f"  max pose deviation: {devs.max():.3e} px (case {outs[int(devs.argmax())].case.case_id}),"
        f" {devs[well].max():.3e} px over the well-conditioned cases",
        f"  max covariance rel. deviation: {cov_well:.3e} over the well-conditioned cases,"
        f" {cov_all:.3e} over all cases",
        f"  max covariance rel. deviation vs the contract at own pose: {max(o.self_cov_dev for o in outs):.3e}"
        f" (residuals/weights: {max(o.self_state_dev for o in outs):.3e})",
        f"  max |d residual| {max(np.max(np.abs(o.actual.residuals_px - o.expected.residuals_px)) for o in outs):.3e} px,"
        f" max |d weight| {max(np.max(np.abs(o.actual.weights - o.expected.weights)) for o in outs):.3e},"
        f" max |d rms| {rms_dev:.3e} px",
    ]
    lines += [f"    over 1e-9 px: {o.case.case_id}: {o.pose_dev:.3e} px, cov {o.cov_dev:.2e}"
              for o in outs if o.pose_dev > POSE_EXACT_PX]
    print("\n" + "\n".join(lines))
    assert within.mean() >= 0.99
    assert devs.max() <= POSE_ANY_PX
    assert all(o.coarse[0] == o.coarse[1] for o in outs)
    assert devs[well].max() <= POSE_EXACT_PX
    assert cov_well <= COV_EXACT_REL


def test_exact_parity_set(run: _Runner) -> None:
    """How ill-conditioned a case must be to leave the exact-parity set.

    A case leaves it when its fit amplifies a move of its start more than
    :data:`AMPLIFICATION_MAX`-fold or its scaled information matrix has a
    condition number above :data:`KAPPA_MAX` (module docstring). The
    threshold is not a convenience: the cases below it are held to 1e-9 px
    and 1e-9 relative (``test_lm_parity``), the set above it is bounded
    here, and the measured margin to the threshold is printed (``-s``).
    The condition number alone does not predict a departure: the polish of
    a four-vertex fit that does not converge in its ten undamped steps
    (``max_iterations_0-02-nav1``) multiplies rounding ~5x per step with
    ``kappa`` ~ 21, which only the amplification sees.
    """
    outs = [run(c) for c in CASES]
    ill = [o for o in outs if not o.well_conditioned]
    well = [o for o in outs if o.well_conditioned]
    lines = [f"exact-parity set: {len(well)}/{len(outs)} cases"
             f" (amplification <= {AMPLIFICATION_MAX:.0e}, kappa <= {KAPPA_MAX:.0e});"
             f" largest inside: amplification {max(o.amplification for o in well):.3g},"
             f" kappa {max(o.kappa for o in well):.3g}"]
    lines += [f"    outside: {o.case.case_id}: amplification {o.amplification:.3g}, kappa {o.kappa:.3g},"
              f" pose {o.pose_dev:.2e} px, cov {o.cov_dev:.2e}" for o in ill]
    print("\n" + "\n".join(lines))
    assert len(ill) <= ILL_CONDITIONED_SHARE_MAX * len(outs)
    # every fit that really amplifies rounding is classified so (non-vacuous:
    # the sweep has such fits), and none of the exact set is near the threshold
    assert any(o.amplification > AMPLIFICATION_MAX for o in outs)
    assert max(o.amplification for o in well) <= AMPLIFICATION_MAX / 3
    # the exact set is held to the exact bar (as test_lm_parity, in one place)
    assert max(o.pose_dev for o in well) <= POSE_EXACT_PX
    assert max(o.cov_dev for o in well) <= COV_EXACT_REL
    # and the cases outside still meet what holds on either branch
    for o in ill:
        assert o.pose_dev <= POSE_ANY_PX
        assert o.self_cov_dev <= COV_EXACT_REL and o.self_state_dev <= 1e-12


def test_sweep_covers_its_families(run: _Runner) -> None:
    """The sweep exercises what it claims (not only that it runs)."""
    outs = [run(c) for c in CASES]
    fam: dict[str, list[Outcome]] = {}
    for o in outs:
        fam.setdefault(o.case.family, []).append(o)
    assert len(outs) >= 300
    assert sum(o.expected.degenerate for o in fam["degenerate"]) >= 10
    assert all(o.expected.iterations == 0 for o in fam["max_iterations_0"])
    # a flat DT: the fit never leaves the seed, with (or without) weight
    assert all(o.expected.offset_vu == o.seed for o in fam["flat_dt"])
    assert {o.expected.degenerate for o in fam["flat_dt"]} == {True, False}
    assert sum(o.case.lm_kwargs.get("fit_rotation", False) for o in outs) >= 50
    assert any(o.case.sigmas.std() > 0 for o in outs)
    binding = [o for o in fam["trust_region"]
               if math.hypot(o.expected.offset_vu[0] - o.seed[0], o.expected.offset_vu[1] - o.seed[1])
               >= 0.9 * o.case.lm_kwargs["trust_region_px"] > 0]
    assert len(binding) >= 3
    outside = [o for o in fam["partly_outside"]
               if 0.05 < np.mean(np.any((o.case.vertices < 0)
                                        | (o.case.vertices > np.array(o.case.image.shape) - 1),
                                        axis=1)) < 0.95]
    assert len(outside) >= 10
    # the polish is applied (moves the pose) in the ridge cases
    moved = 0
    for o in fam["ridge"]:
        mag, dt, grad = run.products(o.case)
        kw = {k: v for k, v in o.case.lm_kwargs.items() if k != "final_gradient_ridge"}
        plain = ref.lm_subpixel_refine(
            vertices_vu=o.case.vertices, normals_vu=o.case.normals,
            sigma_normal_per_vertex_px=o.case.sigmas, image_edge_dt=dt, image_gradient_vu=grad,
            initial_offset_vu=o.seed, **kw)
        moved += plain.offset_vu != o.expected.offset_vu
    assert moved >= 5


# ---------------------------------------------------------------------------
# The pieces, on random inputs
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(30))
def test_sample_dt_bilinear_parity(seed: int) -> None:
    """Same formula, same order (:ref:`contract-numerics`): bit-identical samples."""
    rng = np.random.default_rng([11, seed])
    h, w = (int(x) for x in rng.integers(1, 40, 2))
    dt = rng.normal(0.0, 10.0, (h, w)) if seed % 2 else rng.integers(0, 64, (h, w)).astype(float)
    n = 500
    pts = np.column_stack([rng.uniform(-3.0, h + 2.0, n), rng.uniform(-3.0, w + 2.0, n)])
    pts[:100] = np.round(pts[:100] * 2.0) / 2.0  # integers and half-integers
    pts[100:110, 0] = h - 1.0  # on the last row / column exactly
    pts[110:120, 1] = w - 1.0
    np.testing.assert_array_equal(dtalign.sample_dt_bilinear(dt, pts), ref.sample_dt_bilinear(dt, pts))


@pytest.mark.parametrize("seed", range(20))
def test_polarity_filter_parity(seed: int) -> None:
    rng = np.random.default_rng([12, seed])
    h, w = (int(x) for x in rng.integers(1, 50, 2))
    grad = rng.normal(size=(h, w, 2))
    grad[rng.random((h, w)) < 0.2] = 0.0  # dot product exactly 0: rejected
    n = 300
    pts = np.column_stack([rng.uniform(-3.0, h + 2.0, n), rng.uniform(-3.0, w + 2.0, n)])
    pts[:80] = np.round(pts[:80] * 2.0) / 2.0
    nrm = rng.normal(size=(n, 2))
    offset = (float(np.round(rng.uniform(-2, 2) * 2) / 2), float(rng.uniform(-2, 2)))
    np.testing.assert_array_equal(
        dtalign.polarity_filter(pts, nrm, grad, offset_vu=offset),
        ref.polarity_filter(pts, nrm, grad, offset_vu=offset))


@pytest.mark.parametrize("seed", range(10))
def test_tukey_parity(seed: int) -> None:
    rng = np.random.default_rng([13, seed])
    c = float(rng.uniform(0.5, 8.0)) if seed else dtalign.DEFAULT_TUKEY_C
    r = np.concatenate([rng.normal(0.0, c, 1000), [0.0, -0.0, c, -c, np.nextafter(c, 0.0),
                                                   np.nextafter(c, 9.0), 1e300, -np.inf]])
    with np.errstate(over="ignore"):  # the reference squares 1e300
        want = ref.tukey_biweight_weights(r, c=c)
    np.testing.assert_array_equal(dtalign.tukey_biweight_weights(r, c=c), want)


@pytest.mark.parametrize("seed", range(30))
def test_covariance_parity(seed: int) -> None:
    rng = np.random.default_rng([14, seed])
    n, p = int(rng.integers(1, 60)), int(rng.integers(1, 5))
    jac = rng.normal(size=(n, p)) * rng.uniform(0.01, 100.0, p)
    if seed % 3 == 0 and p > 1:
        jac[:, -1] = jac[:, 0]  # rank deficient
    w = rng.uniform(0.0, 3.0, n) * (rng.random(n) < 0.8)
    rcond = float(rng.choice([dtalign.DEFAULT_PINVH_RCOND, 1e-12, 1e-4]))
    got = dtalign.information_matrix_to_covariance(jac, w, rcond=rcond)
    want = ref.information_matrix_to_covariance(jac, w, rcond=rcond)
    assert np.array_equal(np.isfinite(got), np.isfinite(want))
    assert _rel_dev(got, want) <= 1e-9


@pytest.mark.parametrize("seed", range(20))
def test_build_polyline_mask_parity(seed: int) -> None:
    rng = np.random.default_rng([15, seed])
    h, w = (int(x) for x in rng.integers(1, 60, 2))
    pts = np.column_stack([rng.uniform(-2.0, h + 1.0, 400), rng.uniform(-2.0, w + 1.0, 400)])
    pts[:200] = np.round(pts[:200] * 2.0) / 2.0  # half-integers: round half to even
    np.testing.assert_array_equal(dtalign.build_polyline_mask(pts, (h, w)),
                                  ref.build_polyline_mask(pts, (h, w)))


COARSE_WINDOWS = [(30, 30), (50, 50), (7, 13), (0, 9), (21, 0), (3, 3)]


@pytest.mark.parametrize("window", COARSE_WINDOWS, ids=str)
@pytest.mark.parametrize("kind", ["random", "shifted", "periodic", "empty_edges", "full_edges",
                                  "empty_polyline", "tiny_image"])
def test_coarse_search_parity(kind: str, window: tuple[int, int]) -> None:
    rng = np.random.default_rng([16, COARSE_WINDOWS.index(window), len(kind)])
    h, w = (int(x) for x in rng.integers(40, 90, 2))
    poly = rng.random((h, w)) < 0.02
    edge = rng.random((h, w)) < rng.uniform(0.05, 0.3)
    if kind == "shifted":  # a unique best shift inside the window, plus noise
        dv, du = int(rng.integers(-window[0], window[0] + 1)), int(rng.integers(-window[1], window[1] + 1))
        edge = np.roll(poly, (dv, du), axis=(0, 1)) | (rng.random((h, w)) < 0.05)
    elif kind == "periodic":  # many exactly equal scores: the tie-break decides
        edge = np.zeros((h, w), dtype=bool)
        edge[:, ::3] = True
        edge[::4, :] = True
    elif kind == "empty_edges":
        edge[:] = False
    elif kind == "full_edges":
        edge[:] = True
    elif kind == "empty_polyline":
        poly[:] = False
    elif kind == "tiny_image":  # window much larger than the arrays: clipped
        h, w = int(rng.integers(1, 6)), int(rng.integers(1, 6))
        poly, edge = rng.random((h, w)) < 0.4, rng.random((h, w)) < 0.4
    args = (edge.astype(np.uint8) if kind == "random" else edge, poly, window)
    assert dtalign.coarse_ncc_search(*args) == ref.coarse_ncc_search(*args)


RIDGE_CASES = [c for i, c in enumerate(CASES) if i % 4 == 1 and c.family not in ("degenerate", "flat_dt")]


def _ridge_parity(case: ParityCase, run: _Runner) -> tuple[Any, Any, dict[str, Any]]:
    """Reference and compiled polish from near the reference LM pose."""
    out = run(case)
    rng = np.random.default_rng([17, CASES.index(case)])
    mag, _, _ = run.products(case)
    n = case.vertices.shape[0]
    kw: dict[str, Any] = dict(
        vertices_vu=case.vertices, normals_vu=case.normals, sigma_normal_per_vertex_px=case.sigmas,
        gradient_magnitude=mag,
        initial_offset_vu=(out.expected.offset_vu[0] + float(rng.uniform(-0.7, 0.7)),
                           out.expected.offset_vu[1] + float(rng.uniform(-0.7, 0.7))),
        weight_mask=None if rng.random() < 0.5 else rng.random(n) < 0.8,
        half_width_px=float(rng.choice([3.0, 2.0, 4.5, 1.25])),
        sample_step_px=float(rng.choice([0.5, 0.25, 1.0, 0.3])),
        max_iterations=int(rng.choice([10, 3, 20])),
        max_total_displacement_px=float(rng.choice([1.5, 0.5, np.inf])),
    )
    if case.lm_kwargs.get("fit_rotation"):
        kw.update(fit_rotation=True, pivot_distance_px=case.lm_kwargs["pivot_distance_px"],
                  initial_rotation_rad=out.expected.rotation_rad, pivot_vu=case.lm_kwargs.get("pivot_vu"))
    want = ref.gradient_ridge_refine(**kw)
    got = dtalign.gradient_ridge_refine(**kw)
    run.ridge_devs[case.case_id] = max(
        abs(got.offset_vu[0] - want.offset_vu[0]), abs(got.offset_vu[1] - want.offset_vu[1]),
        abs(got.rotation_rad - want.rotation_rad) * case.rotation_scale)
    return want, got, kw


@pytest.mark.parametrize("case", RIDGE_CASES, ids=[c.case_id for c in RIDGE_CASES])
def test_gradient_ridge_refine_parity(case: ParityCase, run: _Runner) -> None:
    want, got, kw = _ridge_parity(case, run)
    assert (got.iterations, got.converged, got.applied) == (want.iterations, want.converged, want.applied)
    assert run.ridge_devs[case.case_id] <= 1e-6
    if not want.applied:  # the inputs, exactly
        assert got.offset_vu == tuple(kw["initial_offset_vu"])
        assert got.rotation_rad == want.rotation_rad


def test_gradient_ridge_parity_summary(run: _Runner) -> None:
    """The 99 % bar over the ridge cases; prints the measured figures (``-s``)."""
    for case in RIDGE_CASES:
        if case.case_id not in run.ridge_devs:
            _ridge_parity(case, run)
    devs = np.array([run.ridge_devs[c.case_id] for c in RIDGE_CASES])
    print(f"\nridge parity: {devs.size} cases, within 1e-9 px: {100 * np.mean(devs <= 1e-9):.2f} %,"
          f" bit-identical {100 * np.mean(devs == 0):.1f} %, max deviation {devs.max():.3e} px")
    assert np.mean(devs <= 1e-9) >= 0.99
    assert devs.max() <= 1e-6


def _spec_single_vertex(dt: np.ndarray, vertex: np.ndarray, sigma: float) -> tuple[np.ndarray, float, float]:
    """``J``, ``r`` and ``w`` of one vertex at zero offset (:ref:`contract-numerics`, :ref:`contract-lm`)."""
    s = ref.sample_dt_bilinear
    pts = vertex[None, :]
    jac = np.array([(s(dt, pts + [0.25, 0.0]) - s(dt, pts - [0.25, 0.0]))[0] / 0.5,
                    (s(dt, pts + [0.0, 0.25]) - s(dt, pts - [0.0, 0.25]))[0] / 0.5])
    r = float(s(dt, pts)[0])
    w = float(ref.tukey_biweight_weights(np.array([r / sigma]))[0]) / sigma**2
    return jac, r, w


#: Relative residual of a solve of the undamped one-vertex system: LU with
#: partial pivoting is backward stable, ``|H x + g| <= c eps |H| |x|`` with c
#: of order 10 for a 2x2 system, whichever branch (solve or pinvh) it took
#: (measured: 2.7e-16 under three OpenBLAS kernels).
GN_RESIDUAL_REL = 1e-14


def test_lm_single_vertex_without_damping_solves_the_rank_one_system() -> None:
    """One weighted vertex, damping 0: ``H = a a^T`` is singular up to rounding.

    Whether ``solve`` is singular (:ref:`contract-lm` step 2d) is decided by how
    the LU factorisation rounds, which differs between CPUs (OpenBLAS's
    SkylakeX kernel fuses multiply-adds, the compiled elimination does not):
    one path may take pinvh's minimum-norm step and the other a step with a
    large component along the null space of ``a^T``, 70 px away. Either follows
    the contract: both solve the Gauss-Newton system ``a a^T x = -a s``, i.e.
    ``a^T x = -s``, which is asserted for every accepted step, with the
    same iterations, degenerate flag and inlier count.
    """
    vv, uu = np.mgrid[0:32, 0:32].astype(float)
    dt = np.hypot(vv - 3.3, uu - 2.1)  # distance to a point: J is never parallel to an axis
    rng = np.random.default_rng(0)
    moved = {"reference": 0, "compiled": 0}
    for _ in range(200):
        vertex = rng.uniform(8.0, 24.0, 2)
        kw = dict(vertices_vu=vertex[None, :], normals_vu=[[1.0, 0.0]],
                  sigma_normal_per_vertex_px=[100.0], image_edge_dt=dt, use_polarity=False,
                  damping=0.0, max_iterations=1)
        jac, r, w = _spec_single_vertex(dt, vertex, 100.0)
        a, s = math.sqrt(w) * jac, math.sqrt(w) * r
        want, got = ref.lm_subpixel_refine(**kw), dtalign.lm_subpixel_refine(**kw)
        assert (got.iterations, got.degenerate, got.inlier_count) == (1, False, 1)
        assert (want.iterations, want.degenerate, want.inlier_count) == (1, False, 1)
        for name, res in (("reference", want), ("compiled", got)):
            x = np.array(res.offset_vu)  # the seed is (0, 0): the pose is the step
            assert np.isfinite(x).all()
            if not x.any():  # the step was refused (:ref:`contract-lm` step 2f): the seed, not converged
                assert not res.converged
                continue
            moved[name] += 1
            residual = abs(float(a @ x) + s)
            assert residual <= GN_RESIDUAL_REL * (np.linalg.norm(a) * np.linalg.norm(x) + abs(s)), name
            # accepted because the cost fell (:ref:`contract-lm` step 2f: the weights of the seed state)
            assert float(ref.sample_dt_bilinear(dt, vertex[None, :] + x)[0]) ** 2 < r**2
            assert res.converged == (math.hypot(*x) < dtalign.DEFAULT_LM_STEP_TOLERANCE)
    assert min(moved.values()) >= 100  # non-vacuous: most steps are accepted
