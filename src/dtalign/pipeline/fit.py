"""One-call fitting: image in, pose and its uncertainty out.

Every navigation technique that uses the DT fitter repeats the same steps:
image derivatives, a polyline mask, the coarse integer search, the rotation
pivot, the robust LM refinement, then an "is the seed on the window edge?"
test. This module does those steps once, in one place:

* :func:`~dtalign.pipeline.products.prepare_image` computes an image's products
  (gradient, truncated edge DT, edge mask, noise sigma) once;
* :func:`~dtalign.pipeline.fit_polyline_products` fits one polyline against
  those products, so several polylines (a limb, a terminator, a ring edge)
  share them;
* :func:`~dtalign.pipeline.fit_polyline` is the two together for the
  single-polyline case.

The result, :class:`~dtalign.pipeline.PolylineFit`, carries the coarse seed, the full
:class:`~dtalign.LMRefineResult`, the pose, one-sigma uncertainties read
from the covariance and the window-edge flag. What a rank-deficient fit
does not constrain is read with the helpers of
:mod:`dtalign.pipeline.observability`;
:func:`~dtalign.pipeline.products.prepare_image`,
:class:`~dtalign.pipeline.products.ImageProducts` and
:func:`~dtalign.pipeline.products.estimate_noise_sigma` live in
:mod:`dtalign.pipeline.products`. The package :mod:`dtalign.pipeline`
re-exports them all with this module's names. The fits are built here from
the checks and compiled work of :mod:`dtalign.pipeline.jobs`.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..api import checks as check
from ..api.constants import DEFAULT_PINVH_RCOND, DEFAULT_TUKEY_C, POLARITY_PENALTY_RESIDUAL
from ..api.image import edge_threshold
from ..api.lm import fit_checked
from ..api.options import FitOptions, n_params, resolve
from ..api.polylines import Polyline
from ..api.results import ImageDerivativesConfig, LMRefineResult
from . import hypotheses as _hypotheses
from . import jobs
from . import status as _status
from .edge_kind import infer_edge_kind
from .hypotheses import Ambiguity, Hypothesis
from .observability import (
    _sigma_list,
    _sigmas_from_cov,
    covariance_with_unobservable_inf,
    normal_information_covariance,
    null_directions,
    observable_rank,
)
from .products import ImageProducts, _readonly, prepare_image, products_of
from .profile_fit import (
    RIVAL_AGREEMENT_SIGMAS,
    ProfileRefinement,
    check_edge_profile,
    edge_kind_of,
    refine_with_profile,
)
from .records import from_json, to_json
from .region import holds, image_region
from .status import (
    SETTLE_ITERATIONS,
    SETTLE_SIGMAS,
    Assessment,
    FitReason,
    FitStatus,
    Settling,
    assess,
)
from .uncertainty import (
    Evidence,
    PoseUncertainty,
    evidence,
    floor_px,
    pose_uncertainty,
    second_edge_pull,
)

__all__ = ["FitUncertainty", "PolylineFit", "fit_polyline", "fit_polyline_products"]

FloatArray = NDArray[np.float64]

# ---------------------------------------------------------------------------
# Fit result
# ---------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class PolylineFit:
    """Outcome of :func:`fit_polyline` / :func:`fit_polyline_products`.

    Attributes
    ----------
    offset_vu : tuple of float
        Fitted translation ``(dv, du)`` in pixels: add it to the model
        vertices (after the rotation) to land them on the image edges. The
        accepted profile refinement's when there is one; otherwise the
        DT-LM's (``lm.offset_vu``) less the pull of second edges of the
        opposite polarity near the polyline (a thin crescent's other edge,
        :func:`~dtalign.pipeline.uncertainty.second_edge_pull`), which is
        zero where there are none.
    rotation_rad : float
        Fitted rotation about ``pivot_vu`` (0.0 when not fitted): the
        DT-LM's (``lm.rotation_rad``) less the second edges' pull.
    coarse_offset_vu : tuple of int
        The integer seed of the coarse search.
    at_window_edge : bool
        True when the coarse seed lies on the boundary of the search window
        along an axis with a non-zero margin: the true offset may be
        outside the window and the fit should not be trusted.
    lm : LMRefineResult
        The full refinement result (covariance, residuals, weights, ...).
    search_window_vu : tuple of int
        The coarse-search margin used.
    fit_rotation : bool
        Whether the rotation was fitted.
    pivot_vu : tuple of float
        The rotation pivot (the vertex centroid unless given).
    pivot_distance_px : float
        The pivot-to-image-centre distance used to scale the rotation step.
    noise_sigma : float
        The image noise sigma the edge threshold used.
    vertices_vu, normals_vu : ndarray, shape (N, 2)
        The fitted polyline (read-only): what the geometry's covariance
        (``uncertainty.normal_covariance``) is formed from.
    pinvh_rcond : float
        The pseudoinverse cutoff of the covariance.
    tukey_c : float
        The Tukey cutoff used, in units of each vertex's sigma.
    timings_s : dict
        Wall time of each stage in seconds (``noise``, ``derivatives`` when
        the products were computed here, ``coarse``, ``lm``). Fits of
        :func:`dtalign.pipeline.batch.fit_many` have ``fit`` instead of ``coarse`` and
        ``lm``: the threads' compiled time divided by the call's fits.
    hypotheses : tuple of Hypothesis
        Every pose considered (:mod:`dtalign.pipeline.hypotheses`): the fit from the
        coarse seed first, then the other starts; empty when not examined.
    ambiguity : Ambiguity or None
        How clearly this basin beats the best rival basin (its ``ratio``,
        the rival, and whether the rival lies along an unobservable
        direction); None when not examined.
    settling : Settling or None
        For an LM that stopped before its step tolerance: how far the pose
        moved over its last iterations, which decides
        :attr:`~dtalign.pipeline.status.FitReason.NOT_CONVERGED`
        (:func:`~dtalign.pipeline.fit.settle`); None when the LM converged or was not
        examined.
    profile : ProfileRefinement or None
        The photometric refinement against an
        :class:`~dtalign.EdgeProfile` (:mod:`dtalign.pipeline.profile_fit`);
        None when no profile was given. When it is accepted,
        :attr:`offset_vu` is its offset and ``lm.offset_vu`` keeps
        the DT-LM one.
    edge_kind : str or None
        What kind of edge the polyline was declared to be
        (``FitOptions.edge_kind``, or its profile's ``edge``); None when not declared. A ``"terminator"``
        without a profile carries
        :attr:`~dtalign.pipeline.status.FitReason.TERMINATOR_WITHOUT_PROFILE`.

    evidence : Evidence or None
        The DT's residuals and their gradients at the DT-LM pose
        (:class:`~dtalign.pipeline.uncertainty.Evidence`), sampled when the
        fit is concluded: what :attr:`covariance` is formed from; None for a
        fit built without it.
    image_shape : tuple of int or None
        ``(H, W)`` of the image fitted against: what :attr:`outside_image`
        is read against; None for a fit built without it (a dict written
        before it was recorded), which then counts no vertex outside.
    masked_vertices : int or None
        How many vertices, at the fitted pose, lie on a bad pixel of the
        image's mask (:func:`~dtalign.pipeline.products.prepare_image`'s
        ``mask``): the edge was not measured there
        (:attr:`~dtalign.pipeline.status.FitReason.MASKED_PIXELS`); None
        when the image had no bad pixel.
    inferred_edge_kind : str or None
        For a fit given neither ``edge_kind`` nor a profile: the kind the
        image shows along the normals at the DT-LM pose, ``"limb"`` or
        ``"terminator"`` (:func:`~dtalign.pipeline.edge_kind.infer_edge_kind`),
        None for a plain step or when undecided. It chooses the floor of
        :attr:`covariance` as a declared kind would, and an inferred
        terminator carries
        :attr:`~dtalign.pipeline.status.FitReason.TERMINATOR_WITHOUT_PROFILE`.
        None whenever a kind or a profile was given.

    Whether to trust the fit is read by :attr:`status`, :attr:`reasons` and
    :attr:`status_message` (:mod:`dtalign.pipeline.status`); its uncertainty
    by :attr:`sigma_vu` and :attr:`sigma_rotation_rad`, from
    :attr:`covariance`. The covariance's parts and the alternatives (the
    drop-in M-estimator's, the same scaled by the residuals) are under
    :attr:`uncertainty`; the DT-LM stage's own readings under :attr:`lm`.
    Instances compare by identity; compare fields to compare fits.
    """

    offset_vu: tuple[float, float]
    rotation_rad: float
    coarse_offset_vu: tuple[int, int]
    at_window_edge: bool
    lm: LMRefineResult
    search_window_vu: tuple[int, int]
    fit_rotation: bool
    pivot_vu: tuple[float, float]
    pivot_distance_px: float
    noise_sigma: float
    vertices_vu: FloatArray = field(default_factory=lambda: np.zeros((0, 2)), repr=False)
    normals_vu: FloatArray = field(default_factory=lambda: np.zeros((0, 2)), repr=False)
    pinvh_rcond: float = DEFAULT_PINVH_RCOND
    tukey_c: float = DEFAULT_TUKEY_C
    timings_s: dict[str, float] = field(default_factory=dict, repr=False)
    hypotheses: tuple[Hypothesis, ...] = field(default=(), repr=False)
    ambiguity: Ambiguity | None = None
    # not printed: the status and reasons say what it decided
    settling: Settling | None = field(default=None, repr=False)
    profile: ProfileRefinement | None = field(default=None, repr=False)
    edge_kind: str | None = None
    evidence: Evidence | None = field(default=None, repr=False)
    image_shape: tuple[int, int] | None = field(default=None, repr=False)
    masked_vertices: int | None = field(default=None, repr=False)
    inferred_edge_kind: str | None = None

    @property
    def n_params(self) -> int:
        """The pose parameters fitted: 2 (``dv``, ``du``), 3 with the rotation."""
        return int(n_params(self.fit_rotation))

    def __post_init__(self) -> None:
        for name in ("vertices_vu", "normals_vu"):
            object.__setattr__(self, name, _readonly(np.asarray(getattr(self, name))))

    @functools.cached_property
    def uncertainty(self) -> FitUncertainty:
        """The covariance's parts and its other readings (:class:`FitUncertainty`)."""
        return FitUncertainty(self)

    @property
    def covariance(self) -> FloatArray:
        """The pose covariance (2 x 2, or 3 x 3 with rotation), pixels and radians.

        The noise measured in the residuals (the neighbouring vertices'
        correlation counted), plus a floor for what the edge model leaves:
        :mod:`dtalign.pipeline.uncertainty` says how, the docs' uncertainty
        page how often it covers the truth. Zero along a direction the
        geometry does not observe (read :attr:`sigma_vu`: ``inf`` there);
        all ``inf`` when degenerate. The drop-in contract's M-estimator
        pseudoinverse is ``lm.covariance``.
        """
        return self.uncertainty.covariance

    @property
    def settled(self) -> bool:
        """Whether the pose is settled: the LM converged, or it stopped but its
        pose no longer moved (:class:`~dtalign.pipeline.status.Settling`; a fit
        without one, such as a rival hypothesis, reads the LM's ``converged``)."""
        return self.lm.converged or (self.settling is not None and self.settling.settled)

    @property
    def polarity_rejected(self) -> NDArray[np.bool_]:
        """Vertices whose normal disagreed with the image gradient (residual 1e6)."""
        return np.asarray(self.lm.residuals_px) == POLARITY_PENALTY_RESIDUAL

    @property
    def tukey_rejected(self) -> NDArray[np.bool_]:
        """Polarity-accepted vertices the Tukey biweight gave zero weight."""
        return (np.asarray(self.lm.weights) == 0.0) & ~self.polarity_rejected

    @functools.cached_property
    def outside_image(self) -> NDArray[np.bool_]:
        """Vertices that lie outside the image, so that nothing measured them.

        A vertex is outside when the pixel the polarity test reads for it
        -- its position shifted by the coarse seed (:attr:`coarse_offset_vu`,
        the LM's start), rounded to the nearest pixel -- is not in rows
        ``0 .. H-1`` and columns ``0 .. W-1`` of :attr:`image_shape`: the
        polarity test rejects it (there is no gradient to read), so it is
        counted here and not as a normal pointing the wrong way
        (:attr:`~dtalign.pipeline.status.FitReason.OUTSIDE_IMAGE`). All
        False when :attr:`image_shape` is None.
        """
        return _readonly(_status.outside_mask(self))

    @property
    def observable_rank(self) -> int:
        """Number of pose directions the polyline's geometry constrains.

        The rank of ``uncertainty.normal_covariance``, not of
        :attr:`covariance` (which can look full rank on a digitised diagonal
        edge): 2 (or 3 with rotation) for a limb, 1 for parallel straight
        edges fitted in translation, 0 when degenerate.
        """
        return observable_rank(self.uncertainty.normal_covariance, self.pinvh_rcond)

    @property
    def unobservable_directions(self) -> FloatArray:
        """Unit pose directions the geometry does not constrain, shape (K, P)."""
        return self.uncertainty.unobservable_directions

    @property
    def sigma_vu(self) -> tuple[float, float]:
        """One-sigma uncertainty of ``dv`` and ``du``, pixels: the one to read.

        The square root of the diagonal of :attr:`covariance` (the noise
        measured, neighbours correlated, plus the edge model's floor), **``inf``
        for an axis that a direction the geometry does not observe involves**
        (a straight edge along ``u`` gives ``(s, inf)``; a diagonal straight
        edge ``(inf, inf)``: read it with :meth:`sigma_along` its normal),
        and ``inf`` for a degenerate fit.
        """
        sig = self.uncertainty.sigmas
        return sig[0], sig[1]

    @property
    def sigma_rotation_rad(self) -> float | None:
        """One-sigma of the rotation (from :attr:`covariance`), ``inf`` when
        unobservable; None when not fitted."""
        return self.uncertainty.sigmas[2] if self.fit_rotation else None

    @functools.cached_property
    def assessment(self) -> Assessment:
        """Its status, reasons and message, found once by
        :func:`~dtalign.pipeline.status.assess` (when the pipeline concludes
        the fit, or on first reading for a fit built otherwise)."""
        return assess(self)

    @property
    def reasons(self) -> tuple[FitReason, ...]:
        """Every condition that makes the fit failed, suspect or ambiguous, or a note
        (:class:`~dtalign.pipeline.status.FitReason`, str values such as
        ``"degenerate"``); empty for a clean fit."""
        return self.assessment.reasons

    @property
    def status(self) -> FitStatus:
        """``"ok"``, ``"suspect"``, ``"ambiguous"`` or ``"failed"``: the worst
        severity among :attr:`reasons` (:class:`~dtalign.pipeline.status.FitStatus`)."""
        return self.assessment.status

    @property
    def failed(self) -> bool:
        """True when :attr:`status` is ``"failed"``."""
        return self.status is FitStatus.FAILED

    @property
    def status_message(self) -> str:
        """The status and each reason explained, one line (``"ok"`` for a clean fit)."""
        return self.assessment.message

    def transform(self, vertices_vu: ArrayLike) -> FloatArray:
        """Apply the fitted pose (rotation about the pivot, then offset) to vertices."""
        verts = check.vertices(vertices_vu, "vertices_vu")
        theta = self.rotation_rad
        rel = verts - self.pivot_vu
        if theta != 0.0:
            c, s_ = math.cos(theta), math.sin(theta)
            rel = np.column_stack([c * rel[:, 0] - s_ * rel[:, 1], s_ * rel[:, 0] + c * rel[:, 1]])
        return rel + self.pivot_vu + self.offset_vu

    def sigma_along(self, direction_vu: tuple[float, float] | ArrayLike, *,
                    scaled: bool = False) -> float:
        """One-sigma of the translation projected on a direction ``(v, u)``.

        ``sqrt(d^T C d)`` with ``d`` the unit direction and ``C`` the
        translation block of :attr:`covariance` (of the M-estimator's
        ``uncertainty.covariance_scaled`` with ``scaled=True``): for a straight edge, pass its normal to get
        the across-edge uncertainty. ``inf`` when ``d`` has a component
        (above 1e-6) along an :attr:`unobservable_directions` entry or a null
        direction of the covariance, and for a degenerate fit.
        """
        d = np.asarray(check.pair(direction_vu, "direction_vu"))
        norm = float(np.hypot(d[0], d[1]))
        if norm == 0.0:
            raise ValueError("direction_vu must not be zero")
        d = d / norm
        cov = np.asarray(self.lm.covariance if scaled else self.covariance)
        if not np.isfinite(cov).all():
            return math.inf
        nulls = [*self.unobservable_directions, *null_directions(cov, self.pinvh_rcond)]
        # Components of a null direction below this are rounding, not geometry.
        if any(abs(float(e[0] * d[0] + e[1] * d[1])) > 1e-6 for e in nulls):
            return math.inf
        factor = self.uncertainty.variance_factor if scaled else 1.0
        if not math.isfinite(factor):
            return math.inf
        return float(math.sqrt(max(float(d @ cov[:2, :2] @ d), 0.0) * factor))

    def observable_offset(self) -> list[tuple[tuple[float, float], float, float]]:
        """The translation read along the directions the fit observes.

        For each unit direction ``e`` of the translation plane orthogonal
        to every :attr:`unobservable_directions` entry (two for a limb, one
        for a straight edge, none when degenerate): ``(e, e . offset_vu,
        sigma_along(e))``. For a straight edge this is the across-edge
        offset and its sigma, the reading to lead with.
        """
        if self.lm.degenerate:
            return []
        nulls = np.asarray(self.unobservable_directions)
        plane = np.eye(2)
        if nulls.size:
            # translation parts of the null directions, orthonormalised
            t = nulls[:, :2]
            t = t[np.linalg.norm(t, axis=1) > 1e-6]
            if t.size:
                q = np.linalg.svd(t, full_matrices=True)[2]
                plane = q[np.linalg.matrix_rank(t):]
        out = []
        for e in plane:
            if e[np.argmax(np.abs(e))] < 0:  # a stable sign: largest component positive
                e = -e
            ev = (float(e[0]) + 0.0, float(e[1]) + 0.0)  # (+ 0.0: no -0.0)
            out.append((ev, ev[0] * self.offset_vu[0] + ev[1] * self.offset_vu[1],
                        self.sigma_along(ev)))
        return out

    def to_dict(self, *, arrays: bool = False) -> dict[str, Any]:
        """A JSON-ready summary; with ``arrays=True``, everything :meth:`from_dict` needs.

        The fields (``_WRITTEN``), the LM's under the keys of ``_LM_KEYS``,
        and the readings of ``_READINGS``, each in its JSON form
        (:func:`~dtalign.pipeline.records.to_json`): a value that is
        not finite is written as ``None`` (JSON ``null``), in practice
        ``+inf``, the sigma or covariance of a direction the fit does not
        measure, or the rms of a degenerate fit.

        Parameters
        ----------
        arrays : bool, optional
            Also write the per-vertex arrays (``vertices_vu``,
            ``normals_vu``, ``residuals_px``, ``weights``, ``evidence``), from
            which the fit's derived readings (status, sigmas, observable rank)
            are computed again on loading.
        """
        out = {name: to_json(getattr(self, name)) for name in _WRITTEN}
        if self.masked_vertices is not None:  # only a masked image's fit has the key
            out["masked_vertices"] = int(self.masked_vertices)
        out.update((key, to_json(getattr(self.lm, name))) for key, name in _LM_KEYS.items())
        out.update((key, to_json(read(self))) for key, read in _READINGS.items())
        if arrays:  # as they are: their values are finite, or NaN where nothing is
            found = self.evidence
            out.update({name: np.asarray(a).tolist() for name, a in (
                ("vertices_vu", self.vertices_vu), ("normals_vu", self.normals_vu),
                ("residuals_px", self.lm.residuals_px), ("weights", self.lm.weights))})
            out["evidence"] = None if found is None else {
                k: None if v is None else np.asarray(v).tolist() for k, v in found._asdict().items()}
        return out

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> PolylineFit:
        """The fit :meth:`to_dict` described, from ``to_dict(arrays=True)`` (or its JSON).

        ``from_dict(fit.to_dict(arrays=True)).to_dict(arrays=True)`` equals
        ``fit.to_dict(arrays=True)``: the fields are read back
        (:func:`~dtalign.pipeline.records.from_json`), and the readings
        (status, reasons, sigmas, observable rank) computed again from them
        and the per-vertex arrays. ``None`` stands for ``+inf`` (``nan`` for
        a coarse score).

        Raises
        ------
        ValueError
            If ``d`` lacks the per-vertex arrays (a summary written by
            ``to_dict()`` without ``arrays=True``) or another field.
        """
        missing = [k for k in ("vertices_vu", "normals_vu", "residuals_px", "weights")
                   if k not in d]
        if missing:
            raise ValueError(
                f"PolylineFit.from_dict needs the per-vertex arrays {missing}: write the dict "
                "with to_dict(arrays=True)"
            )

        def array(x: Any, shape: tuple[int, ...] = (-1,)) -> FloatArray:
            return _readonly(np.asarray(x, dtype=np.float64).reshape(shape))

        try:
            # a dict written before "dt_offset_vu" and "dt_rotation_rad" has the
            # LM's pose as the fit's, and one written before the pipeline's own
            # covariance has the LM's as "covariance"
            lm_cov = d.get("covariance_mestimator", d["covariance"])
            lm = from_json(
                LMRefineResult,
                {name: d[key] if key in d else d[_LM_FALLBACK[key]]
                 for key, name in _LM_KEYS.items() if name != "covariance"},
                covariance=_readonly(np.array([[_inf(x) for x in row] for row in lm_cov],
                                              dtype=np.float64)),
                residuals_px=array(d["residuals_px"]), weights=array(d["weights"]),
                polarity_rejected_count=int(d["polarity_rejected"]))
            vertices = array(d["vertices_vu"], (-1, 2))
            found = d.get("evidence")
            return from_json(
                cls, d, lm=lm, vertices_vu=vertices, normals_vu=array(d["normals_vu"], (-1, 2)),
                evidence=None if found is None else _evidence_from(found, len(vertices)))
        except KeyError as exc:
            raise ValueError(f"PolylineFit.from_dict: the dict has no {exc.args[0]!r}") from None

    def summary(self) -> str:
        """The fit in at most a dozen lines: the status and its reasons, the
        offset and its one-sigma, the rank, the LM, the seed and, when there
        is one, the edge profile's refinement (``str(fit)``). A failed fit's
        sigmas read ``not measured (failed)``: its ``inf`` (or a finite sigma
        from a few stray inliers) is no measurement; the fields keep their
        values. Every reading is also an attribute (:meth:`to_dict` has them all)."""
        failed = self.status is FitStatus.FAILED

        def sig(x: float | None) -> str:
            return "inf" if x is None or not math.isfinite(x) else f"{x:.4g}"

        sv = (_status.UNMEASURED_TEXT if failed
              else f"({sig(self.sigma_vu[0])}, {sig(self.sigma_vu[1])}) px")
        lines = [f"PolylineFit: {self.status}",
                 f"  reasons: {', '.join(map(str, self.reasons)) or 'none'}",
                 f"  offset_vu: ({self.offset_vu[0]:.5f}, {self.offset_vu[1]:.5f}) px",
                 f"  sigma_vu: {sv}"]
        if self.fit_rotation:
            sr = _status.UNMEASURED_TEXT if failed else f"{sig(self.sigma_rotation_rad)} rad"
            lines += [f"  rotation_rad: {self.rotation_rad:.6g} about {_pair(self.pivot_vu)}",
                      f"  sigma_rotation_rad: {sr}"]
        lm = self.lm
        settled = "converged" if lm.converged else ("settled" if self.settled else "not settled")
        lines += [f"  observable_rank: {self.observable_rank} of {self.n_params}",
                  f"  vertices: {len(lm.residuals_px)}, {lm.inlier_count} inliers, "
                  f"rms {lm.rms_px:.4g} px",
                  f"  lm: {lm.iterations} iterations, {settled}",
                  f"  coarse_offset_vu: {tuple(self.coarse_offset_vu)} in a window "
                  f"±{tuple(self.search_window_vu)}"]
        if self.profile is not None:
            ref = self.profile
            lines.append(f"  profile: {'accepted' if ref.accepted else 'rejected'}, DT-LM offset "
                         f"{_pair(self.lm.offset_vu)}, walk {ref.walk_px:.3g} px")
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.summary()

    def __repr__(self) -> str:
        return (f"<PolylineFit {self.status}: offset_vu={_pair(self.offset_vu)}, "
                f"sigma_vu={_pair(self.sigma_vu)}, reasons={[str(r) for r in self.reasons]}>")


