"""The four-lane fast path and its plain twin give the same bits (``_kernels.lanes``).

Both paths run in this one process: the package's kernels take whichever
:data:`dtalign._kernels.lanes.VECTOR` selects (the vector code when Numba
compiles normally, the plain one under ``NUMBA_BOUNDSCHECK=1``), and
:func:`_twin_graph` compiles a second copy of the LM's call graph (without
caching) in which every name bound to a lane kernel of one path is bound to
its namesake of the other.
Every parity case of ``_parity_cases`` is then fitted both ways and every
output compared byte for byte; so are the kernels one by one, on inputs
that reach their edge cases. The vector kernels are LLVM IR: with the JIT
disabled only the plain path exists (and the whole suite runs on it).
"""

from __future__ import annotations

import inspect
import types
from typing import Any

import numba
import numpy as np
import pytest
from numba.core.registry import CPUDispatcher

import dtalign
from _parity_cases import ParityCase, build_cases, make_image
from dtalign._kernels import fit as kfit
from dtalign._kernels import lanes
from dtalign._kernels.lanes import plain, vector
from dtalign.api.checks import check_lm_inputs
from dtalign.api.options import fit_arguments

pytestmark = pytest.mark.skipif(
    numba.config.DISABLE_JIT, reason="the vector intrinsics are LLVM IR: with the JIT disabled only the plain twin runs"
)

CASES = build_cases()

#: The lane kernels of the package's path by identity, each with its twin.
_OURS, _OTHER = (vector, plain) if lanes.VECTOR else (plain, vector)
TWINS = {id(getattr(_OURS, name)): getattr(_OTHER, name) for name in lanes.__all__
         if name != "VECTOR" and callable(getattr(_OURS, name))}


def _twin_graph(dispatcher: Any, memo: dict[int, Any], swapped: set[str]) -> Any:
    """``dispatcher`` compiled again, uncached, with the twin in place of every
    lane kernel it reaches; the dispatcher itself if it reaches none."""
    if id(dispatcher) in memo:
        return memo[id(dispatcher)]
    fn = dispatcher.py_func
    swaps = {}
    for name in fn.__code__.co_names:
        value = fn.__globals__.get(name)
        if id(value) in TWINS:
            swaps[name] = TWINS[id(value)]
            swapped.add(name)
        elif isinstance(value, CPUDispatcher) and value.py_func.__module__.startswith("dtalign._kernels"):
            copy = _twin_graph(value, memo, swapped)
            if copy is not value:
                swaps[name] = copy
    result = dispatcher
    if swaps:
        clone = types.FunctionType(fn.__code__, {**fn.__globals__, **swaps}, fn.__name__,
                                   fn.__defaults__, fn.__closure__)
        options = {k: v for k, v in dispatcher.targetoptions.items() if k != "nopython"}
        result = numba.njit(**options)(clone)
    memo[id(dispatcher)] = result
    return result


@pytest.fixture(scope="module")
def twin_fit() -> Any:
    """The compiled fit on the path the package does not take."""
    swapped: set[str] = set()
    fit = _twin_graph(kfit.fit, {}, swapped)
    # every lane kernel the fit calls was replaced (a miss would compare a path with itself)
    assert swapped == {"sample_state", "lane_sums", "lane_cost", "summary_lanes", "polarity",
                       "staging_buffers"}
    return fit


def _same_bits(a: Any, b: Any) -> bool:
    if isinstance(a, tuple):
        return len(a) == len(b) and all(_same_bits(x, y) for x, y in zip(a, b, strict=True))
    a, b = np.asarray(a), np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def _kernel_inputs(case: ParityCase, derivatives: Any) -> tuple[Any, ...]:
    """The compiled fit's arguments for ``case`` (seeded by the coarse search)."""
    _, dt, grad = derivatives.get(make_image(case.image), case.image.noise_sigma)
    mask = dtalign.build_polyline_mask(case.vertices, dt.shape)
    coarse = dtalign.coarse_ncc_search(dt <= 0.5, mask, case.window)
    kw = dict(vertices_vu=case.vertices, normals_vu=case.normals,
              sigma_normal_per_vertex_px=case.sigmas, image_edge_dt=dt, image_gradient_vu=grad,
              initial_offset_vu=(coarse[0] + case.jitter[0], coarse[1] + case.jitter[1]),
              **case.lm_kwargs)
    bound = inspect.signature(dtalign.lm_subpixel_refine).bind(**kw)
    bound.apply_defaults()
    a = check_lm_inputs(dict(bound.arguments))
    return fit_arguments(a)


def test_every_parity_case_fits_to_the_same_bits_on_both_paths(twin_fit: Any, derivatives: Any) -> None:
    families = set()
    for case in CASES:
        args = _kernel_inputs(case, derivatives)
        assert _same_bits(kfit.fit(*args), twin_fit(*args)), case.case_id
        families.add(case.family)
    assert len(CASES) > 100 and len(families) >= 10  # the whole sweep, every family


