"""Run the validation: the renderer's checks, then every family's scenes, fitted and scored.

``python -m benchmarks.validate [--scenes N] [--seed S] [--families F ...]``
renders ``N`` scenes per family and edge from seed ``S``, writes
``benchmarks/results/validation/run-<date>-seed<S>-n<N>.json`` (the run's
metadata, the checks, every fit's record) and a CSV of the records beside
it, and prints the table of :mod:`.tables`. A failing renderer check stops
the run before any fit: the renders are not trusted then.
"""

from __future__ import annotations

import argparse
import csv
import datetime
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import dtalign

from . import checks, families, fitting, tables
from .render import versions

RESULTS = Path(__file__).resolve().parents[1] / "results" / "validation"


def _commit() -> str:
    try:
        out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                             text=True, cwd=Path(__file__).parent, check=True)
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, cwd=Path(__file__).parent)
        return out.stdout.strip() + ("-dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def run_checks() -> list[dict]:
    """Render and measure every renderer check, printing each."""
    results = []
    for name in checks.CHECKS:
        res = checks.measure(name, checks.render_check(name))
        results.append(res)
        print(f"renderer check {name:16s} {res['value']:.2e} ({res['unit']}, tolerance "
              f"{res['tolerance']:.0e}) {'ok' if res['ok'] else 'FAILED'}", flush=True)
    return results


def _rendered(p: dict, cache: Path | None) -> np.ndarray:
    """The render of scene ``p``, read from ``cache`` when it holds it (and
    written there when not): the renders are deterministic, so a cached one is
    the same image, and refitting after a change to the fit skips Mitsuba."""
    if cache is None:
        return families.render_scene(p)
    path = cache / f"s{p['seed']}_{p['family']}_{p['edge']}_{p['index']}.npy"
    if path.exists():
        return np.load(path)
    image = families.render_scene(p)
    cache.mkdir(parents=True, exist_ok=True)
    np.save(path, image)
    return image


def run_scenes(n_scenes: int, seed: int, which: list[str],
               cache: Path | None = None) -> list[dict]:
    """Draw, render (or read from ``cache``) and fit every scene; one record per
    fit (no images)."""
    records = []
    for family in which:
        for edge in families.edges_of(family):
            for index in range(n_scenes):
                p = families.draw(family, edge, index, seed)
                t0 = time.perf_counter()
                image = _rendered(p, cache)
                t_render = time.perf_counter() - t0
                fits = [{**{k: p[k] for k in ("family", "edge", "index", "seed")},
                         "render_s": t_render, "scene": p, **rec}
                        for rec in fitting.fit_scene(p, image)]
                records += fits
                print(f"{family:15s} {edge:10s} {index:3d}  render {t_render:5.1f} s  " + "  ".join(
                    f"{r['method']}: {r['status']} {r.get('error_px', float('nan')):.4f}"
                    for r in fits), flush=True)
    return records


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.validate", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", type=int, default=4, help="scenes per family and edge")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--families", nargs="+", default=list(families.FAMILIES),
                    choices=families.FAMILIES)
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument("--cache", type=Path, default=None,
                    help="a directory of renders to read, and to write those it lacks")
    args = ap.parse_args(argv)
    started = datetime.datetime.now(datetime.UTC)
    meta = dict(date=started.isoformat(timespec="seconds"), commit=_commit(), seed=args.seed,
                scenes=args.scenes, families=args.families, dtalign=dtalign.__version__,
                render_cache=None if args.cache is None else str(args.cache),
                **versions())
    print(json.dumps(meta), flush=True)
    t0 = time.perf_counter()
    check_results = run_checks()
    if not all(c["ok"] for c in check_results):
        print("a renderer check failed: no scene is fitted", file=sys.stderr)
        return 1
    records = run_scenes(args.scenes, args.seed, args.families, args.cache)
    meta["run_s"] = time.perf_counter() - t0
    rows = tables.summarise(records)
    args.out.mkdir(parents=True, exist_ok=True)
    stem = f"run-{started:%Y%m%dT%H%M%S}-seed{args.seed}-n{args.scenes}"
    (args.out / f"{stem}.json").write_text(json.dumps(
        dict(meta=meta, checks=check_results, summary=rows, records=records), indent=1))
    flat = ["family", "edge", "index", "method", "status", "error_px", "accepted", "d2",
            "d2_scaled", "d2_mestimator", "time_s", "exception"]
    with open(args.out / f"{stem}.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=flat, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(records)
    print(tables.rst_table(rows))
    print(f"run {meta['run_s']:.0f} s, {len(records)} fits; written {args.out / stem}.json")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