class FitUncertainty:
    """A fit's covariance, its parts and its other readings (``fit.uncertainty``).

    :attr:`PolylineFit.covariance` and :attr:`PolylineFit.sigma_vu` are the
    ones to read; this holds what they are made of and the alternatives the
    docs' uncertainty page compares them with: the drop-in M-estimator's
    covariance, the same scaled by the residuals, and the geometry's own
    covariance, which decides what the fit observes. Each is formed on first
    reading.
    """

    def __init__(self, fit: PolylineFit) -> None:
        self._fit = fit

    @functools.cached_property
    def parts(self) -> PoseUncertainty | None:
        """The pipeline's covariance in parts (:func:`~dtalign.pipeline.uncertainty.pose_uncertainty`),
        from the fit's ``evidence``; None for a fit built without it (then
        :attr:`covariance` is the M-estimator's)."""
        fit = self._fit
        return None if fit.evidence is None else pose_uncertainty(fit, fit.evidence)

    @property
    def covariance(self) -> FloatArray:
        """:attr:`PolylineFit.covariance`: ``noise + bias + floor``."""
        parts = self.parts
        return self._fit.lm.covariance if parts is None else parts.covariance

    @property
    def noise(self) -> FloatArray | None:
        """The measured part: the DT-LM sandwich, or the profile refinement's
        covariance for the translation; None without :attr:`parts`."""
        return None if self.parts is None else self.parts.noise

    @property
    def bias(self) -> FloatArray | None:
        """``beta beta^T``, the second edges' pull; None without :attr:`parts`
        or when the covariance is all ``inf``."""
        return None if self.parts is None else self.parts.bias

    @property
    def floor_px(self) -> float | None:
        """The floor added along every observed direction, px; None without :attr:`parts`."""
        return None if self.parts is None else self.parts.floor_px

    @property
    def source(self) -> str | None:
        """Which pose and floor (a key of :data:`~dtalign.pipeline.uncertainty.FLOORS_PX`);
        None without :attr:`parts`."""
        return None if self.parts is None else self.parts.source

    @functools.cached_property
    def normal_covariance(self) -> FloatArray:
        """Pose covariance when each vertex measures only its shift along its normal.

        Formed by :func:`~dtalign.pipeline.observability.normal_information_covariance`
        from the polyline and the LM's final weights. It decides
        :attr:`PolylineFit.observable_rank`. All ``inf`` (nothing observed)
        without vertices, and when the information matrix overflows float64
        (coordinates or a pivot near the float range).
        """
        fit = self._fit
        unmeasured = _readonly(np.full((fit.n_params, fit.n_params), np.inf))
        if fit.vertices_vu.shape[0] == 0:
            return unmeasured
        try:
            cov = normal_information_covariance(
                fit.vertices_vu, fit.normals_vu, np.asarray(fit.lm.weights),
                offset_vu=fit.lm.offset_vu, rotation_rad=fit.lm.rotation_rad,
                fit_rotation=fit.fit_rotation, pivot_vu=fit.pivot_vu, rcond=fit.pinvh_rcond)
        except ValueError:  # J^T W J overflows: no reading of the geometry exists
            return unmeasured
        return _readonly(np.asarray(cov))

    @functools.cached_property
    def unobservable_directions(self) -> FloatArray:
        """Unit pose directions the geometry does not constrain, shape (K, P)."""
        return null_directions(self.normal_covariance, self._fit.pinvh_rcond)

    @property
    def covariance_unobservable_inf(self) -> FloatArray:
        """:attr:`covariance` with the unobservable directions mapped to ``+inf``
        (and its own null directions;
        :func:`~dtalign.pipeline.observability.covariance_with_unobservable_inf`)."""
        return covariance_with_unobservable_inf(
            self.covariance, self._fit.pinvh_rcond, null_directions=self.unobservable_directions)

    def sigmas_of(self, cov: FloatArray) -> tuple[float, ...]:
        """One-sigma of each pose parameter under ``cov``, ``inf`` where a
        null direction enters: the square roots of its diagonal when no
        direction is unobservable (the usual limb), else of ``cov`` with its
        unobservable directions mapped to ``inf``."""
        if not np.isfinite(cov).all():
            return (math.inf,) * cov.shape[0]
        honest = covariance_with_unobservable_inf(
            cov, self._fit.pinvh_rcond, null_directions=self.unobservable_directions)
        if np.isfinite(honest).all():
            return tuple(_sigma_list(cov))
        return tuple(float(x) for x in _sigmas_from_cov(honest))

    @functools.cached_property
    def sigmas(self) -> tuple[float, ...]:
        """:meth:`sigmas_of` :attr:`covariance`: what :attr:`PolylineFit.sigma_vu` reads."""
        return self.sigmas_of(np.asarray(self.covariance))

    @property
    def covariance_mestimator(self) -> FloatArray:
        """The LM's covariance as :func:`dtalign.lm_subpixel_refine` reports it (``lm.covariance``).

        ``pinvh(J^T W J)`` with ``W`` from the vertex sigmas you passed and the
        final robust weights (:ref:`contract-lm`): as large as those sigmas
        say, whatever the image shows, and blind to the edge model's bias.
        """
        return self._fit.lm.covariance

    @functools.cached_property
    def variance_factor(self) -> float:
        """The a-posteriori residual variance factor ``s^2 = sum(w r^2) / (n - P)``.

        Over the ``n`` vertices with a positive final weight ``w`` (prior
        ``1 / sigma^2`` times the Tukey and polarity factors) and their DT
        residuals ``r``, with ``P`` pose parameters: what
        ``scipy.optimize.curve_fit(absolute_sigma=False)`` multiplies its
        covariance by. 1 when the prior sigmas describe the residuals.
        ``inf`` when degenerate or ``n <= P``.
        """
        lm = self._fit.lm
        if lm.degenerate:
            return math.inf
        w = np.asarray(lm.weights)
        r = np.asarray(lm.residuals_px)
        kept = w > 0.0
        dof = int(np.count_nonzero(kept)) - self._fit.n_params
        if dof <= 0:
            return math.inf
        return float(np.dot(w[kept], r[kept] * r[kept]) / dof)

    @property
    def covariance_scaled(self) -> FloatArray:
        """:attr:`covariance_mestimator` times :attr:`variance_factor`, as
        ``curve_fit(absolute_sigma=False)``: the DT-LM stage's, whatever
        refined it after. All ``inf`` when degenerate."""
        cov = np.asarray(self._fit.lm.covariance)
        factor = self.variance_factor
        if not (math.isfinite(factor) and np.isfinite(cov).all()):
            return _readonly(np.full(cov.shape, np.inf))
        return _readonly(cov * factor)

    @functools.cached_property
    def _sigmas_mestimator(self) -> tuple[float, ...]:
        return self.sigmas_of(np.asarray(self._fit.lm.covariance))

    @property
    def sigma_vu_scaled(self) -> tuple[float, float]:
        """The M-estimator's one-sigma of ``dv`` and ``du`` times ``sqrt(variance_factor)``
        (``inf`` stays ``inf``)."""
        s = math.sqrt(self.variance_factor)
        return self._sigmas_mestimator[0] * s, self._sigmas_mestimator[1] * s

    @property
    def sigma_rotation_rad_scaled(self) -> float | None:
        """The M-estimator's one-sigma of the rotation times ``sqrt(variance_factor)``;
        None when not fitted."""
        if not self._fit.fit_rotation:
            return None
        return self._sigmas_mestimator[2] * math.sqrt(self.variance_factor)


