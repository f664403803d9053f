"""The frame conventions shared by the renderer and the fits, in NumPy only.

Image coordinates are dtalign's: ``(v, u)`` pixel indices, pixel ``(i, j)``
centred at ``(i, j)``. The Mitsuba scene is built in *world* units of one
output pixel: the orthographic sensor sits at the origin looking along +Z
and covers ``X, Y`` in ``[-W/2, W/2]`` for a ``W x W`` frame. Mitsuba's film
pixel ``x`` covers ``[x, x + 1)`` and its +X axis points to the left of the
image, +Y up, so an image point maps to

    ``X = W/2 - 0.5 - u``,  ``Y = W/2 - 0.5 - v``.

The direction toward the viewer is -Z. The Sun follows dtalign's profiles
page: ``s = (-cos(ill), sin(ill))`` in ``(v, u)`` and ``L = (sin(phase) s,
cos(phase))`` with the last component toward the viewer. The renderer's
checks (:mod:`.checks`) verify the mapping to a thousandth of a pixel.

The triaxial ellipsoid's model limb (its projected outline, normals, edge
curvature and Lambert profile) is computed here from the closed forms, as a
navigation model would: it is the model of that family, not the renderer.
"""

from __future__ import annotations

import math

import numpy as np

from dtalign import EdgeProfile


def world_xy(center_vu: tuple[float, float], frame_px: int) -> tuple[float, float]:
    """World ``(X, Y)`` of an image point ``(v, u)`` in a ``frame_px`` square frame."""
    v, u = center_vu
    return frame_px / 2.0 - 0.5 - u, frame_px / 2.0 - 0.5 - v


def vu_to_world_vector(vec_vu: np.ndarray) -> np.ndarray:
    """A direction in the image plane ``(dv, du)`` as a world ``(dX, dY)`` (both flip)."""
    return -np.asarray(vec_vu, dtype=float)


def sun_vector_world(phase_deg: float, illumination_deg: float) -> np.ndarray:
    """Unit world vector toward the Sun, in dtalign's phase / illumination convention."""
    ill, ph = math.radians(illumination_deg), math.radians(phase_deg)
    s_v, s_u = -math.cos(ill), math.sin(ill)
    return np.array([-math.sin(ph) * s_u, -math.sin(ph) * s_v, -math.cos(ph)])


def rotation_matrix(angles_deg: tuple[float, float, float]) -> np.ndarray:
    """Rotation ``Rz(c) @ Ry(b) @ Rx(a)`` of the ellipsoid's principal axes, world frame."""
    a, b, c = (math.radians(x) for x in angles_deg)
    rx = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    ry = np.array([[math.cos(b), 0, math.sin(b)], [0, 1, 0], [-math.sin(b), 0, math.cos(b)]])
    rz = np.array([[math.cos(c), -math.sin(c), 0], [math.sin(c), math.cos(c), 0], [0, 0, 1]])
    return rz @ ry @ rx


def ellipsoid_matrix(axes_px: tuple[float, float, float],
                     angles_deg: tuple[float, float, float]) -> np.ndarray:
    """``M`` with ``x^T M x = 1`` on the surface (world frame, centred)."""
    r = rotation_matrix(angles_deg)
    return r @ np.diag(1.0 / np.asarray(axes_px, dtype=float) ** 2) @ r.T


def _world_to_vu(xy: np.ndarray) -> np.ndarray:
    """World ``(X, Y)`` offsets from the centre as image ``(v, u)`` offsets."""
    return np.stack([-xy[..., 1], -xy[..., 0]], axis=-1)


def _lambert_at(points_vu: np.ndarray, center_vu: np.ndarray, m: np.ndarray,
                sun: np.ndarray) -> np.ndarray:
    """Lambert ``cos i`` (0 off the body and on the night side) at image points."""
    rel = points_vu - center_vu
    xy = np.stack([-rel[..., 1], -rel[..., 0]], axis=-1)  # (X, Y) offsets
    # the ray (X, Y, z): m_zz z^2 + 2 z (m_xz X + m_yz Y) + q(X, Y) - 1 = 0; the front root
    # is the one nearer the viewer (smaller z).
    a = m[2, 2]
    b = 2.0 * (m[0, 2] * xy[..., 0] + m[1, 2] * xy[..., 1])
    q = (m[0, 0] * xy[..., 0] ** 2 + 2 * m[0, 1] * xy[..., 0] * xy[..., 1]
         + m[1, 1] * xy[..., 1] ** 2 - 1.0)
    disc = b * b - 4 * a * q
    hit = disc > 0
    z = (-b - np.sqrt(np.where(hit, disc, 0.0))) / (2 * a)
    x3 = np.stack([xy[..., 0], xy[..., 1], z], axis=-1)
    n = x3 @ m.T
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    return np.where(hit, np.clip(n @ sun, 0.0, None), 0.0)


