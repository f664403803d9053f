"""Whether a pipeline fit can be trusted: its status, the reasons, the log.

A :class:`~dtalign.pipeline.PolylineFit` always returns a pose, even when
nothing was measured (a polyline outside the image, normals that point the
wrong way, a noise sigma so high that no edge survives): the pose is then
the coarse seed and every vertex has zero weight. This module reads, from
what the fit already holds, whether that happened and why:

* :class:`FitReason`: one value per condition found (a fit can have several);
* :class:`FitStatus`: the worst severity among them, ``"ok"``,
  ``"suspect"``, ``"ambiguous"`` or ``"failed"``;
* :class:`Settling`: whether a fit whose LM stopped before its step
  tolerance has nevertheless settled (what :attr:`FitReason.NOT_CONVERGED`
  is decided on);
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
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..api.constants import POLARITY_PENALTY_RESIDUAL

__all__ = [
    "NO_EDGE_GAP",
    "NO_EDGE_MIN_FRACTION",
    "SETTLE_ITERATIONS",
    "SETTLE_SIGMAS",
    "TERMINATOR_PLAIN_MEDIAN_PX",
    "TERMINATOR_PLAIN_P90_PX",
    "TERMINATOR_SIGMA_LIMIT_PX",
    "UNMEASURED_TEXT",
    "FitReason",
    "FitStatus",
    "NoEdgeRun",
    "Settling",
    "describe",
    "fit_problems",
    "fit_reasons",
    "fit_status",
    "log_fit",
    "log_fits",
    "logger",
    "no_edge_run",
    "outside_mask",
    "settled",
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
    """Overall verdict on a fit; compares equal to its string value.

    ``OK``
        Nothing found, or only notes (:attr:`FitReason.NOT_CONVERGED`,
        :attr:`FitReason.RANK_DEFICIENT`): the fit is sound along what the
        geometry observes.
    ``SUSPECT``
        The pose is a measurement but should be checked: an edge profile's
        refinement was discarded (:attr:`FitReason.PROFILE_REJECTED`), a
        limb has no usable edge (:attr:`FitReason.SOFT_EDGE`), a
        terminator was fitted without a profile
        (:attr:`FitReason.TERMINATOR_WITHOUT_PROFILE`), or vertices outside
        the image kept weight (:attr:`FitReason.OUTSIDE_IMAGE_WEIGHTED`).
    ``AMBIGUOUS``
        Another basin, across the edge, fits the image about as well
        (:attr:`FitReason.AMBIGUOUS`): the pose may be the wrong one of two.
    ``FAILED``
        The pose is not a measurement of the image: vertices lie outside the
        image and too few inside it kept any weight, most vertices inside
        the image see the gradient the wrong way (the normals point to the
        dark side), no vertex kept any weight, or the coarse seed is on the
        search-window edge (the true offset may lie outside the window).
    """

    OK = "ok"
    SUSPECT = "suspect"
    AMBIGUOUS = "ambiguous"
    FAILED = "failed"


class FitReason(_Text):
    """One condition found in a fit; compares equal to its string value.

    A fit lists its reasons in the order below: the likeliest cause first.
    Vertices outside the image measure nothing whatever their normals, so
    the outside reasons come first; normals that point the wrong way make a
    fit degenerate and can put the coarse seed on the window edge, so the
    polarity reasons come before ``DEGENERATE`` and ``AT_WINDOW_EDGE``
    (whose advice, to widen the window, would not help then).

    *Outside the image* means, for a vertex: the pixel the polarity test
    reads for it -- its position shifted by the coarse seed (the LM's
    start, where the polarity mask is formed, :ref:`contract-lm`), rounded
    to the nearest pixel -- is not within rows ``0 .. H-1`` and columns
    ``0 .. W-1``. The polarity test rejects such a vertex (there is no
    gradient to read), so the polarity reasons count only the vertices
    inside: a rejection outside is never blamed on the normals
    (:attr:`PolylineFit.outside_image <dtalign.pipeline.PolylineFit.outside_image>`).

    ``OUTSIDE_IMAGE`` (failed)
        Some vertices lie outside the image, and fewer than half of those
        inside kept any weight (inliers outside, which ``use_polarity=False``
        leaves, do not count) (none at all when every vertex is outside):
        too few inside to fit. The polyline is most likely not where the
        image has it (a pose prediction off by more than the polyline's
        overlap with the frame, or vertices not in this image's pixel frame).
    ``OUTSIDE_IMAGE_WEIGHTED`` (suspect)
        As ``PARTLY_OUTSIDE_IMAGE``, but some vertices outside kept weight:
        with ``use_polarity=False`` nothing rejects them, and they sample
        the distance transform clamped to the image border, whose value is
        the border's distance to an edge, not theirs. The pose is a
        measurement with residuals that are not; pass only the vertices
        inside, or keep the polarity test.
    ``PARTLY_OUTSIDE_IMAGE`` (note: the status stays ``OK``)
        Some vertices lie outside the image, but at least half of those
        inside kept their weight and none outside did: the pose is measured
        by the inside ones alone, and its covariance and observable rank
        are formed from them (an outside vertex has zero weight), so its
        sigmas already say what the shorter polyline measures.
    ``ALL_POLARITY_REJECTED`` (failed; with ``DEGENERATE``)
        No vertex inside the image has a normal that points up the image
        gradient: the normals point the wrong way (they must point up the
        gradient, toward the brighter side of the edge), or there is no
        gradient under the polyline at all.
    ``MOST_POLARITY_REJECTED`` (failed)
        More than half of the vertices inside the image (not all) see the
        gradient the wrong way: the normals most likely point to the dark
        side, or the polyline lies on the wrong edge. The pose rests on the
        minority of vertices that happened to agree and is not a
        measurement. When the vertices without an edge are one contiguous
        stretch of the polyline and the rest fit (:func:`no_edge_run`), the
        message names the stretch: part of a limb unlit (a whole circle
        passed for a limb lit on one side) does this with right normals.
    ``DEGENERATE`` (failed)
        No vertex kept any weight: the covariance is ``inf`` and the pose is
        the coarse seed. The polyline may be outside the image, no edge may
        lie near it, or the noise sigma may be so high that no edge passed
        the threshold.
    ``AT_WINDOW_EDGE`` (failed)
        The coarse seed lies on the boundary of the search window: the true
        offset may be outside it; widen ``search_window_vu``.
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
    ``TERMINATOR_WITHOUT_PROFILE`` (suspect)
        The polyline is declared a terminator (``edge_kind="terminator"``)
        and was fitted without an :class:`~dtalign.EdgeProfile`: a Lambert
        terminator is a kink in brightness (``cos i`` through 0), not an
        edge, so the DT puts it wherever the brightness ramp crosses the
        edge threshold, which depends on the noise and the albedo, not on
        where the terminator is. On rendered Lambert terminators
        (:ref:`profiles-terminator`) the plain fit's error has median
        :data:`TERMINATOR_PLAIN_MEDIAN_PX` and 90th percentile
        :data:`TERMINATOR_PLAIN_P90_PX` px. Give the sphere's profile
        (:func:`dtalign.sphere_edge_profile` with ``edge="terminator"``).
    ``TERMINATOR_IMPRECISE`` (suspect)
        A terminator's profile refinement was accepted but its own one-sigma
        exceeds :data:`TERMINATOR_SIGMA_LIMIT_PX` along some direction: near
        phase 90 deg the terminator is nearly straight and its along-edge
        shift barely measured (on the seeded scenes of
        :ref:`profiles-terminator`, 2.40 px off at phase 91 deg with a
        reported one-sigma of 1.56 px; on the coverage harness, 1.25 px off
        at phase 86 deg with 0.35 px).
    ``FLAT_PROFILE_VERTICES`` (note: the status stays ``OK``)
        Some of a limb's vertices have edge profiles with no contrast across
        their strips (an unlit part of the limb): they were left out of the
        profile refinement, which fitted the others
        (``PolylineFit.profile.n_flat_vertices`` counts them).
    ``NOT_CONVERGED`` (note: the status stays ``OK``)
        The pose has not settled: the LM stopped (iteration cap or damping
        bound) before an accepted step fell below ``step_tolerance_px``,
        *and* its pose moved more than :data:`SETTLE_SIGMAS` of its own
        one-sigma (and more than ``step_tolerance_px``) over its last
        :data:`SETTLE_ITERATIONS` iterations (see :class:`Settling`). An LM
        that only creeps along the DT's kinks past the cap (the disc demo
        moves 0.005 px between iterations 30 and 66) is settled and carries
        no reason; one stopped far from its minimum (``max_iterations=2``
        from a seed 3 px off) is not.
    ``AMBIGUOUS`` (ambiguous)
        A rival basin -- a pose fitted from another coarse peak or from the
        competing basin of the DT cost, farther than
        :data:`~dtalign.pipeline.hypotheses.BASIN_RADIUS_PX` away -- costs less than
        :data:`~dtalign.pipeline.hypotheses.AMBIGUITY_THRESHOLD` times this one on the
        common footing of :func:`~dtalign.pipeline.hypotheses.robust_cost`: two
        parallel edges of the same polarity, a decoy edge. See
        :attr:`~dtalign.pipeline.PolylineFit.ambiguity`. Not raised when an
        accepted edge-profile refinement lands on the same pose from the
        rival's start too (``PolylineFit.profile.rival_agrees``): the
        image's photometry has then decided between them. When the
        vertices without an edge at the pose are one contiguous stretch of
        the polyline (:func:`no_edge_run`), the message names it: a whole
        circle passed for a limb lit on one side puts its unlit half on the
        terminator in the rival basin.
    ``AMBIGUOUS_ALONG_EDGE`` (note: the status stays ``OK``)
        The rival basin lies along a direction the fit cannot observe (a
        straight edge's along-edge shift): the pose is ambiguous along the
        edge, which its ``inf`` sigma there already says, not across it.
    ``RANK_DEFICIENT`` (note: the status stays ``OK``)
        The polyline's geometry leaves some pose direction unmeasured (a
        straight edge: the along-edge shift; a circle: its rotation). The
        sigmas along it are ``inf``; see
        :attr:`~dtalign.pipeline.PolylineFit.unobservable_directions`.
    """

    # In the order a fit lists them: the likeliest cause first (normals the
    # wrong way make the fit degenerate and can put the seed on the window
    # edge, not the other way round).
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
#: px: median and 90th percentile over the seeded scenes of
#: ``benchmarks/terminator_error.py`` (:ref:`profiles-terminator`: diameter
#: 100-240 px, phase 35-150 deg, any light direction, noise-free and noisy,
#: window (8, 8); seed 2028, 48 scenes, where 21 of the 48 plain fits were
#: ``ok`` and more than 1 px off before the reason). What
#: :attr:`FitReason.TERMINATOR_WITHOUT_PROFILE` warns of.
TERMINATOR_PLAIN_MEDIAN_PX = 4.6
TERMINATOR_PLAIN_P90_PX = 13.8

#: A terminator's accepted profile refinement whose own one-sigma (the
#: square root of its covariance's largest eigenvalue) exceeds this, px, is
#: suspect (:attr:`FitReason.TERMINATOR_IMPRECISE`): an ``ok`` terminator
#: more than 1 px off is then more than three of its sigmas off (0.3 % of a
#: Gaussian's draws along that direction), which is what ``ok`` promises
#: for a terminator (the measurements: docs/profiles.rst, "A barely
#: measured terminator").
TERMINATOR_SIGMA_LIMIT_PX = 1.0 / 3.0

#: What a failed fit's printed summary (:meth:`PolylineFit.summary
#: <dtalign.pipeline.PolylineFit.summary>`) and the command line show for its
#: sigmas: its covariance (``inf``, or finite from a few stray inliers) is no
#: measurement. The numeric fields (``sigma_vu``, ``to_dict``) keep their values.
UNMEASURED_TEXT = "not measured (failed)"

#: The status each reason implies (a fit's status is the worst of them).
SEVERITY: dict[FitReason, FitStatus] = {
    FitReason.OUTSIDE_IMAGE: FitStatus.FAILED,
    FitReason.OUTSIDE_IMAGE_WEIGHTED: FitStatus.SUSPECT,
    FitReason.PARTLY_OUTSIDE_IMAGE: FitStatus.OK,
    FitReason.DEGENERATE: FitStatus.FAILED,
    FitReason.ALL_POLARITY_REJECTED: FitStatus.FAILED,
    FitReason.AT_WINDOW_EDGE: FitStatus.FAILED,
    FitReason.MOST_POLARITY_REJECTED: FitStatus.FAILED,
    FitReason.AMBIGUOUS: FitStatus.AMBIGUOUS,
    FitReason.NOT_CONVERGED: FitStatus.OK,
    FitReason.AMBIGUOUS_ALONG_EDGE: FitStatus.OK,
    FitReason.RANK_DEFICIENT: FitStatus.OK,
    FitReason.PROFILE_REJECTED: FitStatus.SUSPECT,
    FitReason.SOFT_EDGE: FitStatus.SUSPECT,
    FitReason.TERMINATOR_WITHOUT_PROFILE: FitStatus.SUSPECT,
    FitReason.TERMINATOR_IMPRECISE: FitStatus.SUSPECT,
    FitReason.FLAT_PROFILE_VERTICES: FitStatus.OK,
}

_ORDER = (FitStatus.OK, FitStatus.SUSPECT, FitStatus.AMBIGUOUS, FitStatus.FAILED)

#: What each status tells the caller, one sentence: the documentation's
#: status table (``docs/status.rst``) is generated from this and the enums.
STATUS_MEANING: dict[FitStatus, str] = {
    FitStatus.OK: "the pose is a measurement; the fit may carry notes (reasons whose "
    "status is ``ok``).",
    FitStatus.SUSPECT: "the pose is a measurement that should be checked: an edge "
    "profile's refinement was discarded, a limb has no usable edge, a terminator was "
    "fitted without a profile, or vertices outside the image kept weight.",
    FitStatus.AMBIGUOUS: "another basin across the edge fits the image about as well: "
    "the pose may be the wrong one of two.",
    FitStatus.FAILED: "the pose is not a measurement of the image: do not use it.",
}

#: What each reason means and what to do, one or two sentences, in the
#: order a fit lists them: the documentation's reasons table is generated
#: from this, :data:`SEVERITY` and the enum.
REASON_MEANING: dict[FitReason, str] = {
    FitReason.OUTSIDE_IMAGE: "some vertices lie outside the image (the pixel the polarity "
    "test reads, the vertex shifted by the coarse seed and rounded, is not within rows "
    "0..H-1 and columns 0..W-1) and fewer than half of those inside kept any weight: too "
    "few inside to fit. Is the polyline in this image's pixel frame, and the predicted "
    "pose within the search window of the truth?",
    FitReason.OUTSIDE_IMAGE_WEIGHTED: "some vertices lie outside the image and kept weight "
    "(``use_polarity=False``: nothing rejected them): they sample the distance transform "
    "clamped to the image border, the border's distance to an edge, not theirs. Pass only "
    "the vertices inside, or keep the polarity test.",
    FitReason.PARTLY_OUTSIDE_IMAGE: "some vertices lie outside the image, but at least half "
    "of those inside kept their weight and none outside did: the pose is measured by the "
    "inside ones alone, and its sigmas and observable rank are formed from them.",
    FitReason.ALL_POLARITY_REJECTED: "no vertex inside the image has a normal that points "
    "up the image gradient: the normals point the wrong way (flip them), or there is no "
    "gradient under the polyline at all. Comes with ``degenerate``.",
    FitReason.MOST_POLARITY_REJECTED: "more than half of the vertices inside the image see "
    "the gradient the wrong way: are the normals pointing to the bright side? (Or the "
    "polyline lies on the wrong edge, or part of a limb is unlit: the message names a "
    "contiguous stretch of vertices that find no edge.) The pose rests on the few "
    "vertices that happened to agree.",
    FitReason.DEGENERATE: "no vertex kept any weight; the pose is the coarse seed, the "
    "covariance ``inf``. The polyline may be outside the image, no edge may lie near it, "
    "or the noise sigma may be so high that no edge passed the threshold.",
    FitReason.AT_WINDOW_EDGE: "the coarse seed is on the boundary of the search window: "
    "the true offset may lie outside it. Widen ``search_window_vu`` (``--window``).",
    FitReason.AMBIGUOUS: "a rival basin across the edge (another coarse peak, or the DT "
    "cost's competing basin) costs less than 1.5 times this one: two parallel edges of "
    "one polarity, a decoy edge (an accepted edge-profile refinement that reaches the same "
    "pose from the rival's start clears it; the message names a contiguous stretch of "
    "vertices that find no edge, such as a limb's unlit half). See "
    ":attr:`~dtalign.pipeline.PolylineFit.ambiguity`.",
    FitReason.PROFILE_REJECTED: "an edge profile was given but its refinement was "
    "discarded (it could not be computed: too few pixels, a singular or non-finite system; "
    "or it did not converge, walked more than 2 px from the DT lock, or fitted a "
    "non-positive gain; the reason says which): the pose is the DT-LM's, with the edge DT's photometric bias "
    "(tenths of a pixel on a limb). See :attr:`~dtalign.pipeline.PolylineFit.profile`.",
    FitReason.SOFT_EDGE: "the limb profile has no usable edge (its brightness rolls off to "
    "the limb, as a Lambert limb at low phase): the position rests on the modelled roll-off "
    "and on the reflectance law being right.",
    FitReason.TERMINATOR_WITHOUT_PROFILE: "the polyline is declared a terminator and was "
    "fitted without an edge profile: the DT puts a terminator (a kink in brightness, not an "
    f"edge) where the ramp crosses the edge threshold: on rendered Lambert terminators the "
    f"error has median {TERMINATOR_PLAIN_MEDIAN_PX:g} px and 90th percentile "
    f"{TERMINATOR_PLAIN_P90_PX:g} px. Give "
    "``sphere_edge_profile(..., edge=\"terminator\")``. See :ref:`profiles-terminator`.",
    FitReason.TERMINATOR_IMPRECISE: "a terminator's profile refinement reports a one-sigma "
    f"above {TERMINATOR_SIGMA_LIMIT_PX:.2f} px along some direction: the pose is barely measured "
    "there (a terminator near phase 90 deg is nearly straight). See "
    ":attr:`~dtalign.pipeline.PolylineFit.profile`.",
    FitReason.FLAT_PROFILE_VERTICES: "some of a limb's vertices have edge profiles with no "
    "contrast across their strips (an unlit part of the limb): they were left out of "
    "the profile refinement, which fitted the others. Pass the sunlit part of a limb.",
    FitReason.NOT_CONVERGED: "the pose has not settled: the LM stopped before its step "
    "tolerance and its pose still moved more than 0.25 sigma over its last 5 iterations. "
    "Raise ``max_iterations``. See `Converged, settled, and the iteration cap`_.",
    FitReason.AMBIGUOUS_ALONG_EDGE: "the rival basin lies along a direction the fit cannot "
    "observe (a straight edge's along-edge shift): ambiguous along the edge, which its "
    "``inf`` sigma there already says, not across it.",
    FitReason.RANK_DEFICIENT: "the geometry leaves a pose direction unmeasured (a straight "
    "edge: the along-edge shift; a circle: its rotation). The sigmas along it are ``inf``.",
}


def _doc_tables() -> str:
    """The documentation's status and reason tables, as reStructuredText.

    Written to ``docs/_generated/status_tables.rst`` by the Sphinx
    configuration at each build (and compared with that file by
    ``tests/test_docs_status.py``), so the page lists exactly the enums'
    members, in their order, with their :data:`SEVERITY`.
    """
    lines = [".. list-table::", "   :header-rows: 1", "   :widths: 15 85", "",
             "   * - status", "     - meaning"]
    for status in FitStatus:
        lines += [f"   * - ``{status.value}``", f"     - {STATUS_MEANING[status]}"]
    lines += ["", ".. list-table::", "   :header-rows: 1", "   :widths: 25 12 63", "",
              "   * - reason", "     - status", "     - meaning"]
    for reason in FitReason:
        severity = SEVERITY[reason]
        cell = f"``{severity.value}``" if severity is not FitStatus.OK else "note (``ok``)"
        lines += [f"   * - ``{reason.value}``", f"     - {cell}",
                  f"     - {REASON_MEANING[reason]}"]
    return "\n".join(lines) + "\n"


def _n_vertices(fit: Any) -> int:
    return int(fit.lm.residuals_px.shape[0])


def _polarity_rejected_count(fit: Any) -> int:
    """Polarity-rejected vertices inside the image (:func:`outside_mask`): a
    vertex outside is rejected for want of a gradient, not for its normal."""
    rejected = np.asarray(fit.lm.residuals_px) == POLARITY_PENALTY_RESIDUAL
    return int(np.count_nonzero(rejected & ~_outside(fit)))


def outside_mask(fit: Any) -> np.ndarray:
    """Which vertices of ``fit`` lie outside its image, shape (N,) bool.

    A vertex is outside when the pixel the polarity test reads for it is
    not in the image: its position plus the coarse seed
    (``fit.coarse_offset_vu``, the LM's start, where the polarity mask is
    formed), rounded to the nearest pixel as the test rounds it, is not
    within rows ``0 .. H-1`` and columns ``0 .. W-1`` of
    ``fit.image_shape``. All False when the fit records no image shape (one
    built by hand, or read from a dict written before the shape was).
    """
    n = _n_vertices(fit)
    shape = getattr(fit, "image_shape", None)
    verts = getattr(fit, "vertices_vu", None)
    if shape is None or verts is None or np.shape(verts) != (n, 2):
        return np.zeros(n, dtype=bool)
    return _outside_of(np.asarray(verts, dtype=np.float64), fit.coarse_offset_vu, shape)


def _outside(fit: Any) -> np.ndarray:
    """:func:`outside_mask`, read from a :class:`~dtalign.pipeline.PolylineFit`'s cache."""
    cached = getattr(fit, "outside_image", None)
    if cached is not None and np.shape(cached) == (_n_vertices(fit),):
        return np.asarray(cached)
    return outside_mask(fit)