def _pair(x: Any) -> str:
    return f"({float(x[0]):.5g}, {float(x[1]):.5g})"


def _inf(x: Any) -> float:
    """A JSON value read back: None is ``+inf``."""
    return math.inf if x is None else float(x)


#: The fields :meth:`PolylineFit.to_dict` writes as they are (the LM's go by
#: :data:`_LM_KEYS`; the arrays only with ``arrays=True``).
_WRITTEN = tuple(f.name for f in dataclasses.fields(PolylineFit)
                 if f.name not in ("lm", "vertices_vu", "normals_vu", "evidence",
                                   "masked_vertices"))

#: The LM result's fields in :meth:`PolylineFit.to_dict`, by key.
_LM_KEYS = {"dt_offset_vu": "offset_vu", "dt_rotation_rad": "rotation_rad",
            "covariance_mestimator": "covariance", "rms_px": "rms_px",
            "raw_rms_px": "raw_rms_px", "iterations": "iterations", "converged": "converged",
            "degenerate": "degenerate", "inlier_count": "inlier_count"}

#: Where a dict written before a key existed keeps its value.
_LM_FALLBACK = {"dt_offset_vu": "offset_vu", "dt_rotation_rad": "rotation_rad"}

#: The readings :meth:`PolylineFit.to_dict` writes beside the fields
#: (:meth:`PolylineFit.from_dict` computes them again).
_READINGS: dict[str, Callable[[PolylineFit], Any]] = {
    "sigma_vu": lambda f: f.sigma_vu,
    "sigma_vu_unobservable_inf": lambda f: f.sigma_vu,
    "sigma_rotation_rad": lambda f: f.sigma_rotation_rad,
    "variance_factor": lambda f: f.uncertainty.variance_factor,
    "sigma_vu_scaled": lambda f: f.uncertainty.sigma_vu_scaled,
    "status": lambda f: f.status,
    "reasons": lambda f: f.reasons,
    "status_message": lambda f: f.status_message,
    "ambiguity_ratio": lambda f: None if f.ambiguity is None else f.ambiguity.ratio,
    "ambiguity_rival_offset_vu": lambda f: (
        None if f.ambiguity is None or f.ambiguity.rival is None
        else f.ambiguity.rival.offset_vu),
    "covariance": lambda f: f.covariance,
    "uncertainty_source": lambda f: f.uncertainty.source,
    "uncertainty_floor_px": lambda f: f.uncertainty.floor_px,
    "normal_covariance": lambda f: f.uncertainty.normal_covariance,
    "observable_rank": lambda f: f.observable_rank,
    "n_vertices": lambda f: len(f.lm.residuals_px),
    "polarity_rejected": lambda f: int(np.count_nonzero(f.polarity_rejected)),
    "outside_image": lambda f: int(np.count_nonzero(f.outside_image)),
    "tukey_rejected": lambda f: int(f.tukey_rejected.sum()),
}


