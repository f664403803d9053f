"""Whether a pipeline fit can be trusted: its status, its reasons, the log.

A :class:`~dtalign.pipeline.PolylineFit` always returns a pose, even when
nothing was measured (a polyline outside the image, normals that point the
wrong way, a noise sigma so high that no edge survives). :func:`assess`
reads from what the fit holds whether that happened and why, once per fit,
into an :class:`Assessment`: the reasons found (:class:`FitReason`, in the
order of the enum, the likeliest cause first), the worst severity among
them (:class:`FitStatus`) and one line explaining them. The fit's
``status``, ``reasons`` and ``status_message``, the command line, the log,
the campaign's store and the documentation's tables all read that.

One table, :data:`REASONS`, holds what each reason is: its severity, the
sentence the documentation prints, and the template of its message, whose
numbers :func:`assess` fills in from the fit.

:data:`logger` (``logging.getLogger("dtalign")``) reports each failed,
ambiguous or suspect fit of the pipeline, the batch functions and the
command line at ``WARNING``, a fit with only notes at ``INFO``. The drop-in
functions never log, exactly as the reference. Nothing here imports Numba.
"""

from __future__ import annotations

import enum
import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from . import measured as _m
from .measured import NO_EDGE_GAP, NO_EDGE_MIN_FRACTION, NoEdgeRun, no_edge_run, outside_mask

__all__ = [
    "NO_EDGE_GAP", "NO_EDGE_MIN_FRACTION", "REASONS", "SETTLE_ITERATIONS", "SETTLE_SIGMAS", "TERMINATOR_PLAIN_MEDIAN_PX",
    "TERMINATOR_PLAIN_P90_PX", "TERMINATOR_SIGMA_LIMIT_PX", "UNMEASURED_TEXT", "Assessment",
    "FitReason", "FitStatus", "NoEdgeRun", "Reason", "Settling", "assess", "describe", "fit_reasons",
    "fit_status", "log_fit", "log_fits", "logger", "no_edge_run", "outside_mask",
]

#: The package's logger. No handler is attached: without logging
#: configuration Python prints WARNING and above to standard error, so a
#: failed fit is never silent; applications configure it as usual.
logger = logging.getLogger("dtalign")


class _Text(str, enum.Enum):
    """An enum whose members print as their string values (``str(FitStatus.OK) == "ok"``)."""

    def __str__(self) -> str:
        return self.value


class FitStatus(_Text):
    """Overall verdict on a fit, the worst severity of its reasons; equal to its string.

    :data:`STATUS_MEANING` says what each means (the docs' status table).
    """

    OK = "ok"
    SUSPECT = "suspect"
    AMBIGUOUS = "ambiguous"
    FAILED = "failed"


class FitReason(_Text):
    """One condition found in a fit; compares equal to its string value.

    A fit lists its reasons in this order, the likeliest cause first:
    vertices outside the image measure nothing whatever their normals, and
    normals that point the wrong way make a fit degenerate and can put the
    coarse seed on the window edge, not the other way round. What each
    means is its entry of :data:`REASONS` (the docs' reasons table).
    """

    OUTSIDE_IMAGE = "outside_image"
    OUTSIDE_IMAGE_WEIGHTED = "outside_image_weighted"
    PARTLY_OUTSIDE_IMAGE = "partly_outside_image"
    ALL_POLARITY_REJECTED = "all_polarity_rejected"
    MOST_POLARITY_REJECTED = "most_polarity_rejected"
    DEGENERATE = "degenerate"
    AT_WINDOW_EDGE = "at_window_edge"
    AMBIGUOUS = "ambiguous"
    PROFILE_REJECTED = "profile_rejected"
    SOFT_EDGE = "soft_edge"
    TERMINATOR_WITHOUT_PROFILE = "terminator_without_profile"
    TERMINATOR_IMPRECISE = "terminator_imprecise"
    FLAT_PROFILE_VERTICES = "flat_profile_vertices"
    NOT_CONVERGED = "not_converged"
    AMBIGUOUS_ALONG_EDGE = "ambiguous_along_edge"
    RANK_DEFICIENT = "rank_deficient"


