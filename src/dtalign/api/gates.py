"""Fit-quality gates of today's techniques (:ref:`contract-gates`).

A fit can converge and still be spurious: most of its vertices rejected
for polarity, the LM stopped early while many were rejected, or a coarse
peak so weak that the seed was a guess. These gates turn a fit's numbers
into named reasons and an optional confidence cap; the thresholds are the
techniques' tuning (they ship 0.84, 0.35, 0.10 and 0.05).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

__all__ = ["DTFitGateConfig", "DTFitGateVerdict", "evaluate_dt_fit_gates"]


@dataclass(frozen=True)
class DTFitGateConfig:
    """Thresholds of :func:`evaluate_dt_fit_gates`, each in ``[0, 1]``.

    Attributes
    ----------
    lm_unconverged_confidence_cap : float
        Confidence cap reported for a fit whose LM did not converge.
    spurious_max_polarity_rejection_fraction : float
        A polarity-rejected fraction at or above this is spurious.
    spurious_unconverged_polarity_rejection_fraction : float
        The same, for an unconverged fit (a lower bar).
    spurious_min_coarse_peak_fraction : float
        A coarse peak score below this is spurious.

    Each value is checked as ``float(value)`` (finite, in ``[0, 1]``,
    ValueError otherwise) and stored as given.
    """

    lm_unconverged_confidence_cap: float
    spurious_max_polarity_rejection_fraction: float
    spurious_unconverged_polarity_rejection_fraction: float
    spurious_min_coarse_peak_fraction: float

    def __post_init__(self) -> None:
        for f in fields(self):
            value = float(getattr(self, f.name))
            if not (math.isfinite(value) and 0.0 <= value <= 1.0):
                raise ValueError(f"DTFitGateConfig.{f.name} must be in [0, 1]; got {value!r}")

    @classmethod
    def from_tuning(cls, mapping: Mapping[str, Any]) -> DTFitGateConfig:
        """The config from a tuning mapping: ``float(mapping[name])`` per field,
        in field order; the first missing key raises ``KeyError(key)``, extra
        keys are ignored."""
        return cls(*(float(mapping[f.name]) for f in fields(cls)))


@dataclass(frozen=True)
class DTFitGateVerdict:
    """Outcome of :func:`evaluate_dt_fit_gates`.

    Attributes
    ----------
    spurious_reasons : tuple of str
        The gates that fired, in the order ``'polarity_rejection_fraction'``,
        ``'lm_unconverged_with_polarity_rejection'``, ``'coarse_peak_fraction'``.
    confidence_cap : float or None
        None for a converged fit, else the config's unconverged cap.
    polarity_rejection_fraction : float
        Rejected vertices over the total (0 without polarity).
    coarse_peak_fraction : float
        The coarse score the gates saw.
    lm_converged : bool
        Whether the LM converged.
    """

    spurious_reasons: tuple[str, ...]
    confidence_cap: float | None
    polarity_rejection_fraction: float
    coarse_peak_fraction: float
    lm_converged: bool

    @property
    def spurious(self) -> bool:
        """True when any gate fired."""
        return bool(self.spurious_reasons)


def evaluate_dt_fit_gates(
    lm_result: Any,
    gate_config: DTFitGateConfig,
    *,
    coarse_peak_fraction: float,
    total_vertex_count: int,
    use_polarity: bool,
) -> DTFitGateVerdict:
    """Apply the fit-quality gates to an LM result (:ref:`contract-gates`).

    Parameters
    ----------
    lm_result : LMRefineResult
        The fit; its ``polarity_rejected_count`` and ``converged`` are read.
    gate_config : DTFitGateConfig
        Thresholds.
    coarse_peak_fraction : float
        Score of the coarse seed (``CoarseSearchResult.score``). A NaN
        never fires its gate.
    total_vertex_count : int
        Vertices of the polyline.
    use_polarity : bool
        Whether the fit used polarity; without it only the coarse gate applies.

    Returns
    -------
    DTFitGateVerdict
    """
    if use_polarity and total_vertex_count > 0:
        frac = lm_result.polarity_rejected_count / total_vertex_count
    else:
        frac = 0.0
    converged = bool(lm_result.converged)
    reasons = []
    if use_polarity and frac >= float(gate_config.spurious_max_polarity_rejection_fraction):
        reasons.append("polarity_rejection_fraction")
    if (use_polarity and not converged
            and frac >= float(gate_config.spurious_unconverged_polarity_rejection_fraction)):
        reasons.append("lm_unconverged_with_polarity_rejection")
    if coarse_peak_fraction < float(gate_config.spurious_min_coarse_peak_fraction):
        reasons.append("coarse_peak_fraction")
    return DTFitGateVerdict(
        spurious_reasons=tuple(reasons),
        confidence_cap=None if converged else gate_config.lm_unconverged_confidence_cap,
        polarity_rejection_fraction=float(frac),
        coarse_peak_fraction=float(coarse_peak_fraction),
        lm_converged=converged,
    )
