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

The triaxial ellipsoid's model (its limb and terminator and their edge
profiles) is dtalign's :mod:`dtalign.api.ellipsoid`, given the renderer's
attitude in dtalign's camera frame (:func:`camera_rotation`).
"""

from __future__ import annotations

import math

import numpy as np


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


#: World ``(X, Y, Z)`` from dtalign's camera frame ``(v, u, w)`` (``w`` toward the viewer):
#: ``X = -u``, ``Y = -v``, ``Z = -w``; a proper rotation, its own inverse.
CAMERA_TO_WORLD = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def camera_rotation(angles_deg: tuple[float, float, float]) -> np.ndarray:
    """The ellipsoid's attitude as :mod:`dtalign.api.ellipsoid` takes it: the columns are
    its principal axes in the camera frame ``(v, u, w)``, from the world's
    :func:`rotation_matrix`."""
    return CAMERA_TO_WORLD @ rotation_matrix(angles_deg)
