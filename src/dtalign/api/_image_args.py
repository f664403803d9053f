"""Argument checks and configuration of the image side (SPEC sections 1 and 5)."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from . import checks as check
from .checks import FloatArray
from .constants import (
    DEFAULT_DT_HALF_WIDTH_PX,
    DEFAULT_EDGE_THRESHOLD_K_SIGMA,
    DEFAULT_IMAGE_GRADIENT_SIGMA_PX,
)


@dataclass(frozen=True)
class ImageDerivativesConfig:
    """Tunables of the image-side products.

    Parameters
    ----------
    image_gradient_sigma_px : float
        Gaussian pre-smoothing sigma of the Sobel gradient, pixels.
    edge_threshold_k_sigma : float
        Edge threshold on the gradient magnitude, in noise sigmas.
    dt_half_width_px : float
        Truncation of the edge distance transform, pixels.

    Every field must be a finite positive number (ValueError otherwise).
    """

    image_gradient_sigma_px: float = DEFAULT_IMAGE_GRADIENT_SIGMA_PX
    edge_threshold_k_sigma: float = DEFAULT_EDGE_THRESHOLD_K_SIGMA
    dt_half_width_px: float = DEFAULT_DT_HALF_WIDTH_PX

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            ok = (
                not isinstance(value, (bool, np.bool_))
                and isinstance(value, (int, float, np.integer, np.floating))
                and math.isfinite(float(value))
                and float(value) > 0.0
            )
            if not ok:
                raise ValueError(f"{f.name} must be a finite positive number; got {value!r}")
            object.__setattr__(self, f.name, float(value))


def resolve_config(config: Any) -> ImageDerivativesConfig:
    """``None`` means the defaults; anything else must be the config type."""
    if config is None:
        return ImageDerivativesConfig()
    if not isinstance(config, ImageDerivativesConfig):
        raise TypeError(
            f"config must be an ImageDerivativesConfig or None, got {type(config).__name__}"
        )
    return config


def check_image(image_ext: Any) -> FloatArray:
    """A non-empty, finite 2-D image as C-contiguous float64."""
    arr = np.asarray(image_ext)
    if arr.ndim != 2:
        raise TypeError(f"image_ext must be 2-D; got ndim={arr.ndim}")
    if arr.dtype.kind not in "biuf":
        raise TypeError(f"image_ext must be a real numeric array, got dtype {arr.dtype}")
    if arr.size == 0:
        raise ValueError(f"image_ext must not be empty, got shape {arr.shape}")
    out = np.ascontiguousarray(arr, dtype=np.float64)
    if not np.isfinite(out).all():
        raise ValueError(
            "image_ext must contain only finite values; NaN or +/-inf would propagate "
            "through gaussian_filter / sobel and poison every derivative downstream"
        )
    return check.readonly(out)


def check_sigma_px(sigma_px: Any) -> float:
    """The Gaussian sigma: finite and > 0."""
    try:
        value = check.real(sigma_px, "sigma_px")
    except TypeError as exc:
        raise ValueError(f"sigma_px must be a finite positive number; got {sigma_px!r}") from exc
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"sigma_px must be a finite positive number; got {sigma_px!r}")
    return value


def check_noise_sigma(image_noise_sigma: Any) -> float:
    """The image noise sigma: finite and >= 0."""
    try:
        value = check.real(image_noise_sigma, "image_noise_sigma")
    except TypeError as exc:
        raise ValueError(
            f"image_noise_sigma must be finite and >= 0; got {image_noise_sigma!r}"
        ) from exc
    if not (math.isfinite(value) and value >= 0.0):
        raise ValueError(f"image_noise_sigma must be finite and >= 0; got {value!r}")
    return value
