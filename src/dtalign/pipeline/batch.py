"""Batch fitting on several cores: many polylines per image, many images.

The compiled kernels release the GIL, so threads fit truly in parallel.
:func:`fit_many` checks its polylines once, fits them in chunks of a few
(one call of the compiled loop each), then settles or examines and
concludes each fit as one task. :func:`fit_images` fits one image per
task, on threads, a process pool or an executor of the caller's;
:func:`map_ordered` is ``[fn(x) for x in items]`` on threads. Results come
in input order, equal to the serial calls'. Nothing global is configured.

Each call makes its own executor (``submit``, ``as_completed``,
``shutdown(cancel_futures=True)``), driven by one more thread of the
call's; the calling thread waits on a queue and runs what the driver sends
it (the progress callback, ``on_image``, the result), so that an interrupt
lands there, never inside an item or the executor's locks
(docs/benchmarks.rst, "Batch driver thread"). Errors name their item (``polylines[31]: ...``) and carry
its ``index``; ``errors="collect"`` puts each failed item's error in its
place (:ref:`batch-errors`, :ref:`batch-progress`).

>>> from dtalign import scenes
>>> from dtalign.pipeline import prepare_image
>>> from dtalign.pipeline.batch import fit_many
>>> scene = scenes.navigation_scene()
>>> products = prepare_image(scene.image, scene.noise_sigma)
>>> fits = fit_many(products, scene.polylines, search_window_vu=(30, 30))
>>> [round(x, 1) for x in fits[0].offset_vu]
[7.3, -4.6]
"""

from __future__ import annotations

import functools
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
    as_completed,
)
from contextlib import contextmanager
from queue import SimpleQueue
from typing import Any, Literal, TypeVar, overload

import numpy as np

from .._progress import Progress, tqdm_progress
from ..api.checks import collect_errors as _check_errors
from ..api.checks import progress_callback as _check_progress
from ..api.checks import workers as _check_workers
from ..api.options import FitOptions, resolve
from ..api.results import ImageDerivativesConfig
from . import jobs as _jobs
from .fit import PolylineFit, conclude, finish, needs_settling, wrap
from .products import ImageProducts, prepare_image
from .status import log_fit, log_fits, logger

__all__ = ["DEFAULT_WORKERS", "fit_images", "fit_many", "map_ordered"]

_T = TypeVar("_T")
_R = TypeVar("_R")


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
#: Chunks of the compiled loop per worker (a thread on a slower core takes
#: fewer), of at most this many polylines (an interrupt waits for the chunks
#: running; progress moves a chunk at a time).
_CHUNKS_PER_WORKER, _MAX_CHUNK = 4, 8


@contextmanager
def _reporter(progress: Callable[[int, int], Any] | bool | None, total: int,
              unit: str) -> Iterator[Progress | None]:
    """The call's :class:`~dtalign._progress.Progress` (None without ``progress``)."""
    if progress is None or progress is False:
        yield None
    elif progress is True:
        with tqdm_progress(total, unit=unit) as report:
            if report is None:
                raise ModuleNotFoundError("progress=True needs tqdm (pip install tqdm); or "
                                          "pass a callable progress(done, total)")
            yield report
    else:
        yield Progress(progress, total)


def _named(exc: Exception, label: str, index: int) -> Exception:
    """``exc`` as item ``index``'s error: same type, message ``f"{label}: {exc}"``,
    ``index`` set, ``exc`` its cause; a type that cannot be rebuilt from one
    message (or formats it, like ``KeyError``) is kept, with ``index`` and a note."""
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
        named.add_note(f"in {label}")
    named.index = index  # type: ignore[attr-defined]
    return named


