"""What a fit measured: which of its vertices, and whether its pose settled.

A vertex measures nothing when it lies outside the image (no gradient to
read, so the polarity test rejects it), when its normal disagrees with
the gradient, or when it finds no edge; an LM stopped before its step
tolerance may still have been moving (:class:`Settling`).
:mod:`dtalign.pipeline.status` reads these to say why a fit failed or
what it lacks. Nothing here imports Numba.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..api.constants import POLARITY_PENALTY_RESIDUAL

__all__ = ["NO_EDGE_GAP", "NO_EDGE_MIN_FRACTION", "SETTLE_ITERATIONS", "SETTLE_SIGMAS",
           "NoEdgeRun", "Settling", "inside_inliers", "n_vertices", "no_edge_hint",
           "no_edge_run", "outside", "outside_mask", "polarity_rejected_inside"]


def n_vertices(fit: Any) -> int:
    return int(fit.lm.residuals_px.shape[0])


def polarity_rejected_inside(fit: Any) -> int:
    """Polarity-rejected vertices inside the image (:func:`outside_mask`): a
    vertex outside is rejected for want of a gradient, not for its normal."""
    rejected = np.asarray(fit.lm.residuals_px) == POLARITY_PENALTY_RESIDUAL
    return int(np.count_nonzero(rejected & ~outside(fit)))


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
    n = n_vertices(fit)
    shape = getattr(fit, "image_shape", None)
    verts = getattr(fit, "vertices_vu", None)
    if shape is None or verts is None or np.shape(verts) != (n, 2):
        return np.zeros(n, dtype=bool)
    return _outside_of(np.asarray(verts, dtype=np.float64), fit.coarse_offset_vu, shape)


def outside(fit: Any) -> np.ndarray:
    """:func:`outside_mask`, read from a :class:`~dtalign.pipeline.PolylineFit`'s cache."""
    cached = getattr(fit, "outside_image", None)
    if cached is not None and np.shape(cached) == (n_vertices(fit),):
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
    out = outside(fit)
    zero = (w == 0.0) & ~out
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
    rest = ~in_run & ~out
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


def no_edge_hint(fit: Any) -> str:
    """The clause naming :func:`no_edge_run`'s stretch, or "" when there is none."""
    run = no_edge_run(fit)
    if run is None:
        return ""
    n = n_vertices(fit)
    return (f"{run.span(n)} ({run.length} of {n}, one contiguous stretch of the polyline) "
            f"find no edge while the rest fit ({run.rest_inliers} inliers of {run.rest}): "
            "is that part of the limb unlit? pass only the sunlit part")


def inside_inliers(fit: Any) -> int:
    """Inliers among the vertices inside the image (with ``use_polarity=False``
    an outside vertex, on the border's clamped distance transform, may be one)."""
    return int(np.count_nonzero((np.asarray(fit.lm.weights) > 0.0) & ~outside(fit)))


#: Iterations over which an unconverged LM's pose movement is judged: enough
#: to span a few of the damping's rejected steps (which count as
#: iterations), few enough that a fit stopped early still shows its descent.
SETTLE_ITERATIONS = 5

#: An unconverged pose has settled when its movement over the last
#: :data:`SETTLE_ITERATIONS` iterations is at most this many of its own
#: one-sigma (the Mahalanobis length under the fit's covariance): further
#: iterations could then move it by a small fraction of its uncertainty.
SETTLE_SIGMAS = 0.25


@dataclass(frozen=True)
class Settling:
    """How far an unconverged LM's pose moved over its last iterations.

    Made by :func:`dtalign.pipeline.fit.settle` (which says how) for a fit
    whose LM stopped before an accepted step fell below ``step_tolerance_px``.

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
