"""The compiled work of the pipeline that is no drop-in stage, behind one door.

:mod:`dtalign.pipeline` calls the kernels only through the api layer
(dependencies point down one layer at a time: pipeline -> api ->
``_kernels``). The drop-in stages have their modules (:mod:`dtalign.api.lm`,
:mod:`dtalign.api.coarse`, ...); what the pipeline needs besides them is
here: the polylines' value checks in one compiled pass, the pipeline's
integer seed, the compiled loop of many polylines with its input and output
records, the coarse score surfaces and their peaks, the noise statistics,
the profile refinement's kernels and the second-edge search of the
pose uncertainty. Inputs reach these already checked
(by :mod:`dtalign.api.checks`, called from :mod:`dtalign.pipeline.jobs`):
like every kernel they do not validate.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .._kernels import coarse as _coarse
from .._kernels import evidence as _evidence
from .._kernels import polarity_search as _ps
from .._kernels import profile as profile_kernels
from .._kernels.checks import OK, polyline_status, polylines_status
from .._kernels.fpload import LANES as FP_LANES
from .._kernels.fpload import fp_throughput
from .._kernels.noise import noise_statistics
from .._kernels.pipeline import LoopInputs, LoopOutputs, fit_polylines
from .._kernels.seeds import top_k

__all__ = [
    "FP_LANES", "OK", "LoopInputs", "LoopOutputs", "fit_polylines", "fp_throughput",
    "noise_statistics", "overlap_surface", "pipeline_seed", "polarity_surface",
    "polyline_status", "polylines_status", "profile_kernels", "second_edge_search", "top_k",
]

overlap_surface = _coarse.overlap_surface
polarity_surface = _ps.polarity_surface
support_of_vertices = _coarse.support_of_vertices
second_edge_search = _evidence.second_edge_search


def pipeline_seed(edge: np.ndarray, gradient: Any, vertices: np.ndarray, normals: np.ndarray,
                  mv: int, mu: int, floor_fraction: float, *, surface: bool = False,
                  ) -> tuple[tuple[int, int], np.ndarray | None]:
    """The pipeline's integer seed, as today's techniques take it, and, with
    ``surface``, the coarse score surface it is the best of (what the
    examination of rival basins draws its other starts from: formed in the
    same pass, not searched again).

    The polarity-weighted search when ``gradient`` is given (limb,
    terminator), else the overlap search of the rasterised polyline
    (rings), both with the support floor ``floor_fraction`` and margins
    already clipped to the image
    (``dtalign._kernels.pipeline.fit_polylines`` seeds the same). The
    surface has rows ``dv + mv``, columns ``du + mu``, NaN where a shift is
    no candidate; None without ``surface``.
    """
    if gradient is not None:
        out = np.full((2 * mv + 1, 2 * mu + 1), np.nan) if surface else np.zeros((0, 0))
        dv, du, _ = _ps.polarity_scan(edge, gradient, vertices, normals, mv, mu,
                                      floor_fraction * vertices.shape[0], out)
        return (int(dv), int(du)), out if surface else None
    h, w = edge.shape
    sv, su = _coarse.support_of_vertices(vertices, h, w)
    floor = floor_fraction * sv.shape[0]
    if sv.shape[0] == 0:
        return (0, 0), np.full((2 * mv + 1, 2 * mu + 1), np.nan) if surface else None
    overlap, counts = _coarse.overlap_tables(edge, sv, su, mv, mu)
    dv, du, _ = _coarse.best_scored(overlap, counts, sv.shape[0], mv, mu, floor)
    grid = _coarse.scored_surface(overlap, counts, sv, mv, mu, floor) if surface else None
    return (int(dv), int(du)), grid
