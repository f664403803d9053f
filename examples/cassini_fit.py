"""Fit real Cassini frames: displace the drawn model, let dtalign bring it back.

Two Cassini ISS narrow-angle frames ship with the project (in
``shared/data/cassini`` beside the repository, or wherever the environment
variable ``DTALIGN_CASSINI_DIR`` points) as summary PNGs: a grey image with
the navigation model drawn over it in pure red. For each frame this script

1. splits the PNG into a clean grey image and the red overlay
   (:func:`dtalign.io.cassini.load_cassini_overlay_frame`),
2. traces the overlay into a model polyline with normals
   (:func:`dtalign.io.cassini.overlay_polylines`),
3. fits the overlay as drawn (the *base* fit: where the image's edges are
   relative to the drawing), then the overlay displaced by a known offset,
   and checks that the fit returns base + displacement,
4. reports the uncertainty, including the rank-deficient reading of the
   straight ring edges, and writes a figure of each displaced fit.

With ``--profile`` it fits each frame with the edge profile its geometry
gives beside the plain fit (:func:`profile_comparison`): for Tethys a
sphere built on the overlay's circle (:func:`dtalign.io.cassini.overlay_circle`),
the phase angle from the sidecar YAML, Minnaert's exponent measured on the
disc and the Sun's in-image direction looked for in the disc's brightness
(:func:`sun_direction_evidence`); for the Keeler ring, whose edges are
not a sphere's, the plain fit and what a generic step profile does.

Run::

    python examples/cassini_fit.py [--data DIR] [--out DIR] [--profile]
"""

from __future__ import annotations

import argparse
import math
import os
import re
import sys
from pathlib import Path

import numpy as np

from dtalign import EdgeProfile, io, pipeline, sphere_edge_profile
from dtalign.io import cassini

FRAMES = {
    "tethys": dict(
        file="N1634226853_1_CALIB.png",
        title="Tethys limb (N1634226853)",
        shape="limb",
        n_lines=1,
        displacement=(6.0, -4.0),
        window=(15, 15),
    ),
    "keeler": dict(
        file="N1863268207_1_CALIB.png",
        title="Keeler gap ring edges (N1863268207)",
        shape="lines",
        n_lines=2,
        displacement=(5.0, 7.0),
        window=(30, 30),
    ),
}


def find_data_dir(explicit: str | None = None) -> Path | None:
    """``--data``, else ``$DTALIGN_CASSINI_DIR``, else ``<repo>/../shared/data/cassini``."""
    candidates = [explicit, os.environ.get("DTALIGN_CASSINI_DIR")]
    candidates.append(str(Path(__file__).resolve().parents[1].parent / "shared" / "data" / "cassini"))
    for c in candidates:
        if c and (Path(c) / FRAMES["tethys"]["file"]).is_file():
            return Path(c)
    return None


def fit_frame(data_dir: Path, key: str) -> dict:
    """Base and displaced fits of one frame; returns everything worth printing."""
    spec = FRAMES[key]
    frame = cassini.load_cassini_overlay_frame(data_dir / spec["file"])
    lines = cassini.overlay_polylines(frame, shape=spec["shape"], n_lines=spec["n_lines"])
    model = io.concatenate_polylines(lines, name=key)
    products = pipeline.prepare_image(frame.image)  # noise sigma estimated (MAD)
    d = np.asarray(spec["displacement"])

    def fit(vertices):
        return pipeline.fit_polyline_products(
            products, vertices, model.normals_vu, model.sigmas, search_window_vu=spec["window"]
        )

    base = fit(model.vertices_vu)
    displaced_vertices = model.vertices_vu - d  # the fit must return base + d
    moved = fit(displaced_vertices)
    error = np.subtract(moved.offset_vu, d) - base.offset_vu
    normal = lines[0].normals_vu[0]
    return dict(
        spec=spec,
        frame=frame,
        lines=lines,
        model=model,
        products=products,
        base=base,
        moved=moved,
        displaced_vertices=displaced_vertices,
        error=error,
        normal=normal,
    )


