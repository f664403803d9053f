"""The layer above the drop-in stages: one-call fits, image products and batches.

* :class:`FitOptions` (from :mod:`dtalign.api.options`): every fit option
  with its default, in one record;
* :mod:`dtalign.pipeline.fit`: :func:`fit_polyline`,
  :func:`fit_polyline_products` and their result, :class:`PolylineFit`;
* :mod:`dtalign.pipeline.products`: an image's products, computed once;
* :mod:`dtalign.pipeline.observability`: which pose directions a fit constrains;
* :mod:`dtalign.pipeline.status`: a fit's status, reasons and log lines;
* :mod:`dtalign.pipeline.seeds` and :mod:`dtalign.pipeline.hypotheses`:
  multi-start seeds and the ambiguity verdict;
* :mod:`dtalign.pipeline.batch`: many polylines or images on several cores;
* :mod:`dtalign.pipeline.jobs`: the checks and compiled-loop inputs those share.

The one-call names are re-exported here (``dtalign.pipeline.fit_polyline``).
Importing this package imports the compiled layer (Numba); ``import
dtalign`` alone does not (its names load on first use).
"""

from ..api.options import DEFAULT_SEARCH_WINDOW_VU, FitOptions
from .fit import FitUncertainty, PolylineFit, fit_polyline, fit_polyline_products
from .observability import (
    covariance_with_unobservable_inf,
    normal_information_covariance,
    null_directions,
    observable_rank,
)
from .products import ImageProducts, estimate_noise_sigma, prepare_image

__all__ = [
    "DEFAULT_SEARCH_WINDOW_VU",
    "FitOptions",
    "FitUncertainty",
    "ImageProducts",
    "PolylineFit",
    "covariance_with_unobservable_inf",
    "estimate_noise_sigma",
    "fit_polyline",
    "fit_polyline_products",
    "normal_information_covariance",
    "null_directions",
    "observable_rank",
    "prepare_image",
]
