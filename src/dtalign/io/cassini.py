"""The real Cassini summary PNGs of ``shared/data/cassini``.

Each is a grey image with the navigation model drawn over it in pure red.
:func:`load_cassini_overlay_frame` splits it into a clean image and the
overlay; :func:`overlay_polylines` traces the overlay into model polylines
with normals; :func:`overlay_circle` gives a limb overlay's circle (the
centre and radius a sphere model of the body starts from). This module reads the PNG through :mod:`dtalign.io.files`.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..scenes import Polyline

__all__ = [
    "CIRCLE_BAND_PX",
    "CassiniFrame",
    "load_cassini_overlay_frame",
    "overlay_circle",
    "overlay_polylines",
]

FloatArray = NDArray[np.float64]
PathLike = str | os.PathLike[str]


@dataclass(frozen=True)
class CassiniFrame:
    """A Cassini summary PNG split into the grey image and its red overlay.

    Attributes
    ----------
    image : ndarray, shape (H, W)
        Grey image (the G channel) with every overlay pixel replaced by the
        median of the non-overlay pixels around it.
    overlay_mask : ndarray of bool, shape (H, W)
        Pixels the overlay touched (any pixel with R, G, B not all equal).
    overlay_strength : ndarray, shape (H, W)
        ``(R - G) / 255`` clipped at 0: the overlay's coverage of a pixel,
        used to weight pixels when tracing the overlay's centre line.
    header_rows : int
        Rows of text header removed from the top of the PNG.
    path : pathlib.Path
        The file read.
    """

    image: FloatArray
    overlay_mask: NDArray[np.bool_]
    overlay_strength: FloatArray
    header_rows: int
    path: Path


def _fill_overlay(grey: FloatArray, mask: NDArray[np.bool_], radius: int) -> FloatArray:
    """Replace masked pixels by the median of unmasked pixels around each."""
    out = grey.copy()
    h, w = grey.shape
    fallback = float(np.median(grey[~mask])) if (~mask).any() else 0.0
    for v, u in zip(*np.nonzero(mask), strict=False):
        r = radius
        while True:
            v0, v1 = max(v - r, 0), min(v + r + 1, h)
            u0, u1 = max(u - r, 0), min(u + r + 1, w)
            keep = ~mask[v0:v1, u0:u1]
            if keep.any():
                out[v, u] = float(np.median(grey[v0:v1, u0:u1][keep]))
                break
            if r >= 8 * radius + 8:
                out[v, u] = fallback
                break
            r *= 2
    return out


def load_cassini_overlay_frame(
    png_path: PathLike, *, header_rows: int | str = "auto", median_radius: int = 2
) -> CassiniFrame:
    """Split a Cassini summary PNG into a clean grey image and the overlay.

    The summary PNGs of ``shared/data/cassini`` are grey (R = G = B) with
    the navigation overlay drawn in pure red: the model polyline at the
    operator-verified offset, plus label text. The grey image is the G
    channel; each pixel the overlay touched is replaced by the median of
    the grey, untouched pixels in a ``(2 r + 1)`` square around it (the
    square grows when it holds no such pixel), so the overlay does not
    create edges of its own.

    Parameters
    ----------
    png_path : str or path-like
        The summary PNG.
    header_rows : int or "auto", optional
        Rows of text banner to crop from the top. ``"auto"`` crops
        ``H - W`` rows when the PNG is taller than wide (the frames are
        square; the Keeler frame, 1120 x 1024, has a 96-row banner).
    median_radius : int, optional
        Half-width ``r`` of the replacement window.

    Returns
    -------
    CassiniFrame

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    ValueError
        If the file is not an RGB image, or ``header_rows`` is invalid.
    """
    # Imported here: dtalign.io imports this module to re-export its names.
    from .files import _existing, _pillow_array

    p = _existing(png_path, "Cassini frame")
    rgb = _pillow_array(p)
    if rgb.ndim != 3 or rgb.shape[2] not in (3, 4):
        raise ValueError(f"Cassini frame {p} must be an RGB image, got shape {rgb.shape}")
    h, w = rgb.shape[:2]
    if header_rows == "auto":
        crop = max(h - w, 0)
    elif isinstance(header_rows, (int, np.integer)) and not isinstance(header_rows, bool):
        crop = int(header_rows)
        if not 0 <= crop < h:
            raise ValueError(f"header_rows must be in [0, {h}), got {crop}")
    else:
        raise ValueError(f"header_rows must be an int or 'auto', got {header_rows!r}")
    if not isinstance(median_radius, (int, np.integer)) or median_radius < 1:
        raise ValueError(f"median_radius must be an int >= 1, got {median_radius!r}")
    rgb = rgb[crop:, :, :3].astype(np.int32)
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    mask = (r != g) | (g != b)
    strength = np.clip((r - g) / 255.0, 0.0, None)
    grey = _fill_overlay(g.astype(np.float64), mask, int(median_radius))
    return CassiniFrame(
        image=grey,
        overlay_mask=mask,
        overlay_strength=strength,
        header_rows=crop,
        path=p,
    )


def _circle_fit(pts: FloatArray) -> tuple[float, float, float]:
    """Algebraic (Kasa) least-squares circle: centre ``(v, u)`` and radius."""
    a = np.column_stack([pts, np.ones(len(pts))])
    y = -(pts**2).sum(axis=1)
    d, e, f = np.linalg.lstsq(a, y, rcond=None)[0]
    cv, cu = -d / 2.0, -e / 2.0
    return float(cv), float(cu), float(math.sqrt(max(cv * cv + cu * cu - f, 0.0)))


def _ransac_circle(
    pts: FloatArray, band: float, rng: np.random.Generator, trials: int = 300
) -> tuple[float, float, float]:
    """The circle with the most points within ``band``, refitted on them."""
    best, best_count = None, -1
    for _ in range(trials):
        sample = pts[rng.choice(len(pts), size=3, replace=False)]
        try:
            cv, cu, r = _circle_fit(sample)
        except np.linalg.LinAlgError:
            continue
        if not (math.isfinite(r) and r > 0):
            continue
        count = int((np.abs(np.hypot(pts[:, 0] - cv, pts[:, 1] - cu) - r) <= band).sum())
        if count > best_count:
            best, best_count = (cv, cu, r), count
    if best is None:
        raise ValueError("overlay has no circular limb to trace")
    cv, cu, r = best
    inliers = np.abs(np.hypot(pts[:, 0] - cv, pts[:, 1] - cu) - r) <= band
    return _circle_fit(pts[inliers])


#: Overlay pixels within this of a candidate circle (pixels) count for it in
#: the RANSAC search of a limb: the drawn line is 1-2 px wide, an oblate or
#: tilted body's limb departs from its best circle by a few pixels, and the
#: label text lies farther off.
CIRCLE_BAND_PX = 8.0


def overlay_circle(frame: CassiniFrame) -> tuple[tuple[float, float], float]:
    """The circle a limb overlay is traced about: its centre ``(v, u)`` and radius, pixels.

    The RANSAC circle of the overlay's pixels (:data:`CIRCLE_BAND_PX`),
    refitted on its inliers: the one :func:`overlay_polylines` orders a
    limb's vertices by and takes its radial normals from, so a sphere built
    on it (:func:`dtalign.sphere_edge_profile`) has the traced polyline's
    normals. It is the drawn model's best circle, not the body: the traced
    vertices follow the drawn limb (an ellipsoid's, for a non-spherical
    body) within a few pixels of it.

    Parameters
    ----------
    frame : CassiniFrame
        From :func:`load_cassini_overlay_frame`.

    Returns
    -------
    center_vu : tuple of float
    radius_px : float

    Raises
    ------
    ValueError
        If the overlay has fewer than 10 pixels or no circle.
    """
    vv, uu = np.nonzero(frame.overlay_mask)
    if len(vv) < 10:
        raise ValueError(f"frame {frame.path} has no overlay to trace ({len(vv)} pixels)")
    pts = np.column_stack([vv, uu]).astype(np.float64)
    cv, cu, radius = _ransac_circle(pts, band=CIRCLE_BAND_PX, rng=np.random.default_rng(0))
    return (cv, cu), radius


def _fourier_design(theta: FloatArray, order: int) -> FloatArray:
    cols = [np.ones_like(theta)]
    for k in range(1, order + 1):
        cols += [np.cos(k * theta), np.sin(k * theta)]
    return np.column_stack(cols)


def _limb_polyline(
    pts: FloatArray, weight: FloatArray, spacing: float, tolerance: float
) -> tuple[FloatArray, FloatArray]:
    """Vertices along a closed limb and their (un-oriented) radial normals.

    A RANSAC circle gives the centre; the radius is then modelled as a
    low-order Fourier series of the angle (an ellipse or an oblate body is
    order 2), refitted in shrinking bands so that pixels farther than
    ``tolerance`` from the curve (label text, arrows) are dropped. The kept pixels are binned by angle,
    one bin per ``spacing`` pixels of arc, and each bin gives the
    strength-weighted mean position: the overlay's sub-pixel centre line.
    """
    cv, cu, radius = _ransac_circle(pts, band=CIRCLE_BAND_PX, rng=np.random.default_rng(0))
    rel = pts - (cv, cu)
    theta = np.arctan2(rel[:, 0], rel[:, 1])
    rad = np.hypot(rel[:, 0], rel[:, 1])
    keep = np.abs(rad - radius) <= CIRCLE_BAND_PX
    # Shrinking bands: an ellipse (order 2) first, then order 4, so label
    # text near the limb cannot pull the curve toward itself.
    for order, band in ((2, 3.0), (4, 2.0 * tolerance), (4, tolerance)):
        design = _fourier_design(theta[keep], order)
        coef = np.linalg.lstsq(design, rad[keep], rcond=None)[0]
        keep = np.abs(rad - _fourier_design(theta, order) @ coef) <= band
    n_bins = max(int(round(2.0 * math.pi * radius / spacing)), 8)
    idx = np.floor((theta[keep] + math.pi) / (2.0 * math.pi) * n_bins).astype(np.int64) % n_bins
    verts = _binned_means(idx, pts[keep], weight[keep], n_bins)
    normals = verts - (cv, cu)
    normals /= np.hypot(normals[:, 0], normals[:, 1])[:, None]
    return verts, normals


def _binned_means(
    idx: NDArray[np.int64], pts: FloatArray, weight: FloatArray, n_bins: int
) -> FloatArray:
    wsum = np.bincount(idx, weights=weight, minlength=n_bins)
    count = np.bincount(idx, minlength=n_bins)
    vsum = np.bincount(idx, weights=weight * pts[:, 0], minlength=n_bins)
    usum = np.bincount(idx, weights=weight * pts[:, 1], minlength=n_bins)
    ok = wsum > 0
    if ok.sum() >= 4:
        # A bin with far more pixels than usual is crossed by label text.
        ok &= count <= 2.5 * np.median(count[ok])
    return np.column_stack([vsum[ok] / wsum[ok], usum[ok] / wsum[ok]])


def _ransac_line(
    pts: FloatArray, tolerance: float, rng: np.random.Generator, trials: int = 400
) -> tuple[FloatArray, FloatArray]:
    """The line through the most points: a point on it and its unit direction."""
    best, best_count = None, -1
    for _ in range(trials):
        i, j = rng.choice(len(pts), size=2, replace=False)
        d = pts[j] - pts[i]
        norm = math.hypot(d[0], d[1])
        if norm < 10.0:
            continue
        d = d / norm
        dist = np.abs((pts[:, 0] - pts[i, 0]) * d[1] - (pts[:, 1] - pts[i, 1]) * d[0])
        count = int((dist <= tolerance).sum())
        if count > best_count:
            best, best_count = (pts[i].copy(), d), count
    if best is None:
        raise ValueError("overlay has no straight line of at least 10 pixels")
    origin, d = best
    for _ in range(2):  # total least-squares refit on the inliers
        dist = np.abs((pts[:, 0] - origin[0]) * d[1] - (pts[:, 1] - origin[1]) * d[0])
        inl = pts[dist <= tolerance]
        origin = inl.mean(axis=0)
        _, _, vt = np.linalg.svd(inl - origin, full_matrices=False)
        d = vt[0]
    return origin, d


def _orient_to_bright_side(
    verts: FloatArray, normals: FloatArray, image: FloatArray, reach_px: float = 30.0
) -> FloatArray:
    """Flip the whole set of normals, if needed, to point to the bright side.

    The bright side is the one whose mean brightness, over every vertex and
    every distance 2, 4, ... ``reach_px`` along the normal, is higher. The
    integral of the gradient along the normal is that brightness
    difference, so this is the polarity test summed over a band rather than
    read at one pixel: it still decides correctly when the drawn overlay
    sits a few pixels (up to about ``reach_px``) off the edge it models.
    """
    h, w = image.shape
    steps = np.arange(2.0, reach_px + 1e-9, 2.0)
    diff = 0.0
    for t in steps:
        for sign in (1.0, -1.0):
            pos = verts + sign * t * normals
            iv = np.clip(np.rint(pos[:, 0]).astype(np.int64), 0, h - 1)
            iu = np.clip(np.rint(pos[:, 1]).astype(np.int64), 0, w - 1)
            diff += sign * float(image[iv, iu].sum())
    return normals if diff >= 0.0 else -normals


def overlay_polylines(
    frame: CassiniFrame,
    *,
    shape: str,
    n_lines: int = 1,
    parallel: bool = True,
    spacing_px: float = 1.0,
    tolerance_px: float = 1.5,
    seed: int = 0,
) -> tuple[Polyline, ...]:
    """Turn a frame's red overlay into model polylines with normals.

    Parameters
    ----------
    frame : CassiniFrame
        From :func:`load_cassini_overlay_frame`.
    shape : {"limb", "lines"}
        ``"limb"``: one closed curve (a body limb) ordered by angle about
        a fitted circle centre; the normals are radial. ``"lines"``:
        ``n_lines`` straight edges found one after the other by RANSAC,
        each ordered along the line; the normals are perpendicular.
    n_lines : int, optional
        Number of straight lines for ``shape="lines"``.
    parallel : bool, optional
        Give all lines one direction (the mean of the fitted ones), so
        their normals are exactly parallel. Ring edges in one frame are
        arcs of concentric ellipses, locally parallel; without this, the
        fitted directions differ by rasterisation noise (~0.1 degree) and
        the model's geometry is numerically, not exactly, rank 1.
    spacing_px : float, optional
        Vertex spacing along the curve, pixels. Each vertex is the
        overlay-strength-weighted mean of the overlay pixels in its bin,
        so it sits on the drawn line's centre to sub-pixel precision.
    tolerance_px : float, optional
        Overlay pixels farther than this from the fitted curve (label text,
        arrows) are not part of the polyline.
    seed : int, optional
        Seeds the RANSAC line search (the result is deterministic).

    Returns
    -------
    tuple of Polyline
        One polyline for a limb, ``n_lines`` for lines. The normals point
        to the bright side of each edge, chosen per polyline on the
        frame's own image: the side that is brighter on average within
        30 px of the curve (robust to an overlay drawn a few pixels off its
        edge). Sigmas are all 1.
    """
    if shape not in ("limb", "lines"):
        raise ValueError(f"shape must be 'limb' or 'lines', got {shape!r}")
    vv, uu = np.nonzero(frame.overlay_mask)
    pts = np.column_stack([vv, uu]).astype(np.float64)
    weight = frame.overlay_strength[vv, uu]
    if len(pts) < 10:
        raise ValueError(f"frame {frame.path} has no overlay to trace ({len(pts)} pixels)")
    out: list[Polyline] = []
    stem = Path(frame.path).stem
    if shape == "limb":
        verts, normals = _limb_polyline(pts, weight, spacing_px, tolerance_px)
        normals = _orient_to_bright_side(verts, normals, frame.image)
        out.append(Polyline(f"{stem}-limb", verts, normals, np.ones(len(verts))))
        return tuple(out)
    rng = np.random.default_rng(seed)
    remaining = np.ones(len(pts), dtype=bool)
    found: list[tuple[NDArray[np.bool_], FloatArray, FloatArray]] = []
    for k in range(int(n_lines)):
        if remaining.sum() < 10:
            raise ValueError(f"frame {frame.path}: found only {k} of {n_lines} lines")
        origin, d = _ransac_line(pts[remaining], tolerance_px, rng)
        rel = pts - origin
        dist = np.abs(rel[:, 0] * d[1] - rel[:, 1] * d[0])
        found.append((remaining & (dist <= tolerance_px), origin, d))
        remaining &= dist > 3.0 * tolerance_px
    if parallel and found:
        ref = found[0][2]
        common = np.sum([d if d @ ref >= 0 else -d for _, _, d in found], axis=0)
        common = common / np.hypot(common[0], common[1])
        found = [(inl, origin, common) for inl, origin, _ in found]
    for k, (inl, origin, d) in enumerate(found):
        t = (pts[inl] - origin) @ d
        idx = np.floor((t - t.min()) / spacing_px).astype(np.int64)
        verts = _binned_means(idx, pts[inl], weight[inl], int(idx.max()) + 1)
        normals = np.tile(np.array([-d[1], d[0]]), (len(verts), 1))
        normals = _orient_to_bright_side(verts, normals, frame.image)
        out.append(Polyline(f"{stem}-line{k}", verts, normals, np.ones(len(verts))))
    return tuple(out)
