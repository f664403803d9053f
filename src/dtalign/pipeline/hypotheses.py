"""Several basins, one verdict: multi-start fits and the ambiguity figure.

The LM converges into the basin its seed picks; a wrong seed gives a
confident wrong answer. Here each candidate pose (an LM fit from each of
the K best distinct coarse seeds, and from the competing basin of the DT
cost) is scored on one common footing, :func:`robust_cost`: the same
vertices, the same prior sigmas, the polarity of each vertex judged at
the pose being scored, and Tukey's bounded loss, so a pose is never
cheaper for having rejected more vertices. The cheapest wins (ties go to
the earlier hypothesis: the single search's seed first), and the best
*rival basin* -- the cheapest hypothesis whose pose lies farther than
:data:`BASIN_RADIUS_PX` from the winner's -- gives the ambiguity figure
``(rival cost + floor) / (winner cost + floor)``: near 1, the image
supports two poses about equally well.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from ..api.basin import find_secondary_dt_minimum
from ..api.constants import DEFAULT_TUKEY_C
from ..api.sampling import rotate_directions, rotate_vertices, sample_dt_bilinear
from ..api.weights import polarity_filter
from .jobs import seed_of
from .seeds import peaks_of

__all__ = [
    "AMBIGUITY_THRESHOLD",
    "BASIN_RADIUS_PX",
    "Ambiguity",
    "Hypothesis",
    "ambiguity_of",
    "robust_cost",
]

#: Two fitted poses closer than this are the same basin (the LM's own
#: capture range on a DT is a few pixels; a 1.5 px ridge polish is a polish).
BASIN_RADIUS_PX = 2.0

#: A rival basin whose cost is within this factor of the winner's makes the
#: fit ambiguous. Calibrated on :mod:`dtalign.robustness`: a same-polarity
#: decoy edge costs 1.0-1.3x the true one, a clean unique fit's best rival
#: several times more (docs/robustness.rst has the table).
AMBIGUITY_THRESHOLD = 1.5

#: Added to both costs of the ratio, per vertex: keeps a near-perfect fit
#: (cost ~0 on a noiseless image) from making any rival look infinitely
#: worse. 0.05 is the loss of a vertex 0.3 sigma off its edge.
COST_FLOOR_PER_VERTEX = 0.05


def tukey_rho(x: NDArray[np.float64], c: float) -> NDArray[np.float64]:
    """Tukey's biweight loss ``(c^2/6) (1 - (1 - (x/c)^2)^3)``, ``c^2/6`` beyond ``c``."""
    with np.errstate(over="ignore", invalid="ignore"):
        s = np.minimum((x / c) ** 2, 1.0)
    rho = (c * c / 6.0) * (1.0 - (1.0 - s) ** 3)
    return np.where(np.isnan(rho), c * c / 6.0, rho)


def robust_cost(
    edge_dt: NDArray[np.float64],
    gradient_vu: NDArray[np.float64],
    vertices_vu: NDArray[np.float64],
    normals_vu: NDArray[np.float64],
    sigmas: NDArray[np.float64],
    *,
    offset_vu: tuple[float, float],
    rotation_rad: float = 0.0,
    pivot_vu: tuple[float, float] = (0.0, 0.0),
    use_polarity: bool = True,
    tukey_c: float = DEFAULT_TUKEY_C,
) -> tuple[float, int]:
    """The common-footing cost of a pose: ``sum rho(DT / sigma)`` and its inliers.

    Every vertex counts: one whose normal disagrees with the gradient at the
    pose (with ``use_polarity``) or that lies outside the image costs the
    loss's maximum ``c^2 / 6``, as a vertex far from any edge does. Returns
    ``(cost, inliers)``, inliers being the vertices below that maximum.
    """
    pts = rotate_vertices(vertices_vu, pivot_vu, rotation_rad)
    nrm = rotate_directions(normals_vu, rotation_rad)
    shifted = np.asarray(pts, dtype=np.float64) + np.asarray(offset_vu, dtype=np.float64)
    h, w = np.shape(edge_dt)
    inside = (
        (shifted[:, 0] >= 0) & (shifted[:, 0] <= h - 1)
        & (shifted[:, 1] >= 0) & (shifted[:, 1] <= w - 1)
    )
    r = sample_dt_bilinear(edge_dt, shifted)
    rho = tukey_rho(r / sigmas, tukey_c)
    worst = tukey_c * tukey_c / 6.0
    rho = np.where(inside, rho, worst)
    if use_polarity:
        accepted = polarity_filter(shifted, nrm, gradient_vu)
        rho = np.where(accepted, rho, worst)
    return float(np.sum(rho)), int(np.count_nonzero(rho < worst))