def _outside_of(verts: np.ndarray, seed: Any, shape: Any) -> np.ndarray:
    """``verts`` shifted by ``seed`` and rounded (``np.rint``, the polarity
    test's rounding), outside ``shape``'s rows and columns."""
    h, w = int(shape[0]), int(shape[1])
    iv = np.rint(verts[:, 0] + float(seed[0]))
    iu = np.rint(verts[:, 1] + float(seed[1]))
    return ~((iv >= 0) & (iv < h) & (iu >= 0) & (iu < w))


#: Inliers at most this many in a row inside a stretch of vertices without an
#: edge do not break it (noise lets a few unlit vertices keep weight).
NO_EDGE_GAP = 3

#: The shortest stretch :func:`no_edge_run` names, and the least of the rest,
#: as fractions of the polyline's vertices.
NO_EDGE_MIN_FRACTION = 0.25


@dataclass(frozen=True)
class NoEdgeRun:
    """A contiguous stretch of a polyline's vertices that find no edge (:func:`no_edge_run`).

    Attributes
    ----------
    first, last : int
        Its first and last vertex; ``last < first`` when it wraps past the
        end of a closed polyline to its start.
    length : int
        Vertices in the stretch.
    zero_weight : int
        Of them, those with zero weight.
    rest_inliers : int
        Inliers among the vertices inside the image and outside the stretch.
    rest : int
        Vertices inside the image and outside the stretch.
    """

    first: int
    last: int
    length: int
    zero_weight: int
    rest_inliers: int
    rest: int

    def span(self, n: int) -> str:
        """``"vertices 112-188"``, or ``"vertices 190-199 and 0-8"`` when it wraps."""
        if self.last >= self.first:
            return f"vertices {self.first}-{self.last}"
        return f"vertices {self.first}-{n - 1} and 0-{self.last}"


