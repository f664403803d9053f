"""A triaxial ellipsoid's limb, terminator and edge profiles, seen along the camera axis.

The ellipsoid counterparts of :func:`~dtalign.sphere_limb_polyline`,
:func:`~dtalign.sphere_terminator_polyline` and
:func:`~dtalign.sphere_edge_profile`, with their conventions (:ref:`profiles`):
an orthographic view, image coordinates ``(v, u)`` in pixels,
``illumination_deg`` the in-image direction toward the Sun (0 toward -v, 90
toward +u), ``phase_deg`` the phase angle in [0, 180).

**The attitude.** The camera frame is ``(v, u, w)``: ``v`` down the image,
``u`` to the right, ``w`` toward the viewer (a right-handed frame; the Sun
is ``L = (sin(phase) s, cos(phase))`` in it, ``s`` the in-image direction
toward the Sun). ``axes_px = (a, b, c)`` are the semi-axes in pixels and
``rotation`` is the 3 x 3 orthonormal matrix whose **columns** are the unit
directions of those three axes in the camera frame (the body-to-camera
rotation); None is the identity, ``a`` along ``v``, ``b`` along ``u``, ``c``
toward the viewer. The surface is ``x^T M x = 1`` about the centre with ``M
= R diag(a, b, c)^-2 R^T``. With equal axes every function here returns the
sphere's result (to rounding).

**The geometry.** The limb is the outline of the ellipsoid, the ellipse
``p^T S2^-1 p = 1`` with ``S2`` the image block of ``S = M^-1``; its point
where the unit vector ``n`` off the disc is perpendicular to it is ``S2 n /
sqrt(n^T S2 n)``, which is how the vertices are placed (at the sphere's
angles of ``n``). The terminator
is the plane section ``x . (M L) = 0``, the points whose surface normal is
perpendicular to the Sun; written ``x = S^(1/2) y`` it is a great circle of
the unit vectors ``y``, walked at the sphere terminator's angles over its
visible half (surface normals toward the viewer). Its normals point up the
image gradient of ``cos i``, toward the day side.

**The profile.** Each profile value is the cell mean, along the vertex's
normal, of the ellipsoid's radiance at image points: the front surface
point of the ray through each point (exact ray-ellipsoid intersection), its
unit normal ``N``, ``cos e = N_w``, ``cos i = N . L``, and the law of
:func:`~dtalign.sphere_edge_profile`. The curvature is the outline's (a
limb) or the projected terminator ellipse's (a terminator) at the vertex.
Nothing here imports Numba.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import checks as check
from .polylines import (
    DEFAULT_POLYLINE_SIGMA_PX,
    DEFAULT_POLYLINE_VERTICES,
    Polyline,
    _limb_directions,
    _phase,
    _terminator_angles,
    _terminator_args,
    sun_direction_vu,
)
from .profiles import (
    SPHERE_PROFILE_HALF_RANGE_PX,
    SPHERE_PROFILE_STEP_PX,
    EdgeProfile,
    _cell_means,
    _law_args,
    _law_radiance,
)

__all__ = ["ellipsoid_edge_profile", "ellipsoid_limb_polyline", "ellipsoid_terminator_polyline"]

FloatArray = NDArray[np.float64]

#: Largest ``|R^T R - I|`` entry a ``rotation`` may have.
ROTATION_TOLERANCE = 1e-9


class _Body:
    """The checked ellipsoid: its centre and the matrices of its surface in the camera frame."""

    def __init__(self, center_vu: Any, axes_px: Any, rotation: Any) -> None:
        self.center = np.asarray(check.pair(center_vu, "center_vu"))
        axes = _axes(axes_px)
        rot = _rotation(rotation)
        self.s_half = (rot * axes) @ rot.T          # S^(1/2) = R diag(a) R^T
        self.m_half = (rot / axes) @ rot.T          # M^(1/2)
        self.s = (rot * axes**2) @ rot.T            # S = M^-1
        self.m = (rot / axes**2) @ rot.T            # x^T M x = 1 on the surface

    def outline_point(self, outward: FloatArray) -> FloatArray:
        """The outline's points (from the centre) where it is perpendicular to the unit
        vectors ``outward``, which point off the disc."""
        sp = outward @ self.s[:2, :2]
        return np.asarray(sp / np.sqrt((outward * sp).sum(axis=1))[:, None], dtype=np.float64)

    def terminator_basis(self, light: FloatArray) -> tuple[FloatArray, FloatArray]:
        """The great circle ``y = cos t e_a + sin t e_b`` of the terminator, its visible half
        at ``t`` in ``(-pi, 0)`` (for a sphere the sphere terminator's)."""
        ell = self.m_half @ light
        ell /= np.linalg.norm(ell)
        k = self.m_half[:, 2] - (self.m_half[:, 2] @ ell) * ell  # the viewer's side of the plane
        e_b = -k / np.linalg.norm(k)
        return np.cross(ell, e_b), e_b

    def front_point(self, rel: FloatArray) -> tuple[FloatArray, NDArray[np.bool_]]:
        """The front surface point ``(v, u, w)`` of the ray through each image offset ``rel``
        (its last axis ``(dv, du)``; off the body the tangent depth), and whether it hits."""
        m = self.m
        dv, du = rel[..., 0], rel[..., 1]
        b = 2.0 * (m[0, 2] * dv + m[1, 2] * du)
        q = m[0, 0] * dv * dv + 2.0 * m[0, 1] * dv * du + m[1, 1] * du * du - 1.0
        disc = b * b - 4.0 * m[2, 2] * q
        w = (-b + np.sqrt(np.maximum(disc, 0.0))) / (2.0 * m[2, 2])
        return np.stack([dv, du, w], axis=-1), disc > 0.0


def _light(phase_deg: float, illumination_deg: float) -> FloatArray:
    """The unit vector toward the Sun in the camera frame, ``(sin(phase) s, cos(phase))``."""
    phase = math.radians(phase_deg)
    s_v, s_u = sun_direction_vu(illumination_deg)
    return np.array([math.sin(phase) * s_v, math.sin(phase) * s_u, math.cos(phase)])


def _axes(value: Any) -> FloatArray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError("axes_px must be three semi-axes in pixels") from exc
    if arr.shape != (3,):
        raise ValueError(f"axes_px must be three semi-axes in pixels, got shape {arr.shape}")
    if not (np.isfinite(arr).all() and (arr > 0.0).all()):
        raise ValueError(f"axes_px must be finite and > 0, got {tuple(arr.tolist())}")
    return arr


def _rotation(value: Any) -> FloatArray:
    if value is None:
        return np.eye(3)
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError("rotation must be a 3 x 3 matrix of numbers") from exc
    if arr.shape != (3, 3):
        raise ValueError(f"rotation must be a 3 x 3 matrix, got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError("rotation must be finite")
    err = float(np.abs(arr.T @ arr - np.eye(3)).max())
    if err > ROTATION_TOLERANCE:
        raise ValueError(f"rotation must be orthonormal (its columns the axes' unit "
                         f"directions), got |R^T R - I| = {err:.3g}")
    return arr


def _day_normals(body: _Body, x: FloatArray, light: FloatArray) -> FloatArray:
    """Unit in-image gradients of ``cos i`` at the terminator's surface points ``x``: with
    ``F = (M x) . L`` and the front surface's slope ``dw/dp = -(M x)_vu / (M x)_w``,
    ``grad F = (M L)_vu - (M L)_w (M x)_vu / (M x)_w``."""
    mx = x @ body.m
    mx /= np.linalg.norm(mx, axis=1)[:, None]
    ml = body.m @ light
    grad = ml[None, :2] - ml[2] * mx[:, :2] / np.maximum(mx[:, 2], 1e-12)[:, None]
    size = np.hypot(grad[:, 0], grad[:, 1])
    if not (size > 0.0).all():
        raise ValueError("a terminator vertex lies at the sub-solar point: cos i has no "
                         "gradient there, so no normal")
    return np.asarray(grad / size[:, None], dtype=np.float64)


def _terminator_curvature(body: _Body, x: FloatArray, e_a: FloatArray, e_b: FloatArray,
                          normals: FloatArray) -> FloatArray:
    """Signed curvature of the projected terminator at the surface points ``x``: the image of
    ``S^(1/2) (cos t e_a + sin t e_b)`` is ``p(t)`` with ``p'' = -p``, so ``kappa = p'' . n /
    |p'|^2`` (positive where it bends toward the normals' side)."""
    y = x @ body.m_half
    t = np.arctan2(y @ e_b, y @ e_a)
    a1, b1 = (body.s_half @ e_a)[:2], (body.s_half @ e_b)[:2]
    p = np.cos(t)[:, None] * a1 + np.sin(t)[:, None] * b1
    dp = -np.sin(t)[:, None] * a1 + np.cos(t)[:, None] * b1
    return np.asarray(-(p * normals).sum(axis=1) / (dp * dp).sum(axis=1), dtype=np.float64)


def ellipsoid_limb_polyline(
    center_vu: Any,
    axes_px: Any,
    *,
    rotation: ArrayLike | None = None,
    illumination_deg: float | None = None,
    phase_deg: float | None = None,
    sunlit_only: bool = True,
    n_vertices: int = DEFAULT_POLYLINE_VERTICES,
    sigma: float = DEFAULT_POLYLINE_SIGMA_PX,
) -> Polyline:
    """The geometric limb of a triaxial ellipsoid: its outline, normals into the disc.

    By default the sunlit half: the part of the outline where the unit
    vector ``n`` perpendicular to it, pointing off the disc, faces the Sun,
    ``n . s > 0``. At the limb the surface normal is ``(n, 0)``, so ``cos i
    = sin(phase) n . s`` there, as on a sphere: the lit part of the limb is
    exactly that half at every phase. The vertex at ``n`` is ``S2 n /
    sqrt(n^T S2 n)`` from the centre (the module's *geometry*), ``n`` at the
    angles of :func:`~dtalign.sphere_limb_polyline`'s vertex directions; the
    normals are ``-n``, into the disc.

    Parameters
    ----------
    center_vu : tuple of float
        The ellipsoid's centre in the image, ``(v, u)`` pixels.
    axes_px : sequence of three float
        Its semi-axes ``(a, b, c)``, pixels, > 0.
    rotation : array_like, shape (3, 3), optional
        Orthonormal; its columns are the directions of ``a``, ``b`` and
        ``c`` in the camera frame ``(v, u, w)``, ``w`` toward the viewer
        (the module's *attitude*). None: the identity.
    illumination_deg, phase_deg, sunlit_only, n_vertices, sigma
        As :func:`~dtalign.sphere_limb_polyline`'s: ``illumination_deg``
        required with ``sunlit_only=True``, ``phase_deg`` in [0, 180)
        checked and not otherwise used, ``n_vertices >= 2``, ``sigma > 0``.

    Returns
    -------
    Polyline
        ``name`` and ``edge_kind`` ``"limb"``; the vertices run
        counter-clockwise on the displayed image, as the sphere's.

    Raises
    ------
    TypeError
        If a number is not a real number (``n_vertices`` not an int,
        ``sunlit_only`` not a bool); the message names the argument.
    ValueError
        If a value is out of range or malformed (``rotation`` not
        orthonormal to :data:`ROTATION_TOLERANCE`), or ``illumination_deg``
        is missing with ``sunlit_only=True``; the message names the
        argument.

    Examples
    --------
    >>> from dtalign import ellipsoid_limb_polyline
    >>> limb = ellipsoid_limb_polyline((150.0, 150.0), (60.0, 80.0, 70.0),
    ...                                illumination_deg=90.0, n_vertices=5)
    >>> limb.vertices_vu[2].tolist()   # the Sun toward +u: the end of the u semi-axis
    [150.0, 230.0]
    """
    body = _Body(center_vu, axes_px, rotation)
    outward = _limb_directions(illumination_deg, phase_deg, sunlit_only, n_vertices)
    sig = check.positive_real(sigma, "sigma")
    return Polyline("limb", body.center[None, :] + body.outline_point(outward), -outward,
                    np.full(outward.shape[0], sig), edge_kind="limb")


def ellipsoid_terminator_polyline(
    center_vu: Any,
    axes_px: Any,
    *,
    rotation: ArrayLike | None = None,
    illumination_deg: float,
    phase_deg: float,
    n_vertices: int = DEFAULT_POLYLINE_VERTICES,
    sigma: float = DEFAULT_POLYLINE_SIGMA_PX,
) -> Polyline:
    """The visible half of a triaxial ellipsoid's terminator, normals toward the day side.

    The terminator is the plane section of the surface whose normals are
    perpendicular to the Sun (the module's *geometry*); the half facing the
    viewer projects to half an ellipse from one end of the lit limb to the
    other. The vertices are at the sphere's great-circle angles
    (:func:`~dtalign.sphere_terminator_polyline`) mapped onto the
    ellipsoid; the normals point up the gradient of ``cos i``, the bright
    side.

    Parameters
    ----------
    center_vu : tuple of float
        The ellipsoid's centre in the image, ``(v, u)`` pixels.
    axes_px : sequence of three float
        Its semi-axes ``(a, b, c)``, pixels, > 0.
    rotation : array_like, shape (3, 3), optional
        As :func:`ellipsoid_limb_polyline`'s.
    illumination_deg, phase_deg, n_vertices, sigma
        As :func:`~dtalign.sphere_terminator_polyline`'s: ``phase_deg`` in
        (0, 180), ``n_vertices >= 2``, ``sigma > 0``.

    Returns
    -------
    Polyline
        ``name`` and ``edge_kind`` ``"terminator"``; fit it with
        :func:`ellipsoid_edge_profile` (``edge="terminator"``).

    Raises
    ------
    TypeError
        If a number is not a real number (``n_vertices`` not an int); the
        message names the argument.
    ValueError
        If a value is out of range or malformed (``phase_deg`` 0 included);
        the message names the argument.
    """
    body = _Body(center_vu, axes_px, rotation)
    ill, phase_d, n = _terminator_args(illumination_deg, phase_deg, n_vertices)
    sig = check.positive_real(sigma, "sigma")
    light = _light(phase_d, ill)
    e_a, e_b = body.terminator_basis(light)
    t = _terminator_angles(n)
    x = (np.cos(t)[:, None] * e_a + np.sin(t)[:, None] * e_b) @ body.s_half
    return Polyline("terminator", body.center[None, :] + x[:, :2], _day_normals(body, x, light),
                    np.full(n, sig), edge_kind="terminator")


def ellipsoid_edge_profile(
    vertices_vu: ArrayLike,
    *,
    center_vu: Any,
    axes_px: Any,
    rotation: ArrayLike | None = None,
    phase_deg: float,
    illumination_deg: float,
    edge: str = "limb",
    law: str = "lambert",
    minnaert_k: float | None = None,
    psf_sigma_px: float | None = None,
    fit_law: bool = True,
    step_px: float = SPHERE_PROFILE_STEP_PX,
    half_range_px: float = SPHERE_PROFILE_HALF_RANGE_PX,
) -> EdgeProfile:
    """The edge profile of a shaded triaxial ellipsoid's limb or terminator at each vertex.

    :func:`~dtalign.sphere_edge_profile` for the ellipsoid of
    :func:`ellipsoid_limb_polyline` (the module's *profile*): the same laws,
    offsets grid, cell means and shape basis, the radiance read on the
    ellipsoid's own surface, so the incidence and emission angles and the
    fall-off across each vertex are the ellipsoid's there.

    Parameters
    ----------
    vertices_vu : array_like, shape (N, 2)
        Vertices on the model edge (the ellipsoid's limb or terminator).
    center_vu, axes_px, rotation
        The ellipsoid, as :func:`ellipsoid_limb_polyline`'s.
    phase_deg, illumination_deg, law, minnaert_k, psf_sigma_px, fit_law, step_px, half_range_px
        As :func:`~dtalign.sphere_edge_profile`'s.
    edge : {"limb", "terminator"}
        Which edge the vertices lie on. Limb normals point into the disc,
        perpendicular to the outline through the vertex (the ellipse
        ``p^T S2^-1 p = 1``), its curvature the outline's there; terminator normals point up the gradient of
        ``cos i`` at the front surface point under the vertex, its
        curvature the projected terminator's.

    Returns
    -------
    EdgeProfile

    Raises
    ------
    ValueError
        On a malformed argument (the message names it), a limb vertex at
        the centre, or a terminator at phase 0 (there is none).

    Examples
    --------
    >>> from dtalign import ellipsoid_edge_profile, ellipsoid_limb_polyline
    >>> ellipsoid = dict(center_vu=(100.0, 100.0), axes_px=(60.0, 50.0, 45.0))
    >>> limb = ellipsoid_limb_polyline(**ellipsoid, illumination_deg=30.0, n_vertices=50)
    >>> profile = ellipsoid_edge_profile(limb.vertices_vu, **ellipsoid, phase_deg=40.0,
    ...                                  illumination_deg=30.0)
    >>> profile.n_vertices, profile.edge
    (50, 'limb')
    """
    verts = check.vertices(vertices_vu, "vertices_vu", allow_empty=False)
    body = _Body(center_vu, axes_px, rotation)
    phase_d = _phase(phase_deg)
    ill = check.finite_real(illumination_deg, "illumination_deg")
    if edge not in ("limb", "terminator"):
        raise ValueError(f"edge must be 'limb' or 'terminator', got {edge!r}")
    k, psf, h, half = _law_args(law, minnaert_k, psf_sigma_px, step_px, half_range_px)
    light = _light(phase_d, ill)
    rel = verts - body.center
    if edge == "limb":
        outward = np.linalg.solve(body.s[:2, :2], rel.T).T
        size = np.hypot(outward[:, 0], outward[:, 1])
        if (size == 0.0).any():
            raise ValueError("a limb vertex lies at center_vu: it has no normal")
        outward /= size[:, None]
        support = np.sqrt((outward * (outward @ body.s[:2, :2])).sum(axis=1))
        normals = -outward
        curvature = support**3 / np.linalg.det(body.s[:2, :2])
    else:
        if phase_d == 0.0:
            raise ValueError("an ellipsoid at phase 0 has no terminator")
        x, _ = body.front_point(rel)
        normals = _day_normals(body, x, light)
        curvature = _terminator_curvature(body, x, *body.terminator_basis(light), normals)

    def radiance(pv: FloatArray, pu: FloatArray) -> tuple[FloatArray, FloatArray]:
        x, hit = body.front_point(np.stack([pv - body.center[0], pu - body.center[1]], axis=-1))
        n3 = x @ body.m
        with np.errstate(invalid="ignore", divide="ignore"):
            n3 /= np.linalg.norm(n3, axis=-1)[..., None]
        return _law_radiance(n3 @ light, n3[..., 2], hit, law, k)

    offsets, values, basis = _cell_means(verts, normals, radiance, h, half, fit_law)
    return EdgeProfile(offsets_px=offsets, values=values, normals_vu=normals,
                       curvature_px=np.asarray(curvature, dtype=np.float64), psf_sigma_px=psf,
                       edge=edge, shape_values=basis)
