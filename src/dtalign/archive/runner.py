"""Running a campaign on Dask: :func:`run`.

The client submits one task per missing item (:func:`~dtalign.archive.tasks.fit_item`,
which reads, prepares and fits the image on the worker), takes the results
as they complete, and appends them to the store in batches of whole items.
Dask retries the tasks of a worker that dies (up to
``distributed.scheduler.allowed-failures`` times, 3 by default, before it
reports ``KilledWorker``, which is recorded as the item's failure); an
item's own error (a missing or corrupt file, a bad option) comes back as a
failure row. Ctrl-C writes what has arrived, cancels the rest and
re-raises :class:`KeyboardInterrupt`; running again resumes.

Dask (``distributed``) is imported only when :func:`run` is called.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import threading
import time
import uuid
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .._progress import tqdm_bar
from ..api import checks as check
from .manifest import Item, read_manifest
from .store import Store
from .tasks import failure_row, fit_item, fit_items

__all__ = ["RunSummary", "auto_items_per_task", "run"]

PathLike = str | os.PathLike[str]

#: Items per store part: a part every 32 items keeps the store's cost far
#: below a fit's and loses at most 32 items of work on a hard crash.
DEFAULT_FLUSH_ITEMS = 32

#: ...or every 10 s, whichever comes first, so a slow campaign still lands
#: its results on disk often.
DEFAULT_FLUSH_SECONDS = 10.0

#: Tasks submitted ahead of the results: enough to keep any cluster busy,
#: few enough that the client and scheduler hold no campaign-sized state.
DEFAULT_MAX_PENDING = 1000

#: Items per task unless the caller says: Dask's CPU per task (a little less
#: of it in the client's process, where a LocalCluster's scheduler runs, than
#: on the worker) is about a sixth of a 1024^2 frame's fit with three
#: polylines; four frames a task bring that from 16 % to 4 %, and let one
#: scheduler (single-threaded) feed four times the workers
#: (docs/campaign.rst, "Throughput", has the measurements).
MAX_AUTO_ITEMS_PER_TASK = 4

#: ...but never fewer than this many tasks per worker thread, so that a
#: short campaign still spreads over every worker and ends evenly.
MIN_TASKS_PER_THREAD = 4


def auto_items_per_task(items: int, threads: int) -> int:
    """Items per task when :func:`run` is given none.

    ``MAX_AUTO_ITEMS_PER_TASK`` (4), or fewer when the campaign is too short
    to give every worker thread ``MIN_TASKS_PER_THREAD`` (4) tasks of that
    size; a cluster with no workers yet counts as one thread.

    Parameters
    ----------
    items : int
        Items to run.
    threads : int
        Worker threads of the cluster at the start.

    Returns
    -------
    int

    >>> auto_items_per_task(32, 2), auto_items_per_task(10, 2), auto_items_per_task(5, 8)
    (4, 1, 1)
    """
    per_task = items // (MIN_TASKS_PER_THREAD * max(threads, 1))
    return max(1, min(MAX_AUTO_ITEMS_PER_TASK, per_task))

#: Dask settings (documented ``distributed`` configuration) of the LocalCluster
#: :func:`run` starts, given to its scheduler, nannies and workers only, never
#: set globally (docs/campaign.rst, "Throughput", has the measurements):
#:
#: * no sampling profiler: it walks the task's stack every 10 ms for a
#:   dashboard this cluster does not serve;
#: * the event-loop health check every second, not every 20 ms, in every
#:   process; these two are about a third of Dask's own CPU on tasks of a frame;
#: * workers keep the memory a task frees for the next one (glibc's settings,
#:   through the pre-spawn environment; a user's variables of these names win).
#:   Dask's MALLOC_TRIM_THRESHOLD_=65536 returns it at once and turns off
#:   glibc's adaptive mmap threshold, so every image-sized array of every frame
#:   is fresh memory the kernel must zero, about a fifth of a frame's CPU.
#:   32 MiB is glibc's largest mmap threshold (a 2048^2 float64 frame); a
#:   worker holds on to the memory of its largest task.
#:
#: BLAS and OpenMP already run single-threaded in Dask's workers (the same
#: pre-spawn environment sets OMP/MKL/OPENBLAS_NUM_THREADS=1), and no kernel
#: starts Numba threads.
LOCAL_CLUSTER_CONFIG: dict[str, Any] = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.nanny.pre-spawn-environ.MALLOC_MMAP_THRESHOLD_": 32 * 2**20,
    "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": 2**30,
}


@dataclass
class RunSummary:
    """What a :func:`run` did.

    Attributes
    ----------
    store : str
        The store's folder.
    items : int
        Items in the manifest.
    skipped_done, skipped_failed : int
        Items already done (skipped), and already failed (skipped without
        ``retry_failed``).
    submitted : int
        Items run this time.
    done, failed : int
        Of those, the items stored with results, and with a failure.
    rows : int
        Result rows written (one per polyline).
    flagged_rows : int
        Of those, the fits whose ``status`` is not ``"ok"`` (suspect,
        ambiguous or failed: the ``status`` and ``reasons`` columns say
        why), printed as "flagged"; 0 with a
        ``dtalign`` whose fits carry no status.
    interrupted : bool
        True when Ctrl-C stopped the run (the store holds what had finished).
    elapsed_s, warm_s, store_s : float
        Wall time of the run, of the workers' warm-up, and spent writing
        the store.
    store_parts : int
        Part files written.
    workers : int
        Workers at the start.
    items_per_task : int
        Items per task (given, or chosen by
        :func:`~dtalign.archive.runner.auto_items_per_task`).
    run_id : str
        Recorded in every row written.
    """

    store: str
    items: int
    skipped_done: int = 0
    skipped_failed: int = 0
    submitted: int = 0
    done: int = 0
    failed: int = 0
    rows: int = 0
    flagged_rows: int = 0
    interrupted: bool = False
    elapsed_s: float = 0.0
    warm_s: float = 0.0
    store_s: float = 0.0
    store_parts: int = 0
    workers: int = 0
    items_per_task: int = 0
    run_id: str = field(default_factory=lambda: uuid.uuid4().hex[:12])

    def __str__(self) -> str:
        text = (
            # "in error" for items that raised, "flagged" for fits whose status
            # is not ok: one word for each, never "failed" for both
            f"{self.done} item(s) done, {self.failed} item(s) in error ({self.rows} result rows), "
            f"{self.skipped_done} already done"
        )
        if self.flagged_rows:
            text += (f", {self.flagged_rows} fit(s) flagged (status not 'ok': see the status "
                     "and reasons columns)")
        if self.skipped_failed:
            text += f", {self.skipped_failed} item(s) in error earlier (--retry-failed to redo)"
        text += (f"; {self.elapsed_s:.1f} s on {self.workers} worker(s), "
                 f"{self.items_per_task} item(s) a task (warm-up {self.warm_s:.1f} s); "
                 f"store {self.store}")
        return text + (" (interrupted)" if self.interrupted else "")


def _dask() -> Any:
    try:
        import distributed
    except ImportError:
        raise ImportError(
            "running a campaign needs Dask: pip install 'dtalign[dask]'"
        ) from None
    return distributed


@contextlib.contextmanager
def _client(client: Any, scheduler: str | None, workers: int | None) -> Iterator[Any]:
    """The client to use: the caller's, one for ``scheduler``, or a new LocalCluster."""
    if client is not None:
        if scheduler is not None or workers is not None:
            raise ValueError("give client, or scheduler / workers, not both")
        yield client
        return
    distributed = _dask()
    if scheduler is not None:
        if workers is not None:
            raise ValueError("workers applies to a local cluster, not to an existing scheduler")
        with distributed.Client(scheduler) as c:
            yield c
        return
    n = check.int_at_least((os.cpu_count() or 1) if workers is None else workers, "workers")
    with _nanny_environ_restored(), local_cluster(n) as cluster, distributed.Client(cluster) as c:
        c._dtalign_owned = True  # _execute: closing it stops the tasks
        yield c


