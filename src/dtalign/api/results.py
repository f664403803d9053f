"""Frozen result types returned by the fitters (:ref:`contract-lm`), and
the image side's configuration, :class:`ImageDerivativesConfig` (section 5)."""

from __future__ import annotations

import dataclasses
import enum
import math
from dataclasses import dataclass, fields

import numpy as np
from numpy.typing import NDArray

from .constants import (
    DEFAULT_DT_HALF_WIDTH_PX,
    DEFAULT_EDGE_THRESHOLD_K_SIGMA,
    DEFAULT_IMAGE_GRADIENT_SIGMA_PX,
)

__all__ = [
    "CoarseSearchResult",
    "ImageDerivativesConfig",
    "LMRefineResult",
    "RidgeRefineResult",
    "SecondaryBasin",
]

#: Arrays up to this many elements are printed in full by ``summary()`` (a
#: 3 x 3 covariance); larger ones (per-vertex residuals) as a digest.
_SUMMARY_FULL_ARRAY_MAX = 9


def _format_array(value: np.ndarray) -> str:
    if value.size <= _SUMMARY_FULL_ARRAY_MAX:
        text = np.array2string(value, precision=6, separator=", ", max_line_width=10_000)
        return " ".join(text.split())
    head = f"array {value.shape} {value.dtype}"
    if value.dtype.kind not in "fiu":
        return head
    data = np.asarray(value, dtype=np.float64).ravel()
    finite = data[np.isfinite(data)]
    if finite.size == 0:
        return f"{head}, no finite value"
    text = (
        f"{head}: min {finite.min():.4g}, median {float(np.median(finite)):.4g}, "
        f"max {finite.max():.4g}"
    )
    if finite.size < data.size:
        text += f", {data.size - finite.size} non-finite"
    return text


def _format_value(value: object, indent: str) -> str:
    if isinstance(value, np.ndarray):
        return _format_array(value)
    if isinstance(value, (bool, np.bool_)):
        return str(bool(value))
    if isinstance(value, (float, np.floating)):
        if not math.isfinite(value):
            return str(float(value))
        text = f"{float(value):.6g}"
        return text if any(c in text for c in ".e") else text + ".0"
    if isinstance(value, enum.Enum):
        return str(value.value)
    if isinstance(value, tuple) and all(isinstance(x, (int, float, np.number, enum.Enum)) for x in value):
        return "(" + ", ".join(_format_value(x, indent) for x in value) + ")"
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return summary_text(value, indent + "    ").lstrip()
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k!r}: {_format_value(v, indent)}" for k, v in value.items()) + "}"
    return repr(value)


def summary_text(obj: object, indent: str = "", extra: tuple[str, ...] = (),
                 text: dict[str, str] | None = None) -> str:
    """``Type`` then one ``name: value`` line per field, arrays summarised.

    Generic over the dataclass's fields (those with ``repr=True``), so a new
    field shows up without touching this; in the manner of SciPy's
    ``OptimizeResult``, but an array of more than a few elements is shown
    as its shape and min / median / max rather than in full. ``extra``
    names properties to print after the fields; ``text`` gives, by name,
    what to print instead of a value (a failed fit's sigmas, which are no
    measurement, as words rather than ``inf``).
    """
    text = text or {}
    assert dataclasses.is_dataclass(obj)
    names = [f.name for f in dataclasses.fields(obj) if f.repr]
    names += [n for n in extra if n not in names]  # derived readings worth a line
    width = max((len(n) for n in names), default=0)
    lines = [f"{indent}{type(obj).__name__}"]
    for name in names:
        shown = text[name] if name in text else _format_value(getattr(obj, name), indent)
        lines.append(f"{indent}  {name:>{width}}: {shown}")
    return "\n".join(lines)


def _readonly(name: str, value: object) -> NDArray[np.float64]:
    if not isinstance(value, np.ndarray):
        raise TypeError(f"LMRefineResult.{name} must be an ndarray; got {type(value).__name__}")
    # A read-only view: the result cannot be edited through it, and the
    # caller's own array (if they built the result by hand) is untouched.
    view = value.view()
    view.flags.writeable = False
    return view


class _Printed:
    """A result printed field by field: a field added to it shows up too."""

    __slots__ = ()

    def summary(self) -> str:
        """A short text summary: one line per field, the per-vertex arrays
        as their shape and min / median / max (``repr`` gives the same)."""
        return summary_text(self)

    def __repr__(self) -> str:
        return summary_text(self)


# repr=False: the dataclass would otherwise write its own __repr__ over _Printed's.
@dataclass(frozen=True, repr=False)
class LMRefineResult(_Printed):
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


@dataclass(frozen=True, repr=False)
class RidgeRefineResult(_Printed):
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
    """Outcome of the scored coarse searches (:ref:`contract-coarse-scored`).

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
    """The best integer shift outside the converged basin (:ref:`contract-basin`).

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


@dataclass(frozen=True)
class ImageDerivativesConfig:
    """Tunables of the image-side products.

    Parameters
    ----------
    image_gradient_sigma_px : float
        Gaussian pre-smoothing sigma of the Sobel gradient, pixels.
    edge_threshold_k_sigma : float
        Edge threshold on the gradient magnitude, in noise sigmas.
    dt_half_width_px : float
        Truncation of the edge distance transform, pixels.

    Every field must be a finite positive number (ValueError otherwise).
    """

    image_gradient_sigma_px: float = DEFAULT_IMAGE_GRADIENT_SIGMA_PX
    edge_threshold_k_sigma: float = DEFAULT_EDGE_THRESHOLD_K_SIGMA
    dt_half_width_px: float = DEFAULT_DT_HALF_WIDTH_PX

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            ok = (
                not isinstance(value, (bool, np.bool_))
                and isinstance(value, (int, float, np.integer, np.floating))
                and math.isfinite(float(value))
                and float(value) > 0.0
            )
            if not ok:
                raise ValueError(f"{f.name} must be a finite positive number; got {value!r}")
            object.__setattr__(self, f.name, float(value))
