"""Photometric edge profiles: what the image should look like across each edge vertex.

* :class:`EdgeProfile`: per-vertex predicted radiance along each vertex's
  unit normal, on one shared grid of offsets (the geometric edge at 0);
* :func:`sphere_edge_profile`: the profile of a sphere's limb or terminator
  under the Lambert, Minnaert or Lommel-Seeliger law, from the geometry of
  the profiles page of the docs (:ref:`profiles`).

The profile is the sharp radiance: the fit
(:mod:`dtalign.pipeline.profile_fit`) applies the pixel's area average and
the PSF itself, so one profile serves every sub-pixel position and normal
direction. Nothing here imports Numba.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import checks as check

__all__ = ["EDGE_KINDS", "SPHERE_LAWS", "EdgeProfile", "sphere_edge_profile"]

FloatArray = NDArray[np.float64]

#: Edge kinds a profile may name (``"other"`` for anything else a technique models).
EDGE_KINDS = ("limb", "terminator", "ring", "other")

#: Reflectance laws of :func:`sphere_edge_profile`.
SPHERE_LAWS = ("lambert", "minnaert", "lommel-seeliger")

#: Default sample spacing of a sphere profile along the normal, pixels: the
#: profile is piecewise linear between samples; each sample is the mean over
#: its cell (exact integral of a jump), so the spacing adds only a symmetric
#: blur of variance ~h^2/4, negligible beside the pixel's 1/12.
SPHERE_PROFILE_STEP_PX = 0.1

#: Default half-range of a sphere profile, pixels: the fit reads pixels up to
#: its half-width plus its walk, the pixel box and 4 PSF sigmas from the edge.
SPHERE_PROFILE_HALF_RANGE_PX = 12.0

#: Sub-samples per profile cell of :func:`sphere_edge_profile` (the cell mean
#: of the limb's jump and square-root rise).
_SUBSAMPLES = 4


@dataclass(frozen=True, eq=False)
class EdgeProfile:
    """Predicted image brightness across each vertex of a polyline.

    Attributes
    ----------
    offsets_px : ndarray, shape (M,)
        Offsets along each vertex's normal, pixels, increasing with one
        constant step, M >= 4; the geometric edge is at offset 0 (the
        vertex). Positive offsets lie on the side the normal points to.
    values : ndarray, shape (N, M)
        The sharp radiance (no PSF, no pixel average) at each vertex and
        offset, any units (the fit has a free gain and background);
        piecewise linear between samples. A jump is best sampled as cell
        means (each value the mean over its cell), as
        :func:`sphere_edge_profile` does.
    normals_vu : ndarray, shape (N, 2)
        The unit normal each profile runs along.
    curvature_px : ndarray, shape (N,)
        Signed curvature of the edge at each vertex, 1/pixels: positive
        when the edge bends toward the normal's side (a limb with normals
        into the disc: ``1 / R``), 0 for a straight edge.
    psf_sigma_px : float or None
        The image's Gaussian PSF sigma, pixels (0 for none); None when
        unknown: the fit then estimates it.
    edge : str
        What kind of edge it is (:data:`EDGE_KINDS`).
    shape_values : ndarray, shape (N, M), or None
        An optional shape basis: the fit models the radiance as ``values +
        a * shape_values`` with the amplitude ``a`` fitted, so a model that
        is uncertain in one direction (a sphere's reflectance law:
        :func:`sphere_edge_profile` gives the first-order change of the
        limb darkening) is fitted along it. None: the profile is fitted as
        given.
    step_jump : ndarray, shape (N,)
        Fraction of each vertex's contrast that is a step at the edge:
        the profile's change across the edge's cell over its full range
        within ``PROFILE_HALF_WIDTH_PX``; near 0 for a soft roll-off (a
        limb at low phase) that puts the edge nowhere in particular.
        Computed, not given.

    Instances are read-only and compare by identity.
    """

    offsets_px: FloatArray
    values: FloatArray
    normals_vu: FloatArray
    curvature_px: FloatArray
    psf_sigma_px: float | None = None
    edge: str = "other"
    shape_values: FloatArray | None = field(default=None, repr=False)
    step_jump: FloatArray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        offsets = check.as_float_array(self.offsets_px, "offsets_px")
        if offsets.ndim != 1 or offsets.shape[0] < 4:
            raise ValueError(f"offsets_px must have shape (M,) with M >= 4, got {offsets.shape}")
        check.require_finite(offsets, "offsets_px")
        step = np.diff(offsets)
        h = float(step.mean())
        if not h > 0.0 or np.abs(step - h).max() > 1e-6 * max(h, 1.0):
            raise ValueError("offsets_px must increase with one constant step")
        if not offsets[0] < 0.0 < offsets[-1]:
            raise ValueError("offsets_px must straddle the edge at 0")
        values = check.as_float_array(self.values, "values")
        if values.ndim != 2 or values.shape[1] != offsets.shape[0] or values.shape[0] == 0:
            raise ValueError(
                f"values must have shape (N, {offsets.shape[0]}) with N > 0, got {values.shape}"
            )
        check.require_finite(values, "values")
        n = values.shape[0]
        normals = check.as_float_array(self.normals_vu, "normals_vu")
        if normals.shape != (n, 2):
            raise ValueError(f"normals_vu must have shape ({n}, 2), got {normals.shape}")
        check.require_finite(normals, "normals_vu")
        if np.abs(np.hypot(normals[:, 0], normals[:, 1]) - 1.0).max() > 1e-6:
            raise ValueError("normals_vu must be unit vectors")
        curvature = check.as_float_array(self.curvature_px, "curvature_px")
        if curvature.shape != (n,):
            raise ValueError(f"curvature_px must have shape ({n},), got {curvature.shape}")
        check.require_finite(curvature, "curvature_px")
        psf = self.psf_sigma_px
        if psf is not None:
            psf = check.nonnegative_real(psf, "psf_sigma_px")
        if not isinstance(self.edge, str) or self.edge not in EDGE_KINDS:
            raise ValueError(f"edge must be one of {EDGE_KINDS}, got {self.edge!r}")
        if self.shape_values is not None:
            shape = check.as_float_array(self.shape_values, "shape_values")
            if shape.shape != values.shape:
                raise ValueError(
                    f"shape_values must have the shape of values {values.shape}, got {shape.shape}"
                )
            check.require_finite(shape, "shape_values")
            object.__setattr__(self, "shape_values", check.readonly(shape))
        object.__setattr__(self, "offsets_px", check.readonly(offsets))
        object.__setattr__(self, "values", check.readonly(values))
        object.__setattr__(self, "normals_vu", check.readonly(normals))
        object.__setattr__(self, "curvature_px", check.readonly(curvature))
        object.__setattr__(self, "psf_sigma_px", psf)
        object.__setattr__(self, "step_jump", check.readonly(_step_jump(offsets, values)))

    @property
    def n_vertices(self) -> int:
        """N, the number of vertices."""
        return int(self.values.shape[0])

    @property
    def step_px(self) -> float:
        """The offsets' step, pixels."""
        return float(self.offsets_px[1] - self.offsets_px[0])