def local_cluster(n: int) -> Any:
    """The LocalCluster :func:`run` starts: ``n`` worker processes, one thread each.

    Public so that a caller who wants its own :class:`distributed.Client`
    (several campaigns on one cluster, the benchmark) gets the same cluster,
    settings included; pass ``run(..., client=Client(local_cluster(n)))``.

    Processes, one thread each: a worker per core, no GIL shared between
    fits. A terminal's Ctrl-C reaches the workers too; the client's process
    handles it (stores what has arrived, closes the cluster), so the workers
    ignore it: the ones started now inherit SIG_IGN, a replacement started
    later sets it in the preload (:func:`dtalign.archive._plugin.dask_setup`).
    No dashboard; the scheduler's HTTP routes on a free port, not on 8787.
    :data:`LOCAL_CLUSTER_CONFIG` applies to the scheduler and the nannies
    (set while they start) and to every worker process, a replacement for a
    killed one included: it is the nannies' ``config``, which they give each
    process they start (a nanny's copy of the global configuration is
    shallow, so what is set only while it starts is gone by the restart).

    The environment variables the nannies set in this process to start
    their workers are put back once the workers run
    (:func:`_nanny_environ_restored`). A nanny that starts a replacement
    later sets them again, for the life of the cluster; :func:`run` puts
    them back when the cluster it started closes.
    """
    import dask

    distributed = _dask()
    with _sigint_ignored(), dask.config.set(LOCAL_CLUSTER_CONFIG), _nanny_environ_restored():
        return distributed.LocalCluster(
            n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
            scheduler_kwargs={"dashboard_address": ":0"}, preload=["dtalign.archive._plugin"],
            config=dict(LOCAL_CLUSTER_CONFIG),
        )


