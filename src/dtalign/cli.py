"""The ``dtalign`` command line (also ``python -m dtalign``).

Subcommands:

* ``demo``: fit the synthetic disc scene and report each stage;
* ``fit IMAGE POLYLINE [IMAGE POLYLINE ...]``: fit model polylines to
  images (``--batch LIST`` or ``--glob PATTERN`` for many images, each with
  the polyline CSV of the same stem);
* ``overlay PNG``: split a Cassini summary PNG into an image (.npy) and
  its traced model overlay (polyline CSV), ready for ``fit``;
* ``bench``: the quick benchmark table;
* ``archive MANIFEST --out STORE``: a campaign on Dask (:mod:`dtalign.archive`).

Errors are printed as one line, ``dtalign: error: ...``, with exit status
1 (2 for a malformed command line). A batch never stops on one bad image:
it reports it, goes on, and exits 1 at the end if anything failed. A fit
whose status is ``failed`` (:mod:`dtalign.status`) gives exit status 3
(:data:`EXIT_FIT_FAILED`) when nothing else went wrong; failed and suspect
fits are also reported on standard error as ``dtalign: warning: ...``.
"""

from __future__ import annotations

import argparse
import glob
import importlib
import json
import logging
import math
import os
import sys
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = ["build_parser", "main"]

PROG = "dtalign"

#: Exit status when every input was read and fitted but some fit failed
#: (its status is "failed": degenerate, all vertices polarity-rejected, or
#: the seed on the window edge); 1 stays "an error stopped the work".
EXIT_FIT_FAILED = 3


class _Warnings(logging.Handler):
    """Prints the ``dtalign`` logger's records as ``dtalign: warning: LABEL: ...``.

    ``label`` names the input being fitted (the pipeline's message does not
    know the file); the stream is looked up at each record, so the handler
    follows a replaced ``sys.stderr``.
    """

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.label = ""

    def emit(self, record: logging.LogRecord) -> None:
        where = f"{self.label}: " if self.label else ""
        print(f"{PROG}: {record.levelname.lower()}: {where}{record.getMessage()}", file=sys.stderr)


class CLIError(Exception):
    """A user-facing error: printed as one line, exit status 1."""


def _fail(message: str) -> int:
    print(f"{PROG}: error: {message}", file=sys.stderr)
    return 1


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().replace("\n", " ")
    if isinstance(exc, FileNotFoundError) and not text:
        text = "file not found"
    return text or type(exc).__name__