# ---------------------------------------------------------------------------
# Fitting
# ---------------------------------------------------------------------------


def fit_polyline_products(
    products: ImageProducts,
    vertices_vu: ArrayLike | Polyline,
    normals_vu: ArrayLike | None = None,
    sigmas: ArrayLike | float | None = None,
    *,
    edge_profile: Any = None,
    options: FitOptions | None = None,
    **overrides: Any,
) -> PolylineFit:
    """Fit one polyline against precomputed image products.

    The steps, each once: check the options, then the polyline
    (:func:`~dtalign.pipeline.jobs.check_options`, :func:`~dtalign.pipeline.jobs.item`); find the integer seed of the
    polyline against ``products.edge_mask`` (the polarity-weighted search,
    or the overlap search when ``use_polarity=False``); refine from it with
    the LM of :func:`dtalign.lm_subpixel_refine`; examine the fit against
    its rival basins (:func:`dtalign.pipeline.hypotheses.examine`); judge
    whether an unconverged fit has settled (:func:`~dtalign.pipeline.fit.settle`); refine against
    the image with the edge profile, when there is one; assess it
    (:func:`~dtalign.pipeline.status.assess`).

    Parameters
    ----------
    products : ImageProducts
        From :func:`~dtalign.pipeline.products.prepare_image`.
    vertices_vu : array_like, shape (N, 2), or Polyline
        The model polyline's vertices ``(v, u)`` in pixels, N > 0, with
        ``normals_vu`` and ``sigmas``; or the whole polyline, a
        :class:`~dtalign.Polyline` (its vertices, normals, sigmas, edge kind
        and edge profile), alone.
    normals_vu : array_like, shape (N, 2)
        Unit normals pointing to the bright side of each edge (the polarity
        test accepts a vertex when its normal points up the gradient).
    sigmas : array_like, shape (N,), or float
        Prior one-sigma of each vertex along its normal, pixels, > 0; a
        single number applies to every vertex (see the guide's "Choosing
        the vertex sigmas").
    edge_profile : EdgeProfile, optional
        The polyline's edge profile (:func:`dtalign.sphere_edge_profile`),
        when the polyline is given as arrays: after the DT-LM lock the
        offset is refined against the image's pixels with it
        (:mod:`dtalign.pipeline.profile_fit`).
    options : FitOptions, optional
        The call's options (:class:`~dtalign.api.options.FitOptions`: the
        search window, rotation and pivot, the LM's, ``seeds``,
        ``ambiguity``, ``edge_kind``); the defaults when None.
    **overrides
        Any field of :class:`~dtalign.api.options.FitOptions` by name
        (``search_window_vu=(30, 30)``, ``fit_rotation=True``,
        ``trust_region_px=1.0``): it replaces the field of ``options``.

    Returns
    -------
    PolylineFit

    Raises
    ------
    TypeError
        If ``products`` is not an :class:`~dtalign.pipeline.products.ImageProducts`,
        an option is unknown, or a window entry is not an int.
    ValueError
        On malformed vertices, normals, sigmas, window, pivot or LM
        parameters; the message names the argument.
    """
    vertices_vu, normals_vu, sigmas, edge_profile, kind = polyline_parts(
        vertices_vu, normals_vu, sigmas, edge_profile)
    opts = resolve(options, overrides)
    if not isinstance(products, ImageProducts):
        raise TypeError(f"products must be an ImageProducts, got {type(products).__name__}")
    shared = jobs.plan(products, jobs.check_options(opts))
    item = jobs.item(shared, vertices_vu, normals_vu, jobs.broadcast_sigmas(vertices_vu, sigmas))
    profile, kind = edge_of(shared, edge_profile, kind, item.normals)
    # the seed (with its score surface, when the fit is to be examined), the LM
    # from it, then the examination and the settling
    t1 = time.perf_counter()
    seed, surface = jobs.seed_of(shared, item, surface=opts.examined)
    fit = fit_from(shared, item, seed, time.perf_counter() - t1)
    fit = conclude(finish(fit, shared, item, surface), products, profile, kind)
    _status.log_fit(fit)
    return fit


