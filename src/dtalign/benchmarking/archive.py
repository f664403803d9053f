"""The campaign rows: :func:`dtalign.archive.run` on a LocalCluster against the serial loop.

``archive_32_frames``: a campaign of 32 synthetic frames (1024 x 1024,
three polylines each: :func:`dtalign.archive.make_example`) on the
LocalCluster :func:`~dtalign.archive.run` starts, with 2 worker processes
(one thread each, the settings of
:data:`dtalign.archive.runner.LOCAL_CLUSTER_CONFIG`), results into a fresh
store, against the serial loop over the same items in this process
(:func:`dtalign.archive.fit_item`: read, prepare, fit, the ambiguity
examination included; no store), the two alternated. Timed region: the cluster side times one whole
``run(items, store, client)``, from planning against the (empty) store to
its last part written, with ``run``'s default tasks (4 frames each here,
``items_per_task`` in the row); the cluster is started and its workers
warmed before any timing, and both sides have run the campaign once
untimed, so the ratio measures a campaign's throughput, not Dask's
start-up. ``single_s`` and ``single_ratio`` are the same campaign in tasks
of one frame (``items_per_task=1``), timed alike in each pair. ``cold_s`` and
``cold_ratio`` are the start-up included: one ``run(items, store,
workers=2)`` that starts, warms and closes its own cluster, timed once.
The stored rows must equal the serial loop's, bit for bit (the cold run's
too).

``archive_store_per_item``: the client's time writing the store (building
the Arrow tables, writing and syncing the part files) per item, against
the serial time of one item.

The campaign row is judged as the batch rows are
(:func:`~dtalign.benchmarking.scaling.judge`, against its SHA-256
control, as whole images are). That control is SHA-256 tasks (GIL-free C code, each about
a frame's time) run the same two ways, serially here and through the same
cluster, alternated with the campaign: its ratio is what the machine,
shared with other processes, and Dask's cost per task allowed two
processes at that moment. ``fp_control_ratio`` is the same for compiled
work bound by floating-point throughput (:mod:`~dtalign.benchmarking.fpload`),
which two virtual CPUs sharing one physical core's FP pipes scale far less
on than on SHA-256. ``other_load_cores`` is the CPU of processes
other than this one and its two workers. ``cpu_ceiling_ratio`` is the
ratio two otherwise idle cores would allow at best: twice the serial
loop's CPU time over the campaign's (this process's, the scheduler and
client in it, plus both workers'), medians; on a machine whose cores other
sessions share, the kernel gives a session's processes together about one
session's share, so the wall-clock ratio can stay near 1x whatever the
code does, while CPU time changes much less.

Optional: the rows are skipped (an ``info`` row says so) when Dask or
pyarrow is missing, and the section runs only in a full run or when asked
for (``--only archive``).
"""

from __future__ import annotations

import functools
import hashlib
import os
import shutil
import statistics
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from . import scaling
from .timing import _Load, _progress

__all__ = ["ARCHIVE_FRAMES", "ARCHIVE_TARGET", "STORE_OVERHEAD_TARGET", "measure_archive"]

#: The campaign of the issue: 32 frames of 1024^2, three polylines each.
ARCHIVE_FRAMES = 32
ARCHIVE_SIZE = 1024
#: Two worker processes on a 2-core machine, less the client's and the scheduler's share.
ARCHIVE_TARGET = 1.7
#: The store may cost at most this fraction of one item's serial time.
STORE_OVERHEAD_TARGET = 0.05

#: Columns that differ between two runs of the same fits (times, places, run ids).
_VOLATILE = {"read_s", "prepare_s", "fit_s", "item_s", "worker", "run_id", "finished_at"}


def _skipped(reason: str) -> list[dict[str, Any]]:
    return [{"name": "archive_32_frames", "kind": "archive", "reference": "-", "dtalign": "-",
             "target": f">= {ARCHIVE_TARGET:g}x", "passed": True, "skipped": reason,
             "description": f"skipped: {reason}"}]


#: The control task: SHA-256 over 40 MiB, GIL-free C code with the CPU's SHA
#: instructions that takes about a frame's time (a shorter task would
#: measure Dask's cost per task more than the machine). Its 2-process scaling
#: through the same cluster, a task each, is what the machine (other sessions
#: share the cores) and Dask's cost per task allowed at that moment.
_CONTROL_MIB = 40
_CONTROL_TASKS = 32