def report(key: str, r: dict) -> str:
    spec, base, moved = r["spec"], r["base"], r["moved"]
    f3 = lambda x: f"{x:+.3f}" if math.isfinite(x) else "inf"  # noqa: E731
    out = [f"== {spec['title']} =="]
    out.append(
        f"model: {len(r['model'])} vertices traced from the overlay "
        f"({', '.join(str(len(p)) for p in r['lines'])} per curve); "
        f"noise sigma estimated {r['products'].noise_sigma:.3f} DN"
    )
    out.append(
        f"base fit (overlay as drawn): offset ({f3(base.offset_vu[0])}, {f3(base.offset_vu[1])}) px"
    )
    dv, du = spec["displacement"]
    out.append(
        f"displaced by ({dv:+.2f}, {du:+.2f}) px: coarse seed {moved.coarse_offset_vu}, "
        f"fit ({f3(moved.offset_vu[0])}, {f3(moved.offset_vu[1])}) px"
    )
    ev, eu = r["error"]
    n = r["normal"]
    out.append(
        f"fit - displacement - base = ({ev:+.4f}, {eu:+.4f}) px; "
        f"across the edge (normal {n[0]:+.4f}, {n[1]:+.4f}): {float(r['error'] @ n):+.4f} px"
    )
    out.append(
        f"inliers {moved.lm.inlier_count}/{len(r['model'])}, polarity-rejected "
        f"{int(moved.polarity_rejected.sum())}, Tukey-rejected {int(moved.tukey_rejected.sum())}, "
        f"rms {moved.lm.rms_px:.3f} px"
    )
    sv, su = moved.sigma_vu
    out.append(f"sigma_vu (noise, correlated neighbours, edge-model floor): "
               f"sigma_v {sv:.4f}, sigma_u {su:.4f} px")
    cn = np.asarray(moved.uncertainty.normal_covariance)
    out.append(
        f"geometry (normals): observable rank {moved.observable_rank} of 2; "
        f"normal-covariance eigenvalues {np.array2string(np.linalg.eigvalsh(cn), precision=3)}"
    )
    for e in moved.unobservable_directions:
        t = e / np.hypot(e[0], e[1])
        along = float(t @ cn @ t)
        out.append(
            f"  unobservable direction ({t[0]:+.4f}, {t[1]:+.4f}): pinvh variance {along:.1e} "
            f"(zero: no information); sigma across the edge {moved.sigma_along(n):.4f} px"
        )
    if moved.at_window_edge:
        out.append("WARNING: coarse seed on the search-window edge")
    return "\n".join(out)


