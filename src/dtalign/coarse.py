"""Stage 1: rasterise the polyline and search integer shifts (SPEC section 2)."""

from __future__ import annotations

from typing import Any

import numpy as np

from . import _validation as check
from ._args import check_coarse_inputs
from ._kernels import coarse as _k

__all__ = ["build_polyline_mask", "coarse_ncc_search", "coarse_search_vertices"]


def build_polyline_mask(vertices_vu: Any, shape_vu: Any) -> np.ndarray:
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


def coarse_ncc_search(edge_mask: Any, polyline_mask: Any, search_window_vu: Any) -> tuple[int, int]:
    """Integer shift that puts the most polyline pixels on edge pixels.

    For each shift ``(dv, du)`` in ``[-mv, mv] x [-mu, mu]`` the score is
    the fraction of the polyline pixels still inside the image that land on
    an edge pixel; shifts that leave no pixel inside are skipped.

    Parameters
    ----------
    edge_mask : array_like, shape (H, W)
        Edge pixels (nonzero), e.g. ``edge_dt <= 0.5``.
    polyline_mask : array_like, shape (H, W)
        Polyline pixels (nonzero), e.g. from :func:`build_polyline_mask`.
    search_window_vu : tuple or list of two int
        Non-negative margins ``(mv, mu)``; margins larger than the image
        are clipped.

    Returns
    -------
    tuple of int
        The best ``(dv, du)``. Exactly equal scores go to the smallest
        ``(|dv| + |du|, |dv|, dv, du)``; an empty polyline gives ``(0, 0)``.

    Raises
    ------
    ValueError
        ``must be 2-D``, ``shape mismatch``, ``length-2 sequence of ints``,
        ``must be non-negative``.
    TypeError
        ``search_window_vu[i] must be int`` for a bool, float or other entry.
    """
    edge, poly, mv, mu = check_coarse_inputs(edge_mask, polyline_mask, search_window_vu)
    h, w = edge.shape
    if h == 0 or w == 0:
        return 0, 0
    dv, du = _k.coarse_search(edge, poly, mv, mu)
    return int(dv), int(du)


def coarse_search_vertices(
    edge_mask: Any, vertices_vu: Any, search_window_vu: Any
) -> tuple[int, int]:
    """``coarse_ncc_search(edge_mask, build_polyline_mask(vertices_vu, shape), window)``
    without the polyline mask.

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
