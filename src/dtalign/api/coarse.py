"""Stage 1: rasterise the polyline and search integer shifts (:ref:`contract-numerics`)."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .._kernels import coarse as _k
from .._kernels import polarity_search as _ps
from . import checks as check
from .checks import check_coarse_inputs, check_polarity_search_inputs
from .constants import DEFAULT_COARSE_MIN_SUPPORT_FRACTION
from .results import CoarseSearchResult

__all__ = [
    "CoarseSearchResult",
    "build_polyline_mask",
    "coarse_ncc_search",
    "coarse_ncc_search_scored",
    "coarse_polarity_search_scored",
    "coarse_search_vertices",
]


def build_polyline_mask(vertices_vu: ArrayLike, shape_vu: Any) -> np.ndarray:
    """Rasterise vertices into a boolean image.

    Parameters
    ----------
    vertices_vu : array_like, shape (N, 2)
        Pixel-centric ``(v, u)`` vertices.
    shape_vu : tuple of int
        ``(H, W)`` of the mask.

    Returns
    -------
    ndarray of bool, shape (H, W)
        True at each vertex rounded half-to-even (``np.rint``); vertices
        outside the image are dropped.
    """
    pts = check.vertices(vertices_vu, "vertices_vu")
    h, w = check.shape2(shape_vu)
    return _k.rasterise(pts, h, w)  # type: ignore[no-any-return]


def coarse_ncc_search(
    edge_mask: ArrayLike,
    polyline_mask: ArrayLike,
    search_window_vu: Any,
    *,
    min_support_fraction: float = DEFAULT_COARSE_MIN_SUPPORT_FRACTION,
) -> tuple[int, int]:
    """Integer shift that puts the most polyline pixels on edge pixels.

    ``coarse_ncc_search_scored(...).offset_vu``: for each shift ``(dv, du)``
    in ``[-mv, mv] x [-mu, mu]`` that keeps at least
    ``min_support_fraction`` of the polyline pixels (and at least one)
    inside the image, the score is the fraction of those pixels that land
    on an edge pixel.

    Parameters
    ----------
    edge_mask : array_like, shape (H, W)
        Edge pixels (nonzero), e.g. ``edge_dt <= 0.5``. A float mask's
        values are summed (a weighted overlap).
    polyline_mask : array_like, shape (H, W)
        Polyline pixels (nonzero), e.g. from :func:`build_polyline_mask`.
    search_window_vu : tuple or list of two int
        Non-negative margins ``(mv, mu)``; margins larger than the image
        are clipped.
    min_support_fraction : float, optional
        Smallest fraction of the polyline pixels a shift must keep inside
        the image to be a candidate, in ``[0, 1]``; 0 gives the design's
        search (:ref:`contract-numerics`).

    Returns
    -------
    tuple of int
        The best ``(dv, du)``. Exactly equal scores go to the smallest
        ``(|dv| + |du|, |dv|, dv, du)``; an empty polyline gives ``(0, 0)``.

    Raises
    ------
    ValueError
        ``must be 2-D``, ``shape mismatch``, ``length-2 sequence of ints``,
        ``must be non-negative``, ``min_support_fraction must be in [0, 1]``.
    TypeError
        ``search_window_vu[i] must be int`` for a bool, float or other entry.
    """
    return coarse_ncc_search_scored(
        edge_mask, polyline_mask, search_window_vu, min_support_fraction=min_support_fraction
    ).offset_vu


def coarse_ncc_search_scored(
    edge_mask: ArrayLike,
    polyline_mask: ArrayLike,
    search_window_vu: Any,
    *,
    min_support_fraction: float = DEFAULT_COARSE_MIN_SUPPORT_FRACTION,
) -> CoarseSearchResult:
    """:func:`coarse_ncc_search` with the winning score (:ref:`contract-coarse-scored`).

    Parameters
    ----------
    edge_mask, polyline_mask, search_window_vu, min_support_fraction
        As :func:`coarse_ncc_search`.

    Returns
    -------
    CoarseSearchResult
        The best shift and ``max(score, 0.0)``; ``((0, 0), 0.0)`` for an
        empty polyline mask. The zero shift is always a candidate.
    """
    edge, poly, mv, mu, fraction = check_coarse_inputs(
        edge_mask, polyline_mask, search_window_vu, min_support_fraction
    )
    if poly.size == 0:
        return CoarseSearchResult((0, 0), 0.0)
    search = _k.coarse_search_scored if edge.dtype == np.bool_ else _k.coarse_search_values
    dv, du, score = search(edge, poly, mv, mu, fraction)
    return CoarseSearchResult((int(dv), int(du)), max(float(score), 0.0))


def coarse_polarity_search_scored(
    edge_mask: ArrayLike,
    image_gradient_vu: ArrayLike,
    vertices_vu: ArrayLike,
    normals_vu: ArrayLike,
    search_window_vu: Any,
    *,
    min_support_fraction: float = DEFAULT_COARSE_MIN_SUPPORT_FRACTION,
) -> CoarseSearchResult:
    """Coarse search weighting each vertex by its normal's agreement with the gradient.

    A vertex whose shifted pixel ``rint(v + dv), rint(u + du)`` is an edge
    pixel scores ``max(n_hat . g / |g|, 0)`` there (0 elsewhere), so an edge
    of the wrong polarity (a crater rim inside a limb, a neighbouring ring
    edge) cannot win the seed. A shift's score is the mean over the
    vertices it keeps inside the image (:ref:`contract-polarity-search`).

    Parameters
    ----------
    edge_mask : array_like, shape (H, W)
        Edge pixels (nonzero).
    image_gradient_vu : array_like, shape (H, W, 2)
        Signed gradient; only its direction matters. A NaN gradient gives
        a NaN score, which never wins.
    vertices_vu, normals_vu : array_like, shape (N, 2)
        Polyline vertices (each counted, duplicates and off-frame ones
        included) and normals pointing toward the bright side; a zero
        normal never matches.
    search_window_vu : tuple or list of two int
        Non-negative margins ``(mv, mu)``.
    min_support_fraction : float, optional
        Smallest fraction of the N vertices a shift must keep in the image.

    Returns
    -------
    CoarseSearchResult
        The best shift (ties as :func:`coarse_ncc_search`) and
        ``max(score, 0.0)``; ``((0, 0), 0.0)`` with no vertex or no
        eligible shift.
    """
    a = check_polarity_search_inputs(
        edge_mask, image_gradient_vu, vertices_vu, normals_vu, search_window_vu,
        min_support_fraction,
    )
    if a.vertices.shape[0] == 0 or a.edge.size == 0:
        return CoarseSearchResult((0, 0), 0.0)
    dv, du, score = _ps.polarity_search(
        a.edge, a.gradient, a.vertices, a.normals, a.mv, a.mu,
        a.fraction * a.vertices.shape[0],
    )
    return CoarseSearchResult((int(dv), int(du)), max(float(score), 0.0))


def coarse_search_vertices(
    edge_mask: ArrayLike, vertices_vu: ArrayLike, search_window_vu: Any
) -> tuple[int, int]:
    """``coarse_ncc_search(edge_mask, build_polyline_mask(vertices_vu, shape), window,
    min_support_fraction=0.0)`` without the polyline mask.

    Same result (the support is the same set of pixels), but no image-sized
    mask is allocated and scanned per polyline: what a pipeline fitting many
    polylines against one image's edge mask wants (it also keeps threads
    from contending for the allocator).

    Parameters
    ----------
    edge_mask : array_like, shape (H, W)
        Edge pixels (nonzero), e.g. ``edge_dt <= 0.5``.
    vertices_vu : array_like, shape (N, 2)
        Polyline vertices; rounded half-to-even, outside ones dropped.
    search_window_vu : tuple or list of two int
        Non-negative margins ``(mv, mu)``.

    Returns
    -------
    tuple of int
        The best ``(dv, du)``, as :func:`coarse_ncc_search`.
    """
    edge = check.mask2d(edge_mask, "edge_mask")
    pts = check.vertices(vertices_vu, "vertices_vu")
    mv, mu = check.search_window(search_window_vu)
    h, w = edge.shape
    mv = min(mv, max(h - 1, 0))
    mu = min(mu, max(w - 1, 0))
    if h == 0 or w == 0:
        return 0, 0
    pv, pu = _k.support_of_vertices(pts, h, w)
    dv, du = _k.search_support(edge, pv, pu, mv, mu)
    return int(dv), int(du)