def _ignore_sigint() -> None:
    """A process-pool worker's start: a terminal's Ctrl-C (sent to the whole
    process group) is the parent's to act on; the worker finishes its image."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


class _Call:
    """One batch call, as the thread that runs its work sees it: ``pool`` runs
    :meth:`each`'s items (None: this thread, looking at ``stop`` before each);
    with ``guard``, each item on the pool looks at ``stop`` before it starts;
    ``posts`` is the calling thread's queue when a driver runs the work."""

    def __init__(self, report: Progress | None = None, workers: int = 1,
                 stop: threading.Event | None = None) -> None:
        self.report, self.workers = report, workers
        self.stop = threading.Event() if stop is None else stop
        self.pool: Executor | None = None
        self.guard = False
        self.posts: SimpleQueue[Any] | None = None

    def post(self, fn: Callable[..., Any], *args: Any) -> None:
        """``fn(*args)`` in the calling thread."""
        if self.posts is None:
            fn(*args)
        else:
            self.posts.put((fn, args))

    def advance(self, k: int) -> None:
        """Report ``k`` more items done."""
        if self.report is not None and k:
            self.post(self.report.advance, k)

    def each(self, fn: Callable[[_T], _R], items: Sequence[_T], *, stop_early: bool,
             sizes: Sequence[int] | None = None,
             ordered: Callable[[int, Any, Exception | None], Any] | None = None,
             ) -> tuple[list[_R | None], dict[int, Exception]]:
        """``fn(x)`` for each of ``items``: ``(results, errors)`` (None where it
        raised or did not run; ``errors[i]`` the ``Exception``). With
        ``stop_early`` none after a failed one starts once it is seen, and all
        before the first failure run. Each returned (or, collecting, failed)
        item reports ``sizes[i]`` done (default 1); ``ordered(i, result,
        error)`` is called in input order as soon as the items up to ``i``
        are done (with ``stop_early``, up to the first failure)."""
        if self.stop.is_set():
            raise CancelledError("the batch was stopped")
        n = len(items)
        results: list[_R | None] = [None] * n
        errors: dict[int, Exception] = {}
        done, after = [False] * n, 0
        failed: list[int] = []  # with stop_early, the items seen failing

        def guarded(i: int) -> _R:
            if self.stop.is_set() or (failed and i > min(failed)):
                raise CancelledError  # skipped: the batch stopped, or an item before failed
            return fn(items[i])

        def seen(i: int, future: Future[Any]) -> None:  # where the item completed
            exc = None if future.cancelled() else future.exception()
            if exc is not None and not isinstance(exc, CancelledError):  # it failed
                failed.append(i)
                for later in futures[i + 1 :]:
                    later.cancel()

        if self.pool is None:
            futures: list[Future[Any]] = []
        elif self.guard:
            futures = [self.pool.submit(guarded, i) for i in range(n)]
        else:  # a process pool or the caller's executor: what must not start is cancelled
            futures = [self.pool.submit(fn, x) for x in items]
        for i, future in enumerate(futures if stop_early else ()):
            future.add_done_callback(functools.partial(seen, i))
        index = {f: i for i, f in enumerate(futures)}
        order = range(n) if self.pool is None else map(index.__getitem__, as_completed(futures))
        try:
            for i in order:
                if self.stop.is_set():
                    raise CancelledError("the batch was stopped")
                try:
                    results[i] = guarded(i) if self.pool is None else futures[i].result()
                except CancelledError:
                    if self.stop.is_set():
                        raise
                    if failed and i > min(failed):
                        continue  # skipped after a failure
                    errors[i] = CancelledError()  # by the executor's owner
                except Exception as exc:  # the item's own error
                    errors[i] = exc
                if not (stop_early and errors):
                    self.advance(1 if sizes is None else sizes[i])
                done[i] = True
                while after < n and done[after] and not (stop_early and errors
                                                         and after > min(errors)):
                    if ordered is not None:
                        ordered(after, results[after], errors.get(after))
                    after += 1
                if stop_early and errors and after > min(errors):
                    break  # the first failure and all before it are in
        finally:
            for future in futures:  # a no-op for those done
                future.cancel()
        return results, errors


def _shutdown(executor: Executor) -> None:
    """``executor.shutdown(wait=True, cancel_futures=True)``; retried for up to
    5 s while it raises "cannot join thread before it is started": an
    interrupt landed in a process pool's ``Thread.start``, whose manager
    thread then starts a moment later (and must be joined, so that its
    worker processes stop)."""
    for _ in range(50):
        try:
            executor.shutdown(wait=True, cancel_futures=True)
            return
        except RuntimeError:
            time.sleep(0.1)
    executor.shutdown(wait=True, cancel_futures=True)


