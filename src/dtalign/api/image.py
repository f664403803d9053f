"""Image-side products: gradient, gradient magnitude and the clipped edge DT.

Drop-in for the NumPy/SciPy specification :mod:`dtalign.reference.image`
(:ref:`contract-surface`, :ref:`contract-image`): same names, keywords, defaults, checks and error
messages, and bit-identical results, computed by the compiled kernels of
:mod:`dtalign._kernels.image` in two streaming sweeps over the image.

The inputs are validated and converted to C-contiguous float64 once, here;
the kernels never validate.
"""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .._kernels import image as _k
from .checks import (
    FloatArray,
    check_image,
    check_noise_sigma,
    check_sigma_px,
    resolve_config,
    smoothing_sigma,
)
from .constants import DEFAULT_IMAGE_GRADIENT_SIGMA_PX, NOISE_SIGMA_FLOOR
from .results import ImageDerivativesConfig

__all__ = [
    "ImageDerivativesConfig",
    "build_image_edge_dt",
    "compute_all_image_derivatives",
    "compute_image_gradient_vu",
]

#: Sector test of the Canny thinning: tan(67.5 deg) = 1 + sqrt(2), computed
#: exactly as the reference does.
_SECTOR_K = float(1.0 + np.sqrt(2.0))

#: ``scipy.ndimage.gaussian_filter`` defaults that the contract fixes.
_TRUNCATE = 4.0
#: ``gaussian_filter`` leaves an axis alone when its sigma is not above this.
_SCIPY_MIN_SIGMA = 1e-15


def _gaussian_weights(sigma: float) -> FloatArray:
    """SciPy's 1-D Gaussian correlation weights, bit for bit.

    Mirrors ``gaussian_filter1d`` / ``_gaussian_kernel1d`` (SciPy 1.11-1.17):
    ``radius = int(truncate * sigma + 0.5)``,
    ``phi = exp(-0.5 / sigma**2 * x**2)``, ``phi /= phi.sum()``, reversed
    for correlation. A sigma SciPy skips becomes the identity ``[1.0]``
    (``x * 1.0 == x`` exactly).
    """
    if not sigma > _SCIPY_MIN_SIGMA:
        return np.ones(1)
    radius = int(_TRUNCATE * float(sigma) + 0.5)
    sigma2 = sigma * sigma
    x = np.arange(-radius, radius + 1)
    phi = np.exp(-0.5 / sigma2 * x**2)
    phi = phi / phi.sum()
    return np.ascontiguousarray(phi[::-1], dtype=np.float64)


def support_px(cfg: ImageDerivativesConfig) -> int:
    """How far from a pixel the image decides its products under ``cfg``, pixels.

    The edge DT at a pixel is the distance to the nearest edge pixel within
    ``dt_half_width_px``; whether a pixel is an edge depends on the image
    within the Gaussian's radius (SciPy's: ``int(4 sigma + 0.5)``), the Sobel
    step and the thinning's neighbours (one pixel each). A crop of an image
    padded by this much gives the whole image's products inside the padding
    (:mod:`dtalign.pipeline.region`).
    """
    radius = (len(_gaussian_weights(cfg.image_gradient_sigma_px)) - 1) // 2
    return int(math.floor(cfg.dt_half_width_px)) + 1 + radius + 2


def _column_cap(half_width: float, shape: tuple[int, int]) -> float:
    """Cap of the 1-D column distances that leaves the clipped DT exact.

    With column distances ``g`` capped at ``C``, the capped squared
    distance ``D'`` satisfies ``min(D, C**2) <= D' <= D``. If ``C > hw``:
    ``D <= hw**2`` gives ``D' = D``, and ``D > hw**2`` gives
    ``D' > hw**2``, so ``min(sqrt(D'), hw)`` is unchanged (sqrt is
    monotone and correctly rounded). If instead ``hw >= H + W``, nothing in
    the image is that far, so ``C = H + W`` keeps every distance exact and
    only an image without edges reaches ``C`` (filled with ``hw``).
    The small cap keeps all arithmetic in exact small integers.
    """
    bound = shape[0] + shape[1]
    if half_width >= bound:
        return float(bound)
    return float(math.floor(half_width) + 1)


