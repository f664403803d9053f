"""The four-vertices-at-a-time kernels (``_kernels.lanes``) against the
one-vertex-at-a-time code they replace in the LM's hot loops.

Samples, Jacobians, residuals, weights and polarity flags must be
bit-identical (same IEEE operations in the same order); only the sums over
vertices are taken in a different order (lane-wise), so they are compared
to the sequential sums with a relative tolerance of a few ulps times N.
The LM-level tests run whichever path :data:`dtalign._kernels.lanes.VECTOR`
selects (the plain twin under ``NUMBA_DISABLE_JIT=1``); the tests that call
the vector intrinsics directly need the JIT (they are LLVM IR, not Python).
``test_lanes_twin.py`` compares the two paths with each other.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest
from numba import njit

from dtalign._kernels import lanes
from dtalign._kernels import lm as klm
from dtalign._kernels import robust as krob
from dtalign._kernels.lanes import vector
from dtalign._kernels.lanes.simd import load4, splat, store4
from dtalign._kernels.lanes.simd_image import (
    CELLS_PER_SLOT,
    FRACS_PER_SLOT,
    bilinear4,
    finish_state,
    positions4,
    stage_state,
    state4,
)
from dtalign._kernels.sampling import bilinear, sample_many

EPS_T = lanes.EPS_T

#: The vector intrinsics are LLVM IR: with the JIT disabled they cannot run.
needs_jit = pytest.mark.skipif(numba.config.DISABLE_JIT, reason="the vector intrinsics are LLVM IR, not Python")


@njit
def _lanes_direct(dt, pts, dv, du, theta, out):
    """Per group of four: the sample and both central differences, unstaged;
    row 3 is bilinear4 alone."""
    c, s = math.cos(theta), math.sin(theta)
    for i in range(0, pts.shape[0] - pts.shape[0] % 4, 4):
        v, u = positions4(pts, i, dv, du, theta, c, s, 1.5, -2.0)
        sample, j_v, j_u = state4(dt, v, u, EPS_T, 2 * EPS_T)
        store4(out[0], i, sample)
        store4(out[1], i, j_v)
        store4(out[2], i, j_u)
        store4(out[3], i, bilinear4(dt, v, u))


@njit
def _lanes_staged(dt, pts, dv, du, theta, out):
    """The same through stage_state / finish_state, one slot per group (edge
    groups unstaged, through state4)."""
    c, s = math.cos(theta), math.sin(theta)
    n4 = pts.shape[0] - pts.shape[0] % 4
    cells = np.empty((n4 // 4 + 1) * CELLS_PER_SLOT, np.int32)
    fracs = np.empty((n4 // 4 + 1) * FRACS_PER_SLOT)
    for i in range(0, n4, 4):
        v, u = positions4(pts, i, dv, du, theta, c, s, 1.5, -2.0)
        g = i // 4
        if stage_state(dt, v, u, EPS_T, cells, fracs, g):
            sample, j_v, j_u = finish_state(dt, cells, fracs, g, 2 * EPS_T)
        else:
            sample, j_v, j_u = state4(dt, v, u, EPS_T, 2 * EPS_T)
        store4(out[0], i, sample)
        store4(out[1], i, j_v)
        store4(out[2], i, j_u)
        store4(out[3], i, sample)


def _scalar(dt, pts, dv, du, theta):
    """The one-by-one code: transform, bilinear, central differences."""
    c, s = math.cos(theta), math.sin(theta)
    out = np.empty((4, pts.shape[0]))
    for i in range(pts.shape[0]):
        if theta == 0.0:
            v, u = pts[i, 0] + dv, pts[i, 1] + du
        else:
            v = 1.5 + c * (pts[i, 0] - 1.5) - s * (pts[i, 1] + 2.0) + dv
            u = -2.0 + s * (pts[i, 0] - 1.5) + c * (pts[i, 1] + 2.0) + du
        out[0, i] = bilinear(dt, v, u)
        out[1, i] = (bilinear(dt, v + EPS_T, u) - bilinear(dt, v - EPS_T, u)) / (2 * EPS_T)
        out[2, i] = (bilinear(dt, v, u + EPS_T) - bilinear(dt, v, u - EPS_T)) / (2 * EPS_T)
        out[3, i] = out[0, i]
    return out


def _positions(rng, n, h, w):
    """Vertices inside, on and outside the image, exact integers, halves, NaN and inf."""
    pts = rng.uniform(-3.0, max(h, w) + 3.0, size=(n, 2))
    k = rng.random(n)
    pts[k < 0.15] = np.floor(pts[k < 0.15])  # on grid lines: fractions exactly 0
    pts[(k >= 0.15) & (k < 0.25), 0] = h - 1.0  # the last row: a clamped corner
    pts[(k >= 0.25) & (k < 0.3), 1] = w - 1.0 + 0.25  # the +eps sample leaves the image
    pts[(k >= 0.3) & (k < 0.33)] = np.nan
    pts[(k >= 0.33) & (k < 0.35), 1] = np.inf
    pts[(k >= 0.35) & (k < 0.37), 0] = -1e300
    return pts


@needs_jit
@pytest.mark.parametrize("shape", [(2, 2), (2, 7), (9, 2), (17, 23), (64, 64)])
@pytest.mark.parametrize("theta", [0.0, 0.3])
def test_lane_samples_are_bit_identical(shape, theta):
    rng = np.random.default_rng(sum(shape) + int(theta * 10))
    dt = rng.uniform(0.0, 20.0, size=shape)
    for _ in range(20):
        pts = _positions(rng, 4 * int(rng.integers(1, 40)), *shape)
        dv, du = rng.uniform(-1.0, 1.0, 2)
        want = _scalar(dt, pts, dv, du, theta)
        for kernel in (_lanes_direct, _lanes_staged):
            got = np.full_like(want, -7.0)
            kernel(dt, pts, dv, du, theta, got)
            np.testing.assert_array_equal(got, want)


@needs_jit
def test_lane_samples_read_non_finite_dt_values_as_the_scalar_code_does():
    rng = np.random.default_rng(3)
    dt = rng.uniform(0.0, 5.0, size=(12, 12))
    dt[4, 6] = np.nan
    dt[8, 2] = np.inf
    dt[11, 11] = -np.inf  # the clamped corner
    pts = _positions(rng, 400, 12, 12)
    want = _scalar(dt, pts, 0.1, -0.2, 0.0)
    for kernel in (_lanes_direct, _lanes_staged):
        got = np.zeros_like(want)
        kernel(dt, pts, 0.1, -0.2, 0.0, got)
        np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("polarity", [
    pytest.param(vector.polarity, marks=needs_jit, id="vector"),
    pytest.param(lanes.polarity, id="switched"),
])
def test_polarity_lanes_match_the_scalar_test(polarity):
    rng = np.random.default_rng(11)
    for trial in range(300):
        h, w = (int(x) for x in rng.integers(1, 30, 2))
        grad = rng.normal(size=(h, w, 2))
        if trial % 4 == 0:
            grad[rng.integers(h), rng.integers(w), rng.integers(2)] = (np.nan, np.inf, -np.inf)[
                trial % 3
            ]
        n = int(rng.integers(0, 30))
        pts = rng.uniform(-4.0, max(h, w) + 4.0, size=(n, 2))
        ties = rng.random((n, 2)) < 0.3
        pts[ties] = np.floor(pts[ties]) + 0.5  # rint rounds half to even
        pts[rng.random(n) < 0.1] = np.nan
        nrm = rng.normal(size=(n, 2))
        nrm[rng.random(n) < 0.1] = 0.0
        dv, du = (float(x) for x in rng.uniform(-2.0, 2.0, 2))
        want, want_bad = krob.polarity(pts, nrm, grad, dv, du)
        got, got_bad = polarity(pts, nrm, grad, dv, du)
        assert got_bad == want_bad
        if not want_bad:
            np.testing.assert_array_equal(got, want)


def _state_scalar(dt, pts, sig, pol, pose, fit_rotation, tukey_c):
    """The contract's state at ``pose``, vertex by vertex, with sequential sums."""
    dv, du, theta = pose
    p = 3 if fit_rotation else 2
    n = pts.shape[0]
    r, w, jac = np.empty(n), np.empty(n), np.empty((p, n))
    c, s = math.cos(theta), math.sin(theta)
    for i in range(n):
        v, u = (pts[i, 0] + dv, pts[i, 1] + du) if theta == 0.0 else (
            c * pts[i, 0] - s * pts[i, 1] + dv, s * pts[i, 0] + c * pts[i, 1] + du)
        r[i] = bilinear(dt, v, u) if pol[i] != 0.0 else klm.PENALTY
        jac[0, i] = (bilinear(dt, v + EPS_T, u) - bilinear(dt, v - EPS_T, u)) / (2 * EPS_T)
        jac[1, i] = (bilinear(dt, v, u + EPS_T) - bilinear(dt, v, u - EPS_T)) / (2 * EPS_T)
        if fit_rotation:
            rot = []
            for t in (theta + lanes.EPS_R, theta - lanes.EPS_R):
                ct, st = math.cos(t), math.sin(t)
                rot.append(bilinear(dt, ct * pts[i, 0] - st * pts[i, 1] + dv,
                                    st * pts[i, 0] + ct * pts[i, 1] + du))
            jac[2, i] = (rot[0] - rot[1]) / (2 * lanes.EPS_R)
        w[i] = (1.0 / (sig[i] * sig[i])) * krob.tukey_many(np.array([r[i] / sig[i]]), tukey_c)[0] * pol[i]
    sw = np.sqrt(w)
    a = sw[:, None] * jac.T
    return r, w, jac, a.T @ a, a.T @ (sw * r), float(np.sum(w * r * r)), float(np.sum(w))


