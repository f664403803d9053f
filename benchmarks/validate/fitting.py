"""Fit a validation scene with dtalign's public API, and score each fit against its truth.

Three fits of every scene, all with ``search_window_vu=(8, 8)``:

``plain``
    the guide's call as a new user writes it: ``fit_polyline(image,
    P.vertices_vu, P.normals_vu, P.sigmas)``, the kind not declared;
``plain_kind``
    the same with ``edge_kind=P.edge_kind`` (the profiles page's
    *Terminators*);
``profile``
    the profiles page's call: ``edge_profile=sphere_edge_profile(...,
    edge=P.edge_kind, law=..., psf_sigma_px=None)`` (the PSF estimated), a
    Lambert profile unless the family declares its law.

``P`` is :func:`dtalign.sphere_limb_polyline` (the sunlit half) or
:func:`dtalign.sphere_terminator_polyline` at the model centre; for the
ellipsoid, its exact outline and Lambert profile (:mod:`.geometry`).

Scores: the error against the planted offset (px), the status and reasons,
whether the refinement was accepted, the squared Mahalanobis distance of
the error under the pipeline's :attr:`~dtalign.pipeline.PolylineFit.covariance`
(the one ``sigma_vu`` reads, which :doc:`uncertainty` calls the pipeline's,
built to cover the truth; the tables use it), under ``covariance_scaled``
and under ``covariance_mestimator``, with directions the covariance does
not observe left out (a pseudoinverse). An exception is a finding: its type
and message are recorded and the other fits go on.
"""

from __future__ import annotations

import time

import numpy as np

from dtalign import (
    fit_polyline,
    sphere_edge_profile,
    sphere_limb_polyline,
    sphere_terminator_polyline,
)

from .geometry import ellipsoid_limb_model

METHODS = ("plain", "plain_kind", "profile")
SEARCH_WINDOW_VU = (8, 8)
#: chi-square quantiles, 2 degrees of freedom: 95 % and 99.9 %
CHI2_95, CHI2_999 = 5.991, 13.8155


def model(p: dict):
    """The model polyline ``(vertices, normals, sigmas, edge_kind)`` and its edge profile."""
    centre = tuple(p["model_center_vu"])
    sphere = dict(center_vu=centre, radius_px=p["radius_px"], phase_deg=p["phase_deg"],
                  illumination_deg=p["illumination_deg"])
    if p["shape"] == "ellipsoid":
        v, n, s, profile = ellipsoid_limb_model(centre, tuple(p["axes_px"]),
                                                tuple(p["angles_deg"]), p["phase_deg"],
                                                p["illumination_deg"])
        return (v, n, s, "limb"), profile
    if p["edge"] == "limb":
        poly = sphere_limb_polyline(**sphere)
    else:
        poly = sphere_terminator_polyline(**sphere)
    law = {"law": p["profile_law"]}
    if p["profile_law"] == "minnaert":
        law["minnaert_k"] = p["profile_k"]
    profile = sphere_edge_profile(poly.vertices_vu, **sphere, edge=poly.edge_kind,
                                  psf_sigma_px=None, **law)
    return (poly.vertices_vu, poly.normals_vu, poly.sigmas, poly.edge_kind), profile


def _d2(err: np.ndarray, cov) -> float:
    c = np.asarray(cov, dtype=float)[:2, :2]
    if not np.isfinite(c).all():
        return float("nan")
    return float(err @ np.linalg.pinv(c, rcond=1e-9, hermitian=True) @ err)


def score(fit, truth: np.ndarray) -> dict:
    """What one fit says and how far it is from the truth."""
    err = np.asarray(fit.offset_vu, dtype=float) - truth
    prof = fit.profile
    return dict(
        error_px=float(np.hypot(*err)), error_vu=err.tolist(), offset_vu=list(fit.offset_vu),
        status=str(fit.status), reasons=[str(r) for r in fit.reasons],
        accepted=None if prof is None else bool(prof.accepted),
        profile_reason=None if prof is None else prof.reason,
        sigma_vu=list(fit.sigma_vu), sigma_vu_scaled=list(fit.uncertainty.sigma_vu_scaled),
        d2=_d2(err, fit.covariance), d2_scaled=_d2(err, fit.uncertainty.covariance_scaled),
        d2_mestimator=_d2(err, fit.uncertainty.covariance_mestimator),
        psf_sigma_px=None if prof is None else float(prof.psf_sigma_px),
        misfit=None if prof is None else float(getattr(prof, "misfit", float("nan"))),
        edge_scatter_px=None if prof is None else float(getattr(prof, "edge_scatter_px",
                                                                  float("nan"))),
        edge_noise_px=None if prof is None else float(getattr(prof, "edge_noise_px",
                                                                float("nan"))),
        uncertainty_source=fit.uncertainty.source,
        inferred_edge_kind=getattr(fit, "inferred_edge_kind", None),
        exception=None,
    )


def fit_scene(p: dict, image: np.ndarray) -> list[dict]:
    """The three fits of one scene, one record each (an exception recorded, not raised)."""
    truth = np.asarray(p["offset_vu"], dtype=float)
    records = []
    try:
        (verts, normals, sigmas, kind), profile = model(p)
    except Exception as exc:  # a finding: the model's builders raised
        return [dict(method=m, exception=f"{type(exc).__name__}: {exc}", status="raised")
                for m in METHODS]
    calls = {"plain": {}, "plain_kind": {"edge_kind": kind}, "profile": {"edge_profile": profile}}
    for method in METHODS:
        t0 = time.perf_counter()
        try:
            fit = fit_polyline(image, verts, normals, sigmas, search_window_vu=SEARCH_WINDOW_VU,
                               **calls[method])
            rec = score(fit, truth)
        except Exception as exc:  # a finding: record it, fit the rest
            rec = dict(exception=f"{type(exc).__name__}: {exc}", status="raised")
        rec.update(method=method, time_s=time.perf_counter() - t0)
        records.append(rec)
    return records


def confidently_wrong(rec: dict) -> bool:
    """``ok`` and outside the 99.9 % ellipse of the pipeline's covariance, or > 1 px off."""
    if rec.get("status") != "ok":
        return False
    d2 = rec["d2"]
    return bool(rec["error_px"] > 1.0 or not np.isfinite(d2) or d2 > CHI2_999)
