"""Reading images and model polylines from files.

* :func:`load_image`: ``.npy``, ``.png`` (and other formats Pillow reads),
  and ``.fits`` when astropy is installed.
* :func:`load_polyline_csv` / :func:`save_polyline_csv`: a model polyline
  as CSV with the header columns ``v,u,nv,nu,sigma``.
* :func:`load_cassini_overlay_frame` and :func:`overlay_polylines`: the
  real Cassini summary PNGs of ``shared/data/cassini`` (a grey image with a
  pure-red model overlay) turned into an image and a model polyline.

Every loader raises a :class:`ValueError` (or :class:`FileNotFoundError`)
whose message names the file and what is wrong with it, so a command line
can print it as one line.
"""

from __future__ import annotations

import csv
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from .scenes import Polyline

__all__ = [
    "CassiniFrame",
    "POLYLINE_COLUMNS",
    "concatenate_polylines",
    "load_cassini_overlay_frame",
    "load_image",
    "load_polyline_csv",
    "overlay_polylines",
    "save_polyline_csv",
]

FloatArray = NDArray[np.float64]
PathLike = str | os.PathLike[str]

#: Required header columns of a polyline CSV, in the order they are written.
POLYLINE_COLUMNS: tuple[str, ...] = ("v", "u", "nv", "nu", "sigma")

_FITS_SUFFIXES = {".fits", ".fit", ".fts"}

#: ITU-R BT.601 luma weights, used for a colour image that is not grey.
_LUMA = np.array([0.299, 0.587, 0.114])


def _existing(path: PathLike, what: str) -> Path:
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{what} not found: {p}")
    if p.is_dir():
        raise ValueError(f"{what} is a directory, not a file: {p}")
    return p


def _rgb_to_grey(arr: np.ndarray) -> FloatArray:
    """Grey from an ``(H, W, 3|4)`` array: the G channel when R == G == B."""
    rgb = arr[..., :3].astype(np.float64)
    if np.array_equal(rgb[..., 0], rgb[..., 1]) and np.array_equal(rgb[..., 1], rgb[..., 2]):
        return np.ascontiguousarray(rgb[..., 1])
    return np.ascontiguousarray(rgb @ _LUMA)


def _pillow_array(p: Path) -> np.ndarray:
    try:
        from PIL import Image
    except ImportError:
        raise ImportError(
            f"reading {p.suffix or 'image'} files needs Pillow: pip install dtalign[cli]"
        ) from None
    try:
        with Image.open(p) as img:
            img.load()
            if img.mode in ("P", "PA", "LA", "1"):
                img = img.convert("RGBA" if "A" in img.mode or img.mode == "P" else "L")
            return np.asarray(img)
    except OSError as exc:
        raise ValueError(f"cannot read image {p}: {exc}") from None


def load_image(path: PathLike) -> FloatArray:
    """Read a 2-D image as float64.

    Parameters
    ----------
    path : str or path-like
        ``.npy`` (a 2-D numeric array, loaded without pickles), ``.fits`` /
        ``.fit`` / ``.fts`` (the first HDU holding 2-D data; needs astropy),
        or any format Pillow reads (``.png``, ``.tif``, ``.jpg``...).
        A colour image whose channels are all equal (a grey image saved as
        RGB, like the Cassini summary PNGs) gives its G channel; any other
        colour image gives the BT.601 luma ``0.299 R + 0.587 G + 0.114 B``.
        An alpha channel is ignored.

    Returns
    -------
    ndarray, shape (H, W), float64

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    ValueError
        If the file cannot be read or does not hold a non-empty, finite,
        2-D image.
    ImportError
        For a FITS file without astropy, or a PNG without Pillow; the
        message says what to install.
    """
    p = _existing(path, "image file")
    suffix = p.suffix.lower()
    if suffix == ".npy":
        try:
            arr = np.load(p, allow_pickle=False)
        except (OSError, ValueError) as exc:
            raise ValueError(f"cannot read image {p}: {exc}") from None
        if not isinstance(arr, np.ndarray) or arr.dtype.kind not in "biuf":
            raise ValueError(f"image {p} must hold a numeric array")
    elif suffix in _FITS_SUFFIXES:
        arr = _load_fits(p)
    else:
        arr = _pillow_array(p)
    if arr.ndim == 3 and arr.shape[2] in (3, 4):
        arr = _rgb_to_grey(arr)
    if arr.ndim != 2:
        raise ValueError(f"image {p} must be 2-D (or RGB), got shape {arr.shape}")
    if arr.size == 0:
        raise ValueError(f"image {p} is empty (shape {arr.shape})")
    out = np.ascontiguousarray(arr, dtype=np.float64)
    if not np.isfinite(out).all():
        raise ValueError(f"image {p} has NaN or inf pixels")
    return out


def _load_fits(p: Path) -> np.ndarray:
    try:
        from astropy.io import fits
    except ImportError:
        raise ImportError(
            f"reading FITS file {p} needs astropy: pip install astropy"
        ) from None
    try:
        with fits.open(p, memmap=False) as hdul:
            for hdu in hdul:
                data = getattr(hdu, "data", None)
                if data is not None and np.ndim(data) == 2:
                    return np.array(data, dtype=np.float64)
    except OSError as exc:
        raise ValueError(f"cannot read FITS file {p}: {exc}") from None
    raise ValueError(f"FITS file {p} has no HDU with 2-D image data")


