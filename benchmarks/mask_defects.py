"""Fits of the defect scenes with and without their bad-pixel mask: docs/robustness.rst's table.

For each seed, scene (the 400 x 400 disc of ``disc_scene(shape=(400, 400),
radius=120.0)``, and a rendered Lambert limb with its edge profile) and
defect of :func:`dtalign.scenes.add_defects`: the clean fit, the fit with
the defect masked, and the fit of the same image without a mask. Prints one
line per case and a summary table (reStructuredText)::

    PYTHONPATH=src python benchmarks/mask_defects.py 10
"""

from __future__ import annotations

import logging
import math
import sys

import numpy as np

from dtalign import scenes, sphere_edge_profile
from dtalign.pipeline import fit_polyline

#: chi-square with 2 degrees of freedom at 99.9 %.
CHI2_2_999 = -2.0 * math.log(1.0 - 0.999)
#: The sphere's sunward limb point (light from 45 deg, 0 = up), from +v toward +u.
LIT_DEG = 135.0


def _read(fit, truth):
    e = np.subtract(fit.offset_vu, truth)
    cov = np.asarray(fit.covariance)[:2, :2]
    d2 = float(e @ np.linalg.pinv(cov) @ e) if np.isfinite(cov).all() else math.inf
    return {"err": float(np.hypot(*e)), "d2": d2, "status": str(fit.status),
            "sigma": math.hypot(*fit.sigma_vu), "masked": fit.masked_vertices}


def _disc(seed):
    sc = scenes.disc_scene(shape=(400, 400), radius=120.0, seed=seed)
    return (sc.image, sc.polyline, sc.true_offset_vu, ((400 - 1) / 2.0, (400 - 1) / 2.0), 120.0,
            {"search_window_vu": (30, 30)}, {})


def _sphere(seed):
    s = scenes.render_sphere(shape=(240, 240), center_vu=(120.3, 119.6), radius_px=70.0,
                             phase_deg=30.0, illumination_deg=45.0, offset_vu=(0.4, -0.7),
                             read_noise_dn=1.0, seed=seed)
    prof = sphere_edge_profile(s.limb.vertices_vu, center_vu=s.model_center_vu, radius_px=70.0,
                               phase_deg=30.0, illumination_deg=45.0, edge="limb")
    return (s.image, s.limb, s.true_offset_vu, s.center_vu, 70.0,
            {"search_window_vu": (8, 8), "edge_profile": prof},
            {"saturation_dn": 1.5 * float(s.image.max()), "blob_at_deg": LIT_DEG})


def cases(seeds):
    """One dict per (scene, defect, seed): the clean, masked and unmasked readings."""
    for name, build in (("disc", _disc), ("sphere", _sphere)):
        for seed in seeds:
            image, poly, truth, centre, radius, kw, defect_kw = build(seed)
            clean = _read(fit_polyline(image, poly, **kw), truth)
            for kind in scenes.DEFECTS:
                img, mask = scenes.add_defects(image, kind, limb_center_vu=centre,
                                               limb_radius_px=radius, seed=seed, **defect_kw)
                masked = _read(fit_polyline(img, poly, mask=mask, **kw), truth)
                try:
                    bare = _read(fit_polyline(img, poly, **kw), truth)
                except ValueError:
                    bare = None
                yield {"scene": name, "kind": kind, "seed": seed, "clean": clean,
                       "masked": masked, "unmasked": bare}


def summary(rows):
    """The docs' table: per scene and defect, over the seeds."""
    out = ["==========  ================  =====  ==========  ==========  ========  =========  "
           "============  ============  ==========",
           "scene       defect            seeds  clean err   masked err  masked /  masked     "
           "masked max    unmasked      unmasked",
           "                                     median px   median px   clean     within 2x  "
           "d2 (ok)       err median    ok, max d2",
           "==========  ================  =====  ==========  ==========  ========  =========  "
           "============  ============  =========="]
    keys = sorted({(r["scene"], r["kind"]) for r in rows}, key=lambda k: (k[0], scenes.DEFECTS.index(k[1])))
    for scene, kind in keys:
        sel = [r for r in rows if (r["scene"], r["kind"]) == (scene, kind)]
        ce = np.median([r["clean"]["err"] for r in sel])
        me = np.median([r["masked"]["err"] for r in sel])
        ratio = max(r["masked"]["err"] / r["clean"]["err"] for r in sel)
        within = sum(r["masked"]["err"] <= 2.0 * r["clean"]["err"] for r in sel)
        ok = sum(r["masked"]["status"] == "ok" for r in sel)
        md2 = max(r["masked"]["d2"] for r in sel)
        bare = [r["unmasked"] for r in sel if r["unmasked"] is not None]
        if bare:
            ue = f"{np.median([b['err'] for b in bare]):.4f}"
            bok = [b for b in bare if b["status"] == "ok"]
            ud = f"{len(bok)}, {max((b['d2'] for b in bok), default=0.0):.2f}"
        else:
            ue, ud = "ValueError", "(refused)"
        out.append(f"{scene:10s}  {kind:16s}  {len(sel):5d}  {ce:10.4f}  {me:10.4f}  {ratio:8.2f}  "
                   f"{within:4d}/{len(sel):<4d}  {md2:6.2f} ({ok})   {ue:12s}  {ud}")
    out.append(out[0])
    return "\n".join(out)


def main(argv):
    logging.getLogger("dtalign").setLevel(logging.ERROR)  # the unmasked fits' warnings
    seeds = range(int(argv[0]) if argv else 10)
    rows = []
    for r in cases(seeds):
        rows.append(r)
        m, b = r["masked"], r["unmasked"]
        print(f"{r['scene']:6s} {r['kind']:16s} {r['seed']:2d}  clean {r['clean']['err']:.4f}  "
              f"masked {m['err']:.4f} d2 {m['d2']:.2f} {m['status']} on-mask {m['masked']}  "
              + ("unmasked refused (NaN)" if b is None else
                 f"unmasked {b['err']:.4f} d2 {b['d2']:.2f} {b['status']}"), flush=True)
    print(summary(rows))


if __name__ == "__main__":
    main(sys.argv[1:])
