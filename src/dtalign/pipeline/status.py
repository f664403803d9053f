"""Whether a pipeline fit can be trusted: its status, the reasons, the log.

A :class:`~dtalign.pipeline.PolylineFit` always returns a pose, even when
nothing was measured (a polyline outside the image, normals that point the
wrong way, a noise sigma so high that no edge survives): the pose is then
the coarse seed and every vertex has zero weight. This module reads, from
what the fit already holds, whether that happened and why:

* :class:`FitReason`: one value per condition found (a fit can have several);
* :class:`FitStatus`: the worst severity among them, ``"ok"``,
  ``"suspect"`` or ``"failed"``;
* :func:`fit_reasons`, :func:`fit_status` and :func:`describe`: what
  :attr:`PolylineFit.reasons <dtalign.pipeline.PolylineFit.reasons>`,
  :attr:`~dtalign.pipeline.PolylineFit.status` and
  :attr:`~dtalign.pipeline.PolylineFit.status_message` return;
* :data:`logger`, ``logging.getLogger("dtalign")``: the pipeline, the batch
  functions and the command line report each failed or suspect fit on it
  at ``WARNING`` (a fit with only notes, not converged or rank-deficient,
  at ``INFO``). The drop-in functions
  (:func:`dtalign.lm_subpixel_refine` and the rest of the drop-in surface, :ref:`contract-surface`) never
  log, exactly as the reference.

Nothing here imports Numba: the status of a fit costs a few attribute
reads (the observable rank, needed only for
:attr:`FitReason.RANK_DEFICIENT`, is computed on first use).
"""

from __future__ import annotations

import enum
import logging
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from ..api.constants import POLARITY_PENALTY_RESIDUAL

__all__ = [
    "FitReason",
    "FitStatus",
    "describe",
    "fit_problems",
    "fit_reasons",
    "fit_status",
    "log_fit",
    "log_fits",
    "logger",
]

#: The package's logger. No handler is attached: without logging
#: configuration Python prints WARNING and above to standard error, so a
#: failed fit is never silent; applications configure it as usual.
logger = logging.getLogger("dtalign")


class FitStatus(str, enum.Enum):
    """Overall verdict on a fit; compares equal to its string value.

    ``OK``
        Nothing found, or only notes (:attr:`FitReason.NOT_CONVERGED`,
        :attr:`FitReason.RANK_DEFICIENT`): the fit is sound along what the
        geometry observes.
    ``SUSPECT``
        The pose is a measurement but should be checked: most vertices were
        polarity-rejected.
    ``AMBIGUOUS``
        Another basin, across the edge, fits the image about as well
        (:attr:`FitReason.AMBIGUOUS`): the pose may be the wrong one of two.
    ``FAILED``
        The pose is not a measurement of the image: no vertex kept any
        weight, or the coarse seed is on the search-window edge (the true
        offset may lie outside the window).
    """

    OK = "ok"
    SUSPECT = "suspect"
    AMBIGUOUS = "ambiguous"
    FAILED = "failed"

    def __str__(self) -> str:
        return self.value


