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

:func:`render_sphere` is the ground truth of the accuracy measurements: a
shaded sphere (Lambert, Minnaert or Lommel-Seeliger) at any phase and light
direction, integrated over each pixel's area, blurred, with noise, and a
planted sub-pixel offset. Its shading shares no code with the edge-profile
model the fit uses; its model polylines are the public builders'
(:func:`dtalign.sphere_limb_polyline`, :func:`dtalign.sphere_terminator_polyline`),
so a user who builds them for the same sphere gets the same polylines.
:class:`Polyline` and :func:`sun_direction_vu` are
:mod:`dtalign.api.polylines`'s, re-exported here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

# The model polylines' record and the sphere's limb and terminator are the
# public builders' (one implementation: a user's builder output is the
# scene's polyline); the shading below shares nothing with the fit's model.
from .api.polylines import (
    Polyline,
    sphere_limb_polyline,
    sphere_terminator_polyline,
    sun_direction_vu,
)

__all__ = [
    "DEFECTS", "Polyline", "Scene", "SphereScene", "add_defects", "disc_scene", "navigation_scene",
    "render_sphere", "sun_direction_vu",
]

FloatArray = NDArray[np.float64]


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
    true_vu: FloatArray, offset_vu: tuple[float, float], rotation_rad: float,
    centroid: FloatArray | None = None,
) -> tuple[FloatArray, tuple[float, float]]:
    """Model vertices that the pose (offset, rotation about their centroid) maps onto ``true_vu``.

    With pivot ``p = mean(true) - offset`` the model is
    ``p + R(-theta) (true - mean(true))``; its centroid is ``p``, so the
    default pivot of the fitters is exactly ``p``. A given ``centroid``
    replaces ``mean(true)``: polylines that move as one rigid body are all
    displaced about the same point.
    """
    mean = true_vu.mean(axis=0) if centroid is None else centroid
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


def _scene(
    image: FloatArray, noise_sigma: float, polylines: tuple[Polyline, ...],
    offset_vu: tuple[float, float], rotation_rad: float, pivot: tuple[float, float],
    centre: tuple[float, float], search_window: int, outliers: tuple[int, ...] = (),
) -> Scene:
    """The :class:`Scene` of a displaced pose; the pivot's distance is from the image centre."""
    return Scene(
        image=image,
        noise_sigma=noise_sigma,
        polylines=polylines,
        true_offset_vu=(float(offset_vu[0]), float(offset_vu[1])),
        true_rotation_rad=float(rotation_rad),
        pivot_vu=pivot,
        pivot_distance_px=max(math.hypot(pivot[0] - centre[0], pivot[1] - centre[1]), 1.0),
        search_window_vu=(search_window, search_window),
        outlier_indices=outliers,
    )


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

    poly = Polyline("limb", model, normals, np.ones(n_vertices))
    return _scene(image, noise_sigma, (poly,), offset_vu, rotation_rad, pivot, (cv, cu),
                  search_window, outliers)


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
    moved = [_displace(p, offset_vu, rotation_rad, mean) for p in (limb, term, ring_pts)]
    polys = tuple(
        Polyline(name, m[0], _rotate_vectors(n, -rotation_rad), np.ones(n_vertices))
        for name, m, n in zip(("limb", "terminator", "ring"), moved, (limb_n, term_n, ring_n), strict=True)
    )
    pivot = moved[0][1]  # the limb's, the same for all three
    return _scene(image, noise_sigma, polys, offset_vu, rotation_rad, pivot, (cv, cu), search_window)


# ---------------------------------------------------------------------------
# Photometric spheres: an independent renderer for accuracy measurements
# ---------------------------------------------------------------------------
#
# This renderer shades the 3-D surface at every sub-pixel sample and averages
# the samples over each pixel. It deliberately shares no code with the edge
# profile model the fit uses (dtalign.profiles): a renderer built from the
# fit's own model would only show that the model agrees with itself.

#: Reflectance laws :func:`render_sphere` knows.
SPHERE_LAWS = ("lambert", "minnaert", "lommel-seeliger")

#: PSF shapes :func:`render_sphere` knows: a Gaussian, and a Gaussian core
#: with broad wings (not a Gaussian: what a fit that assumes one is not told).
SPHERE_PSFS = ("gaussian", "core+wings")