def no_edge_run(fit: Any) -> NoEdgeRun | None:
    """The contiguous stretch of vertices that find no edge while the rest fit, if any.

    Read from the final weights: the vertices inside the image with zero
    weight (polarity- or Tukey-rejected) are grouped into stretches of
    consecutive vertices (:data:`NO_EDGE_GAP` inliers in a row do not break
    one; a closed polyline, whose last vertex lies within two median
    spacings of its first, wraps). The longest is returned when it holds at
    least :data:`NO_EDGE_MIN_FRACTION` of the vertices, three quarters of
    its own vertices and four fifths of all the zero-weight ones, and the
    vertices outside it (at least that fraction of the polyline too) are
    three-quarters inliers: one part of the polyline finds no edge, the
    rest does, which is what a limb with an unlit part looks like with its
    normals right. None otherwise.
    """
    w = np.asarray(fit.lm.weights)
    n = w.shape[0]
    if n < 8:
        return None
    outside = _outside(fit)
    zero = (w == 0.0) & ~outside
    idx = np.flatnonzero(zero)
    if idx.size == 0:
        return None
    breaks = np.flatnonzero(np.diff(idx) > NO_EDGE_GAP + 1)
    starts = [int(idx[0]), *(int(idx[b + 1]) for b in breaks)]
    ends = [*(int(idx[b]) for b in breaks), int(idx[-1])]
    runs = [(a, b) for a, b in zip(starts, ends, strict=True)]  # b >= a
    if _closed(fit) and len(runs) > 1 and int(idx[0]) + n - int(idx[-1]) <= NO_EDGE_GAP + 1:
        # the last stretch runs on past the end into the first
        runs = [(runs[-1][0], runs[0][1] + n), *runs[1:-1]]
    first, last = max(runs, key=lambda r: r[1] - r[0])
    length = last - first + 1
    members = np.arange(first, last + 1) % n
    in_run = np.zeros(n, dtype=bool)
    in_run[members] = True
    n_zero = int(np.count_nonzero(zero[in_run]))
    rest = ~in_run & ~outside
    n_rest = int(np.count_nonzero(rest))
    rest_inliers = int(np.count_nonzero(w[rest] > 0.0))
    least = NO_EDGE_MIN_FRACTION * n
    if not (length >= least and n_rest >= least and 4 * n_zero >= 3 * length
            and 5 * n_zero >= 4 * idx.size and 4 * rest_inliers >= 3 * n_rest):
        return None
    return NoEdgeRun(first, last % n, length, n_zero, rest_inliers, n_rest)