class FitReason(str, enum.Enum):
    """One condition found in a fit; compares equal to its string value.

    ``DEGENERATE`` (failed)
        No vertex kept any weight: the covariance is ``inf`` and the pose is
        the coarse seed. The polyline may be outside the image, no edge may
        lie near it, or the noise sigma may be so high that no edge passed
        the threshold.
    ``ALL_POLARITY_REJECTED`` (failed; with ``DEGENERATE``)
        No vertex's normal points up the image gradient: the normals point
        the wrong way (they must point up the gradient, toward the brighter
        side of the edge), or there is no gradient under the polyline at
        all (a polyline outside the image is rejected this way too).
    ``AT_WINDOW_EDGE`` (failed)
        The coarse seed lies on the boundary of the search window: the true
        offset may be outside it; widen ``search_window_vu``.
    ``MOST_POLARITY_REJECTED`` (suspect)
        More than half of the vertices were polarity-rejected: the normals
        may point the wrong way, or the polyline lies on the wrong edge.
    ``NOT_CONVERGED`` (note: the status stays ``OK``)
        The LM stopped at its iteration cap (``max_iterations``, default
        30; rejected steps count) or at its damping bound (no step lowered
        the cost any more), before an accepted step fell below
        ``step_tolerance_px``. The pose is the best found. A note, not a
        suspicion: the DT's cost surface has kinks, so on clean synthetic
        limbs the LM often creeps on past 30 iterations (the disc demo
        converges at 66, 0.005 px from where the cap stopped it); the
        result does not record the cap, so the two endings look alike.
    ``AMBIGUOUS`` (ambiguous)
        A rival basin -- a pose fitted from another coarse peak or from the
        competing basin of the DT cost, farther than
        :data:`~dtalign.pipeline.hypotheses.BASIN_RADIUS_PX` away -- costs less than
        :data:`~dtalign.pipeline.hypotheses.AMBIGUITY_THRESHOLD` times this one on the
        common footing of :func:`~dtalign.pipeline.hypotheses.robust_cost`: two
        parallel edges of the same polarity, a decoy edge. See
        :attr:`~dtalign.pipeline.PolylineFit.ambiguity`.
    ``AMBIGUOUS_ALONG_EDGE`` (note: the status stays ``OK``)
        The rival basin lies along a direction the fit cannot observe (a
        straight edge's along-edge shift): the pose is ambiguous along the
        edge, which its ``inf`` sigma there already says, not across it.
    ``PROFILE_REJECTED`` (suspect)
        An :class:`~dtalign.EdgeProfile` was given but its refinement
        (:mod:`dtalign.pipeline.profile_fit`) was discarded: it did not
        converge, walked farther than
        :data:`~dtalign.pipeline.profile_fit.MAX_WALK_PX` from the DT lock
        or fitted a non-positive gain. The pose is the DT-LM's, which
        carries the edge DT's photometric bias (tenths of a pixel on a
        limb) the profile was meant to remove.
    ``SOFT_EDGE`` (suspect)
        A limb profile has no usable edge: its brightness rolls off to the
        edge (a Lambert limb at low phase,
        :data:`~dtalign.pipeline.profile_fit.SOFT_EDGE_STEP_JUMP`), so the
        edge's position rests on the modelled roll-off alone and on the
        reflectance law being right.
    ``RANK_DEFICIENT`` (note: the status stays ``OK``)
        The polyline's geometry leaves some pose direction unmeasured (a
        straight edge: the along-edge shift; a circle: its rotation). The
        sigmas along it are ``inf``; see
        :attr:`~dtalign.pipeline.PolylineFit.unobservable_directions`.
    """

    DEGENERATE = "degenerate"
    ALL_POLARITY_REJECTED = "all_polarity_rejected"
    AT_WINDOW_EDGE = "at_window_edge"
    MOST_POLARITY_REJECTED = "most_polarity_rejected"
    AMBIGUOUS = "ambiguous"
    NOT_CONVERGED = "not_converged"
    AMBIGUOUS_ALONG_EDGE = "ambiguous_along_edge"
    RANK_DEFICIENT = "rank_deficient"
    PROFILE_REJECTED = "profile_rejected"
    SOFT_EDGE = "soft_edge"

    def __str__(self) -> str:
        return self.value


#: The status each reason implies (a fit's status is the worst of them).
SEVERITY: dict[FitReason, FitStatus] = {
    FitReason.DEGENERATE: FitStatus.FAILED,
    FitReason.ALL_POLARITY_REJECTED: FitStatus.FAILED,
    FitReason.AT_WINDOW_EDGE: FitStatus.FAILED,
    FitReason.MOST_POLARITY_REJECTED: FitStatus.SUSPECT,
    FitReason.AMBIGUOUS: FitStatus.AMBIGUOUS,
    FitReason.NOT_CONVERGED: FitStatus.OK,
    FitReason.AMBIGUOUS_ALONG_EDGE: FitStatus.OK,
    FitReason.RANK_DEFICIENT: FitStatus.OK,
    FitReason.PROFILE_REJECTED: FitStatus.SUSPECT,
    FitReason.SOFT_EDGE: FitStatus.SUSPECT,
}

