"""Bad-pixel masks: image products that ignore the pixels a mask names.

A mask (``True`` = bad: saturated, a cosmic ray, a missing line, a dead
column) and every NaN or inf pixel of an image given with one are
*unmeasured*: :func:`masked_parts` computes the products of
:func:`~dtalign.pipeline.products.prepare_image` from the other pixels
only, so a masked pixel never becomes an edge and does not distort the
derivatives, the noise estimate or the profile strips around it:

* **smoothing** by normalised convolution: the Gaussian of the image with
  its bad pixels zeroed, divided by the Gaussian of the valid pixels'
  indicator. The result is the Gaussian-weighted mean of the valid pixels
  near each pixel, so a saturated plateau or a zero-filled line does not
  leak into its neighbours, and a masked pixel that is mostly surrounded
  by valid ones (a cosmic ray, a one-row gap) is filled from them. Where
  less than :data:`MIN_VALID_WEIGHT` of the Gaussian's weight is valid the
  smoothed value would be an extrapolation: it is *undefined*;
* **Sobel** on the smoothed image, kept only where its 3 x 3 support is
  defined (zero elsewhere);
* **edges**: the Canny-style thinning of :mod:`dtalign.reference.image`,
  where a pixel whose gradient is undefined counts as a larger neighbour
  (an edge next to it is not a confirmed maximum), then every edge on a
  bad pixel or an undefined gradient dropped before the distance
  transform: the DT inside a masked region is the distance to the
  measured edges around it;
* **noise**: Immerkaer's response only where its 3 x 3 support is all
  valid (:func:`masked_noise_sigma`);
* the **profile refinement** (:mod:`dtalign.pipeline.profile_fit`) leaves
  the strips' pixels on the mask out (it reads ``ImageProducts.mask``).

Without bad pixels (no mask, or an all-False one on a finite image)
:func:`~dtalign.pipeline.products.prepare_image` does not come here: its
products are the compiled ones, bit for bit. The drop-in
:func:`dtalign.compute_all_image_derivatives` keeps refusing NaN: the
masked path is the pipeline's, written with SciPy.
"""

from __future__ import annotations

import logging
import math
import os
import time
from typing import Any

import numpy as np
import scipy.ndimage
from numpy.typing import ArrayLike, NDArray

from ..api.checks import check_image, check_noise_sigma
from ..api.image import edge_threshold
from ..api.results import ImageDerivativesConfig
from ..reference.image import clipped_edge_dt, thinned_edges
from ..reference.noise import MAD_TO_SIGMA, NOISE_KERNEL, NOISE_KERNEL_NORM

logger = logging.getLogger("dtalign")

__all__ = [
    "MIN_VALID_WEIGHT",
    "bad_pixels",
    "check_mask",
    "load_mask",
    "masked_derivatives",
    "masked_noise_sigma",
    "masked_vertex_count",
    "masked_parts",
]

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

#: The least fraction of a pixel's Gaussian weight that must fall on valid
#: pixels for its smoothed value to be defined. At one half the normalised
#: mean is dominated by measured pixels on the pixel's own side: a one-pixel
#: line or a single masked pixel is filled (its neighbours hold 0.6 and
#: more of the weight at the default sigma), the inside of a masked blob is
#: not, and neither is the first masked column past a straight mask border
#: (less than 0.4 of its weight is valid).
MIN_VALID_WEIGHT = 0.5

_BOX = np.ones((3, 3), dtype=bool)