def polyline_parts(polyline: Any, normals_vu: Any, sigmas: Any, edge_profile: Any = None
                   ) -> tuple[Any, Any, Any, Any, str | None]:
    """``(vertices, normals, sigmas, edge_profile, edge_kind)`` of a one-call fit's
    polyline: a :class:`~dtalign.Polyline` (or a record with its attributes)
    alone, or the arrays; the kind is None where the polyline declares none."""
    if normals_vu is None and sigmas is None and hasattr(polyline, "vertices_vu"):
        own = getattr(polyline, "edge_profile", None)
        if own is not None and edge_profile is not None:
            raise TypeError("edge_profile is given twice: the polyline has one already")
        return (polyline.vertices_vu, polyline.normals_vu, polyline.sigmas,
                own if edge_profile is None else edge_profile,
                getattr(polyline, "edge_kind", None))
    if normals_vu is None or sigmas is None:
        raise TypeError("give a Polyline, or vertices_vu with normals_vu and sigmas")
    return polyline, normals_vu, sigmas, edge_profile, None


def fit_polyline(
    image: ArrayLike,
    vertices_vu: ArrayLike | Polyline,
    normals_vu: ArrayLike | None = None,
    sigmas: ArrayLike | float | None = None,
    *,
    noise_sigma: float | None = None,
    config: ImageDerivativesConfig | None = None,
    edge_profile: Any = None,
    options: FitOptions | None = None,
    mask: ArrayLike | None = None,
    **overrides: Any,
) -> PolylineFit:
    """Fit a model polyline to an image in one call.

    The answer of ``fit_polyline_products(prepare_image(image, noise_sigma,
    config=config, mask=mask), vertices_vu, ...)`` (offsets within 1e-9 px,
    the same status), computed on the region of the frame the polyline can
    reach (:mod:`dtalign.pipeline.region`, :ref:`region`), with the noise
    estimated on the region's pixels when not given (an image with bad
    pixels: the masked products of the whole frame). To fit several
    polylines to one image, use :func:`~dtalign.pipeline.batch.fit_images`
    (their one region), or :func:`~dtalign.pipeline.products.prepare_image`
    once and :func:`fit_polyline_products` per polyline (or
    :func:`~dtalign.pipeline.batch.fit_many`) on the full frame.

    Parameters
    ----------
    image : array_like, shape (H, W), or (H, W, 3 or 4) for colour
        The image (any real dtype; converted to float64). A colour image is
        converted as :func:`~dtalign.pipeline.products.prepare_image` says
        (:mod:`dtalign.api.colour`), and the conversion logged.
    vertices_vu, normals_vu, sigmas, edge_profile
        The model polyline: its arrays (and profile), or a
        :class:`~dtalign.Polyline` alone; see :func:`fit_polyline_products`.
    noise_sigma : float, optional
        Image noise sigma; estimated on the region's pixels
        (:func:`~dtalign.pipeline.products.estimate_noise_sigma` of the
        crop) when None.
    config : ImageDerivativesConfig, optional
        Image-side tunables.
    options : FitOptions, optional
        The call's options (:class:`~dtalign.api.options.FitOptions`);
        the defaults when None.
    mask : array_like of bool, shape (H, W), optional
        Bad pixels (True = bad), which the fit ignores; NaN and inf pixels
        are then bad too (:func:`~dtalign.pipeline.products.prepare_image`).
    **overrides
        Any field of :class:`~dtalign.api.options.FitOptions` by name
        (``search_window_vu``, ``fit_rotation``, ``use_polarity``,
        ``trust_region_px``, ``max_iterations``, ``seeds``, ``ambiguity``, ...).

    Returns
    -------
    PolylineFit

    Examples
    --------
    >>> from dtalign import scenes
    >>> from dtalign.pipeline import fit_polyline
    >>> scene = scenes.disc_scene()
    >>> fit = fit_polyline(scene.image, scene.polyline, search_window_vu=(30, 30))
    >>> [round(x, 1) for x in fit.offset_vu]
    [7.3, -4.6]
    """
    try:  # (a malformed polyline or option: the full frame, and the fit's checks say so)
        verts = polyline_parts(vertices_vu, normals_vu, sigmas)[0]
        region = image_region(image, [verts], resolve(options, overrides), config)
    except (TypeError, ValueError):
        region = None
    products = products_of(image, noise_sigma, config, region, mask)
    fit = fit_polyline_products(products, vertices_vu, normals_vu, sigmas,
                                edge_profile=edge_profile, options=options, **overrides)
    if not holds(products.region, fit):  # it left the region: the frame's, the same noise
        products = prepare_image(image, products.noise_sigma, config=config, mask=mask)
        fit = fit_polyline_products(products, vertices_vu, normals_vu, sigmas,
                                    edge_profile=edge_profile, options=options, **overrides)
    return fit