@dataclass(frozen=True)
class Hypothesis:
    """One candidate pose of a multi-start fit.

    Attributes
    ----------
    source : str
        ``'seed 1'``, ``'seed 2'``, ... (the coarse search's best first),
        ``'basin'`` (the competing basin of the DT cost) or ``'basin across
        1'`` (the same, with the window closed along an unobservable
        direction).
    seed_vu : tuple of int
        The integer start.
    coarse_score : float
        The coarse score of the start (NaN for the basin start).
    offset_vu : tuple of float
        The fitted translation.
    rotation_rad : float
        The fitted rotation.
    cost : float
        :func:`robust_cost` at the fitted pose.
    inliers : int
        Vertices below the loss's maximum there.
    converged : bool
        Whether the LM from this start converged.
    """

    source: str
    seed_vu: tuple[int, int]
    coarse_score: float
    offset_vu: tuple[float, float]
    rotation_rad: float
    cost: float
    inliers: int
    converged: bool

    #: JSON's None reads back as NaN for the coarse score (:mod:`dtalign.pipeline.records`).
    NONFINITE: ClassVar[dict[str, float]] = {"coarse_score": math.nan}


@dataclass(frozen=True)
class Ambiguity:
    """How clearly the winning basin beats the best rival basin.

    Attributes
    ----------
    ratio : float
        ``(rival cost + floor) / (winner cost + floor)`` of the best rival
        basin across the edge (displaced in the observed directions);
        ``inf`` when there is none.
    rival : Hypothesis or None
        That rival.
    ambiguous : bool
        ``ratio`` is below the threshold, or (``along_unobservable``) a
        hypothesis displaced only along the unobservable directions is.
    along_unobservable : bool
        The ambiguity lies along a direction the fit cannot observe (a
        straight edge's along-edge axis): along the edge, not across it.
    reason : str
        One line for people ('' when not ambiguous).
    """

    ratio: float
    rival: Hypothesis | None
    ambiguous: bool
    along_unobservable: bool
    reason: str


def ambiguity_of(
    winner: Hypothesis,
    hypotheses: tuple[Hypothesis, ...],
    unobservable: NDArray[np.float64],
    n_vertices: int,
    *,
    threshold: float = AMBIGUITY_THRESHOLD,
) -> Ambiguity:
    """The ambiguity figure of ``winner`` among ``hypotheses`` (see the module).

    ``unobservable`` holds the winner's unobservable pose directions as rows
    (:attr:`dtalign.pipeline.PolylineFit.unobservable_directions`). A rival
    basin is a hypothesis displaced from the winner by more than
    :data:`BASIN_RADIUS_PX` in the directions the fit observes (across the
    edge); the figure is the best such rival's. A hypothesis displaced only
    along the unobservable directions is ambiguity along the edge, reported
    (``along_unobservable``) when no rival across it is ambiguous.
    """
    floor = COST_FLOOR_PER_VERTEX * n_vertices
    dirs = np.asarray(unobservable, dtype=np.float64)
    basis = _translation_basis(dirs)
    across: list[Hypothesis] = []
    along: list[Hypothesis] = []
    for h in hypotheses:
        d = np.subtract(h.offset_vu, winner.offset_vu)
        observed = d - basis @ (basis.T @ d) if basis.shape[1] else d
        if float(np.hypot(observed[0], observed[1])) > BASIN_RADIUS_PX:
            across.append(h)
        elif float(np.hypot(d[0], d[1])) > BASIN_RADIUS_PX:
            along.append(h)
    ratio = math.inf
    rival = None
    if across:
        rival = min(across, key=lambda h: h.cost)  # min keeps the first of equal costs
        ratio = (rival.cost + floor) / (winner.cost + floor)
    if ratio < threshold:
        assert rival is not None
        reason = (
            f"a rival basin at offset ({rival.offset_vu[0]:.1f}, {rival.offset_vu[1]:.1f}) "
            f"costs only {ratio:.2f}x the winner (threshold {threshold:g}x): the image "
            "supports two poses"
        )
        return Ambiguity(float(ratio), rival, True, False, reason)
    if along:
        side = min(along, key=lambda h: h.cost)
        side_ratio = (side.cost + floor) / (winner.cost + floor)
        if side_ratio < threshold:
            d = np.subtract(side.offset_vu, winner.offset_vu)
            axis = d / np.hypot(d[0], d[1])
            reason = (
                f"a rival basin {float(np.hypot(d[0], d[1])):.1f} px away along "
                f"(dv, du) = ({axis[0]:+.2f}, {axis[1]:+.2f}), a direction this fit cannot "
                f"observe, costs {side_ratio:.2f}x the winner: ambiguous along the edge, "
                "not across it"
            )
            return Ambiguity(float(ratio), rival, True, True, reason)
    return Ambiguity(float(ratio), rival, False, False, "")


