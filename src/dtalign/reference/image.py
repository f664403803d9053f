"""Plain NumPy/SciPy image side: the executable specification of :ref:`contract-image`.

Gaussian smoothing and Sobel derivatives are SciPy's; the Canny-style
thinning is written out with whole-array NumPy operations; the distance
transform is SciPy's exact Euclidean transform.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.ndimage

from ..api.checks import (
    FloatArray,
    check_image,
    check_noise_sigma,
    check_sigma_px,
    resolve_config,
    smoothing_sigma,
)
from ..api.constants import DEFAULT_IMAGE_GRADIENT_SIGMA_PX, NOISE_SIGMA_FLOOR

#: Sector test of the Canny thinning: tan(67.5 deg) = 1 + sqrt(2).
_SECTOR_K = 1.0 + np.sqrt(2.0)


def compute_image_gradient_vu(
    image_ext: Any, *, sigma_px: float = DEFAULT_IMAGE_GRADIENT_SIGMA_PX
) -> FloatArray:
    """Sobel-of-Gaussian gradient, ``[..., 0] = g_v`` and ``[..., 1] = g_u``."""
    image = check_image(image_ext)
    sigma = check_sigma_px(sigma_px)
    smoothing_sigma(sigma, image.shape, "sigma_px")
    return _gradient(image, sigma)


def _gradient(image: FloatArray, sigma: float) -> FloatArray:
    smooth = scipy.ndimage.gaussian_filter(image.astype(np.float64), sigma)
    g_v = scipy.ndimage.sobel(smooth, axis=0, mode="constant", cval=0.0)
    g_u = scipy.ndimage.sobel(smooth, axis=1, mode="constant", cval=0.0)
    return np.stack([g_v, g_u], axis=-1)


def _neighbour(mag: FloatArray, dv: int, du: int) -> FloatArray:
    """``mag[v + dv, u + du]`` with ``-inf`` outside the image."""
    h, w = mag.shape
    padded = np.full((h + 2, w + 2), -np.inf)
    padded[1:-1, 1:-1] = mag
    return padded[1 + dv : 1 + dv + h, 1 + du : 1 + du + w]


def thinned_edges(g_v: FloatArray, g_u: FloatArray, mag: FloatArray, threshold: float
                  ) -> np.ndarray:
    """The edge pixels: non-maximum suppression of ``mag`` along the quantised
    gradient direction, then ``mag > threshold`` (:ref:`contract-image`)."""
    av = np.abs(g_v)
    au = np.abs(g_u)
    horizontal = au >= av * _SECTOR_K
    vertical = ~horizontal & (av >= au * _SECTOR_K)
    diagonal = ~horizontal & ~vertical
    main_diag = diagonal & (g_v * g_u >= 0.0)
    anti_diag = diagonal & ~main_diag
    keep = np.zeros(mag.shape, dtype=bool)
    for sector, (dv, du) in (
        (horizontal, (0, 1)),
        (vertical, (1, 0)),
        (main_diag, (1, 1)),
        (anti_diag, (1, -1)),
    ):
        a = _neighbour(mag, dv, du)
        b = _neighbour(mag, -dv, -du)
        keep |= sector & (mag >= a) & (mag >= b)
    return keep & (mag > threshold)


def clipped_edge_dt(edges: np.ndarray, half_width: float) -> FloatArray:
    """The Euclidean distance to the nearest of ``edges``, clipped at ``half_width``
    (all ``half_width`` without edges)."""
    if not edges.any():
        return np.full(edges.shape, half_width)
    dist = scipy.ndimage.distance_transform_edt(~edges)
    return np.minimum(dist, half_width)


def build_image_edge_dt(
    image_ext: Any, image_noise_sigma: float, *, config: Any = None
) -> tuple[FloatArray, FloatArray]:
    """Gradient magnitude and the truncated DT of the thinned edge mask."""
    magnitude, edge_dt, _ = compute_all_image_derivatives(
        image_ext, image_noise_sigma, config=config
    )
    return magnitude, edge_dt


def compute_all_image_derivatives(
    image_ext: Any, image_noise_sigma: float, *, config: Any = None
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Gradient magnitude, truncated edge DT and gradient vectors."""
    image = check_image(image_ext)
    noise = check_noise_sigma(image_noise_sigma)
    cfg = resolve_config(config)
    smoothing_sigma(cfg.image_gradient_sigma_px, image.shape, "config.image_gradient_sigma_px")
    grad = _gradient(image, cfg.image_gradient_sigma_px)
    g_v = grad[..., 0]
    g_u = grad[..., 1]
    magnitude = np.hypot(g_v, g_u)
    threshold = cfg.edge_threshold_k_sigma * max(noise, NOISE_SIGMA_FLOOR)
    edges = thinned_edges(g_v, g_u, magnitude, threshold)
    return magnitude, clipped_edge_dt(edges, cfg.dt_half_width_px), grad