#: Set by a nanny in its own process's environment besides the pre-spawn
#: variables: the workers' hash seed (one for all, so that they hash alike)
#: and the parent's pid (``distributed.proctitle``).
_NANNY_SET_VARIABLES = ("PYTHONHASHSEED", "__DASK_PARENT_PID")


@contextlib.contextmanager
def _nanny_environ_restored() -> Iterator[None]:
    """Put back, on leaving, the environment variables Dask's nannies set here.

    A nanny writes its workers' pre-spawn environment
    (``distributed.nanny.pre-spawn-environ``: OMP/MKL/OPENBLAS_NUM_THREADS=1
    and glibc's malloc settings), PYTHONHASHSEED and ``__DASK_PARENT_PID``
    into ``os.environ`` before it starts a worker, and leaves them there; a
    LocalCluster's nannies run in the caller's process. Left behind, those
    values would reach every subprocess the caller starts later
    (single-threaded BLAS, a fixed hash seed), and the next cluster's
    nannies would take them for the user's own settings. Only these
    variables are put back, to what they were.
    """
    import dask

    prefix = "distributed.nanny.pre-spawn-environ."
    names = {*dask.config.get("distributed.nanny.pre-spawn-environ", default={}),
             *(k[len(prefix):] for k in LOCAL_CLUSTER_CONFIG if k.startswith(prefix)),
             *_NANNY_SET_VARIABLES}
    before = {name: os.environ.get(name) for name in names}
    try:
        yield
    finally:
        for name, value in before.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def _quiet_logs() -> None:
    """Only errors that matter from Dask's loggers: a cluster closed on purpose
    (after Ctrl-C) logs its cancelled tasks and closed comms at length."""
    logging.getLogger("distributed").setLevel(logging.CRITICAL + 1)


@contextlib.contextmanager
def _sigint_ignored() -> Iterator[None]:
    """Ignore SIGINT in the block (main thread only: elsewhere there is no handler to set)."""
    if (threading.current_thread() is not threading.main_thread()
            or signal.getsignal(signal.SIGINT) is None):  # a handler set outside Python: keep it
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


@contextlib.contextmanager
def _defer_sigint() -> Iterator[None]:
    """Hold a Ctrl-C back until the block is over (a store write and its bookkeeping).

    Without it an interrupt between a part's rename and the bookkeeping
    after it would make the clean-up write those rows a second time.
    Signal handlers belong to the main thread; elsewhere there is no
    KeyboardInterrupt to defer.
    """
    if (threading.current_thread() is not threading.main_thread()
            or signal.getsignal(signal.SIGINT) is None):  # a handler set outside Python: keep it
        yield
        return
    pending: list[Any] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: pending.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        if pending:
            raise KeyboardInterrupt


