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

from ._version import __version__
from .api.constants import (
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

# public name -> submodule that defines it
_LAZY: dict[str, str] = {
    "CoarseSearchResult": ".api.results",
    "LMRefineResult": ".api.results",
    "RidgeRefineResult": ".api.results",
    "SecondaryBasin": ".api.results",
    "coarse_ncc_search": ".api.coarse",
    "coarse_ncc_search_scored": ".api.coarse",
    "coarse_polarity_search_scored": ".api.coarse",
    "find_secondary_dt_minimum": ".api.basin",
    "DTFitGateConfig": ".api.gates",
    "DTFitGateVerdict": ".api.gates",
    "evaluate_dt_fit_gates": ".api.gates",
    "build_polyline_mask": ".api.coarse",
    "polarity_filter": ".api.weights",
    "tukey_biweight_weights": ".api.weights",
    "information_matrix_to_covariance": ".api.weights",
    "lm_subpixel_refine": ".api.lm",
    "gradient_ridge_refine": ".api.ridge",
    "sample_dt_bilinear": ".api.sampling",
    "apply_translation": ".api.sampling",
    "ImageDerivativesConfig": ".api.results",
    "compute_image_gradient_vu": ".api.image",
    "build_image_edge_dt": ".api.image",
    "compute_all_image_derivatives": ".api.image",
    # beyond the drop-in surface: the one-call pipeline
    "ImageProducts": ".pipeline.products",
    "PolylineFit": ".pipeline.fit",
    "FitOptions": ".api.options",
    "covariance_with_unobservable_inf": ".pipeline.observability",
    "normal_information_covariance": ".pipeline.observability",
    "null_directions": ".pipeline.observability",
    "observable_rank": ".pipeline.observability",
    "estimate_noise_sigma": ".pipeline.products",
    "fit_polyline": ".pipeline.fit",
    "fit_polyline_products": ".pipeline.fit",
    "prepare_image": ".pipeline.products",
    "warm_up": ".warmup",
    # photometric edge profiles
    "EdgeProfile": ".api.profiles",
    "sphere_edge_profile": ".api.profiles",
    "model_image_edge_profile": ".api.model_profile",
    "ProfileRefinement": ".pipeline.profile_fit",
    # model polylines: the record and a sphere's limb and terminator
    "Polyline": ".api.polylines",
    "sphere_limb_polyline": ".api.polylines",
    "sphere_terminator_polyline": ".api.polylines",
    # a triaxial ellipsoid's limb, terminator and edge profile
    "ellipsoid_limb_polyline": ".api.ellipsoid",
    "ellipsoid_terminator_polyline": ".api.ellipsoid",
    "ellipsoid_edge_profile": ".api.ellipsoid",
}

#: Private names today's techniques import (:ref:`contract-private`): importable,
#: not in ``__all__``.
_PRIVATE_LAZY: dict[str, str] = {
    "_rotate_vertices": ".api.sampling",
    "_rotate_directions": ".api.sampling",
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
    """The public names, for ``dir(dtalign)`` and tab completion.

    Not ``globals()``: that also holds this module's helpers (``importlib``,
    ``Any``, ``TYPE_CHECKING``, ``_LAZY``) and the subpackage ``api`` that the
    constants' import binds; a name loaded lazily is listed before its first
    use as after it.
    """
    return sorted({*__all__, "__version__"})


if TYPE_CHECKING:  # static analysers see ordinary imports
    from .api.basin import find_secondary_dt_minimum
    from .api.coarse import (
        build_polyline_mask,
        coarse_ncc_search,
        coarse_ncc_search_scored,
        coarse_polarity_search_scored,
    )
    from .api.ellipsoid import (
        ellipsoid_edge_profile,
        ellipsoid_limb_polyline,
        ellipsoid_terminator_polyline,
    )
    from .api.gates import DTFitGateConfig, DTFitGateVerdict, evaluate_dt_fit_gates
    from .api.image import (
        build_image_edge_dt,
        compute_all_image_derivatives,
        compute_image_gradient_vu,
    )
    from .api.lm import lm_subpixel_refine
    from .api.model_profile import model_image_edge_profile
    from .api.options import FitOptions
    from .api.polylines import Polyline, sphere_limb_polyline, sphere_terminator_polyline
    from .api.profiles import EdgeProfile, sphere_edge_profile
    from .api.results import (
        CoarseSearchResult,
        ImageDerivativesConfig,
        LMRefineResult,
        RidgeRefineResult,
        SecondaryBasin,
    )
    from .api.ridge import gradient_ridge_refine
    from .api.sampling import (
        _rotate_directions,
        _rotate_vertices,
        apply_translation,
        sample_dt_bilinear,
    )
    from .api.weights import (
        information_matrix_to_covariance,
        polarity_filter,
        tukey_biweight_weights,
    )
    from .pipeline.fit import PolylineFit, fit_polyline, fit_polyline_products
    from .pipeline.observability import (
        covariance_with_unobservable_inf,
        normal_information_covariance,
        null_directions,
        observable_rank,
    )
    from .pipeline.products import ImageProducts, estimate_noise_sigma, prepare_image
    from .pipeline.profile_fit import ProfileRefinement
    from .warmup import warm_up
