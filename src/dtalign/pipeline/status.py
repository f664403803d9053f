"""Whether a pipeline fit can be trusted: its status, its reasons, the log.

A :class:`~dtalign.pipeline.PolylineFit` always returns a pose, even when
nothing was measured. :func:`assess` reads from what the fit holds, once,
which :class:`FitReason` apply, the worst severity among them
(:class:`FitStatus`) and one line explaining them, each reason's message
from its row of :data:`REASONS`. The fit, the command line, the log
(:func:`log_fit`), the campaign's store and the docs' tables read that.
Nothing here imports Numba.
"""

from __future__ import annotations

import enum
import logging
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import numpy as np

from . import measured as _m
from .hypotheses import AMBIGUITY_THRESHOLD
from .measured import (
    NO_EDGE_GAP,
    NO_EDGE_MIN_FRACTION,
    SETTLE_ITERATIONS,
    SETTLE_SIGMAS,
    NoEdgeRun,
    Settling,
    no_edge_run,
    outside_mask,
)
from .profile_fit import MISFIT_LIMIT, horns_disagree, misfitted

__all__ = [
    "NO_EDGE_GAP", "NO_EDGE_MIN_FRACTION", "REASONS", "SETTLE_ITERATIONS", "SETTLE_SIGMAS", "TERMINATOR_PLAIN_MEDIAN_PX",
    "TERMINATOR_PLAIN_P90_PX", "TERMINATOR_SIGMA_LIMIT_PX", "UNMEASURED_TEXT", "Assessment",
    "FitReason", "FitStatus", "NoEdgeRun", "Reason", "Settling", "assess", "describe", "fit_reasons",
    "fit_status", "log_fit", "log_fits", "logger", "no_edge_run", "outside_mask",
]

#: The package's logger (:func:`log_fit`). No handler is attached: without
#: logging configuration Python prints WARNING and above to standard error,
#: so a failed fit is never silent. The drop-in functions never log,
#: exactly as the reference.
logger = logging.getLogger("dtalign")


class _Text(str, enum.Enum):
    """An enum whose members print as their string values (``str(FitStatus.OK) == "ok"``)."""

    def __str__(self) -> str:
        return self.value


class FitStatus(_Text):
    """A fit's verdict, the worst severity of its reasons (:data:`STATUS_MEANING`)."""

    OK = "ok"
    SUSPECT = "suspect"
    AMBIGUOUS = "ambiguous"
    FAILED = "failed"


class FitReason(_Text):
    """One condition found in a fit (its row of :data:`REASONS`).

    A fit lists its reasons in this order, the likeliest cause first:
    vertices outside the image measure nothing whatever their normals, and
    wrong normals make a fit degenerate and can put the coarse seed on the
    window edge, not the other way round.
    """

    OUTSIDE_IMAGE = "outside_image"
    OUTSIDE_IMAGE_WEIGHTED = "outside_image_weighted"
    PARTLY_OUTSIDE_IMAGE = "partly_outside_image"
    MASKED_PIXELS = "masked_pixels"
    ALL_POLARITY_REJECTED = "all_polarity_rejected"
    MOST_POLARITY_REJECTED = "most_polarity_rejected"
    DEGENERATE = "degenerate"
    AT_WINDOW_EDGE = "at_window_edge"
    AMBIGUOUS = "ambiguous"
    PROFILE_REJECTED = "profile_rejected"
    SOFT_EDGE = "soft_edge"
    PROFILE_MISFIT = "profile_misfit"
    TERMINATOR_WITHOUT_PROFILE = "terminator_without_profile"
    TERMINATOR_IMPRECISE = "terminator_imprecise"
    NIGHT_SIDE_LIT = "night_side_lit"
    FLAT_PROFILE_VERTICES = "flat_profile_vertices"
    NOT_CONVERGED = "not_converged"
    AMBIGUOUS_ALONG_EDGE = "ambiguous_along_edge"
    RANK_DEFICIENT = "rank_deficient"


#: The median error, px, of plain (profile-less) fits of rendered Lambert
#: terminators (:ref:`profiles-terminator`): what ``terminator_without_profile`` warns of.
TERMINATOR_PLAIN_MEDIAN_PX = 4.6
#: Their 90th percentile, px.
TERMINATOR_PLAIN_P90_PX = 13.8