def check_mask(mask: ArrayLike, shape: tuple[int, ...], name: str = "mask") -> BoolArray:
    """``mask`` as a C-contiguous bool array of ``shape`` (True = bad pixel).

    Booleans, or integers that are all 0 or 1 (a mask saved as ``uint8``);
    anything else is refused rather than guessed at.

    Raises
    ------
    TypeError
        If ``mask`` is not boolean or integer (floats, strings, objects).
    ValueError
        If its shape is not ``shape``, or its integers are not all 0 or 1.
    """
    arr = np.asarray(mask)
    if arr.dtype != np.bool_:
        if arr.dtype.kind not in "iu":
            raise TypeError(f"{name} must be a boolean array (True = bad pixel), "
                            f"got dtype {arr.dtype}")
        if arr.size and not np.isin(arr, (0, 1)).all():
            raise ValueError(f"{name} must hold only 0 and 1 (True = bad pixel); a mask image "
                             "with other values: pass mask_image != 0")
    if arr.shape != tuple(shape):
        raise ValueError(f"{name} must have the image's shape {tuple(shape)}, got {arr.shape}")
    return np.ascontiguousarray(arr, dtype=np.bool_)


def bad_pixels(image: Any, mask: ArrayLike | None) -> tuple[FloatArray, BoolArray] | None:
    """The image with its bad pixels zeroed and the bad pixels, or None when none are bad.

    The bad pixels are ``mask`` (checked by :func:`check_mask`) and, when a
    mask is given, every NaN or inf pixel. None (no mask, or no bad pixel)
    sends :func:`~dtalign.pipeline.products.prepare_image` down its usual,
    compiled path, where a NaN is an error as before.

    Raises
    ------
    TypeError, ValueError
        As ``check_image`` for the image; as :func:`check_mask` for the
        mask; ValueError when every pixel is bad.
    """
    if mask is None:
        return None
    raw = np.asarray(image)
    if raw.ndim != 2 or raw.dtype.kind not in "biuf" or raw.size == 0:
        check_image(raw, "image")  # raises its usual message
    bad = check_mask(mask, raw.shape)
    arr = np.asarray(raw, dtype=np.float64)
    finite = np.isfinite(arr)
    if finite.all() and not bad.any():
        return None
    bad = bad | ~finite
    if bad.all():
        raise ValueError(f"mask leaves no valid pixel: all {bad.size} pixels are masked "
                         "or not finite")
    return check_image(np.where(bad, 0.0, arr), "image"), bad


def masked_noise_sigma(image: FloatArray, bad: BoolArray) -> float:
    """Immerkaer's noise estimate over the responses whose 3 x 3 support is valid.

    :func:`dtalign.reference.estimate_noise_sigma` (``1.4826 * MAD / 6``, or
    ``sqrt(pi / 2) * mean|x| / 6`` when the MAD is 0) of the interior
    responses none of whose nine pixels is bad: a saturated plateau, a
    cosmic ray or a gap never enters the median. 0.0 when no response has
    a valid support.
    """
    if image.shape[0] < 3 or image.shape[1] < 3:
        return 0.0
    response = scipy.ndimage.convolve(image, NOISE_KERNEL, mode="reflect")[1:-1, 1:-1]
    touched = scipy.ndimage.binary_dilation(bad, _BOX)[1:-1, 1:-1]
    filtered = response[~touched]
    if filtered.size == 0:
        return 0.0
    centre = float(np.median(filtered))
    mad = float(np.median(np.abs(filtered - centre)))
    if mad > 0.0:
        return MAD_TO_SIGMA * mad / NOISE_KERNEL_NORM
    return math.sqrt(math.pi / 2.0) * float(np.mean(np.abs(filtered))) / NOISE_KERNEL_NORM