#: The error of plain (profile-less) fits of rendered Lambert terminators,
#: px, median and 90th percentile (:ref:`profiles-terminator`, which says
#: on which scenes): what :attr:`FitReason.TERMINATOR_WITHOUT_PROFILE` warns of.
TERMINATOR_PLAIN_MEDIAN_PX = 4.6
TERMINATOR_PLAIN_P90_PX = 13.8

#: A terminator's accepted profile refinement whose own one-sigma (the
#: square root of its covariance's largest eigenvalue) exceeds this, px, is
#: suspect (:attr:`FitReason.TERMINATOR_IMPRECISE`): an ``ok`` terminator
#: more than 1 px off is then more than three of its sigmas off, which is
#: what ``ok`` promises for a terminator (docs/profiles.rst, "A barely
#: measured terminator").
TERMINATOR_SIGMA_LIMIT_PX = 1.0 / 3.0

#: What a failed fit's printed summary and the command line show for its
#: sigmas: its covariance (``inf``, or finite from a few stray inliers) is
#: no measurement. The numeric fields (``sigma_vu``, ``to_dict``) keep their values.
UNMEASURED_TEXT = "not measured (failed)"

_OK, _SUSPECT, _AMBIGUOUS, _FAILED = FitStatus
_ORDER = (_OK, _SUSPECT, _AMBIGUOUS, _FAILED)

#: What each status tells the caller, one sentence (the docs' status table).
STATUS_MEANING: dict[FitStatus, str] = {
    _OK: "the pose is a measurement; the fit may carry notes (reasons whose status is ``ok``).",
    _SUSPECT: "the pose is a measurement that should be checked: an edge profile's refinement "
    "was discarded, a limb has no usable edge, a terminator was fitted without a profile, or "
    "vertices outside the image kept weight.",
    _AMBIGUOUS: "another basin across the edge fits the image about as well: the pose may be "
    "the wrong one of two.",
    _FAILED: "the pose is not a measurement of the image: do not use it.",
}


class Reason(NamedTuple):
    """One row of :data:`REASONS`."""

    #: The status the reason implies (a fit's status is the worst of its reasons').
    severity: FitStatus
    #: What it means and what to do: the docs' reasons table.
    meaning: str
    #: The message, a :meth:`str.format` template of the facts :func:`assess` reads.
    message: str


_HEAD = "{n_out} of {n} vertices lie outside the {h} x {w} image"