#: A terminator's accepted profile refinement whose own one-sigma (the root of
#: its covariance's largest eigenvalue) exceeds this, px, is suspect,
#: ``terminator_imprecise``: an ``ok`` terminator more than 1 px off is then
#: more than three of its sigmas off (:ref:`profiles-terminator`).
TERMINATOR_SIGMA_LIMIT_PX = 1.0 / 3.0

#: How far inside the search window, px along each axis, a terminator's
#: accepted, scan-started profile refinement must put the pose for the
#: coarse seed on the window's edge not to matter (``at_window_edge``).
WINDOW_EDGE_CLEARANCE_PX = 1.0

#: What a failed fit's printed summary and the command line show for its
#: sigmas, which are no measurement; the numeric fields keep their values.
UNMEASURED_TEXT = "not measured (failed)"

_OK, _SUSPECT, _AMBIGUOUS, _FAILED = FitStatus
_ORDER = (_OK, _SUSPECT, _AMBIGUOUS, _FAILED)

#: What each status tells the caller, one sentence (the docs' status table).
STATUS_MEANING: dict[FitStatus, str] = {
    _OK: "the pose is a measurement; the fit may carry notes (reasons whose status is ``ok``).",
    _SUSPECT: "the pose is a measurement that should be checked: its ``suspect`` reasons say "
    "what to check.",
    _AMBIGUOUS: "another basin across the edge fits the image about as well: the pose may be "
    "the wrong one of two.",
    _FAILED: "the pose is not a measurement of the image: do not use it.",
}


class Reason(NamedTuple):
    """One row of :data:`REASONS`: the ``severity`` the reason implies, its ``meaning``
    (the docs' reasons table: what it means, what to do) and its ``message``, a
    ``str.format`` template of the ``fit`` and the facts :func:`assess` reads."""

    severity: FitStatus
    meaning: str
    message: str


_HEAD = ("{n_out} of {n} vertices lie outside the {fit.image_shape[0]} x "
         "{fit.image_shape[1]} image")