# ---------------------------------------------------------------------------
# Polyline CSV
# ---------------------------------------------------------------------------


def load_polyline_csv(path: PathLike, *, name: str | None = None) -> Polyline:
    """Read a model polyline from a CSV file.

    The first row is a header naming at least the columns ``v``, ``u``
    (vertex row and column, pixels), ``nv``, ``nu`` (the normal, pointing
    to the bright side of the edge) and ``sigma`` (prior one-sigma along
    the normal, pixels, > 0), in any order; names are matched
    case-insensitively after stripping spaces, and other columns are
    ignored. Blank lines and lines starting with ``#`` are skipped.

    Parameters
    ----------
    path : str or path-like
        The CSV file.
    name : str, optional
        The polyline's name; the file stem when None.

    Returns
    -------
    Polyline
        ``vertices_vu (N, 2)``, ``normals_vu (N, 2)``, ``sigmas (N,)``.

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    ValueError
        If columns are missing (the message lists them), a value is not a
        finite number (the message gives the line and column), a sigma is
        not > 0, or there are no vertex rows.
    """
    p = _existing(path, "polyline file")
    try:
        with open(p, newline="", encoding="utf-8-sig") as fh:
            rows = [row for row in csv.reader(fh)]
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"cannot read polyline CSV {p}: {exc}") from None
    numbered = [
        (i + 1, row)
        for i, row in enumerate(rows)
        if row and any(c.strip() for c in row) and not row[0].lstrip().startswith("#")
    ]
    if not numbered:
        raise ValueError(f"polyline CSV {p} is empty: need a header {','.join(POLYLINE_COLUMNS)}")
    header = [c.strip().lower() for c in numbered[0][1]]
    missing = [c for c in POLYLINE_COLUMNS if c not in header]
    if missing:
        raise ValueError(
            f"polyline CSV {p}: missing column(s) {', '.join(missing)} "
            f"(need {','.join(POLYLINE_COLUMNS)}; found {','.join(header) or 'nothing'})"
        )
    index = {c: header.index(c) for c in POLYLINE_COLUMNS}
    data = np.empty((len(numbered) - 1, len(POLYLINE_COLUMNS)))
    for k, (line, row) in enumerate(numbered[1:]):
        if len(row) < len(header):
            raise ValueError(
                f"polyline CSV {p} line {line}: {len(row)} cell(s), but the header has {len(header)}"
            )
        for j, col in enumerate(POLYLINE_COLUMNS):
            cell = row[index[col]].strip()
            try:
                value = float(cell)
            except ValueError:
                raise ValueError(
                    f"polyline CSV {p} line {line}: column {col} is not a number: {cell!r}"
                ) from None
            if not math.isfinite(value):
                raise ValueError(
                    f"polyline CSV {p} line {line}: column {col} must be finite, got {cell!r}"
                )
            data[k, j] = value
    if data.shape[0] == 0:
        raise ValueError(f"polyline CSV {p} has a header but no vertex rows")
    bad = np.nonzero(data[:, 4] <= 0.0)[0]
    if bad.size:
        line = numbered[1 + int(bad[0])][0]
        raise ValueError(f"polyline CSV {p} line {line}: column sigma must be > 0")
    return Polyline(
        name=p.stem if name is None else name,
        vertices_vu=np.ascontiguousarray(data[:, 0:2]),
        normals_vu=np.ascontiguousarray(data[:, 2:4]),
        sigmas=np.ascontiguousarray(data[:, 4]),
    )


def save_polyline_csv(path: PathLike, polyline: Polyline) -> Path:
    """Write a polyline as CSV with the header ``v,u,nv,nu,sigma``.

    Values are written with 17 significant digits, so
    :func:`load_polyline_csv` reads back the same float64 numbers.

    Returns
    -------
    pathlib.Path
        The path written.
    """
    p = Path(path)
    data = np.column_stack(
        [
            np.asarray(polyline.vertices_vu, dtype=np.float64).reshape(-1, 2),
            np.asarray(polyline.normals_vu, dtype=np.float64).reshape(-1, 2),
            np.asarray(polyline.sigmas, dtype=np.float64).reshape(-1),
        ]
    )
    with open(p, "w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh)
        writer.writerow(POLYLINE_COLUMNS)
        for row in data:
            writer.writerow([f"{x:.17g}" for x in row])
    return p


def concatenate_polylines(polylines: Sequence[Polyline], name: str = "combined") -> Polyline:
    """Join several polylines into one (to fit them as one rigid model)."""
    if not polylines:
        raise ValueError("polylines must not be empty")
    return Polyline(
        name=name,
        vertices_vu=np.concatenate([p.vertices_vu for p in polylines]),
        normals_vu=np.concatenate([p.normals_vu for p in polylines]),
        sigmas=np.concatenate([p.sigmas for p in polylines]),
    )


# ---------------------------------------------------------------------------
# Cassini summary PNGs
# ---------------------------------------------------------------------------


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
    cv, cu, radius = _ransac_circle(pts, band=8.0, rng=np.random.default_rng(0))
    rel = pts - (cv, cu)
    theta = np.arctan2(rel[:, 0], rel[:, 1])
    rad = np.hypot(rel[:, 0], rel[:, 1])
    keep = np.abs(rad - radius) <= 8.0
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