#: Every reason: its severity, its meaning, its message.
REASONS: dict[FitReason, Reason] = {
    FitReason.OUTSIDE_IMAGE: Reason(
        _FAILED, "some vertices lie outside the image (the pixel the polarity test reads, the "
        "vertex shifted by the coarse seed and rounded, is not within rows 0..H-1 and columns "
        "0..W-1) and fewer than half of those inside kept any weight: too few inside to fit. Is "
        "the polyline in this image's pixel frame, and the predicted pose within the search "
        "window of the truth?", _HEAD + "{too_few_inside}"),
    FitReason.OUTSIDE_IMAGE_WEIGHTED: Reason(
        _SUSPECT, "some vertices lie outside the image and kept weight (``use_polarity=False``: "
        "nothing rejected them): they sample the distance transform clamped to the image "
        "border, the border's distance to an edge, not theirs. Pass only the vertices inside, "
        "or keep the polarity test.",
        _HEAD + ", and {outside_inliers} of them kept weight beside the {inliers_in} inliers "
        "inside: without the polarity test they sample the distance transform clamped to the "
        "image border, the border's distance to an edge, not theirs (pass only the vertices "
        "inside, or use the polarity test)"),
    FitReason.PARTLY_OUTSIDE_IMAGE: Reason(
        _OK, "some vertices lie outside the image, but at least half of those inside kept their "
        "weight and none outside did: the pose is measured by the inside ones alone, and its "
        "sigmas and observable rank are formed from them.",
        _HEAD + ": the pose is measured by the {n_in} inside ({inliers_in} inliers), its "
        "sigmas by their geometry"),
    FitReason.ALL_POLARITY_REJECTED: Reason(
        _FAILED, "no vertex inside the image has a normal that points up the image gradient: "
        "the normals point the wrong way (flip them), or there is no gradient under the "
        "polyline at all. Comes with ``degenerate``.",
        "{all_who} polarity-rejected: the normals point the wrong way (they must point up the "
        "image gradient, toward the brighter side: flip them), or there is no gradient under "
        "the polyline ({all_where})"),
    FitReason.MOST_POLARITY_REJECTED: Reason(
        _FAILED, "more than half of the vertices inside the image see the gradient the wrong "
        "way: are the normals pointing to the bright side? (Or the polyline lies on the wrong "
        "edge, or part of a limb is unlit: the message names a contiguous stretch of vertices "
        "that find no edge.) The pose rests on the few vertices that happened to agree.",
        "{most_who} see the gradient the wrong way ({rejected_counts}): {unlit_or}{question}"),
    FitReason.DEGENERATE: Reason(
        _FAILED, "no vertex kept any weight; the pose is the coarse seed, the covariance "
        "``inf``. The polyline may be outside the image, no edge may lie near it, or the noise "
        "sigma may be so high that no edge passed the threshold.",
        "degenerate: no vertex of {n} kept any weight, the pose is the coarse seed {seed} (is "
        "the polyline inside the image? is there an edge near it? noise sigma "
        "{noise_sigma:.4g}: too high for any edge to pass?)"),
    FitReason.AT_WINDOW_EDGE: Reason(
        _FAILED, "the coarse seed is on the boundary of the search window: the true offset may "
        "lie outside it. Widen ``search_window_vu`` (``--window``).",
        "at window edge: the coarse seed {seed} is on the edge of the search window "
        "±{window}; the true offset may lie outside it: widen search_window_vu"),
    FitReason.AMBIGUOUS: Reason(
        _AMBIGUOUS, "a rival basin across the edge (another coarse peak, or the DT cost's "
        "competing basin) costs less than 1.5 times this one: two parallel edges of one "
        "polarity, a decoy edge (an accepted edge-profile refinement that reaches the same pose "
        "from the rival's start clears it; the message names a contiguous stretch of vertices "
        "that find no edge, such as a limb's unlit half). See "
        ":attr:`~dtalign.pipeline.PolylineFit.ambiguity`.", "{rival}{at_pose_unlit}"),
    FitReason.PROFILE_REJECTED: Reason(
        _SUSPECT, "an edge profile was given but its refinement was discarded (it could not be "
        "computed: too few pixels, a singular or non-finite system; or it did not converge, "
        "walked more than 2 px from the DT lock, or fitted a non-positive gain; the reason "
        "says which): the pose is the DT-LM's, with the edge DT's photometric bias (tenths of a "
        "pixel on a limb). See :attr:`~dtalign.pipeline.PolylineFit.profile`.",
        "profile refinement rejected: {profile_reason}; the pose is the DT-LM's (biased by the "
        "edge DT's photometric offset)"),
    FitReason.SOFT_EDGE: Reason(
        _SUSPECT, "the limb profile has no usable edge (its brightness rolls off to the limb, as "
        "a Lambert limb at low phase): the position rests on the modelled roll-off and on the "
        "reflectance law being right.",
        "soft edge: the profile's step at the edge is {step_jump:.2f} of its contrast (the "
        "brightness rolls off to the edge, as a limb at low phase): the position rests on the "
        "modelled roll-off and the reflectance law"),
    FitReason.TERMINATOR_WITHOUT_PROFILE: Reason(
        _SUSPECT, "the polyline is declared a terminator and was fitted without an edge "
        "profile: the DT puts a terminator (a kink in brightness, not an edge) where the ramp "
        "crosses the edge threshold: on rendered Lambert terminators the error has median "
        f"{TERMINATOR_PLAIN_MEDIAN_PX:g} px and 90th percentile {TERMINATOR_PLAIN_P90_PX:g} px. "
        "Give ``sphere_edge_profile(..., edge=\"terminator\")``. See :ref:`profiles-terminator`.",
        "terminator without a profile: the DT puts a terminator where the brightness ramp "
        "crosses the edge threshold (on rendered Lambert terminators the median error is "
        f"{TERMINATOR_PLAIN_MEDIAN_PX:g} px); fit it with "
        "sphere_edge_profile(..., edge='terminator')"),
    FitReason.TERMINATOR_IMPRECISE: Reason(
        _SUSPECT, "a terminator's profile refinement reports a one-sigma above "
        f"{TERMINATOR_SIGMA_LIMIT_PX:.2f} px along some direction: the pose is barely measured "
        "there (a terminator near phase 90 deg is nearly straight). See "
        ":attr:`~dtalign.pipeline.PolylineFit.profile`.",
        "terminator imprecise: the profile refinement's one-sigma is {profile_sigma:.3g} px "
        f"along some direction (above {TERMINATOR_SIGMA_LIMIT_PX:.2f} px): the pose is barely "
        "measured there"),
    FitReason.FLAT_PROFILE_VERTICES: Reason(
        _OK, "some of a limb's vertices have edge profiles with no contrast across their strips "
        "(an unlit part of the limb): they were left out of the profile refinement, which "
        "fitted the others. Pass the sunlit part of a limb.",
        "{n_flat} of {n_model} vertices' profiles have no contrast (an unlit part of a limb?): "
        "left out of the profile refinement"),
    FitReason.NOT_CONVERGED: Reason(
        _OK, "the pose has not settled: the LM stopped before its step tolerance and its pose "
        "still moved more than 0.25 sigma over its last 5 iterations. Raise "
        "``max_iterations``. See `Converged, settled, and the iteration cap`_.",
        "not converged: {moved} (raise max_iterations)"),
    FitReason.AMBIGUOUS_ALONG_EDGE: Reason(
        _OK, "the rival basin lies along a direction the fit cannot observe (a straight edge's "
        "along-edge shift): ambiguous along the edge, which its ``inf`` sigma there already "
        "says, not across it.", "{rival}"),
    FitReason.RANK_DEFICIENT: Reason(
        _OK, "the geometry leaves a pose direction unmeasured (a straight edge: the along-edge "
        "shift; a circle: its rotation). The sigmas along it are ``inf``.",
        "rank deficient: observable rank {rank} of {n_params}; the pose is not measured along "
        "{null_directions}{inf_there}"),
}