#: Every reason: its severity, its meaning (one sentence), its message.
REASONS: dict[FitReason, Reason] = {
    FitReason.OUTSIDE_IMAGE: Reason(
        _FAILED, "some vertices lie outside the image and fewer than half of those inside kept "
        "any weight, too few to fit: is the polyline in this image's pixel frame, the predicted "
        "pose within the search window of the truth (:ref:`status-outside-image`)?",
        _HEAD + "{too_few_inside}"),
    FitReason.OUTSIDE_IMAGE_WEIGHTED: Reason(
        _SUSPECT, "vertices outside the image kept weight (``use_polarity=False``) and read the "
        "distance transform clamped to the image border, not theirs: pass only the vertices "
        "inside, or keep the polarity test (:ref:`status-outside-image`).",
        _HEAD + ", and {outside_inliers} of them kept weight beside the {inliers_in} inliers "
        "inside: without the polarity test they sample the distance transform clamped to the "
        "image border, the border's distance to an edge, not theirs (pass only the vertices "
        "inside, or use the polarity test)"),
    FitReason.PARTLY_OUTSIDE_IMAGE: Reason(
        _OK, "some vertices lie outside the image, but at least half of those inside kept their "
        "weight and none outside did: the inside ones alone measure the pose and its sigmas.",
        _HEAD + ": the pose is measured by the {n_in} inside ({inliers_in} inliers), its "
        "sigmas by their geometry"),
    FitReason.MASKED_PIXELS: Reason(
        _OK, "some vertices lie on bad pixels of the image's mask (``prepare_image(..., "
        "mask=...)``), where no edge was measured: the pose and its sigmas rest on the others "
        "(:ref:`robustness-masks`).",
        "{fit.masked_vertices} of {n} vertices lie on masked pixels: no edge was measured "
        "there, the pose rests on the others"),
    FitReason.ALL_POLARITY_REJECTED: Reason(
        _FAILED, "no vertex inside the image has a normal that points up the image gradient: "
        "flip the normals, or there is no gradient under the polyline (comes with "
        "``degenerate``).",
        "all {n_in} vertices{inside} polarity-rejected: the normals point the wrong way (they "
        "must point up the image gradient, toward the brighter side: flip them), or there is no "
        "gradient under the polyline ({all_where})"),
    FitReason.MOST_POLARITY_REJECTED: Reason(
        _FAILED, "more than half of the vertices inside the image see the gradient the wrong "
        "way, so the pose rests on the few that agreed: flip the normals, or the polyline lies "
        "on the wrong edge or an unlit part of a limb (:ref:`status-unlit-stretch`).",
        "most vertices{inside} see the gradient the wrong way ({rejected} of {of_inside} "
        "polarity-rejected, {fit.lm.inlier_count} inliers): {unlit_or}{displaced}are the normals pointing "
        "to the bright side? (they must point up the image gradient; flip them if not)"),
    FitReason.DEGENERATE: Reason(
        _FAILED, "no vertex kept any weight, so the pose is the coarse seed and the covariance "
        "``inf``: the polyline is outside the image, no edge lies near it, or the noise sigma "
        "is too high for any edge to pass the threshold.",
        "degenerate: no vertex of {n} kept any weight, the pose is the coarse seed {seed} (is "
        "the polyline inside the image? is there an edge near it? noise sigma "
        "{fit.noise_sigma:.4g}: too high for any edge to pass?)"),
    FitReason.AT_WINDOW_EDGE: Reason(
        _FAILED, "the coarse seed is on the boundary of the search window, so the true offset "
        "may lie outside it: widen ``search_window_vu`` (``--window``). Not raised when a "
        "terminator's accepted profile refinement, started from its own scan, puts the pose "
        f"at least {WINDOW_EDGE_CLEARANCE_PX:g} px inside the window.",
        "at window edge: the coarse seed {seed} is on the edge of the search window "
        "±{window}; the true offset may lie outside it: widen search_window_vu"),
    FitReason.AMBIGUOUS: Reason(
        _AMBIGUOUS, f"a rival basin across the edge costs less than {AMBIGUITY_THRESHOLD:g} times this one (two "
        "parallel edges of one polarity, a decoy edge, an unlit part of a limb), and no accepted "
        "edge-profile refinement reaches this pose from the rival's start "
        "(:attr:`~dtalign.pipeline.PolylineFit.ambiguity`).", "{fit.ambiguity.reason}{at_pose_unlit}"),
    FitReason.PROFILE_REJECTED: Reason(
        _SUSPECT, "the edge profile's refinement was discarded (:ref:`profiles-result`), so the "
        "pose is the DT-LM's, with the edge DT's photometric bias (tenths of a pixel on a limb).",
        "profile refinement rejected: {fit.profile.reason}; the pose is the DT-LM's (biased by the "
        "edge DT's photometric offset)"),
    FitReason.SOFT_EDGE: Reason(
        _SUSPECT, "the limb profile has no usable edge (its brightness rolls off to the limb, as "
        "a Lambert limb at low phase): the position rests on the modelled roll-off and on the "
        "reflectance law being right.",
        "soft edge: the profile's step at the edge is {fit.profile.step_jump:.2f} of its contrast (the "
        "brightness rolls off to the edge, as a limb at low phase): the position rests on the "
        "modelled roll-off and the reflectance law"),
    FitReason.PROFILE_MISFIT: Reason(
        _SUSPECT, "the accepted profile refinement leaves residuals its model does not explain: "
        "a shape common to the vertices (a reflectance law, a PSF or a brightening that differ "
        "from the declared ones), vertex edges or gains spread beyond the noise (relief, "
        "craters, an albedo that varies along the edge), or a "
        "terminator whose horns (the vertices whose strips the limb cuts) move its pose; its "
        "pose may then be off by more than its sigma (:ref:`profiles-result`): declare the law, "
        "or check the surface.",
        "profile misfit: the fitted model leaves a residual shape of {fit.profile.misfit:.3g} of "
        "its gain (limit {misfit_limit:g}) and the vertices' edges spread "
        "{fit.profile.edge_scatter_px:.3g} px about the pose against {fit.profile.edge_noise_px:.3g} "
        "px from the noise, their gains {fit.profile.gain_scatter:.3g} of the gain against "
        "{fit.profile.gain_noise:.3g}{horns}: the profile does not describe this edge (another law, PSF or "
        "surface), and the pose may be off by more than its sigma"),
    FitReason.TERMINATOR_WITHOUT_PROFILE: Reason(
        _SUSPECT, "a terminator (declared, or seen in the image's ramp when no kind was declared: "
        "``PolylineFit.inferred_edge_kind``) was fitted without an edge "
        "profile, and the DT puts a "
        "terminator where the brightness ramp crosses the edge threshold (median error "
        f"{TERMINATOR_PLAIN_MEDIAN_PX:g} px, 90th percentile {TERMINATOR_PLAIN_P90_PX:g} px on "
        "rendered Lambert terminators, :ref:`profiles-terminator`): give "
        "``sphere_edge_profile(..., edge=\"terminator\")``.",
        "terminator without a profile: the DT puts a terminator where the brightness ramp "
        "crosses the edge threshold (on rendered Lambert terminators the median error is "
        f"{TERMINATOR_PLAIN_MEDIAN_PX:g} px); fit it with "
        "sphere_edge_profile(..., edge='terminator')"),
    FitReason.TERMINATOR_IMPRECISE: Reason(
        _SUSPECT, "a terminator's profile refinement reports a one-sigma above "
        f"{TERMINATOR_SIGMA_LIMIT_PX:.2f} px along some direction (a terminator near phase 90 deg "
        "is nearly straight): the pose is barely measured there.",
        "terminator imprecise: the profile refinement's one-sigma is {profile_sigma:.3g} px "
        f"along some direction (above {TERMINATOR_SIGMA_LIMIT_PX:.2f} px): the pose is barely "
        "measured there"),
    FitReason.NIGHT_SIDE_LIT: Reason(
        _OK, "a terminator's night side is brighter than the sky around it: lit by the planet "
        "or a ring, the kink stays where it is; floored at that level (an ambient term, stray "
        "light), the kink moves toward the lit side, and the image cannot tell the two apart, "
        "so the covariance holds the difference "
        "(:ref:`a night side above the sky <profiles-night-side>`).",
        "night side lit: it reads {fit.profile.night_level:.3g} above the sky "
        "({night_percent:.2g} % of the gain); floored at that level instead, the terminator "
        "would lie {night_shift:.3g} px toward the night side, which its sigma holds"),
    FitReason.FLAT_PROFILE_VERTICES: Reason(
        _OK, "vertices whose edge profiles have no contrast (an unlit part of a limb) were left "
        "out of the profile refinement, which fitted the others: pass the sunlit part of a limb.",
        "{fit.profile.n_flat_vertices} of {n_model} vertices' profiles have no contrast (an unlit part of a limb?): "
        "left out of the profile refinement"),
    FitReason.NOT_CONVERGED: Reason(
        _OK, "the LM stopped before its step tolerance and its pose still moved more than "
        f"{SETTLE_SIGMAS:g} sigma over its last {SETTLE_ITERATIONS} iterations: raise "
        "``max_iterations`` (`Converged, settled, and the iteration cap`_).",
        "not converged: {moved} (raise max_iterations)"),
    FitReason.AMBIGUOUS_ALONG_EDGE: Reason(
        _OK, "the rival basin lies along a direction the fit cannot observe (a straight edge's "
        "along-edge shift), where its sigma is already ``inf``: not ambiguous across the edge.",
        "{fit.ambiguity.reason}"),
    FitReason.RANK_DEFICIENT: Reason(
        _OK, "the geometry leaves a pose direction unmeasured (a straight edge: the along-edge "
        "shift; a circle: its rotation), and the sigmas along it are ``inf``.",
        "rank deficient: observable rank {fit.observable_rank} of {fit.n_params}; the pose is "
        "not measured along {null_directions}{inf_there}"),
}

