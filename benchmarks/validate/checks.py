"""The renderer's own validation: closed forms a right render must reproduce.

Each check is a render (:data:`CHECKS`: a Lambert body of albedo 1, no PSF,
no noise, 1x with 256 stratified samples a pixel, a 96 x 96 frame) and a
measurement of it (:func:`measure`), in the units of :mod:`.render` (a
Lambert surface reads ``A cos i``; with the Sun's irradiance 1 instead of
``pi`` that is the familiar ``A cos(i) / pi``):

``centroid``
    a sphere at phase 0 at a sub-pixel centre: the brightness centroid is
    the planted centre (the disc is symmetric) -- the pixel convention.
``flux``
    a sphere at phase 60 deg: the total flux is ``(2/3) pi R^2 Phi(a)``, the
    Lambert sphere's phase law ``Phi(a) = (sin a + (pi - a) cos a) / pi``.
``centre_radiance``
    a sphere at phase 40 deg centred on a pixel: that pixel reads
    ``cos(40 deg)`` (the mean of ``cos e`` over the pixel is lower by
    ``1 / (12 R^2)``, 1e-4 at this radius).
``terminator_90``
    a sphere at phase 90 deg, the light at 30 deg (oblique to the pixel
    axes): the lit half reads ``d / R`` at a distance ``d`` past the line
    through the centre across the Sun's direction; a straight-line fit of
    the fully lit pixels away from the limb puts the line's zero at the
    centre, and every pixel a pixel beyond it on the night side is 0.
``mesh_centroid``, ``mesh_flux``
    the same two on the UV-sphere mesh the ellipsoid and crater families
    render (as an ellipsoid of equal axes through ``to_world``).
"""

from __future__ import annotations

import math

import numpy as np

FRAME_PX = 96
RADIUS_PX = 30.0

#: name: (body keywords, shape, tolerance, what the tolerance bounds)
CHECKS = {
    "centroid": (dict(center_vu=(47.137, 48.291), phase_deg=0.0, illumination_deg=0.0),
                 "sphere", 2e-3, "px from the planted centre"),
    "flux": (dict(center_vu=(47.6, 48.3), phase_deg=60.0, illumination_deg=30.0),
             "sphere", 1e-3, "relative to the analytic flux"),
    "centre_radiance": (dict(center_vu=(48.0, 48.0), phase_deg=40.0, illumination_deg=120.0),
                        "sphere", 1e-3, "relative to cos(i)"),
    "terminator_90": (dict(center_vu=(47.71, 48.43), phase_deg=90.0, illumination_deg=30.0),
                      "sphere", 2e-3, "px from the centre"),
    "mesh_centroid": (dict(center_vu=(47.137, 48.291), phase_deg=0.0, illumination_deg=0.0),
                      "ellipsoid", 2e-3, "px from the planted centre"),
    "mesh_flux": (dict(center_vu=(47.6, 48.3), phase_deg=60.0, illumination_deg=30.0),
                  "ellipsoid", 1e-3, "relative to the analytic flux"),
}


def render_check(name: str) -> np.ndarray:
    """The check's render (Mitsuba)."""
    from .render import Body, render

    kw, shape, _, _ = CHECKS[name]
    body = Body(radius_px=RADIUS_PX, shape=shape, axes_px=(RADIUS_PX,) * 3, **kw)
    return render(body, FRAME_PX, 1, 256, seed=7)


def lambert_phase_flux(radius_px: float, phase_deg: float) -> float:
    """Total flux of a Lambert sphere of albedo 1 (``A cos i`` units)."""
    a = math.radians(phase_deg)
    return 2.0 / 3.0 * math.pi * radius_px ** 2 * (math.sin(a) + (math.pi - a) * math.cos(a)) / math.pi


def measure(name: str, image: np.ndarray) -> dict:
    """The check's measurement on its render: ``value`` (the deviation), ``tolerance``, ``ok``."""
    kw, _, tol, unit = CHECKS[name]
    cv, cu = kw["center_vu"]
    v, u = np.indices(image.shape, dtype=float)
    out: dict = {"name": name, "tolerance": tol, "unit": unit}
    if name.endswith("centroid"):
        total = image.sum()
        dv, du = (v * image).sum() / total - cv, (u * image).sum() / total - cu
        out.update(value=float(math.hypot(dv, du)), detail={"dv": float(dv), "du": float(du)})
    elif name.endswith("flux"):
        want = lambert_phase_flux(RADIUS_PX, kw["phase_deg"])
        out.update(value=float(abs(image.sum() / want - 1.0)),
                   detail={"flux": float(image.sum()), "analytic": want})
    elif name == "centre_radiance":
        want = math.cos(math.radians(kw["phase_deg"]))
        got = float(image[int(cv), int(cu)])
        out.update(value=abs(got / want - 1.0), detail={"pixel": got, "cos_i": want})
    else:
        ill = math.radians(kw["illumination_deg"])
        s = np.array([-math.cos(ill), math.sin(ill)])
        d = (v - cv) * s[0] + (u - cu) * s[1]
        rho = np.hypot(v - cv, u - cu) / RADIUS_PX
        lit = (d > 1.5) & (rho < 0.85)
        slope, intercept = np.polyfit(d[lit], image[lit], 1)
        zero = -intercept / slope
        night = (d < -1.0) & (rho < 0.95)
        out.update(value=float(abs(zero)),
                   detail={"zero_px": float(zero), "slope_times_R": float(slope * RADIUS_PX),
                           "night_max": float(image[night].max())})
        out["ok"] = bool(abs(zero) <= tol and image[night].max() == 0.0
                         and abs(slope * RADIUS_PX - 1.0) < 1e-3)
        return out
    out["ok"] = bool(out["value"] <= tol)
    return out