#: Views of :data:`REASONS`: each reason's severity, and its meaning.
SEVERITY = {r: row.severity for r, row in REASONS.items()}
REASON_MEANING = {r: row.meaning for r, row in REASONS.items()}


#: Iterations over which an unconverged LM's pose movement is judged: enough
#: to span a few of the damping's rejected steps (which count as
#: iterations), few enough that a fit stopped early still shows its descent.
SETTLE_ITERATIONS = 5

#: An unconverged pose has settled when its movement over the last
#: :data:`SETTLE_ITERATIONS` iterations is at most this many of its own
#: one-sigma (the Mahalanobis length under the fit's covariance): further
#: iterations could then move it by a small fraction of its uncertainty.
#: (docs/status.rst, "Converged, settled, and the iteration cap", says
#: what the fits measured moved.)
SETTLE_SIGMAS = 0.25


@dataclass(frozen=True)
class Settling:
    """How far an unconverged LM's pose moved over its last iterations.

    Made by the pipeline (:func:`dtalign.pipeline.fit.settle`) for a fit
    whose LM stopped before an accepted step fell below
    ``step_tolerance_px``: the LM is run again from the same start for
    ``iterations - SETTLE_ITERATIONS`` iterations (the same deterministic
    path, stopped earlier), and the two poses are compared. With fewer
    iterations than that, the start itself is the earlier pose.

    Attributes
    ----------
    iterations : int
        The iterations the movement spans (``SETTLE_ITERATIONS``, or all of
        them when the LM ran fewer).
    shift_px : float
        The translation's movement plus the rotation's times the pivot
        distance, pixels.
    shift_sigmas : float
        The movement's length in units of the fit's one-sigma
        (``sqrt(d^T C^+ d)`` with ``C`` the LM covariance): a movement along
        a direction the geometry does not observe counts zero.
    settled : bool
        ``shift_sigmas <= SETTLE_SIGMAS`` or ``shift_px <= step_tolerance_px``.
    """

    iterations: int
    shift_px: float
    shift_sigmas: float
    settled: bool