#: Views of :data:`REASONS`: each reason's severity, and its meaning.
SEVERITY = {r: row.severity for r, row in REASONS.items()}
REASON_MEANING = {r: row.meaning for r, row in REASONS.items()}


class Assessment(NamedTuple):
    """What :func:`assess` found in a fit: its status, reasons and message."""

    status: FitStatus
    reasons: tuple[FitReason, ...]
    #: ``"ok"``, or the status then every reason explained, one line.
    message: str


def fit_status(reasons: Sequence[FitReason]) -> FitStatus:
    """The worst severity among ``reasons`` (``OK`` when empty)."""
    return max((SEVERITY[r] for r in reasons), key=_ORDER.index, default=_OK)


class _Facts(dict[str, Any]):
    """What :func:`assess` reads of one fit, each fact by :data:`_FACT` when first asked for."""

    def __init__(self, fit: Any) -> None:
        super().__init__(fit=fit)
        self.fit = fit

    def __missing__(self, key: str) -> Any:
        value = self[key] = _FACT[key](self)
        return value


def _reasons(x: _Facts) -> tuple[FitReason, ...]:
    """The reasons found in ``x.fit``, in the enum's order."""
    fit, R = x.fit, FitReason
    lm, amb, profile = fit.lm, fit.ambiguity, fit.profile
    n_in, outside = x["n_in"], x["n_out"] > 0
    too_few = lm.degenerate or 2 * x["inliers_in"] < n_in
    # a polarity-rejected vertex has zero weight: it is the majority only then
    rejected = x["rejected"] if 2 * lm.inlier_count < n_in else 0
    found = {
        R.OUTSIDE_IMAGE: outside and too_few,
        # use_polarity=False: nothing rejected those outside
        R.OUTSIDE_IMAGE_WEIGHTED: outside and not too_few and lm.inlier_count > x["inliers_in"],
        R.PARTLY_OUTSIDE_IMAGE: outside and not too_few and lm.inlier_count <= x["inliers_in"],
        R.ALL_POLARITY_REJECTED: n_in > 0 and rejected == n_in,
        R.MOST_POLARITY_REJECTED: rejected != n_in and 2 * rejected > n_in,
        R.DEGENERATE: lm.degenerate,
        R.AT_WINDOW_EDGE: fit.at_window_edge and not _found_inside_window(fit),
        R.MASKED_PIXELS: bool(getattr(fit, "masked_vertices", None)),
    }
    if not lm.degenerate:  # nothing was measured: the rest means nothing
        given = profile is not None
        # an accepted refinement that lands on the same pose from the rival's
        # start has let the image decide between the two basins
        decided = given and profile.accepted and profile.rival_agrees is True
        rival = amb is not None and amb.ambiguous
        # declared, or seen in the image when nothing was declared
        terminator = (fit.edge_kind or getattr(fit, "inferred_edge_kind", None)) == "terminator"
        found.update({
            R.AMBIGUOUS: rival and not amb.along_unobservable and not decided,
            R.PROFILE_REJECTED: given and not profile.accepted,
            R.SOFT_EDGE: given and profile.soft_edge,
            R.PROFILE_MISFIT: given and misfitted(profile),
            R.TERMINATOR_WITHOUT_PROFILE: not given and terminator,
            R.TERMINATOR_IMPRECISE: given and profile.accepted and terminator
            and x["profile_sigma"] > TERMINATOR_SIGMA_LIMIT_PX,
            R.NIGHT_SIDE_LIT: given and profile.accepted and profile.night_shift_vu is not None,
            R.FLAT_PROFILE_VERTICES: given and profile.n_flat_vertices > 0,
            R.NOT_CONVERGED: not fit.settled,
            R.AMBIGUOUS_ALONG_EDGE: rival and amb.along_unobservable,
            R.RANK_DEFICIENT: fit.observable_rank < fit.n_params,
        })
    return tuple(r for r in FitReason if found.get(r))


