"""Image products: what the fitter needs from one image, computed once.

* :func:`estimate_noise_sigma` estimates an image's Gaussian noise sigma
  (Immerkaer's kernel, robust to edges and smooth shading);
* :func:`prepare_image` computes an image's products (gradient, truncated
  edge DT, edge mask, noise sigma) once, as an :class:`ImageProducts`;
* :func:`~dtalign.pipeline.fit_polyline_products` then fits one polyline
  against them, so several polylines (a limb, a terminator, a ring edge)
  share them.

These names are re-exported by :mod:`dtalign.pipeline` and the top-level
``dtalign`` package.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..api import checks as check
from ..api.checks import check_image, check_noise_sigma, resolve_config
from ..api.colour import grey_image, log_note
from ..api.loop import noise_statistics
from ..api.results import ImageDerivativesConfig
from .region import Region

__all__ = [
    "ImageProducts",
    "estimate_noise_sigma",
    "prepare_image",
]

FloatArray = NDArray[np.float64]

#: 1.4826 * MAD is the standard deviation of a Gaussian.
_MAD_TO_SIGMA = 1.4826

#: The L2 norm of Immerkaer's kernel ``[[1, -2, 1], [-2, 4, -2], [1, -2, 1]]``
#: (the product of two second differences, zero on any planar patch).
_NOISE_KERNEL_NORM = 6.0


def _compute_all_image_derivatives(
    image: FloatArray, noise_sigma: float, *, config: ImageDerivativesConfig
) -> Any:
    """:func:`dtalign.compute_all_image_derivatives` of an image already checked.

    Imported at call time: importing this module must not import the
    compiled kernels.
    """
    from ..api.image import all_derivatives

    return all_derivatives(image, noise_sigma, config)


def _readonly(arr: np.ndarray) -> np.ndarray:
    view = arr.view()
    view.flags.writeable = False
    return view


# ---------------------------------------------------------------------------
# Noise
# ---------------------------------------------------------------------------


#: The noise estimate's step on integer-valued pixels: the filtered values
#: are integers, so their MAD moves in whole DN and the estimate
#: ``1.4826 * MAD / 6`` in steps of this (0.2471 DN).
QUANTISED_NOISE_STEP = 1.4826 / 6.0

#: An estimate of at most this many (whole or half) steps is reported as
#: quantised: a few steps say "about a DN", not three digits.
#: (8-bit Cassini summary frames give exactly 2 steps, 0.4942 DN.)
_QUANTISED_NOTE_STEPS = 4

logger = logging.getLogger("dtalign")


def quantised_noise_steps(sigma: float) -> float | None:
    """How many :data:`QUANTISED_NOISE_STEP` a noise estimate is, when it sits on that floor.

    A whole or half number of steps, at most a few (the MAD of quantised
    pixels, see :func:`estimate_noise_sigma`); None otherwise.
    """
    steps = sigma / QUANTISED_NOISE_STEP
    half = round(steps * 2) / 2
    if 0.0 < steps <= _QUANTISED_NOTE_STEPS and abs(steps - half) < 1e-9:
        return half
    return None


def _quantised_note(sigma: float) -> None:
    """Log at INFO when an estimate sits on the quantisation floor of integer pixels.

    That is, when it is a whole or half number of :data:`QUANTISED_NOISE_STEP`,
    at most a few: the MAD of the filtered values was a whole number of DN,
    which quantised pixels give (the bulk of the image: an image whose
    overlay was painted over with medians still has it) and continuous
    noise almost never does.
    """
    steps = quantised_noise_steps(sigma)
    if steps is None:
        return
    logger.info(
        "noise sigma estimated as %.4g = %g x %.4f (1.4826 / 6 of 1 DN): the MAD of quantised "
        "pixels, so it only says 'about %g DN'; pass noise_sigma if the camera's noise is known",
        sigma, steps, QUANTISED_NOISE_STEP, round(sigma, 1))


def estimate_noise_sigma(image: ArrayLike) -> float:
    """Robust estimate of the per-pixel Gaussian noise sigma of an image.

    The image is convolved with Immerkaer's 3 x 3 kernel
    ``[[1, -2, 1], [-2, 4, -2], [1, -2, 1]]`` (the product of two second
    differences), which cancels any locally planar intensity: the flat
    inside and outside of a bright disc, and smooth shading, give zero.
    Only noise and the few pixels on an edge remain. For white Gaussian
    noise of sigma ``s`` the output has standard deviation ``6 s`` (the
    kernel's L2 norm), so the estimate is ``1.4826 * MAD / 6`` over the
    interior pixels, where MAD is the median absolute deviation from the
    median. The median ignores the edge pixels as long as they are a
    minority of the image.

    When more than half of the filtered pixels are equal (a quantised image
    with almost no noise, where the MAD is 0), the mean absolute value is
    used instead: ``sqrt(pi / 2) * mean(|x|) / 6``, Immerkaer's original
    estimator.

    On integer-valued pixels (8- or 16-bit data) the filtered values are
    integers, so the MAD is a whole (or half) number of DN and the estimate
    moves in steps of :data:`QUANTISED_NOISE_STEP` = 1.4826 / 6 = 0.2471:
    a low-noise 8-bit frame gives a few steps (both Cassini summary frames
    give exactly 0.4942, two steps), which says "about half a DN", not four
    digits. :func:`prepare_image` logs an ``INFO`` note when its estimate
    sits on that floor; pass ``noise_sigma`` when the camera's noise is
    known.

    The work is compiled (:mod:`dtalign._kernels.noise`: the responses a
    row at a time, exact selection medians) and gives the value of its
    NumPy/SciPy definition, :func:`dtalign.reference.estimate_noise_sigma`
    (bit for bit in the tests; the contract is 1e-12 relative), in a
    fraction of its time (``estimate_noise_sigma`` benchmark row).

    Parameters
    ----------
    image : array_like, shape (H, W)
        A finite 2-D image.

    Returns
    -------
    float
        The noise sigma in the image's units (0.0 for a constant or
        noiseless planar image, or an image smaller than 3 x 3).

    Raises
    ------
    TypeError
        If ``image`` is not 2-D or not numeric.
    ValueError
        If ``image`` is empty or has NaN or inf pixels.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> image = 100.0 + rng.normal(0.0, 2.0, (256, 256))
    >>> round(estimate_noise_sigma(image), 1)
    2.0
    """
    return _estimate_noise_sigma_checked(check_image(image))


def _estimate_noise_sigma_checked(arr: FloatArray) -> float:
    """:func:`estimate_noise_sigma` of an image :func:`check_image` returned.

    The compiled :func:`dtalign._kernels.noise.noise_statistics` gives the
    same median and MAD as the NumPy definition
    (:func:`dtalign.reference.estimate_noise_sigma`), bit for bit.
    """
    if arr.shape[0] < 3 or arr.shape[1] < 3:
        return 0.0
    _, mad, mean_abs = noise_statistics(arr)
    if mad > 0.0:
        return _MAD_TO_SIGMA * mad / _NOISE_KERNEL_NORM
    return math.sqrt(math.pi / 2.0) * mean_abs / _NOISE_KERNEL_NORM


# ---------------------------------------------------------------------------
# Image products
# ---------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class ImageProducts:
    """Everything the fitter needs from one image, computed once.

    Build it with :func:`prepare_image`; pass it to
    :func:`~dtalign.pipeline.fit_polyline_products` as many times as there
    are polylines. The arrays are read-only.

    Attributes
    ----------
    shape : tuple of int
        The image shape ``(H, W)``.
    noise_sigma : float
        The noise sigma the edge threshold used (given, or estimated by
        :func:`estimate_noise_sigma`).
    gradient_magnitude : ndarray, shape (H, W)
        ``hypot(g_v, g_u)`` of the Sobel-of-Gaussian gradient.
    edge_dt : ndarray, shape (H, W)
        Truncated Euclidean distance to the nearest thinned edge pixel.
    gradient_vu : ndarray, shape (H, W, 2)
        The gradient vectors ``(g_v, g_u)`` (polarity and ridge polish).
    edge_mask : ndarray of bool, shape (H, W)
        ``edge_dt <= 0.5``: what the coarse search matches against.
    config : ImageDerivativesConfig
        The tunables the products were computed with.
    noise_sigma_estimated : bool
        True when ``noise_sigma`` was estimated from the image.
    timings_s : dict
        Wall time of each step (``noise``, ``derivatives``), seconds.
    image : ndarray, shape (H, W), or None
        The image itself (float64, read-only), kept by
        :func:`prepare_image` for the profile refinement
        (:mod:`dtalign.pipeline.profile_fit`); None in products built
        without it.
    region : Region or None
        None for the whole frame; else the crop of the frame the arrays
        cover (:mod:`dtalign.pipeline.region`): ``shape`` is then the
        crop's, and the fits on these products work in its pixels and
        report the frame's.
    mask : ndarray of bool, shape (H, W), or None
        The bad pixels (read-only): the ``mask`` given to
        :func:`prepare_image` and the image's NaN or inf pixels, which
        the products were computed without (:mod:`dtalign.pipeline.masked`)
        and the profile refinement leaves out; None when no pixel is bad.

    Instances compare by identity (the arrays have no single truth value).
    """

    shape: tuple[int, int]
    noise_sigma: float
    gradient_magnitude: FloatArray
    edge_dt: FloatArray
    gradient_vu: FloatArray
    edge_mask: NDArray[np.bool_]
    config: ImageDerivativesConfig = field(default_factory=ImageDerivativesConfig)
    noise_sigma_estimated: bool = False
    timings_s: dict[str, float] = field(default_factory=dict, repr=False)
    image: FloatArray | None = field(default=None, repr=False)
    region: Region | None = field(default=None, repr=False)
    mask: NDArray[np.bool_] | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if self.mask is not None:
            from .masked import check_mask

            object.__setattr__(self, "mask", _readonly(check_mask(self.mask, self.shape)))
        if self.image is not None:
            if not isinstance(self.image, np.ndarray) or self.image.shape != tuple(self.shape):
                raise ValueError(f"image must be an ndarray of shape {tuple(self.shape)}")
            object.__setattr__(self, "image", _readonly(self.image))
        # The arrays are checked here, once (as the LM checks its DT and
        # gradient, scan threshold included): every fit then trusts them.
        for name, checked in (("gradient_magnitude", check.image2d), ("edge_dt", check.image2d),
                              ("gradient_vu", check.gradient), ("edge_mask", check.mask2d)):
            value = getattr(self, name)
            if not isinstance(value, np.ndarray):
                raise TypeError(f"{name} must be a numpy.ndarray, got {type(value).__name__}")
            object.__setattr__(self, name, _readonly(checked(value, name)))
        shape = tuple(int(s) for s in self.shape)
        if len(shape) != 2:
            raise ValueError(f"shape must be (H, W), got {self.shape!r}")
        object.__setattr__(self, "shape", shape)
        for name in ("gradient_magnitude", "edge_dt", "edge_mask"):
            if getattr(self, name).shape != shape:
                raise ValueError(
                    f"{name} shape {getattr(self, name).shape} does not match shape {shape}"
                )
        if self.gradient_vu.shape != (*shape, 2):
            raise ValueError(
                f"gradient_vu must have shape {(*shape, 2)}, got {self.gradient_vu.shape}"
            )


def prepare_image(
    image: ArrayLike, noise_sigma: float | None = None, *, config: ImageDerivativesConfig | None = None,
    mask: ArrayLike | None = None,
) -> ImageProducts:
    """Compute an image's fitting products once.

    Parameters
    ----------
    image : array_like, shape (H, W), or (H, W, 3 or 4) for colour
        A finite, non-empty image. A colour one is converted by the rule of
        :mod:`dtalign.api.colour` and the conversion logged on the
        ``dtalign`` logger: equal channels give their grey values (``INFO``),
        others the luma (``WARNING``: a coloured overlay is fitted too).
    noise_sigma : float, optional
        The image noise sigma, in the image's units. Estimated with
        :func:`estimate_noise_sigma` when None.
    config : ImageDerivativesConfig, optional
        Gradient smoothing, edge threshold and DT truncation; defaults when
        None.
    mask : array_like of bool, shape (H, W), optional
        Bad pixels (True = bad: saturated, cosmic rays, missing lines). With
        a mask, NaN and inf pixels are bad too, and the products are
        computed from the other pixels only (:mod:`dtalign.pipeline.masked`):
        no edge on a bad pixel, derivatives by normalised convolution, the
        noise from responses clear of them. An all-False mask on a finite
        image gives the products of no mask, bit for bit.

    Returns
    -------
    ImageProducts

    Raises
    ------
    TypeError
        If ``image`` is not a 2-D (or colour) numeric array, ``config`` is not an
        :class:`~dtalign.ImageDerivativesConfig`, or ``mask`` is not boolean.
    ValueError
        If ``image`` is empty or (without a mask) not finite, ``noise_sigma`` is
        negative or not finite, or ``mask`` does not have the image's shape
        or masks every pixel.
    """
    return products_of(image, noise_sigma, config, None, mask)


def products_of(image: ArrayLike, noise_sigma: float | None,
                config: ImageDerivativesConfig | None, region: Region | None,
                mask: ArrayLike | None = None) -> ImageProducts:
    """:func:`prepare_image` of ``image``, or of ``region``'s crop of a 2-D
    ``image`` (:func:`dtalign.pipeline.region.fit_region`): the crop alone
    is converted, checked and estimated, so pixels outside it are never
    read. An image with bad pixels (``mask``) gets the masked products of
    the whole frame (:mod:`dtalign.pipeline.masked`), whatever ``region``."""
    if mask is not None:
        # colour: the rule of dtalign.api.colour, said on the logger
        image, note = grey_image(image)
        log_note(note)
        from . import masked

        found = masked.bad_pixels(image, mask)
        if found is not None:
            parts = masked.masked_parts(*found, noise_sigma, resolve_config(config))
            if parts["noise_sigma_estimated"] and logger.isEnabledFor(logging.INFO):
                _quantised_note(parts["noise_sigma"])
            return ImageProducts(**parts)
    frame = np.asarray(image) if region is not None else None
    if region is not None and frame is not None and frame.shape == region.frame_shape:
        (v0, u0), (h, w) = region.origin_vu, region.shape
        arr = check_image(frame[v0 : v0 + h, u0 : u0 + w], "image")
    else:
        grey, note = grey_image(image)  # (a no-op on an image made grey above)
        log_note(note)
        arr = check_image(grey, "image")
        region = None
    cfg = resolve_config(config)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    estimated = noise_sigma is None
    if estimated:
        sigma = _estimate_noise_sigma_checked(arr)
        if logger.isEnabledFor(logging.INFO):
            _quantised_note(sigma)
    else:
        sigma = check_noise_sigma(noise_sigma, "noise_sigma")
    t1 = time.perf_counter()
    timings["noise"] = t1 - t0
    magnitude, edge_dt, gradient_vu = _compute_all_image_derivatives(arr, sigma, config=cfg)
    edge_mask = np.asarray(edge_dt) <= 0.5
    timings["derivatives"] = time.perf_counter() - t1
    return ImageProducts(
        shape=(arr.shape[0], arr.shape[1]),
        noise_sigma=float(sigma),
        gradient_magnitude=np.asarray(magnitude),
        edge_dt=np.asarray(edge_dt),
        gradient_vu=np.asarray(gradient_vu),
        edge_mask=edge_mask,
        config=cfg,
        noise_sigma_estimated=estimated,
        timings_s=timings,
        image=arr,
        region=region,
    )