@pytest.mark.parametrize("n", [0, 1, 3, 4, 5, 7, 8, 13, 64, 203])
@pytest.mark.parametrize("fit_rotation", [False, True])
def test_evaluate_state_lanes_and_tail(n, fit_rotation):
    rng = np.random.default_rng(n + 100 * fit_rotation)
    dt = rng.uniform(0.0, 6.0, size=(40, 50))
    pts = rng.uniform(-2.0, 45.0, size=(n, 2))
    sig = rng.uniform(0.5, 2.0, n)
    pol = (rng.random(n) < 0.8).astype(float)
    pose = np.array([0.3, -0.7, 0.02 if fit_rotation else 0.0])
    p = 3 if fit_rotation else 2
    want_r, want_w, want_jac, want_h, want_g, want_cost, want_total = _state_scalar(
        dt, pts, sig, pol, pose, fit_rotation, 4.685)
    for sampled in (False, True):
        r, w, jac = np.zeros(n), np.zeros(n), np.zeros((p, n))
        hess, grad = np.zeros((p, p)), np.zeros(p)
        samples = np.zeros(n)
        if sampled:  # the state a trial step left: samples and Jacobian
            assert lanes.sample_state(dt, pts, pose, np.zeros(2), fit_rotation, samples, jac,
                                      lanes.staging_buffers())
        status, cost, total = klm.evaluate_state(
            dt, pts, 1.0 / (sig * sig), sig, pol, pose, np.zeros(2), fit_rotation, 4.685, r, w,
            jac, hess, grad, samples, sampled, lanes.staging_buffers())
        assert status == (1 if (want_w > 0).any() else 0)
        np.testing.assert_array_equal(r, want_r)
        np.testing.assert_array_equal(w, want_w)
        np.testing.assert_array_equal(jac, want_jac)
        # the sums' order differs (lane-wise, BLAS): a few ulps of the terms' size
        scale = max(1.0, float(np.abs(want_w * want_r * want_r).sum()))
        assert abs(cost - want_cost) <= 1e-13 * scale
        assert abs(total - want_total) <= 1e-13 * max(1.0, float(np.abs(want_w).sum()))
        np.testing.assert_allclose(hess, want_h, rtol=1e-12, atol=1e-12 * (1 + np.abs(want_h).max()))
        np.testing.assert_allclose(grad, want_g, rtol=1e-12, atol=1e-12 * (1 + np.abs(want_g).max()))