def _closed(fit: Any) -> bool:
    """Whether the polyline closes on itself: its last vertex within two
    median spacings of its first."""
    verts = np.asarray(getattr(fit, "vertices_vu", np.zeros((0, 2))), dtype=np.float64)
    if verts.ndim != 2 or verts.shape[0] < 3:
        return False
    steps = np.hypot(*np.diff(verts, axis=0).T)
    gap = float(np.hypot(*(verts[0] - verts[-1])))
    return gap <= 2.0 * float(np.median(steps))


def _no_edge_hint(fit: Any) -> str:
    """The clause naming :func:`no_edge_run`'s stretch, or "" when there is none."""
    run = no_edge_run(fit)
    if run is None:
        return ""
    n = _n_vertices(fit)
    return (f"{run.span(n)} ({run.length} of {n}, one contiguous stretch of the polyline) "
            f"find no edge while the rest fit ({run.rest_inliers} inliers of {run.rest}): "
            "is that part of the limb unlit? pass only the sunlit part")


#: Iterations over which an unconverged LM's pose movement is judged: enough
#: to span a few of the damping's rejected steps (which count as
#: iterations), few enough that a fit stopped early still shows its descent.
SETTLE_ITERATIONS = 5

#: An unconverged pose has settled when its movement over the last
#: :data:`SETTLE_ITERATIONS` iterations is at most this many of its own
#: one-sigma (the Mahalanobis length under the fit's covariance): further
#: iterations could then move it by a small fraction of its uncertainty.
#: Over the seeded disc scenes and the :mod:`dtalign.robustness` families
#: the settled fits moved at most 0.28 sigma, most exactly 0; a fit stopped
#: after 2 iterations from a seed 3 px off moved 17-20 sigma.
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