class Assessment(NamedTuple):
    """What :func:`assess` found in a fit: its status, reasons and message."""

    status: FitStatus
    reasons: tuple[FitReason, ...]
    #: ``"ok"``, or the status then every reason explained, one line.
    message: str


def fit_status(reasons: Sequence[FitReason]) -> FitStatus:
    """The worst severity among ``reasons`` (``OK`` when empty)."""
    return max((SEVERITY[r] for r in reasons), key=_ORDER.index, default=_OK)


def _profile_sigma(profile: Any) -> float:
    """The largest one-sigma of a profile refinement's offset, px (inf when not finite)."""
    cov = np.asarray(profile.covariance, dtype=np.float64)
    if not np.isfinite(cov).all():
        return float("inf")
    return float(np.sqrt(max(float(np.linalg.eigvalsh(cov).max()), 0.0)))


def _reasons(fit: Any) -> list[FitReason]:
    """The reasons found in ``fit``, in the enum's order."""
    lm = fit.lm
    n = _m.n_vertices(fit)
    n_out = int(np.count_nonzero(_m.outside(fit)))
    n_in = n - n_out  # the polarity reasons count only these
    # a polarity-rejected vertex has zero weight: it is the majority only then
    rejected = _m.polarity_rejected_inside(fit) if 2 * lm.inlier_count < n_in else 0
    out: list[FitReason] = []
    if n_out:
        inliers_in = _m.inside_inliers(fit)
        if lm.degenerate or 2 * inliers_in < n_in:
            out.append(FitReason.OUTSIDE_IMAGE)
        elif lm.inlier_count > inliers_in:  # use_polarity=False: nothing rejected them
            out.append(FitReason.OUTSIDE_IMAGE_WEIGHTED)
        else:
            out.append(FitReason.PARTLY_OUTSIDE_IMAGE)
    if n_in > 0 and rejected == n_in:
        out.append(FitReason.ALL_POLARITY_REJECTED)
    elif 2 * rejected > n_in:
        out.append(FitReason.MOST_POLARITY_REJECTED)
    if lm.degenerate:
        out.append(FitReason.DEGENERATE)
    if fit.at_window_edge:
        out.append(FitReason.AT_WINDOW_EDGE)
    if lm.degenerate:  # nothing was measured: convergence and rank mean nothing
        return out
    amb, profile, kind = fit.ambiguity, fit.profile, fit.edge_kind
    # an accepted refinement that lands on the same pose from the rival's start
    # has let the image decide between the two basins
    decided = profile is not None and profile.accepted and profile.rival_agrees is True
    if amb is not None and amb.ambiguous and not amb.along_unobservable and not decided:
        out.append(FitReason.AMBIGUOUS)
    if profile is not None:
        if not profile.accepted:
            out.append(FitReason.PROFILE_REJECTED)
        if profile.soft_edge:
            out.append(FitReason.SOFT_EDGE)
        if (profile.accepted and kind == "terminator"
                and _profile_sigma(profile) > TERMINATOR_SIGMA_LIMIT_PX):
            out.append(FitReason.TERMINATOR_IMPRECISE)
        if profile.n_flat_vertices > 0:
            out.append(FitReason.FLAT_PROFILE_VERTICES)
    elif kind == "terminator":
        out.append(FitReason.TERMINATOR_WITHOUT_PROFILE)
    if not fit.settled:
        out.append(FitReason.NOT_CONVERGED)
    if amb is not None and amb.ambiguous and amb.along_unobservable:
        out.append(FitReason.AMBIGUOUS_ALONG_EDGE)
    if fit.observable_rank < fit.n_params:
        out.append(FitReason.RANK_DEFICIENT)
    return out