def figure(key: str, r: dict, out_dir: Path) -> Path:
    from dtalign.plotting import plot_fit

    path = out_dir / f"cassini_{key}.png"
    dv, du = r["spec"]["displacement"]
    moved = r["moved"]
    title = (
        f"{r['spec']['title']}: overlay displaced by ({dv:+.1f}, {du:+.1f}) px\n"
        f"fit ({moved.offset_vu[0]:+.2f}, {moved.offset_vu[1]:+.2f}) px, "
        f"observable rank {moved.observable_rank}"
    )
    # Zoom on the middle of each traced curve (limb: its left- and top-most points).
    fitted = moved.transform(r["displaced_vertices"])
    if r["spec"]["shape"] == "limb":
        zooms = [fitted[np.argmin(fitted[:, 1])], fitted[np.argmin(fitted[:, 0])]]
    else:
        starts = np.cumsum([0] + [len(p) for p in r["lines"]])
        zooms = [fitted[(a + b) // 2] for a, b in zip(starts[:-1], starts[1:], strict=True)]
    plot_fit(
        r["frame"].image, r["displaced_vertices"], moved, path, title=title, dpi=80,
        zoom_vu=zooms, zoom_half_px=15,
    )
    return path


# --- Fitting with the profile the geometry gives (--profile) ---------------

#: Displacements of the profile comparison (the last one is not a multiple
#: of a quarter pixel, so the bilinear DT and the pixel strips are sampled
#: at new sub-pixel positions).
PROFILE_DISPLACEMENTS = {
    "tethys": ((6.0, -4.0), (-9.5, 3.25), (3.37, -7.81)),
    "keeler": ((5.0, 7.0), (-6.0, -2.5), (3.37, -7.81)),
}

#: Annuli (in units of the traced limb's radius at each angle) of the disc
#: measurements: Minnaert's exponent on the first, robustness on the others.
MINNAERT_RANGES = ((0.3, 0.97), (0.3, 0.8), (0.8, 0.97), (0.5, 0.95))
SUN_ANNULI = tuple(np.concatenate([np.arange(0.3, 0.949, 0.05),
                                   [0.95, 0.97, 0.98, 0.985, 0.99, 0.995]]))


def sidecar_phase_deg(png: Path) -> float | None:
    """The phase angle at the body's centre from the frame's sidecar YAML, if it has one.

    The Tethys sidecar records it only in its selection note
    (``"center_phase_deg": 1.532``); the YAML has no Sun direction.
    """
    yaml = png.with_suffix(".yaml")
    if not yaml.is_file():
        return None
    m = re.search(r'"center_phase_deg":\s*([-+0-9.eE]+)', yaml.read_text())
    return float(m.group(1)) if m else None


def disc_polar(frame, center, limb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each pixel's angle about ``center`` and its radius over the traced limb's radius
    at that angle (the drawn limb is not quite a circle: an ellipsoid's)."""
    rel = limb - np.asarray(center)
    ang = np.arctan2(rel[:, 0], rel[:, 1])
    order = np.argsort(ang)
    vv, uu = np.mgrid[: frame.image.shape[0], : frame.image.shape[1]]
    theta = np.arctan2(vv - center[0], uu - center[1])
    limb_r = np.interp(theta, ang[order], np.hypot(rel[:, 0], rel[:, 1])[order], period=2 * np.pi)
    return np.hypot(vv - center[0], uu - center[1]) / limb_r, theta


def minnaert_k(image, rho, keep, lo: float, hi: float) -> float:
    """Minnaert's exponent from the disc's radial brightness at phase ~0.

    At phase 0 Minnaert's law is ``I = A cos(e)^(2k - 1)``: a straight line
    of ``ln I`` against ``ln cos e``, fitted through the median brightness
    of annuli 0.02 radii wide (medians: craters and albedo spots are
    outliers, not signal).
    """
    edges = np.arange(lo, hi - 1e-9, 0.02)
    meds = [np.median(image[keep & (rho >= a) & (rho < a + 0.02)]) for a in edges]
    cos_e = np.sqrt(1.0 - (edges + 0.01) ** 2)
    slope = np.polyfit(np.log(cos_e), np.log(meds), 1)[0]
    return float((slope + 1.0) / 2.0)


def sun_direction_evidence(image, rho, theta, keep, phase_deg: float, k: float) -> dict:
    """What the disc's brightness says about the Sun's in-image direction.

    In each annulus the brightness's first angular harmonic (of 36 sector
    medians) is a 2-vector. A Minnaert sphere at a small phase ``g`` lit
    from the in-image direction ``s`` has one of amplitude
    ``k tan(g) rho / cos e`` times the annulus's mean along ``s``, growing
    toward the limb (1 DN near the centre, tens of DN at the limb for
    Tethys), while an albedo pattern's does not grow. So the harmonics are
    fitted as a constant 2-vector (albedo) plus the predicted growth times
    a 2-vector ``s``: ``|s|`` near 1 says the phase's asymmetry is there
    and ``s`` points to the Sun; near 0 that it is not seen.
    """
    nb = 36
    ang = (np.arange(nb) + 0.5) / nb * 2 * np.pi - np.pi
    design = np.column_stack([np.ones(nb), np.cos(ang), np.sin(ang)])
    g = math.radians(phase_deg)
    harm, pred, means = [], [], []
    for lo, hi in zip(SUN_ANNULI[:-1], SUN_ANNULI[1:], strict=True):
        m = keep & (rho >= lo) & (rho < hi)
        idx = ((theta[m] + np.pi) / (2 * np.pi) * nb).astype(np.int64) % nb
        med = np.array([np.median(image[m][idx == j]) for j in range(nb)])
        c0, cu, cv = np.linalg.lstsq(design, med, rcond=None)[0]
        r = 0.5 * (lo + hi)
        harm.append((cv, cu))
        means.append(c0)
        pred.append(c0 * k * math.tan(g) * r / math.sqrt(1.0 - r * r))
    harm_a, pred_a = np.asarray(harm), np.asarray(pred)
    fit = np.linalg.lstsq(np.column_stack([np.ones(len(pred_a)), pred_a]), harm_a, rcond=None)[0]
    albedo, s = fit[0], fit[1]
    mean_h = harm_a.mean(axis=0)
    return dict(
        harmonic_vu=harm_a, predicted_amplitude=pred_a, mean=np.asarray(means),
        harmonic_ill_deg=math.degrees(math.atan2(mean_h[1], -mean_h[0])) % 360.0,
        harmonic_amplitude=float(np.hypot(*harm_a.T).mean()),
        albedo_vu=albedo, s_vu=s, s_norm=float(np.hypot(*s)),
        s_ill_deg=math.degrees(math.atan2(s[1], -s[0])) % 360.0,
    )


def tethys_geometry(data_dir: Path) -> dict:
    """The sphere Tethys's profile is built on, and the evidence for each of its numbers."""
    png = data_dir / FRAMES["tethys"]["file"]
    frame = cassini.load_cassini_overlay_frame(png)
    (limb,) = cassini.overlay_polylines(frame, shape="limb")
    center, radius = cassini.overlay_circle(frame)
    rho, theta = disc_polar(frame, center, limb.vertices_vu)
    keep = ~frame.overlay_mask
    ks = [minnaert_k(frame.image, rho, keep, lo, hi) for lo, hi in MINNAERT_RANGES]
    phase = sidecar_phase_deg(png)
    if phase is None:
        raise ValueError(f"{png.with_suffix('.yaml')} gives no center_phase_deg")
    sun = sun_direction_evidence(frame.image, rho, theta, keep & (rho < 1.0), phase, ks[0])
    rel = limb.vertices_vu - np.asarray(center)
    on_circle = np.asarray(center) + radius * rel / np.hypot(rel[:, 0], rel[:, 1])[:, None]
    return dict(frame=frame, limb=limb, center=center, radius=radius, phase=phase,
                k=ks[0], k_ranges=ks, sun=sun, on_circle=on_circle,
                vertex_radius=np.hypot(rel[:, 0], rel[:, 1]))


def limb_profile(geo: dict, sel=slice(None), *, law: str, phase: float = 0.0, ill: float = 0.0,
                 fit_law: bool = True, psf: float | None = None) -> EdgeProfile:
    """The sphere's limb profile at the traced vertices ``sel``.

    Each vertex is projected radially onto the overlay's circle for the
    profile: its normal is unchanged (radial) and its profile's edge at
    offset 0 is then the vertex itself, though the drawn limb departs from
    the circle by a few pixels.
    """
    k = geo["k"] if law == "minnaert" else None
    return sphere_edge_profile(
        geo["on_circle"][sel], center_vu=geo["center"], radius_px=geo["radius"],
        phase_deg=phase, illumination_deg=ill, edge="limb", law=law, minnaert_k=k,
        fit_law=fit_law, psf_sigma_px=psf,
    )


def tethys_methods(geo: dict) -> dict:
    """Every way the comparison fits the limb: keyword arguments of the fit."""
    k = geo["k"]
    ill_h = round(geo["sun"]["harmonic_ill_deg"])
    return {
        "plain, edge_kind undeclared": {},
        "plain, edge_kind='limb'": dict(edge_kind="limb"),
        "Lambert, phase 0": dict(edge_profile=limb_profile(geo, law="lambert")),
        f"Minnaert k={k:.3f}, phase 0": dict(edge_profile=limb_profile(geo, law="minnaert")),
        f"Minnaert k={k:.3f}, phase 0, fit_law=False":
            dict(edge_profile=limb_profile(geo, law="minnaert", fit_law=False)),
        f"Minnaert k={k:.3f}, phase 0, PSF 0.5 px given":
            dict(edge_profile=limb_profile(geo, law="minnaert", psf=0.5)),
        f"Minnaert k={k:.3f}, phase 0, PSF 1.0 px given":
            dict(edge_profile=limb_profile(geo, law="minnaert", psf=1.0)),
        # the direction the disc's harmonic points to, at the sidecar's phase
        f"Minnaert k={k:.3f}, phase {geo['phase']:.3f}, ill {ill_h} (disc harmonic)":
            dict(edge_profile=limb_profile(geo, law="minnaert", phase=geo["phase"], ill=ill_h)),
    }


def _fit(products, polyline, displacement, window, sel=slice(None), **kw):
    return pipeline.fit_polyline_products(
        products, polyline.vertices_vu[sel] - np.asarray(displacement), polyline.normals_vu[sel],
        polyline.sigmas[sel], search_window_vu=window, **kw)


def _row(fit, base, displacement) -> dict:
    """One run: the fit, its recovery error and that error over its sigma."""
    err = np.subtract(fit.offset_vu, displacement) - np.asarray(base.offset_vu)
    sig = np.hypot(fit.sigma_vu, base.sigma_vu)  # the sigma of a difference of two fits
    return dict(fit=fit, displacement=displacement, error=err, error_sigmas=np.abs(err) / sig)


def profile_runs(data_dir: Path) -> dict:
    """Every run of the comparison: Tethys's methods at the drawn pose and displaced,
    opposite halves of its limb, the Sun directions at the sidecar's phase, and the
    Keeler ring's plain and step-profile fits."""
    geo = tethys_geometry(data_dir)
    products = pipeline.prepare_image(geo["frame"].image)
    limb, window = geo["limb"], FRAMES["tethys"]["window"]
    methods = tethys_methods(geo)
    runs: dict = {"geo": geo, "tethys": {}, "halves": {}, "sun_scan": {}}
    for name, kw in methods.items():
        base = _fit(products, limb, (0.0, 0.0), window, **kw)
        runs["tethys"][name] = [_row(base, base, (0.0, 0.0))] + [
            _row(_fit(products, limb, d, window, **kw), base, d)
            for d in PROFILE_DISPLACEMENTS["tethys"]]
    rel = limb.vertices_vu - np.asarray(geo["center"])
    halves = {"left": rel[:, 1] < 0, "right": rel[:, 1] >= 0,
              "top": rel[:, 0] < 0, "bottom": rel[:, 0] >= 0}
    minnaert = f"Minnaert k={geo['k']:.3f}, phase 0"
    for name, law in (("plain, edge_kind undeclared", None), ("Lambert, phase 0", "lambert"),
                      (minnaert, "minnaert")):
        for half, sel in halves.items():
            kw = {} if law is None else dict(edge_profile=limb_profile(geo, sel, law=law))
            runs["halves"][(name, half)] = _fit(products, limb, (0.0, 0.0), window, sel, **kw)
    for ill in range(0, 360, 30):
        profile = limb_profile(geo, law="minnaert", phase=geo["phase"], ill=ill)
        runs["sun_scan"][ill] = _fit(products, limb, (0.0, 0.0), window, edge_profile=profile)
    runs["keeler"] = keeler_runs(data_dir)
    return runs


def step_profile(polyline) -> EdgeProfile:
    """A sharp step across each vertex (dark on the side opposite the normal), edge "ring"."""
    h = 0.1
    offsets = (np.arange(-120, 120) + 0.5) * h
    n = len(polyline.vertices_vu)
    return EdgeProfile(offsets_px=offsets, values=np.tile((offsets > 0).astype(float), (n, 1)),
                       normals_vu=polyline.normals_vu, curvature_px=np.zeros(n), edge="ring")


def keeler_runs(data_dir: Path) -> dict:
    """The ring's plain fit (edge_kind undeclared and "ring") and a step profile's."""
    spec = FRAMES["keeler"]
    frame = cassini.load_cassini_overlay_frame(data_dir / spec["file"])
    lines = cassini.overlay_polylines(frame, shape="lines", n_lines=2)
    model = io.concatenate_polylines(lines, name="keeler")
    products = pipeline.prepare_image(frame.image)
    methods = {"plain, edge_kind undeclared": {}, "plain, edge_kind='ring'": dict(edge_kind="ring"),
               "step profile, edge 'ring'": dict(edge_profile=step_profile(model))}
    out: dict = {"normal": lines[0].normals_vu[0], "methods": {}}
    for name, kw in methods.items():
        base = _fit(products, model, (0.0, 0.0), spec["window"], **kw)
        out["methods"][name] = [_row(base, base, (0.0, 0.0))] + [
            _row(_fit(products, model, d, spec["window"], **kw), base, d)
            for d in PROFILE_DISPLACEMENTS["keeler"]]
    return out


def _reasons(fit) -> str:
    return ", ".join(str(r) for r in fit.reasons) or "-"


def _verdict(p) -> str:
    return "accepted" if p.accepted else f"rejected ({p.reason})"


def _pair(x, fmt="+.3f") -> str:
    return "(" + ", ".join("inf" if not math.isfinite(v) else format(v, fmt) for v in x) + ")"


def profile_report(runs: dict) -> str:
    """The comparison as text tables."""
    geo = runs["geo"]
    sun = geo["sun"]
    out = ["== Tethys (N1634226853): the geometry of the profile =="]
    vr = geo["vertex_radius"]
    out.append(f"overlay circle: centre {_pair(geo['center'], '.2f')}, radius {geo['radius']:.2f} px; "
               f"traced vertices {vr.min():.1f}-{vr.max():.1f} px from the centre")
    out.append(f"phase angle (sidecar YAML note): {geo['phase']} deg; terminator "
               f"{geo['radius'] * (1 - math.cos(math.radians(geo['phase']))):.2f} px inside "
               "the limb on the far side: none to fit")
    out.append("Minnaert k from the disc's radial medians: " + ", ".join(
        f"{lo}-{hi}: {k:.3f}" for (lo, hi), k in zip(MINNAERT_RANGES, geo["k_ranges"], strict=True)))
    amp = np.hypot(*sun["harmonic_vu"].T)
    out.append(f"disc first harmonic: {amp.min():.1f}-{amp.max():.1f} DN over the annuli "
               f"{SUN_ANNULI[0]:.2f}-{SUN_ANNULI[-1]:.3f} R (mean {sun['harmonic_amplitude']:.1f}), "
               f"toward ill {sun['harmonic_ill_deg']:.0f} deg; the phase's predicted "
               f"{sun['predicted_amplitude'][0]:.1f}-{sun['predicted_amplitude'][-1]:.1f} DN, "
               "growing toward the limb")
    out.append(f"fitted illumination component |s| = {sun['s_norm']:.2f} of the predicted "
               f"(direction {sun['s_ill_deg']:.0f} deg): the Sun's direction is not seen")
    out.append("")
    out.append("== Tethys: every run (error = fit - displacement - base; "
               "/sigma: over hypot of the two fits' sigmas) ==")
    for name, rows in runs["tethys"].items():
        out.append(f"-- {name}")
        for r in rows:
            fit, p = r["fit"], r["fit"].profile
            extra = "" if p is None else (
                f" | {_verdict(p)}, psf {p.psf_sigma_px:.2f}{'' if p.psf_estimated else ' (given)'}"
                f", wings {p.wing_fraction:.2f}, law amp {p.shape_amplitude:+.3f}, gain {p.gain:.0f}"
                f", step {p.step_jump:.2f}, walk {p.walk_px:.2f}")
            out.append(f"  d={_pair(r['displacement'], '+.2f'):16s} offset {_pair(fit.offset_vu)} "
                       f"err {_pair(r['error'], '+.4f')} /sigma {_pair(r['error_sigmas'], '.2f')} "
                       f"sigma {_pair(fit.sigma_vu, '.4f')} {fit.status} [{_reasons(fit)}]{extra}")
    out.append("")
    out.append("== Tethys: opposite halves of the limb, each fitted alone (drawn pose) ==")
    names = sorted({n for n, _ in runs["halves"]}, key=list(runs["tethys"]).index)
    for name in names:
        h = {half: runs["halves"][(name, half)] for half in ("left", "right", "top", "bottom")}
        out.append(f"-- {name}")
        for half, f in h.items():
            p = f.profile
            extra = "" if p is None else (
                f" | {_verdict(p)}, gain {p.gain:.0f}, law amp {p.shape_amplitude:+.3f}"
                f", walk {p.walk_px:.2f}")
            out.append(f"   {half:6s} offset {_pair(f.offset_vu)} {f.status} [{_reasons(f)}]{extra}")
        du = h["left"].offset_vu[1] - h["right"].offset_vu[1]
        dv = h["top"].offset_vu[0] - h["bottom"].offset_vu[0]
        mean_u = 0.5 * (h["left"].offset_vu[1] + h["right"].offset_vu[1])
        mean_v = 0.5 * (h["top"].offset_vu[0] + h["bottom"].offset_vu[0])
        full = runs["tethys"][name][0]["fit"].offset_vu
        out.append(f"   left - right du {du:+.3f} px; top - bottom dv {dv:+.3f} px; halves' means "
                   f"(v {mean_v:+.3f}, u {mean_u:+.3f}) against the full limb's {_pair(full)}")
    out.append("")
    out.append(f"== Tethys: Minnaert k={geo['k']:.3f} at the sidecar's phase "
               f"{geo['phase']} deg, Sun direction scanned (drawn pose) ==")
    for ill, fit in runs["sun_scan"].items():
        p = fit.profile
        out.append(f"  ill {ill:3d}: offset {_pair(fit.offset_vu)} {fit.status}, residual scale "
                   f"{p.residual_scale:.2f} DN")
    ph0 = runs["tethys"][f"Minnaert k={geo['k']:.3f}, phase 0"][0]["fit"]
    out.append(f"  phase 0 (no direction): offset {_pair(ph0.offset_vu)}, residual scale "
               f"{ph0.profile.residual_scale:.2f} DN")
    out.append("")
    out.append("== Keeler gap (N1863268207): plain and a step profile "
               "(across = error along the edge normal) ==")
    kr = runs["keeler"]
    n = kr["normal"]
    for name, rows in kr["methods"].items():
        out.append(f"-- {name}")
        for r in rows:
            fit, p = r["fit"], r["fit"].profile
            extra = "" if p is None else f" | profile accepted {p.accepted}: {p.reason or '-'}"
            out.append(f"  d={_pair(r['displacement'], '+.2f'):16s} offset {_pair(fit.offset_vu)} "
                       f"across {float(r['error'] @ n):+.4f} sigma across {fit.sigma_along(n):.4f} "
                       f"rank {fit.observable_rank} {fit.status} [{_reasons(fit)}]{extra}")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", help="folder with the Cassini PNGs")
    parser.add_argument("--out", default=".", help="where to write the figures (default .)")
    parser.add_argument("--no-plot", action="store_true", help="print only")
    parser.add_argument("--profile", action="store_true",
                        help="compare the fit with the geometry's edge profile and the plain fit")
    args = parser.parse_args(argv)
    data = find_data_dir(args.data)
    if data is None:
        print("Cassini frames not found: pass --data or set DTALIGN_CASSINI_DIR", file=sys.stderr)
        return 1
    if args.profile:
        print(profile_report(profile_runs(data)))
        return 0
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    for key in FRAMES:
        r = fit_frame(data, key)
        print(report(key, r))
        if not args.no_plot:
            print(f"figure: {figure(key, r, out_dir)}")
        print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
