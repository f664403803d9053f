"""Polarity test, Tukey biweight and the information-matrix covariance."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .._kernels import lanes as _lanes
from .._kernels import robust as _k
from . import checks as check
from .checks import FloatArray, check_covariance_inputs, tukey_c_value
from .constants import DEFAULT_PINVH_RCOND, DEFAULT_TUKEY_C

__all__ = [
    "information_matrix_to_covariance",
    "polarity_filter",
    "tukey_biweight_weights",
]


def polarity_filter(
    vertices_vu: ArrayLike, normals_vu: ArrayLike, image_gradient_vu: ArrayLike, *, offset_vu: Any = (0.0, 0.0)
) -> np.ndarray:
    """Accept the vertices whose normal points up the image gradient.

    Parameters
    ----------
    vertices_vu, normals_vu : array_like, shape (N, 2)
        Model vertices and their normals, which should point to the bright
        side of each edge (into the disc for a limb): up the gradient.
    image_gradient_vu : array_like, shape (H, W, 2)
        Signed gradient ``(g_v, g_u)`` from :func:`compute_image_gradient_vu`.
    offset_vu : tuple of float, optional
        Shift applied to the vertices before the test.

    Returns
    -------
    ndarray of bool, shape (N,)
        True iff the vertex, shifted and rounded half-to-even, is inside the
        image and ``n_v g_v + n_u g_u > 0`` at that pixel.
    """
    pts = check.vertices(vertices_vu, "vertices_vu")
    nrm = check.normals(normals_vu, pts.shape[0])
    grad = check.gradient(image_gradient_vu)
    dv, du = check.pair(offset_vu, "offset_vu")
    accepted, bad = _lanes.polarity(pts, nrm, grad, dv, du)
    if bad:
        raise check.nonfinite_read("image_gradient_vu")
    return accepted != 0.0  # type: ignore[no-any-return]


def tukey_biweight_weights(residuals: ArrayLike, *, c: float = DEFAULT_TUKEY_C) -> FloatArray:
    """Holland-Welsch biweight of scaled residuals.

    Parameters
    ----------
    residuals : array_like, shape (N,)
        Residuals already divided by their sigma.
    c : float, optional
        Cutoff; residuals with ``|r / c| > 1`` get weight 0.

    Returns
    -------
    ndarray, shape (N,)
        ``(1 - (r/c)^2)^2`` inside the cutoff, 0 outside (and for NaN).
    """
    c = tukey_c_value(c)
    r = check.as_float_array(residuals, "residuals")
    if r.ndim != 1:
        raise ValueError(f"residuals must be 1-D; got ndim={r.ndim}")
    return _k.tukey_many(r, c)  # type: ignore[no-any-return]


def information_matrix_to_covariance(
    jacobian: ArrayLike, weights: ArrayLike, *, rcond: float = DEFAULT_PINVH_RCOND
) -> FloatArray:
    """Covariance as the pseudoinverse of the information matrix ``J^T W J``.

    Parameters
    ----------
    jacobian : array_like, shape (N, P)
        Residual Jacobian.
    weights : array_like, shape (N,)
        Non-negative IRLS weights.
    rcond : float, optional
        Relative eigenvalue cutoff of :func:`scipy.linalg.pinvh`.

    Returns
    -------
    ndarray, shape (P, P)
        The symmetrised pseudoinverse. Along an unobservable direction (a
        straight edge's along-edge axis) the variance is 0, not inf
        (:ref:`contract-decisions`). With no rows or no positive weight it is the
        ``(P, P)`` zero matrix (:ref:`contract-numerics`); ``lm_subpixel_refine``
        marks its degenerate fits with an all-``+inf`` covariance instead.
    """
    jac, w, rcond = check_covariance_inputs(jacobian, weights, rcond)
    if jac.shape[0] == 0 or not (w > 0).any():
        # :ref:`contract-numerics`: no information is the zero matrix here (a caller's s2 * cov
        # with s2 == 0 must stay 0); the +inf sentinel is the LM's (:ref:`contract-lm`)
        return np.zeros((jac.shape[1], jac.shape[1]))
    info, _ = _k.normal_equations(jac, w, np.zeros(jac.shape[0]), jac.shape[1])
    cov, ok = _k.symmetric_pinvh(info, rcond)
    if not ok:
        raise ValueError(
            "jacobian and weights are too large: the information matrix J^T W J overflows"
        )
    return cov  # type: ignore[no-any-return]