def settled(fit: Any) -> bool:
    """Whether a fit's pose is settled: the LM converged, or its :class:`Settling` says so.

    A fit without a :class:`Settling` (one made by hand, or a rival
    hypothesis) falls back on the LM's own ``converged``.
    """
    if fit.lm.converged:
        return True
    s = getattr(fit, "settling", None)
    return s is not None and bool(s.settled)


def _not_converged_text(fit: Any) -> str:
    s = getattr(fit, "settling", None)
    n = fit.lm.iterations
    if s is None:
        return (f"not converged: the LM stopped after {n} iterations before its step fell "
                "below step_tolerance_px (raise max_iterations)")
    return (f"not converged: the pose still moved {s.shift_px:.3g} px "
            f"({s.shift_sigmas:.3g} sigma) over the LM's last {s.iterations} of {n} "
            "iterations (raise max_iterations)")


def fit_problems(fit: Any) -> tuple[FitReason, ...]:
    """Every reason but ``RANK_DEFICIENT`` (the one that needs the observable rank).

    Cheap: a few attribute reads, and a count of the polarity-rejected
    vertices only when at most half the vertices are inliers (a
    polarity-rejected vertex has zero weight, so it cannot be the majority
    otherwise).

    Parameters
    ----------
    fit : PolylineFit
        Or any record with its ``lm``, ``at_window_edge`` and, where present,
        ``ambiguity``, ``profile``, ``edge_kind`` and ``settling``.

    Returns
    -------
    tuple of FitReason
        In the order of :class:`FitReason`.
    """
    lm = fit.lm
    n = _n_vertices(fit)
    n_out = int(np.count_nonzero(_outside(fit)))
    n_in = n - n_out  # the polarity reasons count only these
    rejected = _polarity_rejected_count(fit) if 2 * lm.inlier_count < n_in else 0
    out: list[FitReason] = []
    if n_out:
        # too few inside to fit: fewer than half of them kept any weight
        inliers_in = _inside_inliers(fit)
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
    if lm.degenerate:  # nothing was measured: convergence means nothing
        return tuple(out)
    ambiguity = getattr(fit, "ambiguity", None)
    profile = getattr(fit, "profile", None)
    # an accepted profile refinement that lands on the same pose from the
    # rival basin's start has let the image decide between the two
    decided = (profile is not None and profile.accepted
               and getattr(profile, "rival_agrees", None) is True)
    if (ambiguity is not None and ambiguity.ambiguous and not ambiguity.along_unobservable
            and not decided):
        out.append(FitReason.AMBIGUOUS)
    if profile is not None:
        if not profile.accepted:
            out.append(FitReason.PROFILE_REJECTED)
        if profile.soft_edge:
            out.append(FitReason.SOFT_EDGE)
        if (profile.accepted and getattr(fit, "edge_kind", None) == "terminator"
                and _profile_sigma(profile) > TERMINATOR_SIGMA_LIMIT_PX):
            out.append(FitReason.TERMINATOR_IMPRECISE)
        if getattr(profile, "n_flat_vertices", 0) > 0:
            out.append(FitReason.FLAT_PROFILE_VERTICES)
    elif getattr(fit, "edge_kind", None) == "terminator":
        out.append(FitReason.TERMINATOR_WITHOUT_PROFILE)
    if not settled(fit):
        out.append(FitReason.NOT_CONVERGED)
    if ambiguity is not None and ambiguity.ambiguous and ambiguity.along_unobservable:
        out.append(FitReason.AMBIGUOUS_ALONG_EDGE)
    return tuple(out)