_ORDER = (FitStatus.OK, FitStatus.SUSPECT, FitStatus.AMBIGUOUS, FitStatus.FAILED)


def _n_vertices(fit: Any) -> int:
    return int(fit.lm.residuals_px.shape[0])


def _polarity_rejected_count(fit: Any) -> int:
    return int(np.count_nonzero(np.asarray(fit.lm.residuals_px) == POLARITY_PENALTY_RESIDUAL))


def fit_problems(fit: Any) -> tuple[FitReason, ...]:
    """Every reason but ``RANK_DEFICIENT`` (the one that needs the observable rank).

    Cheap: a few attribute reads, and a count of the polarity-rejected
    vertices only when at most half the vertices are inliers (a
    polarity-rejected vertex has zero weight, so it cannot be the majority
    otherwise).

    Parameters
    ----------
    fit : PolylineFit

    Returns
    -------
    tuple of FitReason
        In the order of :class:`FitReason`.
    """
    lm = fit.lm
    n = _n_vertices(fit)
    rejected = _polarity_rejected_count(fit) if 2 * lm.inlier_count < n else 0
    out: list[FitReason] = []
    if lm.degenerate:
        out.append(FitReason.DEGENERATE)
    if n > 0 and rejected == n:
        out.append(FitReason.ALL_POLARITY_REJECTED)
    if fit.at_window_edge:
        out.append(FitReason.AT_WINDOW_EDGE)
    if lm.degenerate:  # nothing was measured: convergence means nothing
        return tuple(out)
    if 2 * rejected > n:
        out.append(FitReason.MOST_POLARITY_REJECTED)
    ambiguity = getattr(fit, "ambiguity", None)
    if ambiguity is not None and ambiguity.ambiguous and not ambiguity.along_unobservable:
        out.append(FitReason.AMBIGUOUS)
    if not lm.converged:
        out.append(FitReason.NOT_CONVERGED)
    if ambiguity is not None and ambiguity.ambiguous and ambiguity.along_unobservable:
        out.append(FitReason.AMBIGUOUS_ALONG_EDGE)
    profile = getattr(fit, "profile", None)
    if profile is not None:
        if not profile.accepted:
            out.append(FitReason.PROFILE_REJECTED)
        if profile.soft_edge:
            out.append(FitReason.SOFT_EDGE)
    return tuple(out)


def fit_reasons(fit: Any) -> tuple[FitReason, ...]:
    """:func:`fit_problems`, plus ``RANK_DEFICIENT`` when the geometry leaves a direction unmeasured.

    Parameters
    ----------
    fit : PolylineFit

    Returns
    -------
    tuple of FitReason
    """
    out = fit_problems(fit)
    if not fit.lm.degenerate and fit.observable_rank < (3 if fit.fit_rotation else 2):
        out += (FitReason.RANK_DEFICIENT,)
    return out


def fit_status(reasons: Iterable[FitReason]) -> FitStatus:
    """The worst severity among ``reasons`` (``OK`` when empty)."""
    return max((SEVERITY[r] for r in reasons), key=_ORDER.index, default=FitStatus.OK)


