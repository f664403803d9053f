"""The fit options: one record, the only place each option is named.

:class:`FitOptions` holds every option of the one-call fit, the batch, the
command line and the campaign besides the search window: the LM's, the
ridge polish's, the polarity test's, the multi-start and ambiguity
examination's, and the edge profile's. Each field has its default and its
doc here, and its check where the fit runs it (:func:`resolve` and
:func:`dtalign.pipeline.jobs.plan`, in the order that fixes which error a bad
call raises). The public functions take a record (``options=``), keywords
(``trust_region_px=1.0``), or both (the keywords replace the record's
fields); :func:`resolve` turns them into one record, once per call.

The LM's fields (``group="lm"`` in their metadata) are exactly the keywords
of :func:`dtalign.lm_subpixel_refine` and reach it, and its compiled twin
:class:`dtalign.api.options.LMKernelOptions`, by name: a new LM option is a
field here and a field of the kernel's record, nowhere else.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from ..api import checks as check
from ..api.constants import (
    DEFAULT_LM_DAMPING,
    DEFAULT_LM_MAX_ITERATIONS,
    DEFAULT_LM_STEP_TOLERANCE,
    DEFAULT_PINVH_RCOND,
    DEFAULT_TUKEY_C,
)

__all__ = ["DEFAULT_SEARCH_WINDOW_VU", "DEFAULT_SEEDS", "FitOptions", "resolve"]

#: The pipeline's coarse-search margin when a call gives none, px per axis:
#: wide enough for the pointing errors the navigation frames show (the
#: disc demo's offset is ~9 px), small enough that a 1024 x 1024 frame's
#: search stays a small part of the fit. The command line's ``--window``
#: default is the same value. The window is each call's own argument, not a
#: field of :class:`FitOptions`: every public fit names it.
DEFAULT_SEARCH_WINDOW_VU: tuple[int, int] = (30, 30)

#: How many starts the one-call pipeline fits by default: 1, the coarse
#: search's seed (multi-start is opt-in: ``seeds=3``).
DEFAULT_SEEDS = 1

_LM = {"group": "lm"}


@dataclass(frozen=True)
class FitOptions:
    """Every option of a pipeline fit but the search window, with its default.

    Pass one to :func:`~dtalign.pipeline.fit_polyline`,
    :func:`~dtalign.pipeline.fit_polyline_products`,
    :func:`~dtalign.pipeline.batch.fit_many` or
    :func:`~dtalign.pipeline.batch.fit_images` as ``options=``, or give its
    fields as keywords (they replace the record's). Values are checked when
    a fit runs, with messages naming the field.

    Attributes
    ----------
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
    edge_profile : EdgeProfile or None
        The predicted brightness across each vertex
        (:func:`dtalign.sphere_edge_profile` for a sphere's limb or
        terminator): after the DT-LM lock the offset is refined against the
        image's pixels with it (:mod:`dtalign.pipeline.profile_fit`). One
        polyline's own: the batch takes it from each polyline instead.
    """

    fit_rotation: bool = False
    pivot_vu: tuple[float, float] | None = None
    pivot_distance_px: float | None = None
    use_polarity: bool = field(default=True, metadata=_LM)
    trust_region_px: float | None = field(default=None, metadata=_LM)
    tikhonov_alpha: float = field(default=0.0, metadata=_LM)
    final_gradient_ridge: bool = field(default=False, metadata=_LM)
    initial_rotation_rad: float = field(default=0.0, metadata=_LM)
    max_iterations: int = field(default=DEFAULT_LM_MAX_ITERATIONS, metadata=_LM)
    damping: float = field(default=DEFAULT_LM_DAMPING, metadata=_LM)
    step_tolerance_px: float = field(default=DEFAULT_LM_STEP_TOLERANCE, metadata=_LM)
    tukey_c: float = field(default=DEFAULT_TUKEY_C, metadata=_LM)
    pinvh_rcond: float = field(default=DEFAULT_PINVH_RCOND, metadata=_LM)
    seeds: int = DEFAULT_SEEDS
    ambiguity: bool = True
    edge_profile: Any = field(default=None, repr=False)

    def lm_keywords(self) -> dict[str, Any]:
        """The LM's options as :func:`dtalign.lm_subpixel_refine` keywords."""
        return {f.name: getattr(self, f.name) for f in _LM_FIELDS}

    @property
    def examined(self) -> bool:
        """Whether a fit is examined against rival basins (or multi-started)."""
        return bool(self.ambiguity) or self.seeds > 1


_LM_FIELDS = tuple(f for f in dataclasses.fields(FitOptions) if f.metadata.get("group") == "lm")

#: Every option's name (what the public functions accept as keywords).
NAMES = frozenset(f.name for f in dataclasses.fields(FitOptions))


def resolve(options: Any = None, overrides: dict[str, Any] | None = None, *,
            profile: bool = True) -> FitOptions:
    """The options of one call: ``options`` (a :class:`FitOptions`, or None for
    the defaults) with ``overrides`` (keywords) in place of its fields.

    Checks the names and ``seeds`` (the first option a fit checks); the
    other values are checked by :func:`dtalign.pipeline.jobs.plan` in the
    fit's order. ``profile=False`` (the batch: each polyline brings its own
    profile) refuses ``edge_profile``.
    """
    if options is None:
        options = _DEFAULTS
    elif not isinstance(options, FitOptions):
        raise TypeError(f"options must be a FitOptions, got {type(options).__name__}")
    if overrides:
        accepted = NAMES if profile else NAMES - {"edge_profile"}
        unknown = sorted(set(overrides) - accepted)
        if unknown:
            raise TypeError(
                f"unexpected fit option(s) {', '.join(map(repr, unknown))}; "
                f"accepted: {', '.join(sorted(accepted))}"
            )
        options = dataclasses.replace(options, **overrides)
    if not profile and options.edge_profile is not None:
        raise TypeError("options.edge_profile is one polyline's: give each polyline its own "
                        "(an edge_profile attribute, or a 4th item)")
    seeds = check.check_seeds(options.seeds)
    if type(options.seeds) is not int:  # a NumPy integer: one type from here on
        options = dataclasses.replace(options, seeds=seeds)
    return options


_DEFAULTS = FitOptions()
