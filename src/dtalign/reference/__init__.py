"""The NumPy specification of dtalign: same names, same contract, no Numba.

``dtalign.reference`` implements the contract (:ref:`contract`) in plain NumPy/SciPy, one readable
function per rule. It is the oracle the compiled path is tested against and
the baseline every benchmark ratio is measured against. It shares the
package's argument checks, constants and result types, so it refuses the
same inputs with the same messages and returns the same dataclasses.
"""

from __future__ import annotations

from .fitting import (
    apply_translation,
    build_polyline_mask,
    coarse_ncc_search,
    coarse_ncc_search_scored,
    coarse_polarity_search_scored,
    find_secondary_dt_minimum,
    gradient_ridge_refine,
    information_matrix_to_covariance,
    lm_subpixel_refine,
    polarity_filter,
    sample_dt_bilinear,
    tukey_biweight_weights,
)
from .image import (
    build_image_edge_dt,
    compute_all_image_derivatives,
    compute_image_gradient_vu,
)
from .noise import estimate_noise_sigma

__all__ = [
    "apply_translation",
    "build_image_edge_dt",
    "build_polyline_mask",
    "coarse_ncc_search",
    "coarse_ncc_search_scored",
    "coarse_polarity_search_scored",
    "compute_all_image_derivatives",
    "find_secondary_dt_minimum",
    "compute_image_gradient_vu",
    "estimate_noise_sigma",
    "gradient_ridge_refine",
    "information_matrix_to_covariance",
    "lm_subpixel_refine",
    "polarity_filter",
    "sample_dt_bilinear",
    "tukey_biweight_weights",
]