@pytest.mark.parametrize("where", [0, 5, 10, 11])
def test_evaluate_state_refuses_a_non_finite_dt_in_lanes_and_tail(where):
    """A NaN read by vertex ``where`` (lanes: 0..7; tail: 8..10 of 11) is status -1."""
    dt = np.ones((30, 30))
    pts = np.column_stack([np.arange(11.0) + 5.0, np.full(11, 7.0)])
    if where < 11:
        dt[int(pts[where, 0]), 7] = np.nan
    r, w, jac = np.zeros(11), np.zeros(11), np.zeros((2, 11))
    status, _, _ = klm.evaluate_state(
        dt, pts, np.ones(11), np.ones(11), np.ones(11), np.zeros(3), np.zeros(2), False, 4.685,
        r, w, jac, np.zeros((2, 2)), np.zeros(2), np.zeros(11), False, lanes.staging_buffers())
    assert status == (-1 if where < 11 else 1)


@pytest.mark.parametrize("n", [0, 3, 4, 9, 257])
@pytest.mark.parametrize("fit_rotation", [False, True])
def test_trial_cost_samples_jacobian_and_sum(n, fit_rotation):
    rng = np.random.default_rng(n)
    dt = rng.uniform(0.0, 6.0, size=(33, 31))
    pts = rng.uniform(-1.0, 34.0, size=(n, 2))
    pol = (rng.random(n) < 0.7).astype(float)
    w = rng.uniform(0.0, 2.0, n)
    pose = np.array([0.25, 0.5, 0.01 if fit_rotation else 0.0])
    p = 3 if fit_rotation else 2
    samples, jac = np.full(n, np.nan), np.full((p, n), np.nan)
    cost, ok = klm.trial_cost(dt, pts, pol, w, pose, np.zeros(2), fit_rotation, samples, jac,
                              lanes.staging_buffers())
    want_r, _, want_jac, *_ = _state_scalar(dt, pts, np.ones(n), np.ones(n), pose, fit_rotation, 4.685)
    assert ok
    np.testing.assert_array_equal(samples, want_r)  # pol = 1 there: the samples themselves
    np.testing.assert_array_equal(jac, want_jac)
    ri = np.where(pol != 0.0, want_r, klm.PENALTY)
    assert abs(cost - float(np.sum(w * ri * ri))) <= 1e-13 * max(1.0, float(np.sum(w * ri * ri)))


