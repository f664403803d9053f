"""Seeded synthetic scenes (:ref:`contract-scenes`) for the demo, tests and benchmarks.

The base scene is a bright disc (100 DN inside, 0 outside) centred on a
1024 x 1024 image with Gaussian noise of 2 DN, and a limb polyline on the
disc's circle displaced by a known offset: the polyline sits at
``centre - offset``, so a correct fit returns ``offset``. Normals point into
the disc, the bright side, so every limb vertex passes the polarity test.

:func:`navigation_scene` adds what a real frame has and a disc lacks: a
half-lit body (limb arc plus terminator arc) and a straight ring edge, so a
rotation fit is observable and the end-to-end workload fits three different
polylines against one image's products.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

__all__ = ["Polyline", "Scene", "disc_scene", "navigation_scene"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Polyline:
    """A model polyline: vertices, normals (to the bright side) and per-vertex sigmas."""

    name: str
    vertices_vu: FloatArray
    normals_vu: FloatArray
    sigmas: FloatArray

    def __len__(self) -> int:
        return int(self.vertices_vu.shape[0])


@dataclass(frozen=True)
class Scene:
    """An image, its noise level, polylines and the truth they were made from.

    Attributes
    ----------
    image : ndarray, shape (H, W)
        The noisy image in DN.
    noise_sigma : float
        The standard deviation of the added noise.
    polylines : tuple of Polyline
        Model polylines, each displaced from the true edge by the truth.
    true_offset_vu : tuple of float
        The offset a correct fit returns.
    true_rotation_rad : float
        The rotation a correct fit returns (about ``pivot_vu``).
    pivot_vu : tuple of float
        The rotation pivot: the centroid of the first polyline.
    pivot_distance_px : float
        Distance from the pivot to the image centre, floored at 1.
    search_window_vu : tuple of int
        The coarse-search margin of the scene (:ref:`contract-scenes`).
    """

    image: FloatArray
    noise_sigma: float
    polylines: tuple[Polyline, ...]
    true_offset_vu: tuple[float, float]
    true_rotation_rad: float
    pivot_vu: tuple[float, float]
    pivot_distance_px: float
    search_window_vu: tuple[int, int] = (30, 30)
    outlier_indices: tuple[int, ...] = field(default=())

    @property
    def polyline(self) -> Polyline:
        """The first (for :func:`disc_scene`, the only) polyline."""
        return self.polylines[0]


def _centre(shape: tuple[int, int]) -> tuple[float, float]:
    return (shape[0] - 1) / 2.0, (shape[1] - 1) / 2.0


def _noisy(clean: FloatArray, noise_sigma: float, seed: int) -> FloatArray:
    rng = np.random.default_rng(seed)
    return clean + rng.normal(0.0, noise_sigma, clean.shape)


def _displace(
    true_vu: FloatArray, offset_vu: tuple[float, float], rotation_rad: float
) -> tuple[FloatArray, tuple[float, float]]:
    """Model vertices that the pose (offset, rotation about their centroid) maps onto ``true_vu``.

    With pivot ``p = mean(true) - offset`` the model is
    ``p + R(-theta) (true - mean(true))``; its centroid is ``p``, so the
    default pivot of the fitters is exactly ``p``.
    """
    mean = true_vu.mean(axis=0)
    pivot = mean - np.asarray(offset_vu)
    c, s = math.cos(-rotation_rad), math.sin(-rotation_rad)
    d = true_vu - mean
    model = np.empty_like(true_vu)
    model[:, 0] = pivot[0] + c * d[:, 0] - s * d[:, 1]
    model[:, 1] = pivot[1] + s * d[:, 0] + c * d[:, 1]
    return model, (float(pivot[0]), float(pivot[1]))


def _rotate_vectors(vec: FloatArray, theta: float) -> FloatArray:
    c, s = math.cos(theta), math.sin(theta)
    return np.stack([c * vec[:, 0] - s * vec[:, 1], s * vec[:, 0] + c * vec[:, 1]], axis=1)


def disc_scene(
    *,
    shape: tuple[int, int] = (1024, 1024),
    radius: float = 150.0,
    n_vertices: int = 200,
    offset_vu: tuple[float, float] = (7.3, -4.6),
    rotation_rad: float = 0.0,
    noise_sigma: float = 2.0,
    outlier_fraction: float = 0.0,
    outlier_shift_px: float = 30.0,
    search_window: int = 30,
    seed: int = 0,
) -> Scene:
    """The disc scene of :ref:`contract-scenes` and its variants.

    Parameters
    ----------
    shape : tuple of int
        Image shape ``(H, W)``.
    radius : float
        Disc radius in pixels.
    n_vertices : int
        Limb vertices, evenly spaced in angle.
    offset_vu, rotation_rad : tuple of float, float
        The truth: the pose that maps the model polyline onto the limb.
    noise_sigma : float
        Gaussian noise in DN, from ``numpy.random.default_rng(seed)``.
    outlier_fraction : float
        Fraction of vertices (chosen by the same generator) pushed
        ``outlier_shift_px`` outward along the radius.
    search_window : int
        The symmetric coarse-search margin recorded on the scene.
    seed : int
        Seeds the noise and the choice of outliers.

    Returns
    -------
    Scene
    """
    cv, cu = _centre(shape)
    vv, uu = np.mgrid[0 : shape[0], 0 : shape[1]]
    clean = np.where((vv - cv) ** 2 + (uu - cu) ** 2 <= radius**2, 100.0, 0.0)
    image = _noisy(clean, noise_sigma, seed)

    phi = 2.0 * np.pi * np.arange(n_vertices) / n_vertices
    radial = np.stack([np.cos(phi), np.sin(phi)], axis=1)
    true_vu = np.array([cv, cu]) + radius * radial
    normals_true = -radial  # into the disc: the bright side
    model, pivot = _displace(true_vu, offset_vu, rotation_rad)
    normals = _rotate_vectors(normals_true, -rotation_rad)

    outliers: tuple[int, ...] = ()
    if outlier_fraction > 0.0:
        rng = np.random.default_rng(seed + 1_000_003)
        count = int(round(outlier_fraction * n_vertices))
        idx = np.sort(rng.choice(n_vertices, size=count, replace=False))
        model[idx] -= outlier_shift_px * normals[idx]
        outliers = tuple(int(i) for i in idx)

    distance = max(math.hypot(pivot[0] - cv, pivot[1] - cu), 1.0)
    poly = Polyline("limb", model, normals, np.ones(n_vertices))
    return Scene(
        image=image,
        noise_sigma=noise_sigma,
        polylines=(poly,),
        true_offset_vu=(float(offset_vu[0]), float(offset_vu[1])),
        true_rotation_rad=float(rotation_rad),
        pivot_vu=pivot,
        pivot_distance_px=distance,
        search_window_vu=(search_window, search_window),
        outlier_indices=outliers,
    )


def navigation_scene(
    *,
    shape: tuple[int, int] = (1024, 1024),
    radius: float = 150.0,
    n_vertices: int = 200,
    offset_vu: tuple[float, float] = (7.3, -4.6),
    rotation_rad: float = 0.0,
    noise_sigma: float = 2.0,
    search_window: int = 30,
    seed: int = 0,
) -> Scene:
    """A half-lit body and a ring edge: three polylines on one image.

    The body is lit from +u: its lit region is the right half-disc plus the
    left half of an ellipse with semi-axes ``radius`` (v) and
    ``radius / 2`` (u), whose boundary is the terminator. A bright ring
    band (60 DN) spans the image below the body; its upper edge is straight.
    Polylines, in order: ``limb`` (right half of the circle),
    ``terminator`` (left half-ellipse) and ``ring`` (the band's upper edge),
    all displaced by the same pose about the limb's centroid. Normals point
    into the bright side.
    """
    h, w = shape
    cv, cu = _centre(shape)
    b = radius / 2.0
    vv, uu = np.mgrid[0:h, 0:w]
    dv, du = vv - cv, uu - cu
    in_disc = dv**2 + du**2 <= radius**2
    in_ellipse = (dv / radius) ** 2 + (du / b) ** 2 <= 1.0
    lit = in_disc & ((du >= 0.0) | in_ellipse)
    # An integer first row, so the band's upper edge is exactly ring_top - 0.5.
    ring_top = float(math.floor(min(cv + radius + 0.35 * (h - cv - radius), h - 20.0)))
    ring = (vv >= ring_top) & (vv <= ring_top + 40.0)
    clean = np.where(lit, 100.0, 0.0) + np.where(ring, 60.0, 0.0)
    image = _noisy(clean, noise_sigma, seed)

    # Keep clear of the limb/terminator cusps at the poles, where the two
    # curves meet and neither edge is clean.
    ang = np.linspace(-0.42 * np.pi, 0.42 * np.pi, n_vertices)
    limb = np.stack([cv + radius * np.sin(ang), cu + radius * np.cos(ang)], axis=1)
    limb_n = -np.stack([np.sin(ang), np.cos(ang)], axis=1)
    term = np.stack([cv + radius * np.sin(ang), cu - b * np.cos(ang)], axis=1)
    # The lit side of the terminator is +u: the normal of the ellipse
    # (v/R^2, u/b^2) points outward, i.e. toward -u on the left half.
    tn = np.stack([-np.sin(ang) / radius, np.cos(ang) / b], axis=1)
    term_n = tn / np.hypot(tn[:, 0], tn[:, 1])[:, None]
    ring_u = np.linspace(0.1 * w, 0.9 * w, n_vertices)
    ring_v = np.full(n_vertices, ring_top - 0.5)
    ring_pts = np.stack([ring_v, ring_u], axis=1)
    ring_n = np.tile([1.0, 0.0], (n_vertices, 1))

    # One rigid pose for every polyline: displace all about the limb centroid.
    mean = limb.mean(axis=0)
    pivot = mean - np.asarray(offset_vu)
    c, s = math.cos(-rotation_rad), math.sin(-rotation_rad)

    def place(pts: FloatArray) -> FloatArray:
        d = pts - mean
        return np.stack(
            [pivot[0] + c * d[:, 0] - s * d[:, 1], pivot[1] + s * d[:, 0] + c * d[:, 1]], axis=1
        )

    polys = tuple(
        Polyline(name, place(p), _rotate_vectors(n, -rotation_rad), np.ones(n_vertices))
        for name, p, n in (("limb", limb, limb_n), ("terminator", term, term_n), ("ring", ring_pts, ring_n))
    )
    piv = (float(pivot[0]), float(pivot[1]))
    return Scene(
        image=image,
        noise_sigma=noise_sigma,
        polylines=polys,
        true_offset_vu=(float(offset_vu[0]), float(offset_vu[1])),
        true_rotation_rad=float(rotation_rad),
        pivot_vu=piv,
        pivot_distance_px=max(math.hypot(piv[0] - cv, piv[1] - cu), 1.0),
        search_window_vu=(search_window, search_window),
    )