def _profile_sigma(profile: Any) -> float:
    """The largest one-sigma of a profile refinement's offset, px (inf when not finite)."""
    cov = np.asarray(profile.covariance, dtype=np.float64)
    if not np.isfinite(cov).all():
        return float("inf")
    return float(np.sqrt(max(float(np.linalg.eigvalsh(cov).max()), 0.0)))


def fit_reasons(fit: Any) -> tuple[FitReason, ...]:
    """:func:`fit_problems`, plus ``RANK_DEFICIENT`` when the geometry leaves a direction unmeasured.

    Parameters
    ----------
    fit : PolylineFit
        As :func:`fit_problems` reads it, with ``observable_rank`` and ``fit_rotation``.

    Returns
    -------
    tuple of FitReason
        In the order of :class:`FitReason`.
    """
    out = fit_problems(fit)
    if not fit.lm.degenerate and fit.observable_rank < (3 if fit.fit_rotation else 2):
        out += (FitReason.RANK_DEFICIENT,)
    return out


def fit_status(reasons: Iterable[FitReason]) -> FitStatus:
    """The worst severity among ``reasons`` (``OK`` when empty)."""
    return max((SEVERITY[r] for r in reasons), key=_ORDER.index, default=FitStatus.OK)


def _inside_inliers(fit: Any) -> int:
    """Inliers among the vertices inside the image (with ``use_polarity=False``
    an outside vertex, on the border's clamped distance transform, may be one)."""
    return int(np.count_nonzero((np.asarray(fit.lm.weights) > 0.0) & ~_outside(fit)))