def ellipsoid_limb_model(center_vu: tuple[float, float], axes_px: tuple[float, float, float],
                         angles_deg: tuple[float, float, float], phase_deg: float,
                         illumination_deg: float, n_vertices: int = 200,
                         step_px: float = 0.1, half_range_px: float = 12.0
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray, EdgeProfile]:
    """The sunlit part of a triaxial ellipsoid's limb and its Lambert edge profile.

    The outline of ``x^T M x = 1`` seen along Z is the ellipse ``p^T Q p = 1``
    with ``Q = A - b b^T / c`` (``M`` partitioned into its XY block ``A``,
    column ``b`` and corner ``c``): the rays tangent to the surface. Vertices
    are spaced evenly in the ellipse's angle over the half whose surface
    normal faces the Sun; normals point into the disc (``-Q p``); the
    curvature is the ellipse's. The profile's values are cell means of
    ``cos i`` along each normal (4 sub-samples a cell), with the
    ray-ellipsoid intersection computed exactly.

    Returns
    -------
    vertices_vu, normals_vu, sigmas, profile
        The model polyline (sigmas 1 px) and its :class:`dtalign.EdgeProfile`
        (``edge="limb"``, PSF unknown: estimated by the fit).
    """
    m = ellipsoid_matrix(axes_px, angles_deg)
    q = m[:2, :2] - np.outer(m[:2, 2], m[:2, 2]) / m[2, 2]
    sun = sun_vector_world(phase_deg, illumination_deg)
    evals, evecs = np.linalg.eigh(q)
    t = np.linspace(0.0, 2 * math.pi, 4 * n_vertices, endpoint=False)
    xy = (evecs @ (np.stack([np.cos(t), np.sin(t)]) / np.sqrt(evals)[:, None])).T
    z = -(xy @ m[:2, 2]) / m[2, 2]
    n3 = np.concatenate([xy, z[:, None]], axis=1) @ m.T
    lit = n3 @ sun > 0.0
    # the lit arc as one run of t: start at the first lit sample after an unlit one
    start = int(np.argmax(lit & ~np.roll(lit, 1)))
    order = np.roll(np.arange(t.size), -start)
    arc = order[: int(lit.sum())]
    ta = np.unwrap(t[arc])
    tv = np.linspace(ta[0], ta[-1], n_vertices + 2)[1:-1]
    xy_v = (evecs @ (np.stack([np.cos(tv), np.sin(tv)]) / np.sqrt(evals)[:, None])).T
    grad = xy_v @ q.T                      # outward normal of the outline, world XY
    inward_world = -grad / np.linalg.norm(grad, axis=1, keepdims=True)
    center = np.asarray(center_vu, dtype=float)
    verts = center + _world_to_vu(xy_v)
    normals = _world_to_vu(inward_world)
    # curvature of the ellipse p(t) = E diag(1/sqrt(l)) (cos t, sin t): |p' x p''| / |p'|^3
    a_ax, b_ax = 1.0 / np.sqrt(evals)
    curvature = a_ax * b_ax / (a_ax ** 2 * np.sin(tv) ** 2 + b_ax ** 2 * np.cos(tv) ** 2) ** 1.5
    offsets = np.arange(-half_range_px, half_range_px + 0.5 * step_px, step_px)
    sub = (np.arange(4) + 0.5) / 4 - 0.5
    fine = (offsets[:, None] + step_px * sub[None, :]).ravel()
    pts = verts[:, None, :] + fine[None, :, None] * normals[:, None, :]
    values = _lambert_at(pts, center, m, sun).reshape(n_vertices, offsets.size, 4).mean(axis=2)
    profile = EdgeProfile(offsets_px=offsets, values=values, normals_vu=normals,
                          curvature_px=curvature, psf_sigma_px=None, edge="limb")
    return verts, normals, np.ones(n_vertices), profile
