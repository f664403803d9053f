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
from ..api.sampling import sample_dt_bilinear
from .products import _readonly

__all__ = [
    "CORRELATION_LENGTH_PX",
    "Evidence",
    "FLOORS_PX",
    "INLIER_WEIGHT_FRACTION",
    "PROFILE_FLOOR_PER_PSF",
    "PoseUncertainty",
    "evidence",
    "floor_covariance",
    "floor_px",
    "pose_uncertainty",
    "sandwich_covariance",
    "source_of",
]

FloatArray = NDArray[np.float64]

#: How far along the edge two vertices share image evidence, in pixels: the
#: edge pixels come from a Gaussian-smoothed gradient (a few pixels of
#: support) thinned to one pixel, a DT value is the distance to the nearest
#: of them (shared by the vertices around it), and the pixel quantisation
#: repeats along a tilted edge. Beyond this a pair's Bartlett weight is
#: zero. Measured: 4 to 12 px change the step-edge families' coverage by a
#: few hundredths; 8 px is the best of them on the noisy ones.
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
#: no edge, where the DT lock lands several pixels off (median 5.7 px).
#: ``"profile"``: an accepted limb (or other) profile refinement: the
#: profile model's residual error with no blur; it grows with the blur
#: (:data:`PROFILE_FLOOR_PER_PSF`).
#: ``"profile_terminator"``: an accepted terminator profile refinement,
#: whose kink is located less sharply than a limb's step (chosen on the
#: rendered terminators' seeds 0-199 once the refinement fitted a
#: terminator without a background slope and with its sigma free; 0.15 px
#: before, when those fits were 0.17 px off at the median).
FLOORS_PX: dict[str, float] = {
    "dt": 0.03,
    "dt_limb": 0.23,
    "dt_terminator": 4.0,
    "profile": 0.003,
    "profile_terminator": 0.05,
}

#: The profile floor's growth with the PSF's sigma ``s`` (px per px): an
#: accepted profile refinement's floor is ``hypot(FLOORS_PX["profile"],
#: PROFILE_FLOOR_PER_PSF * s)``. A one-sided edge's blur and position are
#: correlated, and the refinement holds an estimated sigma fixed while it
#: fits the offset: on rendered limbs (calibration seeds 0-59 and 100-159)
#: the median error rose from 0.005 px (sigma below 0.3 px) to 0.018 px
#: (sigma above 1.2 px) while the pixels' covariance rose from 0.003 to
#: 0.008 px.
PROFILE_FLOOR_PER_PSF: float = 0.01

#: A vertex whose final weight is below this fraction of the largest is
#: mostly rejected (for the Tukey biweight: about two of its sigmas off its
#: edge): an outlier, whose pull the biweight has already bounded, not a
#: noisy measurement of the pose. It is left out of the noise term, which it
#: would otherwise dominate (on the ``outliers`` family the term was then
#: 1.5 times the real scatter).
INLIER_WEIGHT_FRACTION: float = 0.7

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
        ``noise + floor``: what :attr:`dtalign.pipeline.PolylineFit.covariance`
        reports (read-only).
    noise : ndarray, shape (P, P)
        The measured part: the DT-LM sandwich, or the profile refinement's
        covariance for the translation (read-only).
    floor_px : float
        The floor added along every observed direction, px.
    source : str
        Which pose and floor: a key of :data:`FLOORS_PX`.
    """

    covariance: FloatArray
    noise: FloatArray
    floor_px: float
    source: str


def _pinv_psd(m: FloatArray) -> FloatArray:
    w, v = np.linalg.eigh(0.5 * (m + m.T))
    top = float(w.max()) if w.size else 0.0
    keep = w > _RCOND * top if top > 0.0 else np.zeros(w.shape, dtype=bool)
    inv = np.where(keep, 1.0 / np.where(keep, w, 1.0), 0.0)
    return (v * inv) @ v.T


def sandwich_covariance(jac: FloatArray, residuals: FloatArray, weights: FloatArray,
                        points_vu: FloatArray, *,
                        correlation_px: float = CORRELATION_LENGTH_PX) -> FloatArray:
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
    info = (a * w[:, None]).T @ a
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
    """

    residuals: FloatArray
    jacobian: FloatArray
    points_vu: FloatArray


def evidence(fit: Any, edge_dt: FloatArray) -> Evidence:
    """The :class:`Evidence` of ``fit`` (a :class:`~dtalign.pipeline.PolylineFit`)
    on ``edge_dt``, the edge DT it was fitted to."""
    lm = fit.lm
    rel = np.asarray(fit.vertices_vu, dtype=np.float64) - np.asarray(fit.pivot_vu)
    if lm.rotation_rad != 0.0:  # the pose rotation of :ref:`contract-numerics`
        c, s = np.cos(lm.rotation_rad), np.sin(lm.rotation_rad)
        rel = np.column_stack([c * rel[:, 0] - s * rel[:, 1], s * rel[:, 0] + c * rel[:, 1]])
    pts = rel + np.asarray(fit.pivot_vu) + np.asarray(lm.offset_vu)
    eps = JACOBIAN_TRANSLATION_EPS_PX
    n = pts.shape[0]
    # one sampling call: the pose, then +-eps along v and along u
    at = sample_dt_bilinear(edge_dt, (pts + _STEPS * eps).reshape(-1, 2)).reshape(5, n)
    jac = np.empty((n, 3 if fit.fit_rotation else 2))
    jac[:, 0] = (at[1] - at[2]) / (2.0 * eps)
    jac[:, 1] = (at[3] - at[4]) / (2.0 * eps)
    if fit.fit_rotation:
        # d/dtheta of the DT at a rotated vertex: its gradient along the
        # vertex's motion, perpendicular to its lever arm from the pivot
        lever = pts - np.asarray(lm.offset_vu) - np.asarray(fit.pivot_vu)
        jac[:, 2] = -lever[:, 1] * jac[:, 0] + lever[:, 0] * jac[:, 1]
    return Evidence(_readonly(at[0]), _readonly(jac), _readonly(pts))


def source_of(fit: Any) -> str:
    """Which pose ``fit`` reports and so which floor applies: a key of :data:`FLOORS_PX`."""
    kind = fit.edge_kind
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
    p = 3 if fit.fit_rotation else 2
    w = np.asarray(fit.lm.weights, dtype=np.float64)
    source = source_of(fit)
    floor = floor_px(source, fit.profile)
    if fit.lm.degenerate:
        full = np.full((p, p), np.inf)
        return PoseUncertainty(_readonly(full), _readonly(full), floor, source)
    jac = np.asarray(found.jacobian)
    inlier = w >= INLIER_WEIGHT_FRACTION * float(w.max())
    w_in = np.where(inlier, w, 0.0)
    noise = sandwich_covariance(jac, np.where(inlier, found.residuals, 0.0), w_in,
                                np.asarray(found.points_vu))
    if fit.profile is not None and fit.profile.accepted:
        # the translation is the profile's: its pixels' covariance replaces
        # the DT's (the rotation, when fitted, stays the DT-LM's)
        prof = np.asarray(fit.profile.covariance, dtype=np.float64)
        noise = noise.copy()
        noise[:2, :] = 0.0
        noise[:, :2] = 0.0
        noise[:2, :2] = prof if np.isfinite(prof).all() else np.inf
    if not np.isfinite(noise).all():
        full = np.full((p, p), np.inf)
        return PoseUncertainty(_readonly(full), _readonly(noise), floor, source)
    cov = noise + floor_covariance(jac, w, floor)
    return PoseUncertainty(_readonly(cov), _readonly(noise), floor, source)
