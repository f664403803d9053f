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

Run::

    python examples/cassini_fit.py [--data DIR] [--out DIR]
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

import numpy as np

from dtalign import io, pipeline
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
    out.append(f"DT covariance (pinvh, the contract's): sigma_v {sv:.4f}, sigma_u {su:.4f} px")
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
        iv, iu = moved.sigma_vu
        out.append(f"  inf reading: sigma_v {iv}, sigma_u {iu}")
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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", help="folder with the Cassini PNGs")
    parser.add_argument("--out", default=".", help="where to write the figures (default .)")
    parser.add_argument("--no-plot", action="store_true", help="print only")
    args = parser.parse_args(argv)
    data = find_data_dir(args.data)
    if data is None:
        print("Cassini frames not found: pass --data or set DTALIGN_CASSINI_DIR", file=sys.stderr)
        return 1
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
