"""The competing-basin second opinion (:ref:`contract-basin`)."""

from __future__ import annotations

from typing import Any

from numpy.typing import ArrayLike

from .._kernels import basin as _k
from .checks import check_basin_inputs, nonfinite_read
from .constants import DEFAULT_COARSE_MIN_SUPPORT_FRACTION
from .results import SecondaryBasin

__all__ = ["SecondaryBasin", "find_secondary_dt_minimum"]


def find_secondary_dt_minimum(
    image_edge_dt: ArrayLike,
    vertices_vu: ArrayLike,
    *,
    converged_offset_vu: Any,
    search_window_vu: Any,
    exclude_radius_px: float,
    min_support_fraction: float = DEFAULT_COARSE_MIN_SUPPORT_FRACTION,
) -> SecondaryBasin | None:
    """The best integer shift outside the converged basin of the DT cost.

    The cost at an offset is the mean bilinear DT sample of the shifted
    vertices that stay inside the image (``0 <= v <= H-1``,
    ``0 <= u <= W-1``); it is undefined when fewer than
    ``min_support_fraction`` of the vertices do. Every integer shift
    ``(dv, du)`` of the window farther than ``exclude_radius_px`` from the
    converged offset is a candidate; the lowest ``(cost, distance)`` wins
    (an exact tie keeps the first shift scanned, rows outer). The rival is
    returned whether or not it beats the converged cost: a caller flags the
    fit when ``cost_px / max(converged_cost_px, 0.25)`` is small.

    Parameters
    ----------
    image_edge_dt : array_like, shape (H, W)
        Edge distance transform.
    vertices_vu : array_like, shape (N, 2)
        Polyline vertices at the fitted rotation (rotate them first with
        ``_rotate_vertices`` when the fit rotated).
    converged_offset_vu : tuple of float
        The fitted translation.
    search_window_vu : tuple of two numbers
        Margins around the zero shift; ``int()`` of each is used, and a
        negative one scans nothing.
    exclude_radius_px : float
        Radius of the converged basin, pixels.
    min_support_fraction : float, optional
        Smallest in-bounds fraction of the vertices for a defined cost.

    Returns
    -------
    SecondaryBasin or None
        None when there are no vertices, the converged cost is undefined,
        or no shift is a candidate.
    """
    a = check_basin_inputs(
        image_edge_dt, vertices_vu, converged_offset_vu, search_window_vu, exclude_radius_px,
        min_support_fraction,
    )
    n = a.vertices.shape[0]
    if n == 0:
        return None
    status, dv, du, distance, cost, converged_cost = _k.secondary_basin(
        a.dt, a.vertices, a.converged[0], a.converged[1], a.mv, a.mu, a.exclude_radius,
        a.fraction * n,
    )
    if status == _k.NONFINITE:
        raise nonfinite_read("image_edge_dt")
    if status != _k.FOUND:
        return None
    return SecondaryBasin((int(dv), int(du)), float(distance), float(cost), float(converged_cost))
