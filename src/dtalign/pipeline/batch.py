"""Batch fitting on several cores: many polylines per image, many images.

The compiled kernels release the GIL (``nogil=True``), so threads fit truly
in parallel. :func:`fit_many` checks its polylines (the first one and the
shared options as :func:`~dtalign.pipeline.fit_polyline_products` does,
the others in bulk), then fits them in chunks, one call of the compiled
loop (``dtalign._kernels.pipeline``) per chunk of at most a few polylines;
each fit's examination of rival basins and its conclusion (the edge
profile's refinement, the evidence of its covariance) run one fit a task on
the same threads. :func:`fit_images` fits one image per task, on threads, a process pool or an
executor of the caller's; :func:`map_ordered` is ``[fn(x) for x in items]``
on threads. Results come in input order, equal to the serial calls'.
Nothing global is configured: no Numba threading layer, no thread count.

Threads and interrupts
----------------------
Each call makes its own :class:`~concurrent.futures.ThreadPoolExecutor`
and shuts it down before it returns. One more thread of the call's, its
driver, submits the items to the pool and collects them as they complete;
the calling thread only waits on the driver's reports, runs the progress
callback and ``on_image``, and raises what the driver hands it. So an
exception a signal handler raises (KeyboardInterrupt, a ``SIGALRM``
timeout's) arrives in that wait, never inside an item, where it would pass
for the item's error or break Numba's boxing of a kernel's result. The call
then sets its stop event, which every item looks at before it starts,
waits for the workers to finish what they hold (a chunk is a few
milliseconds) and propagates.

The wait is on a ``queue.SimpleQueue``, whose ``get`` is C code.
The executor's own waits and ``submit`` go through
``threading.Condition`` and ``Semaphore``, which are Python code in
CPython: an exception raised inside them can leave a lock held or release
one that is not. Beside a busy core, the script of
``tests/test_batch_interrupts.py`` (256 interrupts a run) failed in 2 of
8 runs when the calling thread itself submitted and waited on
``as_completed``: a batch that never returned (the pool's workers blocked
on the semaphore's lock the interrupt had left held) and a
``RuntimeError: release unlocked lock`` in the place of the interrupt. It
passed in each of the 8 runs alternated with those on this design, and in
14 more.

Errors
------
With ``errors="raise"`` (the default) a batch raises the error of the first
failing item in input order, as the serial loop would, after fitting the
items before it; items are taken in order and none after a failed one
starts once the failure is seen. The exception has the type of the item's
own error, a message naming the item (``polylines[31]: ...``,
``images[4] (frame.png): ...``), the item's position as its ``index``
attribute and the item's own error as its ``__cause__``. With
``errors="collect"`` every item is fitted and a failed item's place holds
its exception (as ``asyncio.gather(..., return_exceptions=True)`` does)::

    out = fit_many(products, polylines, search_window_vu=(30, 30), errors="collect")
    failed = {e.index: e for e in out if isinstance(e, Exception)}

Collected are the errors of an item's data and fit and, in
:func:`fit_images`, any ordinary exception of an image's task (a file that
cannot be loaded, an image that cannot be prepared); an item of neither
accepted form, a bad option or a bad ``workers`` raises at once.

Progress
--------
``progress=callback`` calls ``callback(done, total)`` once per completed
item (a polyline of :func:`fit_many`, an image of :func:`fit_images`),
``done`` = 1, 2, ..., ``total``, from the calling thread as it sees the
items complete (a polyline with an edge profile once it is refined): the
callback needs no lock. A failed item collected counts as completed; with
``errors="raise"`` the calls stop at the first failure.
If the callback raises, the batch stops as on an interrupt and its
exception propagates unchanged (it is not collected). ``progress=True``
shows a tqdm bar on standard error (tqdm comes with the ``cli`` extra); for
a bar of one's own pass its update as the callback::

    from tqdm.auto import tqdm

    with tqdm(total=len(polylines), unit="polyline") as bar:
        fits = fit_many(products, polylines, search_window_vu=(30, 30),
                        progress=lambda done, total: bar.update(done - bar.n))

Examples
--------
>>> from dtalign import scenes
>>> from dtalign.pipeline.batch import fit_many
>>> from dtalign.pipeline import prepare_image
>>> scene = scenes.navigation_scene()
>>> products = prepare_image(scene.image, scene.noise_sigma)
>>> fits = fit_many(products, scene.polylines, search_window_vu=(30, 30))
>>> [round(x, 1) for x in fits[0].offset_vu]
[7.3, -4.6]
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import signal
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import (
    CancelledError,
    Executor,
    Future,
    ProcessPoolExecutor,
    ThreadPoolExecutor,
)
from contextlib import contextmanager, nullcontext
from queue import SimpleQueue
from typing import Any, Literal, TypeVar, overload

import numpy as np

from .._progress import Progress, tqdm_progress
from ..api.checks import collect_errors as _check_errors
from ..api.checks import progress_callback as _check_progress
from ..api.checks import workers as _check_workers
from ..api.options import DEFAULT_SEARCH_WINDOW_VU, FitOptions, resolve
from ..api.results import ImageDerivativesConfig
from . import jobs as _jobs
from .fit import PolylineFit, conclude, finish, needs_settling, wrap
from .products import ImageProducts, prepare_image
from .status import log_fit, log_fits, logger

__all__ = ["DEFAULT_WORKERS", "fit_images", "fit_many", "map_ordered", "results_equal"]

_T = TypeVar("_T")
_R = TypeVar("_R")
#: ``hand(i, result, error)``: an item of :meth:`_Runner.each` handed on in input order.
_Hand = Callable[[int, Any, "Exception | None"], Any]


def _usable_cpus() -> int:
    """The CPUs this process may run on (its affinity mask where the OS has one)."""
    try:
        return len(os.sched_getaffinity(0)) or 1
    except (AttributeError, OSError):  # no affinity mask on this OS (macOS, Windows)
        return os.cpu_count() or 1


#: Default workers: the CPUs this process may use, read at import (a
#: container or ``taskset`` limits them below ``os.cpu_count()``).
DEFAULT_WORKERS = _usable_cpus()

_EXECUTORS = ("thread", "process")


@contextmanager
def _reporter(progress: Callable[[int, int], Any] | bool | None, total: int,
              unit: str) -> Iterator[Progress | None]:
    """The call's :class:`~dtalign._progress.Progress` (None without ``progress``);
    with ``progress=True``, one that drives a tqdm bar, closed on the way out."""
    if progress is None or progress is False:
        yield None
    elif progress is True:
        with tqdm_progress(total, unit=unit) as report:
            if report is None:
                raise ModuleNotFoundError(
                    "progress=True needs tqdm (pip install tqdm); or pass a callable "
                    "progress(done, total)"
                )
            yield report
    else:
        yield Progress(progress, total)


def _named(exc: Exception, label: str, index: int) -> Exception:
    """``exc`` as the error of item ``index``: the same type, the message
    ``f"{label}: {exc}"``, an ``index`` attribute and ``exc`` as its cause.

    A type that cannot be built from one message (or formats it itself,
    like ``KeyError``) keeps its own message and gets ``index`` and a note.
    """
    message = f"{label}: {exc}"
    try:
        named = type(exc)(message)
        same = str(named) == message
    except Exception:  # a constructor that wants other arguments
        same = False
    if same:
        named.__cause__ = exc
    else:
        named = exc
        if hasattr(named, "add_note"):  # Python >= 3.11
            named.add_note(f"in {label}")
    named.index = index  # type: ignore[attr-defined]
    return named


#: How long :func:`_once_started` waits for a thread whose start an exception
#: interrupted: a thread starts within milliseconds.
_THREAD_START_WAIT_S = 5.0


def _once_started(finish: Callable[[], Any], thread: threading.Thread | None = None) -> None:
    """``finish()`` (a thread's join, a pool's shutdown), tried again while a
    thread is still starting.

    An exception raised in ``Thread.start``'s wait for the new thread (a
    signal handler's, in the calling thread) leaves the thread starting
    behind it, and ``finish()`` raises "cannot join thread before it is
    started" until it has. Not tried again once ``thread`` is known to no
    one (it never started) or after :data:`_THREAD_START_WAIT_S`: the
    interrupt matters more than a stray thread or process.
    """
    deadline = time.monotonic() + _THREAD_START_WAIT_S
    while True:
        try:
            finish()
            return
        except RuntimeError:
            gone = thread is not None and thread not in threading.enumerate()
            if gone or time.monotonic() > deadline:
                return
            time.sleep(0.01)


def _ignore_sigint() -> None:
    """A pool worker's start: Ctrl-C is the parent's to act on.

    A terminal's Ctrl-C goes to the whole process group, workers included;
    each would die with a KeyboardInterrupt traceback on stderr (and break
    the pool) while the parent stops the batch anyway. Ignoring it, the
    workers finish the image they hold and the parent's interrupt
    propagates alone (:func:`_process_pool` shuts the pool down).
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)


