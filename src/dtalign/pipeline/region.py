"""The part of an image a fit can reach, and the image products computed on it alone.

A fit reads the image products (gradient, edge DT, edge mask) only near its
polyline: at the vertices moved over the search window, a few pixels
around each of those places, and the profile strips' pixels. The products
there depend on the image only within the edge DT's truncation
(``config.dt_half_width_px``) and the derivative kernels' support. So a
crop of the image holding every polyline's reach, padded by that much,
gives the same products where the fits read them as the whole frame does,
for a fraction of the work (:ref:`region`).

* :func:`fit_region` is the one place the region is computed, from the
  polylines' vertices, the call's :class:`~dtalign.FitOptions` and the
  :class:`~dtalign.ImageDerivativesConfig`;
* :func:`~dtalign.pipeline.products.products_of` computes the products on
  it (the noise estimated on its pixels when not given);
* :func:`holds` tells whether a fit stayed where the region's products
  equal the frame's; :func:`refit_outside` fits those that did not again
  on the full frame, as the callers do (:func:`dtalign.pipeline.fit_polyline`,
  :func:`dtalign.pipeline.batch.fit_images`, the campaign tasks).

The fits work in the crop's pixels and report the frame's: the last step
of every fit (``dtalign.pipeline.fit.conclude``) moves them back.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np

from ..api.results import ImageDerivativesConfig

__all__ = ["DRIFT_PX", "READ_MARGIN_PX", "ROTATION_ALLOWANCE_RAD", "Region", "fit_region",
           "holds", "image_region", "refit_outside"]

#: How far a fit's pose may end beyond its search window (the LM walks on
#: from the window's best integer seed) before it reads outside the region.
DRIFT_PX = 4

#: How far from a posed vertex the fit reads the products, pixels: the
#: bilinear samples and their Jacobian steps, the polarity test's rounding,
#: the evidence's second edges (``SECOND_EDGE_REACH_PX`` = 5 along the normal)
#: and its curvature steps.
READ_MARGIN_PX = 8

#: With ``fit_rotation``, how far the fitted rotation may turn from the
#: initial one before the vertices leave the region, radians: the vertices'
#: reach grows by this times their farthest distance from the pivot.
ROTATION_ALLOWANCE_RAD = 0.02

#: A region covering at least this fraction of the frame is not worth its
#: bookkeeping: the full frame is prepared instead.
FULL_FRAME_FRACTION = 0.7


class Region(NamedTuple):
    """A crop of a frame, rows ``v0 : v0 + shape[0]`` and columns ``u0 : u0 + shape[1]``.

    Attributes
    ----------
    origin_vu : tuple of int
        ``(v0, u0)``, the crop's first row and column in the frame.
    shape : tuple of int
        The crop's ``(rows, columns)``.
    frame_shape : tuple of int
        The frame's ``(H, W)``.
    exact : tuple of int
        ``(v_lo, v_hi, u_lo, u_hi)``, frame pixels (half-open): where the
        crop's products equal the frame's; the crop less the padding on
        each side that is not the frame's own border.
    """

    origin_vu: tuple[int, int]
    shape: tuple[int, int]
    frame_shape: tuple[int, int]
    exact: tuple[int, int, int, int]


def support_px(config: ImageDerivativesConfig) -> int:
    """How far from a pixel the image decides its products, pixels
    (:func:`dtalign.api.image.support_px`: the DT's truncation and the
    derivative kernels' reach)."""
    from ..api.image import support_px as image_support  # (at call time: it loads the kernels)

    return image_support(config)


def _reach(vertices: Any, options: Any, profile: Any) -> tuple[float, float, float, float] | None:
    """``(v_lo, v_hi, u_lo, u_hi)`` around which one polyline's fit reads the
    products (frame pixels), or None when its vertices are not a finite
    ``(N, 2)`` array (the fit's own checks then name the fault)."""
    try:
        verts = np.asarray(vertices, dtype=np.float64)
    except (TypeError, ValueError):
        return None
    if verts.ndim != 2 or verts.shape[1] != 2 or verts.shape[0] == 0 \
            or not np.isfinite(verts).all():
        return None
    theta = float(options.initial_rotation_rad)
    pivot = (verts.mean(axis=0) if options.pivot_vu is None
             else np.asarray(options.pivot_vu, dtype=np.float64))
    rel = verts - pivot
    if theta != 0.0:
        c, s = math.cos(theta), math.sin(theta)
        rel = np.column_stack([c * rel[:, 0] - s * rel[:, 1], s * rel[:, 0] + c * rel[:, 1]])
    placed = rel + pivot
    wv, wu = (int(w) for w in options.search_window_vu)
    turn = 0.0
    if options.fit_rotation:
        turn = ROTATION_ALLOWANCE_RAD * float(np.hypot(rel[:, 0], rel[:, 1]).max())
    pad_v = wv + DRIFT_PX + READ_MARGIN_PX + turn
    pad_u = wu + DRIFT_PX + READ_MARGIN_PX + turn
    lo = placed.min(axis=0)
    hi = placed.max(axis=0)
    return (float(lo[0]) - pad_v, float(hi[0]) + pad_v, float(lo[1]) - pad_u,
            float(hi[1]) + pad_u)


def fit_region(frame_shape: tuple[int, int], polylines: Any, options: Any,
               config: ImageDerivativesConfig) -> Region | None:
    """The region of a frame that the fits of ``polylines`` can reach.

    Parameters
    ----------
    frame_shape : tuple of int
        The image's ``(H, W)``.
    polylines : sequence
        Each polyline's vertices ``(N, 2)`` (frame pixels).
    options : FitOptions
        The call's options: the search window, the rotation and pivot.
    config : ImageDerivativesConfig
        The products' tunables (the DT truncation, the Gaussian).

    Returns
    -------
    Region or None
        The union of the polylines' reaches, padded by :func:`support_px`
        and clipped to the frame; None when that is most of the frame
        (:data:`FULL_FRAME_FRACTION`), or when a polyline's vertices are
        malformed (the full frame is prepared and the fit's checks report
        them).
    """
    h, w = (int(s) for s in frame_shape)
    boxes = [_reach(v, options, None) for v in polylines]
    if not boxes or any(b is None for b in boxes):
        return None
    pad = support_px(config)
    v_lo = min(b[0] for b in boxes if b is not None)
    v_hi = max(b[1] for b in boxes if b is not None)
    u_lo = min(b[2] for b in boxes if b is not None)
    u_hi = max(b[3] for b in boxes if b is not None)
    # whole pixels: the reach's pixels and their padding, within the frame
    r0 = max(0, math.floor(v_lo) - pad)
    r1 = min(h, math.ceil(v_hi) + 1 + pad)
    c0 = max(0, math.floor(u_lo) - pad)
    c1 = min(w, math.ceil(u_hi) + 1 + pad)
    if r1 - r0 < 3 or c1 - c0 < 3 or (r1 - r0) * (c1 - c0) >= FULL_FRAME_FRACTION * h * w:
        return None
    exact = (r0 + (pad if r0 > 0 else 0), r1 - (pad if r1 < h else 0),
             c0 + (pad if c0 > 0 else 0), c1 - (pad if c1 < w else 0))
    return Region((r0, c0), (r1 - r0, c1 - c0), (h, w), exact)


def holds(region: Region | None, fit: Any) -> bool:
    """Whether ``fit`` (frame coordinates) read only where ``region``'s products
    equal the frame's: every posed vertex of its DT-LM pose, its reported
    pose and each hypothesis it examined at least :data:`READ_MARGIN_PX`
    inside the exact zone. Always True for the full frame (None)."""
    if region is None:
        return True
    verts = np.asarray(fit.vertices_vu, dtype=np.float64)
    if verts.shape[0] == 0:
        return True
    rel = verts - np.asarray(fit.pivot_vu)
    poses = {(*fit.lm.offset_vu, fit.lm.rotation_rad), (*fit.offset_vu, fit.rotation_rad)}
    poses.update((*h.offset_vu, h.rotation_rad) for h in fit.hypotheses)
    # the limits on the crop's sides inside the frame; its sides on the
    # frame's border are the frame's own (a vertex beyond them is outside
    # the image on either products)
    (v0, u0), (h, w), (fh, fw) = region.origin_vu, region.shape, region.frame_shape
    v_lo, v_hi, u_lo, u_hi = region.exact
    m = READ_MARGIN_PX
    lo_v = v_lo + m if v0 > 0 else -math.inf
    hi_v = v_hi - 1 - m if v0 + h < fh else math.inf
    lo_u = u_lo + m if u0 > 0 else -math.inf
    hi_u = u_hi - 1 - m if u0 + w < fw else math.inf
    for dv, du, theta in poses:
        if not (math.isfinite(dv) and math.isfinite(du) and math.isfinite(theta)):
            return False
        c, s = math.cos(theta), math.sin(theta)
        pv = c * rel[:, 0] - s * rel[:, 1] + fit.pivot_vu[0] + dv
        pu = s * rel[:, 0] + c * rel[:, 1] + fit.pivot_vu[1] + du
        if pv.min() < lo_v or pv.max() > hi_v or pu.min() < lo_u or pu.max() > hi_u:
            return False
    return True


def image_region(image: Any, polylines: Any, options: Any, config: Any) -> Region | None:
    """:func:`fit_region` of a call's arguments as given: the polylines' vertices
    on a 2-D ``image``, the call's options (a :class:`~dtalign.FitOptions`)
    and config (None for the defaults). None (the full frame) when any of
    them is malformed, so that the fit's own checks report it, in their
    order."""
    from ..api.checks import resolve_config

    try:
        if np.ndim(image) != 2:
            return None
        return fit_region(np.shape(image), list(polylines), options, resolve_config(config))
    except (TypeError, ValueError, AttributeError):
        return None


def refit_outside(region: Region | None, fits: list[Any],
                  refit: Callable[[list[int]], list[Any]]) -> list[Any]:
    """``fits`` with each fit that did not :func:`hold <holds>` in ``region``
    replaced by ``refit(indices)``'s (the full frame's fits of those
    polylines, in order); errors and missing fits stay as they are."""
    if region is None:
        return fits
    redo = [i for i, f in enumerate(fits)
            if f is not None and not isinstance(f, Exception) and not holds(region, f)]
    if redo:
        for i, fit in zip(redo, refit(redo), strict=True):
            fits[i] = fit
    return fits