# ---------------------------------------------------------------------------
# Building fits from the compiled work (:mod:`dtalign.pipeline.jobs`)
# ---------------------------------------------------------------------------


def _evidence_from(found: dict[str, Any], n: int) -> Evidence:
    """The :class:`Evidence` of a :meth:`PolylineFit.to_dict`'s ``"evidence"``;
    a fit saved before the curvature and the second edges has None there."""
    def read(key: str, shape: tuple[int, ...]) -> FloatArray:
        return _readonly(np.asarray(found[key], dtype=np.float64).reshape(shape))

    return Evidence(
        read("residuals", (-1,)), read("jacobian", (n, -1)), read("points_vu", (-1, 2)),
        None if found.get("curvature") is None else read("curvature", (-1,)),
        None if found.get("second_edge_vu") is None else read("second_edge_vu", (-1, 2)),
    )


def edge_of(shared: jobs.Plan, profile: Any, kind: str | None, normals: FloatArray,
            ) -> tuple[Any, str | None]:
    """A polyline's checked edge profile (None without one) and its edge kind:
    its own ``kind``, else the call's option, as the profile allows."""
    if profile is not None:
        profile = check_edge_profile(profile, normals)
        if shared.products.image is None:
            raise ValueError("edge_profile needs the image: these products were built "
                             "without it (use prepare_image)")
    return profile, edge_kind_of(shared.options.edge_kind if kind is None else kind, profile)