@functools.lru_cache(maxsize=1)
def _use_libm_hypot() -> bool:
    """Whether this platform's ``np.hypot`` differs from the glibc port.

    Checked once per process on a fixed probe set (normal, widely scaled,
    integer-valued, tiny, huge and zero pairs); on any difference every
    magnitude goes through libm's ``hypot`` instead (slower, same result as
    NumPy on platforms where NumPy also calls libm).
    """
    rng = np.random.default_rng(20240611)
    n = 4096
    x = np.concatenate(
        [
            rng.normal(size=n),
            rng.normal(size=n) * np.exp(rng.normal(size=n) * 20.0),
            rng.integers(-300, 300, size=n).astype(np.float64),
            np.array([0.0, -0.0, 1.0, 3.0, 1e-310, 1e300, 2.0**511, 2.0**-511, 1.0]),
        ]
    )
    y = np.concatenate(
        [
            rng.normal(size=n),
            rng.normal(size=n),
            rng.integers(-300, 300, size=n).astype(np.float64),
            np.array([0.0, 0.0, 2.0**-54, 4.0, 1e-300, 1e300, 2.0**511, 2.0**-511, 2.0**-53]),
        ]
    )
    out = np.empty_like(x)
    _k.hypot_row(x, y, out, False)
    return not np.array_equal(out.view(np.int64), np.hypot(x, y).view(np.int64))


def compute_image_gradient_vu(
    image_ext: ArrayLike, *, sigma_px: float = DEFAULT_IMAGE_GRADIENT_SIGMA_PX
) -> FloatArray:
    """Sobel-of-Gaussian image gradient.

    Parameters
    ----------
    image_ext : array_like, shape (H, W)
        Finite real image (any real dtype or memory layout), non-empty.
    sigma_px : float, optional
        Sigma of the Gaussian pre-smoothing in pixels (SciPy's
        ``gaussian_filter``: mode ``reflect``, truncate 4.0); at most
        ``max(H, W, 32)``, which bounds the work (docs/limits.rst).

    Returns
    -------
    ndarray, shape (H, W, 2), float64
        ``[..., 0] = g_v`` (Sobel along rows, axis 0) and ``[..., 1] = g_u``
        (along columns, axis 1), mode ``constant`` with ``cval = 0``.

    Raises
    ------
    TypeError
        If the image is not 2-D (``image_ext must be 2-D``) or not real.
    ValueError
        If the image is empty or has NaN/inf pixels (``finite``), or
        ``sigma_px`` is not finite and > 0
        (``sigma_px must be a finite positive number``).
    """
    image = check_image(image_ext)
    sigma = check_sigma_px(sigma_px)
    smoothing_sigma(sigma, image.shape, "sigma_px")
    grad = np.empty(image.shape + (2,))
    _k.gradient_vu(image, _gaussian_weights(sigma), grad)
    return grad


def build_image_edge_dt(
    image_ext: ArrayLike, image_noise_sigma: float, *, config: Any = None
) -> tuple[FloatArray, FloatArray]:
    """Gradient magnitude and the clipped distance transform of the edges.

    Parameters
    ----------
    image_ext : array_like, shape (H, W)
        Finite real image, non-empty.
    image_noise_sigma : float
        Noise standard deviation of the image (DN), finite and >= 0. The
        edge threshold is ``edge_threshold_k_sigma * max(noise, 1e-6)``.
    config : ImageDerivativesConfig, optional
        Smoothing sigma, edge threshold and DT clip; ``None`` means the
        defaults.

    Returns
    -------
    gradient_magnitude : ndarray, shape (H, W), float64
        ``hypot(g_v, g_u)``.
    edge_dt : ndarray, shape (H, W), float64
        Euclidean distance to the nearest thinned edge pixel, clipped at
        ``dt_half_width_px`` (all ``dt_half_width_px`` without edges).

    Raises
    ------
    TypeError, ValueError
        As :func:`compute_all_image_derivatives`.
    """
    magnitude, edge_dt, _ = compute_all_image_derivatives(
        image_ext, image_noise_sigma, config=config
    )
    return magnitude, edge_dt