def _state_inputs(rng: np.random.Generator, n: int, shape: tuple[int, int]):
    """A DT with zeros, vertices inside, on grid lines and outside, some rejected."""
    dt = rng.uniform(0.0, 8.0, size=shape)
    dt[rng.random(shape) < 0.02] = 0.0
    pts = rng.uniform(-3.0, max(shape) + 3.0, size=(n, 2))
    grid = rng.random(n) < 0.15
    pts[grid] = np.floor(pts[grid])
    pol = (rng.random(n) < 0.8).astype(float)
    sig = rng.uniform(0.3, 3.0, n)
    return dt, pts, pol, sig


@pytest.mark.parametrize("shape", [(1, 7), (2, 2), (5, 1), (37, 41)])
@pytest.mark.parametrize("fit_rotation", [False, True])
@pytest.mark.parametrize("n", [0, 1, 4, 7, 33, 130])
def test_lane_kernels_match_their_twins(shape: tuple[int, int], fit_rotation: bool, n: int) -> None:
    rng = np.random.default_rng(n + 7 * shape[0] + fit_rotation)
    p = 3 if fit_rotation else 2
    dt, pts, pol, sig = _state_inputs(rng, n, shape)
    pose = np.array([0.4, -0.3, 0.05 if fit_rotation else 0.0])
    pivot = np.array([2.0, 3.5])
    n4 = n - n % 4
    out = {}
    for twin in (vector, plain):
        samples, jac = np.full(n, -1.0), np.full((p, n), -1.0)
        ok = twin.sample_state(dt, pts, pose, pivot, fit_rotation, samples, jac, twin.staging_buffers())
        r, w = np.full(n, -1.0), np.full(n, -1.0)
        sums = twin.lane_sums(samples, pol, jac, 1.0 / (sig * sig), sig, r, w, 4.685, n4)
        cost = twin.lane_cost(pol, w, samples, n4)
        summary = twin.summary_lanes(r, w, n4)
        out[twin.__name__] = (ok, samples, jac, sums, r, w, cost, summary)
    assert _same_bits(out[vector.__name__], out[plain.__name__])


def test_lane_kernels_read_non_finite_values_alike() -> None:
    rng = np.random.default_rng(1)
    dt = rng.uniform(0.0, 5.0, size=(20, 20))
    dt[3, 4], dt[10, 10], dt[19, 19] = np.nan, np.inf, -np.inf
    for _ in range(40):
        pts = rng.uniform(-2.0, 22.0, size=(int(rng.integers(0, 40)), 2))
        n = pts.shape[0]
        res = []
        for twin in (vector, plain):
            samples, jac = np.zeros(n), np.zeros((3, n))
            ok = twin.sample_state(dt, pts, np.array([0.1, 0.2, 0.01]), np.zeros(2), True,
                                   samples, jac, twin.staging_buffers())
            res.append((ok, samples, jac))
        assert _same_bits(res[0], res[1])


def test_polarity_twins_agree() -> None:
    rng = np.random.default_rng(2)
    for trial in range(200):
        h, w = (int(x) for x in rng.integers(1, 25, 2))
        grad = rng.normal(size=(h, w, 2))
        if trial % 5 == 0:
            grad[rng.integers(h), rng.integers(w), rng.integers(2)] = np.nan
        n = int(rng.integers(0, 30))
        pts = rng.uniform(-3.0, max(h, w) + 3.0, size=(n, 2))
        pts[rng.random((n, 2)) < 0.3] = 2.5  # rint ties
        nrm = rng.normal(size=(n, 2))
        dv, du = (float(x) for x in rng.uniform(-2.0, 2.0, 2))
        (fast, fast_bad), (slow, slow_bad) = (t.polarity(pts, nrm, grad, dv, du) for t in (vector, plain))
        assert fast_bad == slow_bad
        if not fast_bad:  # on a bad read the flags are incomplete, and unused
            assert _same_bits(fast, slow)


def test_mask_scan_twins_agree() -> None:
    rng = np.random.default_rng(3)
    for _ in range(300):
        n = int(rng.integers(1, 600))
        flat = (rng.random(n) < rng.choice([0.0, 0.01, 0.3, 1.0])).astype(np.uint8)
        words = flat[: n // 8 * 8].view(np.uint64)
        start = int(rng.integers(0, n + 1))
        stop = int(rng.integers(start, n + 1))
        cap = int(rng.integers(0, n + 2))
        outs = [np.full(cap, -1, np.int64) for _ in range(2)]
        counts = [t.fill(flat, words, start, stop, o, 3) for t, o in zip((vector, plain), outs, strict=True)]
        assert counts[0] == counts[1]
        np.testing.assert_array_equal(outs[0], outs[1])