#: Half-width (pixels) over which :attr:`EdgeProfile.step_jump` compares
#: the step at the edge with the full contrast: the fit's own half-width.
STEP_JUMP_HALF_WIDTH_PX = 3.5


def _step_jump(offsets: FloatArray, values: FloatArray) -> FloatArray:
    h = offsets[1] - offsets[0]
    j = int(np.searchsorted(offsets, 0.0))  # first offset >= 0
    lo, hi = max(j - 2, 0), min(j + 1, offsets.shape[0] - 1)
    near = np.abs(offsets) <= STEP_JUMP_HALF_WIDTH_PX + 0.5 * h
    span = values[:, near].max(axis=1) - values[:, near].min(axis=1)
    jump = np.abs(values[:, hi] - values[:, lo])
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(span > 0.0, jump / np.where(span > 0.0, span, 1.0), 0.0)
    return np.asarray(np.clip(out, 0.0, 1.0), dtype=np.float64)


def _law_radiance(cos_i: FloatArray, cos_e: FloatArray, inside: NDArray[np.bool_], law: str,
                  k: float) -> tuple[FloatArray, FloatArray]:
    """Radiance (albedo 1) under ``law`` from ``cos i`` and ``cos e`` (0 outside the body and
    on the night side), and its derivative along Minnaert's exponent, ``I ln(cos i cos e)``."""
    lit = inside & (cos_i > 0.0)
    ci = np.where(lit, cos_i, 0.0)
    if law == "lambert":
        out = ci
    elif law == "minnaert":
        ce = np.where(lit, np.maximum(cos_e, 1e-300), 1.0)
        out = np.where(lit, ci**k * ce ** (k - 1.0), 0.0)
    else:
        out = np.where(lit, ci / np.where(lit, ci + cos_e, 1.0), 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        dk = np.where(lit, out * np.log(np.where(lit, ci * np.maximum(cos_e, 1e-300), 1.0)), 0.0)
    return np.asarray(out, dtype=np.float64), np.asarray(dk, dtype=np.float64)


def _sphere_radiance(pv: FloatArray, pu: FloatArray, center: tuple[float, float], radius: float,
                     phase: float, sun: tuple[float, float], law: str, k: float
                     ) -> tuple[FloatArray, FloatArray]:
    """:func:`_law_radiance` of the sphere at image points."""
    qv = (pv - center[0]) / radius
    qu = (pu - center[1]) / radius
    rho2 = qv * qv + qu * qu
    cos_e = np.sqrt(np.clip(1.0 - rho2, 0.0, None))
    cos_i = math.sin(phase) * (qv * sun[0] + qu * sun[1]) + math.cos(phase) * cos_e
    return _law_radiance(cos_i, cos_e, rho2 < 1.0, law, k)


def _terminator_geometry(rel: FloatArray, radius: float, phase: float,
                         sun: tuple[float, float]) -> tuple[FloatArray, FloatArray]:
    """Normals up ``grad cos i`` and the curvature of the terminator's ellipse
    (semi-axes ``R`` and ``R |cos phase|``) at vertices ``rel`` (from the
    centre, in radii)."""
    rho2 = np.clip((rel**2).sum(axis=1), 0.0, 1.0 - 1e-12)
    grad = (math.sin(phase) * np.asarray(sun)[None, :]
            - math.cos(phase) * rel / np.sqrt(1.0 - rho2)[:, None])
    size = np.hypot(grad[:, 0], grad[:, 1])
    if not (size > 0.0).all():
        raise ValueError("a terminator vertex lies at the sub-solar point: cos i has no "
                         "gradient there, so no normal")
    perp = np.array([-sun[1], sun[0]])
    cos_t = np.clip(rel @ perp, -1.0, 1.0)
    sin_t2 = 1.0 - cos_t**2
    a, b = radius, radius * abs(math.cos(phase))
    curvature = (math.copysign(1.0, math.cos(phase)) * a * b
                 / (a * a * sin_t2 + b * b * cos_t**2) ** 1.5)
    return grad / size[:, None], np.asarray(curvature, dtype=np.float64)


def _law_args(law: Any, minnaert_k: Any, psf_sigma_px: Any, step_px: Any, half_range_px: Any
              ) -> tuple[float, float | None, float, float]:
    """The law's and the grid's arguments of a body's edge profile, checked:
    ``(minnaert_k or 1, psf_sigma_px, step_px, half_range_px)``."""
    if law not in SPHERE_LAWS:
        raise ValueError(f"law must be one of {SPHERE_LAWS}, got {law!r}")
    if law == "minnaert":
        if minnaert_k is None:
            raise ValueError("minnaert_k is required with law='minnaert'")
        k = check.positive_real(minnaert_k, "minnaert_k")
    elif minnaert_k is not None:
        raise ValueError("minnaert_k is only used with law='minnaert'")
    else:
        k = 1.0
    psf = None if psf_sigma_px is None else check.nonnegative_real(psf_sigma_px, "psf_sigma_px")
    h = check.positive_real(step_px, "step_px")
    half = check.positive_real(half_range_px, "half_range_px")
    if half < 4.0 * h:
        raise ValueError("half_range_px must be at least 4 * step_px")
    return k, psf, h, half


def _cell_means(verts: FloatArray, normals: FloatArray,
                radiance: Callable[[FloatArray, FloatArray], tuple[FloatArray, FloatArray]],
                h: float, half: float, fit_law: bool
                ) -> tuple[FloatArray, FloatArray, FloatArray | None]:
    """The offsets grid (``h`` apart, the edge midway between two cells, ``half`` each way)
    and the cell means along each vertex's normal of ``radiance(pv, pu) -> (I, dI/dk)``:
    ``(offsets, values, shape basis or None)``."""
    n_half = int(math.ceil(half / h))
    offsets = np.asarray((np.arange(-n_half, n_half) + 0.5) * h, dtype=np.float64)
    sub = (np.arange(_SUBSAMPLES) + 0.5) / _SUBSAMPLES - 0.5
    along = (offsets[:, None] + h * sub[None, :]).ravel()
    pv = verts[:, 0:1] + along[None, :] * normals[:, 0:1]
    pu = verts[:, 1:2] + along[None, :] * normals[:, 1:2]
    rad, dk = radiance(pv, pu)
    shape = (verts.shape[0], offsets.shape[0], _SUBSAMPLES)
    values = rad.reshape(shape).mean(axis=2)
    basis = dk.reshape(shape).mean(axis=2) if fit_law else None
    return offsets, values, basis


def sphere_edge_profile(
    vertices_vu: ArrayLike,
    *,
    center_vu: Any,
    radius_px: float,
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
    """The edge profile of a shaded sphere's limb or terminator at each vertex.

    Physics and conventions: :ref:`profiles`. A point ``p`` at normalised
    radius ``rho = |p - c| / R`` has the surface normal ``((p - c) / R,
    sqrt(1 - rho^2))``, ``cos e`` its last component; the Sun is ``L =
    (sin(phase) s, cos(phase))`` with ``s = (-cos(ill), sin(ill))`` the
    in-image direction toward the Sun; ``cos i = N . L``. Radiance with
    albedo 1: Lambert ``cos i``, Minnaert ``cos(i)^k cos(e)^(k - 1)``,
    Lommel-Seeliger ``cos i / (cos i + cos e)``; 0 off the disc and where
    ``cos i <= 0``. Each value is the mean of the radiance over its cell
    of the offsets grid along the normal.

    Parameters
    ----------
    vertices_vu : array_like, shape (N, 2)
        Vertices on the model edge (the sphere's limb or terminator).
    center_vu : tuple of float
        The model sphere's centre.
    radius_px : float
        Its radius, pixels, > 0.
    phase_deg : float
        Phase angle, degrees, in [0, 180).
    illumination_deg : float
        In-image direction from the centre toward the Sun: 0 toward -v
        (up), 90 toward +u.
    edge : {"limb", "terminator"}
        Which edge the vertices lie on. Limb normals point into the disc
        (curvature ``1 / R``); terminator normals point toward the lit side
        (the gradient of ``cos i``), its curvature that of the projected
        ellipse (semi-axes ``R`` and ``R |cos phase|``).
    law : {"lambert", "minnaert", "lommel-seeliger"}
    minnaert_k : float, optional
        Minnaert's exponent, > 0 (``law="minnaert"`` only).
    psf_sigma_px : float, optional
        The image's Gaussian PSF sigma, >= 0; None when unknown (the fit
        estimates it).
    fit_law : bool, optional
        Give the profile a shape basis (``EdgeProfile.shape_values``):
        the first-order change of the radiance with Minnaert's exponent,
        ``I ln(cos i cos e)``, so the fit adjusts the limb darkening when
        the law is not quite right (True, the default); False fits the law
        exactly as given.
    step_px, half_range_px : float, optional
        The offsets grid: ``step_px`` apart, the geometric edge midway
        between two samples' cells, reaching ``half_range_px`` each way.

    Returns
    -------
    EdgeProfile

    Raises
    ------
    ValueError
        On a malformed argument (the message names it), or a terminator at
        phase 0 (there is none).
    """
    verts = check.vertices(vertices_vu, "vertices_vu", allow_empty=False)
    center = check.pair(center_vu, "center_vu")
    radius = check.positive_real(radius_px, "radius_px")
    phase_d = check.finite_real(phase_deg, "phase_deg")
    if not 0.0 <= phase_d < 180.0:
        raise ValueError(f"phase_deg must be in [0, 180), got {phase_d!r}")
    ill = math.radians(check.finite_real(illumination_deg, "illumination_deg"))
    if edge not in ("limb", "terminator"):
        raise ValueError(f"edge must be 'limb' or 'terminator', got {edge!r}")
    k, psf, h, half = _law_args(law, minnaert_k, psf_sigma_px, step_px, half_range_px)
    phase = math.radians(phase_d)
    sun = (-math.cos(ill), math.sin(ill))
    cvec = np.asarray(center)
    rel = (verts - cvec) / radius
    if edge == "limb":
        dist = np.hypot(rel[:, 0], rel[:, 1])
        if (dist == 0.0).any():
            raise ValueError("a limb vertex lies at center_vu: it has no normal")
        normals = -rel / dist[:, None]
        curvature = np.full(verts.shape[0], 1.0 / radius)
    else:
        if phase_d == 0.0:
            raise ValueError("a sphere at phase 0 has no terminator")
        normals, curvature = _terminator_geometry(rel, radius, phase, sun)
    offsets, values, basis = _cell_means(
        verts, normals, lambda pv, pu: _sphere_radiance(pv, pu, center, radius, phase, sun, law, k),
        h, half, fit_law)
    return EdgeProfile(offsets_px=offsets, values=values, normals_vu=normals,
                       curvature_px=curvature, psf_sigma_px=psf, edge=edge, shape_values=basis)