@contextmanager
def _process_pool(workers: int) -> Iterator[ProcessPoolExecutor]:
    """A ``ProcessPoolExecutor`` shut down at the end, whose exceptions are the caller's.

    An exception raised while the pool starts its manager thread (at the
    first submit) leaves that thread starting behind it; the pool's
    ``shutdown(wait=True)`` then raises "cannot join thread before it is
    started" in the place of the exception. Here the shutdown is tried again
    until the thread has started (it then stops the worker processes), and
    the exception propagates.
    """
    pool = ProcessPoolExecutor(max_workers=workers, initializer=_ignore_sigint)
    try:
        yield pool
    except BaseException:
        _once_started(functools.partial(pool.shutdown, wait=True, cancel_futures=True))
        raise
    pool.shutdown(wait=True)


#: Chunks of the compiled loop per worker thread: enough that a thread on a
#: slower core simply takes fewer of them.
_CHUNKS_PER_WORKER = 4

#: Polylines per chunk at most: an interrupt or a raising progress callback
#: waits for the chunks running, and progress moves in steps of a chunk.
_MAX_CHUNK = 8


def _chunks(k: int, workers: int) -> list[int]:
    """Bounds of the chunks of ``k`` polylines: chunk ``c`` is ``bounds[c]:bounds[c + 1]``."""
    size = max(1, min(_MAX_CHUNK, -(-k // (workers * _CHUNKS_PER_WORKER))))
    return [*range(0, k, size), k]


def _put_done(done: SimpleQueue[Any], token: object, i: int, future: Future[Any]) -> None:
    """A future's done callback: item ``i`` of the call ``token`` has completed."""
    done.put((token, i))


class _Runner:
    """Where one call's work runs; the calling thread only hands it on, waits and reports.

    ``_Runner(workers)``: a thread pool of the call's own, shut down on the
    way out. ``_Runner(pool=...)``: an executor of the caller's or a process
    pool; what was not started is cancelled on the way out. With a pool, a
    thread of the call's, the driver, runs :meth:`call`'s functions,
    submits :meth:`each`'s items and collects them; the calling thread only
    hands it work and waits on its reports (see "Threads and interrupts"
    in the module docstring). ``_Runner(stop=...)``: no pool, the calling
    thread runs everything (an image's task inside a batch) and looks at the
    batch's ``stop`` before each item. Leaving with an exception sets
    :attr:`stop`.
    """

    def __init__(self, workers: int = 1, *, report: Progress | None = None,
                 pool: Executor | None = None, stop: threading.Event | None = None) -> None:
        self.workers, self.report = workers, report
        self.stop = threading.Event() if stop is None else stop
        self.own = pool is None and stop is None
        self.pool = (ThreadPoolExecutor(workers, thread_name_prefix="dtalign-batch")
                     if self.own else pool)
        self._driver: threading.Thread | None = None
        # queue.SimpleQueue is C code: put and get hold no lock a signal
        # handler's exception could leave behind
        self._tasks: SimpleQueue[Any] = SimpleQueue()  # to the driver; None: leave
        self._reports: SimpleQueue[tuple[str, Any]] = SimpleQueue()  # to the calling thread
        self._done: SimpleQueue[Any] = SimpleQueue()  # items completed; None: stop

    def __enter__(self) -> _Runner:
        if self.pool is not None:
            self._driver = threading.Thread(target=self._drive, name="dtalign-batch-driver")
            try:
                self._driver.start()
            except BaseException:  # a signal handler's, while the driver started
                self._leave()
                raise
        return self

    def __exit__(self, kind: Any, exc: BaseException | None, tb: Any) -> None:
        if exc is not None:
            self.stop.set()
            self._done.put(None)  # wakes the driver if it waits on items
        if self._driver is not None:
            self._leave()

    def _leave(self) -> None:
        """Let the driver finish its task and go (it shuts the call's own pool down)."""
        assert self._driver is not None
        self._tasks.put(None)
        _once_started(self._driver.join, self._driver)

    def _drive(self) -> None:
        """The driver thread: run each task handed to it, report how it ended."""
        while (task := self._tasks.get()) is not None:
            try:
                self._reports.put(("returned", task()))
            except BaseException as exc:  # the calling thread's to raise
                self._reports.put(("raised", exc))
        if self.own:
            assert self.pool is not None
            self.pool.shutdown(wait=True, cancel_futures=True)

    def _ask(self, task: Callable[[], _R], ordered: _Hand | None = None) -> _R:
        """``task()`` run by the driver, while the calling thread reports the
        progress and hands on the items the driver sends it."""
        self._tasks.put(task)
        while True:
            kind, value = self._reports.get()  # the wait an interrupt lands in
            if kind == "advance":
                self.advance(value)
            elif kind == "hand":
                assert ordered is not None
                ordered(*value)
            elif kind == "returned":
                return value  # type: ignore[no-any-return]
            else:
                raise value

    def call(self, fn: Callable[..., _R], *args: Any, **kwargs: Any) -> _R:
        """``fn(*args, **kwargs)`` in another thread while the calling thread waits."""
        if self.pool is None:
            return fn(*args, **kwargs)
        return self._ask(functools.partial(fn, *args, **kwargs))

    def advance(self, k: int) -> None:
        """Report ``k`` more items done (the calling thread)."""
        if self.report is not None:
            self.report.advance(k)

    def each(self, fn: Callable[[_T], _R], items: Sequence[_T], *, stop_early: bool,
             sizes: Sequence[int] | None = None, ordered: _Hand | None = None,
             ) -> tuple[list[_R | None], dict[int, Exception]]:
        """``fn(x)`` for each of ``items``, taken in input order: ``(results, errors)``.

        ``results[i]`` is what ``fn(items[i])`` returned (None if it raised
        or never ran), ``errors`` maps ``i`` to the ``Exception`` it raised.
        With ``stop_early`` no item after a failed one starts once the
        failure is seen; every item before it was taken already, so the
        first failure in input order is in ``errors``. Each item that
        returns (or fails, without ``stop_early``) is reported as
        ``sizes[i]`` items done (default 1), in the calling thread as it
        completes. ``ordered(i, result, error)`` is then called (calling
        thread) for each item in input order, as soon as it and the items
        before it have returned or failed; with ``stop_early``, for none
        after a failed one.
        """
        if self.pool is None:
            return self._each_here(fn, items, stop_early, sizes, ordered)
        return self._ask(functools.partial(self._each_on_pool, fn, items, stop_early, sizes,
                                           ordered is not None), ordered)

    def _each_on_pool(self, fn: Callable[[_T], _R], items: Sequence[_T], stop_early: bool,
                      sizes: Sequence[int] | None, hand: bool,
                      ) -> tuple[list[_R | None], dict[int, Exception]]:
        """:meth:`each` on the pool, run by the driver: it submits the items,
        takes them as they complete and sends the calling thread the
        progress and the items to hand on."""
        assert self.pool is not None
        n = len(items)
        results: list[_R | None] = [None] * n
        errors: dict[int, Exception] = {}
        first, lock = [n], threading.Lock()  # the first failed item
        settled, after = [False] * n, 0  # the items returned or failed; the next to hand on
        token = object()  # this call's completions (a cancelled earlier one's may linger)

        def guarded(i: int) -> Any:
            if self.stop.is_set() or i > first[0]:
                return _SKIPPED
            try:
                return fn(items[i])
            except Exception:
                if stop_early:
                    with lock:
                        first[0] = min(first[0], i)
                raise

        # On a pool of the caller's (perhaps another process) ``fn`` runs as
        # it is; what must not start is cancelled.
        futures = self._submit_each(guarded if self.own else fn,
                                    range(n) if self.own else items, token)
        try:
            for _ in futures:  # each submitted item completes once (none after a stop)
                while (got := self._done.get()) is not None and got[0] is not token:
                    pass  # an earlier call's cancelled item
                if got is None:  # the calling thread has left with an exception
                    raise CancelledError("the batch was stopped")
                future = futures[i := got[1]]
                if future.cancelled():
                    if stop_early and errors and i > min(errors):
                        continue  # cancelled here, after a failure
                    error: BaseException | None = CancelledError()  # by the executor's owner
                else:
                    error = future.exception()
                if error is None:
                    result = future.result()
                    if result is _SKIPPED:
                        continue
                    results[i] = result
                elif isinstance(error, Exception):  # the item's error
                    errors[i] = error
                    if stop_early:
                        for later in futures[i + 1 :]:
                            later.cancel()
                else:
                    raise error
                if not (stop_early and errors):
                    self._reports.put(("advance", 1 if sizes is None else sizes[i]))
                settled[i] = True
                while (hand and after < n and settled[after]
                       and not (stop_early and errors and after > min(errors))):
                    self._reports.put(("hand", (after, results[after], errors.get(after))))
                    after += 1
        finally:
            for future in futures:  # a no-op for those done
                future.cancel()
        return results, errors

    def _submit_each(self, fn: Callable[[Any], Any], args: Iterable[Any],
                     token: object) -> list[Future[Any]]:
        """``fn(x)`` submitted for each of ``args`` (the driver), each telling
        :attr:`_done` when it completes; none once the call is stopped."""
        assert self.pool is not None
        futures: list[Future[Any]] = []
        for i, x in enumerate(args):
            if self.stop.is_set():
                break
            future = self.pool.submit(fn, x)
            future.add_done_callback(functools.partial(_put_done, self._done, token, i))
            futures.append(future)
        return futures

    def _each_here(self, fn: Callable[[_T], _R], items: Sequence[_T], stop_early: bool,
                   sizes: Sequence[int] | None, ordered: _Hand | None,
                   ) -> tuple[list[_R | None], dict[int, Exception]]:
        """:meth:`each` in the calling thread (no pool), looking at the
        enclosing batch's stop event before each item."""
        results: list[_R | None] = [None] * len(items)
        errors: dict[int, Exception] = {}
        for i, x in enumerate(items):
            if self.stop.is_set():
                raise CancelledError("the batch was stopped")
            try:
                results[i] = fn(x)
            except Exception as exc:  # the item's error, reported in input order
                errors[i] = exc
            if not (stop_early and errors):
                self.advance(1 if sizes is None else sizes[i])
            if ordered is not None:
                ordered(i, results[i], errors.get(i))
            if stop_early and errors:
                break
        return results, errors


def _runner(workers: int, report: Progress | None) -> _Runner:
    """The call's :class:`_Runner`: a pool of ``workers`` threads, but none for
    one worker and no report outside the main thread (a task of another
    batch, a campaign's): there no signal handler runs, so the calling
    thread may do the work itself, as the serial loop does."""
    if workers == 1 and report is None and threading.current_thread() is not threading.main_thread():
        return _Runner(stop=threading.Event())
    return _Runner(workers, report=report)


#: What an item of :meth:`_Runner.each` returns when the batch stopped before it.
_SKIPPED = object()


def _polyline_parts(item: Any, index: int) -> tuple[Any, Any, Any]:
    """``(vertices, normals, sigmas)`` of a polyline given as an object or a 3-sequence
    (or a 4-sequence whose last item is its edge profile, :func:`_polyline`)."""
    if type(item) in (tuple, list) and len(item) in (3, 4):  # plain: no such attributes
        return item[0], item[1], _jobs.broadcast_sigmas(item[0], item[2])
    try:  # one attempt for the three attributes, not three hasattr() calls
        return item.vertices_vu, item.normals_vu, _jobs.broadcast_sigmas(item.vertices_vu,
                                                                          item.sigmas)
    except AttributeError:
        pass
    if isinstance(item, Sequence) and not isinstance(item, (str, bytes)) and len(item) == 3:
        return item[0], item[1], _jobs.broadcast_sigmas(item[0], item[2])
    raise TypeError(
        f"polylines[{index}] must have vertices_vu, normals_vu and sigmas attributes "
        f"or be a (vertices_vu, normals_vu, sigmas) sequence, got {type(item).__name__}"
    )


def _polyline(item: Any, index: int) -> tuple[Any, Any, Any, Any, str | None]:
    """Polyline ``index`` of a call as ``(vertices, normals, sigmas, edge_profile,
    edge_kind)``: its parts (:func:`_polyline_parts`), the profile it carries
    (the 4th item of a ``(vertices_vu, normals_vu, sigmas, edge_profile)``
    sequence or an ``edge_profile`` attribute) and the kind it declares (an
    ``edge_kind`` attribute); None where it has none (for the kind: the
    options' :attr:`~dtalign.api.options.FitOptions.edge_kind` then)."""
    parts = _polyline_parts(item, index)
    if type(item) in (tuple, list):  # plain: no such attributes
        return (*parts, item[3] if len(item) == 4 else None, None)
    return (*parts, getattr(item, "edge_profile", None), getattr(item, "edge_kind", None))


def _fit_and_conclude(products: ImageProducts, polylines: list[tuple[Any, ...]], window: Any,
                      options: FitOptions, collect: bool, runner: _Runner) -> list[Any]:
    """The fits of one image's checked polylines (:func:`_polyline`'s tuples),
    each concluded (:func:`_concluded`), their steps run by ``runner``.

    A polyline with an edge profile is reported done when it is concluded
    (its refinement is most of its time), the others when they are fitted
    (or examined)."""
    late = [p[3] is not None for p in polylines]
    fits = _fit_parts(products, [p[:3] for p in polylines], window, options, collect, runner,
                      late)
    return _concluded(products, fits, polylines, options, collect, runner, late)


def _concluded(products: ImageProducts, fits: list[Any], polylines: list[tuple[Any, ...]],
               options: FitOptions, collect: bool, runner: _Runner,
               late: Sequence[bool]) -> list[Any]:
    """``fits`` concluded as :func:`~dtalign.pipeline.fit_polyline_products`
    concludes one (:func:`dtalign.pipeline.fit.conclude`): refined with their
    polylines' edge profiles, marked with their edge kinds (each polyline's,
    else the options', else each profile's ``edge``), their evidence for the
    covariance sampled; a bad profile or kind is the polyline's error
    (raised, or collected in its place). The fits are concluded on
    ``runner``'s threads: a profile refinement is compiled work that
    releases the GIL, several times a fit's own time. The polylines marked
    ``late`` are reported done here: concluded, or failed before it."""
    from .profile_fit import check_edge_profile, edge_kind_of

    def one(i: int) -> Any:
        *_, profile, kind = polylines[i]
        checked = None if profile is None else check_edge_profile(profile, fits[i].normals_vu)
        kind = options.edge_kind if kind is None else kind
        return conclude(fits[i], products, checked, edge_kind_of(kind, checked))

    todo = [i for i, fit in enumerate(fits) if not isinstance(fit, Exception)]
    runner.advance(sum(late[i] for i, fit in enumerate(fits) if isinstance(fit, Exception)))
    done, failed = runner.each(one, todo, stop_early=not collect,
                               sizes=[int(late[i]) for i in todo])
    out = list(fits)
    for k, i in enumerate(todo):  # in input order: the first bad polyline's error is raised
        exc = failed.get(k)
        if exc is None:
            out[i] = done[k]
            continue
        if not isinstance(exc, (TypeError, ValueError)):
            raise exc
        out[i] = _named(exc, f"polylines[{i}]", i)
        if not collect:
            raise out[i] from exc
    return out


def map_ordered(
    fn: Callable[[_T], _R], items: Iterable[_T], *, workers: int = DEFAULT_WORKERS
) -> list[_R]:
    """``[fn(x) for x in items]`` on a thread pool, in input order.

    Useful for any of the public fitting functions: their kernels release
    the GIL, so two threads run two fits at once. The threads of a pool
    made for the call take the items in turn (see the module docstring).

    Parameters
    ----------
    fn : callable
        Applied to each item.
    items : iterable
        The inputs.
    workers : int, optional
        Threads (default: the CPUs this process may use); 1 runs the plain
        serial loop ``[fn(x) for x in items]`` in the calling thread.

    Returns
    -------
    list
        ``fn(item)`` for each item, in order.

    Raises
    ------
    TypeError, ValueError
        If ``workers`` is not an int >= 1. An exception raised by ``fn`` is
        re-raised unchanged: the one of the first failing item in input
        order (the remaining items are not started once a failure is seen).
    """
    n = _check_workers(workers)
    todo = list(items)
    if n == 1:
        return [fn(x) for x in todo]
    with _Runner(n) as runner:
        results, errors = runner.each(fn, todo, stop_early=True)
    if errors:
        raise errors[min(errors)]
    return results  # type: ignore[return-value]


#: The fields of a result that hold wall times, which :func:`results_equal` skips.
_WALL_TIMES = frozenset({"timings_s", "time_s"})


def results_equal(a: Any, b: Any) -> bool:
    """Whether two fit results are equal field by field (arrays bitwise, NaN == NaN).

    :class:`~dtalign.pipeline.PolylineFit` and
    :class:`~dtalign.LMRefineResult` compare by identity; this compares
    their contents, recursing into nested results and lists. ``timings_s``
    and a profile refinement's ``time_s`` are ignored (wall times differ
    between runs).

    Parameters
    ----------
    a, b : object
        Results, lists of results, arrays or plain values.

    Returns
    -------
    bool
    """
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(results_equal(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        x, y = np.asarray(a), np.asarray(b)
        return x.shape == y.shape and x.dtype == y.dtype and bool(
            np.array_equal(x, y, equal_nan=x.dtype.kind in "fc")
        )
    if dataclasses.is_dataclass(a) and not isinstance(a, type):
        if type(a) is not type(b):
            return False
        return all(
            results_equal(getattr(a, f.name), getattr(b, f.name))
            for f in dataclasses.fields(a)
            if f.name not in _WALL_TIMES
        )
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return bool(a == b)


@overload
def fit_many(
    products: ImageProducts, polylines: Iterable[Any], *,
    search_window_vu: tuple[int, int] = ...,
    workers: int = ..., errors: Literal["raise"] = ...,
    progress: Callable[[int, int], Any] | bool | None = ..., options: FitOptions | None = ...,
    **overrides: Any,
) -> list[PolylineFit]: ...
@overload
def fit_many(
    products: ImageProducts, polylines: Iterable[Any], *,
    search_window_vu: tuple[int, int] = ...,
    workers: int = ..., errors: Literal["collect"],
    progress: Callable[[int, int], Any] | bool | None = ..., options: FitOptions | None = ...,
    **overrides: Any,
) -> list[PolylineFit | Exception]: ...
def fit_many(
    products: ImageProducts,
    polylines: Iterable[Any],
    *,
    search_window_vu: tuple[int, int] = DEFAULT_SEARCH_WINDOW_VU,
    workers: int = DEFAULT_WORKERS,
    errors: str = "raise",
    progress: Callable[[int, int], Any] | bool | None = None,
    options: FitOptions | None = None,
    **overrides: Any,
) -> list[Any]:
    """Fit many polylines against one image's products, on ``workers`` threads.

    Parameters
    ----------
    products : ImageProducts
        From :func:`dtalign.pipeline.prepare_image`, shared (read-only) by
        every fit.
    polylines : iterable
        Each item has ``vertices_vu``, ``normals_vu`` and ``sigmas``
        attributes (like :class:`dtalign.scenes.Polyline`) or is a
        ``(vertices_vu, normals_vu, sigmas)`` sequence. A polyline with an
        ``edge_profile`` attribute, or a ``(vertices_vu, normals_vu, sigmas,
        edge_profile)`` sequence, is refined with its
        :class:`~dtalign.EdgeProfile` as
        :func:`~dtalign.pipeline.fit_polyline_products` does.
    search_window_vu : tuple of int, optional
        Coarse-search margin ``(mv, mu)`` for every polyline; default
        ``(30, 30)`` (:data:`~dtalign.pipeline.DEFAULT_SEARCH_WINDOW_VU`).
    workers : int, optional
        Threads (default: the CPUs this process may use); 1 fits serially
        (in one thread of the call's pool when called from the main thread).
    errors : {"raise", "collect"}, optional
        ``"raise"``: raise the first failing polyline's error (named
        ``polylines[i]: ...``, with ``index`` i). ``"collect"``: fit every
        polyline; a failed one's place in the result holds its error
        (see the module docstring).
    progress : callable or bool, optional
        ``progress(done, total)`` is called once per completed polyline,
        ``done`` = 1, 2, ..., ``total``, from the calling thread (a chunk's
        polylines together; one with an edge profile once it is refined,
        most of its time); if it raises, the batch stops and its exception
        propagates unchanged. ``True`` shows a tqdm bar (tqdm is needed);
        None or False (default): no report. See the module docstring's
        "Progress" section.
    options : FitOptions, optional
        The options of every polyline's fit
        (:class:`~dtalign.api.options.FitOptions`, as
        :func:`~dtalign.pipeline.fit_polyline_products` takes them; the
        edge profile and kind are each polyline's own, above).
    **overrides
        Any field of ``options`` by name (``fit_rotation``,
        ``trust_region_px``, ...), as :func:`~dtalign.pipeline.fit_polyline_products` takes them.

    Returns
    -------
    list of PolylineFit
        One per polyline, in input order, equal to the serial calls' (with
        ``errors="collect"``, exceptions in place of the failed ones).

    Raises
    ------
    TypeError
        If ``products`` is not an ``ImageProducts``, a polyline has neither
        form, ``workers`` is not an int, ``progress`` is neither callable
        nor a bool nor None, or an option is unknown.
    ValueError
        If ``workers < 1`` or ``errors`` is unknown; a bad option value;
        with ``errors="raise"``, the error of the first failing polyline.
    """
    if not isinstance(products, ImageProducts):
        raise TypeError(f"products must be an ImageProducts, got {type(products).__name__}")
    n = _check_workers(workers)
    collect = _check_errors(errors)
    progress = _check_progress(progress)
    opts = resolve(options, {**overrides, "search_window_vu": search_window_vu})
    items = [_polyline(item, i) for i, item in enumerate(polylines)]
    with _reporter(progress, len(items), "polyline") as report, _runner(n, report) as runner:
        out = _fit_and_conclude(products, items, search_window_vu, opts, collect, runner)
        # logged in a worker: logging drops an exception raised inside a
        # handler's emit, a timeout's landing in the calling thread too
        runner.call(_log, out, "polylines")
        return out


def _log(results: list[Any], label: str) -> None:
    """Report on dtalign's logger each failed or suspect fit
    (:func:`dtalign.pipeline.status.log_fits`) and, collected, each error at
    WARNING; an image's list of fits (:func:`fit_images`) as ``label[i].polylines``."""
    if not any(isinstance(r, (Exception, list)) for r in results):
        log_fits(results, label)
        return
    for i, r in enumerate(results):
        if isinstance(r, Exception):
            logger.warning("%s", r)
        elif isinstance(r, list):
            _log(r, f"{label}[{i}].polylines")
        else:
            log_fit(r, f"{label}[{i}]")


def _fit_parts(
    products: ImageProducts, parts: list[tuple[Any, Any, Any]], window: Any,
    options: FitOptions, collect: bool, runner: _Runner, late: Sequence[bool],
) -> list[Any]:
    """:func:`fit_many` of checked arguments, its steps run by ``runner``, which
    reports the polylines complete (fitted, or failed and collected) but
    those marked ``late`` (:func:`_concluded` reports them).

    Raising: the first polyline is checked with everything the polylines
    share (:func:`dtalign.pipeline.jobs.plan`), which fixes which error a bad
    call raises; then the others in bulk, up to the first bad one
    (:func:`~dtalign.pipeline.jobs.prepare`); the polylines before it are fitted.
    An error of the first polyline that the probe polyline of
    :func:`_probe_plan` gets too is the call's (a shared argument's): it is
    raised as it is, not as the polyline's. Collecting: the shared
    arguments are checked with the probe (an error there is raised), then
    each run of good polylines up to the next bad one is fitted.
    """
    if not parts:
        return []
    if not collect:
        try:
            shared, first = runner.call(_jobs.plan, products, *parts[0], options)
        except (TypeError, ValueError) as exc:  # what a bad polyline or option raises
            if runner.call(_call_error, products, window, options, exc):
                raise
            raise _named(exc, "polylines[0]", 0) from exc
        batch, error = runner.call(_jobs.prepare, shared, parts, first)
        fits, fit_errors = _fit_batch(shared, batch, runner, True, late)
        if fit_errors:  # a kernel error, before the first bad polyline
            j = min(fit_errors)
            raise _named(fit_errors[j], f"polylines[{j}]", j)
        if error is not None:
            raise _named(error, f"polylines[{batch.n}]", batch.n)
        return fits
    shared = runner.call(_probe_plan, products, window, options)
    out: list[Any] = []
    while len(out) < len(parts):
        s = len(out)
        batch, error = runner.call(_jobs.prepare, shared, parts[s:])
        fits, fit_errors = _fit_batch(shared, batch, runner, False, late[s:])
        for j, fit_error in fit_errors.items():
            fits[j] = _named(fit_error, f"polylines[{s + j}]", s + j)
        out += fits
        if error is not None:
            out.append(_named(error, f"polylines[{len(out)}]", len(out)))
            runner.advance(int(not late[len(out) - 1]))
    return out


def _probe_plan(products: ImageProducts, window: Any, options: FitOptions) -> Any:
    """The shared plan of a call, checked with a probe polyline: one vertex at
    the image centre, which fails no check of its own."""
    h, w = products.shape
    probe = (np.array([[(h - 1) / 2.0, (w - 1) / 2.0]]), np.array([[1.0, 0.0]]), np.ones(1))
    return _jobs.plan(products, *probe, options)[0]


def _call_error(products: ImageProducts, window: Any, options: FitOptions,
                exc: Exception) -> bool:
    """Whether the first polyline's ``exc`` is the call's (a shared argument's)
    error: the probe polyline gets the same one."""
    try:
        _probe_plan(products, window, options)
    except Exception as probe_exc:
        return type(probe_exc) is type(exc) and str(probe_exc) == str(exc)
    return False


def _fit_batch(
    shared: Any, batch: Any, runner: _Runner, stop_early: bool, late: Sequence[bool],
) -> tuple[list[Any], dict[int, Exception]]:
    """Fit the checked polylines of ``batch``, one call of the compiled loop per
    chunk (:func:`_chunks`) on ``runner``'s threads, then make their result objects.

    Returns the fits (None where one failed) and the errors by polyline;
    with ``stop_early``, no fits once a polyline has failed. The results are
    made in one pass at the end, from output arrays all the fits share.
    Each fit's ``timings_s`` has ``fit``: the compiled time of the call's
    fits divided evenly among them. When the options ask for it, each fit
    is then examined against rival basins as
    :func:`~dtalign.pipeline.fit_polyline_products` does
    (:func:`dtalign.pipeline.hypotheses.examine`), on the same threads; the
    polylines are reported done after it, else after their chunk, but those
    marked ``late`` (``late[j]`` for the batch's polyline ``j``), which are
    reported when concluded.
    """
    k = batch.n
    if k == 0:
        return [], {}
    examine = shared.options.examined
    args, codes, out = runner.call(_jobs.loop_inputs, shared, batch)
    bounds = _chunks(k, runner.workers)
    busy = [0.0] * (len(bounds) - 1)

    def fit(c: int) -> None:
        lo, hi = bounds[c], bounds[c + 1]
        t0 = time.perf_counter()
        first = _jobs.run_loop(args, lo, hi, codes, out)
        busy[c] = time.perf_counter() - t0
        if first < hi:  # a polyline failed (the loop went on with the chunk's others)
            _jobs.raise_for(int(codes[first]))

    chunks = range(len(bounds) - 1)
    _, failed = runner.each(fit, chunks, stop_early=stop_early,
                            sizes=[0 if examine else sum(not late[j] for j in
                                                         range(bounds[c], bounds[c + 1]))
                                   for c in chunks])
    errors: dict[int, Exception] = {}
    for c, exc in failed.items():  # each failed polyline's own error
        bad = [j for j in range(bounds[c], bounds[c + 1]) if codes[j] != _jobs.OK] or [bounds[c]]
        errors[bad[0]] = exc
        errors.update({j: _kernel_error(int(codes[j])) for j in bad[1:]})
    if errors and stop_early:
        return [], errors
    fits: list[Any] = runner.call(_results, shared, batch, out, sum(busy) / k, errors)
    if examine:  # failed fits are not examined
        runner.advance(sum(not late[j] for j in errors))
    # Without the examination only the unconverged fits have work left: their
    # settling (dtalign.pipeline.fit.settle), one more LM each.
    good = [j for j, f in enumerate(fits) if f is not None and (examine or needs_settling(f))]
    bounds_of = batch.starts.tolist()

    def one(j: int) -> Any:
        s, e = bounds_of[j], bounds_of[j + 1]
        item = _jobs.Item(batch.pts[s:e], batch.nrm[s:e], batch.sig[s:e],
                          (float(batch.pivots[j, 0]), float(batch.pivots[j, 1])),
                          float(batch.distances[j]))
        return finish(fits[j], shared, item)

    examined, failures = runner.each(one, good, stop_early=stop_early,
                                     sizes=[int(examine and not late[j]) for j in good])
    for i, j in enumerate(good):
        fits[j] = examined[i]
        if i in failures:
            errors[j] = failures[i]
    return ([], errors) if errors and stop_early else (fits, errors)


def _kernel_error(code: int) -> Exception:
    """The ValueError of a :func:`~dtalign._kernels.pipeline.fit_polylines` error code."""
    try:
        _jobs.raise_for(code)
    except ValueError as exc:
        return exc
    raise AssertionError(f"error code {code} raised nothing")  # pragma: no cover


def _results(shared: Any, batch: Any, out: Any, per_fit: float,
             errors: dict[int, Exception]) -> list[Any]:
    """The fits of ``batch`` from the loop's outputs (None where one failed)."""
    fits: list[Any] = wrap(shared, batch, _jobs.readonly_views(out), 0, batch.n)
    for arr in out:  # lock the outputs whose rows the fits' read-only views share
        arr.flags.writeable = False
    for j, f in enumerate(fits):
        f.timings_s["fit"] = per_fit
        if j in errors:  # its rows were never written
            fits[j] = None
    return fits


def _image_parts(item: Any, index: int
                 ) -> tuple[Any, float | None, list[tuple[Any, Any, Any, Any, Any]]]:
    if isinstance(item, Sequence) and not isinstance(item, (str, bytes)) and len(item) == 3:
        image, noise, polys = item
    elif all(hasattr(item, a) for a in ("image", "noise_sigma", "polylines")):
        image, noise, polys = item.image, item.noise_sigma, item.polylines
    else:
        raise TypeError(
            f"items[{index}] must be an (image, noise_sigma, polylines) sequence or have "
            f"image, noise_sigma and polylines attributes (like dtalign.scenes.Scene), "
            f"got {type(item).__name__}"
        )
    if isinstance(polys, (str, bytes)) or not isinstance(polys, Iterable):
        raise TypeError(f"items[{index}] polylines must be an iterable of polylines")
    return image, noise, [_polyline(p, j) for j, p in enumerate(polys)]


def _is_path(image: Any) -> bool:
    return isinstance(image, (str, os.PathLike))


def _fit_image(job: tuple[Any, ...], abort: threading.Event | None = None) -> list[Any]:
    """One image (``job``: its item's parts, the call's arguments and its
    index): made by its loader if it has one, loaded if a path, its
    products, then its polylines serially, stopping between them once
    ``abort`` (the batch's stop event) is set (module level: picklable for a
    process pool)."""
    image, noise, parts, window, config, options, collect, index = job
    if parts is None:  # a loader (fit_images' callable item): the item is made here
        image, noise, parts = _image_parts(image(), index)
    if _is_path(image):
        from ..io.files import load_image

        image = load_image(image)
    products = prepare_image(image, noise, config=config)
    return _fit_and_conclude(products, parts, window, options, collect,
                             _Runner(stop=threading.Event() if abort is None else abort))


@overload
def fit_images(
    items: Iterable[Any], *, search_window_vu: tuple[int, int] = ..., workers: int = ...,
    executor: str | Executor = ..., config: ImageDerivativesConfig | None = ...,
    errors: Literal["raise"] = ..., progress: Callable[[int, int], Any] | bool | None = ...,
    on_image: Callable[[int, Any], Any] | None = ..., options: FitOptions | None = ...,
    **overrides: Any,
) -> list[list[PolylineFit]]: ...
@overload
def fit_images(
    items: Iterable[Any], *, search_window_vu: tuple[int, int] = ..., workers: int = ...,
    executor: str | Executor = ..., config: ImageDerivativesConfig | None = ...,
    errors: Literal["collect"], progress: Callable[[int, int], Any] | bool | None = ...,
    on_image: Callable[[int, Any], Any] | None = ..., options: FitOptions | None = ...,
    **overrides: Any,
) -> list[list[PolylineFit | Exception] | Exception]: ...
def fit_images(
    items: Iterable[Any],
    *,
    search_window_vu: tuple[int, int] = DEFAULT_SEARCH_WINDOW_VU,
    workers: int = DEFAULT_WORKERS,
    executor: str | Executor = "thread",
    config: ImageDerivativesConfig | None = None,
    errors: str = "raise",
    progress: Callable[[int, int], Any] | bool | None = None,
    on_image: Callable[[int, Any], Any] | None = None,
    options: FitOptions | None = None,
    **overrides: Any,
) -> list[Any]:
    """Prepare and fit many images, one image per task.

    Parameters
    ----------
    items : iterable
        Each item is an ``(image, noise_sigma, polylines)`` sequence (or an
        object with those attributes, like :class:`dtalign.scenes.Scene`);
        ``image`` is an array or a path (loaded in the task with
        :func:`dtalign.io.load_image`), ``noise_sigma`` may be None
        (estimated), ``polylines`` as in :func:`fit_many`. An item may also
        be a callable that returns such an item (a loader, as the command
        line's files are read): it is called in the image's task, and what
        it raises is the image's error.
    search_window_vu : tuple of int, optional
        Coarse-search margin for every polyline; default ``(30, 30)``
        (:data:`~dtalign.pipeline.DEFAULT_SEARCH_WINDOW_VU`).
    workers : int, optional
        Parallel tasks (default: the CPUs this process may use); 1 runs
        serially (with ``executor="thread"``, as :func:`fit_many`).
    executor : {"thread", "process"} or concurrent.futures.Executor, optional
        ``"thread"`` (default) shares memory and relies on the kernels
        releasing the GIL; ``"process"`` uses a process pool of ``workers``
        processes made for the call (each image and its results are
        pickled; workers load the compiled kernels from Numba's on-disk
        cache). An ``Executor`` (a pool of the caller's, a Dask client's
        ``get_executor()``) is used as it is and left running; ``workers``
        is then not used. Results are equal either way.
    config : ImageDerivativesConfig, optional
        Image-side tunables for every image.
    errors : {"raise", "collect"}, optional
        ``"raise"``: raise the first failing image's error, named
        ``images[i]: ...`` (``images[i] (path): ...`` for a path), with
        ``index`` i and the image's own error (perhaps a polyline's) as its
        cause. ``"collect"``: a failed image's place holds its error and a
        failed polyline's place in its image's list holds its own (see the
        module docstring); every ordinary exception of an image's task is
        collected, loader errors included.
    progress : callable or bool, optional
        ``progress(done, total)`` is called once per completed image (all
        its polylines fitted), ``done`` = 1, 2, ..., ``total``, from the
        calling thread, with any executor; if it raises, the batch stops (on
        an ``Executor`` of the caller's, the tasks it runs already finish
        there) and its exception propagates unchanged. ``True`` shows a tqdm
        bar (tqdm is needed); None or False (default): no report.
    on_image : callable, optional
        ``on_image(i, result)`` is called for each image in input order, as
        soon as it and the images before it are done, from the calling
        thread; ``result`` is what the returned list holds at ``i`` (with
        ``errors="raise"``, only the images before the first failure). A
        stream of results: what was handed on stays handed on if the batch
        is then interrupted. The images handed on are not logged: reporting
        them is the callback's (as :func:`dtalign.pipeline.status.log_fits`
        does). If it raises, the batch stops as on an interrupt and its
        exception propagates unchanged.
    options : FitOptions, optional
        The options of every polyline's fit, as in :func:`fit_many`.
    **overrides
        Any field of ``options`` by name, as in :func:`fit_many`.

    Returns
    -------
    list of list of PolylineFit
        Per image (input order), one fit per polyline (input order).

    Raises
    ------
    TypeError
        On a malformed item, a bad ``workers`` type, a ``progress`` neither
        callable nor a bool nor None, or an unknown option.
    ValueError
        If ``workers < 1``, ``executor`` or ``errors`` is unknown; with
        ``errors="raise"``, the first failing image's error.
    """
    n = _check_workers(workers)
    collect = _check_errors(errors)
    if not isinstance(executor, Executor) and executor not in _EXECUTORS:
        raise ValueError(f"executor must be one of {_EXECUTORS} or an Executor, got {executor!r}")
    if config is not None and not isinstance(config, ImageDerivativesConfig):
        raise TypeError(f"config must be an ImageDerivativesConfig, got {type(config).__name__}")
    progress = _check_progress(progress)
    opts = resolve(options, {**overrides, "search_window_vu": search_window_vu})
    jobs = [((item, None, None) if callable(item) else _image_parts(item, i))
            + (search_window_vu, config, opts, collect, i) for i, item in enumerate(items)]
    out: list[Any] = [None] * len(jobs)

    def hand(i: int, fits: Any, exc: Exception | None) -> None:  # in input order
        image: Any = jobs[i][0]  # an image's error is named with its path if it has one
        label = f"images[{i}] ({os.fspath(image)})" if _is_path(image) else f"images[{i}]"
        out[i] = fits if exc is None else _named(exc, label, i)
        if on_image is not None and (exc is None or collect):
            on_image(i, out[i])

    own = not isinstance(executor, Executor)
    with _reporter(progress, len(jobs), "image") as report:
        if own and (executor == "thread" or n == 1 or len(jobs) < 2):
            with _runner(n, report) as runner:
                _, failures = runner.each(lambda job: _fit_image(job, runner.stop), jobs,
                                          stop_early=not collect, ordered=hand)
                # in a worker, as fit_many logs
                return runner.call(_image_results, out, failures, collect, on_image is None)
        with (nullcontext(executor) if isinstance(executor, Executor)
              else _process_pool(min(n, len(jobs))) as pool,
              _Runner(pool=pool, report=report) as runner):
            _, failures = runner.each(_fit_image, jobs, stop_early=not collect, ordered=hand)
    return _image_results(out, failures, collect, on_image is None)


def _image_results(out: list[Any], failures: dict[int, Exception], collect: bool,
                   log: bool) -> list[Any]:
    """:func:`fit_images`' results (each failed image's named error in its
    place): the first failure raised, else the failed and suspect fits
    logged (in the caller's process) unless ``on_image`` took them.

    On threads this runs in a worker. On an executor the calling
    thread runs it: an exception a signal handler raises inside a log
    record's output there is logging's to drop (it prints "Logging error").
    """
    if failures and not collect:
        raise out[min(failures)]
    if log:
        _log(out, "items")
    return out