# ---------------------------------------------------------------------------
# Parser
# ---------------------------------------------------------------------------


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``dtalign`` command."""
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Align a model polyline against an image's edge distance transform.",
    )
    parser.add_argument("--version", action="store_true", help="print the version and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    demo = sub.add_parser(
        "demo",
        help="fit the synthetic disc scene and time each stage",
        description="Build the seeded disc scene (SPEC section 7), run derivatives, "
        "coarse search and LM, and print the truth, the fit and the stage times.",
    )
    demo.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
    demo.add_argument("--n-vertices", type=int, default=200, help="limb vertices (default 200)")
    demo.add_argument(
        "--rotation",
        type=float,
        default=None,
        metavar="RAD",
        help="true rotation in radians; also fits the rotation",
    )
    demo.add_argument("--window", type=int, default=30, help="search margin in px (default 30)")
    demo.add_argument("--repeat", type=int, default=1, help="run the stages N times, report the last")
    demo.add_argument("--plot", metavar="OUT.png", help="write a picture of the fit")
    demo.add_argument("--json", action="store_true", help="print JSON instead of text")

    fit = sub.add_parser(
        "fit",
        help="fit model polylines (CSV v,u,nv,nu,sigma) to images",
        description="Fit each IMAGE (.npy, .png, .fits) with its POLYLINE CSV "
        "(header v,u,nv,nu,sigma). Give IMAGE POLYLINE pairs, or --batch/--glob "
        "for many images whose polyline is the .csv of the same stem.",
    )
    fit.add_argument("pairs", nargs="*", metavar="IMAGE POLYLINE", help="image and polyline files")
    fit.add_argument(
        "--batch",
        metavar="LIST",
        help="text file, one 'IMAGE [POLYLINE]' per line (POLYLINE defaults to IMAGE's stem + .csv)",
    )
    fit.add_argument("--glob", metavar="PATTERN", help="images matching PATTERN (quote it)")
    fit.add_argument(
        "--window",
        type=int,
        nargs="+",
        default=[30],
        metavar="N",
        help="search margin: one int for both axes or two (V U); default 30",
    )
    fit.add_argument("--noise-sigma", type=float, help="image noise sigma (default: estimated)")
    fit.add_argument("--rotation", action="store_true", help="also fit an in-plane rotation")
    fit.add_argument("--ridge", action="store_true", help="finish with the gradient-ridge polish")
    fit.add_argument("--trust-region", type=float, metavar="PX", help="LM trust region (1.0 in production)")
    fit.add_argument("--tikhonov", type=float, default=0.0, metavar="ALPHA", help="pull toward the coarse seed")
    fit.add_argument("--no-polarity", action="store_true", help="do not reject vertices by polarity")
    fit.add_argument("--json", action="store_true", help="print JSON instead of a table")
    fit.add_argument(
        "--plot",
        metavar="OUT.png",
        help="write a picture of the fit (with several images: OUT_<image stem>.png)",
    )
    fit.add_argument("--no-progress", action="store_true", help="no progress bar")

    overlay = sub.add_parser(
        "overlay",
        help="split a Cassini summary PNG into an image and a model polyline CSV",
        description="Read a summary PNG (grey image + red model overlay), write the clean "
        "grey image (.npy) and the traced overlay as a polyline CSV, optionally displaced.",
    )
    overlay.add_argument("png", metavar="PNG", help="the summary PNG")
    overlay.add_argument("--shape", choices=("limb", "lines"), required=True, help="what the overlay is")
    overlay.add_argument("--n-lines", type=int, default=2, help="straight lines to trace (default 2)")
    overlay.add_argument("--image", required=True, metavar="OUT.npy", help="write the grey image here")
    overlay.add_argument("--polyline", required=True, metavar="OUT.csv", help="write the polyline here")
    overlay.add_argument(
        "--displace",
        type=float,
        nargs=2,
        default=(0.0, 0.0),
        metavar=("DV", "DU"),
        help="move the model by -(DV, DU): a correct fit then returns about (DV, DU)",
    )

    bench = sub.add_parser(
        "bench",
        help="quick benchmark table",
        description="Run dtalign.benchmarking (options are passed through).",
        add_help=False,
    )
    bench.add_argument("args", nargs=argparse.REMAINDER)

    # archive: campaigns on Dask; the parser and command live in dtalign.archive.cli.
    from .archive import cli as archive_cli

    archive_cli.add_parser(sub)
    return parser


# ---------------------------------------------------------------------------
# demo
# ---------------------------------------------------------------------------


_WARNINGS = _Warnings()


def _log_label(label: str) -> None:
    """Name the input the next pipeline warnings are about."""
    _WARNINGS.label = label


def _fmt(x: float, digits: int = 3) -> str:
    return f"{x:.{digits}f}" if math.isfinite(x) else ("inf" if x > 0 else "-inf")


def _cmd_demo(args: argparse.Namespace) -> int:
    from . import pipeline, scenes
    from ._constants import DEFAULT_LM_MAX_ITERATIONS

    if args.n_vertices < 3:
        raise CLIError(f"--n-vertices must be >= 3, got {args.n_vertices}")
    if args.window < 0:
        raise CLIError(f"--window must be >= 0, got {args.window}")
    if args.repeat < 1:
        raise CLIError(f"--repeat must be >= 1, got {args.repeat}")
    rotation = 0.0 if args.rotation is None else float(args.rotation)
    t0 = time.perf_counter()
    scene = scenes.disc_scene(
        n_vertices=args.n_vertices, rotation_rad=rotation, seed=args.seed, search_window=args.window
    )
    t_scene = time.perf_counter() - t0
    poly = scene.polyline
    for _ in range(args.repeat):
        products = pipeline.prepare_image(scene.image, scene.noise_sigma)
        fit = pipeline.fit_polyline_products(
            products,
            poly.vertices_vu,
            poly.normals_vu,
            poly.sigmas,
            search_window_vu=scene.search_window_vu,
            fit_rotation=args.rotation is not None,
            pivot_vu=scene.pivot_vu,
            pivot_distance_px=scene.pivot_distance_px if args.rotation is not None else None,
            trust_region_px=1.0,
        )
    noise_est = pipeline.estimate_noise_sigma(scene.image)
    t = fit.timings_s
    if args.json:
        out = {
            "true_offset_vu": list(scene.true_offset_vu),
            "true_rotation_rad": scene.true_rotation_rad,
            "noise_sigma_true": scene.noise_sigma,
            "noise_sigma_estimated": noise_est,
            "fit": fit.to_dict(),
            "scene_s": t_scene,
        }
        print(json.dumps(out, indent=2))
    else:
        h, w = scene.image.shape
        print(f"scene     : {h} x {w} disc, radius 150 px, {len(poly)} limb vertices, seed {args.seed}")
        print(f"noise     : sigma {scene.noise_sigma:g} DN (estimated from the image: {noise_est:.3f})")
        tv, tu = scene.true_offset_vu
        print(f"true      : offset (dv, du) = ({tv:.3f}, {tu:.3f}) px", end="")
        print(f", rotation {scene.true_rotation_rad:.5f} rad" if args.rotation is not None else "")
        print(f"coarse    : offset (dv, du) = {fit.coarse_offset_vu} (window ±{args.window})")
        (dv, du), (sv, su) = fit.offset_vu, fit.sigma_vu
        (sv2, su2) = fit.sigma_vu_scaled
        print(f"fitted    : dv = {_fmt(dv, 4)} ± {_fmt(sv, 4)}   du = {_fmt(du, 4)} ± {_fmt(su, 4)} px (1 sigma)")
        print(f"scaled    : ± {_fmt(sv2, 4)}, ± {_fmt(su2, 4)} px (1 sigma scaled by the residuals, "
              f"variance factor {_fmt(fit.variance_factor, 4)})")
        if fit.fit_rotation:
            print(f"rotation  : {fit.rotation_rad:.6f} ± {_fmt(fit.sigma_rotation_rad or 0.0, 6)} rad")
        print(f"error     : dv {dv - tv:+.4f}, du {du - tu:+.4f} px")
        if fit.observable_rank < (3 if fit.fit_rotation else 2):
            print(
                f"observable: rank {fit.observable_rank}: a circle turned about its centre "
                "looks the same, so its rotation is not measured (sigma inf)"
            )
        print(
            f"LM        : {fit.lm.iterations} iterations (cap {DEFAULT_LM_MAX_ITERATIONS}), "
            f"converged={fit.converged}, rms {_fmt(fit.rms_px)} px, "
            f"inliers {fit.inlier_count}/{len(poly)}"
        )
        if not fit.converged:
            print("            (it stopped at the cap before an accepted step fell below "
                  "0.001 px: the pose is the best found; see the docs)")
        print(f"status    : {fit.status}" + (
            f" ({', '.join(map(str, fit.reasons))})" if fit.reasons else ""))
        print(
            f"wall time : derivatives {t.get('derivatives', 0.0) * 1e3:.1f} ms, "
            f"coarse {t.get('coarse', 0.0) * 1e3:.1f} ms, lm {t.get('lm', 0.0) * 1e3:.1f} ms"
            + (" (first call: includes Numba compilation; try --repeat 2)" if args.repeat == 1 else "")
        )
    if args.plot:
        _plot(scene.image, poly.vertices_vu, fit, args.plot, "demo")
    return 0


def _plot(image: Any, vertices: Any, fit: Any, path: str | Path, label: str) -> None:
    from .plotting import plot_fit

    plot_fit(image, vertices, fit, path)
    print(f"{label}: wrote {path}", file=sys.stderr)


# ---------------------------------------------------------------------------
# fit
# ---------------------------------------------------------------------------


@dataclass
class _Job:
    image: Path
    polyline: Path


def _jobs(args: argparse.Namespace) -> tuple[list[_Job], bool]:
    """The (image, polyline) jobs and whether this is a batch."""
    jobs: list[_Job] = []
    if len(args.pairs) % 2:
        raise CLIError(
            "fit needs IMAGE POLYLINE pairs: got an odd number of files "
            f"({len(args.pairs)}); use --batch or --glob for images with same-stem .csv polylines"
        )
    for i in range(0, len(args.pairs), 2):
        jobs.append(_Job(Path(args.pairs[i]), Path(args.pairs[i + 1])))
    if args.batch:
        listfile = Path(args.batch)
        if not listfile.is_file():
            raise CLIError(f"batch list not found: {listfile}")
        for line in listfile.read_text(encoding="utf-8").splitlines():
            parts = line.split("#", 1)[0].split()
            if not parts:
                continue
            if len(parts) > 2:
                raise CLIError(f"batch list {listfile}: expected 'IMAGE [POLYLINE]', got {line!r}")
            img = Path(parts[0])
            if not img.is_absolute():
                img = listfile.parent / img
            if len(parts) == 2:
                pl = Path(parts[1]) if Path(parts[1]).is_absolute() else listfile.parent / parts[1]
            else:
                pl = img.with_suffix(".csv")
            jobs.append(_Job(img, pl))
    if args.glob:
        matches = sorted(p for p in glob.glob(args.glob) if not p.lower().endswith(".csv"))
        if not matches:
            raise CLIError(f"no image matches --glob {args.glob!r}")
        jobs.extend(_Job(Path(m), Path(m).with_suffix(".csv")) for m in matches)
    if not jobs:
        raise CLIError("fit needs IMAGE POLYLINE (or --batch LIST, or --glob PATTERN)")
    return jobs, bool(args.batch or args.glob or len(jobs) > 1)


def _window(values: Sequence[int]) -> tuple[int, int]:
    if len(values) not in (1, 2):
        raise CLIError(f"--window takes one or two ints, got {len(values)}")
    if any(v < 0 for v in values):
        raise CLIError(f"--window must be non-negative, got {' '.join(map(str, values))}")
    return (values[0], values[0]) if len(values) == 1 else (values[0], values[1])


def _fit_one(job: _Job, args: argparse.Namespace, window: tuple[int, int]) -> tuple[Any, Any, Any]:
    from . import io, pipeline

    image = io.load_image(job.image)
    poly = io.load_polyline_csv(job.polyline)
    fit = pipeline.fit_polyline(
        image,
        poly.vertices_vu,
        poly.normals_vu,
        poly.sigmas,
        search_window_vu=window,
        noise_sigma=args.noise_sigma,
        fit_rotation=args.rotation,
        use_polarity=not args.no_polarity,
        trust_region_px=args.trust_region,
        tikhonov_alpha=args.tikhonov,
        final_gradient_ridge=args.ridge,
    )
    return image, poly, fit


def _progress(items: list[_Job], enabled: bool) -> Iterable[_Job]:
    if not enabled:
        return items
    try:
        from tqdm import tqdm
    except ImportError:
        return _plain_progress(items)
    return tqdm(items, desc="fitting", unit="image", file=sys.stderr)


def _plain_progress(items: list[_Job]) -> Iterable[_Job]:
    for i, item in enumerate(items, 1):
        print(f"[{i}/{len(items)}] {item.image}", file=sys.stderr)
        yield item


def _table_single(job: _Job, poly: Any, fit: Any) -> str:
    d = fit.to_dict()
    p = 3 if fit.fit_rotation else 2
    lines = [
        f"image        : {job.image}",
        f"polyline     : {job.polyline} ({len(poly)} vertices)",
        f"noise sigma  : {fit.noise_sigma:.4g}",
        f"coarse       : (dv, du) = {fit.coarse_offset_vu}, window ±{fit.search_window_vu}",
        _offset_line(fit),
    ]
    if fit.fit_rotation:
        lines.append(
            f"rotation     : {fit.rotation_rad:.6f} ± {_fmt(fit.sigma_rotation_rad, 6)} rad"
            f" about {tuple(round(x, 2) for x in fit.pivot_vu)}"
        )
    rank = fit.observable_rank
    obs = f"rank {rank} of {p}"
    for e in fit.unobservable_directions:
        obs += f"; unobservable along {tuple(round(float(x), 4) for x in e)} (sigma inf)"
    lines += [
        f"observable   : {obs}",
        f"fit quality  : rms {_fmt(fit.rms_px)} px, inliers {fit.inlier_count}/{len(poly)}, "
        f"polarity-rejected {d['polarity_rejected']}, Tukey-rejected {d['tukey_rejected']}",
        f"LM           : {fit.lm.iterations} iterations, converged={fit.converged}, "
        f"degenerate={fit.degenerate}",
    ]
    lines.append(f"status       : {fit.status_message}")
    t = fit.timings_s
    lines.append(
        "wall time    : "
        + ", ".join(f"{k} {t[k] * 1e3:.1f} ms" for k in ("noise", "derivatives", "coarse", "lm") if k in t)
    )
    return "\n".join(lines)


def _offset_line(fit: Any) -> str:
    """The main line: the offset where the fit observes it, with the rank.

    A fully observed fit gives ``dv = ... ± ...   du = ... ± ...``; a
    rank-deficient one leads with the offset along each observed direction
    and says which direction is not measured (no finite sigma there).
    """
    (dv, du), (sv, su) = fit.offset_vu, fit.sigma_vu
    if fit.degenerate:
        return f"offset       : none measured (degenerate; the coarse seed is {fit.coarse_offset_vu})"
    observed = fit.observable_offset()
    if len(observed) == 2 and math.isfinite(sv) and math.isfinite(su):
        return (f"offset       : dv = {_fmt(dv, 4)} ± {_fmt(sv, 4)}   du = {_fmt(du, 4)} ± "
                f"{_fmt(su, 4)} px (1 sigma)")
    parts = [f"along ({e[0]:.4f}, {e[1]:.4f}): {_fmt(x, 4)} ± {_fmt(sd, 4)} px"
             for e, x, sd in observed]
    p = 3 if fit.fit_rotation else 2
    # no (dv, du) here: along the unmeasured direction it is the seed's, not a measurement
    return (f"offset       : rank {fit.observable_rank} of {p}: " + "; ".join(parts)
            + " (1 sigma); not measured along "
            + " and ".join(f"({float(e[0]) + 0.0:.4f}, {float(e[1]) + 0.0:.4f})"
                           for e in fit.unobservable_directions if abs(e[0]) + abs(e[1]) > 1e-6))


def _cmd_fit(args: argparse.Namespace) -> int:
    window = _window(args.window)
    jobs, batch = _jobs(args)
    results: list[dict[str, Any]] = []
    failures = 0
    failed_fits = 0
    show_progress = batch and not args.no_progress and not args.json
    for job in _progress(jobs, show_progress):
        _log_label(str(job.image))
        try:
            image, poly, fit = _fit_one(job, args, window)
            if args.plot:
                out = Path(args.plot)
                if batch:
                    out = out.with_name(f"{out.stem}_{job.image.stem}{out.suffix or '.png'}")
                _plot(image, poly.vertices_vu, fit, out, str(job.image))
        except (OSError, ValueError, TypeError, ImportError) as exc:
            failures += 1
            msg = _one_line(exc)
            results.append({"image": str(job.image), "polyline": str(job.polyline), "error": msg})
            if not batch:
                return _fail(msg)
            print(f"{PROG}: FAILED {job.image}: {msg}", file=sys.stderr)
            continue
        entry = {"image": str(job.image), "polyline": str(job.polyline), **fit.to_dict()}
        results.append(entry)
        failed_fits += fit.failed
        if not args.json and not batch:
            print(_table_single(job, poly, fit))
    if args.json:
        print(json.dumps(results if batch else results[0], indent=2))
    elif batch:
        print(_table_batch(results))
    if failures:
        print(f"{PROG}: {failures} of {len(jobs)} image(s) failed", file=sys.stderr)
        return 1
    if failed_fits:
        print(f"{PROG}: {failed_fits} of {len(jobs)} fit(s) failed (status 'failed')",
              file=sys.stderr)
        return EXIT_FIT_FAILED
    return 0


def _table_batch(results: list[dict[str, Any]]) -> str:
    header = f"{'image':<32} {'dv':>9} {'du':>9} {'sigma_v':>8} {'sigma_u':>8} {'rank':>4} {'inliers':>9}  status"
    rows = [header, "-" * len(header)]
    for r in results:
        name = Path(r["image"]).name[:32]
        if "error" in r:
            rows.append(f"{name:<32} {'':>9} {'':>9} {'':>8} {'':>8} {'':>4} {'':>9}  FAILED: {r['error']}")
            continue

        def f(x: Any, d: int) -> str:
            return x if isinstance(x, str) else f"{x:.{d}f}"

        status = r["status"] + (f" ({', '.join(r['reasons'])})" if r["reasons"] else "")
        rows.append(
            f"{name:<32} {f(r['offset_vu'][0], 3):>9} {f(r['offset_vu'][1], 3):>9} "
            f"{f(r['sigma_vu'][0], 4):>8} {f(r['sigma_vu'][1], 4):>8} {r['observable_rank']:>4} "
            f"{str(r['inlier_count']) + '/' + str(r['n_vertices']):>9}  {status}"
        )
    return "\n".join(rows)


# ---------------------------------------------------------------------------
# bench and main
# ---------------------------------------------------------------------------


def _cmd_overlay(args: argparse.Namespace) -> int:
    import numpy as np

    from . import io
    from .scenes import Polyline

    if args.n_lines < 1:
        raise CLIError(f"--n-lines must be >= 1, got {args.n_lines}")
    frame = io.load_cassini_overlay_frame(args.png)
    lines = io.overlay_polylines(frame, shape=args.shape, n_lines=args.n_lines)
    model = io.concatenate_polylines(lines, name=Path(args.png).stem)
    moved = Polyline(
        model.name, model.vertices_vu - np.asarray(args.displace), model.normals_vu, model.sigmas
    )
    np.save(args.image, frame.image)
    io.save_polyline_csv(args.polyline, moved)
    print(
        f"{args.png}: {frame.image.shape[0]} x {frame.image.shape[1]} image "
        f"({frame.header_rows} header rows cropped) -> {args.image}; "
        f"{len(moved)} vertices on {len(lines)} curve(s) -> {args.polyline}"
    )
    return 0


def _cmd_bench(args: argparse.Namespace) -> int:
    try:
        module = importlib.import_module("dtalign.benchmarking")
    except ModuleNotFoundError as exc:
        if exc.name not in ("dtalign.benchmarking",):
            raise
        return _fail("benchmarks are not available: this build has no dtalign.benchmarking module")
    rest = [a for a in args.args if a != "--"]
    result = module.main(rest)
    return int(result or 0)


def _cmd_archive(args: argparse.Namespace) -> int:
    from .archive import cli as archive_cli

    return archive_cli.command(args)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``dtalign`` command line; returns the exit status.

    Parameters
    ----------
    argv : sequence of str, optional
        Arguments without the program name; ``sys.argv[1:]`` when None.
    """
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["bench"]:
        # Everything after "bench" belongs to the benchmark module, options too.
        return _cmd_bench(argparse.Namespace(args=argv[1:]))
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse printed its one-line usage error
        return int(exc.code or 0)
    if args.version:
        from . import __version__

        print(f"{PROG} {__version__}")
        return 0
    if args.command is None:
        parser.print_help()
        return 2
    handlers = {"demo": _cmd_demo, "fit": _cmd_fit, "overlay": _cmd_overlay, "bench": _cmd_bench,
                "archive": _cmd_archive}
    log = logging.getLogger("dtalign")
    log.addHandler(_WARNINGS)
    _log_label(args.command if args.command == "demo" else "")
    try:
        return handlers[args.command](args)
    except CLIError as exc:
        return _fail(str(exc))
    except (OSError, ValueError, TypeError, ImportError) as exc:
        if os.environ.get("DTALIGN_DEBUG"):
            raise
        return _fail(_one_line(exc))
    except KeyboardInterrupt:
        return _fail("interrupted")
    finally:
        log.removeHandler(_WARNINGS)
