"""An uncertainty that covers the truth: the pipeline's pose covariance.

The drop-in :func:`dtalign.lm_subpixel_refine` reports the pseudoinverse of
the M-estimator information matrix, ``pinvh(J^T W J)`` with ``W`` from the
prior vertex sigmas (:ref:`contract-lm`): it is as large as the sigmas the
caller passed, whatever the image says. Scaling it by the residual variance
(``curve_fit(absolute_sigma=False)``) treats the vertices as independent,
which they are not: neighbouring vertices read the same smoothed gradient
and the same thinned edge pixels. Neither reading accounts for what the
edge model leaves (the edge detector's localisation bias, a limb's
physical bias toward the sun).

:attr:`dtalign.pipeline.PolylineFit.covariance` is built here
(:func:`pose_uncertainty`) from three parts, and the docs' uncertainty page
measures how often it covers the truth:

1. **The noise actually measured.** For the DT-LM pose, the robust fit's
   sandwich covariance ``H^+ B H^+`` with ``H = sum w J J^T`` and the scores
   ``psi_i = w_i r_i J_i`` (``r_i`` the DT residual at the fitted pose,
   ``J_i`` its gradient by pose parameter: the LM's own Jacobian rows). For
   an accepted profile refinement, its own covariance from the image
   pixels' residuals (:class:`~dtalign.pipeline.profile_fit.ProfileRefinement`):
   the pixels' noise is independent where the vertices' is not.
   The bread ``H`` holds the cost's curvature across the DT gradient too
   (:data:`CURVATURE_STEP_PX`): a vertex whose nearest edge pixel is an
   isolated point (a sparse, noisy edge) sits in a cone of the DT, stiff
   along the edge as well as across it, which the Gauss-Newton part
   ``w J J^T`` misses.
2. **The correlation of neighbouring vertices.** ``B`` sums
   ``k(s_ij) psi_i psi_j^T`` over pairs of vertices with a Bartlett
   (triangular) weight of their distance ``s_ij``, which reaches zero at
   :data:`CORRELATION_LENGTH_PX` (a heteroscedasticity- and
   autocorrelation-consistent estimate, as Newey and West's). Vertices
   closer than that share image evidence, so they count as less than
   independent samples.
3. **A floor for what the model leaves**, ``floor^2`` along every pose
   direction the geometry observes: a bias along the normals that more
   vertices do not average away. Each floor is a measured figure
   (:data:`FLOORS_PX`, with the table on the docs' uncertainty page): the
   DT edge's localisation, a limb fitted without its profile (the steepest
   gradient sits inside the silhouette), a terminator without one (no edge
   at all), and the profile model's residual error.
4. **The pull of a second edge**, ``beta beta^T``: a DT-LM pose whose
   vertices have an edge of the opposite polarity a few pixels away along
   their normals (a thin crescent's other edge, a crater's rim inside a
   limb) is pushed away from it, because the smoothed gradient of the two
   edges overlaps and its ridge moves (:data:`SECOND_EDGE_SHIFT_PX`). Each
   vertex's shift is measured from the gradient along its normal
   (:func:`evidence`) and ``beta`` is the pose shift they make together,
   propagated through the same ``H`` (:func:`second_edge_pull`). The fit's
   pose is the DT-LM's less ``beta`` (``PolylineFit.offset_vu``);
   ``beta beta^T`` stays in the covariance, the error a modelled
   correction may leave, which more vertices do not average away.

Directions the geometry does not observe (a straight edge's along-edge
shift) get zero here, as in the drop-in's pseudoinverse; the fit's
``sigma_vu`` reads them as ``inf`` (:mod:`dtalign.pipeline.observability`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from ..api.constants import JACOBIAN_TRANSLATION_EPS_PX
from ..api.loop import second_edge_search
from ..api.sampling import sample_dt_bilinear
from .products import _readonly

__all__ = [
    "CORRELATION_LENGTH_PX",
    "CURVATURE_STEP_PX",
    "Evidence",
    "FLOORS_PX",
    "INLIER_WEIGHT_FRACTION",
    "PROFILE_FLOOR_PER_PSF",
    "PoseUncertainty",
    "SECOND_EDGE_DECAY_PX",
    "SECOND_EDGE_MAX_SHIFT_PX",
    "SECOND_EDGE_REACH_PX",
    "SECOND_EDGE_SHIFT_PX",
    "evidence",
    "floor_covariance",
    "floor_px",
    "information",
    "pose_uncertainty",
    "sandwich_covariance",
    "second_edge_pull",
    "second_edge_shift",
    "source_of",
]

FloatArray = NDArray[np.float64]

#: How far along the edge two vertices share image evidence, in pixels: the
#: edge pixels come from a Gaussian-smoothed gradient (a few pixels of
#: support) thinned to one pixel, a DT value is the distance to the nearest
#: of them (shared by the vertices around it), and the pixel quantisation
#: repeats along a tilted edge. Beyond this a pair's Bartlett weight is
#: zero. The coverage is not sensitive to it within a few pixels; 8 px is
#: the best measured on the noisy families (docs/uncertainty.rst, "The
#: pipeline's covariance").
CORRELATION_LENGTH_PX: float = 8.0

#: The floor of each kind of pose, px along the normals (part 3 above), keyed
#: by :attr:`PoseUncertainty.source`. Measured on seeded rendered scenes with
#: a planted offset (the docs' uncertainty page has the tables):
#:
#: ``"dt"``: a DT-LM pose on an edge with no declared physics. On noise-free
#: anti-aliased step edges the DT-LM pose is off by a median 0.05-0.1 px
#: though its residuals carry no noise: the thinned edge of a smoothed
#: gradient sits where the pixel grid puts it.
#: ``"dt_limb"``: a limb (``edge_kind="limb"``) fitted without its profile:
#: its steepest gradient lies inside the silhouette, 0.1-0.6 px toward the
#: body's centre on rendered Lambert spheres at phase 20-60 deg.
#: ``"dt_terminator"``: a terminator fitted without its profile: a ramp with
#: no edge, where the DT lock lands several pixels off.
#: ``"profile"``: an accepted limb (or other) profile refinement: the
#: profile model's residual error with no blur; it grows with the blur
#: (:data:`PROFILE_FLOOR_PER_PSF`).
#: ``"profile_terminator"``: an accepted terminator profile refinement,
#: whose kink is located less sharply than a limb's step; the largest floor
#: whose 68 % coverage of the rendered terminators stays at most 0.78.
FLOORS_PX: dict[str, float] = {
    "dt": 0.03,
    "dt_limb": 0.23,
    "dt_terminator": 4.0,
    "profile": 0.003,
    "profile_terminator": 0.045,
}

#: The profile floor's growth with the PSF's sigma ``s`` (px per px): an
#: accepted profile refinement's floor is ``hypot(FLOORS_PX["profile"],
#: PROFILE_FLOOR_PER_PSF * s)``. A one-sided edge's blur and position are
#: correlated, and the refinement holds an estimated sigma fixed while it
#: fits the offset, so its error grows with the blur faster than the
#: pixels' own covariance does (the measured rise: docs/uncertainty.rst).
PROFILE_FLOOR_PER_PSF: float = 0.01

#: A vertex whose final weight is below this fraction of the largest is
#: mostly rejected (for the Tukey biweight: about two of its sigmas off its
#: edge): an outlier, whose pull the biweight has already bounded, not a
#: noisy measurement of the pose. It is left out of the noise term, which it
#: would otherwise dominate.
INLIER_WEIGHT_FRACTION: float = 0.7

#: The step of the DT's second difference across its gradient (the
#: curvature of :func:`evidence`), px. The DT of an isolated edge pixel is a
#: cone, whose curvature across its gradient is ``1/r``; the DT of a thinned
#: line of edge pixels is flat along the line but for the pixel scallops,
#: which a step of a few pixels averages away (a step of 1 px meets them).
#: Of the steps measured, 3 px put the coverage of the sparse-edge families
#: nearest the targets (the comparison: docs/uncertainty.rst).
CURVATURE_STEP_PX: float = 3.0

#: How far along each vertex's normal, either way, :func:`evidence` looks
#: for an edge of the opposite polarity, px: beyond it the shift
#: :func:`second_edge_shift` assigns is below 0.02 px.
SECOND_EDGE_REACH_PX: float = 5.0

#: The shift of a vertex's detected edge by an edge of opposite polarity
#: 3 px away along its normal, px (:func:`second_edge_shift`), and
#: :data:`SECOND_EDGE_DECAY_PX` its e-folding with the distance. The edge
#: pixels are the ridge of a gradient smoothed by a Gaussian of 1.2 px: two
#: opposite edges a few pixels apart overlap in it and their ridges move
#: apart. A 1-D model of the detector (the Gaussian, the pixel's box, the
#: central difference) has the curve's shape; the thinning on a tilted
#: pixel grid makes the shift about 1.5 times the model's, so the constants
#: are the ones measured on rendered crescents (docs/uncertainty.rst,
#: part 4).
SECOND_EDGE_SHIFT_PX: float = 0.43
#: See :data:`SECOND_EDGE_SHIFT_PX`.
SECOND_EDGE_DECAY_PX: float = 0.65
#: The shift is capped here, px: closer than 3 px the two edges' gradients
#: merge into one ridge and the model no longer holds; the largest shift
#: measured was 0.36 px.
SECOND_EDGE_MAX_SHIFT_PX: float = 0.5

#: The step of the gradient profile :func:`evidence` reads along each
#: normal, px: a peak's place is refined between the samples by a
#: parabola, so half a pixel is enough.
_PROFILE_STEP_PX: float = 0.5

#: The offsets along each normal at which that profile is read, px.
_PROFILE_STEPS = np.arange(-SECOND_EDGE_REACH_PX, SECOND_EDGE_REACH_PX + 0.5 * _PROFILE_STEP_PX,
                           _PROFILE_STEP_PX)

#: Where along the normal, px either side of the vertex, its own edge's
#: gradient peak is looked for.
_OWN_EDGE_PX: float = 1.5

#: Lags of the correlation sum are capped here (a vertex pairs with at most
#: this many successors): a densely sampled polyline reaches the
#: correlation length within far fewer, and the cap keeps the sum linear.
_MAX_LAG: int = 64

#: The sampling offsets of :func:`evidence`, in units of the central
#: difference's half-step: the pose, then +-1 along v and along u.
_STEPS = np.array([[0.0, 0.0], [1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])[:, None, :]

#: Relative cutoff of the pseudoinverses here: directions whose information
#: is below this fraction of the largest are the geometry's null directions.
_RCOND: float = 1e-10


@dataclass(frozen=True)
class PoseUncertainty:
    """The pipeline's covariance of a pose, and its parts.

    Attributes
    ----------
    covariance : ndarray, shape (P, P)
        ``noise + bias + floor``: what :attr:`dtalign.pipeline.PolylineFit.covariance`
        reports (read-only).
    noise : ndarray, shape (P, P)
        The measured part: the DT-LM sandwich, or the profile refinement's
        covariance for the translation (read-only).
    floor_px : float
        The floor added along every observed direction, px.
    source : str
        Which pose and floor: a key of :data:`FLOORS_PX`.
    bias : ndarray, shape (P, P), or None
        ``beta beta^T``, the DT-LM pose's shift by second edges of the
        opposite polarity (part 4 above); for an accepted profile
        refinement zero, or ``b b^T`` with ``b`` its
        ``ProfileRefinement.night_shift_vu`` (a terminator whose night side
        is lit). Read-only; None when the covariance is all ``inf``.
    """

    covariance: FloatArray
    noise: FloatArray
    floor_px: float
    source: str
    bias: FloatArray | None = None


def _pinv_psd(m: FloatArray) -> FloatArray:
    w, v = np.linalg.eigh(0.5 * (m + m.T))
    top = float(w.max()) if w.size else 0.0
    keep = w > _RCOND * top if top > 0.0 else np.zeros(w.shape, dtype=bool)
    inv = np.where(keep, 1.0 / np.where(keep, w, 1.0), 0.0)
    return (v * inv) @ v.T


def sandwich_covariance(jac: FloatArray, residuals: FloatArray, weights: FloatArray,
                        points_vu: FloatArray, *,
                        correlation_px: float = CORRELATION_LENGTH_PX,
                        information: FloatArray | None = None) -> FloatArray:
    """The robust fit's covariance from its residuals, neighbours correlated.

    Parameters
    ----------
    jac : ndarray, shape (N, P)
        Each vertex's residual gradient by pose parameter (the LM's rows).
    residuals : ndarray, shape (N,)
        The residuals at the fitted pose.
    weights : ndarray, shape (N,)
        The fit's final weights (0 for rejected vertices).
    points_vu : ndarray, shape (N, 2)
        The vertices at the fitted pose, in polyline order: a pair is
        weighted by its distance, over at most ``_MAX_LAG`` successors.
    correlation_px : float, optional
        Where the Bartlett weight of a pair reaches zero.
    information : ndarray, shape (P, P), optional
        The bread ``H``; the Gauss-Newton ``sum w J J^T`` of the weighted
        vertices when None (:func:`information` adds the DT's curvature).

    Returns
    -------
    ndarray, shape (P, P)
        Symmetric, positive semi-definite; all ``inf`` when at most ``P``
        vertices keep a weight.
    """
    keep = weights > 0.0
    p = jac.shape[1]
    n = int(np.count_nonzero(keep))
    if n <= p:
        return np.full((p, p), np.inf)
    a = jac[keep]
    w = weights[keep]
    pts = points_vu[keep]
    info = (a * w[:, None]).T @ a if information is None else information
    psi = (w * residuals[keep])[:, None] * a
    meat = psi.T @ psi
    # the triangle is a positive semi-definite kernel of the distance along a
    # line; a curve's chords bend it a little, clipped below
    for lag in range(1, min(n - 1, _MAX_LAG) + 1):
        d = np.hypot(pts[lag:, 0] - pts[:-lag, 0], pts[lag:, 1] - pts[:-lag, 1])
        k = np.clip(1.0 - d / correlation_px, 0.0, None)
        if not k.any():
            break
        c = (psi[lag:] * k[:, None]).T @ psi[:-lag]
        meat += c + c.T
    bread = _pinv_psd(info)
    cov = bread @ meat @ bread * (n / (n - p))
    # rounding of a near-singular product, clipped back to semi-definite
    ev, vec = np.linalg.eigh(0.5 * (cov + cov.T))
    return np.asarray((vec * np.clip(ev, 0.0, None)) @ vec.T)


def _motion(jac: FloatArray, lever_vu: FloatArray | None) -> FloatArray:
    """Each vertex's unit direction across its DT gradient, as a pose row:
    how far each pose parameter moves the vertex along it."""
    g = jac[:, :2] / np.maximum(np.hypot(jac[:, 0], jac[:, 1]), 1e-300)[:, None]
    across = np.column_stack([-g[:, 1], g[:, 0]])
    if jac.shape[1] == 2 or lever_vu is None:
        return across
    # the rotation moves a vertex along perp(lever), as in :func:`evidence`
    turn = -lever_vu[:, 1] * across[:, 0] + lever_vu[:, 0] * across[:, 1]
    return np.column_stack([across, turn])


def information(jac: FloatArray, residuals: FloatArray, weights: FloatArray,
                curvature: FloatArray | None = None,
                lever_vu: FloatArray | None = None) -> FloatArray:
    """The bread of :func:`sandwich_covariance`: the robust cost's Hessian.

    ``sum w J J^T`` (Gauss-Newton) plus, with ``curvature``, the DT's own
    curvature across its gradient, ``sum w r c m m^T`` with ``m`` the
    vertex's motion across its DT gradient per pose parameter. For an
    isolated edge pixel at distance ``r`` the DT is a cone and
    ``r c = 1``: moving the vertex along the edge costs as much as across.

    Parameters
    ----------
    jac, residuals, weights : ndarray
        As :func:`sandwich_covariance`'s.
    curvature : ndarray, shape (N,), optional
        The DT's second difference across its gradient at each vertex,
        ``>= 0`` (the ``curvature`` of :class:`Evidence`).
    lever_vu : ndarray, shape (N, 2), optional
        Each vertex's lever arm from the pivot (a fit with a rotation).

    Returns
    -------
    ndarray, shape (P, P)
    """
    keep = weights > 0.0
    a = jac[keep]
    w = weights[keep]
    info = (a * w[:, None]).T @ a
    if curvature is None:
        return np.asarray(info)
    m = _motion(a, None if lever_vu is None else lever_vu[keep])
    bend = w * residuals[keep] * curvature[keep]
    return np.asarray(info + (m * bend[:, None]).T @ m)


def second_edge_shift(distance_px: FloatArray, ratio: FloatArray) -> FloatArray:
    """The shift of a vertex's detected edge by an edge of the opposite
    polarity ``distance_px`` away along its normal, px.

    ``ratio`` is that edge's gradient over the vertex's own (at most 1):
    the shift of a ridge by a small overlapping one is linear in the
    overlap. ``inf`` distances (no such edge) shift nothing.
    """
    d = np.asarray(distance_px, dtype=np.float64)
    shift = np.where(np.isfinite(d), SECOND_EDGE_SHIFT_PX
                     * np.exp(-(np.where(np.isfinite(d), d, 0.0) - 3.0) / SECOND_EDGE_DECAY_PX),
                     0.0)
    return np.asarray(np.minimum(shift, SECOND_EDGE_MAX_SHIFT_PX) * np.asarray(ratio))


def floor_covariance(jac: FloatArray, weights: FloatArray, floor_px: float) -> FloatArray:
    """``floor^2`` along every pose direction the geometry observes.

    The observable directions are the range of ``sum w J J^T``. The
    rotation gets ``floor^2`` divided by the weighted mean squared lever
    arm: the rotation that moves the vertices by ``floor`` on average.
    """
    keep = weights > 0.0
    p = jac.shape[1]
    if not keep.any() or floor_px == 0.0:
        return np.zeros((p, p))
    a = jac[keep]
    w = weights[keep]
    info = (a * w[:, None]).T @ a
    ev, vec = np.linalg.eigh(0.5 * (info + info.T))
    top = float(ev.max())
    observed = vec[:, ev > _RCOND * top] if top > 0.0 else vec[:, :0]
    scale = np.ones(p)
    if p == 3:
        lever2 = float(np.sum(w * a[:, 2] ** 2) / max(np.sum(w * (a[:, 0] ** 2 + a[:, 1] ** 2)),
                                                       1e-300))
        scale[2] = 1.0 / lever2 if lever2 > 0.0 else 0.0
    s = np.sqrt(scale)
    return np.asarray(floor_px**2 * ((observed @ observed.T) * s[:, None] * s[None, :]))


class Evidence(NamedTuple):
    """What the DT said at a fit's DT-LM pose, per vertex: the noise term's input.

    Sampled once when the fit is made (:func:`evidence`); the covariance
    is formed from it when first read (:func:`pose_uncertainty`).

    Attributes
    ----------
    residuals : ndarray, shape (N,)
        The edge DT at each vertex, pixels.
    jacobian : ndarray, shape (N, P)
        Its gradient by pose parameter (central differences of
        ``JACOBIAN_TRANSLATION_EPS_PX`` (0.25 px), as the LM's; the
        rotation's through the vertex's lever arm).
    points_vu : ndarray, shape (N, 2)
        The vertices at the pose.
    curvature : ndarray, shape (N,), or None
        The DT's second difference across its gradient, step
        :data:`CURVATURE_STEP_PX`, clipped at zero (1/px); None in a fit
        saved before it was sampled.
    second_edge_vu : ndarray, shape (N, 2), or None
        The shift of each vertex's detected edge by an edge of the opposite
        polarity along its normal (:func:`second_edge_shift`), px, pointing
        away from that edge; zero where there is none. None in a fit saved
        before it was sampled.
    """

    residuals: FloatArray
    jacobian: FloatArray
    points_vu: FloatArray
    curvature: FloatArray | None = None
    second_edge_vu: FloatArray | None = None


def _second_edges(magnitude: FloatArray, gradient_vu: FloatArray, pts: FloatArray,
                  normals: FloatArray, threshold: float) -> FloatArray:
    """Each vertex's ``second_edge_vu`` (:class:`Evidence`).

    The gradient magnitude is read along the vertex's normal within
    :data:`SECOND_EDGE_REACH_PX` either way. The vertex's own edge is its
    peak within :data:`_OWN_EDGE_PX`, which must pass ``threshold`` (the
    detector's edge threshold); the second edge is the nearest other local
    peak above ``threshold`` whose gradient points against the normal: an
    edge the detector keeps, of the opposite polarity
    (:func:`dtalign.api.loop.second_edge_search`, compiled: it releases the
    GIL, so a threaded batch concludes its fits in parallel).
    """
    dist, ratio, side = second_edge_search(magnitude, gradient_vu, pts, normals, _PROFILE_STEPS,
                                           _PROFILE_STEP_PX, threshold, _OWN_EDGE_PX)
    # the ridge moves away from the other edge
    return np.asarray(-(second_edge_shift(dist, ratio) * side)[:, None] * normals)


def evidence(fit: Any, edge_dt: FloatArray, gradient: tuple[FloatArray, FloatArray] | None = None,
             threshold: float = math.inf) -> Evidence:
    """The :class:`Evidence` of ``fit`` (a :class:`~dtalign.pipeline.PolylineFit`)
    on ``edge_dt``, the edge DT it was fitted to; with ``gradient`` (the
    image products' ``gradient_magnitude`` and ``gradient_vu``) and
    ``threshold`` (their edge threshold), the second edges too (zero
    without)."""
    lm = fit.lm
    rel = np.asarray(fit.vertices_vu, dtype=np.float64) - np.asarray(fit.pivot_vu)
    normals = np.asarray(fit.normals_vu, dtype=np.float64).reshape(-1, 2)
    if lm.rotation_rad != 0.0:  # the pose rotation of :ref:`contract-numerics`
        c, s = np.cos(lm.rotation_rad), np.sin(lm.rotation_rad)
        rel = np.column_stack([c * rel[:, 0] - s * rel[:, 1], s * rel[:, 0] + c * rel[:, 1]])
        normals = np.column_stack([c * normals[:, 0] - s * normals[:, 1],
                                   s * normals[:, 0] + c * normals[:, 1]])
    pts = rel + np.asarray(fit.pivot_vu) + np.asarray(lm.offset_vu)
    eps = JACOBIAN_TRANSLATION_EPS_PX
    n = pts.shape[0]
    # one sampling call: the pose, then +-eps along v and along u
    at = sample_dt_bilinear(edge_dt, (pts + _STEPS * eps).reshape(-1, 2)).reshape(5, n)
    jac = np.empty((n, fit.n_params))
    jac[:, 0] = (at[1] - at[2]) / (2.0 * eps)
    jac[:, 1] = (at[3] - at[4]) / (2.0 * eps)
    if fit.fit_rotation:
        # d/dtheta of the DT at a rotated vertex: its gradient along the
        # vertex's motion, perpendicular to its lever arm from the pivot
        lever = pts - np.asarray(lm.offset_vu) - np.asarray(fit.pivot_vu)
        jac[:, 2] = -lever[:, 1] * jac[:, 0] + lever[:, 0] * jac[:, 1]
    # the DT's curvature across its gradient (a zero gradient: none)
    step = CURVATURE_STEP_PX * _motion(jac[:, :2], None)
    side = sample_dt_bilinear(edge_dt, np.concatenate([pts + step, pts - step])).reshape(2, n)
    bend = (side[0] + side[1] - 2.0 * at[0]) / CURVATURE_STEP_PX**2
    bend = np.where(np.hypot(jac[:, 0], jac[:, 1]) > 0.0, np.clip(bend, 0.0, None), 0.0)
    unit = normals / np.maximum(np.hypot(normals[:, 0], normals[:, 1]), 1e-300)[:, None]
    second = (np.zeros((n, 2)) if gradient is None or n == 0
              else _second_edges(gradient[0], np.asarray(gradient[1]), pts, unit, threshold))
    return Evidence(_readonly(at[0]), _readonly(jac), _readonly(pts), _readonly(bend),
                    _readonly(second))


def source_of(fit: Any) -> str:
    """Which pose ``fit`` reports and so which floor applies: a key of :data:`FLOORS_PX`.

    The kind is the declared one, else the one the image shows
    (``fit.inferred_edge_kind``): a limb fitted plainly keeps its
    photometric bias whether or not its kind was declared."""
    kind = fit.edge_kind or getattr(fit, "inferred_edge_kind", None)
    if fit.profile is not None and fit.profile.accepted:
        return "profile_terminator" if kind == "terminator" else "profile"
    return {"limb": "dt_limb", "terminator": "dt_terminator"}.get(kind or "", "dt")


def floor_px(source: str, profile: Any = None) -> float:
    """The floor of a pose of kind ``source`` (a key of :data:`FLOORS_PX`), px;
    for ``"profile"``, grown with ``profile.psf_sigma_px``
    (:data:`PROFILE_FLOOR_PER_PSF`)."""
    base = FLOORS_PX[source]
    if source != "profile" or profile is None:
        return base
    psf = float(profile.psf_sigma_px)
    return math.hypot(base, PROFILE_FLOOR_PER_PSF * psf) if math.isfinite(psf) else base


class _Bread(NamedTuple):
    """What the noise and the second edges' pull are formed from."""

    jac: FloatArray
    weights: FloatArray  # the inliers' robust weights, zero elsewhere
    residuals: FloatArray  # the inliers' residuals, zero elsewhere
    info: FloatArray  # the bread H of the sandwich (:func:`information`)


def _bread(fit: Any, found: Evidence) -> _Bread:
    """The inliers and the bread ``H`` of a non-degenerate ``fit``."""
    w = np.asarray(fit.lm.weights, dtype=np.float64)
    jac = np.asarray(found.jacobian)
    inlier = w >= INLIER_WEIGHT_FRACTION * float(w.max())
    w_in = np.where(inlier, w, 0.0)
    res = np.where(inlier, found.residuals, 0.0)
    lever = None
    if jac.shape[1] == 3:
        lever = (np.asarray(found.points_vu) - np.asarray(fit.lm.offset_vu)
                 - np.asarray(fit.pivot_vu))
    bend = None if found.curvature is None else np.asarray(found.curvature)
    return _Bread(jac, w_in, res, information(jac, res, w_in, bend, lever))


def _pull(b: _Bread, found: Evidence) -> FloatArray:
    """``beta``: the vertices' second-edge shifts propagated to the pose
    through the same bread, ``H^+ sum w_i J_i (J_i . s_i)``."""
    p = b.jac.shape[1]
    keep = b.weights > 0.0
    if found.second_edge_vu is None or not keep.any():
        return np.zeros(p)
    a = b.jac[keep]
    moved = np.einsum("nk,nk->n", a[:, :2], np.asarray(found.second_edge_vu)[keep])
    return np.asarray(_pinv_psd(b.info) @ ((a * b.weights[keep, None]).T @ moved))


def second_edge_pull(fit: Any, found: Evidence) -> FloatArray:
    """The DT-LM pose's shift by second edges of the opposite polarity (part 4).

    Parameters
    ----------
    fit : PolylineFit
        The fit (its DT-LM pose, weights and pivot are read).
    found : Evidence
        Its :func:`evidence`.

    Returns
    -------
    ndarray, shape (P,)
        ``beta``, pixels (and radians for a fitted rotation): the DT-LM
        pose minus ``beta`` is the pose the second edges did not push.
        Zero for a degenerate fit and where no vertex has a second edge.
    """
    p = fit.n_params
    # most polylines have no second edge: no bread to form for them
    if fit.lm.degenerate or found.second_edge_vu is None or not np.any(found.second_edge_vu):
        return np.zeros(p)
    return _pull(_bread(fit, found), found)


def pose_uncertainty(fit: Any, found: Evidence) -> PoseUncertainty:
    """The covariance of ``fit``'s pose (a :class:`~dtalign.pipeline.PolylineFit`).

    Parameters
    ----------
    fit : PolylineFit
        The fit, its profile refinement and edge kind set.
    found : Evidence
        Its :func:`evidence`.

    Returns
    -------
    PoseUncertainty
        All ``inf`` for a degenerate fit, or one with too few inliers.
    """
    p = fit.n_params
    w = np.asarray(fit.lm.weights, dtype=np.float64)
    source = source_of(fit)
    floor = floor_px(source, fit.profile)
    if fit.lm.degenerate:
        full = np.full((p, p), np.inf)
        return PoseUncertainty(_readonly(full), _readonly(full), floor, source)
    b = _bread(fit, found)
    jac = b.jac
    noise = sandwich_covariance(jac, b.residuals, b.weights, np.asarray(found.points_vu),
                                information=b.info)
    bias = np.zeros((p, p))
    if fit.profile is not None and fit.profile.accepted:
        # the translation is the profile's: its pixels' covariance replaces
        # the DT's (the rotation, when fitted, stays the DT-LM's)
        prof = np.asarray(fit.profile.covariance, dtype=np.float64)
        noise = noise.copy()
        noise[:2, :] = 0.0
        noise[:, :2] = 0.0
        noise[:2, :2] = prof if np.isfinite(prof).all() else np.inf
        night = fit.profile.night_shift_vu
        if night is not None:
            # a terminator whose night side is lit: floored there instead, its
            # kink would lie this far from the fitted one (``night_side_lit``)
            bias[:2, :2] = np.outer(night, night)
    else:
        # the pose is corrected by beta (:func:`dtalign.pipeline.fit.conclude`),
        # but beta is a modelled shift: its size stays in the covariance as
        # the error the correction may leave
        beta = _pull(b, found)
        bias = np.outer(beta, beta)
    if not np.isfinite(noise).all():
        full = np.full((p, p), np.inf)
        return PoseUncertainty(_readonly(full), _readonly(noise), floor, source)
    cov = noise + bias + floor_covariance(jac, w, floor)
    return PoseUncertainty(_readonly(cov), _readonly(noise), floor, source, _readonly(bias))
