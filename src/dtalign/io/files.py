"""Reading images and model polylines from files.

* :func:`load_image`: ``.npy``, ``.png`` (and other formats Pillow reads),
  and ``.fits`` when astropy is installed.
* :func:`load_polyline_csv` / :func:`save_polyline_csv`: a model polyline
  as CSV with the header columns ``v,u,nv,nu,sigma``.
* The Cassini summary PNGs are read by :mod:`dtalign.io.cassini`, which
  builds on this module (never the reverse).

Every loader raises a :class:`ValueError` (or :class:`FileNotFoundError`)
whose message names the file and what is wrong with it, so a command line
can print it as one line.
"""

from __future__ import annotations

import csv
import math
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..api.colour import Conversion, grey_image, log_note
from ..scenes import Polyline

__all__ = [
    "POLYLINE_COLUMNS",
    "concatenate_polylines",
    "load_image",
    "load_polyline_csv",
    "read_image",
    "save_polyline_csv",
]

FloatArray = NDArray[np.float64]
PathLike = str | os.PathLike[str]

#: Required header columns of a polyline CSV, in the order they are written.
POLYLINE_COLUMNS: tuple[str, ...] = ("v", "u", "nv", "nu", "sigma")

_FITS_SUFFIXES = {".fits", ".fit", ".fts"}

def _existing(path: PathLike, what: str) -> Path:
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{what} not found: {p}")
    if p.is_dir():
        raise ValueError(f"{what} is a directory, not a file: {p}")
    return p


def _reason(exc: BaseException) -> str:
    """``Type: message`` of an exception on one line (some span several)."""
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


#: Pillow modes read as they are: grey (``1`` as 0/255), palette, RGB(A)
#: and the integer and float grey modes, whose values are kept unscaled.
_PILLOW_AS_IS = {"L", "RGB", "RGBA", "I", "I;16", "I;16L", "I;16B", "I;16N", "F"}

#: Pillow modes Pillow converts for us: to grey for a grey image with
#: alpha, to RGB(A) for the rest. CMYK and YCbCr are colour spaces whose
#: channels are not R, G, B: read raw they would give an inverted or wrong
#: image. Any other mode (LAB, premultiplied ``La``, packed 15/16-bit
#: RGB...) is refused by name.
_PILLOW_CONVERT = {
    "1": "L",
    "LA": "L",
    "P": "RGBA",
    "PA": "RGBA",
    "RGBX": "RGB",
    "RGBa": "RGBA",
    "CMYK": "RGB",
    "YCbCr": "RGB",
    "HSV": "RGB",
}


def _pillow_array(p: Path) -> np.ndarray:
    try:
        from PIL import Image
    except ImportError:
        raise ImportError(
            f"reading {p.suffix or 'image'} files needs Pillow: pip install pillow "
            "(or install dtalign with its extra: pip install '.[cli]' in a clone)"
        ) from None
    try:
        with Image.open(p) as img:
            frames = getattr(img, "n_frames", 1)
            mode = img.mode
            if frames == 1 and mode in _PILLOW_AS_IS | _PILLOW_CONVERT.keys():
                img.load()
                if mode in _PILLOW_CONVERT:
                    return np.asarray(img.convert(_PILLOW_CONVERT[mode]))
                return np.asarray(img)
    except Exception as exc:  # OSError, DecompressionBombError, SyntaxError from a plugin...
        raise ValueError(f"cannot read image {p}: {_reason(exc)}") from None
    if frames != 1:
        raise ValueError(
            f"image {p} has {frames} frames (an animation or a stack): "
            "dtalign reads one 2-D image; save the frame you want on its own"
        )
    raise ValueError(
        f"image {p} has Pillow mode {mode!r}, which dtalign does not read: "
        "save it as grey (L, I;16, I or F) or RGB"
    )


def load_image(path: PathLike, *, nonfinite: bool = False) -> FloatArray:
    """Read a 2-D image as float64; a colour image's conversion is logged.

    :func:`read_image` (``nonfinite`` as there), with its note about a
    colour image logged on the ``dtalign`` logger (``INFO`` for a grey
    image saved as colour, ``WARNING`` for a colour one read as its luma).
    """
    image, note = read_image(path, nonfinite=nonfinite)
    log_note(note)
    return image