def _run(work: Callable[[_Call], _R], call: _Call,
         pool: Executor | Callable[[], Executor] | None) -> _R:
    """``work(call)`` on ``pool`` (an executor of the caller's, or how to make one
    of the call's own, shut down at the end), in a driver thread; ``work(call)``
    in this thread without a pool.

    The device: the calling thread never touches the executor. The driver
    makes the pool, runs ``work`` and shuts the pool down; the calling
    thread waits on a ``SimpleQueue`` (C code: a signal handler's exception
    leaves no lock behind) and runs what the driver posts. On an exception
    there (an interrupt, a raising callback) it stops the call and waits for
    the driver before propagating, so that no fit starts afterwards.
    """
    if pool is None:
        return work(call)
    posts: SimpleQueue[Any] = SimpleQueue()
    call.posts = posts

    def drive() -> None:
        try:
            executor = pool if isinstance(pool, Executor) else pool()  # type: ignore[misc]
            call.pool, call.guard = executor, isinstance(executor, ThreadPoolExecutor)
            try:  # (items on this process's threads look at the stop)
                outcome: tuple[bool, Any] = (True, work(call))
            finally:
                if executor is not pool:
                    _shutdown(executor)
        except BaseException as exc:  # the calling thread's to raise
            outcome = (False, exc)
        posts.put((None, outcome))

    driver = threading.Thread(target=drive, name="dtalign-batch-driver")
    try:
        driver.start()
        while (got := posts.get())[0] is not None:  # the wait an interrupt lands in
            got[0](*got[1])
        driver.join()
    except BaseException:
        call.stop.set()
        _join(driver)
        raise
    returned, value = got[1]
    if returned:
        return value  # type: ignore[no-any-return]
    raise value


def _join(thread: threading.Thread) -> None:
    """``thread.join()``, also after an exception interrupted ``thread.start()``:
    ``join`` refuses a thread still starting; one not started in 5 s never will."""
    deadline = time.monotonic() + 5.0
    while True:
        try:
            return thread.join()
        except RuntimeError:  # "cannot join thread before it is started"
            if thread not in threading.enumerate() or time.monotonic() > deadline:
                return
            time.sleep(0.01)


def _threads(workers: int, report: Progress | None) -> Callable[[], Executor] | None:
    """How to make the call's pool of ``workers`` threads; None (the calling
    thread fits serially) for one worker without a report outside the main
    thread (a task of another batch, a campaign's), where no signal handler runs."""
    if workers == 1 and report is None and threading.current_thread() is not threading.main_thread():
        return None
    return functools.partial(ThreadPoolExecutor, workers, thread_name_prefix="dtalign-batch")


def _polyline(item: Any, index: int) -> tuple[Any, Any, Any, Any, str | None]:
    """Polyline ``index`` as ``(vertices, normals, sigmas, edge_profile,
    edge_kind)`` from a 3- or 4-sequence or an object's attributes."""
    if type(item) in (tuple, list) and len(item) in (3, 4):  # plain: no such attributes
        return (item[0], item[1], _jobs.broadcast_sigmas(item[0], item[2]),
                item[3] if len(item) == 4 else None, None)
    try:  # one attempt for the three attributes, not three hasattr() calls
        parts = item.vertices_vu, item.normals_vu, _jobs.broadcast_sigmas(item.vertices_vu,
                                                                           item.sigmas)
    except AttributeError:
        if not (isinstance(item, Sequence) and not isinstance(item, (str, bytes))
                and len(item) == 3):
            raise TypeError(
                f"polylines[{index}] must have vertices_vu, normals_vu and sigmas attributes "
                f"or be a (vertices_vu, normals_vu, sigmas) sequence, got {type(item).__name__}"
            ) from None
        parts = item[0], item[1], _jobs.broadcast_sigmas(item[0], item[2])
    return (*parts, getattr(item, "edge_profile", None), getattr(item, "edge_kind", None))