class _Writer:
    """Collects finished tasks and appends their items to the store in parts.

    A finished task's rows stay on its worker until the part they belong to
    is written; the part's rows are then fetched in one ``client.gather``.
    A fetch costs about a twentieth of a frame's fit in CPU, in the client's
    process and in the worker's, whatever it carries, so one per part rather than per task
    (docs/campaign.rst, "Throughput"). A result whose worker dies before it
    is fetched is computed again by Dask (the client still holds its future).
    """

    def __init__(self, client: Any, store: Store, summary: RunSummary, flush_items: int,
                 flush_seconds: float) -> None:
        self.client, self.store, self.summary = client, store, summary
        self.flush_items, self.flush_seconds = flush_items, flush_seconds
        self.finished: list[tuple[Any, list[Item]]] = []  # finished tasks, rows on the workers
        self.results: list[dict[str, Any]] = []
        self.failures: list[dict[str, Any]] = []
        self.taken = 0  # items of the rows above
        self.last = time.monotonic()
        self.written: set[str] = set()

    def add_finished(self, fut: Any, chunk: list[Item]) -> None:
        """A task that returned: its rows are fetched with the part's."""
        self.finished.append((fut, chunk))
        self._maybe_flush()

    def add_failed(self, chunk: list[Item], exc: BaseException) -> None:
        """A task that never returned (``KilledWorker`` and the like)."""
        self._take_failed(chunk, exc)
        self._maybe_flush()

    def _take_failed(self, chunk: list[Item], exc: BaseException) -> None:
        for item in chunk:
            self._take(item.id, [], failure_row(item, exc, self.summary.run_id))

    def _take(self, item_id: str, results: list[dict[str, Any]],
              failure: dict[str, Any] | None) -> None:
        if item_id in self.written:  # a task never lands twice
            return
        self.written.add(item_id)
        self.results.extend(results)
        if failure is not None:
            self.failures.append(failure)
        self.taken += 1

    def _maybe_flush(self) -> None:
        items = self.taken + sum(len(chunk) for _, chunk in self.finished)
        if items >= self.flush_items or time.monotonic() - self.last >= self.flush_seconds:
            self.flush()

    def fetch(self) -> None:
        """Bring the finished tasks' rows to the client, in one round trip.

        Interruptible (a Ctrl-C here leaves ``finished`` as it was); gathered
        as a dict so that a result lost for good (its recomputation failed)
        comes back as None in its place, and is recorded as the task's failure.
        """
        if not self.finished:
            return
        payloads = self.client.gather(dict(enumerate(f for f, _ in self.finished)),
                                      errors="skip")
        with _defer_sigint():  # the rows taken, and only those, leave ``finished``
            self._take_payloads(payloads)

    def _take_payloads(self, payloads: dict[int, Any]) -> None:
        finished, self.finished = self.finished, []
        for k, (fut, chunk) in enumerate(finished):
            payload = payloads.get(k)
            if payload is not None:
                for item, p in zip(chunk, [payload] if len(chunk) == 1 else payload,
                                   strict=True):
                    self._take(item.id, p["results"], p["failure"])
            elif fut.status == "error":
                self._take_failed(chunk, fut.exception())
            # else cancelled: nothing is stored; the items run again next time
            fut.release()

    def abandon(self) -> None:
        """Forget the finished tasks not fetched: they run again next time."""
        self.finished = []

    @property
    def failed_so_far(self) -> int:
        return self.summary.failed + len(self.failures)

    def flush(self) -> None:
        self.fetch()
        if not self.taken:
            return
        with _defer_sigint():
            t0 = time.perf_counter()
            self.store.append(self.results, self.failures)
            s = self.summary
            s.store_s += time.perf_counter() - t0
            s.store_parts += bool(self.results) + bool(self.failures)
            s.rows += len(self.results)
            s.flagged_rows += sum(r.get("status") not in (None, "ok") for r in self.results)
            s.failed += len(self.failures)
            s.done += self.taken - len(self.failures)
            self.results, self.failures = [], []
            self.taken = 0
            self.last = time.monotonic()


def _progress(total: int, enabled: bool) -> Any:
    bar = tqdm_bar(total, unit="image", desc="campaign", dynamic_ncols=True) if enabled else None
    if bar is not None:
        return bar

    class _Silent:
        def update(self, n: int = 1) -> None:
            pass

        def set_postfix_str(self, s: str) -> None:
            pass

        def close(self) -> None:
            pass

    return _Silent()


