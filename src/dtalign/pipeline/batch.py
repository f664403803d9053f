"""Batch fitting on several cores: many polylines per image, many images.

The compiled kernels release the GIL, so threads fit truly in parallel.
:func:`fit_many` checks the call's options once and each polyline once,
then fits them in chunks of a few, one task each (``_fit_run``);
:func:`fit_images` fits one image per task, on threads, a process pool or
an executor of the caller's; :func:`map_ordered` is ``[fn(x) for x in
items]`` on threads. Results come in input order, equal to the serial
calls'; nothing global is configured. Each call makes its own executor
(``submit``, ``as_completed``, ``result()``,
``shutdown(cancel_futures=True)``), driven by a thread of its own
(``_Call.run``). An item's error propagates as it is, with a note
naming the item (:ref:`batch-errors`, :ref:`batch-progress`).

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
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import (
    CancelledError,
    Executor,
    Future,
    ProcessPoolExecutor,
    ThreadPoolExecutor,
    as_completed,
)
from queue import SimpleQueue
from typing import Any, Literal, TypeVar, overload

from .._progress import Progress, reporter
from ..api.checks import collect_errors as _check_errors
from ..api.checks import progress_callback as _check_progress
from ..api.checks import workers as _check_workers
from ..api.options import FitOptions, resolve
from ..api.results import ImageDerivativesConfig
from . import jobs as _jobs
from .fit import PolylineFit, conclude, edge_of, finish, needs_settling, wrap
from .products import ImageProducts, prepare_image, products_of
from .region import image_region, refit_outside
from .status import log_fit, logger

__all__ = ["DEFAULT_WORKERS", "fit_images", "fit_many", "map_ordered"]

_T = TypeVar("_T")
_R = TypeVar("_R")


#: Default workers: the CPUs this process may run on, read at import (its
#: affinity mask where the OS has one: a container or ``taskset`` limits
#: them below ``os.cpu_count()``).
DEFAULT_WORKERS = (len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
                   else os.cpu_count()) or 1

_EXECUTORS = ("thread", "process")
#: Chunks of the compiled loop per worker (a thread on a slower core takes
#: fewer), of at most this many polylines (progress moves a chunk at a time).
_CHUNKS_PER_WORKER, _MAX_CHUNK = 4, 8


def _noted(exc: Exception, label: str, index: int) -> Exception:
    """``exc``, item ``index``'s error, with the note ``label`` naming the item
    and ``index`` set: its type and message stay its own."""
    exc.add_note(label)
    exc.index = index  # type: ignore[attr-defined]
    return exc


class _Call:
    """One batch call, as the thread that runs its work sees it: ``pool`` runs
    :meth:`each`'s items (None: this thread, looking at ``stop`` before each);
    with ``guard``, each item on the pool looks at ``stop`` before it starts;
    ``posts`` is the calling thread's queue while :meth:`run` drives the work."""

    def __init__(self, report: Progress | None = None, workers: int = 1,
                 stop: threading.Event | None = None) -> None:
        self.report, self.workers = report, workers
        self.stop = threading.Event() if stop is None else stop
        self.pool: Executor | None = None
        self.guard = False
        self.posts: SimpleQueue[Any] | None = None

    def run(self, work: Callable[[_Call], _R], pool: Executor | Callable[[], Executor] | None,
            ) -> _R:
        """``work(self)`` on ``pool`` (an executor of the caller's, or how to make
        one of the call's own, shut down at the end), in a driver thread;
        in this thread without a pool.

        The one device of the batch: the calling thread, where a signal
        handler's exception (an interrupt, a timeout) lands, never touches
        the executor, whose ``submit`` and waits are Python code that such
        an exception can leave with a lock held (docs/benchmarks.rst, "Batch
        driver thread"). The driver makes the pool, runs ``work`` and shuts
        the pool down; the calling thread waits on a ``SimpleQueue`` (C code)
        and runs what the driver posts. On an exception there (an interrupt,
        a raising callback) it stops the call and waits for the driver
        before propagating, so that no fit starts afterwards (:func:`_join`).
        """
        if pool is None:
            return work(self)
        posts: SimpleQueue[Any] = SimpleQueue()
        self.posts = posts

        def drive() -> None:
            try:
                executor = pool if isinstance(pool, Executor) else pool()  # type: ignore[misc]
                self.pool, self.guard = executor, isinstance(executor, ThreadPoolExecutor)
                try:  # (items on this process's threads look at the stop)
                    outcome: tuple[bool, Any] = (True, work(self))
                finally:
                    if executor is not pool:
                        _join(functools.partial(executor.shutdown, wait=True,
                                                cancel_futures=True))
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
            self.stop.set()
            _join(driver.join, lambda: driver in threading.enumerate())
            raise
        returned, value = got[1]
        if returned:
            return value  # type: ignore[no-any-return]
        raise value

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
                end = min(errors) + 1 if stop_early and errors else n  # the items that count
                while after < end and done[after]:
                    if ordered is not None:
                        ordered(after, results[after], errors.get(after))
                    after += 1
                if after == end:
                    break  # all in (with stop_early, the first failure and all before it)
        finally:
            for future in futures:  # a no-op for those done
                future.cancel()
        return results, errors