def test_trial_cost_reports_an_unreadable_jacobian_without_failing_the_cost():
    """A NaN only the Jacobian samples reach leaves the cost finite and ok False."""
    dt = np.ones((30, 30))
    dt[10, 20] = np.nan
    pts = np.array([[10.0, 18.9], [5.0, 5.0], [6.0, 6.0], [7.0, 7.0], [8.0, 8.0]])
    for n in (4, 5):  # the vertex in the lanes, and with a tail behind it
        cost, ok = klm.trial_cost(dt, pts[:n], np.ones(n), np.ones(n), np.zeros(3), np.zeros(2),
                                  False, np.zeros(n), np.zeros((2, n)), lanes.staging_buffers())
        assert math.isfinite(cost) and not ok


def test_tiny_images_take_the_one_by_one_path():
    """A DT with a single row or column has no inside cells: lanes_for is 0."""
    for shape in [(1, 9), (9, 1), (1, 1)]:
        dt = np.arange(float(np.prod(shape))).reshape(shape)
        pts = np.column_stack([np.linspace(-1, 9, 12), np.linspace(9, -1, 12)])
        samples = np.zeros(12)
        klm.trial_cost(dt, pts, np.ones(12), np.ones(12), np.zeros(3), np.zeros(2), False,
                       samples, np.zeros((2, 12)), lanes.staging_buffers())
        np.testing.assert_array_equal(samples, sample_many(dt, pts))


@njit
def _load_strided(a):
    return load4(a, 0)


@needs_jit
def test_vector_loads_refuse_non_contiguous_arrays_at_compile_time():
    """A strided view must not be read as four consecutive elements."""
    with pytest.raises(numba.core.errors.TypingError):
        _load_strided(np.arange(16.0)[::2])


@njit
def _splat_sum(x):
    out = np.empty(4)
    store4(out, 0, splat(x) + splat(x) * splat(2.0) - splat(1.0) / splat(4.0))
    return out


@needs_jit
def test_vector_arithmetic_is_lane_wise_ieee():
    x = 0.1
    np.testing.assert_array_equal(_splat_sum(x), np.full(4, x + x * 2.0 - 1.0 / 4.0))


def _unaligned(a):
    """A C-contiguous float64 copy of ``a`` at an address that is not 8-byte aligned."""
    buf = bytearray(a.nbytes + 4)
    out = np.frombuffer(buf, dtype=np.float64, count=a.size, offset=4).reshape(a.shape)
    out[...] = a
    assert not out.flags.aligned
    return out


def test_unaligned_inputs_give_the_same_state():
    """Vector loads from unaligned views (of a byte buffer) assume no alignment."""
    rng = np.random.default_rng(5)
    dt = rng.uniform(0.0, 6.0, size=(40, 50))
    pts = rng.uniform(-2.0, 45.0, size=(37, 2))
    sig = rng.uniform(0.5, 2.0, 37)
    pol = np.ones(37)
    pose = np.array([0.3, -0.7, 0.0])
    results = []
    for d, p in ((dt, pts), (_unaligned(dt), _unaligned(pts))):
        r, w, jac = np.zeros(37), np.zeros(37), np.zeros((2, 37))
        hess, grad = np.zeros((2, 2)), np.zeros(2)
        out = klm.evaluate_state(d, p, 1.0 / (sig * sig), sig, pol, pose, np.zeros(2), False,
                                 4.685, r, w, jac, hess, grad, np.zeros(37), False,
                                 lanes.staging_buffers())
        results.append((out, r, w, jac, hess, grad))
    assert results[0][0] == results[1][0]
    for a, b in zip(results[0][1:], results[1][1:], strict=True):
        np.testing.assert_array_equal(a, b)