def _plan(items: Sequence[Item], store: Store, retry_failed: bool, summary: RunSummary
          ) -> list[Item]:
    done = store.fingerprints()
    failed = store.failed_ids()
    changed = [i for i in items if i.id in done and done[i.id] != i.fingerprint]
    if changed:
        raise ValueError(
            f"store {store.path} holds results for item {changed[0].id!r} (and "
            f"{len(changed) - 1} more) from a different manifest entry: its files, noise, "
            "window or options changed; write to a new store"
        )
    todo = []
    for item in items:
        if item.id in done:
            summary.skipped_done += 1
        elif item.id in failed and not retry_failed:
            summary.skipped_failed += 1
        else:
            todo.append(item)
    return todo


def run(
    manifest: PathLike | Sequence[Item],
    store: PathLike | Store,
    client: Any = None,
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    window: Any = None,
    options: Mapping[str, Any] | None = None,
    retry_failed: bool = False,
    progress: bool = True,
    warm: bool = True,
    flush_items: int = DEFAULT_FLUSH_ITEMS,
    flush_seconds: float = DEFAULT_FLUSH_SECONDS,
    max_pending: int = DEFAULT_MAX_PENDING,
    items_per_task: int | None = None,
) -> RunSummary:
    """Fit every missing item of a campaign on Dask and store the results.

    Parameters
    ----------
    manifest : str, path-like or sequence of Item
        A manifest file (:mod:`dtalign.archive.manifest`) or its items.
    store : str, path-like or Store
        The results store's folder (created when missing). Items it holds
        already are skipped.
    client : distributed.Client, optional
        Run on this client's cluster (left open).
    scheduler : str, optional
        Address of an existing scheduler (``tcp://host:8786``) to connect
        to, when no ``client`` is given.
    workers : int, optional
        Worker processes of the LocalCluster started when neither
        ``client`` nor ``scheduler`` is given (one thread each); the CPU
        count by default.
    window, options
        Defaults for items that give none: the coarse-search margin (30)
        and fit options (:func:`dtalign.pipeline.fit_polyline_products`
        keywords). Only used when ``manifest`` is a file.
    retry_failed : bool, optional
        Also run the items the store holds as failed.
    progress : bool, optional
        A tqdm progress bar on standard error (rate and ETA).
    warm : bool, optional
        Load (or compile) the kernels once on every worker before the
        tasks run, and on every worker that joins later.
    flush_items, flush_seconds : optional
        Write a store part every this many items or seconds, whichever
        comes first (32 items, 10 s); at the end, on an error and on Ctrl-C.
    max_pending : int, optional
        Tasks in flight at once (1000).
    items_per_task : int, optional
        Items one task reads and fits, one after the other. By default
        (None) :func:`~dtalign.archive.runner.auto_items_per_task`: 4,
        fewer in a campaign too short for 4 tasks per worker thread. Dask
        costs a few milliseconds of CPU per task, split between the worker
        and the scheduler, so frames that take tens of milliseconds run
        faster in tasks of a few; give 1 for frames of a second or more. A
        worker that dies costs the items of the tasks it held; a Ctrl-C,
        those of the tasks still running.

    Returns
    -------
    RunSummary

    Raises
    ------
    KeyboardInterrupt
        On Ctrl-C, after the results that had arrived are stored and the
        rest cancelled.
    ValueError
        On a malformed manifest, conflicting arguments, or a store whose
        done items were made from different manifest entries.
    ImportError
        Without Dask or pyarrow (``pip install 'dtalign[dask]'``).
    StoreBusyError
        If another run is writing to the store.
    """
    t_start = time.perf_counter()
    if isinstance(manifest, (str, os.PathLike)):
        items = read_manifest(manifest, window=window, options=options)
    else:
        items = list(manifest)
        if not all(isinstance(i, Item) for i in items):
            raise TypeError("manifest must be a path or a sequence of dtalign.archive.Item")
        if len({i.id for i in items}) != len(items):
            raise ValueError("manifest items must have unique ids")
    for name, value in (("flush_items", flush_items), ("max_pending", max_pending),
                        ("items_per_task", 1 if items_per_task is None else items_per_task)):
        check.int_at_least(value, name)
    st = store if isinstance(store, Store) else Store(store)
    summary = RunSummary(store=str(Path(st.path)), items=len(items))
    with st.lock():
        todo = _plan(items, st, retry_failed, summary)
        summary.submitted = len(todo)
        if todo:
            with _client(client, scheduler, workers) as c:
                _execute(c, todo, st, summary, progress=progress, warm=warm,
                         flush_items=flush_items, flush_seconds=float(flush_seconds),
                         max_pending=max_pending, items_per_task=items_per_task)
    summary.elapsed_s = time.perf_counter() - t_start
    return summary