def _outside_text(fit: Any, reason: FitReason) -> str:
    """:func:`_explain` of the two outside reasons: ``"140 of 200 vertices lie
    outside the 320 x 320 image"`` and what the ones inside did."""
    n = _n_vertices(fit)
    k = int(np.count_nonzero(_outside(fit)))
    h, w = fit.image_shape
    head = f"{k} of {n} vertices lie outside the {h} x {w} image"
    inside, inliers = n - k, _inside_inliers(fit)
    if reason is FitReason.PARTLY_OUTSIDE_IMAGE:
        text = (f"{head}: the pose is measured by the {inside} inside ({inliers} inliers), "
                "its sigmas by their geometry")
        return text
    if reason is FitReason.OUTSIDE_IMAGE_WEIGHTED:
        return (f"{head}, and {fit.lm.inlier_count - inliers} of them kept weight beside the "
                f"{inliers} inliers inside: without the polarity test they sample the distance "
                "transform clamped to the image border, the border's distance to an edge, not "
                "theirs (pass only the vertices inside, or use the polarity test)")
    if inside == 0:
        return (f"{head}: nothing inside to fit (is the polyline in this image's pixel frame, "
                "(v, u) = (row, column)? is the predicted pose this far off?)")
    return (f"{head}, and only {inliers} of the {inside} inside kept any weight: too few to "
            "fit (is the predicted pose off by more than the search window?)")


def _polarity_text(fit: Any, reason: FitReason) -> str:
    """:func:`_explain` of the polarity reasons, over the vertices inside the image."""
    n = _n_vertices(fit)
    n_in = n - int(np.count_nonzero(_outside(fit)))
    if reason is FitReason.ALL_POLARITY_REJECTED:
        # with vertices outside, those are named first and not counted here
        who, where = ((f"all {n} vertices", "outside the image, or no edge there") if n_in == n
                      else (f"all {n_in} vertices inside the image", "no edge there"))
        return (
            f"{who} polarity-rejected: the normals point the wrong way (they must "
            "point up the image gradient, toward the brighter side: flip them), or there is "
            f"no gradient under the polyline ({where})"
        )
    k = _polarity_rejected_count(fit)
    counts = (f"{k} of {n} polarity-rejected, {fit.lm.inlier_count} inliers" if n_in == n
              else f"{k} of the {n_in} inside polarity-rejected, {fit.lm.inlier_count} inliers")
    who = "most vertices" if n_in == n else "most vertices inside the image"
    hint = _no_edge_hint(fit)
    question = ("are the normals pointing to the bright side? (they must point up the image "
                "gradient; flip them if not)")
    if n_in != n:  # a polyline partly off the image is most likely displaced
        question = "is there an edge under them (is the polyline displaced)? " + question
    if hint:
        return (f"{who} see the gradient the wrong way ({counts}): {hint}; if not, "
                + question)
    return f"{who} see the gradient the wrong way ({counts}): {question}"