def _translation_basis(unobservable: NDArray[np.float64]) -> NDArray[np.float64]:
    """An orthonormal basis (columns) of the translation parts of the
    unobservable directions; ``(2, 0)`` when every direction is observed."""
    if unobservable.size == 0:
        return np.zeros((2, 0))
    parts = unobservable.reshape(-1, unobservable.shape[-1])[:, :2]
    parts = parts[np.hypot(parts[:, 0], parts[:, 1]) > 1e-6]
    if parts.shape[0] == 0:
        return np.zeros((2, 0))
    q, r = np.linalg.qr(parts.T)
    keep = np.abs(np.diag(r)) > 1e-6
    return q[:, keep]


#: Extra coarse peaks drawn for a fit with an unobservable direction: one
#: edge's peaks repeat along it every few pixels (the seeds' separation), so
#: the peaks of a parallel edge across it rank behind them.
ALONG_EDGE_PEAKS = 12

def _unobservable(fit: Any) -> NDArray[np.float64]:
    """The fit's unobservable directions as rows; none when they cannot be
    formed (an information matrix that overflows: the pose is then not
    examined along any direction)."""
    try:
        return np.asarray(fit.unobservable_directions, dtype=np.float64).reshape(
            -1, fit.n_params
        )
    except (ValueError, FloatingPointError, OverflowError):
        return np.zeros((0, fit.n_params))


def examine(fit: Any, shared: Any, item: Any, *, refit: Any, surface: Any = None) -> Any:
    """The pipeline's fit, examined against rival basins (and, with
    ``seeds > 1`` in the call's options, replaced by the cheapest of several starts).

    The starts: the fit's own coarse seed; the next ``seeds - 1`` distinct
    peaks of the coarse score surface (``_coarse_starts``; at least the
    second, for the ambiguity figure); and the competing basin of the DT
    cost (``_basin_starts``). Each is fitted by the same LM
    (``refit(seed)`` gives a :class:`~dtalign.pipeline.PolylineFit`) and
    costed by :func:`robust_cost`. With one seed the fit itself is kept
    whatever the costs (results stay those of the single start); with more,
    the cheapest of the coarse starts and the basin start wins, ties to the
    earlier. The returned fit carries every hypothesis and its
    :class:`Ambiguity`. ``surface`` is the coarse score surface the fit's
    seed came from, when the caller has it (formed again when None).
    """
    t0 = time.perf_counter()
    seeds = shared.options.seeds
    fits = [("seed 1", fit.coarse_offset_vu, math.nan, fit)]
    for source, seed, score in (_coarse_starts(fit, shared, item, seeds, surface)
                                + _basin_starts(fit, shared, item)):
        # A start that cannot be fitted (its LM diverged on an extreme input)
        # is no hypothesis: the examination never fails a fit that succeeded.
        try:
            fits.append((source, seed, score, refit(seed)))
        except (ValueError, FloatingPointError, OverflowError):
            pass
    hypotheses = []
    for start in fits:
        hypotheses.append(_hypothesis(shared, item, *start))
    best = 0
    if seeds > 1:
        for j, h in enumerate(hypotheses):
            if h.cost < hypotheses[best].cost:
                best = j
    chosen = fits[best][3]
    amb = ambiguity_of(hypotheses[best], tuple(hypotheses), _unobservable(chosen),
                       item.vertices.shape[0])
    timings = dict(chosen.timings_s)
    timings["hypotheses"] = time.perf_counter() - t0
    return dataclasses.replace(
        chosen, hypotheses=tuple(hypotheses), ambiguity=amb, timings_s=timings
    )