def _found_inside_window(fit: Any) -> bool:
    """Whether an accepted profile refinement that started from its own scan (a
    terminator's: ``ProfileRefinement.start_offset_vu``)
    put the pose at least :data:`WINDOW_EDGE_CLEARANCE_PX` inside the search window.

    Its pose does not rest on the coarse seed: a DT lock on a terminator's
    ramp sits where the ramp crosses the edge threshold, often at the window's
    edge, and the scan finds the kink from there. Such refinements of rendered
    terminators are as accurate as the others (:ref:`validation`), so the
    seed's place says nothing about the pose then.
    """
    ref = fit.profile
    if ref is None or not ref.accepted or ref.start_offset_vu is None:
        return False
    return all(w > 0 and abs(o) <= w - WINDOW_EDGE_CLEARANCE_PX
               for o, w in zip(fit.offset_vu, fit.search_window_vu, strict=True))


def _profile_sigma(x: _Facts) -> float:
    """The largest one-sigma of the profile refinement's offset, px (inf when not finite)."""
    cov = np.asarray(x.fit.profile.covariance, dtype=np.float64)
    if not np.isfinite(cov).all():
        return float("inf")
    return float(np.sqrt(max(float(np.linalg.eigvalsh(cov).max()), 0.0)))


def _ratio(a: float, b: float) -> float:
    """``a / b``, inf for a zero ``b``."""
    return a / b if b > 0.0 else float("inf")