def read_image(path: PathLike, *, nonfinite: bool = False
               ) -> tuple[FloatArray, Conversion | None]:
    """Read a 2-D image as float64, and say how a colour image was converted.

    Parameters
    ----------
    path : str or path-like
        ``.npy`` (a 2-D numeric array, loaded without pickles), ``.fits`` /
        ``.fit`` / ``.fts`` (the first HDU holding 2-D data; needs astropy),
        or any format Pillow reads (``.png``, ``.tif``, ``.jpg``...).
        A colour image follows the pipeline's rule
        (:mod:`dtalign.api.colour`): channels all equal (a grey image saved
        as RGB, like the Cassini summary PNGs) give their G channel; any
        other colour image gives the BT.601 luma ``0.299 R + 0.587 G +
        0.114 B``. An alpha channel is ignored. Pillow modes: grey ``L``, ``I;16``,
        ``I`` and ``F`` keep their values; ``1`` gives 0/255; ``LA`` its
        grey; palette (``P``, ``PA``), ``CMYK``, ``YCbCr``, ``HSV``,
        ``RGBX`` and ``RGBa`` are converted to RGB by Pillow first. Other
        modes (``LAB``...) and multi-frame files (animations, stacks) are
        refused by name.
    nonfinite : bool, optional
        Keep NaN and inf pixels (for a bad-pixel mask to cover them:
        :func:`dtalign.pipeline.prepare_image`'s ``mask``) instead of
        refusing the file.

    Returns
    -------
    image : ndarray, shape (H, W), float64
    note : Conversion or None
        What was done to a colour image (:class:`dtalign.api.colour.Conversion`),
        None for a grey one.

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    ValueError
        If the file cannot be read (whatever the reading library raised:
        an empty or truncated file, a header claiming more pixels than
        Pillow's decompression-bomb limit or than the file holds...) or
        does not hold a non-empty, 2-D image, finite unless ``nonfinite``. The message is one
        line and names the file.
    ImportError
        For a FITS file without astropy, or a PNG without Pillow; the
        message says what to install.
    """
    p = _existing(path, "image file")
    suffix = p.suffix.lower()
    if suffix == ".npy":
        arr = _load_npy(p)
    elif suffix in _FITS_SUFFIXES:
        arr = _load_fits(p)
    else:
        arr = _pillow_array(p)
    arr, note = grey_image(arr, f"image {p}")
    if arr.ndim != 2:
        raise ValueError(f"image {p} must be 2-D (or RGB), got shape {arr.shape}")
    if arr.size == 0:
        raise ValueError(f"image {p} is empty (shape {arr.shape})")
    out = np.ascontiguousarray(arr, dtype=np.float64)
    if not nonfinite and not np.isfinite(out).all():
        raise ValueError(f"image {p} has NaN or inf pixels")
    return out, note


def _load_npy(p: Path) -> np.ndarray:
    """A numeric array from a ``.npy`` file, without pickles.

    Memory-mapped, so a header that claims more data than the file holds
    is refused before anything of that size is allocated.
    """
    try:
        arr = np.load(p, allow_pickle=False, mmap_mode="r")
    except Exception as exc:  # EOFError (empty file), ValueError (bad header, pickles)...
        raise ValueError(f"cannot read image {p}: {_reason(exc)}") from None
    if not isinstance(arr, np.ndarray):
        close = getattr(arr, "close", None)
        if close is not None:
            close()
        raise ValueError(f"image {p} must hold a numeric array, got {type(arr).__name__}")
    if arr.dtype.kind not in "biuf":
        raise ValueError(f"image {p} must hold a numeric array, got dtype {arr.dtype}")
    try:
        # A copy in memory: the caller gets an ordinary array, not a view of the file.
        return np.array(arr, dtype=np.float64, order="C")
    except Exception as exc:  # e.g. OSError: the file cannot be read back
        raise ValueError(f"cannot read image {p}: {_reason(exc)}") from None


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
    except Exception as exc:  # astropy raises OSError, but also others for bad headers
        raise ValueError(f"cannot read FITS file {p}: {_reason(exc)}") from None
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
        If the file cannot be read (not UTF-8, a cell over
        ``csv.field_size_limit()``, 128 KiB by default: the message gives
        the line), columns are missing (the message lists them), a value is
        not a finite number (the message gives the line and column), a
        sigma is not > 0, or there are no vertex rows. Every message is one
        line and names the file.
    """
    p = _existing(path, "polyline file")
    try:
        with open(p, newline="", encoding="utf-8-sig") as fh:
            reader = csv.reader(fh)
            try:
                rows = list(reader)
            except csv.Error as exc:  # a NUL byte, a cell over csv.field_size_limit()
                raise ValueError(
                    f"polyline CSV {p} line {reader.line_num}: {_reason(exc)}"
                ) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"cannot read polyline CSV {p}: {_reason(exc)}") from None
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