def _fit_and_conclude(products: ImageProducts, polylines: list[tuple[Any, ...]],
                      options: FitOptions, collect: bool, call: _Call) -> list[Any]:
    """One image's fits (:func:`_polyline`'s tuples), each then concluded
    (:func:`dtalign.pipeline.fit.conclude`: profile refinement, edge kind,
    evidence) as one task (a refinement is compiled, several times a fit).
    A polyline with a profile is reported done once concluded."""
    from .profile_fit import check_edge_profile, edge_kind_of

    late = [p[3] is not None for p in polylines]
    fits = _fit_parts(products, [p[:3] for p in polylines], options, collect, call,
                      late)

    def one(i: int) -> Any:
        *_, profile, kind = polylines[i]
        checked = None if profile is None else check_edge_profile(profile, fits[i].normals_vu)
        kind = options.edge_kind if kind is None else kind
        return conclude(fits[i], products, checked, edge_kind_of(kind, checked))

    todo = [i for i, fit in enumerate(fits) if not isinstance(fit, Exception)]
    call.advance(sum(late[i] for i, fit in enumerate(fits) if isinstance(fit, Exception)))
    done, failed = call.each(one, todo, stop_early=not collect, sizes=[late[i] for i in todo])
    for k, i in enumerate(todo):  # in input order: the first bad polyline's error is raised
        if (exc := failed.get(k)) is None:
            fits[i] = done[k]
        elif not isinstance(exc, (TypeError, ValueError)):
            raise exc
        elif collect:
            fits[i] = _named(exc, f"polylines[{i}]", i)
        else:
            raise _named(exc, f"polylines[{i}]", i) from exc
    return fits


def _fit_parts(products: ImageProducts, parts: list[tuple[Any, Any, Any]],
               options: FitOptions, collect: bool, call: _Call, late: Sequence[bool],
               ) -> list[Any]:
    """The fits of checked polylines (collecting, a failed one's error in its
    place), reported done but those marked ``late``. Raising, the first
    polyline is checked with the shared arguments (:func:`~dtalign.pipeline.jobs.plan`,
    whose order fixes which error a bad call raises; an error the probe of
    :func:`_probe_plan` gets too is the call's, not named); collecting, the
    probe alone. Then each run of good polylines up to the next bad one
    (:func:`~dtalign.pipeline.jobs.prepare`) is fitted."""
    if not parts:
        return []
    first = None
    if collect:
        shared = _probe_plan(products, options)
    else:
        try:
            shared, first = _jobs.plan(products, *parts[0], options)
        except (TypeError, ValueError) as exc:  # what a bad polyline or option raises
            if _call_error(products, options, exc):
                raise
            raise _named(exc, "polylines[0]", 0) from exc
    out: list[Any] = []
    while len(out) < len(parts):
        s = len(out)
        batch, error = _jobs.prepare(shared, parts[s:], first)
        fits, fit_errors = _fit_batch(shared, batch, call, not collect, late[s:])
        if fit_errors and not collect:  # a kernel error, before the first bad polyline
            j = min(fit_errors)
            raise _named(fit_errors[j], f"polylines[{j}]", j)
        for j, fit_error in fit_errors.items():
            fits[j] = _named(fit_error, f"polylines[{s + j}]", s + j)
        out += fits
        if error is not None:
            out.append(_named(error, f"polylines[{len(out)}]", len(out)))
            if not collect:
                raise out[-1]
            call.advance(int(not late[len(out) - 1]))
        first = None
    return out


def _probe_plan(products: ImageProducts, options: FitOptions) -> Any:
    """A call's shared plan, checked with a probe polyline: one vertex at the
    image centre, which fails no check of its own."""
    h, w = products.shape
    probe = (np.array([[(h - 1) / 2.0, (w - 1) / 2.0]]), np.array([[1.0, 0.0]]), np.ones(1))
    return _jobs.plan(products, *probe, options)[0]


def _call_error(products: ImageProducts, options: FitOptions,
                exc: Exception) -> bool:
    """Whether the first polyline's ``exc`` is a shared argument's: the probe gets it too."""
    try:
        _probe_plan(products, options)
    except Exception as probe_exc:
        return type(probe_exc) is type(exc) and str(probe_exc) == str(exc)
    return False