def _join(join: Callable[[], Any], starting: Callable[[], bool] = lambda: True) -> None:
    """``join()``, tried again for up to 5 s while it raises "cannot join thread
    before it is started" and the thread is ``starting()``: an exception
    interrupted a ``Thread.start`` (the driver's, or a process pool's manager
    thread's, whose worker processes stop once it is joined), and the
    thread starts a moment later; one not started by then never will."""
    deadline = time.monotonic() + 5.0
    while True:
        try:
            return join()
        except RuntimeError:
            if not starting() or time.monotonic() > deadline:
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


def _fit_polylines(products: ImageProducts, polylines: list[tuple[Any, ...]],
                   checked: _jobs.Checked, collect: bool, call: _Call) -> list[Any]:
    """One image's fits of :func:`_polyline`'s tuples, in input order: each run
    of polylines up to the next bad one (:func:`~dtalign.pipeline.jobs.prepare`)
    fitted by :func:`_fit_run`. A failed polyline's error, noted
    ``polylines[i]``, is raised (the first in input order, after the fits
    before it), or collecting put in its place (and reported done)."""
    shared = _jobs.plan(products, checked)
    fits: list[Any] = []
    while len(fits) < len(polylines):
        s = len(fits)
        batch, error = _jobs.prepare(shared, [p[:3] for p in polylines[s:]])
        done = _fit_run(shared, batch, polylines[s : s + batch.n], call, collect)
        if error is not None:
            done.append(error)
        for i, result in enumerate(done, s):
            if isinstance(result, Exception):
                _noted(result, f"polylines[{i}]", i)
                if not collect:
                    raise result
        call.advance(int(error is not None))
        fits += done
    return fits