def _hypothesis(shared: Any, item: Any, source: str, seed: tuple[int, int], score: float,
                f: Any) -> Hypothesis:
    """The :class:`Hypothesis` of fit ``f`` from start ``seed``, costed by :func:`robust_cost`."""
    products = shared.products
    cost, inliers = robust_cost(
        products.edge_dt, products.gradient_vu, item.vertices, item.normals, item.sigmas,
        offset_vu=f.offset_vu, rotation_rad=f.rotation_rad, pivot_vu=item.pivot,
        use_polarity=shared.lm.use_polarity, tukey_c=shared.lm.tukey_c,
    )
    return Hypothesis(
        source=source, seed_vu=(int(seed[0]), int(seed[1])), coarse_score=float(score),
        offset_vu=f.offset_vu, rotation_rad=f.rotation_rad, cost=cost, inliers=inliers,
        converged=bool(f.lm.converged),
    )


def _coarse_starts(fit: Any, shared: Any, item: Any, seeds: int, surface: Any
                   ) -> list[tuple[str, tuple[int, int], float]]:
    """The coarse peaks to start from besides the fit's own seed, across its edge.

    Along an unobservable direction (a straight edge) the peaks of one edge
    repeat along it; the starts wanted are peaks across it, so more peaks
    are drawn and those that only slide along the first seed's edge skipped.
    """
    if surface is None:  # the surface the pipeline's seed came from
        _, surface = seed_of(shared, item, surface=True)
    basis = _translation_basis(_unobservable(fit))
    wanted = max(seeds, 2) - 1
    peaks = peaks_of(surface, shared.mv, shared.mu,
                     wanted + 1 + (ALONG_EDGE_PEAKS if basis.shape[1] else 0))
    starts = []
    for j, peak in enumerate(peaks[1:], start=2):
        d = np.subtract(peak.offset_vu, fit.coarse_offset_vu).astype(np.float64)
        across = d - basis @ (basis.T @ d) if basis.shape[1] else d
        if wanted == 0 or not np.hypot(across[0], across[1]) > BASIN_RADIUS_PX:
            continue
        starts.append((f"seed {j}", peak.offset_vu, peak.score))
        wanted -= 1
    return starts


def _basin_starts(fit: Any, shared: Any, item: Any) -> list[tuple[str, tuple[int, int], float]]:
    """The competing basins of the DT cost outside :data:`BASIN_RADIUS_PX`
    (:func:`dtalign.find_secondary_dt_minimum`): over the whole window and,
    along each unobservable direction (a straight edge, where every shift
    costs the same, so the best rival of the whole window lies there), with
    the window closed along the image axis nearest that direction."""
    if fit.lm.degenerate:
        return []
    window = shared.window
    placed = rotate_vertices(item.vertices, item.pivot, fit.rotation_rad)
    scans = [("basin", window)]
    for k, direction in enumerate(_unobservable(fit)[:, :2]):
        if np.hypot(direction[0], direction[1]) > 0.5:
            closed = (0, window[1]) if abs(direction[0]) > abs(direction[1]) else (window[0], 0)
            scans.append((f"basin across {k + 1}", closed))
    starts = []
    for source, scan_window in scans:
        rival = find_secondary_dt_minimum(
            shared.products.edge_dt, placed, converged_offset_vu=fit.offset_vu,
            search_window_vu=scan_window, exclude_radius_px=BASIN_RADIUS_PX,
            min_support_fraction=0.5,
        )
        if rival is not None:
            starts.append((source, rival.offset_vu, math.nan))
    return starts
