"""Numeric parameters outside a bounded range are refused up front.

Before, these ended in Numba's internals after a compile (``max_iterations``
beyond int64, ridge profiles of 10^300 samples: TypingError), in a
MemoryError (``sample_step_px=1e-9``), or ran for minutes (a Gaussian sigma
of 10^6 px). Each must now be a ValueError naming the argument, raised
before any kernel runs, and the largest accepted value must still work.
"""

from __future__ import annotations

import numpy as np
import pytest

import dtalign
from dtalign import reference

#: The documented limits (docs/ranges.rst), spelled out so this file runs
#: against a version without them.
MAX_ITERATIONS = 2**63 - 1
MAX_RIDGE_PROFILE_SAMPLES = 10_001

V = np.array([[5.0, 5.0], [5.0, 9.0], [9.0, 5.0], [9.0, 9.0]])
N = np.tile([1.0, 0.0], (4, 1))
S = np.ones(4)
DT = np.add.outer(np.arange(16.0), np.zeros(16)) % 3.0
MAG = np.ones((16, 16))

MODULES = [pytest.param(dtalign, id="dtalign"), pytest.param(reference, id="reference")]


def _lm(module, **kw):
    return module.lm_subpixel_refine(
        vertices_vu=V, normals_vu=N, sigma_normal_per_vertex_px=S, image_edge_dt=DT,
        initial_offset_vu=(0.0, 0.0), use_polarity=False, **kw,
    )


def _ridge(module, **kw):
    return module.gradient_ridge_refine(
        vertices_vu=V, normals_vu=N, sigma_normal_per_vertex_px=S, gradient_magnitude=MAG,
        initial_offset_vu=(0.0, 0.0), **kw,
    )


@pytest.mark.parametrize("module", MODULES)
@pytest.mark.parametrize("value", [2**63, 2**64, 10**30])
@pytest.mark.parametrize("fit", [_lm, _ridge], ids=["lm", "ridge"])
def test_max_iterations_beyond_int64_is_refused(module, fit, value):
    with pytest.raises(ValueError, match=r"max_iterations must be at most 2\*\*63 - 1"):
        fit(module, max_iterations=value)


@pytest.mark.parametrize("fit", [_lm, _ridge], ids=["lm", "ridge"])
def test_max_iterations_at_the_int64_limit_is_accepted(fit):
    # The fits stop on their own long before the cap (convergence, damping).
    fit(dtalign, max_iterations=MAX_ITERATIONS)
    fit(dtalign, max_iterations=np.int64(MAX_ITERATIONS))


@pytest.mark.parametrize("module", MODULES)
@pytest.mark.parametrize(
    "kw",
    [
        {"sample_step_px": 1e-300},
        {"half_width_px": 1e300},
        {"sample_step_px": 1e-9},
        {"half_width_px": 1e300, "sample_step_px": 1e-300},  # ratio overflows to inf
        {"half_width_px": 2500.5, "sample_step_px": 0.5},  # 10,003 samples: one step over
    ],
)
def test_ridge_profile_too_long_is_refused(module, kw):
    with pytest.raises(ValueError, match=r"half_width_px / sample_step_px must round to at most 5000"):
        _ridge(module, **kw)


def test_documented_limits_are_the_checked_ones():
    from dtalign.api import checks as _validation

    assert _validation.MAX_ITERATIONS == MAX_ITERATIONS
    assert _validation.MAX_RIDGE_PROFILE_SAMPLES == MAX_RIDGE_PROFILE_SAMPLES


def test_ridge_profile_at_the_cap_is_accepted():
    assert MAX_RIDGE_PROFILE_SAMPLES == 2 * round(2500.0 / 0.5) + 1
    _ridge(dtalign, half_width_px=2500.0, sample_step_px=0.5, max_iterations=1)
    _ridge(reference, half_width_px=2500.0, sample_step_px=0.5, max_iterations=1)


def test_ridge_existing_checks_come_first():
    with pytest.raises(ValueError, match="sample_step_px must be a finite positive number"):
        _ridge(dtalign, sample_step_px=0.0)
    with pytest.raises(ValueError, match="must round to at least 1"):
        _ridge(dtalign, half_width_px=0.1, sample_step_px=1.0)


@pytest.mark.parametrize("module", MODULES)
@pytest.mark.parametrize("shape, sigma", [((2, 2), 1e6), ((8, 8), 33.0), ((40, 10), 40.5), ((1, 300), 1e300)])
def test_smoothing_sigma_wider_than_the_image_is_refused(module, shape, sigma):
    image = np.ones(shape)
    with pytest.raises(ValueError, match=r"^sigma_px must be at most the image's longer side"):
        module.compute_image_gradient_vu(image, sigma_px=sigma)
    cfg = dtalign.ImageDerivativesConfig(image_gradient_sigma_px=sigma)
    for fn in (module.compute_all_image_derivatives, module.build_image_edge_dt):
        with pytest.raises(ValueError, match=r"^config\.image_gradient_sigma_px must be at most"):
            fn(image, 1.0, config=cfg)


@pytest.mark.parametrize("shape, sigma", [((1, 1), 1.2), ((2, 2), 32.0), ((40, 10), 40.0), ((1, 300), 50.0)])
def test_smoothing_sigma_within_the_cap_matches_the_reference(shape, sigma):
    image = np.arange(float(np.prod(shape))).reshape(shape) % 7.0
    np.testing.assert_array_equal(
        dtalign.compute_image_gradient_vu(image, sigma_px=sigma),
        reference.compute_image_gradient_vu(image, sigma_px=sigma),
    )


def test_spec_sigma_message_still_comes_first():
    with pytest.raises(ValueError, match="sigma_px must be a finite positive number"):
        dtalign.compute_image_gradient_vu(np.ones((2, 2)), sigma_px=np.inf)
    with pytest.raises(TypeError, match="image_ext must be 2-D"):
        dtalign.compute_image_gradient_vu(np.ones(3), sigma_px=1e6)
