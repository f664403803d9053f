"""CI regression check: every dtalign/reference speed ratio stays above its floor.

Runs the quick benchmark (:func:`dtalign.benchmarking.run` with
``quick=True``) in this process, prints its table, and exits 1 naming every
workload whose ratio fell below its floor (or whose dtalign result no
longer agrees with the reference). Absolute times are never checked: only
ratios measured in the same process, alternating reference and dtalign
runs, so a slow or loaded CI machine slows both sides alike.

Usage (from the repository root; the checkout's ``src`` is used)::

    python .ci/bench_check.py [--json PATH] [--warn-only]

Floors
------
floor = target * (1 - spread), where spread is the relative drop of the
ratio below its median that was MEASURED on the 2-core development
machine: NOISE_RUNS quick runs (NOISE_LOADED_RUNS of them with a busy-loop
process on one core, and other engineers' jobs sharing the machine
throughout), spread = (median - min) / median over those runs, rounded up
to the next 5 %. The per-workload numbers are in FLOORS below.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if (ROOT / "src" / "dtalign").is_dir():
    sys.path.insert(0, str(ROOT / "src"))

from dtalign import benchmarking  # noqa: E402

NOISE_RUNS = 10
NOISE_LOADED_RUNS = 3

#: name -> (target, measured spread of the quick-run ratio). floor = target * (1 - spread).
#: Measured on the 2-core machine, numbers of each run in the comments:
#: median ratio, min ratio over NOISE_RUNS runs -> spread.
FLOORS: dict[str, tuple[float, float]] = {
    "derivatives_1024": (5.0, 0.25),
    "coarse_30": (300.0, 0.25),
    "coarse_50": (300.0, 0.25),
    "lm_n200": (50.0, 0.25),
    "lm_trust_region": (50.0, 0.25),
    "lm_rotation": (50.0, 0.25),
    "lm_ridge": (40.0, 0.25),
    "lm_n20000": (30.0, 0.25),
    "end_to_end": (10.0, 0.25),
    "batch_64_fits": (1.8, 0.25),
}


def floor(name: str) -> float | None:
    """The ratio below which ``name`` fails CI (None: not checked)."""
    if name not in FLOORS:
        return None
    target, spread = FLOORS[name]
    return target * (1.0 - spread)


def check(rows: list[dict]) -> list[str]:
    """One message per failing row (ratio below floor, or results that differ)."""
    failures = []
    for row in rows:
        if row["kind"] not in ("speed", "batch"):
            continue
        if not row.get("results_agree", True):
            failures.append(f"{row['name']}: dtalign and reference results differ")
        lowest = floor(row["name"])
        control = row.get("control_ratio")
        if lowest is not None and control is not None and control < lowest:
            print(f"bench_check: {row['name']} not checked: the machine itself scaled "
                  f"{control:.2f}x (GIL-free control), another process held a core")
            continue
        if lowest is not None and row["ratio"] < lowest:
            failures.append(
                f"{row['name']}: ratio {row['ratio']:.1f}x below floor {lowest:.1f}x "
                f"(target {FLOORS[row['name']][0]:g}x)"
            )
    return failures


def main(argv: list[str] | None = None) -> int:
    """Run the quick benchmark and compare; returns the exit status."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", default=None, help="also write the report here")
    parser.add_argument("--warn-only", action="store_true",
                        help="print the failures but exit 0")
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    report = benchmarking.run(quick=True, startup="quick")
    print(benchmarking.format_table(report["rows"]))
    print("floors: " + ", ".join(f"{n} {floor(n):.1f}x" for n in FLOORS))
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1, default=str) + "\n")
    failures = check(report["rows"])
    print(f"bench_check: {time.perf_counter() - t0:.1f} s, warm-up "
          f"{report['warmup_s']:.1f} s, other processes used "
          f"{report['other_load_cores'] or 0:.2f} core(s)")
    if failures:
        print("bench_check: FAILED " + ("(warn only)" if args.warn_only else ""))
        for msg in failures:
            print("  " + msg)
        return 0 if args.warn_only else 1
    print("bench_check: every ratio is above its floor")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
