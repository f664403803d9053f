"""Observability of a fit: what its covariance does and does not constrain.

A rank-deficient fit (a straight edge: the along-edge shift is not
measured) reports *zero* variance along its null direction, because the
covariance is the pseudoinverse of the information matrix (:ref:`contract-decisions`).
The helpers here read such a covariance without changing that default:

* :func:`observable_rank` and :func:`null_directions`: how many, and which,
  parameter directions the covariance constrains;
* :func:`covariance_with_unobservable_inf`: the reading with ``+inf``
  variance along the null directions;
* :func:`normal_information_covariance`: the covariance when each vertex
  measures only its shift along its normal (the aperture problem), from
  which :class:`~dtalign.pipeline.PolylineFit` reads its observable rank.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..api import checks as check
from ..api.constants import DEFAULT_PINVH_RCOND
from ..api.options import n_params as _n_params

__all__ = [
    "covariance_with_unobservable_inf",
    "normal_information_covariance",
    "null_directions",
    "observable_rank",
]

FloatArray = NDArray[np.float64]


def _information_matrix_to_covariance(jac: FloatArray, w: FloatArray, rcond: float) -> FloatArray:
    """:func:`dtalign.information_matrix_to_covariance`, imported on first use,
    so importing this module does not import the compiled kernels."""
    from ..api.weights import information_matrix_to_covariance

    return information_matrix_to_covariance(jac, w, rcond=rcond)


def _null_space(cov: FloatArray, rcond: float) -> tuple[FloatArray, FloatArray, NDArray[np.bool_]]:
    """Eigen-decomposition of a covariance and which eigen-directions are null.

    ``pinvh`` keeps information eigenvalues down to ``rcond`` times the
    largest, so a kept covariance eigenvalue is at least ``rcond`` times the
    largest covariance eigenvalue; a discarded one is zero up to rounding.
    Half of ``rcond`` (but never less than a rounding margin) separates them.
    """
    values, vectors = np.linalg.eigh(0.5 * (cov + cov.T))
    top = float(values.max()) if values.size else 0.0
    if top <= 0.0:
        return values, vectors, np.ones(values.shape, dtype=bool)
    eps_margin = 16.0 * cov.shape[0] * np.finfo(np.float64).eps
    cut = top * max(0.5 * rcond, eps_margin)
    return values, vectors, values <= cut


def _check_covariance(cov: Any) -> FloatArray:
    arr = np.asarray(cov, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[0] != arr.shape[1] or arr.shape[0] == 0:
        raise ValueError(f"cov must be a square (P, P) matrix with P > 0, got shape {arr.shape}")
    if np.isnan(arr).any():
        raise ValueError("cov must not contain NaN")
    return arr


def observable_rank(cov: ArrayLike, rcond: float = DEFAULT_PINVH_RCOND) -> int:
    """Number of parameter directions a fit's covariance actually constrains.

    Parameters
    ----------
    cov : array_like, shape (P, P)
        A covariance as returned by :func:`dtalign.lm_subpixel_refine`
        (the pseudoinverse of the information matrix).
    rcond : float, optional
        The relative cutoff the covariance was computed with.

    Returns
    -------
    int
        ``P`` for a fully constrained fit, fewer for a rank-deficient one
        (1 for a straight edge fitted in translation), 0 for a degenerate
        fit (an all-``inf`` covariance).

    Raises
    ------
    ValueError
        If ``cov`` is not square or contains NaN, or ``rcond`` is negative
        or not finite.
    """
    arr = _check_covariance(cov)
    rcond = check.nonnegative_real(rcond, "rcond")
    if not np.isfinite(arr).all():
        return 0
    _, _, null = _null_space(arr, rcond)
    return int((~null).sum())


def covariance_with_unobservable_inf(
    cov: ArrayLike, rcond: float = DEFAULT_PINVH_RCOND, *, null_directions: ArrayLike | None = None
) -> FloatArray:
    """Map the null directions of a pseudoinverse covariance to ``+inf``.

    :func:`dtalign.lm_subpixel_refine` returns ``pinvh(J^T W J)``, whose
    variance along a direction the data does not constrain is zero,
    meaning "no information". This is the other reading: the limit of
    ``V diag(lambda) V^T`` as the null eigenvalues go to ``+inf``. An entry
    ``(i, j)`` touched by a null direction ``e`` (``e[i] * e[j]`` not
    negligible) becomes ``+inf`` or ``-inf`` by the sign of ``e[i] * e[j]``;
    every other entry keeps the finite value of the covariance restricted
    to the observable directions, so the diagonal is ``+inf`` for each
    parameter a null direction involves. A fit's own ``covariance`` is
    unchanged (:ref:`contract-decisions`).

    Parameters
    ----------
    cov : array_like, shape (P, P)
        A symmetric covariance (the pseudoinverse of an information matrix).
        An all-``inf`` (degenerate) covariance gives all ``+inf``.
    rcond : float, optional
        The relative cutoff the pseudoinverse used
        (default :data:`dtalign.DEFAULT_PINVH_RCOND`): eigen-directions of
        ``cov`` with a variance below ``rcond / 2`` times the largest are
        its null directions.
    null_directions : array_like, shape (K, P), optional
        Further directions to treat as unobservable (for example
        :attr:`~dtalign.pipeline.PolylineFit.unobservable_directions`); they
        need not be unit vectors. ``cov`` is first restricted to their orthogonal complement.

    Returns
    -------
    ndarray, shape (P, P)
        A new array; finite where the fit constrains the parameters.

    Raises
    ------
    ValueError
        If ``cov`` is not square or contains NaN, ``rcond`` is negative or
        not finite, or ``null_directions`` has the wrong shape or is not
        finite.

    Examples
    --------
    A straight vertical edge constrains ``u`` only:

    >>> import numpy as np
    >>> covariance_with_unobservable_inf(np.array([[0.0, 0.0], [0.0, 0.01]])).tolist()
    [[inf, 0.0], [0.0, 0.01]]
    """
    arr = _check_covariance(cov)
    rcond = check.nonnegative_real(rcond, "rcond")
    p = arr.shape[0]
    if not np.isfinite(arr).all():
        return np.full(arr.shape, np.inf)
    extra = np.zeros((0, p))
    if null_directions is not None:
        extra = np.asarray(null_directions, dtype=np.float64).reshape(-1, p) if np.size(
            null_directions
        ) else np.zeros((0, p))
        if extra.ndim != 2 or extra.shape[1] != p or not np.isfinite(extra).all():
            raise ValueError(f"null_directions must be finite with shape (K, {p})")
        norms = np.linalg.norm(extra, axis=1)
        extra = extra[norms > 0] / norms[norms > 0, None]
    if extra.shape[0]:
        # Orthonormal basis of the given directions, then project them out.
        basis = np.linalg.svd(extra, full_matrices=False)[2][: np.linalg.matrix_rank(extra)]
        proj = np.eye(p) - basis.T @ basis
        arr = proj @ arr @ proj
    values, vectors, null = _null_space(arr, rcond)
    if null.all():
        return np.full(arr.shape, np.inf)
    kept = vectors[:, ~null]
    out = (kept * values[~null]) @ kept.T
    out = 0.5 * (out + out.T)
    # Components of a null eigenvector below this are rounding, not geometry.
    tiny = 1e-6
    for e in vectors[:, null].T:
        outer = np.outer(e, e)
        touched = np.abs(outer) > tiny * tiny
        out[touched] = np.copysign(np.inf, outer[touched])
    return out


def null_directions(cov: ArrayLike, rcond: float = DEFAULT_PINVH_RCOND) -> FloatArray:
    """Unit vectors spanning the unobservable directions of a covariance.

    Parameters
    ----------
    cov : array_like, shape (P, P)
        A pseudoinverse covariance; all-``inf`` means nothing is observed.
    rcond : float, optional
        The pseudoinverse cutoff (see :func:`covariance_with_unobservable_inf`).

    Returns
    -------
    ndarray, shape (K, P)
        ``K = P - observable_rank(cov, rcond)`` orthonormal rows.

    Raises
    ------
    ValueError
        As :func:`observable_rank`.
    """
    arr = _check_covariance(cov)
    rcond = check.nonnegative_real(rcond, "rcond")
    if not np.isfinite(arr).all():
        return np.eye(arr.shape[0])
    _, vectors, null = _null_space(arr, rcond)
    return np.ascontiguousarray(vectors[:, null].T)


def normal_information_covariance(
    vertices_vu: ArrayLike,
    normals_vu: ArrayLike,
    weights: ArrayLike,
    *,
    offset_vu: tuple[float, float] = (0.0, 0.0),
    rotation_rad: float = 0.0,
    fit_rotation: bool = False,
    pivot_vu: tuple[float, float] | None = None,
    rcond: float = DEFAULT_PINVH_RCOND,
) -> FloatArray:
    """Covariance of the pose when each vertex measures only its normal shift.

    A vertex on an edge sees a displacement across the edge, never along it
    (the aperture problem). With the residual Jacobian rows ``-n_i`` (and,
    with rotation, ``-n_i . d(pos_i)/d(theta)``) the covariance is the
    pseudoinverse of ``A^T W A``, computed by
    :func:`dtalign.information_matrix_to_covariance`. This is the
    continuous-edge version of the DT-Jacobian covariance of
    :func:`dtalign.lm_subpixel_refine`. On real pixels the DT Jacobian also
    picks up along-edge information from the staircase of a digitised
    diagonal edge and from nearby clutter edges; this covariance does not,
    so parallel straight edges give exactly rank 1.

    Parameters
    ----------
    vertices_vu, normals_vu : array_like, shape (N, 2)
        The model polyline (before the pose).
    weights : array_like, shape (N,)
        Per-vertex weights (the LM's final IRLS weights).
    offset_vu, rotation_rad, fit_rotation, pivot_vu
        The pose; the normals are rotated by ``rotation_rad``. With
        ``fit_rotation`` the result is 3 x 3 (``dv, du, theta``).
    rcond : float, optional
        Pseudoinverse cutoff.

    Returns
    -------
    ndarray, shape (P, P)
        All ``+inf`` when no vertex has a positive weight.

    Raises
    ------
    TypeError
        If the vertices or normals are not numeric, or ``rotation_rad`` is
        not a real number.
    ValueError
        On malformed vertices, normals, weights, offset or pivot; the
        message names the argument.
    """
    verts = check.vertices(vertices_vu, "vertices_vu", allow_empty=False)
    norms = check.normals(normals_vu, verts.shape[0])
    w = np.asarray(weights, dtype=np.float64)
    if w.shape != (verts.shape[0],) or not np.isfinite(w).all() or (w < 0).any():
        raise ValueError(
            f"weights must be a finite, non-negative 1-D vector of length {verts.shape[0]}"
        )
    check.pair(offset_vu, "offset_vu")
    theta = check.finite_real(rotation_rad, "rotation_rad")
    pivot = check.resolve_pivot(verts, pivot_vu)
    n_params = int(_n_params(fit_rotation))
    if not (w > 0).any():
        return np.full((n_params, n_params), np.inf)
    c, s_ = math.cos(theta), math.sin(theta)
    rel = verts - pivot
    rot_rel = np.column_stack([c * rel[:, 0] - s_ * rel[:, 1], s_ * rel[:, 0] + c * rel[:, 1]])
    rot_n = np.column_stack(
        [c * norms[:, 0] - s_ * norms[:, 1], s_ * norms[:, 0] + c * norms[:, 1]]
    )
    cols = [-rot_n[:, 0], -rot_n[:, 1]]
    if fit_rotation:
        # d(pos)/d(theta) = (-(u - pu), v - pv) of the rotated vertex.
        cols.append(-(rot_n[:, 0] * -rot_rel[:, 1] + rot_n[:, 1] * rot_rel[:, 0]))
    jac = np.column_stack(cols)
    return _information_matrix_to_covariance(jac, w, rcond)


def _sigma_list(cov: FloatArray) -> list[float]:
    """:func:`_sigmas_from_cov` of one ``(P, P)`` covariance, as Python floats.

    A positive diagonal (the usual case) takes ``math.sqrt``: the same
    correctly rounded IEEE square root as ``np.sqrt``, without the six
    ufunc calls and ``np.errstate`` that every fit's result would otherwise
    pay. Anything else (zero of either sign, negative, NaN) goes
    through :func:`_sigmas_from_cov` itself.
    """
    diag = np.diagonal(cov).tolist()
    if all(x > 0.0 for x in diag):
        return [math.sqrt(x) for x in diag]
    return _sigmas_from_cov(cov).tolist()  # type: ignore[no-any-return]


def _sigmas_from_cov(cov: FloatArray) -> FloatArray:
    """Square roots of the diagonal: negatives give 0, NaN gives ``inf``.

    For a stack of covariances ``(..., P, P)``, of each one's diagonal.
    """
    diag = np.diagonal(cov, axis1=-2, axis2=-1).astype(np.float64, copy=True)
    with np.errstate(invalid="ignore"):
        return np.where(np.isnan(diag), np.inf, np.sqrt(np.maximum(diag, 0.0)))
