"""Pose transforms and bilinear sampling of the distance transform."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .._kernels import sampling as _k
from . import checks as check
from .checks import FloatArray

__all__ = ["apply_translation", "sample_dt_bilinear"]


def sample_dt_bilinear(dt: ArrayLike, vertices_vu: ArrayLike) -> FloatArray:
    """Sample an image bilinearly at sub-pixel positions.

    Parameters
    ----------
    dt : array_like, shape (H, W)
        The image to sample (typically the edge distance transform).
    vertices_vu : array_like, shape (N, 2)
        Pixel-centric ``(v, u)`` positions; positions outside the image are
        clamped to its border.

    Returns
    -------
    ndarray, shape (N,)
        ``a (1-fv)(1-fu) + b (1-fv) fu + c fv (1-fu) + d fv fu`` with the
        four neighbouring pixels ``a, b, c, d`` (:ref:`contract-numerics`).

    Raises
    ------
    ValueError
        ``dt must be 2-D``; ``vertices_vu must have shape (N, 2)``; NaN or
        inf in either argument.
    """
    field = check.image2d(dt, "dt")
    pts = check.vertices(vertices_vu, "vertices_vu")
    out = _k.sample_many(field, pts)
    if not np.isfinite(out).all():
        raise check.nonfinite_read("dt")
    return out  # type: ignore[no-any-return]


def apply_translation(vertices_vu: ArrayLike, dv: float, du: float) -> FloatArray:
    """Return a copy of the vertices shifted by ``(dv, du)`` pixels.

    Parameters
    ----------
    vertices_vu : array_like, shape (N, 2)
        Vertices to shift.
    dv, du : float
        Row and column shift.

    Returns
    -------
    ndarray, shape (N, 2)
        A new float64 array; the input is not modified.
    """
    pts = check.vertices(vertices_vu, "vertices_vu")
    dv = check.finite_real(dv, "dv")
    du = check.finite_real(du, "du")
    out = np.array(pts, dtype=np.float64, copy=True)
    out[:, 0] += dv
    out[:, 1] += du
    return out


def _rotate_vertices(vertices_vu: Any, pivot_vu: Any, theta: float) -> Any:
    """Rotate vertices by ``theta`` about ``pivot_vu`` (the pose rotation of :ref:`contract-numerics`).

    ``v' = pv + cos(theta) (v - pv) - sin(theta) (u - pu)``,
    ``u' = pu + sin(theta) (v - pv) + cos(theta) (u - pu)``. At exactly
    ``theta == 0.0`` the input object itself is returned (no arithmetic),
    as today's techniques rely on. Private, but imported by those techniques
    (:ref:`contract-private`).
    """
    if theta == 0.0:
        return vertices_vu
    pts = np.asarray(vertices_vu, dtype=np.float64)
    pv, pu = (float(x) for x in pivot_vu)
    c = np.cos(theta)
    s = np.sin(theta)
    dv = pts[:, 0] - pv
    du = pts[:, 1] - pu
    return np.stack([pv + c * dv - s * du, pu + s * dv + c * du], axis=1)


def _rotate_directions(directions_vu: Any, theta: float) -> Any:
    """Rotate direction vectors (normals) by ``theta`` about the origin.

    The input object itself at exactly ``theta == 0.0``; private, imported
    by today's techniques (:ref:`contract-private`).
    """
    if theta == 0.0:
        return directions_vu
    d = np.asarray(directions_vu, dtype=np.float64)
    c = np.cos(theta)
    s = np.sin(theta)
    return np.stack([c * d[:, 0] - s * d[:, 1], s * d[:, 0] + c * d[:, 1]], axis=1)


#: The two rotations under public names for the package's own layers (the
#: pipeline's hypotheses); the underscored names are the :ref:`contract-private`
#: ones today's techniques import from ``dtalign``, and stay the definitions.
rotate_vertices = _rotate_vertices
rotate_directions = _rotate_directions
