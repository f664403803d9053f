"""CI regression check: every dtalign/reference speed ratio stays above its floor.

Runs the quick benchmark (:func:`dtalign.benchmarking.run` with
``quick=True``) in this process, prints its table, and exits 1 naming every
workload whose ratio fell below its floor twice (a workload below its floor
is measured once more: :func:`confirm`), every scaling row the run failed
twice against its target and its control
(:func:`dtalign.benchmarking.scaling.judge`), or whose dtalign result no
longer agrees with the reference. Absolute times are never checked: only
ratios measured in the same process, alternating reference and dtalign
runs (or one worker and two), so a slow or loaded CI machine slows both
sides alike.

Usage (from the repository root; the installed ``dtalign`` is used, or the
checkout's ``src`` when none is installed)::

    python .ci/bench_check.py [--json PATH] [--warn-only]

Floors
------
floor = min(target, achieved) * (1 - spread), where ``achieved`` is the
median ratio measured today (it matters only where a target is not met
yet) and spread is the relative drop of the ratio below its median that
was MEASURED on the 2-core development machine: NOISE_RUNS quick runs in
three campaigns (NOISE_LOADED_RUNS of them with a busy-loop process on one
core; in one campaign other engineers' test suites shared the machine
throughout), spread = (median - min) / median of the ratio over a
campaign's runs, the largest of the three, rounded up to the next 5 %.
Where a CI run on another machine measured a larger drop on unchanged
code (E below: most likely a machine's caches, not the code), that drop
sets the spread. The per-workload numbers are in FLOORS below.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import NamedTuple

ROOT = Path(__file__).resolve().parent.parent
try:  # the installed package (CI installs the checkout; its kernel cache is warm)
    import dtalign
except ImportError:  # a bare checkout: use its src/
    sys.path.insert(0, str(ROOT / "src"))
    import dtalign

from dtalign import benchmarking  # noqa: E402

NOISE_RUNS = 35
NOISE_LOADED_RUNS = 12

#: name -> (target, achieved median, spread);
#: floor = min(target, achieved) * (1 - spread).
#: Where the target is met the floor is the target less the measured noise
#: margin (issue #3). Where it is not met reliably the floor guards the
#: ratio achieved, less the same margin, so a regression still fails CI;
#: the missed targets are printed on every run and stated in the notes.
#: The scaling rows (2 workers against 1) have no floor here: the run
#: judges each against its target and the same run's control
#: (:func:`dtalign.benchmarking.scaling.judge`), and CI fails the rows that
#: run failed, measured twice.
#: Measured 2026-11-22 on the 2-core development machine in three campaigns
#: of quick runs: A (10 runs) while other engineers' test suites kept 1.0-1.6
#: cores busy, 3 of them with an extra busy-loop process; B (10 runs) quiet,
#: 4 with a busy-loop process on one core; C (15 runs, of faster kernels
#: than A and B's) quiet, 5 with a busy-loop process. Per workload: median ratio /
#: lowest ratio / (median - lowest) / median. The spread used is the largest
#: of the three, rounded up to the next 5 % (A's shared machine sets most),
#: and the achieved median C's lower one (quiet or busy-loop runs). D (5
#: quick runs later the same day, after the LM kernels took four vertices at
#: a time) is listed where it changed a row: all its spreads were within
#: the margins above.
FLOORS: dict[str, tuple[float, float, float]] = {
    # A 11.8 / 11.3 / 0.04   B 11.7 / 11.3 / 0.04   C 11.2 / 11.0 / 0.02
    "derivatives_1024": (5.0, 11.2, 0.05),
    # A 240 / 186 / 0.23     B 236 / 218 / 0.07     C 312 / 294 / 0.10
    "coarse_30": (300.0, 312.0, 0.25),
    # A 465 / 390 / 0.16     B 464 / 421 / 0.09     C 599 / 569 / 0.05
    "coarse_50": (300.0, 599.0, 0.20),
    # the scans of :ref:`contract-today` (issue 13), 2026-12-01, runs while other sessions shared
    # the two cores (1.1-1.7 cores busy): coarse_scored 409-412x; polarity
    # 299-432x. Basin, with the neighbours' bounds: 16 quick runs 373-1131x
    # (median 516x, (median - lowest) / median 0.28: the 0.30 below), 6 full
    # runs 589-668x, bench_check 510x (load average 2.9-5.2, 1.0-1.5 cores
    # busy); its floor is the target less the margin, below the lowest.
    # The margins are those of the rows above with the same kind of kernel
    # (coarse_30's for the mask searches), until quiet campaigns measure them.
    "coarse_scored_30": (300.0, 409.0, 0.25),
    "polarity_search_30": (300.0, 299.0, 0.30),
    "secondary_basin_30": (300.0, 373.0, 0.30),
    # A 80.8 / 59.3 / 0.27   B 77.2 / 74.5 / 0.03   C 93.5 / 91.2 / 0.03
    # D 107 / 104 / 0.04
    "lm_n200": (50.0, 107.0, 0.30),
    # A 85.2 / 57.1 / 0.33   B 77.3 / 75.1 / 0.03   C 92.3 / 91.0 / 0.02
    # D 108 / 105 / 0.03
    "lm_trust_region": (50.0, 108.0, 0.35),
    # A 48.3 / 39.3 / 0.19   B 49.0 / 46.3 / 0.06   C 55.0 / 54.1 / 0.02
    # D 91.7 / 88.2 / 0.04
    "lm_rotation": (50.0, 91.7, 0.20),
    # A 29.4 / 14.9 / 0.49   B 36.1 / 31.2 / 0.14   C 55.3 / 52.8 / 0.09
    # D 56.0 / 50.5 / 0.10
    "lm_ridge": (40.0, 56.0, 0.50),
    # A 10.5 / 9.0 / 0.14    B 9.6 / 7.5 / 0.22     C 12.6 / 12.3 / 0.03
    # D (the target met since) 31.8 / 31.0 / 0.03
    # E, CI machines: the fresh-clone CI run of a926c37 (2026-12-02; twice as
    # long as the green runs before it) gave 19.9x and, measured again, 20.6x,
    # on LM code unchanged since the green run of 7ee4619, with lm_n200 at
    # 96.7x (that machine could not be inspected). The row is the one whose
    # working set outgrows a core's L2: ~104 bytes per vertex (points,
    # sigmas and their 1/sigma^2, polarity, residuals, weights, samples and
    # Jacobian of the state and of the trial step), 2.1 MB at N = 20,000.
    # On the development machine of that day (2 MiB of L2 per core) a
    # vertex-iteration cost 10-20 % more from N = 40,000 than up to
    # N = 20,000 (20 forced iterations), and the row gave 29.7-30.2x; a
    # CPU with less L2 pays that at N = 20,000, while the reference's NumPy
    # temporaries stream from memory on any CPU. Spread
    # (31.8 - 19.9) / 31.8 = 0.37, rounded up: 0.40 (floor 18x).
    "lm_n20000": (30.0, 31.8, 0.40),
    # A 20.1 / 17.0 / 0.15   B 20.4 / 19.6 / 0.04   C 20.9 / 20.5 / 0.03
    "end_to_end": (10.0, 20.9, 0.15),
}


def floor(name: str) -> float | None:
    """The ratio below which ``name`` fails CI (None: not checked)."""
    if name not in FLOORS:
        return None
    target, achieved, spread = FLOORS[name]
    return min(target, achieved) * (1.0 - spread)


def missed_targets(rows: list[dict]) -> list[str]:
    """Rows whose ratio is below the issue's target (printed; failed only
    below a speed row's floor, or by a scaling row's judgement)."""
    out = []
    for row in rows:
        if row["kind"] == "batch" and row.get("target") is not None:
            if row["ratio"] < row["target"]:
                out.append(f"{row['name']} {row['ratio']:.2f}x < target {row['target']:g}x "
                           f"({row.get('rule', 'no control')})")
        elif row["name"] in FLOORS and row["ratio"] < FLOORS[row["name"]][0]:
            out.append(f"{row['name']} {row['ratio']:.1f}x < target {FLOORS[row['name']][0]:g}x")
    return out


class Failure(NamedTuple):
    """A failing row: ``kind`` is ``"ratio"`` (below its floor, or a scaling
    row below its target and its control) or ``"results"``."""

    name: str
    kind: str
    message: str


def check(rows: list[dict]) -> list[Failure]:
    """One failure per failing row and reason (ratio below floor or, for a
    scaling row, the run's judgement; results that differ)."""
    failures = []
    for row in rows:
        if row["kind"] not in ("speed", "batch"):
            continue
        if not row.get("results_agree", True):
            failures.append(Failure(row["name"], "results",
                                    f"{row['name']}: dtalign and reference results differ"))
        if row["kind"] == "batch":  # judged in the run, against the same run's control
            if row.get("results_agree", True) and not row["passed"]:
                failures.append(Failure(
                    row["name"], "ratio",
                    f"{row['name']}: ratio {row['ratio']:.2f}x {row['rule']}: needs "
                    f"{row['required_ratio']:.2f}x (target {row['target']:g}x, "
                    f"{row['judged_by']} {row[row['judged_by']]:.2f}x)",
                ))
            continue
        lowest = floor(row["name"])
        if lowest is not None and row["ratio"] < lowest:
            failures.append(Failure(
                row["name"], "ratio",
                f"{row['name']}: ratio {row['ratio']:.1f}x below floor {lowest:.1f}x "
                f"(target {FLOORS[row['name']][0]:g}x)",
            ))
    return failures


def _rerun_name(row: dict) -> str | None:
    """What :func:`dtalign.benchmarking.run` takes to measure ``row`` again."""
    if row["name"] in benchmarking.WORKLOADS:
        return row["name"]
    return "batch" if row["kind"] == "batch" else None


def confirm(failures: list[Failure], rows: list[dict]) -> list[Failure]:
    """Measure the rows below their floor once more; keep the failures that repeat.

    The machine's speed drifts over minutes: right after the test suite the
    compiled coarse scans have measured up to twice their usual time while
    the NumPy reference moved 10 % (in two CI runs of 2026-12-01/02 and a
    re-run, coarse_30, coarse_50 and coarse_scored_30 at 132-218x against
    floors of 225-240x; coarse_30 372x from the same install five minutes
    later). A regression is in the code and shows again; a moment's
    slowness does not. Results that differ from the reference fail at once.
    """
    ratio_failed = {f.name for f in failures if f.kind == "ratio"}
    below = {r["name"]: r for r in rows if r["name"] in ratio_failed}
    others = [f for f in failures if f.kind != "ratio"]
    wanted = {_rerun_name(r) for r in below.values()}
    if None in wanted or not below:
        return failures
    print(f"bench_check: measuring again: {', '.join(sorted(below))}")
    again = benchmarking.run(sorted(n for n in wanted if n is not None), quick=True,
                             startup="none")["rows"]
    print(benchmarking.format_table([r for r in again if r["name"] in below]))
    repeated = check([r for r in again if r["name"] in below])
    measured = {r["name"] for r in again}
    return others + [f._replace(message=f"{f.message} (and again)") for f in repeated] + [
        Failure(name, "ratio", f"{name}: not measured again")
        for name in below if name not in measured
    ]


def main(argv: list[str] | None = None) -> int:
    """Run the quick benchmark and compare; returns the exit status."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", default=None, help="also write the report here")
    parser.add_argument("--warn-only", action="store_true",
                        help="print the failures but exit 0")
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    print(f"bench_check: dtalign {dtalign.__version__} from {Path(dtalign.__file__).parent}")
    report = benchmarking.run(quick=True, startup="quick")
    print(benchmarking.format_table(report["rows"]))
    print("floors: " + ", ".join(f"{n} {floor(n):.1f}x" for n in FLOORS))
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1, default=str) + "\n")
    failures = check(report["rows"])
    if failures:
        failures = confirm(failures, report["rows"])
    missed = missed_targets(report["rows"])
    if missed:
        print("bench_check: below target (not a failure): " + "; ".join(missed))
    print(f"bench_check: {time.perf_counter() - t0:.1f} s, warm-up "
          f"{report['warmup_s']:.1f} s, other processes used "
          f"{report['other_load_cores'] or 0:.2f} core(s)")
    if failures:
        print("bench_check: FAILED " + ("(warn only)" if args.warn_only else ""))
        for failure in failures:
            print("  " + failure.message)
        return 0 if args.warn_only else 1
    print("bench_check: every ratio is above its floor")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
