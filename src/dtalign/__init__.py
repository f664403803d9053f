"""dtalign: align a model polyline against an image's edge distance transform.

A drop-in, Numba-compiled replacement for the NumPy DT-fitting module used
by spacecraft navigation techniques: coarse integer search, robust
sub-pixel Levenberg-Marquardt with Tukey IRLS, gradient-ridge polish and a
pseudoinverse covariance, plus the image-side gradient / edge / distance
transform products. What each function computes, exactly, is the
documentation's contract page (:ref:`contract`); the plain NumPy
implementation of it lives in :mod:`dtalign.reference`.

Public names are loaded on first use, so ``import dtalign`` does not import
Numba or SciPy; kernels compile lazily on their first call (and are cached
on disk).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from ._constants import (
    _INFINITY_DT_PENALTY_PX,
    DEFAULT_COARSE_MIN_SUPPORT_FRACTION,
    DEFAULT_DT_HALF_WIDTH_PX,
    DEFAULT_EDGE_THRESHOLD_K_SIGMA,
    DEFAULT_IMAGE_GRADIENT_SIGMA_PX,
    DEFAULT_LM_DAMPING,
    DEFAULT_LM_MAX_ITERATIONS,
    DEFAULT_LM_STEP_TOLERANCE,
    DEFAULT_PINVH_RCOND,
    DEFAULT_RIDGE_HALF_WIDTH_PX,
    DEFAULT_RIDGE_MAX_ITERATIONS,
    DEFAULT_RIDGE_MAX_TOTAL_DISPLACEMENT_PX,
    DEFAULT_RIDGE_SAMPLE_STEP_PX,
    DEFAULT_TUKEY_C,
)

__version__ = "0.1.0"

# public name -> submodule that defines it
_LAZY: dict[str, str] = {
    "CoarseSearchResult": "._results",
    "LMRefineResult": "._results",
    "RidgeRefineResult": "._results",
    "SecondaryBasin": "._results",
    "coarse_ncc_search": ".coarse",
    "coarse_ncc_search_scored": ".coarse",
    "coarse_polarity_search_scored": ".coarse",
    "find_secondary_dt_minimum": ".basin",
    "DTFitGateConfig": ".gates",
    "DTFitGateVerdict": ".gates",
    "evaluate_dt_fit_gates": ".gates",
    "build_polyline_mask": ".coarse",
    "polarity_filter": ".weights",
    "tukey_biweight_weights": ".weights",
    "information_matrix_to_covariance": ".weights",
    "lm_subpixel_refine": ".lm",
    "gradient_ridge_refine": ".ridge",
    "sample_dt_bilinear": ".sampling",
    "apply_translation": ".sampling",
    "ImageDerivativesConfig": "._image_args",
    "compute_image_gradient_vu": ".image",
    "build_image_edge_dt": ".image",
    "compute_all_image_derivatives": ".image",
    # beyond the drop-in surface: the one-call pipeline
    "ImageProducts": ".pipeline",
    "PolylineFit": ".pipeline",
    "covariance_with_unobservable_inf": ".observability",
    "normal_information_covariance": ".observability",
    "null_directions": ".observability",
    "observable_rank": ".observability",
    "estimate_noise_sigma": ".pipeline",
    "fit_polyline": ".pipeline",
    "fit_polyline_products": ".pipeline",
    "prepare_image": ".pipeline",
}

#: Private names today's techniques import (SPEC section 8.6): importable,
#: not in ``__all__``.
_PRIVATE_LAZY: dict[str, str] = {
    "_rotate_vertices": ".sampling",
    "_rotate_directions": ".sampling",
}

__all__ = [
    "DEFAULT_COARSE_MIN_SUPPORT_FRACTION",
    "DEFAULT_DT_HALF_WIDTH_PX",
    "DEFAULT_EDGE_THRESHOLD_K_SIGMA",
    "DEFAULT_IMAGE_GRADIENT_SIGMA_PX",
    "DEFAULT_LM_DAMPING",
    "DEFAULT_LM_MAX_ITERATIONS",
    "DEFAULT_LM_STEP_TOLERANCE",
    "DEFAULT_PINVH_RCOND",
    "DEFAULT_RIDGE_HALF_WIDTH_PX",
    "DEFAULT_RIDGE_MAX_ITERATIONS",
    "DEFAULT_RIDGE_MAX_TOTAL_DISPLACEMENT_PX",
    "DEFAULT_RIDGE_SAMPLE_STEP_PX",
    "DEFAULT_TUKEY_C",
    *sorted(_LAZY),
]


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name) or _PRIVATE_LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'dtalign' has no attribute {name!r}")
    value = getattr(importlib.import_module(module, __name__), name)
    globals()[name] = value  # later look-ups skip this hook
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


if TYPE_CHECKING:  # static analysers see ordinary imports
    from ._image_args import ImageDerivativesConfig
    from ._results import CoarseSearchResult, LMRefineResult, RidgeRefineResult, SecondaryBasin
    from .basin import find_secondary_dt_minimum
    from .coarse import (
        build_polyline_mask,
        coarse_ncc_search,
        coarse_ncc_search_scored,
        coarse_polarity_search_scored,
    )
    from .gates import DTFitGateConfig, DTFitGateVerdict, evaluate_dt_fit_gates
    from .image import (
        build_image_edge_dt,
        compute_all_image_derivatives,
        compute_image_gradient_vu,
    )
    from .lm import lm_subpixel_refine
    from .observability import (
        covariance_with_unobservable_inf,
        normal_information_covariance,
        null_directions,
        observable_rank,
    )
    from .pipeline import (
        ImageProducts,
        PolylineFit,
        estimate_noise_sigma,
        fit_polyline,
        fit_polyline_products,
        prepare_image,
    )
    from .ridge import gradient_ridge_refine
    from .sampling import (
        _rotate_directions,
        _rotate_vertices,
        apply_translation,
        sample_dt_bilinear,
    )
    from .weights import (
        information_matrix_to_covariance,
        polarity_filter,
        tukey_biweight_weights,
    )