#: ...hashed as 40 passes over a buffer of 1 MiB, which each worker keeps.
#: The control must not change the campaign it is compared with: a 40 MiB
#: buffer kept in a worker made every later campaign on that worker fault in
#: ~21,600 fresh pages (about 180 without it) and take 15-20 % more CPU
#: (docs/campaign.rst, "Throughput").
_CONTROL_BUFFER_MIB = 1


#: The second control: compiled work bound by floating-point throughput
#: (:mod:`~dtalign.benchmarking.fpload`), 270 units of about a fit each,
#: about a frame's time, the same two ways. Two virtual CPUs that share a physical
#: core's FP pipes scale far less on it than on SHA-256; the fits keep
#: those pipes busy as it does.
_FP_UNITS = 270


def _fp_control_task(k: int) -> float:
    from . import fpload

    return sum(fpload.unit() for _ in range(_FP_UNITS))


@functools.lru_cache(maxsize=1)
def _control_buffer() -> bytes:
    return bytes(range(256)) * (_CONTROL_BUFFER_MIB * 4096)


def _control_task(k: int) -> bytes:
    buffer, h = _control_buffer(), hashlib.sha256()
    for _ in range(_CONTROL_MIB // _CONTROL_BUFFER_MIB):
        h.update(buffer)  # (releases the GIL: hashlib does for more than 2 KiB)
    return h.digest()


def _cpu_s() -> float:
    """CPU seconds of the calling process (a worker's, through ``client.run``)."""
    t = os.times()
    return t.user + t.system


def _comparable(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    out = [{k: v for k, v in r.items() if k not in _VOLATILE} for r in rows]
    return sorted(out, key=lambda r: (r["item_id"], r["polyline_index"]))


@dataclass
class _Pairs:
    """What the timed (serial, cluster) pairs measured, an entry per pair."""

    t_serial: list[float] = field(default_factory=list)
    t_cluster: list[float] = field(default_factory=list)
    t_single: list[float] = field(default_factory=list)  # tasks of one frame
    cpu_serial: list[float] = field(default_factory=list)  # this process (the idle scheduler's thread included)
    cpu_cluster: list[float] = field(default_factory=list)  # this process (scheduler, client, store) + workers
    cpu_single: list[float] = field(default_factory=list)
    store_s: list[float] = field(default_factory=list)
    c_serial: list[float] = field(default_factory=list)  # the SHA-256 control
    c_cluster: list[float] = field(default_factory=list)
    f_serial: list[float] = field(default_factory=list)  # the floating-point control
    f_cluster: list[float] = field(default_factory=list)
    agree: bool = True  # every stored row equals the serial loop's
    summary: Any = None  # the last campaign's summary


def _write_campaign(tmp: Path) -> tuple[list[Any], list[dict[str, Any]]]:
    """The campaign's items, written to disk, and the serial loop's rows (its warm-up)."""
    from ..archive import fit_item, make_example, read_manifest

    _progress(f"archive: writing {ARCHIVE_FRAMES} frames of {ARCHIVE_SIZE}^2 ...")
    items = read_manifest(make_example(tmp / "campaign", frames=ARCHIVE_FRAMES,
                                       size=ARCHIVE_SIZE))
    # The frames just written (256 MiB) are on disk before any timing:
    # left dirty, the kernel writes them back about 30 s later
    # (vm.dirty_expire_centisecs), in the middle of a timed pair, and a
    # store part's fsync then waits for that writeback (286 ms once,
    # against about 10 ms); the serial loop syncs nothing and never pays.
    if hasattr(os, "sync"):
        os.sync()
    serial_rows = [r for i in items for r in fit_item(i)["results"]]  # warm, and the truth
    return items, serial_rows


def _warm(client: Any, items: list[Any], tmp: Path) -> None:
    """One untimed campaign and control round, as the serial loop had one."""
    from ..archive import run

    # The workers' first frames pay for first-touch allocations of
    # image-sized arrays (and the run registers the plugin that warms each
    # worker's kernels).
    run(items, tmp / "store-warm", client, progress=False, warm=True)
    client.gather(client.map(_control_task, range(4), pure=False))
    client.gather(client.map(_fp_control_task, range(4), pure=False))
    _control_task(0)
    _fp_control_task(0)


def _on_cluster(client: Any, call: Callable[[], Any]) -> tuple[Any, float, float]:
    """``call()``'s value, wall seconds, and CPU seconds here and in the workers."""
    w0 = client.run(_cpu_s)
    c0, t0 = _cpu_s(), time.perf_counter()
    value = call()
    wall = time.perf_counter() - t0
    c1, w1 = _cpu_s(), client.run(_cpu_s)
    return value, wall, c1 - c0 + sum(w1.values()) - sum(w0.values())


def _control(client: Any, task: Callable[[int], Any], serial: list[float],
             cluster: list[float]) -> None:
    """A control's tasks timed serially here, then through the cluster."""
    t0 = time.perf_counter()
    for j in range(_CONTROL_TASKS):
        task(j)
    serial.append(time.perf_counter() - t0)
    t0 = time.perf_counter()
    client.gather(client.map(task, range(_CONTROL_TASKS), pure=False))
    cluster.append(time.perf_counter() - t0)


def _stored_as_serial(summary: Any, store: Path, n_items: int,
                      serial_rows: list[dict[str, Any]]) -> bool:
    """Whether a run did every item and stored the serial loop's rows."""
    from ..archive import Store

    return summary.done == n_items and (
        _comparable(Store(store).results().to_pylist()) == _comparable(serial_rows))


def _pair(k: int, items: list[Any], tmp: Path, client: Any,
          serial_rows: list[dict[str, Any]], p: _Pairs) -> None:
    """Pair ``k``: the serial loop, the campaign (run's tasks, then a frame a task), the controls."""
    from ..archive import fit_item, run

    c0, t0 = _cpu_s(), time.perf_counter()
    for item in items:
        fit_item(item)
    p.t_serial.append(time.perf_counter() - t0)
    p.cpu_serial.append(_cpu_s() - c0)
    store, single_store = tmp / f"store-{k}", tmp / f"store-{k}-single"
    summary, wall, cpu = _on_cluster(
        client, lambda: run(items, store, client, progress=False, warm=False))
    p.t_cluster.append(wall)
    p.cpu_cluster.append(cpu)
    single, wall, cpu = _on_cluster(
        client, lambda: run(items, single_store, client, progress=False, warm=False,
                            items_per_task=1))
    p.t_single.append(wall)
    p.cpu_single.append(cpu)
    p.agree = p.agree and _stored_as_serial(single, single_store, len(items), serial_rows)
    p.store_s.append(summary.store_s)
    _control(client, _control_task, p.c_serial, p.c_cluster)
    _control(client, _fp_control_task, p.f_serial, p.f_cluster)
    p.agree = p.agree and _stored_as_serial(summary, store, len(items), serial_rows)
    p.summary = summary


def measure_archive(repeats: int = 5) -> list[dict[str, Any]]:
    """The two campaign rows (or one ``info`` row when Dask or pyarrow is missing).

    Parameters
    ----------
    repeats : int
        Alternating (serial, cluster) pairs; medians are reported.
    """
    try:
        import distributed
        import pyarrow  # noqa: F401
    except ImportError as exc:
        return _skipped(f"needs dtalign[dask] ({exc.name} is missing)")
    from ..archive import local_cluster, run

    tmp = Path(tempfile.mkdtemp(prefix="dtalign-bench-archive-"))
    try:
        items, serial_rows = _write_campaign(tmp)
        _progress("archive: starting a LocalCluster of 2 worker processes ...")
        load_average = os.getloadavg()[0]
        with local_cluster(2) as cluster, distributed.Client(cluster) as client:
            _warm(client, items, tmp)
            p = _Pairs()
            cpu0 = client.run(_cpu_s)
            with _Load() as load:
                t_load = time.monotonic()
                for k in range(repeats):
                    _pair(k, items, tmp, client, serial_rows, p)
                workers_cpu = sum(client.run(_cpu_s).values()) - sum(cpu0.values())
                t_load = time.monotonic() - t_load
        # The start-up included: a run that starts, warms and closes its own cluster.
        t0 = time.perf_counter()
        cold = run(items, tmp / "store-cold", workers=2, progress=False)
        t_cold = time.perf_counter() - t0
        p.agree = p.agree and _stored_as_serial(cold, tmp / "store-cold", len(items),
                                                serial_rows)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    other = None if load.cores is None else max(0.0, load.cores - workers_cpu / t_load)
    return _rows(p, len(items), t_cold, cold.warm_s, load_average, other)


def _rows(p: _Pairs, n_items: int, t_cold: float, cold_warm_s: float, load_average: float,
          other: float | None) -> list[dict[str, Any]]:
    """The campaign row and the store row, from the pairs' medians; says the first."""
    serial, cluster_t = statistics.median(p.t_serial), statistics.median(p.t_cluster)
    ratio = serial / cluster_t
    per_item = serial / n_items
    store_item = statistics.median(p.store_s) / n_items
    fraction = store_item / per_item
    summary = p.summary
    controls = {"control_ratio": statistics.median(p.c_serial) / statistics.median(p.c_cluster),
                "fp_control_ratio": statistics.median(p.f_serial) / statistics.median(p.f_cluster)}
    own = scaling.CONTROLS["archive_32_frames"]
    verdict = scaling.judge(ratio, ARCHIVE_TARGET, controls[own.key], fraction=own.fraction)
    rows = [
        {"name": "archive_32_frames", "kind": "batch",
         "description": f"dtalign.archive.run: {ARCHIVE_FRAMES} frames {ARCHIVE_SIZE}^2 x 3 "
                        "polylines, serial loop vs LocalCluster of 2 processes, "
                        f"{summary.items_per_task} frames per task (run's default; cluster "
                        f"started and warmed beforehand; with start-up {serial / t_cold:.2f}x; "
                        f"a frame per task {serial / statistics.median(p.t_single):.2f}x)",
         "reference_s": serial, "dtalign_s": cluster_t, "ratio": ratio,
         "ratio_of_minima": min(p.t_serial) / min(p.t_cluster), "target": ARCHIVE_TARGET,
         "passed": p.agree and verdict.passed, "results_agree": p.agree,
         "rule": verdict.rule, "required_ratio": verdict.required, "parallel_share": 1.0,
         "judged_by": own.key, **controls,
         "control_times_s": [p.c_serial, p.c_cluster],
         "fp_control_times_s": [p.f_serial, p.f_cluster],
         "reference_times_s": p.t_serial, "dtalign_times_s": p.t_cluster,
         "pair_ratios": [a / b for a, b in zip(p.t_serial, p.t_cluster, strict=True)],
         # What two otherwise idle cores would allow: the CPU both sides used
         # (the sharing of the cores between sessions does not change it much).
         "cpu_ceiling_ratio": 2 * statistics.median(p.cpu_serial) / statistics.median(p.cpu_cluster),
         "cpu_serial_s": p.cpu_serial, "cpu_cluster_s": p.cpu_cluster,
         "items_per_task": summary.items_per_task,
         "single_s": statistics.median(p.t_single),
         "single_ratio": serial / statistics.median(p.t_single), "single_times_s": p.t_single,
         "single_cpu_ceiling_ratio": 2 * statistics.median(p.cpu_serial)
         / statistics.median(p.cpu_single), "cpu_single_s": p.cpu_single,
         "cold_s": t_cold, "cold_ratio": serial / t_cold, "cold_warm_s": cold_warm_s,
         "load_average": load_average, "other_load_cores": other},
        {"name": "archive_store_per_item", "kind": "archive",
         "description": "client time writing the store per item, vs one item's serial time",
         "reference": f"item {per_item * 1e3:.2f} ms", "dtalign":
         f"store {store_item * 1e3:.3f} ms ({fraction * 100:.2f} %)",
         "target": f"<= {STORE_OVERHEAD_TARGET * 100:g} %",
         "passed": fraction <= STORE_OVERHEAD_TARGET, "store_s_per_item": store_item,
         "item_s": per_item, "store_fraction": fraction, "store_times_s": p.store_s},
    ]
    _progress(f"archive_32_frames: {ratio:.2f}x in tasks of {summary.items_per_task} "
              f"({rows[0]['single_ratio']:.2f}x in tasks of one frame; control "
              f"{rows[0]['control_ratio']:.2f}x, FP "
              f"{rows[0]['fp_control_ratio']:.2f}x, with "
              f"start-up {serial / t_cold:.2f}x, CPU ceiling {rows[0]['cpu_ceiling_ratio']:.2f}x); "
              f"store {fraction * 100:.2f} % of an item")
    return rows
