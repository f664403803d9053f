"""The terminator error table (docs/profiles.rst, :ref:`profiles-terminator`), in one run.

Renders seeded Lambert spheres with :func:`dtalign.scenes.render_sphere` (an
independent renderer), fits the visible half of the geometric terminator
(``cos i = 0``, normals toward the lit side) declared as a terminator
(``edge_kind="terminator"``), plainly and with
``sphere_edge_profile(..., edge="terminator")``, with the search window
(8, 8), and reports the error against the planted offset and the statuses:
how many fits are ``ok`` while more than 1 px off (confidently wrong), and
how many plain fits would have been ``ok`` without the declared kind.

Run ``python benchmarks/terminator_error.py`` (``--scenes N``, ``--seed S``).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from dtalign import fit_polyline, sphere_edge_profile
from dtalign.benchmarking.timing import rst_table
from dtalign.pipeline.status import FitReason, FitStatus, fit_status
from dtalign.scenes import render_sphere

#: Frame size and oversampling of every scene (the issue's).
SHAPE = (300, 300)
#: Shot noise (electrons per DN) and read noise (DN) of the noisy scenes (as
#: benchmarks/profile_bias.py).
POISSON_GAIN = 20.0
READ_NOISE_DN = 1.0
#: The coarse window of every fit (the issue's).
WINDOW = (8, 8)


def scene(rng: np.random.Generator, noisy: bool, seed: int, psf: float | None = None) -> Any:
    """One seeded scene: diameter 100-240 px, phase 35-150 deg, any light direction."""
    diameter = rng.uniform(100.0, 240.0)
    phase = rng.uniform(35.0, 150.0)
    ill = rng.uniform(0.0, 360.0)
    offset = rng.uniform(-0.5, 0.5, 2) + rng.integers(-2, 3, 2)
    centre = np.array(SHAPE) / 2.0 + rng.uniform(-0.5, 0.5, 2)
    noise = dict(poisson_gain=POISSON_GAIN, read_noise_dn=READ_NOISE_DN) if noisy else {}
    return render_sphere(shape=SHAPE, center_vu=tuple(centre), radius_px=diameter / 2.0,
                         phase_deg=phase, illumination_deg=ill, offset_vu=tuple(offset),
                         albedo_dn=200.0, background_dn=10.0, seed=seed, psf_sigma_px=psf,
                         **noise)


def measure(sc: Any, profile_psf: float | None = 0.0) -> dict[str, Any]:
    """The plain and profile fits of one scene's terminator, declared as one."""
    T = sc.terminator
    truth = np.asarray(sc.true_offset_vu)
    t0 = time.perf_counter()
    plain = fit_polyline(sc.image, T.vertices_vu, T.normals_vu, T.sigmas,
                         search_window_vu=WINDOW, edge_kind="terminator")
    t1 = time.perf_counter()
    prof = sphere_edge_profile(T.vertices_vu, center_vu=sc.model_center_vu,
                               radius_px=sc.radius_px, phase_deg=sc.phase_deg,
                               illumination_deg=sc.illumination_deg, edge="terminator",
                               psf_sigma_px=profile_psf)
    t2 = time.perf_counter()
    fit = fit_polyline(sc.image, T.vertices_vu, T.normals_vu, T.sigmas,
                       search_window_vu=WINDOW, edge_profile=prof)
    t3 = time.perf_counter()
    undeclared = fit_status(r for r in plain.reasons
                            if r is not FitReason.TERMINATOR_WITHOUT_PROFILE)
    return {
        "plain": float(np.hypot(*(np.asarray(plain.offset_vu) - truth))),
        "profile": float(np.hypot(*(np.asarray(fit.offset_vu) - truth))),
        "plain_status": str(plain.status), "undeclared_status": str(undeclared),
        "status": str(fit.status), "reasons": [str(r) for r in fit.reasons],
        "accepted": bool(fit.profile is not None and fit.profile.accepted),
        "t_plain": t1 - t0, "t_profile": t3 - t2,
        "phase": sc.phase_deg, "d": 2 * sc.radius_px, "ill": sc.illumination_deg,
    }


def rows(n_scenes: int, seed: int, psf: float | None = None,
         psf_given: bool = True) -> list[dict[str, Any]]:
    """``n_scenes`` scenes from ``seed``, noise-free and noisy alternately,
    rendered with a Gaussian PSF of sigma ``psf`` (None: none), told to the
    profile when ``psf_given`` (else estimated by the fit)."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n_scenes):
        r = measure(scene(rng, i % 2 == 1, seed * 1000 + i, psf),
                    (psf or 0.0) if psf_given else None)
        r["noise"] = "noisy" if i % 2 else "noise-free"
        out.append(r)
    return out


COLUMNS = ("n", "plain median", "plain p90", "plain ok", "plain ok > 1 px",
           "undeclared ok > 1 px", "profile median", "profile p90", "accepted", "profile ok",
           "profile ok > 1 px")


def stats(rs: Sequence[dict[str, Any]]) -> list[str]:
    p = np.array([r["plain"] for r in rs])
    q = np.array([r["profile"] for r in rs])
    ok = FitStatus.OK.value
    return [str(len(rs)), f"{np.median(p):.2f}", f"{np.percentile(p, 90):.2f}",
            str(sum(r["plain_status"] == ok for r in rs)),
            str(sum(r["plain_status"] == ok and r["plain"] > 1.0 for r in rs)),
            str(sum(r["undeclared_status"] == ok and r["plain"] > 1.0 for r in rs)),
            f"{np.median(q):.2f}", f"{np.percentile(q, 90):.2f}",
            str(sum(r["accepted"] for r in rs)), str(sum(r["status"] == ok for r in rs)),
            str(sum(r["status"] == ok and r["profile"] > 1.0 for r in rs))]


def table(groups: list[tuple[str, list[dict[str, Any]]]]) -> str:
    """An RST simple table, one row per group (errors in px)."""
    return rst_table(["", *COLUMNS], [[name, *stats(rs)] for name, rs in groups if rs])


def run(n_scenes: int, seed: int, psf: float | None = None, psf_given: bool = True) -> str:
    t0 = time.perf_counter()
    rs = rows(n_scenes, seed, psf, psf_given)
    groups = [("all", rs), ("noise-free", [r for r in rs if r["noise"] == "noise-free"]),
              ("noisy", [r for r in rs if r["noise"] == "noisy"]),
              ("phase 35-90", [r for r in rs if r["phase"] < 90]),
              ("phase 90-150", [r for r in rs if r["phase"] >= 90])]
    worst = sorted(rs, key=lambda r: -r["profile"])[:3]
    tail = "; ".join(f"{r['profile']:.2f} px {r['status']} ({', '.join(r['reasons'])})"
                     for r in worst)
    told = "given" if psf_given else "estimated"
    return (f"seed {seed}, {n_scenes} scenes, PSF sigma {psf or 0:g} px ({told}), "
            f"{time.perf_counter() - t0:.0f} s\n\n"
            f"{table(groups)}\n\nworst profile fits: {tail}")


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--scenes", type=int, default=48)
    ap.add_argument("--seed", type=int, default=2028)
    ap.add_argument("--psf", type=float, default=None, help="render with this Gaussian PSF sigma")
    ap.add_argument("--psf-estimated", action="store_true",
                    help="do not tell the profile the PSF: the fit estimates it")
    args = ap.parse_args(argv)
    print(run(args.scenes, args.seed, args.psf, not args.psf_estimated))
    return 0


if __name__ == "__main__":
    sys.exit(main())