#: The core+wings PSF: this fraction of the light in a Gaussian of
#: ``WINGS_SCALE`` times the core sigma, the rest in the core. Real optics
#: scatter a few to tens of percent into a halo; 20 % at 4x is a strong,
#: clearly non-Gaussian case.
WINGS_FRACTION = 0.2
WINGS_SCALE = 4.0

#: Gaussian kernels reach this many sigmas (the mass beyond is < 1e-6).
_PSF_TRUNCATE = 5.0


@dataclass(frozen=True)
class SphereScene:
    """A rendered sphere, its model polylines and the truth they were made from.

    The model polylines sit around ``model_center_vu = center_vu - offset``:
    a correct fit of either returns ``true_offset_vu`` (as for
    :func:`disc_scene`).

    Attributes
    ----------
    image : ndarray, shape (H, W)
        The rendered image in DN (background, PSF and noise included).
    noise_sigma : float
        Standard deviation of the added noise at the background level (read
        noise and the background's shot noise); 0.0 when noise-free.
    peak_snr : float
        The brightest pixel's signal above background over its noise
        standard deviation (``inf`` when noise-free).
    true_offset_vu : tuple of float
        The planted offset a correct fit returns.
    center_vu : tuple of float
        Where the sphere's centre really is in the image.
    model_center_vu : tuple of float
        Where the model (the polylines) puts it: ``center_vu - true_offset_vu``.
    radius_px, phase_deg, illumination_deg : float
        The sphere's geometry and lighting (see :func:`render_sphere`).
    law : str
        The reflectance law rendered.
    minnaert_k : float or None
        Minnaert's exponent (``law="minnaert"`` only).
    psf : str
        The PSF shape rendered (``"none"`` when no blur).
    psf_sigma_px : float or None
        The PSF's (core) sigma, None when no blur.
    limb : Polyline
        The sunlit half of the geometric limb around the model centre,
        normals into the disc (the bright side), sigmas 1 px:
        :func:`~dtalign.sphere_limb_polyline` of the model centre, radius,
        light direction and ``n_vertices``.
    terminator : Polyline or None
        The visible half of the geometric terminator (``cos i = 0``) around
        the model centre, normals toward the lit side, sigmas 1 px
        (:func:`~dtalign.sphere_terminator_polyline`); None at phase 0,
        where it lies behind the limb.
    """

    image: FloatArray
    noise_sigma: float
    peak_snr: float
    true_offset_vu: tuple[float, float]
    center_vu: tuple[float, float]
    model_center_vu: tuple[float, float]
    radius_px: float
    phase_deg: float
    illumination_deg: float
    law: str
    minnaert_k: float | None
    psf: str
    psf_sigma_px: float | None
    limb: Polyline
    terminator: Polyline | None