def _explain(fit: Any, reason: FitReason) -> str:
    n = _n_vertices(fit)
    if reason in (FitReason.OUTSIDE_IMAGE, FitReason.PARTLY_OUTSIDE_IMAGE,
                  FitReason.OUTSIDE_IMAGE_WEIGHTED):
        return _outside_text(fit, reason)
    if reason in (FitReason.ALL_POLARITY_REJECTED, FitReason.MOST_POLARITY_REJECTED):
        return _polarity_text(fit, reason)
    if reason is FitReason.DEGENERATE:
        return (
            f"degenerate: no vertex of {n} kept any weight, the pose is the coarse seed "
            f"{tuple(fit.coarse_offset_vu)} (is the polyline inside the image? is there an "
            f"edge near it? noise sigma {fit.noise_sigma:.4g}: too high for any edge to pass?)"
        )
    if reason is FitReason.AT_WINDOW_EDGE:
        return (
            f"at window edge: the coarse seed {tuple(fit.coarse_offset_vu)} is on the edge of "
            f"the search window ±{tuple(fit.search_window_vu)}; the true offset may lie outside "
            "it: widen search_window_vu"
        )
    if reason is FitReason.AMBIGUOUS:
        # no label of its own: the status already says "ambiguous"; the hint
        # names the vertices without an edge when they are one stretch
        hint = _no_edge_hint(fit)
        return str(fit.ambiguity.reason) + (f"; at this pose {hint}" if hint else "")
    if reason is FitReason.AMBIGUOUS_ALONG_EDGE:
        # the along-edge text ends "ambiguous along the edge, not across it"
        return str(fit.ambiguity.reason)
    if reason is FitReason.NOT_CONVERGED:
        return _not_converged_text(fit)
    if reason in _PROFILE_REASONS:
        return _explain_profile(fit, reason)
    p = 3 if fit.fit_rotation else 2
    dirs = "; ".join(
        "(" + ", ".join(f"{round(float(x), 4) + 0.0:g}" for x in e) + ")"
        for e in fit.unobservable_directions
    )
    # a failed fit's sigmas are no measurement anywhere: no "inf" to read there
    there = "" if fit_status(fit_problems(fit)) is FitStatus.FAILED else " (sigma inf there)"
    return (
        f"rank deficient: observable rank {fit.observable_rank} of {p}; the pose is not "
        f"measured along {dirs}{there}"
    )


#: The reasons about an edge's photometric profile (:func:`_explain_profile`).
_PROFILE_REASONS = frozenset({FitReason.PROFILE_REJECTED, FitReason.TERMINATOR_WITHOUT_PROFILE,
                              FitReason.TERMINATOR_IMPRECISE, FitReason.SOFT_EDGE,
                              FitReason.FLAT_PROFILE_VERTICES})


def _explain_profile(fit: Any, reason: FitReason) -> str:
    """:func:`_explain` of the reasons about the edge's photometric profile."""
    if reason is FitReason.PROFILE_REJECTED:
        return (
            f"profile refinement rejected: {fit.profile.reason}; the pose is the DT-LM's "
            "(biased by the edge DT's photometric offset)"
        )
    if reason is FitReason.TERMINATOR_WITHOUT_PROFILE:
        return (
            "terminator without a profile: the DT puts a terminator where the brightness ramp "
            f"crosses the edge threshold (on rendered Lambert terminators the median error is "
            f"{TERMINATOR_PLAIN_MEDIAN_PX:g} px); fit it with "
            "sphere_edge_profile(..., edge='terminator')"
        )
    if reason is FitReason.TERMINATOR_IMPRECISE:
        return (
            f"terminator imprecise: the profile refinement's one-sigma is "
            f"{_profile_sigma(fit.profile):.3g} px along some direction (above "
            f"{TERMINATOR_SIGMA_LIMIT_PX:.2f} px): the pose is barely measured there"
        )
    if reason is FitReason.FLAT_PROFILE_VERTICES:
        n = len(fit.vertices_vu)
        return (
            f"{fit.profile.n_flat_vertices} of {n} vertices' profiles have no contrast (an unlit "
            "part of a limb?): left out of the profile refinement"
        )
    assert reason is FitReason.SOFT_EDGE
    return (
        f"soft edge: the profile's step at the edge is {fit.profile.step_jump:.2f} of its "
        "contrast (the brightness rolls off to the edge, as a limb at low phase): the "
        "position rests on the modelled roll-off and the reflectance law"
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
                or getattr(fit, "profile", None) is not None
                or getattr(fit, "edge_kind", None) == "terminator"
                or _outside(fit).any()):
            log_fit(fit, f"{label}[{i}]")
