"""Colour images: the one rule the pipeline, the file reader and the CLI share.

dtalign fits grey images. An ``(H, W, 3)`` or ``(H, W, 4)`` array (RGB,
RGBA; the alpha channel is ignored) is converted, and the conversion is
said, never silent:

* channels all equal (a grey image saved as colour, like the Cassini
  summary PNGs before their overlay is drawn): the G channel, exactly the
  grey values; a note at ``INFO`` on the ``dtalign`` logger;
* any other colour image: the BT.601 luma ``0.299 R + 0.587 G + 0.114 B``,
  with a ``WARNING``: anything drawn in colour on the image (a model
  overlay) is then part of the image and is fitted too (``dtalign
  overlay`` separates a Cassini summary PNG's red overlay from its image).

Used by :func:`dtalign.pipeline.products.prepare_image` (and so by
:func:`dtalign.pipeline.fit_polyline`) and :func:`dtalign.io.load_image`;
the command line prints the same note. The drop-in functions keep the
contract's 2-D images and are not affected.
"""

from __future__ import annotations

import logging
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

__all__ = ["LUMA_WEIGHTS", "Conversion", "grey_image", "is_colour", "log_note"]

#: BT.601 luma weights of R, G, B: the usual grey of a colour picture.
LUMA_WEIGHTS = (0.299, 0.587, 0.114)

logger = logging.getLogger("dtalign")


class Conversion(NamedTuple):
    """What :func:`grey_image` did to a colour image."""

    text: str
    """One line: the image, its channels, and the conversion."""
    luma: bool
    """True for a real colour image (luma: lossy, logged at ``WARNING``),
    False for equal channels (exact, ``INFO``)."""


def is_colour(arr: Any) -> bool:
    """Whether ``arr`` has the shape of a colour image, ``(H, W, 3 or 4)``."""
    shape = np.shape(arr)
    return len(shape) == 3 and shape[2] in (3, 4)


def grey_image(arr: Any, name: str = "image") -> tuple[Any, Conversion | None]:
    """``arr`` as a grey float64 image, and the note that says how (None for grey input).

    Parameters
    ----------
    arr : array_like
        A 2-D image, or an ``(H, W, 3|4)`` colour one. Other shapes are
        returned as they are, for the caller's own check to refuse.
    name : str
        What to call the image in the note (an argument or a file name).

    Returns
    -------
    grey : ndarray
        The image; for colour input, C-contiguous float64 of shape (H, W).
    note : Conversion or None
        What was done, or None when nothing was.
    """
    if not is_colour(arr):
        return arr, None
    a = np.asarray(arr)
    if a.dtype.kind not in "biuf":
        return a, None  # the caller's dtype check names the problem
    rgb = a[..., :3].astype(np.float64)
    channels = "RGBA" if a.shape[2] == 4 else "RGB"
    if np.array_equal(rgb[..., 0], rgb[..., 1]) and np.array_equal(rgb[..., 1], rgb[..., 2]):
        return np.ascontiguousarray(rgb[..., 1]), Conversion(
            f"{name}: {channels} with equal channels, read as its grey values", False)
    grey: NDArray[np.float64] = np.ascontiguousarray(rgb @ np.asarray(LUMA_WEIGHTS))
    return grey, Conversion(
        f"{name}: colour {channels} image converted to grey (luma 0.299 R + 0.587 G + 0.114 B): "
        "anything drawn on it in colour, such as a model overlay, is fitted too (dtalign "
        "overlay separates a Cassini summary PNG's overlay from its image)", True)


def log_note(note: Conversion | None) -> None:
    """Log :func:`grey_image`'s note: ``INFO`` when exact, ``WARNING`` for luma."""
    if note is not None:
        logger.log(logging.WARNING if note.luma else logging.INFO, "%s", note.text)
