"""What kind of edge the image shows along a polyline's normals, when none was declared.

A plain fit (no :class:`~dtalign.EdgeProfile`, no ``edge_kind``) of a
rendered limb or terminator carries the edge DT's photometric bias: a
limb's steepest gradient lies inside the silhouette, a terminator is a ramp
with no edge. The floors of :mod:`dtalign.pipeline.uncertainty` account for
it only when the kind is known. :func:`infer_edge_kind` reads the kind from
the image instead: the median brightness profile across the vertices, along
their normals (which point to the bright side) at the fitted pose, from
:data:`SKY_PX` outside the edge to :data:`FAR_PX` inside it. Three shapes
are told apart by how the brightness inside the edge moves on from its
first level beyond the step, ``drift = (far - near) / (near - sky)``:

* a **plain step** (a uniform disc, a ring band, a painted edge): flat on
  both sides, ``|drift|`` below :data:`LIMB_DRIFT`: no kind (the
  ``"dt"`` floor);
* a **limb**: a one-sided step from the sky to a lit surface whose
  brightness keeps changing inward (a reflectance law's limb darkening or
  brightening), ``|drift|`` between :data:`LIMB_DRIFT` and
  :data:`RAMP_DRIFT`;
* a **terminator**: a ramp out of the dark side, whose brightness is still
  rising far inside, ``drift`` above :data:`RAMP_DRIFT`.

A bright side that ends within :data:`FAR_PX` (``drift`` below
``-RAMP_DRIFT``: a thin crescent, a narrow band), and a step or drift the
noise explains (:data:`SIGNIFICANCE`), and a bright side broken by a
second edge (:data:`MAX_INNER_STEP`) are left without a kind.
The thresholds are read off the validation renders and the project's own
scenes (docs/uncertainty.rst, "A plain fit's edge kind").
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from ..api.sampling import sample_dt_bilinear

__all__ = [
    "FAR_PX",
    "LIMB_DRIFT",
    "MAX_INNER_STEP",
    "MID_PX",
    "MIN_VERTICES",
    "NEAR_PX",
    "RAMP_DRIFT",
    "SIGNIFICANCE",
    "SKY_PX",
    "edge_drift",
    "infer_edge_kind",
]

#: Where the dark side's level is read, px outside the edge along the normals.
SKY_PX: tuple[float, ...] = (-8.0, -7.0, -6.0, -5.0, -4.0)
#: Where the bright side's first level is read, px inside: past a blurred step.
NEAR_PX: tuple[float, ...] = (2.0, 3.0, 4.0)
#: Between the two, read for :data:`MAX_INNER_STEP` only.
MID_PX: tuple[float, ...] = (5.0, 6.0, 7.0)
#: Where the bright side's level farther in is read, px inside.
FAR_PX: tuple[float, ...] = (8.0, 9.0, 10.0, 11.0, 12.0)
#: Below this ``|drift|`` the bright side is flat: a plain step. Rendered
#: limbs at phase 20-70 deg read 0.08-0.4; uniform discs and bands 0.00.
LIMB_DRIFT: float = 0.04
#: Above this ``drift`` the brightness is a ramp: a terminator. Rendered
#: terminators read 0.7-1.1 at the DT lock.
RAMP_DRIFT: float = 0.6
#: A level is read as changed only when its median moves by more than this
#: many standard errors of the median (from the vertices' own scatter):
#: neighbouring vertices share pixels, so that scatter understates the
#: error, and a noisy uniform disc must stay a plain step.
SIGNIFICANCE: float = 5.0
#: The largest change of the median profile between neighbouring samples
#: inside the edge (:data:`NEAR_PX` to :data:`FAR_PX`, 1 px apart), as a
#: fraction of the step, for a drift to be read as the surface's: rendered
#: limbs read up to 0.1, terminators 0.11-0.19; a second edge inside (a
#: crater's rim a few pixels in, a neighbouring ring) reads 0.3-0.65. A
#: change the noise explains (:data:`SIGNIFICANCE` of the standard error of
#: the median of the vertices' own changes) does not count: a heavy-noise
#: terminator's 66 vertices read 0.30 from noise alone.
MAX_INNER_STEP: float = 0.25
#: Fewer usable vertices (an inlier, its whole profile inside the image) than
#: this, and no kind is inferred.
MIN_VERTICES: int = 8


def infer_edge_kind(image: ArrayLike, points_vu: ArrayLike, normals_vu: ArrayLike,
                    weights: ArrayLike) -> str | None:
    """The kind of edge the image shows at ``points_vu`` along ``normals_vu``.

    Parameters
    ----------
    image : array_like, shape (H, W)
        The image fitted.
    points_vu : array_like, shape (N, 2)
        The vertices at the fitted pose, px.
    normals_vu : array_like, shape (N, 2)
        Their normals, pointing to the bright side.
    weights : array_like, shape (N,)
        The fit's robust weights: vertices of zero weight are left out.

    Returns
    -------
    str or None
        ``"limb"``, ``"terminator"``, or None: a plain step, a bright side
        narrower than :data:`FAR_PX`, no step up along the normals, a
        change the noise explains (:data:`SIGNIFICANCE`), a second edge
        inside (:data:`MAX_INNER_STEP`), or fewer than
        :data:`MIN_VERTICES` usable vertices.
    """
    levels = _levels(image, points_vu, normals_vu, weights)
    if levels is None:
        return None
    strips, jump, moved = levels
    n, n_sky = jump.size, len(SKY_PX)
    if not float(np.median(jump)) > SIGNIFICANCE * _standard_error(jump, n):
        return None  # no step up along the normals that the noise does not explain
    step = float(np.median(jump))
    drift = float(np.median(moved)) / step
    # the steps between neighbouring samples inside, those the noise does not
    # explain (heavy noise alone moves a median profile of few vertices by
    # more than MAX_INNER_STEP of a faint step)
    steps = np.abs(np.diff(np.median(strips[n_sky:], axis=1)))
    noise = np.array([_standard_error(row, n) for row in np.diff(strips[n_sky:], axis=0)])
    inner = float(np.max(np.where(steps > SIGNIFICANCE * noise, steps, 0.0))) / step
    if inner > MAX_INNER_STEP:
        return None  # a second edge inside (a crater's rim, another ring), not a surface
    if abs(float(np.median(moved))) <= SIGNIFICANCE * _standard_error(moved, n):
        return None  # the bright side is flat within the noise: a plain step
    if drift > RAMP_DRIFT:
        return "terminator"
    if LIMB_DRIFT <= abs(drift) <= RAMP_DRIFT:
        return "limb"
    return None


def edge_drift(image: ArrayLike, points_vu: ArrayLike, normals_vu: ArrayLike,
               weights: ArrayLike) -> float | None:
    """The ``drift`` :func:`infer_edge_kind` reads (the median change of the
    bright side past its first level, over the median step), whatever kind
    it then infers; None for fewer than :data:`MIN_VERTICES` usable vertices
    or no step. Parameters as :func:`infer_edge_kind`'s."""
    levels = _levels(image, points_vu, normals_vu, weights)
    if levels is None:
        return None
    _, jump, moved = levels
    step = float(np.median(jump))
    return float(np.median(moved)) / step if step != 0.0 else None