def _shade(
    dv: FloatArray, du: FloatArray, radius: float, phase: float, sun: tuple[float, float],
    law: str, k: float, albedo: float,
) -> FloatArray:
    """Radiance at image offsets ``(dv, du)`` from the centre (0 off the disc and in the dark)."""
    rho2 = (dv * dv + du * du) / (radius * radius)
    inside = rho2 < 1.0
    cos_e = np.sqrt(np.where(inside, 1.0 - rho2, 0.0))
    sin_p, cos_p = math.sin(phase), math.cos(phase)
    cos_i = (dv * (sin_p * sun[0]) + du * (sin_p * sun[1])) / radius + cos_e * cos_p
    lit = inside & (cos_i > 0.0)
    ci = np.where(lit, cos_i, 0.0)
    if law == "lambert":
        out = ci
    elif law == "minnaert":
        # For k < 1, cos(e)^(k-1) brightens the limb without bound (an
        # integrable singularity, (1 - rho^2)^((k-1)/2)): the pixel average is
        # finite, and the samples, which never lie on rho = 1, stay finite.
        ce = np.where(lit, cos_e, 1.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            out = np.where(lit, ci**k * ce ** (k - 1.0), 0.0)
    else:  # lommel-seeliger
        with np.errstate(divide="ignore", invalid="ignore"):
            out = np.where(lit, ci / (ci + cos_e), 0.0)
    return albedo * np.where(np.isfinite(out), out, 0.0)


def _gaussian_kernel_1d(sigma: float) -> FloatArray:
    half = max(1, int(math.ceil(_PSF_TRUNCATE * sigma)))
    x = np.arange(-half, half + 1, dtype=np.float64)
    g = np.exp(-0.5 * (x / sigma) ** 2)
    return g / g.sum()


def _blur_fine(fine: FloatArray, sigma_fine: float) -> FloatArray:
    """Separable Gaussian blur of the fine grid (zero outside: the sky)."""
    from scipy.ndimage import convolve1d

    g = _gaussian_kernel_1d(sigma_fine)
    out = convolve1d(fine, g, axis=0, mode="constant", cval=0.0)
    return convolve1d(out, g, axis=1, mode="constant", cval=0.0)


def render_sphere(
    *,
    shape: tuple[int, int] = (300, 300),
    center_vu: tuple[float, float] | None = None,
    radius_px: float = 85.0,
    phase_deg: float = 35.0,
    illumination_deg: float = 0.0,
    offset_vu: tuple[float, float] = (0.0, 0.0),
    law: str = "lambert",
    minnaert_k: float | None = None,
    albedo_dn: float = 200.0,
    background_dn: float = 0.0,
    psf_sigma_px: float | None = None,
    psf: str = "gaussian",
    oversample: int = 8,
    poisson_gain: float | None = None,
    read_noise_dn: float = 0.0,
    seed: int = 0,
    n_vertices: int = 200,
) -> SphereScene:
    """Render a shaded sphere with a planted offset, for accuracy measurements.

    Each pixel ``(i, j)`` (centred at ``(i, j)``) is the mean of
    ``oversample x oversample`` radiance samples over its area; the PSF is
    applied on that fine grid before the average, then background, shot
    noise and read noise are added.

    Geometry (see the profiles page of the docs): a point ``p`` at
    normalised radius ``rho = |p - c| / R`` has the surface normal
    ``N = ((p - c) / R, sqrt(1 - rho^2))`` in ``(v, u, z)``, ``z`` toward the
    viewer, so ``cos e = N_z``; the Sun is ``L = (sin(phase) s, cos(phase))``
    with ``s`` the in-image direction toward the Sun; ``cos i = N . L``.
    Laws (albedo ``A``): Lambert ``A cos i``; Minnaert
    ``A cos(i)^k cos(e)^(k-1)``; Lommel-Seeliger ``A cos i / (cos i + cos e)``.

    Parameters
    ----------
    shape : tuple of int
        Image shape ``(H, W)``.
    center_vu : tuple of float, optional
        The sphere's true centre; the image centre when None.
    radius_px : float
        Radius in pixels, > 0.
    phase_deg : float
        Phase angle in ``[0, 180)`` degrees.
    illumination_deg : float
        In-image direction from the centre toward the Sun: 0 is toward the
        top of the image (-v), 90 toward +u.
    offset_vu : tuple of float
        The planted truth: the model polylines sit at ``center - offset``.
    law : {"lambert", "minnaert", "lommel-seeliger"}
        The reflectance law.
    minnaert_k : float, optional
        Minnaert's exponent, > 0 (``law="minnaert"`` only; 1 is Lambert).
    albedo_dn : float
        ``A`` in DN.
    background_dn : float
        Sky level in DN.
    psf_sigma_px : float, optional
        The PSF's (core) Gaussian sigma in pixels; no blur when None or 0.
    psf : {"gaussian", "core+wings"}
        The PSF shape: a Gaussian, or ``1 - WINGS_FRACTION`` of the light in
        the Gaussian core and the rest in a Gaussian ``WINGS_SCALE`` times wider.
    oversample : int
        Samples per pixel along each axis, >= 1.
    poisson_gain : float, optional
        Electrons per DN for shot noise; no shot noise when None.
    read_noise_dn : float
        Gaussian read noise in DN.
    seed : int
        Seeds the noise (``numpy.random.default_rng``).
    n_vertices : int
        Vertices of each model polyline, >= 2.

    Returns
    -------
    SphereScene
    """
    _check_sphere(law, psf, minnaert_k, phase_deg, radius_px, oversample, n_vertices)
    h, w = int(shape[0]), int(shape[1])
    c = np.asarray(_centre((h, w)) if center_vu is None else center_vu, dtype=np.float64)
    off = np.asarray(offset_vu, dtype=np.float64)
    phase = math.radians(phase_deg)
    sun = sun_direction_vu(illumination_deg)
    k = float(minnaert_k) if minnaert_k is not None else 1.0
    psf_sigma = float(psf_sigma_px) if psf_sigma_px is not None else 0.0
    blur = psf_sigma > 0.0
    # The model polylines first: the builders check the light direction too.
    model_c = c - off
    n = int(n_vertices)
    limb = sphere_limb_polyline(model_c, radius_px, illumination_deg=illumination_deg,
                                n_vertices=n)
    term = (sphere_terminator_polyline(model_c, radius_px, illumination_deg=illumination_deg,
                                       phase_deg=phase_deg, n_vertices=n)
            if phase_deg > 0.0 else None)
    signal = _sphere_signal((h, w), c, radius_px, phase, sun, law, k, albedo_dn,
                            psf if blur else "none", psf_sigma, int(oversample))
    image, noise_sigma, peak_snr = _camera(signal, background_dn, poisson_gain, read_noise_dn,
                                           seed)
    return SphereScene(
        image=np.ascontiguousarray(image, dtype=np.float64),
        noise_sigma=float(noise_sigma),
        peak_snr=float(peak_snr),
        true_offset_vu=(float(off[0]), float(off[1])),
        center_vu=(float(c[0]), float(c[1])),
        model_center_vu=(float(model_c[0]), float(model_c[1])),
        radius_px=float(radius_px),
        phase_deg=float(phase_deg),
        illumination_deg=float(illumination_deg),
        law=law,
        minnaert_k=None if minnaert_k is None else float(minnaert_k),
        psf=psf if blur else "none",
        psf_sigma_px=psf_sigma if blur else None,
        limb=limb,
        terminator=term,
    )


def _check_sphere(law: str, psf: str, minnaert_k: float | None, phase_deg: float,
                  radius_px: float, oversample: int, n_vertices: int) -> None:
    """:func:`render_sphere`'s argument checks."""
    if law not in SPHERE_LAWS:
        raise ValueError(f"law must be one of {SPHERE_LAWS}, got {law!r}")
    if psf not in SPHERE_PSFS:
        raise ValueError(f"psf must be one of {SPHERE_PSFS}, got {psf!r}")
    if law == "minnaert":
        if minnaert_k is None or not minnaert_k > 0.0:
            raise ValueError(f"minnaert_k must be > 0 with law='minnaert', got {minnaert_k!r}")
    elif minnaert_k is not None:
        raise ValueError("minnaert_k is only used with law='minnaert'")
    if not 0.0 <= phase_deg < 180.0:
        raise ValueError(f"phase_deg must be in [0, 180), got {phase_deg!r}")
    if not radius_px > 0.0:
        raise ValueError(f"radius_px must be > 0, got {radius_px!r}")
    if int(oversample) != oversample or oversample < 1:
        raise ValueError(f"oversample must be an int >= 1, got {oversample!r}")
    if int(n_vertices) != n_vertices or n_vertices < 2:
        raise ValueError(f"n_vertices must be an int >= 2, got {n_vertices!r}")


def _sphere_signal(shape: tuple[int, int], c: FloatArray, radius_px: float, phase: float,
                   sun: tuple[float, float], law: str, k: float, albedo_dn: float, psf: str,
                   psf_sigma: float, os_: int) -> FloatArray:
    """The noiseless sphere in DN: shaded on the fine grid, blurred (``psf`` not
    ``"none"``), then averaged over each pixel's ``os_ x os_`` samples."""
    h, w = shape
    # Shade only a box around the disc, widened by the PSF's reach.
    reach = (_PSF_TRUNCATE * psf_sigma * (WINGS_SCALE if psf == "core+wings" else 1.0)
             if psf != "none" else 0.0)
    margin = radius_px + reach + 2.0
    i0, i1 = max(0, int(math.floor(c[0] - margin))), min(h, int(math.ceil(c[0] + margin)) + 1)
    j0, j1 = max(0, int(math.floor(c[1] - margin))), min(w, int(math.ceil(c[1] + margin)) + 1)
    sub = (np.arange(os_) + 0.5) / os_ - 0.5
    fv = (np.arange(i0, i1)[:, None] + sub[None, :]).ravel()
    fu = (np.arange(j0, j1)[:, None] + sub[None, :]).ravel()
    fine = _shade(fv[:, None] - c[0], fu[None, :] - c[1], radius_px, phase, sun, law, k,
                  albedo_dn)
    sig = psf_sigma * os_
    if psf == "gaussian":
        fine = _blur_fine(fine, sig)
    elif psf == "core+wings":
        fine = ((1.0 - WINGS_FRACTION) * _blur_fine(fine, sig)
                + WINGS_FRACTION * _blur_fine(fine, WINGS_SCALE * sig))
    signal = np.zeros((h, w))
    signal[i0:i1, j0:j1] = fine.reshape(i1 - i0, os_, j1 - j0, os_).mean(axis=(1, 3))
    return signal


def _camera(signal: FloatArray, background_dn: float, poisson_gain: float | None,
            read_noise_dn: float, seed: int) -> tuple[FloatArray, float, float]:
    """The signal on the sky level with shot and read noise: the image, the noise
    sigma of the background, and the peak's signal-to-noise ratio."""
    clean = signal + background_dn
    rng = np.random.default_rng(seed)
    image = clean
    if poisson_gain is not None:
        image = rng.poisson(np.maximum(clean, 0.0) * poisson_gain) / poisson_gain
    if read_noise_dn > 0.0:
        image = image + rng.normal(0.0, read_noise_dn, signal.shape)
    shot_bg = background_dn / poisson_gain if poisson_gain is not None else 0.0
    noise_sigma = math.sqrt(read_noise_dn**2 + max(shot_bg, 0.0))
    peak = float(signal.max())
    shot_peak = (peak + background_dn) / poisson_gain if poisson_gain is not None else 0.0
    peak_noise = math.sqrt(read_noise_dn**2 + max(shot_peak, 0.0))
    peak_snr = peak / peak_noise if peak_noise > 0.0 else math.inf
    return image, noise_sigma, peak_snr


#: The defects :func:`add_defects` plants.
DEFECTS = ("saturated_blob", "cosmic_rays", "missing_line", "missing_line_nan")


def add_defects(
    image: ArrayLike, kind: str, *, limb_center_vu: tuple[float, float], limb_radius_px: float,
    saturation_dn: float = 250.0, blob_at_deg: float = 30.0, seed: int = 0,
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """A copy of ``image`` with bad pixels planted on a circular limb, and their mask.

    Parameters
    ----------
    image : array_like, shape (H, W)
        The clean image (a :func:`disc_scene` or :func:`render_sphere` one).
    kind : str
        One of :data:`DEFECTS`:

        * ``"saturated_blob"``: the pixels within 6 px of the limb point at
          ``blob_at_deg`` set to ``saturation_dn``;
        * ``"cosmic_rays"``: 300 hits anywhere and 80 within 3 px of the
          limb, each 1 or 2 pixels along a row, adding 200-1000 DN;
        * ``"missing_line"``: the row half a radius below the centre,
          which crosses the limb twice, zero-filled;
        * ``"missing_line_nan"``: the same row set to NaN.
    limb_center_vu, limb_radius_px
        The limb the defects sit on, in image pixels.
    saturation_dn : float
        The blob's value.
    blob_at_deg : float
        Where on the limb the blob sits: the angle from +v toward +u, deg.
    seed : int
        Seeds the cosmic rays.

    Returns
    -------
    image : ndarray, shape (H, W)
        The damaged copy (float64).
    mask : ndarray of bool, shape (H, W)
        True on every planted bad pixel: what to pass as ``mask``.
    """
    img = np.array(image, dtype=np.float64)
    h, w = img.shape
    cv, cu = (float(c) for c in limb_center_vu)
    radius = float(limb_radius_px)
    mask = np.zeros((h, w), dtype=bool)
    if kind == "saturated_blob":
        vv, uu = np.mgrid[0:h, 0:w]
        phi = np.radians(blob_at_deg)
        mask = (vv - cv - radius * np.cos(phi)) ** 2 + (uu - cu - radius * np.sin(phi)) ** 2 <= 36.0
        img[mask] = saturation_dn
    elif kind == "cosmic_rays":
        rng = np.random.default_rng(seed)
        phi = rng.uniform(0.0, 2.0 * np.pi, 80)
        r = radius + rng.uniform(-3.0, 3.0, 80)
        rows = np.r_[rng.integers(0, h, 300), np.rint(cv + r * np.cos(phi)).astype(int)]
        cols = np.r_[rng.integers(0, w, 300), np.rint(cu + r * np.sin(phi)).astype(int)]
        for a, b, n in zip(rows, cols, rng.integers(1, 3, rows.size), strict=True):
            mask[a, b : b + n] = True
        img[mask] += rng.uniform(200.0, 1000.0, int(mask.sum()))
    elif kind in ("missing_line", "missing_line_nan"):
        mask[int(round(cv + 0.5 * radius))] = True
        img[mask] = 0.0 if kind == "missing_line" else np.nan
    else:
        raise ValueError(f"kind must be one of {DEFECTS}, got {kind!r}")
    return img, mask