def conclude(fit: PolylineFit, products: ImageProducts, profile: Any,
             kind: str | None) -> PolylineFit:
    """The last steps of every fit, the batch's too: the refinement with its
    edge profile (when given, :func:`refined`), its edge kind, the DT's
    :class:`~dtalign.pipeline.uncertainty.Evidence` at its DT-LM pose, from
    which :attr:`PolylineFit.covariance` is formed, and last its
    :func:`~dtalign.pipeline.status.assess`-ment, stored on the result (on
    the batch's threads, for a batch)."""
    fit = _in_frame(_measured(fit, products, profile, kind), products)
    # what cached_property stores on first reading, stored now, once
    fit.__dict__["assessment"] = assess(fit)
    return fit


def _in_frame(fit: PolylineFit, products: ImageProducts) -> PolylineFit:
    """``fit``, made on a region's products (:mod:`dtalign.pipeline.region`),
    in the frame's pixels: its vertices, pivot and evidence points moved by
    the crop's origin (exactly: a whole number), and the frame's shape;
    ``fit`` itself on the full frame's products."""
    region = products.region
    if region is None:
        return fit
    origin = np.asarray(region.origin_vu, dtype=np.float64)
    found = fit.evidence
    if found is not None:
        found = found._replace(points_vu=_readonly(found.points_vu + origin))
    return dataclasses.replace(
        fit, vertices_vu=_readonly(np.asarray(fit.vertices_vu) + origin),
        pivot_vu=(fit.pivot_vu[0] + region.origin_vu[0], fit.pivot_vu[1] + region.origin_vu[1]),
        evidence=found, image_shape=region.frame_shape)


def _measured(fit: PolylineFit, products: ImageProducts, profile: Any,
              kind: str | None) -> PolylineFit:
    """:func:`conclude` but the assessment: what it adds to ``fit``, in one
    rebuild (each step reads only the DT-LM's pose, weights and polyline)."""
    changes: dict[str, Any] = {"edge_kind": kind}
    ref = None
    if profile is not None and not fit.lm.degenerate:  # nothing locked: nothing to refine
        ref = refined(fit, products, profile, kind)
        changes.update(profile=ref, timings_s={**fit.timings_s, "profile": ref.time_s})
        if ref.accepted:
            changes["offset_vu"] = ref.offset_vu
    # the detector's own edge threshold: a second edge is one it keeps
    threshold = edge_threshold(products.config, products.noise_sigma)
    found = None if fit.lm.degenerate else evidence(
        fit, products.edge_dt, (products.gradient_magnitude, products.gradient_vu), threshold)
    changes["evidence"] = found
    if kind is None and profile is None and found is not None and products.image is not None:
        # nothing declared: read the kind off the image, so that the floor
        # (uncertainty.source_of) knows a limb's or terminator's bias
        changes["inferred_edge_kind"] = infer_edge_kind(
            products.image, found.points_vu, fit.normals_vu, fit.lm.weights)
    if found is not None and not (ref is not None and ref.accepted):
        # the DT-LM pose less the second edges' pull (uncertainty.second_edge_pull):
        # a thin crescent's other edge pushes the detected edge away from it
        beta = second_edge_pull(fit, found)
        if beta.any():
            lm = fit.lm
            changes["offset_vu"] = (lm.offset_vu[0] - float(beta[0]),
                                    lm.offset_vu[1] - float(beta[1]))
            if beta.shape[0] == 3:
                changes["rotation_rad"] = lm.rotation_rad - float(beta[2])
    out = dataclasses.replace(fit, **changes)
    if products.mask is not None:
        from .masked import masked_vertex_count  # SciPy: only for a masked image

        out = dataclasses.replace(out, masked_vertices=masked_vertex_count(
            out.transform(out.vertices_vu), products.mask))
    return out


def refined(fit: PolylineFit, products: ImageProducts, profile: Any,
            kind: str | None = None) -> ProfileRefinement:
    """``fit`` refined against ``products.image`` with ``profile``
    (:func:`~dtalign.pipeline.profile_fit.refine_with_profile`) from its DT-LM
    pose; an accepted refinement of a fit with an ambiguous rival basin is
    run again from the rival (:func:`rival_check`)."""
    assert products.image is not None
    ref = refine_with_profile(
        products.image, profile, np.asarray(fit.vertices_vu), fit.lm.offset_vu,
        rotation_rad=fit.rotation_rad, pivot_vu=fit.pivot_vu, mask=products.mask,
    )
    return rival_check(fit, ref, products.image, profile, kind, products.mask)


def rival_check(fit: PolylineFit, ref: ProfileRefinement, image: FloatArray, profile: Any,
                kind: str | None, mask: NDArray[np.bool_] | None = None) -> ProfileRefinement:
    """``ref`` with where the refinement lands from the rival basin's start,
    when ``fit``'s DT stage was ambiguous across the edge and ``ref`` was
    accepted; ``ref`` itself otherwise.

    The rival's refinement agrees when it is accepted too and lands within
    :data:`~dtalign.pipeline.profile_fit.RIVAL_AGREEMENT_SIGMAS` of ``ref``'s
    one-sigma (its covariance plus the profile floor of
    :mod:`dtalign.pipeline.uncertainty`, the largest axis): the photometry
    then picks the same pose from either basin, which
    :func:`~dtalign.pipeline.status.assess` reads as no ambiguity.
    """
    amb = fit.ambiguity
    if not (ref.accepted and amb is not None and amb.ambiguous and amb.rival is not None
            and not amb.along_unobservable):
        return ref
    rival = refine_with_profile(image, profile, np.asarray(fit.vertices_vu),
                                amb.rival.offset_vu, rotation_rad=amb.rival.rotation_rad,
                                pivot_vu=fit.pivot_vu, mask=mask)
    floor = floor_px("profile_terminator" if kind == "terminator" else "profile", ref)
    cov = np.asarray(ref.covariance, dtype=np.float64) + floor**2 * np.eye(2)
    sigma = math.sqrt(float(np.linalg.eigvalsh(cov).max())) if np.isfinite(cov).all() else math.inf
    apart = math.hypot(rival.offset_vu[0] - ref.offset_vu[0], rival.offset_vu[1] - ref.offset_vu[1])
    agrees = bool(rival.accepted and apart <= RIVAL_AGREEMENT_SIGMAS * sigma)
    return dataclasses.replace(ref, rival_offset_vu=rival.offset_vu, rival_agrees=agrees,
                               time_s=ref.time_s + rival.time_s)


def _shape_of(products: ImageProducts) -> tuple[int, int]:
    """``(H, W)`` of the image the products were made from (their edge DT's)."""
    h, w = np.shape(products.edge_dt)[:2]
    return int(h), int(w)