def _execute(client: Any, todo: list[Item], store: Store, summary: RunSummary, *,
             progress: bool, warm: bool, flush_items: int, flush_seconds: float,
             max_pending: int, items_per_task: int | None) -> None:
    distributed = _dask()
    threads = client.nthreads()
    summary.workers = len(threads)
    if items_per_task is None:
        items_per_task = auto_items_per_task(len(todo), sum(threads.values()))
    summary.items_per_task = items_per_task
    writer = _Writer(client, store, summary, flush_items, flush_seconds)
    bar = _progress(len(todo), progress)
    # A task's key names the index of its first item.
    queue = iter([(k, todo[k:k + items_per_task]) for k in range(0, len(todo), items_per_task)])
    futures: dict[Any, list[Item]] = {}
    # Completions are noticed on the client's event loop; the rows stay on the
    # workers until the writer fetches a part's worth together.
    completed = distributed.as_completed(raise_errors=False)

    def submit(n: int) -> None:
        for _ in range(n):
            nxt = next(queue, None)
            if nxt is None:
                return
            index, chunk = nxt
            key = f"dtalign-fit-{summary.run_id}-{index}"
            fut = (client.submit(fit_item, chunk[0], summary.run_id, key=key) if len(chunk) == 1
                   else client.submit(fit_items, chunk, summary.run_id, key=key))
            futures[fut] = chunk
            completed.add(fut)

    try:
        if warm:  # inside the try: a Ctrl-C during a long first compile is handled too
            _warm(client, summary)
        submit(max_pending)
        for fut in completed:
            _collect(fut, futures.pop(fut), writer, bar)
            submit(1)
        writer.flush()
    except BaseException as exc:
        _keep_finished(client, writer, summary, exc)
        # Free the cluster of this run's tasks (on our own, this also leaves the
        # scheduler nothing to report to a client that is closing).
        client.cancel(list(futures))
        futures.clear()
        raise
    finally:
        bar.close()


def _warm(client: Any, summary: RunSummary) -> None:
    """Load (or compile) the kernels on every worker, now and on those that join later."""
    from ._plugin import WarmNumba

    t0 = time.perf_counter()
    client.register_plugin(WarmNumba())
    summary.warm_s = time.perf_counter() - t0


def _collect(fut: Any, chunk: list[Item], writer: _Writer, bar: Any) -> None:
    """A completed task's rows (or its failure) to the writer, and the bar moved on."""
    if fut.status == "finished":
        writer.add_finished(fut, chunk)
    elif fut.status == "error":  # the task never returned: KilledWorker and the like
        writer.add_failed(chunk, fut.exception())
        fut.release()
    else:  # "cancelled": nothing is stored; the items run again next time
        fut.release()
    bar.update(len(chunk))
    if writer.failed_so_far:
        bar.set_postfix_str(f"{writer.failed_so_far} failed")


def _keep_finished(client: Any, writer: _Writer, summary: RunSummary,
                   exc: BaseException) -> None:
    """On an error or Ctrl-C: store what finished, and quiet our own cluster's closing."""
    summary.interrupted = isinstance(exc, KeyboardInterrupt)
    # Everything that finished is kept, whatever stopped the run: the rows
    # still on the workers are fetched, unless that fails too (a second
    # Ctrl-C, a lost scheduler): those items then run again next time.
    try:
        writer.fetch()
    except BaseException:
        writer.abandon()
    writer.flush()
    if getattr(client, "_dtalign_owned", False):  # our LocalCluster: it closes next
        _quiet_logs()
        with contextlib.suppress(Exception):
            client.run(_quiet_logs)