def _levels(image: ArrayLike, points_vu: ArrayLike, normals_vu: ArrayLike, weights: ArrayLike
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The usable vertices' samples along their normals (one row per offset of
    :data:`SKY_PX`, :data:`NEAR_PX`, :data:`MID_PX`, :data:`FAR_PX`), their
    steps ``near - sky`` and drifts ``far - near``; None for fewer than
    :data:`MIN_VERTICES` usable vertices (an inlier whose whole profile is
    inside the image)."""
    img = np.asarray(image, dtype=np.float64)
    pts = np.asarray(points_vu, dtype=np.float64)
    nrm = np.asarray(normals_vu, dtype=np.float64)
    length = np.hypot(nrm[:, 0], nrm[:, 1])
    keep = (np.asarray(weights) > 0.0) & (length > 0.0) & np.isfinite(pts).all(axis=1)
    t = np.array(SKY_PX + NEAR_PX + MID_PX + FAR_PX)
    unit = nrm[keep] / length[keep, None]
    at = pts[keep][None, :, :] + t[:, None, None] * unit[None, :, :]
    h, w = img.shape
    inside = ((at[..., 0] >= 0) & (at[..., 0] <= h - 1)
              & (at[..., 1] >= 0) & (at[..., 1] <= w - 1)).all(axis=0)
    if int(inside.sum()) < MIN_VERTICES:
        return None
    strips = sample_dt_bilinear(img, at[:, inside].reshape(-1, 2)).reshape(len(t), -1)
    n_sky, n_near, n_far = len(SKY_PX), len(NEAR_PX), len(FAR_PX)
    sky = np.median(strips[:n_sky], axis=0)
    near = strips[n_sky:n_sky + n_near].mean(axis=0)
    far = strips[-n_far:].mean(axis=0)
    return strips, near - sky, far - near


def _standard_error(x: np.ndarray, n: int) -> float:
    """The standard error of the median of ``x``'s ``n`` values, from their MAD."""
    mad = float(np.median(np.abs(x - np.median(x))))
    return 1.2533 * 1.4826 * mad / np.sqrt(n)