def _explain(fit: Any, reason: FitReason) -> str:
    lm = fit.lm
    n = _n_vertices(fit)
    if reason is FitReason.DEGENERATE:
        return (
            f"degenerate: no vertex of {n} kept any weight, the pose is the coarse seed "
            f"{tuple(fit.coarse_offset_vu)} (is the polyline inside the image? is there an "
            f"edge near it? noise sigma {fit.noise_sigma:.4g}: too high for any edge to pass?)"
        )
    if reason is FitReason.ALL_POLARITY_REJECTED:
        return (
            f"all {n} vertices polarity-rejected: the normals point the wrong way (they must "
            "point up the image gradient, toward the brighter side: flip them), or there is "
            "no gradient under the polyline (outside the image, or no edge there)"
        )
    if reason is FitReason.AT_WINDOW_EDGE:
        return (
            f"at window edge: the coarse seed {tuple(fit.coarse_offset_vu)} is on the edge of "
            f"the search window ±{tuple(fit.search_window_vu)}; the true offset may lie outside "
            "it: widen search_window_vu"
        )
    if reason is FitReason.MOST_POLARITY_REJECTED:
        k = _polarity_rejected_count(fit)
        return (
            f"{k} of {n} vertices polarity-rejected: the normals may point the wrong way "
            "(they must point up the image gradient, toward the brighter side)"
        )
    if reason in (FitReason.AMBIGUOUS, FitReason.AMBIGUOUS_ALONG_EDGE):
        return f"{reason}: {fit.ambiguity.reason}"
    if reason is FitReason.NOT_CONVERGED:
        return (
            f"not converged: the LM stopped after {lm.iterations} iterations, at its cap "
            "(max_iterations, default 30; rejected steps count) or because no step lowered "
            "the cost any more, before an accepted step fell below step_tolerance_px; the "
            "pose is the best found (raise max_iterations to let it finish)"
        )
    if reason is FitReason.PROFILE_REJECTED:
        return (
            f"profile refinement rejected: {fit.profile.reason}; the pose is the DT-LM's "
            "(biased by the edge DT's photometric offset)"
        )
    if reason is FitReason.SOFT_EDGE:
        return (
            f"soft edge: the profile's step at the edge is {fit.profile.step_jump:.2f} of its "
            "contrast (the brightness rolls off to the edge, as a limb at low phase): the "
            "position rests on the modelled roll-off and the reflectance law"
        )
    p = 3 if fit.fit_rotation else 2
    dirs = "; ".join(
        "(" + ", ".join(f"{round(float(x), 4) + 0.0:g}" for x in e) + ")"
        for e in fit.unobservable_directions
    )
    return (
        f"rank deficient: observable rank {fit.observable_rank} of {p}; the pose is not "
        f"measured along {dirs} (sigma inf there)"
    )


def describe(fit: Any, reasons: Sequence[FitReason] | None = None) -> str:
    """One line: the status and every reason, explained.

    Parameters
    ----------
    fit : PolylineFit
    reasons : sequence of FitReason, optional
        Default :func:`fit_reasons` of ``fit``.

    Returns
    -------
    str
        ``"ok"``, or for example ``"failed: degenerate: no vertex of 200
        kept any weight, ..."``.
    """
    reasons = fit_reasons(fit) if reasons is None else tuple(reasons)
    status = fit_status(reasons)
    if not reasons:
        return str(status)
    return f"{status}: " + "; ".join(_explain(fit, r) for r in reasons)


def log_fit(fit: Any, label: str = "fit") -> FitStatus:
    """Report a fit on :data:`logger`: ``WARNING`` if failed or suspect.

    A fit with only notes (not converged, rank-deficient) is reported at
    ``INFO``. Only the cheap :func:`fit_problems` run unless a record is
    emitted or ``INFO`` is enabled.

    Parameters
    ----------
    fit : PolylineFit
    label : str
        Prefix of the message (which fit of a call it is).

    Returns
    -------
    FitStatus
        The fit's status.
    """
    problems = fit_problems(fit)
    status = fit_status(problems)
    if status is not FitStatus.OK:
        if logger.isEnabledFor(logging.WARNING):
            logger.warning("%s %s", label, describe(fit, fit_reasons(fit)))
    elif logger.isEnabledFor(logging.INFO):
        reasons = fit_reasons(fit)
        if reasons:
            logger.info("%s %s", label, describe(fit, reasons))
    return status


def log_fits(fits: Sequence[Any], label: str = "polylines") -> None:
    """:func:`log_fit` for each fit of a batch, labelled ``label[i]``.

    Parameters
    ----------
    fits : sequence of PolylineFit
    label : str
        The name of the batch argument (``"polylines"``, ``"items[3].polylines"``).
    """
    info = logger.isEnabledFor(logging.INFO)
    for i, fit in enumerate(fits):
        lm = fit.lm
        # what fit_problems needs for a status worse than OK, read first: a
        # clean fit (most of a batch) costs a few reads here, not the full check
        if (info or lm.degenerate or fit.at_window_edge
                or 2 * lm.inlier_count < lm.residuals_px.shape[0]
                or getattr(fit, "profile", None) is not None):
            log_fit(fit, f"{label}[{i}]")