def compute_all_image_derivatives(
    image_ext: ArrayLike, image_noise_sigma: float, *, config: Any = None
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Gradient magnitude, clipped edge DT and gradient vectors in one pass.

    Parameters
    ----------
    image_ext : array_like, shape (H, W)
        Finite real image (any real dtype or memory layout), non-empty.
    image_noise_sigma : float
        Noise standard deviation of the image (DN), finite and >= 0.
    config : ImageDerivativesConfig, optional
        ``None`` means ``ImageDerivativesConfig()``. Its
        ``image_gradient_sigma_px`` must be at most ``max(H, W, 32)``
        (ValueError naming ``config.image_gradient_sigma_px``).

    Returns
    -------
    gradient_magnitude : ndarray, shape (H, W), float64
        ``hypot(g_v, g_u)``.
    edge_dt : ndarray, shape (H, W), float64
        Exact Euclidean distance to the nearest edge pixel (Canny-style
        thinning of :ref:`contract-image`, magnitude strictly above the
        threshold), clipped at ``dt_half_width_px``.
    gradient_vu : ndarray, shape (H, W, 2), float64
        As :func:`compute_image_gradient_vu` with
        ``sigma_px = config.image_gradient_sigma_px``.

    Raises
    ------
    TypeError
        If the image is not 2-D (``image_ext must be 2-D``) or not real, or
        ``config`` is not an ``ImageDerivativesConfig``.
    ValueError
        If the image is empty or not finite (``finite``), or the noise
        sigma is negative or not finite
        (``image_noise_sigma must be finite and >= 0``).

    Notes
    -----
    Beyond the three returned arrays the work needs only a few rows of
    scratch memory (plus one float64 copy of the image when the input is
    not already C-contiguous native float64).
    """
    image = check_image(image_ext)
    noise = check_noise_sigma(image_noise_sigma)
    cfg = resolve_config(config)
    return all_derivatives(image, noise, cfg)


def edge_threshold(cfg: ImageDerivativesConfig, noise: float) -> float:
    """The gradient magnitude an edge pixel must reach: ``k`` noise sigmas
    (``cfg.edge_threshold_k_sigma``), the noise floored at
    :data:`~dtalign.api.constants.NOISE_SIGMA_FLOOR`."""
    return float(cfg.edge_threshold_k_sigma * max(noise, NOISE_SIGMA_FLOOR))


def all_derivatives(
    image: FloatArray, noise: float, cfg: ImageDerivativesConfig
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """:func:`compute_all_image_derivatives` of arguments it has checked (the
    pipeline checks the image once per call); the smoothing check is a few
    scalar comparisons and runs on both paths."""
    smoothing_sigma(cfg.image_gradient_sigma_px, image.shape, "config.image_gradient_sigma_px")
    threshold = edge_threshold(cfg, noise)
    half_width = cfg.dt_half_width_px
    grad = np.empty(image.shape + (2,))
    magnitude = np.empty(image.shape)
    edge_dt = np.empty(image.shape)
    _k.all_derivatives(
        image,
        _gaussian_weights(cfg.image_gradient_sigma_px),
        float(threshold),
        _SECTOR_K,
        float(half_width),
        _column_cap(half_width, image.shape),
        _use_libm_hypot(),
        grad,
        magnitude,
        edge_dt,
    )
    return magnitude, edge_dt, grad
