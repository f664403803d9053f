"""Frozen result types returned by the fitters (SPEC sections 3 and 4)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["CoarseSearchResult", "LMRefineResult", "RidgeRefineResult", "SecondaryBasin"]


def _readonly(name: str, value: object) -> NDArray[np.float64]:
    if not isinstance(value, np.ndarray):
        raise TypeError(f"LMRefineResult.{name} must be an ndarray; got {type(value).__name__}")
    # A read-only view: the result cannot be edited through it, and the
    # caller's own array (if they built the result by hand) is untouched.
    view = value.view()
    view.flags.writeable = False
    return view


@dataclass(frozen=True)
class LMRefineResult:
    """Outcome of :func:`dtalign.lm_subpixel_refine`.

    Attributes
    ----------
    offset_vu : tuple of float
        Fitted translation ``(dv, du)`` in pixels.
    rotation_rad : float
        Fitted rotation about the pivot (the initial rotation when rotation
        is not fitted).
    covariance : ndarray, shape (P, P)
        Pseudoinverse of the information matrix ``J^T W J`` at the final
        pose (P = 2, or 3 with rotation); all ``+inf`` when degenerate.
    residuals_px : ndarray, shape (N,)
        DT residual of every vertex at the final pose; polarity-rejected
        vertices carry the penalty residual ``1e6``.
    weights : ndarray, shape (N,)
        Final IRLS weights ``(1 / sigma^2) * tukey * polarity``.
    rms_px : float
        Weighted RMS residual, ``+inf`` when degenerate.
    raw_rms_px : float
        Unweighted RMS residual over the polarity-accepted vertices (all of
        them without polarity); ``+inf`` when none is accepted.
    iterations : int
        LM iterations taken (accepted and rejected steps).
    converged : bool
        True when an accepted step fell below the step tolerance, or the
        final ridge polish ran, was applied and converged.
    inlier_count : int
        Number of vertices with a positive weight.
    degenerate : bool
        True when no vertex carries weight: the covariance is then ``+inf``.
    polarity_rejected_count : int
        Vertices the seed polarity mask rejected (0 without polarity).
    """

    offset_vu: tuple[float, float]
    rotation_rad: float
    covariance: NDArray[np.float64]
    residuals_px: NDArray[np.float64]
    weights: NDArray[np.float64]
    rms_px: float
    raw_rms_px: float
    iterations: int
    converged: bool
    inlier_count: int
    degenerate: bool
    polarity_rejected_count: int = 0

    def __post_init__(self) -> None:
        for name in ("covariance", "residuals_px", "weights"):
            object.__setattr__(self, name, _readonly(name, getattr(self, name)))

    @classmethod
    def _from_kernel(
        cls,
        offset_vu: tuple[float, float],
        rotation_rad: float,
        covariance: NDArray[np.float64],
        residuals_px: NDArray[np.float64],
        weights: NDArray[np.float64],
        rms_px: float,
        raw_rms_px: float,
        iterations: int,
        converged: bool,
        inlier_count: int,
        degenerate: bool,
        polarity_rejected_count: int,
    ) -> LMRefineResult:
        """Wrap arrays a kernel just allocated (nobody else holds them).

        Same fields and invariants as the constructor; the arrays are made
        read-only in place instead of through views, and the frozen
        ``__setattr__`` is bypassed once: this runs on every fit and the
        generated ``__init__`` costs several microseconds.
        """
        for arr in (covariance, residuals_px, weights):
            arr.flags.writeable = False
        obj = object.__new__(cls)
        obj.__dict__.update(
            offset_vu=offset_vu, rotation_rad=rotation_rad, covariance=covariance,
            residuals_px=residuals_px, weights=weights, rms_px=rms_px, raw_rms_px=raw_rms_px,
            iterations=iterations, converged=converged, inlier_count=inlier_count,
            degenerate=degenerate, polarity_rejected_count=polarity_rejected_count,
        )
        return obj


@dataclass(frozen=True)
class RidgeRefineResult:
    """Outcome of :func:`dtalign.gradient_ridge_refine`.

    Attributes
    ----------
    offset_vu : tuple of float
        Refined translation, or the input offset when ``applied`` is False.
    rotation_rad : float
        Refined rotation, or the input rotation when ``applied`` is False.
    iterations : int
        Gauss-Newton iterations run.
    converged : bool
        True when a step fell below the step tolerance.
    applied : bool
        False when no iteration ran or the polish walked farther than
        ``max_total_displacement_px``; the inputs are then returned.
    """

    offset_vu: tuple[float, float]
    rotation_rad: float
    iterations: int
    converged: bool
    applied: bool


@dataclass(frozen=True)
class CoarseSearchResult:
    """Outcome of the scored coarse searches (SPEC section 8.2).

    Attributes
    ----------
    offset_vu : tuple of int
        The best integer shift ``(dv, du)``.
    score : float
        Its score, floored at 0: the edge match fraction (or the sum of a
        float edge mask's values over the count) for
        :func:`dtalign.coarse_ncc_search_scored`, the mean polarity
        agreement for :func:`dtalign.coarse_polarity_search_scored`.
    """

    offset_vu: tuple[int, int]
    score: float


@dataclass(frozen=True)
class SecondaryBasin:
    """The best integer shift outside the converged basin (SPEC section 8.4).

    Attributes
    ----------
    offset_vu : tuple of int
        The rival shift ``(dv, du)``.
    distance_px : float
        Its distance from the converged offset.
    cost_px : float
        Mean DT sample of the shifted vertices there.
    converged_cost_px : float
        The same cost at the converged offset.
    """

    offset_vu: tuple[int, int]
    distance_px: float
    cost_px: float
    converged_cost_px: float