def masked_derivatives(image: FloatArray, bad: BoolArray, noise: float,
                       cfg: ImageDerivativesConfig) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Gradient magnitude, clipped edge DT and gradient of ``image`` without its ``bad`` pixels.

    :func:`dtalign.compute_all_image_derivatives`' three arrays, computed
    as the module says: normalised-convolution smoothing (SciPy's
    ``gaussian_filter``, mode ``reflect``, as the drop-in), Sobel (mode
    ``constant``) where the smoothing is defined, the reference's thinning
    and distance transform with the edges on bad or undefined pixels
    dropped. The gradient and magnitude are 0 where undefined.
    """
    sigma = cfg.image_gradient_sigma_px
    valid = ~bad
    weight = scipy.ndimage.gaussian_filter(valid.astype(np.float64), sigma)
    total = scipy.ndimage.gaussian_filter(np.where(valid, image, 0.0), sigma)
    defined = weight >= MIN_VALID_WEIGHT
    smooth = np.where(defined, total / np.where(defined, weight, 1.0), 0.0)
    # the Sobel of a pixel reads its 3 x 3 neighbours: outside the image is
    # its cval = 0, as on the unmasked path, not undefined
    measured = ~scipy.ndimage.binary_dilation(~defined, _BOX)
    g_v = np.where(measured, scipy.ndimage.sobel(smooth, axis=0, mode="constant", cval=0.0), 0.0)
    g_u = np.where(measured, scipy.ndimage.sobel(smooth, axis=1, mode="constant", cval=0.0), 0.0)
    magnitude = np.hypot(g_v, g_u)
    # an undefined neighbour may be the larger: no edge is confirmed next to one
    edges = thinned_edges(g_v, g_u, np.where(measured, magnitude, np.inf),
                       edge_threshold(cfg, noise))
    edges &= measured & valid
    return magnitude, clipped_edge_dt(edges, cfg.dt_half_width_px), np.stack([g_v, g_u], axis=-1)


def masked_parts(image: FloatArray, bad: BoolArray, noise_sigma: float | None,
                 cfg: ImageDerivativesConfig) -> dict[str, Any]:
    """The fields of the :class:`~dtalign.pipeline.products.ImageProducts` of
    ``image`` (bad pixels zeroed, :func:`bad_pixels`) without its ``bad`` pixels.

    The noise is :func:`masked_noise_sigma` unless given, the derivatives
    :func:`masked_derivatives`; the products keep the zero-filled image
    and ``bad`` as their ``mask``.
    """
    t0 = time.perf_counter()
    estimated = noise_sigma is None
    sigma = (masked_noise_sigma(image, bad) if noise_sigma is None
             else check_noise_sigma(noise_sigma, "noise_sigma"))
    t1 = time.perf_counter()
    magnitude, edge_dt, gradient_vu = masked_derivatives(image, bad, sigma, cfg)
    logger.debug("masked %d of %d pixels", int(bad.sum()), bad.size)
    return dict(
        shape=(image.shape[0], image.shape[1]), noise_sigma=float(sigma),
        gradient_magnitude=magnitude, edge_dt=edge_dt, gradient_vu=gradient_vu,
        edge_mask=edge_dt <= 0.5, config=cfg, noise_sigma_estimated=estimated,
        timings_s={"noise": t1 - t0, "derivatives": time.perf_counter() - t1},
        image=image, mask=bad,
    )


def masked_vertex_count(vertices_vu: FloatArray, bad: BoolArray) -> int:
    """How many of ``vertices_vu`` (already posed) fall on a bad pixel.

    A vertex's pixel is its position rounded to the nearest integer (as the
    polarity test rounds it); vertices outside the image count as not
    masked (:attr:`~dtalign.pipeline.PolylineFit.outside_image` counts them).
    """
    h, w = bad.shape
    iv = np.rint(np.asarray(vertices_vu)[:, 0])
    iu = np.rint(np.asarray(vertices_vu)[:, 1])
    inside = (iv >= 0) & (iv < h) & (iu >= 0) & (iu < w)
    return int(np.count_nonzero(bad[iv[inside].astype(np.intp), iu[inside].astype(np.intp)]))


def load_mask(path: str | os.PathLike[str]) -> BoolArray:
    """A bad-pixel mask read from an image file: nonzero pixels are bad.

    Any file :func:`dtalign.io.load_image` reads (``.npy``, FITS, PNG...),
    so a 0/255 PNG or a 0/1 FITS mask both work.
    """
    from ..io.files import load_image

    return np.ascontiguousarray(load_image(path) != 0)
