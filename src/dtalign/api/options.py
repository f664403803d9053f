"""The fit options: the public record, and the compiled fits' twin of it.

:class:`FitOptions` holds every option of one call of the one-call fit,
the batch, the command line and the campaign: the search window, the
LM's, the ridge polish's, the polarity test's, the multi-start and
ambiguity examination's. What belongs to one polyline (its arrays, its
kind of edge, its edge profile) is the :class:`~dtalign.Polyline`'s.
Each field has its default and its doc here, and its check where the fit
runs it (:func:`resolve` and :func:`dtalign.pipeline.jobs.check_options`,
once per call, in the order that fixes which error a bad call raises). The public functions take
a record (``options=``), keywords (``trust_region_px=1.0``), or both (the
keywords replace the record's fields); :func:`resolve` turns them into one
record, once per call.

The LM's fields (``group="lm"`` in their metadata) are exactly the keywords
of :func:`dtalign.lm_subpixel_refine`.

The compiled twin
-----------------

``dtalign._kernels.fit.fit``, ``fit_with_mask`` and the pipeline's loop
``dtalign._kernels.pipeline.fit_polylines`` take arrays plus one
``LMKernelOptions``, whose fields have the LM keywords' names. Numba
passes a named tuple of scalars as one argument (one specialisation for its
field types, cached like any other), so the options are not a list of
positional arguments kept in step by hand at every call site.
``lm_kernel_options`` builds the record from ``lm_subpixel_refine``'s
checked arguments (``dtalign.api.checks.LMArgs``), once per call;
``fit_arguments`` the whole argument tuple of the compiled fit. Every
field is converted to one Python type (bool, int or float), so every caller
reaches the same compiled specialisation, and the same bits.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from .._kernels.params import n_params
from . import checks as check
from . import constants as c
from .checks import FloatArray, LMArgs
from .image import _use_libm_hypot

__all__ = ["DEFAULT_SEARCH_WINDOW_VU", "DEFAULT_SEEDS", "NO_GRADIENT", "RIDGE_HALF",
           "FitOptions", "LMKernelOptions", "fit_arguments", "gradient_of", "lm_kernel_options",
           "n_params", "resolve"]

DEFAULT_SEARCH_WINDOW_VU = c.DEFAULT_SEARCH_WINDOW_VU

#: How many starts the one-call pipeline fits by default: 1, the coarse
#: search's seed (multi-start is opt-in: ``seeds=3``).
DEFAULT_SEEDS = 1

_LM = {"group": "lm"}


@dataclass(frozen=True)
class FitOptions:
    """Every option of a pipeline fit, with its default.

    Pass one to :func:`~dtalign.pipeline.fit_polyline`,
    :func:`~dtalign.pipeline.fit_polyline_products`,
    :func:`~dtalign.pipeline.batch.fit_many` or
    :func:`~dtalign.pipeline.batch.fit_images` as ``options=``, or give its
    fields as keywords (they replace the record's). Values are checked when
    a fit runs, with messages naming the field.

    Attributes
    ----------
    search_window_vu : tuple of int
        Coarse-search margin ``(mv, mu)``: every integer shift in
        ``[-mv, mv] x [-mu, mu]`` is scored. Default
        :data:`~dtalign.pipeline.DEFAULT_SEARCH_WINDOW_VU`, ``(30, 30)`` (the command line's
        ``--window`` too).
    fit_rotation : bool
        Also fit an in-plane rotation about ``pivot_vu``.
    pivot_vu : tuple of float or None
        Rotation pivot; the vertex centroid when None.
    pivot_distance_px : float or None
        Scales the rotation step into pixels for the convergence test.
        When None and ``fit_rotation`` is True: the distance from the
        pivot to the image centre ``((H-1)/2, (W-1)/2)``, floored at 1.
    use_polarity : bool
        Reject vertices whose normal points down the gradient (and seed
        with the polarity-weighted search).
    trust_region_px : float or None
        Refuse LM steps farther than this from the coarse seed (1.0 is the
        production setting); no limit when None.
    tikhonov_alpha : float
        Pull toward the coarse seed (0 disables it).
    final_gradient_ridge : bool
        Run the gradient-ridge polish after the LM.
    initial_rotation_rad, max_iterations, damping, step_tolerance_px, tukey_c, pinvh_rcond
        Passed to :func:`dtalign.lm_subpixel_refine` unchanged (defaults:
        its own).
    seeds : int
        Starts of a multi-start fit (:mod:`dtalign.pipeline.hypotheses`):
        the LM runs from the ``seeds`` best distinct coarse peaks and from
        the competing basin of the DT cost, and the cheapest pose on a
        common footing wins. 1 (the default) keeps the single start's pose.
    ambiguity : bool
        Examine the fit against its best rival basin (the second coarse
        peak and the competing basin, each fitted): the result's
        ``ambiguity`` and ``hypotheses``, and the status ``ambiguous`` when
        a rival across the edge costs nearly as little. It costs a few LM
        fits; False skips it.
    edge_kind : str or None
        What kind of edge the call's polylines are when a polyline does not
        say (:attr:`Polyline.edge_kind <dtalign.Polyline>`, or its edge
        profile's ``edge``), one of :data:`dtalign.api.profiles.EDGE_KINDS`
        (``"limb"``, ``"terminator"``, ``"ring"``, ``"other"``); None: not
        declared. A polyline's profile of another kind is a ValueError. A ``"terminator"`` fitted
        without a profile carries the reason
        :attr:`~dtalign.pipeline.status.FitReason.TERMINATOR_WITHOUT_PROFILE`:
        the DT puts a Lambert terminator wherever the brightness ramp
        crosses the edge threshold (:ref:`profiles-terminator`).
    """

    search_window_vu: tuple[int, int] = DEFAULT_SEARCH_WINDOW_VU
    fit_rotation: bool = False
    pivot_vu: tuple[float, float] | None = None
    pivot_distance_px: float | None = None
    use_polarity: bool = field(default=True, metadata=_LM)
    trust_region_px: float | None = field(default=None, metadata=_LM)
    tikhonov_alpha: float = field(default=0.0, metadata=_LM)
    final_gradient_ridge: bool = field(default=False, metadata=_LM)
    initial_rotation_rad: float = field(default=0.0, metadata=_LM)
    max_iterations: int = field(default=c.DEFAULT_LM_MAX_ITERATIONS, metadata=_LM)
    damping: float = field(default=c.DEFAULT_LM_DAMPING, metadata=_LM)
    step_tolerance_px: float = field(default=c.DEFAULT_LM_STEP_TOLERANCE, metadata=_LM)
    tukey_c: float = field(default=c.DEFAULT_TUKEY_C, metadata=_LM)
    pinvh_rcond: float = field(default=c.DEFAULT_PINVH_RCOND, metadata=_LM)
    seeds: int = DEFAULT_SEEDS
    ambiguity: bool = True
    edge_kind: str | None = None

    def lm_keywords(self) -> dict[str, Any]:
        """The LM's options as :func:`dtalign.lm_subpixel_refine` keywords."""
        return {f.name: getattr(self, f.name) for f in _LM_FIELDS}

    @property
    def n_params(self) -> int:
        """The pose parameters fitted: 2 (``dv``, ``du``), 3 with the rotation."""
        return int(n_params(self.fit_rotation))

    @property
    def examined(self) -> bool:
        """Whether a fit is examined against rival basins (or multi-started)."""
        return bool(self.ambiguity) or self.seeds > 1


_LM_FIELDS = tuple(f for f in dataclasses.fields(FitOptions) if f.metadata.get("group") == "lm")

#: Every option's name (what the public functions accept as keywords).
NAMES = frozenset(f.name for f in dataclasses.fields(FitOptions))


def resolve(options: Any = None, overrides: dict[str, Any] | None = None) -> FitOptions:
    """The options of one call: ``options`` (a :class:`FitOptions`, or None for
    the defaults) with ``overrides`` (keywords) in place of its fields.

    Checks the names and ``seeds`` (the first option a fit checks); the
    other values are checked by :func:`dtalign.pipeline.jobs.check_options`
    in the fit's order.
    """
    if options is None:
        options = _DEFAULTS
    elif not isinstance(options, FitOptions):
        raise TypeError(f"options must be a FitOptions, got {type(options).__name__}")
    if overrides:
        unknown = sorted(set(overrides) - NAMES)
        if unknown:
            raise TypeError(
                f"unexpected fit option(s) {', '.join(map(repr, unknown))}; "
                f"accepted: {', '.join(sorted(NAMES))}"
            )
        options = dataclasses.replace(options, **overrides)
    seeds = check.check_seeds(options.seeds)
    if type(options.seeds) is not int:  # a NumPy integer: one type from here on
        options = dataclasses.replace(options, seeds=seeds)
    return options


_DEFAULTS = FitOptions()

#: The ridge polish inside LM runs with its defaults (:ref:`contract-lm`):
#: this many profile samples on each side of a vertex.
RIDGE_HALF = round(c.DEFAULT_RIDGE_HALF_WIDTH_PX / c.DEFAULT_RIDGE_SAMPLE_STEP_PX)
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
    step_tolerance_px: float
    tukey_c: float
    #: The pseudoinverse cutoff of the covariance.
    pinvh_rcond: float
    #: The trust region, or -1.0 for none.
    trust_region_px: float
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
        step_tolerance_px=float(a.step_tolerance),
        tukey_c=float(a.tukey_c),
        pinvh_rcond=float(a.pinvh_rcond),
        trust_region_px=-1.0 if a.trust_region_px is None else float(a.trust_region_px),
        tikhonov_alpha=float(a.tikhonov_alpha),
        ridge=bool(a.final_gradient_ridge if ridge is None else ridge),
        ridge_half=int(RIDGE_HALF),
        ridge_sample_step=float(c.DEFAULT_RIDGE_SAMPLE_STEP_PX),
        ridge_max_iterations=int(c.DEFAULT_RIDGE_MAX_ITERATIONS),
        ridge_step_tolerance=float(c.DEFAULT_LM_STEP_TOLERANCE),
        ridge_max_displacement=float(c.DEFAULT_RIDGE_MAX_TOTAL_DISPLACEMENT_PX),
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
