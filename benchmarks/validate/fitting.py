"""Fit a validation scene with dtalign's public API, and score each fit against its truth.

Three fits of every scene (four of an ellipsoid's), all with ``search_window_vu=(8, 8)``:

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
:func:`dtalign.sphere_terminator_polyline` at the model centre, and the
profile :func:`dtalign.sphere_edge_profile`; for the ellipsoid,
:func:`dtalign.ellipsoid_limb_polyline` or
:func:`dtalign.ellipsoid_terminator_polyline` and
:func:`dtalign.ellipsoid_edge_profile`, with the render's attitude. The
ellipsoid's scenes have a fourth fit:

``sphere_profile``
    ``P`` the ellipsoid's, the profile a sphere's of the ellipsoid's mean
    radius, one sphere per vertex placed so that the vertex lies on its
    limb (terminator) with the vertex's normal (:func:`sphere_profile`):
    what the ellipsoid's own profile gains over a sphere's.

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
    EdgeProfile,
    Polyline,
    ellipsoid_edge_profile,
    ellipsoid_limb_polyline,
    ellipsoid_terminator_polyline,
    fit_polyline,
    sphere_edge_profile,
    sphere_limb_polyline,
    sphere_terminator_polyline,
)

from .geometry import camera_rotation

METHODS = ("plain", "plain_kind", "profile", "sphere_profile")
#: a sphere terminator's points the sphere profile's placement interpolates between
_PROBE_VERTICES = 20001
SEARCH_WINDOW_VU = (8, 8)
#: chi-square quantiles, 2 degrees of freedom: 95 % and 99.9 %
CHI2_95, CHI2_999 = 5.991, 13.8155


def model(p: dict):
    """The model polyline ``(vertices, normals, sigmas, edge_kind)`` and its edge profile."""
    centre = tuple(p["model_center_vu"])
    light = dict(phase_deg=p["phase_deg"], illumination_deg=p["illumination_deg"])
    law = {"law": p["profile_law"]}
    if p["profile_law"] == "minnaert":
        law["minnaert_k"] = p["profile_k"]
    if p["shape"] == "ellipsoid":
        body = dict(center_vu=centre, axes_px=tuple(p["axes_px"]),
                    rotation=camera_rotation(tuple(p["angles_deg"])))
        build = ellipsoid_limb_polyline if p["edge"] == "limb" else ellipsoid_terminator_polyline
        poly = build(**body, **light)
        profile = ellipsoid_edge_profile(poly.vertices_vu, **body, **light, edge=poly.edge_kind,
                                         psf_sigma_px=None, **law)
    else:
        sphere = dict(center_vu=centre, radius_px=p["radius_px"], **light)
        build = sphere_limb_polyline if p["edge"] == "limb" else sphere_terminator_polyline
        poly = build(**sphere)
        profile = sphere_edge_profile(poly.vertices_vu, **sphere, edge=poly.edge_kind,
                                      psf_sigma_px=None, **law)
    return (poly.vertices_vu, poly.normals_vu, poly.sigmas, poly.edge_kind), profile


def _angle(vec: np.ndarray) -> np.ndarray:
    return np.arctan2(vec[:, 1], vec[:, 0])


def sphere_profile(p: dict, poly: Polyline) -> EdgeProfile:
    """A sphere's Lambert profile of the ellipsoid's mean radius at each vertex of ``poly``.

    Vertex ``k`` gets :func:`dtalign.sphere_edge_profile` of the sphere of
    radius ``mean(axes_px)`` whose limb (terminator) passes through it with
    the same normal: the limb's centre is the vertex plus the radius along
    the inward normal; the terminator's is found on a dense sphere
    terminator by the direction of its normal. The profiles are stacked.
    """
    radius = float(np.mean(p["axes_px"]))
    light = dict(phase_deg=p["phase_deg"], illumination_deg=p["illumination_deg"])
    verts, normals = poly.vertices_vu, poly.normals_vu
    if poly.edge_kind == "limb":
        centres = verts + radius * normals
    else:
        probe = sphere_terminator_polyline((0.0, 0.0), radius, **light,
                                           n_vertices=_PROBE_VERTICES)
        ang = np.unwrap(_angle(probe.normals_vu))
        if ang[-1] < ang[0]:
            ang, probe_v = ang[::-1], probe.vertices_vu[::-1]
        else:
            probe_v = probe.vertices_vu
        target = ang[0] + np.mod(_angle(normals) - ang[0], 2 * np.pi)
        at = np.stack([np.interp(target, ang, probe_v[:, i]) for i in (0, 1)], axis=1)
        centres = verts - at
    parts = [sphere_edge_profile(verts[k:k + 1], center_vu=tuple(centres[k]), radius_px=radius,
                                 edge=poly.edge_kind, psf_sigma_px=None, **light)
             for k in range(len(poly))]
    return EdgeProfile(offsets_px=parts[0].offsets_px,
                       values=np.vstack([q.values for q in parts]),
                       normals_vu=np.vstack([q.normals_vu for q in parts]),
                       curvature_px=np.concatenate([q.curvature_px for q in parts]),
                       psf_sigma_px=None, edge=poly.edge_kind,
                       shape_values=np.vstack([q.shape_values for q in parts]))


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


def methods_of(p: dict) -> tuple[str, ...]:
    """The fits of a scene: the three, and ``sphere_profile`` for an ellipsoid."""
    return METHODS if p["shape"] == "ellipsoid" else METHODS[:3]


def fit_scene(p: dict, image: np.ndarray) -> list[dict]:
    """The fits of one scene (:func:`methods_of`), one record each (an exception recorded,
    not raised)."""
    truth = np.asarray(p["offset_vu"], dtype=float)
    records = []
    methods = methods_of(p)
    try:
        (verts, normals, sigmas, kind), profile = model(p)
        calls = {"plain": {}, "plain_kind": {"edge_kind": kind},
                 "profile": {"edge_profile": profile}}
        if "sphere_profile" in methods:
            poly = Polyline("model", verts, normals, sigmas, edge_kind=kind)
            calls["sphere_profile"] = {"edge_profile": sphere_profile(p, poly)}
    except Exception as exc:  # a finding: the model's builders raised
        return [dict(method=m, exception=f"{type(exc).__name__}: {exc}", status="raised")
                for m in methods]
    for method in methods:
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
