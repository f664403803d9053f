"""Several distinct coarse seeds instead of one.

The LM is local: it converges into whichever basin its seed picks. The K
best *distinct* seeds -- local maxima of the coarse score surface, each at
least ``min_separation_px`` from the better ones -- let a caller fit from
each and compare the basins they lead to. The first seed is always the
single search's result (:func:`dtalign.coarse_polarity_search_scored` or
:func:`dtalign.coarse_ncc_search_scored` of the rasterised polyline).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from ..api import checks as check
from ..api import loop
from ..api.checks import check_polarity_search_inputs, min_support_fraction_value
from ..api.constants import DEFAULT_COARSE_MIN_SUPPORT_FRACTION
from ..api.results import CoarseSearchResult

__all__ = ["DEFAULT_SEED_SEPARATION_PX", "top_k_seeds"]

#: Two seeds closer than this lead the LM into the same basin: its capture
#: range on a DT is a few pixels either way (the production trust region is 1 px,
#: the DT's slope is 1 px/px out to the truncation).
DEFAULT_SEED_SEPARATION_PX = 3.0


def top_k_seeds(
    edge_mask: ArrayLike,
    vertices_vu: ArrayLike,
    search_window_vu: tuple[int, int],
    *,
    k: int = 3,
    min_separation_px: float = DEFAULT_SEED_SEPARATION_PX,
    normals_vu: ArrayLike | None = None,
    image_gradient_vu: ArrayLike | None = None,
    min_support_fraction: float = DEFAULT_COARSE_MIN_SUPPORT_FRACTION,
) -> tuple[CoarseSearchResult, ...]:
    """The ``k`` best distinct integer seeds of the coarse score surface.

    Parameters
    ----------
    edge_mask : array_like, shape (H, W)
        Edge pixels (nonzero), e.g. ``edge_dt <= 0.5``.
    vertices_vu : array_like, shape (N, 2)
        Polyline vertices.
    search_window_vu : tuple or list of two int
        Non-negative margins ``(mv, mu)``.
    k : int, optional
        How many seeds at most (fewer when the surface has fewer peaks).
    min_separation_px : float, optional
        Smallest distance between two seeds, pixels.
    normals_vu, image_gradient_vu : array_like, optional
        Give both for the polarity-weighted surface
        (:func:`dtalign.coarse_polarity_search_scored`); without them the
        overlap surface of the rasterised polyline
        (:func:`dtalign.coarse_ncc_search_scored`) is used.
    min_support_fraction : float, optional
        The searches' support floor.

    Returns
    -------
    tuple of CoarseSearchResult
        Best first; each a local maximum of the surface (at least as high as
        its 8 neighbours). The first equals the single search's result.
        An empty polyline gives ``(((0, 0), 0.0),)``.
    """
    k = check.positive_int(k, "k")
    separation = check.finite_real(min_separation_px, "min_separation_px")
    if (normals_vu is None) != (image_gradient_vu is None):
        raise ValueError("normals_vu and image_gradient_vu go together (the polarity-weighted surface)")
    if image_gradient_vu is not None:
        a = check_polarity_search_inputs(
            edge_mask, image_gradient_vu, vertices_vu, normals_vu, search_window_vu,
            min_support_fraction,
        )
        if a.vertices.shape[0] == 0 or a.edge.size == 0:
            return (CoarseSearchResult((0, 0), 0.0),)
        surface = loop.polarity_surface(
            a.edge, a.gradient, a.vertices, a.normals, a.mv, a.mu,
            a.fraction * a.vertices.shape[0],
        )
        mv, mu = a.mv, a.mu
    else:
        edge = check.mask2d(edge_mask, "edge_mask")
        pts = check.vertices(vertices_vu, "vertices_vu")
        mv, mu = check.search_window(search_window_vu)
        fraction = min_support_fraction_value(min_support_fraction)
        h, w = edge.shape
        mv, mu = min(mv, max(h - 1, 0)), min(mu, max(w - 1, 0))
        if h == 0 or w == 0:
            return (CoarseSearchResult((0, 0), 0.0),)
        pv, pu = loop.support_of_vertices(pts, h, w)
        if pv.shape[0] == 0:
            return (CoarseSearchResult((0, 0), 0.0),)
        surface = loop.overlap_surface(edge, pv, pu, mv, mu, fraction * pv.shape[0])
    return peaks_of(surface, mv, mu, k, separation)


def peaks_of(surface: np.ndarray, mv: int, mu: int, k: int,
             separation: float = DEFAULT_SEED_SEPARATION_PX) -> tuple[CoarseSearchResult, ...]:
    """:func:`top_k_seeds` of a score surface already formed (rows ``dv + mv``,
    columns ``du + mu``, NaN where a shift is no candidate)."""
    count, dv, du, score = loop.top_k(surface, mv, mu, int(k), float(separation))
    if count == 0:  # no candidate shift at all (the polarity search's empty case)
        return (CoarseSearchResult((0, 0), 0.0),)
    return tuple(
        CoarseSearchResult((int(dv[j]), int(du[j])), max(float(score[j]), 0.0))
        for j in range(count)
    )