def _moved(x: _Facts) -> str:
    s, n = x.fit.settling, x.fit.lm.iterations
    if s is None:
        return f"the LM stopped after {n} iterations before its step fell below step_tolerance_px"
    return (f"the pose still moved {s.shift_px:.3g} px ({s.shift_sigmas:.3g} sigma) over the "
            f"LM's last {s.iterations} of {n} iterations")


def _too_few_inside(x: _Facts) -> str:
    if x["n_in"] == 0:
        return (": nothing inside to fit (is the polyline in this image's pixel frame, "
                "(v, u) = (row, column)? is the predicted pose this far off?)")
    return (f", and only {x['inliers_in']} of the {x['n_in']} inside kept any weight: too few "
            "to fit (is the predicted pose off by more than the search window?)")


#: How each fact a message template names is read (``x`` is the :class:`_Facts`;
#: ``status``, the fit's, is set by :func:`assess`).
_FACT: dict[str, Callable[[_Facts], Any]] = {
    "n": lambda x: _m.n_vertices(x.fit),
    "n_out": lambda x: int(np.count_nonzero(_m.outside(x.fit))),
    "n_in": lambda x: x["n"] - x["n_out"],
    "inliers_in": lambda x: _m.inside_inliers(x.fit),
    "outside_inliers": lambda x: x.fit.lm.inlier_count - x["inliers_in"],
    "rejected": lambda x: _m.polarity_rejected_inside(x.fit),
    "too_few_inside": _too_few_inside,
    # the polarity messages count the vertices inside, and say so when some are not
    "inside": lambda x: "" if x["n_in"] == x["n"] else " inside the image",
    "of_inside": lambda x: x["n"] if x["n_in"] == x["n"] else f"the {x['n_in']} inside",
    "all_where": lambda x: ("outside the image, or no edge there" if x["n_in"] == x["n"]
                            else "no edge there"),
    # a polyline partly off the image is most likely displaced
    "displaced": lambda x: ("" if x["n_in"] == x["n"]
                            else "is there an edge under them (is the polyline displaced)? "),
    "unlit": lambda x: _m.no_edge_hint(x.fit),
    "unlit_or": lambda x: f"{x['unlit']}; if not, " if x["unlit"] else "",
    "at_pose_unlit": lambda x: f"; at this pose {x['unlit']}" if x["unlit"] else "",
    "seed": lambda x: tuple(x.fit.coarse_offset_vu),
    "window": lambda x: tuple(x.fit.search_window_vu),
    "profile_sigma": _profile_sigma,
    "misfit_limit": lambda x: MISFIT_LIMIT,
    "horns": lambda x: (
        f"; refitted without its horns (the vertices whose strips the limb cuts) the pose moves "
        f"{x.fit.profile.horn_shift_px:+.3g} px along the mean normal, "
        f"{_ratio(abs(x.fit.profile.horn_shift_px), x.fit.profile.horn_shift_sigma_px):.3g} of "
        "its sigmas" if horns_disagree(x.fit.profile) else ""),
    "night_percent": lambda x: 100.0 * _ratio(x.fit.profile.night_level, x.fit.profile.gain),
    "night_shift": lambda x: float(np.hypot(*x.fit.profile.night_shift_vu)),
    "n_model": lambda x: len(x.fit.vertices_vu),
    "moved": _moved,
    "null_directions": lambda x: "; ".join(
        "(" + ", ".join(f"{round(float(c), 4) + 0.0:g}" for c in e) + ")"
        for e in x.fit.unobservable_directions),
    # a failed fit's sigmas are no measurement anywhere: no "inf" to read there
    "inf_there": lambda x: "" if x["status"] is _FAILED else " (sigma inf there)",
}


def assess(fit: Any) -> Assessment:
    """The status, the reasons and the message of a
    :class:`~dtalign.pipeline.PolylineFit`: what it reports about itself."""
    x = _Facts(fit)
    reasons = _reasons(x)
    x["status"] = status = fit_status(reasons)
    text = "; ".join(REASONS[r].message.format_map(x) for r in reasons)
    return Assessment(status, reasons, f"{status}: {text}" if reasons else str(status))


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
    """The docs' status and reason tables, as reStructuredText: ``docs/conf.py``
    writes them to ``docs/_generated/status_tables.rst`` at each build."""
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
