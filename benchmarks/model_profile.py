"""Edge profiles from a model render against the sphere's formula (docs/profiles.rst).

Two sets of runs, each fitting every scene's sunlit limb twice with the
pipeline: with :func:`dtalign.sphere_edge_profile` (Lambert, the PSF
estimated) and with :func:`dtalign.model_image_edge_profile` of a noise-free
render of the body at the model's pose, ``oversample`` times finer than the
image, without the PSF (the PSF estimated too).

``--renderer scenes`` (the default; the project's own venv)
    Lambert spheres of :func:`dtalign.scenes.render_sphere`: the model
    render is the same renderer at ``oversample`` times the resolution.
    Both profiles describe the body exactly, so the two fits should agree:
    the table gives the distance between their offsets (``|model -
    sphere|``) and each one's error, for oversample 2, 4 and 8, noise-free
    and noisy, the PSF none or a Gaussian of 0.7 px.
``--renderer mitsuba`` (the validation venv: Mitsuba and GalSim)
    Limb scenes of the validation harness (:mod:`benchmarks.validate`): the
    families ``model_right``, ``craters`` and ``albedo_texture``, the
    observed frame as the harness renders it (noise, PSF, detector); the
    model render is Mitsuba's render of the same body (the same crater mesh,
    the same albedo map) at the model centre, at ``--oversample`` (4), 16
    samples a render pixel (``--clean``: the scenes without the detector's
    noise). The sphere profile knows neither the craters nor
    the albedo map; the model render knows both.

Run ``python benchmarks/model_profile.py`` or, for the second set,
``PYTHONPATH=src:. /work/venv-val/bin/python benchmarks/model_profile.py
--renderer mitsuba`` (``--scenes N`` scenes per group).
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import numpy as np

from dtalign import (
    fit_polyline,
    model_image_edge_profile,
    sphere_edge_profile,
    sphere_limb_polyline,
)
from dtalign.benchmarking.timing import rst_table
from dtalign.scenes import render_sphere

#: The scenes' frame (the validation harness's) and coarse window.
FRAME = (200, 200)
WINDOW = (6, 6)


def fine_sphere(center_vu: tuple[float, float], radius_px: float, phase_deg: float,
                illumination_deg: float, oversample: int, frame: tuple[int, int] = FRAME
                ) -> np.ndarray:
    """A noise-free Lambert render of the sphere, ``oversample`` times finer than the
    frame, in the convention of :func:`~dtalign.model_image_edge_profile` (its default
    ``origin_vu``): image point ``v`` is render coordinate ``k (v + 1/2) - 1/2``."""
    k = oversample
    centre = (k * (center_vu[0] + 0.5) - 0.5, k * (center_vu[1] + 0.5) - 0.5)
    return render_sphere(shape=(frame[0] * k, frame[1] * k), center_vu=centre,
                         radius_px=radius_px * k, phase_deg=phase_deg,
                         illumination_deg=illumination_deg, albedo_dn=1.0, oversample=4,
                         n_vertices=2).image


def _fit(image: np.ndarray, limb: Any, profile: Any) -> tuple[np.ndarray, bool]:
    fit = fit_polyline(image, limb.vertices_vu, limb.normals_vu, limb.sigmas,
                       search_window_vu=WINDOW, edge_profile=profile)
    return np.asarray(fit.offset_vu, dtype=float), bool(fit.profile.accepted)


def scenes_runs(n_scenes: int, seed: int) -> list[dict]:
    """The ``scenes`` set: one record per scene and oversample."""
    records = []
    for k in (2, 4, 8):
        for group, (psf, noisy) in enumerate(((None, False), (0.7, False), (None, True),
                                              (0.7, True))):
            rng = np.random.default_rng([seed, k, group])
            for index in range(n_scenes):
                radius = float(rng.uniform(45.0, 80.0))
                phase = float(rng.uniform(20.0, 70.0))
                ill = float(rng.uniform(0.0, 360.0))
                offset = tuple(rng.uniform(-0.5, 0.5, 2) + rng.integers(-2, 3, 2))
                centre = tuple(np.array(FRAME) / 2.0 + rng.uniform(-0.5, 0.5, 2))
                noise = dict(poisson_gain=20.0, read_noise_dn=1.0) if noisy else {}
                scene = render_sphere(shape=FRAME, center_vu=centre, radius_px=radius,
                                      phase_deg=phase, illumination_deg=ill, offset_vu=offset,
                                      albedo_dn=200.0, background_dn=10.0, psf_sigma_px=psf,
                                      seed=index, **noise)
                sphere = dict(center_vu=scene.model_center_vu, radius_px=radius,
                              phase_deg=phase, illumination_deg=ill)
                limb = scene.limb
                model = fine_sphere(scene.model_center_vu, radius, phase, ill, k)
                t0 = time.perf_counter()
                mprof = model_image_edge_profile(model, limb.vertices_vu, limb.normals_vu,
                                                 oversample=k)
                t_profile = time.perf_counter() - t0
                sprof = sphere_edge_profile(limb.vertices_vu, **sphere, fit_law=False)
                off_s, acc_s = _fit(scene.image, limb, sprof)
                off_m, acc_m = _fit(scene.image, limb, mprof)
                truth = np.asarray(offset)
                records.append(dict(
                    oversample=k, psf=psf, noisy=noisy, index=index,
                    sphere_err=float(np.hypot(*(off_s - truth))),
                    model_err=float(np.hypot(*(off_m - truth))),
                    diff=float(np.hypot(*(off_m - off_s))), accepted=acc_s and acc_m,
                    profile_s=t_profile))
                r = records[-1]
                print(f"k={k} psf={psf} noisy={noisy} {index:2d}  sphere {r['sphere_err']:.4f}  "
                      f"model {r['model_err']:.4f}  |model - sphere| {r['diff']:.4f}  "
                      f"accepted {r['accepted']}", flush=True)
    return records


def scenes_table(records: list[dict]) -> str:
    body = []
    for k in (2, 4, 8):
        for psf, noisy in ((None, False), (0.7, False), (None, True), (0.7, True)):
            rs = [r for r in records if r["oversample"] == k and r["psf"] == psf
                  and r["noisy"] == noisy]
            if not rs:
                continue
            d = np.array([r["diff"] for r in rs])
            body.append([f"{k}", "none" if psf is None else f"{psf:g}",
                         "yes" if noisy else "no", f"{len(rs)}",
                         f"{np.median([r['sphere_err'] for r in rs]):.4f}",
                         f"{np.median([r['model_err'] for r in rs]):.4f}",
                         f"{np.median(d):.4f}", f"{d.max():.4f}",
                         f"{sum(r['accepted'] for r in rs)}"])
    head = ["oversample", "PSF", "noise", "scenes", "sphere err med", "model err med",
            "model to sphere med", "max", "both accepted"]
    return rst_table(head, body)


def mitsuba_runs(n_scenes: int, seed: int, oversample: int, families_: list[str],
                 clean: bool = False, model_seed: int = 1) -> list[dict]:
    """The ``mitsuba`` set: one record per harness scene (``clean``: without the
    detector's noise; the model render's sampler seeded ``model_seed + index``)."""
    from benchmarks.validate import families, fitting
    from benchmarks.validate.render import Body, render, uv_sphere

    records = []
    for family in families_:
        for index in range(n_scenes):
            p = families.draw(family, "limb", index, seed)
            if clean:
                p.update(gain_e_per_dn=None, read_noise_dn=0.0)
            image = families.render_scene(p)
            rng = np.random.default_rng(p["body_seed"])  # the body as render_scene draws it
            body_kw: dict = {}
            if family == "albedo_texture":
                body_kw["albedo_texture"] = families.albedo_map(rng)
            if p["shape"] == "mesh":
                body_kw["mesh_heights"] = families.crater_heights(rng, uv_sphere()[0])
            model_body = Body(center_vu=tuple(p["model_center_vu"]), radius_px=p["radius_px"],
                              phase_deg=p["phase_deg"], illumination_deg=p["illumination_deg"],
                              shape=p["shape"], law=p["law"], minnaert_k=p["minnaert_k"],
                              **body_kw)
            t0 = time.perf_counter()
            model = render(model_body, p["frame_px"], oversample, 16, seed=model_seed + index)
            t_render = time.perf_counter() - t0
            sphere = dict(center_vu=tuple(p["model_center_vu"]), radius_px=p["radius_px"],
                          phase_deg=p["phase_deg"], illumination_deg=p["illumination_deg"])
            limb = sphere_limb_polyline(**sphere)
            (_, _, _, _), sprof = fitting.model(p)
            mprof = model_image_edge_profile(model, limb.vertices_vu, limb.normals_vu,
                                             oversample=oversample)
            truth = np.asarray(p["offset_vu"])
            off_s, acc_s = _fit(image, limb, sprof)
            off_m, acc_m = _fit(image, limb, mprof)
            records.append(dict(
                family=family, index=index, noisy=p["read_noise_dn"] > 0.0, psf=p["psf"]["kind"],
                sphere_err=float(np.hypot(*(off_s - truth))),
                model_err=float(np.hypot(*(off_m - truth))),
                diff=float(np.hypot(*(off_m - off_s))), accepted_s=acc_s, accepted_m=acc_m,
                render_s=t_render))
            r = records[-1]
            print(f"{family:15s} {index:2d} psf {r['psf']:8s} noisy {r['noisy']!s:5s} sphere "
                  f"{r['sphere_err']:.4f} ({acc_s})  model {r['model_err']:.4f} ({acc_m})  "
                  f"|model - sphere| {r['diff']:.4f}  render {t_render:.0f} s", flush=True)
    return records


def mitsuba_table(records: list[dict]) -> str:
    body = []
    for r in records:
        body.append([r["family"], f"{r['index']}", r["psf"], "yes" if r["noisy"] else "no",
                     f"{r['sphere_err']:.4f}", f"{r['model_err']:.4f}", f"{r['diff']:.4f}",
                     f"{'yes' if r['accepted_s'] else 'no'} / "
                     f"{'yes' if r['accepted_m'] else 'no'}"])
    head = ["family", "scene", "PSF", "noise", "sphere err", "model err", "model to sphere",
            "accepted (sphere / model)"]
    return rst_table(head, body)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--renderer", choices=("scenes", "mitsuba"), default="scenes")
    ap.add_argument("--scenes", type=int, default=4, help="scenes per group")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--oversample", type=int, default=4, help="the Mitsuba model's")
    ap.add_argument("--clean", action="store_true",
                    help="the Mitsuba scenes without the detector's noise")
    ap.add_argument("--model-seed", type=int, default=1,
                    help="the Mitsuba model render's sampler seed (plus the scene's index)")
    ap.add_argument("--families", nargs="+",
                    default=["model_right", "craters", "albedo_texture"])
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    if args.renderer == "scenes":
        table = scenes_table(scenes_runs(args.scenes, args.seed))
    else:
        table = mitsuba_table(mitsuba_runs(args.scenes, args.seed, args.oversample,
                                           args.families, args.clean, args.model_seed))
    print()
    print(table)
    print(f"\n{time.perf_counter() - t0:.0f} s in all")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