class _Facts(dict[str, Any]):
    """The facts of one fit's messages, each read (by :data:`_FACT`) when a template names it."""

    fit: Any
    status: FitStatus

    def __init__(self, fit: Any, status: FitStatus) -> None:
        super().__init__()
        self.fit = fit
        self.status = status

    def __missing__(self, key: str) -> Any:
        value = self[key] = _FACT[key](self)
        return value


def _settling_text(fit: Any) -> str:
    s, n = fit.settling, fit.lm.iterations
    if s is None:
        return f"the LM stopped after {n} iterations before its step fell below step_tolerance_px"
    return (f"the pose still moved {s.shift_px:.3g} px ({s.shift_sigmas:.3g} sigma) over the "
            f"LM's last {s.iterations} of {n} iterations")


def _question(x: _Facts) -> str:
    q = ("are the normals pointing to the bright side? (they must point up the image gradient; "
         "flip them if not)")
    # a polyline partly off the image is most likely displaced
    return q if x["n_in"] == x["n"] else "is there an edge under them (is the polyline displaced)? " + q


def _too_few_inside(x: _Facts) -> str:
    if x["n_in"] == 0:
        return (": nothing inside to fit (is the polyline in this image's pixel frame, "
                "(v, u) = (row, column)? is the predicted pose this far off?)")
    return (f", and only {x['inliers_in']} of the {x['n_in']} inside kept any weight: too few "
            "to fit (is the predicted pose off by more than the search window?)")


def _rejected_counts(x: _Facts) -> str:
    k, inliers = _m.polarity_rejected_inside(x.fit), x.fit.lm.inlier_count
    if x["n_in"] == x["n"]:
        return f"{k} of {x['n']} polarity-rejected, {inliers} inliers"
    return f"{k} of the {x['n_in']} inside polarity-rejected, {inliers} inliers"


def _null_directions(fit: Any) -> str:
    return "; ".join("(" + ", ".join(f"{round(float(x), 4) + 0.0:g}" for x in e) + ")"
                     for e in fit.unobservable_directions)


