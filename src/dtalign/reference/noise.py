"""Plain NumPy/SciPy noise estimate: the specification of :func:`dtalign.estimate_noise_sigma`.

Beyond the drop-in surface (:ref:`contract-surface`; the one-call pipeline's noise estimate), kept here
as the oracle the compiled estimate is tested and benchmarked against.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import scipy.ndimage

from ..api.checks import check_image

#: 1.4826 * MAD is the standard deviation of a Gaussian.
MAD_TO_SIGMA = 1.4826

#: Immerkaer's noise-estimation kernel: the product of two second
#: differences. It is zero on any locally planar (or bilinear) patch, so a
#: smooth bright body does not raise the estimate; its L2 norm is 6.
NOISE_KERNEL = np.array([[1.0, -2.0, 1.0], [-2.0, 4.0, -2.0], [1.0, -2.0, 1.0]])
NOISE_KERNEL_NORM = 6.0


def immerkaer_interior(image: Any) -> np.ndarray:
    """Immerkaer's response at the interior pixels, flattened row by row."""
    arr = check_image(image)
    return scipy.ndimage.convolve(arr, NOISE_KERNEL, mode="reflect")[1:-1, 1:-1].ravel()


def estimate_noise_sigma(image: Any) -> float:
    """Robust Gaussian noise sigma: ``1.4826 * MAD / 6`` of Immerkaer's response.

    See :func:`dtalign.pipeline.products.estimate_noise_sigma` for the contract;
    this is its definition: SciPy's convolution, then NumPy medians.
    """
    arr = check_image(image)
    if arr.shape[0] < 3 or arr.shape[1] < 3:
        return 0.0
    filtered = immerkaer_interior(arr)
    centre = float(np.median(filtered))
    mad = float(np.median(np.abs(filtered - centre)))
    if mad > 0.0:
        return MAD_TO_SIGMA * mad / NOISE_KERNEL_NORM
    return math.sqrt(math.pi / 2.0) * float(np.mean(np.abs(filtered))) / NOISE_KERNEL_NORM
