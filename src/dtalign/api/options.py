"""The one record of LM / ridge options the compiled fits take, built in one place.

``dtalign._kernels.fit.fit``, ``fit_with_mask`` and the pipeline's loop
``dtalign._kernels.pipeline.fit_polylines`` take arrays plus one
``LMKernelOptions``. Numba passes a named tuple of scalars as one argument
(one specialisation for its field types, cached like any other), so the
options are not a list of positional arguments kept in step by hand at
every call site. ``lm_kernel_options`` builds the record from
``lm_subpixel_refine``'s checked arguments (``dtalign.api.checks.LMArgs``);
``fit_arguments`` the whole argument tuple of the compiled fit. Every field
is converted to one Python type (bool, int or float), so every caller
reaches the same compiled specialisation, and the same bits.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .checks import FloatArray, LMArgs
from .constants import (
    DEFAULT_LM_STEP_TOLERANCE,
    DEFAULT_RIDGE_HALF_WIDTH_PX,
    DEFAULT_RIDGE_MAX_ITERATIONS,
    DEFAULT_RIDGE_MAX_TOTAL_DISPLACEMENT_PX,
    DEFAULT_RIDGE_SAMPLE_STEP_PX,
)
from .image import _use_libm_hypot

__all__ = ["NO_GRADIENT", "RIDGE_HALF", "LMKernelOptions", "fit_arguments", "gradient_of",
           "lm_kernel_options"]

#: The ridge polish inside LM runs with its defaults (:ref:`contract-lm`):
#: this many profile samples on each side of a vertex.
RIDGE_HALF = round(DEFAULT_RIDGE_HALF_WIDTH_PX / DEFAULT_RIDGE_SAMPLE_STEP_PX)
#: Stand-in gradient when none is given (never read: polarity and ridge are off).
NO_GRADIENT = np.zeros((1, 1, 2))


class LMKernelOptions(NamedTuple):
    """The scalar options of one LM fit, as the kernels read them."""

    #: Fix the seed polarity mask from the gradient (``fit`` and the pipeline's loop).
    use_polarity: bool
    #: Fit the rotation too (three parameters instead of two).
    fit_rotation: bool
    max_iterations: int
    damping: float
    step_tolerance: float
    tukey_c: float
    #: The pseudoinverse cutoff of the covariance (``pinvh_rcond``).
    rcond: float
    #: ``trust_region_px``, or -1.0 for none.
    trust_region: float
    tikhonov_alpha: float
    #: Run the gradient-ridge polish after the LM (``final_gradient_ridge``).
    ridge: bool
    ridge_half: int
    ridge_sample_step: float
    ridge_max_iterations: int
    ridge_step_tolerance: float
    ridge_max_displacement: float
    #: Magnitudes through libm's ``hypot`` (see ``dtalign.api.image``).
    use_libm: bool


def lm_kernel_options(a: LMArgs, ridge: bool | None = None) -> LMKernelOptions:
    """The options record of checked arguments ``a``; ``ridge`` overrides
    ``a.final_gradient_ridge`` (the LM before a caller's ridge stage, :ref:`contract-lm`)."""
    return LMKernelOptions(
        use_polarity=bool(a.use_polarity),
        fit_rotation=bool(a.fit_rotation),
        max_iterations=int(a.max_iterations),
        damping=float(a.damping),
        step_tolerance=float(a.step_tolerance),
        tukey_c=float(a.tukey_c),
        rcond=float(a.pinvh_rcond),
        trust_region=-1.0 if a.trust_region_px is None else float(a.trust_region_px),
        tikhonov_alpha=float(a.tikhonov_alpha),
        ridge=bool(a.final_gradient_ridge if ridge is None else ridge),
        ridge_half=int(RIDGE_HALF),
        ridge_sample_step=float(DEFAULT_RIDGE_SAMPLE_STEP_PX),
        ridge_max_iterations=int(DEFAULT_RIDGE_MAX_ITERATIONS),
        ridge_step_tolerance=float(DEFAULT_LM_STEP_TOLERANCE),
        ridge_max_displacement=float(DEFAULT_RIDGE_MAX_TOTAL_DISPLACEMENT_PX),
        use_libm=bool(_use_libm_hypot()),
    )


def gradient_of(a: LMArgs) -> FloatArray:
    """The gradient the kernels take: the caller's, or :data:`NO_GRADIENT`."""
    return a.gradient if a.gradient is not None else NO_GRADIENT


#: :func:`fit_arguments`' tuple: dt, gradient, vertices, normals, sigmas,
#: initial pose, pivot, pivot distance, options.
FitArguments = tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray,
                     FloatArray, float, LMKernelOptions]


def fit_arguments(a: LMArgs, ridge: bool | None = None) -> FitArguments:
    """The arguments of :func:`dtalign._kernels.fit.fit` for checked arguments
    ``a`` (``fit_with_mask`` takes the same, then the polarity mask)."""
    return (
        a.dt, gradient_of(a), a.vertices, a.normals, a.sigmas,
        np.array([a.offset[0], a.offset[1], a.rotation]), np.array(a.pivot),
        float(a.pivot_distance), lm_kernel_options(a, ridge),
    )