#: How each fact a message template names is read (``x`` is the :class:`_Facts`).
_FACT: dict[str, Callable[[_Facts], Any]] = {
    "n": lambda x: _m.n_vertices(x.fit),
    "n_out": lambda x: int(np.count_nonzero(_m.outside(x.fit))),
    "n_in": lambda x: x["n"] - x["n_out"],
    "h": lambda x: int(x.fit.image_shape[0]),
    "w": lambda x: int(x.fit.image_shape[1]),
    "inliers_in": lambda x: _m.inside_inliers(x.fit),
    "outside_inliers": lambda x: x.fit.lm.inlier_count - x["inliers_in"],
    "too_few_inside": _too_few_inside,
    "all_who": lambda x: (f"all {x['n']} vertices" if x["n_in"] == x["n"]
                          else f"all {x['n_in']} vertices inside the image"),
    "all_where": lambda x: ("outside the image, or no edge there" if x["n_in"] == x["n"]
                            else "no edge there"),
    "most_who": lambda x: ("most vertices" if x["n_in"] == x["n"]
                           else "most vertices inside the image"),
    "rejected_counts": _rejected_counts,
    "question": _question,
    "unlit": lambda x: _m.no_edge_hint(x.fit),
    "unlit_or": lambda x: f"{x['unlit']}; if not, " if x["unlit"] else "",
    "at_pose_unlit": lambda x: f"; at this pose {x['unlit']}" if x["unlit"] else "",
    "seed": lambda x: tuple(x.fit.coarse_offset_vu),
    "window": lambda x: tuple(x.fit.search_window_vu),
    "noise_sigma": lambda x: x.fit.noise_sigma,
    "rival": lambda x: str(x.fit.ambiguity.reason),
    "profile_reason": lambda x: str(x.fit.profile.reason),
    "step_jump": lambda x: x.fit.profile.step_jump,
    "profile_sigma": lambda x: _profile_sigma(x.fit.profile),
    "n_flat": lambda x: x.fit.profile.n_flat_vertices,
    "n_model": lambda x: len(x.fit.vertices_vu),
    "moved": lambda x: _settling_text(x.fit),
    "rank": lambda x: x.fit.observable_rank,
    "n_params": lambda x: x.fit.n_params,
    "null_directions": lambda x: _null_directions(x.fit),
    # a failed fit's sigmas are no measurement anywhere: no "inf" to read there
    "inf_there": lambda x: "" if x.status is _FAILED else " (sigma inf there)",
}


def assess(fit: Any) -> Assessment:
    """The status, the reasons and the message of a fit: what it reports about itself.

    Parameters
    ----------
    fit : PolylineFit

    Returns
    -------
    Assessment
    """
    reasons = tuple(_reasons(fit))
    status = fit_status(reasons)
    if not reasons:
        return Assessment(status, reasons, str(status))
    facts = _Facts(fit, status)
    text = "; ".join(REASONS[r].message.format_map(facts) for r in reasons)
    return Assessment(status, reasons, f"{status}: {text}")


def fit_reasons(fit: Any) -> tuple[FitReason, ...]:
    """``fit.reasons``: what :func:`assess` found."""
    return fit.reasons


def describe(fit: Any) -> str:
    """``fit.status_message``: the status and every reason explained, one line."""
    return fit.status_message


def log_fit(fit: Any, label: str = "fit") -> FitStatus:
    """Report a fit on :data:`logger`: ``WARNING`` if failed, ambiguous or suspect,
    ``INFO`` if it carries only notes; returns its status."""
    if fit.status is not _OK:
        logger.warning("%s %s", label, fit.status_message)
    elif fit.reasons:
        logger.info("%s %s", label, fit.status_message)
    return fit.status


def log_fits(fits: Sequence[Any], label: str = "polylines") -> None:
    """:func:`log_fit` for each fit of a batch, labelled ``label[i]`` (``"polylines"``,
    ``"items[3].polylines"``)."""
    for i, fit in enumerate(fits):
        log_fit(fit, f"{label}[{i}]")


def _doc_tables() -> str:
    """The documentation's status and reason tables, as reStructuredText.

    Written to ``docs/_generated/status_tables.rst`` by the Sphinx
    configuration at each build (and compared with that file by the docs
    tests), so the page lists exactly the enums' members, in their order.
    """
    lines = [".. list-table::", "   :header-rows: 1", "   :widths: 15 85", "",
             "   * - status", "     - meaning"]
    for status in FitStatus:
        lines += [f"   * - ``{status.value}``", f"     - {STATUS_MEANING[status]}"]
    lines += ["", ".. list-table::", "   :header-rows: 1", "   :widths: 25 12 63", "",
              "   * - reason", "     - status", "     - meaning"]
    for reason, row in REASONS.items():
        cell = f"``{row.severity.value}``" if row.severity is not _OK else "note (``ok``)"
        lines += [f"   * - ``{reason.value}``", f"     - {cell}", f"     - {row.meaning}"]
    return "\n".join(lines) + "\n"
