"""How far a plain fit of a soft limb is off, by how soft the limb reads.

Renders seeded spheres with :func:`dtalign.scenes.render_sphere` (radius
25-150 px, phase 0-100 deg, any light direction, Gaussian PSF 0-2 px, read
noise 0-3 DN; Lambert, Minnaert with ``k`` 0.5-1.3, Lommel-Seeliger), fits
each limb (and one scene in four its terminator) with the guide's plain call
(no ``edge_kind``, no profile) and prints, per band of the ``drift`` that
:func:`dtalign.pipeline.edge_kind.infer_edge_kind` reads (how far the bright
side moves on past the step, over the step), the ``ok`` fits' errors and how
many are confidently wrong (``ok`` and more than 1 px off, or outside
their 99.9 % ellipse). docs/uncertainty.rst, "A plain fit's edge kind",
quotes its table.

Run ``python benchmarks/plain_limb_softness.py`` (``--scenes N``, ``--seed S``).
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence

import numpy as np

from dtalign import fit_polyline
from dtalign.pipeline.edge_kind import edge_drift
from dtalign.scenes import render_sphere

LAWS = ("lambert", "minnaert", "lommel-seeliger")
BANDS = (-2.0, 0.0, 0.2, 0.3, 0.4, 0.5, 0.6, 2.0)
CHI2_999 = 13.8155


def run(n_scenes: int, seed: int) -> list[dict]:
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n_scenes):
        law = LAWS[i % 3]
        edge = "terminator" if (i // 3) % 4 == 0 else "limb"
        kw = dict(radius_px=float(rng.uniform(25, 150)),
                  phase_deg=float(rng.uniform(0 if edge == "limb" else 10, 100)),
                  illumination_deg=float(rng.uniform(0, 360)),
                  offset_vu=(float(rng.uniform(-2, 2)), float(rng.uniform(-2, 2))),
                  psf_sigma_px=float(rng.uniform(0, 2)) or None, law=law, background_dn=10.0,
                  read_noise_dn=float(rng.choice([0, 1, 3])), seed=i, shape=(400, 400))
        if law == "minnaert":
            kw["minnaert_k"] = float(rng.uniform(0.5, 1.3))
        sc = render_sphere(**kw)
        poly = getattr(sc, edge)
        fit = fit_polyline(sc.image, poly.vertices_vu, poly.normals_vu, poly.sigmas,
                           search_window_vu=(8, 8))
        err = np.asarray(fit.offset_vu) - np.asarray(sc.true_offset_vu)
        cov = np.asarray(fit.covariance)[:2, :2]
        d2 = float(err @ np.linalg.pinv(cov) @ err) if np.isfinite(cov).all() else 0.0
        out.append(dict(edge=edge, law=law, phase=kw["phase_deg"], status=str(fit.status),
                        kind=fit.inferred_edge_kind, error_px=float(np.hypot(*err)), d2=d2,
                        drift=edge_drift(sc.image, fit.evidence.points_vu, fit.normals_vu,
                                         fit.lm.weights)))
    return out


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=240)
    ap.add_argument("--seed", type=int, default=11)
    args = ap.parse_args(argv)
    recs = run(args.scenes, args.seed)
    print(f"{'edge':10s} {'drift':12s} {'fits':>4s} {'ok':>4s} {'median px':>9s} {'max px':>7s} "
          f"{'wrong':>5s}")
    for edge in ("limb", "terminator"):
        for lo, hi in zip(BANDS[:-1], BANDS[1:], strict=True):
            band = [r for r in recs if r["edge"] == edge and r["drift"] is not None
                    and lo < r["drift"] <= hi]
            ok = [r for r in band if r["status"] == "ok"]
            wrong = sum(r["error_px"] > 1.0 or r["d2"] > CHI2_999 for r in ok)
            errs = [r["error_px"] for r in ok]
            med = f"{np.median(errs):9.2f} {max(errs):7.2f}" if errs else f"{'-':>9s} {'-':>7s}"
            print(f"{edge:10s} {lo:+.1f}..{hi:+.1f}   {len(band):4d} {len(ok):4d} {med} {wrong:5d}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
