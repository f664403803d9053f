"""Model polylines: the :class:`Polyline` record and a sphere's limb and terminator.

* :class:`Polyline`: what belongs to one model polyline -- its vertices,
  the unit normals pointing to the bright side of the edge, the prior
  sigmas, the kind of edge and, optionally, its edge profile -- in the
  form every batch entry point reads (``vertices_vu``, ``normals_vu``,
  ``sigmas``, ``edge_kind`` and ``edge_profile`` attributes);
* :func:`sphere_limb_polyline` and :func:`sphere_terminator_polyline`: the
  geometric limb and terminator of a sphere, with the normals the polarity
  test needs (into the disc for a limb, toward the day side for a
  terminator: the guide's *Normals*) and the geometry conventions of
  :func:`~dtalign.sphere_edge_profile` and :func:`dtalign.scenes.render_sphere`
  (which builds its model polylines with these functions).

Conventions (:ref:`profiles`): image coordinates are ``(v, u)`` pixel
indices; ``illumination_deg`` is the in-image direction from the centre
toward the Sun, 0 toward -v (the top of the image), 90 toward +u, so the
unit vector toward the Sun is :func:`sun_direction_vu`, ``s = (-cos(ill),
sin(ill))``; ``phase_deg`` is the phase angle in [0, 180).

These are geometry only: the vertices and normals a navigation model
predicts. The brightness across the edges is
:func:`~dtalign.sphere_edge_profile`'s, and the renderer that measures
accuracy (:func:`dtalign.scenes.render_sphere`) shades its images with its
own code. Nothing here imports Numba.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from . import checks as check
from .profiles import EDGE_KINDS, EdgeProfile

__all__ = [
    "DEFAULT_POLYLINE_SIGMA_PX", "DEFAULT_POLYLINE_VERTICES", "Polyline",
    "sphere_limb_polyline", "sphere_terminator_polyline", "sun_direction_vu",
]

FloatArray = NDArray[np.float64]

#: Vertices of a built polyline unless told otherwise: the count of
#: :func:`dtalign.scenes.render_sphere`'s polylines and of every measurement
#: of the docs' profile and terminator tables (spacing about 1.3 px on the
#: lit half of a limb of radius 85 px).
DEFAULT_POLYLINE_VERTICES = 200

#: Prior one-sigma of each built vertex along its normal, pixels: what
#: :mod:`dtalign.scenes` and the docs' tables use. It weighs the vertices
#: against each other (and scales the Tukey cutoff, 4.685 sigmas); a model
#: with a known per-vertex error replaces the polyline's ``sigmas``.
DEFAULT_POLYLINE_SIGMA_PX = 1.0


@dataclass(frozen=True)
class Polyline:
    """A model polyline: vertices, normals to the bright side, sigmas, its kind of edge.

    The record :func:`sphere_limb_polyline`, :func:`sphere_terminator_polyline`,
    :mod:`dtalign.scenes` and :func:`dtalign.io.load_polyline_csv` return and
    :func:`dtalign.pipeline.batch.fit_many` (and ``fit_images``) take as a
    polyline. The arrays are kept as given; every fitting function checks
    and converts them once, as it does plain arrays.

    Attributes
    ----------
    name : str
        A label (``"limb"``, a file's stem, ...): printed, plotted, not used
        by the fit.
    vertices_vu : ndarray, shape (N, 2)
        The vertices, ``(v, u)`` pixels.
    normals_vu : ndarray, shape (N, 2)
        Unit normals pointing to the **bright side** of the edge (into the
        disc for a limb, toward the day side for a terminator): the
        polarity test keeps a vertex only where its normal points up the
        image gradient (the guide's *Normals*).
    sigmas : ndarray, shape (N,)
        Prior one-sigma of each vertex along its normal, pixels, > 0.
    edge_kind : str or None
        What kind of edge it is, one of :data:`~dtalign.api.profiles.EDGE_KINDS`
        (``"limb"``, ``"terminator"``, ``"ring"``, ``"other"``); None: not
        declared. The batch fits it as :attr:`FitOptions.edge_kind
        <dtalign.FitOptions>` says (a ``"terminator"`` without a profile is
        flagged, its pose's floor is a terminator's).
    edge_profile : EdgeProfile or None
        The predicted brightness across each vertex
        (:func:`~dtalign.sphere_edge_profile`); the batch refines the fit
        with it. None: a plain DT fit. Add one with
        ``dataclasses.replace(polyline, edge_profile=profile)``.

    Raises
    ------
    ValueError
        If ``edge_kind`` is not an edge kind.
    TypeError
        If ``edge_profile`` is neither None nor an :class:`~dtalign.EdgeProfile`.
    """

    name: str
    vertices_vu: FloatArray
    normals_vu: FloatArray
    sigmas: FloatArray
    edge_kind: str | None = None
    edge_profile: EdgeProfile | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        kind = self.edge_kind
        if kind is not None and (not isinstance(kind, str) or kind not in EDGE_KINDS):
            raise ValueError(f"edge_kind must be one of {EDGE_KINDS} or None, got {kind!r}")
        if self.edge_profile is not None and not isinstance(self.edge_profile, EdgeProfile):
            raise TypeError(f"edge_profile must be an EdgeProfile or None, "
                            f"got {type(self.edge_profile).__name__}")

    def __len__(self) -> int:
        return int(self.vertices_vu.shape[0])


def sun_direction_vu(illumination_deg: float) -> tuple[float, float]:
    """Unit in-image direction toward the Sun: 0 deg is -v (up), 90 deg is +u."""
    a = math.radians(illumination_deg)
    return -math.cos(a), math.sin(a)


def _count(value: Any, name: str) -> int:
    """An int >= 2 (bool refused): a polyline of one vertex has no direction to fit."""
    n = check.count(value, name)
    if n < 2:
        raise ValueError(f"{name} must be an int >= 2, got {n}")
    return n


def _flag(value: Any, name: str) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name} must be True or False, got {type(value).__name__}")
    return bool(value)


def _phase(value: Any) -> float:
    out = check.finite_real(value, "phase_deg")
    if not 0.0 <= out < 180.0:
        raise ValueError(f"phase_deg must be in [0, 180), got {out!r}")
    return out


def _limb_directions(illumination_deg: Any, phase_deg: Any, sunlit_only: Any,
                     n_vertices: Any) -> FloatArray:
    """The limb's vertex directions, checked arguments: unit in-image vectors ``r`` at the
    centres of equal arcs of angle, over the half facing the Sun (``r . s > 0``) or the
    whole turn from opposite the Sun; counter-clockwise on the displayed image."""
    lit_half = _flag(sunlit_only, "sunlit_only")
    if illumination_deg is None:
        if lit_half:
            raise ValueError("illumination_deg is required with sunlit_only=True (the lit half "
                             "faces the Sun); pass sunlit_only=False for the whole limb")
        ill = 0.0
    else:
        ill = check.finite_real(illumination_deg, "illumination_deg")
    if phase_deg is not None:
        _phase(phase_deg)
    n = _count(n_vertices, "n_vertices")
    s = np.asarray(sun_direction_vu(ill))
    perp = np.array([-s[1], s[0]])
    # theta from the sub-solar point, at the centres of n equal arcs
    if lit_half:
        theta = -0.5 * math.pi + math.pi * (np.arange(n) + 0.5) / n
    else:
        theta = -math.pi + 2.0 * math.pi * (np.arange(n) + 0.5) / n
    return np.asarray(np.cos(theta)[:, None] * s[None, :] + np.sin(theta)[:, None] * perp[None, :],
                      dtype=np.float64)


def _terminator_args(illumination_deg: Any, phase_deg: Any, n_vertices: Any
                     ) -> tuple[float, float, int]:
    """A terminator's ``illumination_deg``, ``phase_deg`` (> 0) and ``n_vertices``, checked."""
    ill = check.finite_real(illumination_deg, "illumination_deg")
    phase_d = _phase(phase_deg)
    if phase_d == 0.0:
        raise ValueError("phase_deg must be > 0 for a terminator: at phase 0 it lies behind "
                         "the limb")
    return ill, phase_d, _count(n_vertices, "n_vertices")


def _terminator_angles(n: int) -> FloatArray:
    """The great circle's angles of a terminator's ``n`` vertices: the centres of ``n``
    equal steps of ``(-pi, 0)``, the visible half (none on the cusps)."""
    return np.asarray(-math.pi + math.pi * (np.arange(n) + 0.5) / n, dtype=np.float64)


def sphere_limb_polyline(
    center_vu: Any,
    radius_px: float,
    *,
    illumination_deg: float | None = None,
    phase_deg: float | None = None,
    sunlit_only: bool = True,
    n_vertices: int = DEFAULT_POLYLINE_VERTICES,
    sigma: float = DEFAULT_POLYLINE_SIGMA_PX,
) -> Polyline:
    """The geometric limb of a sphere: the circle of ``radius_px`` about ``center_vu``.

    By default the sunlit half: the arc facing the Sun, ``r . s > 0`` with
    ``r`` the unit radius and ``s`` the Sun's in-image direction. There the
    disc is bright against the sky and the limb has contrast; the other
    half borders the night side, dark on both sides, and has no edge to
    find. The normals point **into the disc**, the bright side, as the
    polarity test needs: ``-r`` at each vertex.

    Parameters
    ----------
    center_vu : tuple of float
        The model sphere's centre, ``(v, u)`` pixels.
    radius_px : float
        Its radius, pixels, > 0.
    illumination_deg : float, optional
        In-image direction from the centre toward the Sun: 0 toward -v
        (up), 90 toward +u. Required with ``sunlit_only=True``; with
        ``sunlit_only=False`` it only sets where the circle starts (None:
        as 0).
    phase_deg : float, optional
        The phase angle, degrees, in [0, 180): checked, not otherwise used.
        At every phase the lit part of the limb is the half facing the Sun
        (at the limb ``cos i = sin(phase) r . s``); at phase 0 the whole
        limb is lit, and the half facing ``illumination_deg`` is still the
        one returned (as :func:`dtalign.scenes.render_sphere` does).
        Accepted so that one set of keywords (``center_vu``, ``radius_px``,
        ``phase_deg``, ``illumination_deg``) builds a limb, a terminator
        and their :func:`~dtalign.sphere_edge_profile`.
    sunlit_only : bool, optional
        True (default): the sunlit half. False: the whole circle (a disc
        lit from the front, a silhouette against a bright background).
    n_vertices : int, optional
        Vertices, >= 2, evenly spaced in angle at the centres of equal
        arcs (so none lies on the lit half's ends, where the limb meets
        the terminator).
    sigma : float, optional
        Every vertex's prior one-sigma along its normal, pixels, > 0.

    Returns
    -------
    Polyline
        ``name`` and ``edge_kind`` ``"limb"``. The vertices run
        counter-clockwise on the displayed image (v down, u right): for
        the Sun at the top, the sunlit half from its right end over the
        top to its left end; the whole circle starts opposite the Sun.

    Raises
    ------
    TypeError
        If a number is not a real number (``n_vertices`` not an int,
        ``sunlit_only`` not a bool); the message names the argument.
    ValueError
        If a value is out of range or ``illumination_deg`` is missing with
        ``sunlit_only=True``; the message names the argument.

    Examples
    --------
    >>> from dtalign import sphere_limb_polyline
    >>> limb = sphere_limb_polyline((150.0, 150.0), 85.0, illumination_deg=0.0, n_vertices=5)
    >>> limb.vertices_vu[2].tolist()   # the sub-solar point: the Sun is up (-v)
    [65.0, 150.0]
    >>> limb.edge_kind, len(limb)
    ('limb', 5)
    """
    center = np.asarray(check.pair(center_vu, "center_vu"))
    radius = check.positive_real(radius_px, "radius_px")
    radial = _limb_directions(illumination_deg, phase_deg, sunlit_only, n_vertices)
    sig = check.positive_real(sigma, "sigma")
    return Polyline("limb", center[None, :] + radius * radial, -radial,
                    np.full(radial.shape[0], sig), edge_kind="limb")


def sphere_terminator_polyline(
    center_vu: Any,
    radius_px: float,
    *,
    illumination_deg: float,
    phase_deg: float,
    n_vertices: int = DEFAULT_POLYLINE_VERTICES,
    sigma: float = DEFAULT_POLYLINE_SIGMA_PX,
) -> Polyline:
    """The visible half of a sphere's geometric terminator, normals toward the day side.

    The terminator is the great circle ``N . L = 0`` between day and night;
    seen from the viewer, the half on the near side (``N_z >= 0``) projects
    to half an ellipse of semi-axes ``R`` (across the Sun's direction) and
    ``R |cos phase|`` (along it), from one end of the lit limb to the
    other. The other half lies on the far side of the sphere, not in the
    image, so it is never returned. The normals point **toward the day
    side**, up the gradient of ``cos i`` (the bright side, as the polarity
    test needs): the direction :func:`~dtalign.sphere_edge_profile` gives a
    terminator's profile.

    Parameters
    ----------
    center_vu : tuple of float
        The model sphere's centre, ``(v, u)`` pixels.
    radius_px : float
        Its radius, pixels, > 0.
    illumination_deg : float
        In-image direction from the centre toward the Sun: 0 toward -v
        (up), 90 toward +u.
    phase_deg : float
        The phase angle, degrees, in (0, 180): below 90 the terminator
        bulges away from the Sun (a gibbous body), above 90 toward it (a
        crescent); at 0 there is none (it lies on the limb, behind it).
    n_vertices : int, optional
        Vertices, >= 2, at the centres of equal steps of the great circle's
        angle (none on the cusps, where the terminator meets the limb and
        its normal is undefined).
    sigma : float, optional
        Every vertex's prior one-sigma along its normal, pixels, > 0.

    Returns
    -------
    Polyline
        ``name`` and ``edge_kind`` ``"terminator"``. A terminator fitted
        without its edge profile is a ramp, not an edge (the status says
        so): give it :func:`~dtalign.sphere_edge_profile` with
        ``edge="terminator"`` (:ref:`profiles`).

    Raises
    ------
    TypeError
        If a number is not a real number (``n_vertices`` not an int); the
        message names the argument.
    ValueError
        If a value is out of range (``phase_deg`` 0 included); the message
        names the argument.
    """
    center = np.asarray(check.pair(center_vu, "center_vu"))
    radius = check.positive_real(radius_px, "radius_px")
    ill, phase_d, n = _terminator_args(illumination_deg, phase_deg, n_vertices)
    sig = check.positive_real(sigma, "sigma")
    s = np.asarray(sun_direction_vu(ill))
    perp = np.array([-s[1], s[0]])
    phase = math.radians(phase_d)
    sin_p, cos_p = math.sin(phase), math.cos(phase)
    # N(t) = cos t * (perp, 0) + sin t * (cos(p) s, -sin(p)): both are unit
    # vectors perpendicular to L and to each other; N_z = -sin t sin p >= 0
    # for t in (-pi, 0), the visible half.
    t = _terminator_angles(n)
    nv = np.cos(t)[:, None] * perp[None, :] + (np.sin(t) * cos_p)[:, None] * s[None, :]
    nz = -np.sin(t) * sin_p
    pts = center[None, :] + radius * nv
    # d(cos i)/dp = sin(p) s / R - cos(p) (p - c) / (R^2 N_z): toward the lit side.
    grad = sin_p * s[None, :] / radius - cos_p * nv / (radius * np.maximum(nz, 1e-12))[:, None]
    grad /= np.hypot(grad[:, 0], grad[:, 1])[:, None]
    return Polyline("terminator", pts, grad, np.full(n, sig), edge_kind="terminator")
