"""A ridge polish that cycles ends, with the plain loop's answer (:ref:`contract-ridge`).

Each polish iteration is a function of the pose alone, so a pose that
comes back bit for bit repeats for ever. On the clean demo disc the polish
never meets its step tolerance: it settles into a cycle (two poses about
0.01 px apart in u, whose last digits wander for a while before they
repeat exactly). Both the compiled kernel and the reference detect the
repeat and run only the iterations that select the pose the full count
ends on; the plain loop (the reference with the detection off) is the
judge, at caps far past the cycle's start, and ``max_iterations=2**63-1``
must return at all.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

import dtalign
from dtalign import reference as ref
from dtalign import scenes
from dtalign.reference import fitting as ref_fitting

HUGE_ODD = 2**63 - 1
HUGE_EVEN = 2**63 - 2
#: Bound on the plain loop's steps searched for the cycle: the demo disc's
#: cycle starts and closes within a few hundred (the search fails loudly
#: rather than guess beyond it).
MAX_STEPS = 4000


@pytest.fixture(scope="module")
def disc():
    """Keywords of the polish on the clean demo disc, started at the truth."""
    s = scenes.disc_scene(noise_sigma=0.0)
    p = s.polyline
    magnitude, _, _ = ref.compute_all_image_derivatives(s.image, 1.0)
    return dict(
        vertices_vu=p.vertices_vu, normals_vu=p.normals_vu, sigma_normal_per_vertex_px=p.sigmas,
        gradient_magnitude=magnitude, initial_offset_vu=s.true_offset_vu,
    )


@pytest.fixture()
def plain(monkeypatch):
    """The reference polish with the cycle detection off: the loop as written
    (only inside the call: the test's own reference calls detect cycles)."""
    loop = functools.partial(ref_fitting._ridge, detect_cycles=False)

    def run(kw, max_iterations):
        with monkeypatch.context() as m:
            m.setattr(ref_fitting, "_ridge", loop)
            return ref.gradient_ridge_refine(**kw, max_iterations=max_iterations)

    return run


def _cycle(plain, kw):
    """(start, period) of the plain loop's pose sequence, one iteration at a time."""
    pose = (*kw["initial_offset_vu"], 0.0)
    seen = {pose: 0}
    for i in range(1, MAX_STEPS + 1):
        r = plain({**kw, "initial_offset_vu": pose[:2], "initial_rotation_rad": pose[2]}, 1)
        assert r.applied and r.iterations == 1 and not r.converged
        pose = (*r.offset_vu, r.rotation_rad)
        if pose in seen:
            return seen[pose], i - seen[pose]
        seen[pose] = i
    raise AssertionError(f"the plain polish did not repeat a pose within {MAX_STEPS} steps")


def _same_cap(huge, start, period):
    """The smallest cap past the cycle's start that ends where ``huge`` ends."""
    cap = start + (huge - start) % period
    return cap if cap > start + period else cap + period


def test_the_demo_disc_cycles(plain, disc):
    start, period = _cycle(plain, disc)
    assert period >= 2
    even, odd = plain(disc, 2 * start + 2 * period), plain(disc, 2 * start + 2 * period + 1)
    assert not even.converged and not odd.converged
    assert even.offset_vu != odd.offset_vu  # the count's parity selects the pose


@pytest.mark.parametrize("cap", [1000, 1001])
def test_cycle_past_detection_equals_the_plain_loop(plain, disc, cap):
    # Brent's detection has closed on the cycle well before 1000 iterations
    # (it starts a few hundred in): the kernel and the reference cut the
    # loop short, the plain loop runs it all.
    want = plain(disc, cap)
    assert want.iterations == cap and not want.converged
    assert dtalign.gradient_ridge_refine(**disc, max_iterations=cap) == want
    assert ref.gradient_ridge_refine(**disc, max_iterations=cap) == want


@pytest.mark.parametrize("huge", [HUGE_EVEN, HUGE_ODD])
def test_largest_cap_returns_the_plain_loops_pose(plain, disc, huge):
    start, period = _cycle(plain, disc)
    cap = _same_cap(huge, start, period)
    assert cap % 2 == huge % 2
    want = plain(disc, cap)
    got = dtalign.gradient_ridge_refine(**disc, max_iterations=huge)
    spec = ref.gradient_ridge_refine(**disc, max_iterations=huge)
    assert got == spec
    assert got.iterations == huge and not got.converged and got.applied
    assert (got.offset_vu, got.rotation_rad) == (want.offset_vu, want.rotation_rad)


def test_a_converging_polish_is_untouched(plain, disc):
    # A noisy disc started off the truth converges: no pose repeats before
    # the step falls below the tolerance, and nothing changes.
    s = scenes.disc_scene(noise_sigma=2.0, seed=3)
    p = s.polyline
    magnitude, _, _ = ref.compute_all_image_derivatives(s.image, s.noise_sigma)
    kw = dict(
        vertices_vu=p.vertices_vu, normals_vu=p.normals_vu, sigma_normal_per_vertex_px=p.sigmas,
        gradient_magnitude=magnitude,
        initial_offset_vu=(s.true_offset_vu[0] + 0.4, s.true_offset_vu[1] - 0.3),
        step_tolerance_px=0.05,
    )
    want = plain(kw, 50)
    assert want.converged
    assert ref.gradient_ridge_refine(**kw, max_iterations=50) == want
    # noisy samples: the kernel's parabola peaks agree to rounding, not bits
    got = dtalign.gradient_ridge_refine(**kw, max_iterations=50)
    assert (got.iterations, got.converged, got.applied) == (want.iterations, True, want.applied)
    np.testing.assert_allclose(got.offset_vu, want.offset_vu, rtol=0, atol=1e-12)


def test_fit_rotation_cycle_equals_the_plain_loop(plain, disc):
    # The rotation column is a finite difference of peak offsets whose last
    # bits differ between kernel and reference from the first iteration
    # (tests/test_parity.py holds them to a tolerance): the reference is
    # held to its plain loop bit for bit, the kernel to a tolerance.
    kw = {**disc, "fit_rotation": True, "pivot_distance_px": 150.0}
    for cap in (1000, 1001):
        want = plain(kw, cap)
        assert want.iterations == cap and not want.converged
        assert ref.gradient_ridge_refine(**kw, max_iterations=cap) == want
        got = dtalign.gradient_ridge_refine(**kw, max_iterations=cap)
        assert (got.iterations, got.converged, got.applied) == (cap, False, True)
        np.testing.assert_allclose(got.offset_vu, want.offset_vu, rtol=0, atol=1e-9)
        np.testing.assert_allclose(got.rotation_rad, want.rotation_rad, rtol=0, atol=1e-12)
