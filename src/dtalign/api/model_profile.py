"""An :class:`~dtalign.api.profiles.EdgeProfile` read from a technique's own render of the body.

A navigation technique that renders its body model (a shape model with
craters, an albedo map, its own reflectance law) knows what the image should
look like across each limb vertex better than any sphere formula.
:func:`model_image_edge_profile` samples that render along each vertex's
normal, on the profile's grid of offsets, so the photometric refinement
(:mod:`dtalign.pipeline.profile_fit`) fits the technique's own model to the
image's pixels. Conventions: :ref:`profiles-model-image`. Nothing here
imports Numba.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import checks as check
from .profiles import (
    EDGE_KINDS,
    SPHERE_PROFILE_HALF_RANGE_PX,
    SPHERE_PROFILE_STEP_PX,
    EdgeProfile,
)

__all__ = ["model_image_edge_profile", "polyline_curvature"]

FloatArray = NDArray[np.float64]

#: Least sub-samples per profile cell: each profile value is the mean of the
#: interpolated render over its cell, at least this many points, and at
#: least two per model pixel the cell spans.
MIN_SUBSAMPLES = 4

#: Tolerance on the normals' length (the one :class:`~dtalign.EdgeProfile` holds).
UNIT_TOLERANCE = 1e-6


def _oversample(value: Any) -> int:
    if not check._is_int(value):
        raise TypeError(f"oversample must be a positive int, got {type(value).__name__} "
                        f"{value!r}")
    if value < 1:
        raise ValueError(f"oversample must be a positive int, got {value!r}")
    return int(value)


def _model_image(value: Any) -> FloatArray:
    arr = check.as_float_array(value, "model_image")
    if arr.ndim != 2:
        raise ValueError(f"model_image must be 2-D; got shape {arr.shape}")
    if arr.shape[0] < 2 or arr.shape[1] < 2:
        raise ValueError(f"model_image must be at least 2 x 2 pixels; got shape {arr.shape}")
    check.require_finite(arr, "model_image")
    return arr


def polyline_curvature(vertices_vu: ArrayLike, normals_vu: ArrayLike) -> FloatArray:
    """Signed curvature of a polyline at each vertex, 1/pixels, from its neighbours.

    The turning of the unit tangent between a vertex's two edges over half
    their summed length (exact, ``1 / R``, for vertices on a circle of
    radius ``R``), positive when the polyline bends toward the normal's
    side (a limb with normals into the disc). An end vertex takes its
    neighbour's value; a polyline of one or two vertices is straight.

    Parameters
    ----------
    vertices_vu, normals_vu : array_like, shape (N, 2)
        The vertices in order along the edge, and their unit normals.

    Returns
    -------
    ndarray, shape (N,)

    Raises
    ------
    ValueError
        On a malformed argument (the message names it), or two consecutive
        vertices that coincide (the tangent between them is undefined).
    """
    verts = check.vertices(vertices_vu, "vertices_vu", allow_empty=False)
    normals = check.normals(normals_vu, verts.shape[0])
    n = verts.shape[0]
    if n < 3:
        return np.zeros(n)
    seg = np.diff(verts, axis=0)
    length = np.hypot(seg[:, 0], seg[:, 1])
    if not (length > 0.0).all():
        k = int(np.argmin(length))
        raise ValueError(f"vertices_vu {k} and {k + 1} coincide: the polyline has no tangent "
                         "there (give curvature_px)")
    tangent = seg / length[:, None]
    turn = (tangent[1:] - tangent[:-1]) / (0.5 * (length[1:] + length[:-1]))[:, None]
    inner = (turn * normals[1:-1]).sum(axis=1)
    return np.asarray(np.concatenate(([inner[0]], inner, [inner[-1]])), dtype=np.float64)


def model_image_edge_profile(
    model_image: ArrayLike,
    vertices_vu: ArrayLike,
    normals_vu: ArrayLike,
    *,
    oversample: int,
    origin_vu: Any = None,
    curvature_px: ArrayLike | None = None,
    edge: str = "limb",
    psf_sigma_px: float | None = None,
    step_px: float = SPHERE_PROFILE_STEP_PX,
    half_range_px: float = SPHERE_PROFILE_HALF_RANGE_PX,
) -> EdgeProfile:
    """The edge profile at each vertex, sampled from a render of the body model.

    The render is the technique's prediction of the image at the model's
    pose, ``oversample`` times finer than the image along each axis. Each
    profile value is the mean, over its cell of the offsets grid along the
    vertex's normal, of the render's bilinear interpolation: the sharp
    radiance across the edge as the model predicts it, in the render's
    units. The fit (:mod:`dtalign.pipeline.profile_fit`) then applies the
    image pixel's area average and the PSF, as for any profile; so the
    render must not be binned to the image's pixels, and should not
    include the PSF unless ``psf_sigma_px=0`` says so. Conventions and
    accuracy: :ref:`profiles-model-image`.

    Parameters
    ----------
    model_image : array_like, shape (H, W)
        The render: each pixel the mean radiance over its area (a box
        filter; a point sample at its centre does as well, to the blur
        the accuracy of :ref:`profiles-model-image` states), finite, at
        least 2 x 2. Sky is whatever the render
        gives it (the fit has a free background).
    vertices_vu : array_like, shape (N, 2)
        The model edge's vertices in **image** coordinates (pixel ``(i, j)``
        centred at ``(i, j)``), in order along the edge, each inside the
        render.
    normals_vu : array_like, shape (N, 2)
        Their unit normals, pointing to the edge's bright side (into the
        disc for a limb): the polyline's own normals.
    oversample : int
        Render pixels per image pixel along each axis, >= 1.
    origin_vu : tuple of float, optional
        The image point at the centre of render pixel ``(0, 0)``: render
        pixel ``(a, b)`` is centred at ``origin_vu + (a, b) / oversample``.
        None: the render tiles the image from its pixel ``(0, 0)``, each
        image pixel ``(i, j)`` covered by render pixels ``oversample * i``
        to ``oversample * i + oversample - 1`` (and likewise in ``j``), so
        ``origin_vu = (0.5 / oversample - 0.5,) * 2``. A render of a window
        around the body gives the window's origin.
    curvature_px : array_like, shape (N,), optional
        The edge's signed curvature at each vertex (see
        :attr:`EdgeProfile.curvature_px <dtalign.EdgeProfile>`); None:
        :func:`polyline_curvature` of the vertices.
    edge : str
        The kind of edge (:data:`~dtalign.api.profiles.EDGE_KINDS`).
    psf_sigma_px : float, optional
        The image's Gaussian PSF sigma still to apply to the render, >= 0:
        0 when the render already includes the PSF; None when unknown (the
        fit estimates it).
    step_px, half_range_px : float, optional
        The offsets grid, as :func:`~dtalign.sphere_edge_profile`'s:
        ``step_px`` apart, the vertex midway between two samples' cells,
        reaching ``half_range_px`` each way (the fit reads its table to
        6 px plus its blur; beyond, the profile is held flat). The render
        must cover it all.

    Returns
    -------
    EdgeProfile
        Without a shape basis: the render is fitted as given.

    Raises
    ------
    TypeError
        If ``oversample`` is not an int, or an array is not numeric.
    ValueError
        On a malformed argument (the message names it): shapes, a value
        that is not finite, normals that are not unit vectors, a vertex
        outside the render, or a profile that reaches outside it.
    """
    image = _model_image(model_image)
    verts = check.vertices(vertices_vu, "vertices_vu", allow_empty=False)
    normals = check.normals(normals_vu, verts.shape[0])
    length = np.hypot(normals[:, 0], normals[:, 1])
    if np.abs(length - 1.0).max() > UNIT_TOLERANCE:
        k = int(np.argmax(np.abs(length - 1.0)))
        raise ValueError(f"normals_vu must be unit vectors; normal {k} has length {length[k]!r}")
    k_os = _oversample(oversample)
    origin = ((0.5 / k_os - 0.5,) * 2 if origin_vu is None
              else check.pair(origin_vu, "origin_vu"))
    if curvature_px is None:
        curvature = polyline_curvature(verts, normals)
    else:
        curvature = check.as_float_array(curvature_px, "curvature_px")
        if curvature.shape != (verts.shape[0],):
            raise ValueError(f"curvature_px must have shape ({verts.shape[0]},), "
                             f"got {curvature.shape}")
        check.require_finite(curvature, "curvature_px")
    if not isinstance(edge, str) or edge not in EDGE_KINDS:
        raise ValueError(f"edge must be one of {EDGE_KINDS}, got {edge!r}")
    psf = None if psf_sigma_px is None else check.nonnegative_real(psf_sigma_px, "psf_sigma_px")
    h = check.positive_real(step_px, "step_px")
    half = check.positive_real(half_range_px, "half_range_px")
    if half < 4.0 * h:
        raise ValueError("half_range_px must be at least 4 * step_px")

    hm, wm = image.shape
    # image point -> render pixel coordinates (render pixel (a, b) centred at (a, b))
    mv = (verts[:, 0] - origin[0]) * k_os
    mu = (verts[:, 1] - origin[1]) * k_os
    outside = (mv < 0.0) | (mv > hm - 1) | (mu < 0.0) | (mu > wm - 1)
    if outside.any():
        k = int(np.argmax(outside))
        raise ValueError(f"vertices_vu {k} {_point(verts[k])} lies outside model_image (its "
                         f"render pixel ({mv[k]:.4g}, {mu[k]:.4g}) is not within the "
                         f"{hm} x {wm} render's pixel centres)")
    n_half = int(math.ceil(half / h))
    offsets = np.asarray((np.arange(-n_half, n_half) + 0.5) * h, dtype=np.float64)
    n_sub = max(MIN_SUBSAMPLES, int(math.ceil(2.0 * h * k_os)))
    sub = (np.arange(n_sub) + 0.5) / n_sub - 0.5
    along = (offsets[:, None] + h * sub[None, :]).ravel()
    pv = mv[:, None] + (k_os * along)[None, :] * normals[:, 0:1]
    pu = mu[:, None] + (k_os * along)[None, :] * normals[:, 1:2]
    reach = ((pv < 0.0) | (pv > hm - 1) | (pu < 0.0) | (pu > wm - 1)).any(axis=1)
    if reach.any():
        k = int(np.argmax(reach))
        raise ValueError(f"the profile of vertices_vu {k} {_point(verts[k])} reaches outside "
                         f"model_image ({half:g} px along its normal): render a larger "
                         "window or give a smaller half_range_px")
    values = _bilinear(image, pv, pu).reshape(verts.shape[0], offsets.shape[0], n_sub)
    return EdgeProfile(offsets_px=offsets, values=values.mean(axis=2), normals_vu=normals,
                       curvature_px=curvature, psf_sigma_px=psf, edge=edge)


def _point(p: FloatArray) -> str:
    return f"({float(p[0]):.6g}, {float(p[1]):.6g})"


def _bilinear(image: FloatArray, pv: FloatArray, pu: FloatArray) -> FloatArray:
    """``image`` bilinearly interpolated at render pixel coordinates inside it."""
    hm, wm = image.shape
    i = np.minimum(np.floor(pv).astype(np.int64), hm - 2)
    j = np.minimum(np.floor(pu).astype(np.int64), wm - 2)
    tv, tu = pv - i, pu - j
    top = image[i, j] * (1.0 - tu) + image[i, j + 1] * tu
    bottom = image[i + 1, j] * (1.0 - tu) + image[i + 1, j + 1] * tu
    return np.asarray(top * (1.0 - tv) + bottom * tv, dtype=np.float64)