def _fit_batch(shared: Any, batch: Any, call: _Call, stop_early: bool, late: Sequence[bool],
               ) -> tuple[list[Any], dict[int, Exception]]:
    """Fit ``batch``: one compiled loop call per chunk, the result objects in
    one pass over the shared outputs (``timings_s["fit"]``: the compiled time
    divided evenly), then :func:`dtalign.pipeline.fit.finish` (examination,
    settling) one task a fit where there is any. Returns the fits (None where
    one failed; none at all once one failed, with ``stop_early``) and the
    errors by polyline. Reported done after the examination, else the chunk."""
    k = batch.n
    if k == 0:
        return [], {}
    examine = shared.options.examined
    args, codes, out = _jobs.loop_inputs(shared, batch)
    size = max(1, min(_MAX_CHUNK, -(-k // (call.workers * _CHUNKS_PER_WORKER))))
    bounds = [*range(0, k, size), k]
    chunks = range(len(bounds) - 1)
    busy = [0.0] * len(chunks)

    def fit(c: int) -> None:
        lo, hi = bounds[c], bounds[c + 1]
        t0 = time.perf_counter()
        first = int(_jobs.fit_polylines(args, lo, hi, codes, out))  # (GIL released)
        busy[c] = time.perf_counter() - t0
        if first < hi:  # a polyline failed (the loop went on with the chunk's others)
            _jobs.raise_for(int(codes[first]))

    sizes = [0 if examine else sum(not late[j] for j in range(bounds[c], bounds[c + 1]))
             for c in chunks]
    _, failed = call.each(fit, chunks, stop_early=stop_early, sizes=sizes)
    errors: dict[int, Exception] = {}
    for c, exc in failed.items():  # each failed polyline's own error
        bad = [j for j in range(bounds[c], bounds[c + 1]) if codes[j] != _jobs.OK] or [bounds[c]]
        errors[bad[0]] = exc
        errors.update({j: _kernel_error(int(codes[j])) for j in bad[1:]})
    if errors and stop_early:
        return [], errors
    fits: list[Any] = wrap(shared, batch, _jobs.readonly_views(out), 0, k)
    for arr in out:  # lock the outputs whose rows the fits' read-only views share
        arr.flags.writeable = False
    for j in range(k):
        fits[j].timings_s["fit"] = sum(busy) / k
        if j in errors:  # its rows were never written
            fits[j] = None
    if examine:  # failed fits are not examined
        call.advance(sum(not late[j] for j in errors))
    good = [j for j, f in enumerate(fits) if f is not None and (examine or needs_settling(f))]
    starts = batch.starts.tolist()

    def one(j: int) -> Any:
        s, e = starts[j], starts[j + 1]
        item = _jobs.Item(batch.pts[s:e], batch.nrm[s:e], batch.sig[s:e],
                          (float(batch.pivots[j, 0]), float(batch.pivots[j, 1])),
                          float(batch.distances[j]))
        return finish(fits[j], shared, item)

    examined, failures = call.each(one, good, stop_early=stop_early,
                                   sizes=[int(examine and not late[j]) for j in good])
    for i, j in enumerate(good):
        fits[j] = examined[i]
        if i in failures:
            errors[j] = failures[i]
    return ([], errors) if errors and stop_early else (fits, errors)


def _kernel_error(code: int) -> Exception:
    """The ValueError of a compiled loop's error code."""
    try:
        _jobs.raise_for(code)
    except ValueError as exc:
        return exc
    raise AssertionError(f"error code {code} raised nothing")  # pragma: no cover


def _log(results: list[Any], label: str) -> None:
    """Log each failed or suspect fit (:func:`~dtalign.pipeline.status.log_fits`),
    each collected error at WARNING, an image's fits as ``label[i].polylines``."""
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


def _image_parts(item: Any, index: int) -> tuple[Any, Any, list[tuple[Any, ...]]]:
    """``(image, noise_sigma, polylines)`` of an item of :func:`fit_images`."""
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
    """One image's task: its loader called, its path loaded, its products, its
    polylines serially, stopping between them once ``abort`` (the batch's
    stop) is set. Module level: a process pool pickles it."""
    image, noise, parts, config, options, collect, index = job
    if parts is None:  # a loader (fit_images' callable item): the item is made here
        image, noise, parts = _image_parts(image(), index)
    if _is_path(image):
        from ..io.files import load_image

        image = load_image(image)
    products = prepare_image(image, noise, config=config)
    return _fit_and_conclude(products, parts, options, collect, _Call(stop=abort))


def map_ordered(fn: Callable[[_T], _R], items: Iterable[_T], *,
                workers: int = DEFAULT_WORKERS) -> list[_R]:
    """``[fn(x) for x in items]`` on ``workers`` threads (default: the CPUs this
    process may use; 1: that serial loop), in input order. The fitting
    functions' kernels release the GIL, so two threads run two fits at once.
    The first failing item's exception (in input order) is re-raised
    unchanged; the remaining items are not started once a failure is seen.
    """
    n = _check_workers(workers)
    todo = list(items)
    if n == 1:
        return [fn(x) for x in todo]

    def work(call: _Call) -> list[Any]:
        results, errors = call.each(fn, todo, stop_early=True)
        if errors:
            raise errors[min(errors)]
        return results

    return _run(work, _Call(), _threads(n, None))


_Progress = Callable[[int, int], Any] | bool | None


@overload
def fit_many(products: ImageProducts, polylines: Iterable[Any], *,
             workers: int = ...,
             errors: Literal["raise"] = ..., progress: _Progress = ...,
             options: FitOptions | None = ..., **overrides: Any) -> list[PolylineFit]: ...
@overload
def fit_many(products: ImageProducts, polylines: Iterable[Any], *,
             workers: int = ...,
             errors: Literal["collect"], progress: _Progress = ...,
             options: FitOptions | None = ...,
             **overrides: Any) -> list[PolylineFit | Exception]: ...
def fit_many(products: ImageProducts, polylines: Iterable[Any], *,
             workers: int = DEFAULT_WORKERS, errors: str = "raise", progress: _Progress = None,
             options: FitOptions | None = None, **overrides: Any) -> list[Any]:
    """Fit many polylines against one image's products, on ``workers`` threads.

    Parameters
    ----------
    products : ImageProducts
        From :func:`dtalign.pipeline.prepare_image`, shared (read-only).
    polylines : iterable
        Each has ``vertices_vu``, ``normals_vu`` and ``sigmas`` attributes
        (like :class:`dtalign.scenes.Polyline`), optionally ``edge_profile``
        and ``edge_kind``, or is a ``(vertices_vu, normals_vu, sigmas)`` or
        ``(vertices_vu, normals_vu, sigmas, edge_profile)`` sequence; a
        profile is refined as :func:`~dtalign.pipeline.fit_polyline_products` does.
    workers : int, optional
        Threads (default: the CPUs this process may use); 1 fits serially.
    errors : {"raise", "collect"}, optional
        Raise the first failing polyline's error (``polylines[i]: ...``,
        with ``index`` i), or put each failed one's error in its place.
    progress : callable or bool, optional
        ``progress(done, total)`` once per completed polyline, from the
        calling thread (a chunk's polylines together, one with a profile
        once refined); if it raises, the batch stops and its exception
        propagates unchanged. ``True``: a tqdm bar.
    options : FitOptions, optional
        Every fit's options, as :func:`~dtalign.pipeline.fit_polyline_products`
        takes them (the search window ``search_window_vu`` among them,
        default ``(30, 30)``); ``**overrides`` any of its fields by name.

    Returns
    -------
    list of PolylineFit
        One per polyline, in input order, equal to the serial calls'.

    Raises
    ------
    TypeError, ValueError
        On bad arguments or options; with ``errors="raise"``, the first
        failing polyline's error.
    """
    if not isinstance(products, ImageProducts):
        raise TypeError(f"products must be an ImageProducts, got {type(products).__name__}")
    n = _check_workers(workers)
    collect = _check_errors(errors)
    progress = _check_progress(progress)
    opts = resolve(options, overrides)
    items = [_polyline(item, i) for i, item in enumerate(polylines)]

    def work(call: _Call) -> list[Any]:
        out = _fit_and_conclude(products, items, opts, collect, call)
        _log(out, "polylines")
        return out

    with _reporter(progress, len(items), "polyline") as report:
        return _run(work, _Call(report, n), _threads(n, report))


@overload
def fit_images(items: Iterable[Any], *,
               workers: int = ..., executor: str | Executor = ...,
               config: ImageDerivativesConfig | None = ..., errors: Literal["raise"] = ...,
               progress: _Progress = ..., on_image: Callable[[int, Any], Any] | None = ...,
               options: FitOptions | None = ...,
               **overrides: Any) -> list[list[PolylineFit]]: ...
@overload
def fit_images(items: Iterable[Any], *,
               workers: int = ..., executor: str | Executor = ...,
               config: ImageDerivativesConfig | None = ..., errors: Literal["collect"],
               progress: _Progress = ..., on_image: Callable[[int, Any], Any] | None = ...,
               options: FitOptions | None = ...,
               **overrides: Any) -> list[list[PolylineFit | Exception] | Exception]: ...
def fit_images(items: Iterable[Any], *,
               workers: int = DEFAULT_WORKERS, executor: str | Executor = "thread",
               config: ImageDerivativesConfig | None = None, errors: str = "raise",
               progress: _Progress = None, on_image: Callable[[int, Any], Any] | None = None,
               options: FitOptions | None = None, **overrides: Any) -> list[Any]:
    """Prepare and fit many images, one image per task.

    Parameters
    ----------
    items : iterable
        ``(image, noise_sigma, polylines)`` sequences or objects with those
        attributes (like :class:`dtalign.scenes.Scene`); ``image`` an array
        or a path (loaded in the task, :func:`dtalign.io.load_image`),
        ``noise_sigma`` None to estimate it, ``polylines`` as in
        :func:`fit_many`. An item may be a loader, a callable returning
        such an item, called in the image's task.
    options, **overrides
        As in :func:`fit_many`, for every polyline.
    workers : int, optional
        Parallel tasks (default: the CPUs this process may use).
    executor : {"thread", "process"} or concurrent.futures.Executor, optional
        Threads (default; the kernels release the GIL), a process pool of
        ``workers`` made for the call (images and results are pickled), or
        an ``Executor`` of the caller's (a Dask client's
        ``get_executor()``), used as it is and left running. Results are
        equal either way.
    config : ImageDerivativesConfig, optional
        Image-side tunables for every image.
    errors : {"raise", "collect"}, optional
        Raise the first failing image's error (``images[i]: ...``,
        ``images[i] (path): ...``, with ``index`` i and the image's own
        error as its cause), or put each failed image's error in its place
        (and a failed polyline's in its image's list).
    progress : callable or bool, optional
        As in :func:`fit_many`, once per completed image, with any executor.
    on_image : callable, optional
        ``on_image(i, result)`` for each image in input order as soon as it
        and those before it are done, from the calling thread; what was
        handed on stays handed on if the batch is interrupted. Those images
        are not logged (that is the callback's). If it raises, the batch
        stops and its exception propagates unchanged.

    Returns
    -------
    list of list of PolylineFit
        Per image (input order), one fit per polyline (input order).

    Raises
    ------
    TypeError, ValueError
        On a malformed item or bad arguments; with ``errors="raise"``, the
        first failing image's error.
    """
    n = _check_workers(workers)
    collect = _check_errors(errors)
    if not isinstance(executor, Executor) and executor not in _EXECUTORS:
        raise ValueError(f"executor must be one of {_EXECUTORS} or an Executor, got {executor!r}")
    if config is not None and not isinstance(config, ImageDerivativesConfig):
        raise TypeError(f"config must be an ImageDerivativesConfig, got {type(config).__name__}")
    progress = _check_progress(progress)
    opts = resolve(options, overrides)
    jobs = [((item, None, None) if callable(item) else _image_parts(item, i))
            + (config, opts, collect, i) for i, item in enumerate(items)]

    def work(call: _Call) -> list[Any]:
        out: list[Any] = [None] * len(jobs)

        def hand(i: int, fits: Any, exc: Exception | None) -> None:  # in input order
            image: Any = jobs[i][0]  # an image's error is named with its path if it has one
            label = f"images[{i}] ({os.fspath(image)})" if _is_path(image) else f"images[{i}]"
            out[i] = fits if exc is None else _named(exc, label, i)
            if on_image is not None and (exc is None or collect):
                call.post(on_image, i, out[i])

        # a process pool pickles _fit_image; threads of this process see the stop
        task = _fit_image if call.pool is not None and not call.guard else (
            lambda job: _fit_image(job, call.stop))
        _, failures = call.each(task, jobs, stop_early=not collect, ordered=hand)
        if failures and not collect:
            raise out[min(failures)]
        if on_image is None:  # else reporting them is the callback's
            _log(out, "items")
        return out

    with _reporter(progress, len(jobs), "image") as report:
        pool = (executor if isinstance(executor, Executor)
                else _threads(n, report) if executor == "thread" or n == 1 or len(jobs) < 2
                else functools.partial(ProcessPoolExecutor, min(n, len(jobs)),
                                       initializer=_ignore_sigint))
        return _run(work, _Call(report), pool)