def new_fit(shared: jobs.Plan, lm: LMRefineResult, coarse: tuple[int, int],
            pivot: tuple[float, float], distance: float, vertices: FloatArray,
            normals: FloatArray, timings: dict[str, float]) -> PolylineFit:
    """The one constructor of the pipeline's :class:`PolylineFit`: the LM's
    result ``lm`` from the integer seed ``coarse``, of the polyline
    ``vertices``, ``normals`` with its pivot, fitted with the call's ``shared``
    plan. The later steps (:func:`finish`, :func:`conclude`) add to it."""
    p = shared.products
    a = shared.lm
    return PolylineFit(
        offset_vu=lm.offset_vu, rotation_rad=lm.rotation_rad, coarse_offset_vu=coarse,
        at_window_edge=jobs.at_window_edge(coarse[0], coarse[1], shared.window),
        lm=lm, search_window_vu=shared.window, fit_rotation=a.fit_rotation,
        pivot_vu=pivot, pivot_distance_px=float(distance), noise_sigma=p.noise_sigma,
        vertices_vu=vertices, normals_vu=normals, pinvh_rcond=a.pinvh_rcond,
        tukey_c=a.tukey_c, timings_s=timings, image_shape=_shape_of(p),
    )


def fit_from(shared: jobs.Plan, it: jobs.Item, coarse: tuple[int, int],
             coarse_s: float = 0.0) -> PolylineFit:
    """The LM from the integer seed ``coarse`` (a multi-start's other starts
    too), as a :class:`PolylineFit`; ``coarse_s`` is the seed's search time."""
    t2 = time.perf_counter()
    lm = fit_checked(shared.lm._replace(
        vertices=it.vertices, normals=it.normals, sigmas=it.sigmas,
        offset=(float(coarse[0]), float(coarse[1])), pivot=it.pivot, pivot_distance=it.distance,
    ))
    t3 = time.perf_counter()
    timings = {**shared.products.timings_s, "coarse": coarse_s, "lm": t3 - t2}
    return new_fit(shared, lm, coarse, it.pivot, it.distance, it.vertices, it.normals, timings)


def finish(fit: PolylineFit, shared: jobs.Plan, it: jobs.Item,
           surface: Any = None) -> PolylineFit:
    """The steps after the LM that every fit takes, the batch's too: the
    examination against rival basins (when the options ask for it; from
    ``surface``, the coarse score surface of the fit's seed, when the caller
    has it), then :func:`settle`."""
    if shared.options.examined:
        fit = _hypotheses.examine(fit, shared, it, surface=surface,
                                  refit=lambda seed: fit_from(shared, it, seed))
    return settle(fit, shared, it)


def needs_settling(fit: PolylineFit) -> bool:
    """Whether :func:`settle` has anything to judge (an unconverged, measured fit)."""
    return not (fit.lm.converged or fit.lm.degenerate) and fit.settling is None


def settle(fit: PolylineFit, shared: jobs.Plan, it: jobs.Item) -> PolylineFit:
    """``fit`` with its :class:`~dtalign.pipeline.status.Settling` when its LM did not converge.

    The LM is deterministic, so running it again from the fit's start
    (``coarse_offset_vu``) with ``iterations - SETTLE_ITERATIONS`` iterations
    gives the pose it held that many iterations before it stopped; with
    fewer iterations than that, the start is the earlier pose. The movement
    between the two, in pixels and in units of the fit's one-sigma, says
    whether further iterations could still change the answer: what
    :attr:`~dtalign.pipeline.status.FitReason.NOT_CONVERGED` means. A
    converged or degenerate fit is returned as it is.
    """
    if not needs_settling(fit):
        return fit
    lm = fit.lm
    a = shared.lm
    start = (float(fit.coarse_offset_vu[0]), float(fit.coarse_offset_vu[1]))
    k = lm.iterations - SETTLE_ITERATIONS
    if k > 0:
        earlier = fit_checked(a._replace(
            vertices=it.vertices, normals=it.normals, sigmas=it.sigmas, offset=start,
            pivot=it.pivot, pivot_distance=it.distance, max_iterations=k,
        ))
        before = (*earlier.offset_vu, earlier.rotation_rad)
        span = SETTLE_ITERATIONS
    else:
        before = (*start, a.rotation)
        span = lm.iterations
    d = np.array([lm.offset_vu[0] - before[0], lm.offset_vu[1] - before[1],
                  lm.rotation_rad - before[2]])
    shift_px = float(math.hypot(d[0], d[1]) + abs(d[2]) * fit.pivot_distance_px)
    p = fit.n_params
    cov = np.asarray(lm.covariance, dtype=np.float64)
    if np.isfinite(cov).all():
        # the information the covariance holds (its pseudoinverse): a movement
        # along a direction the fit does not observe weighs nothing
        info = np.linalg.pinv(cov, rcond=fit.pinvh_rcond, hermitian=True)
        shift_sigmas = float(math.sqrt(max(float(d[:p] @ info @ d[:p]), 0.0)))
    else:
        shift_sigmas = math.inf
    ok = shift_sigmas <= SETTLE_SIGMAS or shift_px <= a.step_tolerance
    return dataclasses.replace(fit, settling=Settling(span, shift_px, shift_sigmas, ok))


def wrap(shared: jobs.Plan, batch: jobs.Batch, out: tuple[Any, ...], lo: int,
         hi: int) -> list[PolylineFit]:
    """:class:`PolylineFit` objects of the compiled results ``lo:hi`` in ``out``
    (:func:`~dtalign.pipeline.jobs.readonly_views` of
    :func:`~dtalign.pipeline.jobs.loop_inputs`' outputs; ``timings_s``
    without ``fit``, which the caller adds)."""
    if hi <= lo:
        return []
    (coarse, poses, iterations, converged, covs, rms, raw_rms, inliers, degenerate, r_all,
     w_all) = out
    p = shared.products
    a = shared.lm
    pts, nrm = batch.pts, batch.nrm
    # Per-fit values as Python scalars in bulk, and read-only arrays whose
    # slices each fit keeps.
    bounds = batch.starts[lo : hi + 1].tolist()
    timings = p.timings_s
    fits = []
    for j, (pose, (dv, du), n_iter, conv, rms_j, raw_j, inl, deg, pv, dist) in enumerate(zip(
        poses[lo:hi].tolist(), coarse[lo:hi].tolist(), iterations[lo:hi].tolist(),
        converged[lo:hi].tolist(), rms[lo:hi].tolist(), raw_rms[lo:hi].tolist(),
        inliers[lo:hi].tolist(), degenerate[lo:hi].tolist(), batch.pivots[lo:hi].tolist(),
        batch.distances[lo:hi].tolist(), strict=True,
    )):
        s_j, e_j = bounds[j], bounds[j + 1]
        residuals = r_all[s_j:e_j]
        lm = LMRefineResult(
            offset_vu=(pose[0], pose[1]), rotation_rad=pose[2], covariance=covs[lo + j],
            residuals_px=residuals, weights=w_all[s_j:e_j],
            rms_px=rms_j, raw_rms_px=raw_j, iterations=n_iter, converged=conv,
            inlier_count=inl, degenerate=deg,
            # the rejected vertices carry the penalty (PolylineFit.polarity_rejected)
            polarity_rejected_count=int(
                np.count_nonzero(residuals == POLARITY_PENALTY_RESIDUAL)
            ) if a.use_polarity else 0,
        )
        fits.append(new_fit(shared, lm, (dv, du), (pv[0], pv[1]), dist, pts[s_j:e_j],
                            nrm[s_j:e_j], dict(timings)))
    return fits