def _fit_run(shared: _jobs.Plan, batch: _jobs.Batch, polylines: list[tuple[Any, ...]],
             call: _Call, collect: bool) -> list[Any]:
    """The fits of checked ``polylines`` (their arrays ``batch``): an ``Exception``
    where one failed, None where none ran once one failed (unless collecting).

    They are fitted in chunks of a few, one task each: one call of the
    compiled loop (GIL released), the chunk's result objects
    (:func:`dtalign.pipeline.fit.wrap`; ``timings_s["fit"]`` the chunk's
    compiled time divided evenly), then for each fit
    :func:`~dtalign.pipeline.fit.finish` (examination, settling) and
    :func:`~dtalign.pipeline.fit.conclude` (profile refinement, edge kind,
    evidence). A chunk's polylines are reported done together.
    """
    k = batch.n
    if k == 0:
        return []
    args, codes, out = _jobs.loop_inputs(shared, batch)
    views = _jobs.readonly_views(out)
    size = max(1, min(_MAX_CHUNK, -(-k // (call.workers * _CHUNKS_PER_WORKER))))
    bounds = [*range(0, k, size), k]
    fits: list[Any] = [None] * k

    def chunk(c: int) -> None:
        lo, hi = bounds[c], bounds[c + 1]
        t0 = time.perf_counter()
        _jobs.fit_polylines(args, lo, hi, codes, out)  # (on past a polyline that fails)
        each_s = (time.perf_counter() - t0) / (hi - lo)
        for j, fit in enumerate(wrap(shared, batch, views, lo, hi), lo):
            if call.stop.is_set():  # (a fit's examination is a few LM fits)
                raise CancelledError("the batch was stopped")
            try:  # (in fit_polyline_products' order: the profile, then the fit)
                profile, kind = edge_of(shared, polylines[j][3], polylines[j][4],
                                        fit.normals_vu)
                if codes[j] != _jobs.OK:  # its rows were never written
                    raise _jobs.kernel_error(int(codes[j]))
                fit.timings_s["fit"] = each_s
                if shared.options.examined or needs_settling(fit):
                    fit = finish(fit, shared, batch.item(j))
                fits[j] = conclude(fit, shared.products, profile, kind)
            except Exception as exc:  # the polyline's own error
                fits[j] = exc
                if not collect:
                    raise  # (the batch stops)

    chunks = range(len(bounds) - 1)
    _, failed = call.each(chunk, chunks, stop_early=not collect,
                          sizes=[bounds[c + 1] - bounds[c] for c in chunks])
    for c, exc in failed.items():  # raised outside a polyline's own work
        if not any(isinstance(f, Exception) for f in fits[bounds[c] : bounds[c + 1]]):
            fits[bounds[c]] = exc
    for arr in out:  # lock the outputs whose rows the fits' read-only views share
        arr.flags.writeable = False
    return fits


def _log(results: list[Any], label: str) -> None:
    """Log each failed or suspect fit (:func:`~dtalign.pipeline.status.log_fit`)
    as ``label[i]`` (an image's fits as ``label[i].polylines``), each collected
    error at WARNING with its last note, the batch's."""
    for i, r in enumerate(results):
        if isinstance(r, Exception):
            logger.warning("%s: %s", r.__notes__[-1], r)
        elif isinstance(r, list):
            _log(r, f"{label}[{i}].polylines")
        else:
            log_fit(r, f"{label}[{i}]")


#: The keys of a mapping item of :func:`fit_images` (``image`` and ``polylines`` required).
_ITEM_KEYS = ("image", "noise_sigma", "polylines", "mask")


def _image_parts(item: Any, index: int) -> tuple[Any, Any, list[tuple[Any, ...]], Any]:
    """``(image, noise_sigma, polylines, mask)`` of an item of :func:`fit_images`."""
    if isinstance(item, Sequence) and not isinstance(item, (str, bytes)) and len(item) in (3, 4):
        image, noise, polys, mask = (*item, None) if len(item) == 3 else item
    elif isinstance(item, Mapping):
        unknown = sorted(map(str, set(item) - set(_ITEM_KEYS)))
        if unknown or not {"image", "polylines"} <= set(item):
            raise TypeError(f"items[{index}] as a mapping needs the keys 'image' and "
                            f"'polylines' (and may have 'noise_sigma', 'mask'), got "
                            f"{sorted(map(str, item))}")
        image, noise, polys, mask = (item.get(k) for k in _ITEM_KEYS)
    elif all(hasattr(item, a) for a in ("image", "noise_sigma", "polylines")):
        image, noise, polys = item.image, item.noise_sigma, item.polylines
        mask = getattr(item, "mask", None)
    else:
        raise TypeError(
            f"items[{index}] must be an (image, noise_sigma, polylines[, mask]) sequence, a "
            f"mapping with those keys, or have image, noise_sigma and polylines attributes "
            f"(like dtalign.scenes.Scene), got {type(item).__name__}"
        )
    if isinstance(polys, (str, bytes)) or not isinstance(polys, Iterable):
        raise TypeError(f"items[{index}] polylines must be an iterable of polylines")
    return image, noise, [_polyline(p, j) for j, p in enumerate(polys)], mask


def _is_path(image: Any) -> bool:
    return isinstance(image, (str, os.PathLike))


def _fit_image(job: tuple[Any, ...], abort: threading.Event | None = None) -> list[Any]:
    """One image's task: its loader called, its path loaded, its products, its
    polylines serially, stopping between them once ``abort`` (the batch's
    stop) is set. Module level: a process pool pickles it."""
    image, noise, parts, mask, config, checked, collect, index = job
    if parts is None:  # a loader (fit_images' callable item): the item is made here
        image, noise, parts, mask = _image_parts(image(), index)
    if _is_path(image):
        from ..io.files import load_image

        image = load_image(image, nonfinite=mask is not None)
    if _is_path(mask):
        from .masked import load_mask

        mask = load_mask(mask)
    # the products of the region its polylines reach (dtalign.pipeline.region);
    # a fit that left it is fitted again on the frame's, with the same noise
    region = image_region(image, [p[0] for p in parts], checked.options, config)
    products = products_of(image, noise, config, region, mask)
    call = _Call(stop=abort)
    fits = _fit_polylines(products, parts, checked, collect, call)
    return refit_outside(products.region, fits, lambda redo: _fit_polylines(
        prepare_image(image, products.noise_sigma, config=config, mask=mask),
        [parts[i] for i in redo], checked, collect, call))


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

    return _Call().run(work, _threads(n, None))


_Progress = Callable[[int, int], Any] | bool | None


@overload
def fit_many(products: ImageProducts, polylines: Iterable[Any], *, workers: int = ...,
             errors: Literal["raise"] = ..., progress: _Progress = ...,
             options: FitOptions | None = ..., **overrides: Any) -> list[PolylineFit]: ...
@overload
def fit_many(products: ImageProducts, polylines: Iterable[Any], *, workers: int = ...,
             errors: Literal["collect"], progress: _Progress = ..., options: FitOptions | None = ...,
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
        Raise the first failing polyline's error (its own, noted
        ``polylines[i]``, with ``index`` i), or put each failed one's error
        in its place (:ref:`batch-errors`).
    progress : callable or bool, optional
        ``progress(done, total)`` from the calling thread once per polyline
        fitted and concluded (a chunk's together); ``True``: a tqdm bar
        (:ref:`batch-progress`).
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
    checked = _jobs.check_options(resolve(options, overrides))
    items = [_polyline(item, i) for i, item in enumerate(polylines)]

    def work(call: _Call) -> list[Any]:
        out = _fit_polylines(products, items, checked, collect, call)
        _log(out, "polylines")
        return out

    with reporter(progress, len(items), "polyline") as report:
        return _Call(report, n).run(work, _threads(n, report))


@overload
def fit_images(items: Iterable[Any], *, workers: int = ..., executor: str | Executor = ...,
               config: ImageDerivativesConfig | None = ..., errors: Literal["raise"] = ...,
               progress: _Progress = ..., on_image: Callable[[int, Any], Any] | None = ...,
               options: FitOptions | None = ..., **overrides: Any) -> list[list[PolylineFit]]: ...
@overload
def fit_images(items: Iterable[Any], *, workers: int = ..., executor: str | Executor = ...,
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
        ``(image, noise_sigma, polylines)`` or ``(image, noise_sigma,
        polylines, mask)`` sequences, mappings with those keys (``image``
        and ``polylines`` required), or objects with those attributes
        (like :class:`dtalign.scenes.Scene`; ``mask`` optional); ``image``
        an array or a path (loaded in the task, :func:`dtalign.io.load_image`),
        ``noise_sigma`` None to estimate it, ``polylines`` as in
        :func:`fit_many`, ``mask`` None, or the image's bad pixels
        (:func:`~dtalign.pipeline.products.prepare_image`'s ``mask``) as
        an array or a mask file (nonzero = bad,
        :func:`~dtalign.pipeline.masked.load_mask`). An item may be a
        loader, a callable returning such an item, called in the image's task.
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
        Raise the first failing image's error (its own, noted ``images[i]``
        or ``images[i] (path)`` after any note of a polyline's, with
        ``index`` i), or put each failed image's error in its place (and a
        failed polyline's in its image's list).
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
    checked = _jobs.check_options(resolve(options, overrides))
    jobs = [((item, None, None, None) if callable(item) else _image_parts(item, i))
            + (config, checked, collect, i) for i, item in enumerate(items)]

    def work(call: _Call) -> list[Any]:
        out: list[Any] = [None] * len(jobs)

        def hand(i: int, fits: Any, exc: Exception | None) -> None:  # in input order
            image: Any = jobs[i][0]  # an image's error is named with its path if it has one
            label = f"images[{i}] ({os.fspath(image)})" if _is_path(image) else f"images[{i}]"
            out[i] = fits if exc is None else _noted(exc, label, i)
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

    with reporter(progress, len(jobs), "image") as report:
        pool = (executor if isinstance(executor, Executor)
                else _threads(n, report) if executor == "thread" or n == 1 or len(jobs) < 2
                # (a terminal's Ctrl-C, sent to the whole process group, is the
                # parent's to act on: each worker finishes its image)
                else functools.partial(ProcessPoolExecutor, min(n, len(jobs)),
                                       initializer=signal.signal,
                                       initargs=(signal.SIGINT, signal.SIG_IGN)))
        return _Call(report).run(work, pool)
