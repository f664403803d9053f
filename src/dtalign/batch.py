"""Batch fitting on several cores: many polylines per image, many images.

The compiled kernels release the GIL (``nogil=True``), so threads run
fits truly in parallel. Two entry points:

* :func:`fit_many` fits many polylines against one image's products
  (:func:`dtalign.pipeline.prepare_image`): the first polyline and the
  shared options are checked as :func:`~dtalign.pipeline.fit_polyline_products`
  checks them, the others in bulk, and the worker threads then run one
  compiled loop (coarse search and LM of every polyline) over them with
  the GIL released throughout, each taking the next polyline from a shared
  counter; the GIL-held Python per fit is a few microseconds instead of a
  third of the fit;
* :func:`fit_images` prepares and fits many images, one image per task.

Both return their results in input order, equal to what the serial calls
return (the kernels are deterministic and share no state), and raise the
exception of the first failing item, as the serial loop would. Nothing
global is configured here: no Numba threading layer, no thread count. The
helper threads are kept, parked (a few, GIL released), for the next call.

Examples
--------
>>> from dtalign import scenes
>>> from dtalign.batch import fit_many
>>> from dtalign.pipeline import prepare_image
>>> scene = scenes.navigation_scene()
>>> products = prepare_image(scene.image, scene.noise_sigma)
>>> fits = fit_many(products, scene.polylines, search_window_vu=(30, 30))
>>> [round(x, 1) for x in fits[0].offset_vu]
[7.3, -4.6]
"""

from __future__ import annotations

import _thread
import dataclasses
import inspect
import itertools
import math
import numbers
import os
import threading
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import Executor, ProcessPoolExecutor, ThreadPoolExecutor
from typing import Any, TypeVar

import numpy as np

from . import _fitjobs
from ._image_args import ImageDerivativesConfig
from .pipeline import ImageProducts, PolylineFit, fit_polyline_products, prepare_image
from .status import log_fits

__all__ = ["DEFAULT_WORKERS", "fit_images", "fit_many", "map_ordered", "results_equal"]

#: Two workers: the machines this runs on have two cores.
DEFAULT_WORKERS = 2

_T = TypeVar("_T")
_R = TypeVar("_R")

#: Keyword options :func:`fit_polyline_products` accepts besides the window.
_FIT_OPTIONS = frozenset(
    name
    for name, p in inspect.signature(fit_polyline_products).parameters.items()
    if p.kind is inspect.Parameter.KEYWORD_ONLY and name != "search_window_vu"
)

#: Their defaults (the options a call leaves out).
_FIT_DEFAULTS = {
    name: p.default
    for name, p in inspect.signature(fit_polyline_products).parameters.items()
    if name in _FIT_OPTIONS
}

_EXECUTORS = ("thread", "process")


def _check_workers(workers: Any) -> int:
    if isinstance(workers, bool) or not isinstance(workers, numbers.Integral):
        raise TypeError(f"workers must be an int >= 1, got {type(workers).__name__}")
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    return int(workers)


def _check_options(options: dict[str, Any]) -> None:
    unknown = sorted(set(options) - _FIT_OPTIONS)
    if unknown:
        raise TypeError(
            f"unexpected fit option(s) {', '.join(map(repr, unknown))}; "
            f"accepted: {', '.join(sorted(_FIT_OPTIONS))}"
        )


def _polyline_parts(item: Any, index: int) -> tuple[Any, Any, Any]:
    """``(vertices, normals, sigmas)`` of a polyline given as an object or a 3-sequence."""
    if type(item) in (tuple, list) and len(item) == 3:  # plain: no such attributes
        return item[0], item[1], item[2]
    try:  # hasattr() three times, in a third of the time
        return item.vertices_vu, item.normals_vu, item.sigmas
    except AttributeError:
        pass
    if isinstance(item, Sequence) and not isinstance(item, (str, bytes)) and len(item) == 3:
        return item[0], item[1], item[2]
    raise TypeError(
        f"polylines[{index}] must have vertices_vu, normals_vu and sigmas attributes "
        f"or be a (vertices_vu, normals_vu, sigmas) sequence, got {type(item).__name__}"
    )


class _Helper:
    """A helper thread that runs one job each time it is started, then parks.

    Parked, it waits on a lock (GIL released). Waking one costs a lock
    release; creating a thread cost ~0.1 ms here before the caller went on,
    and ~0.2 ms before the new thread ran its job: 64 fits on 2 threads took
    0.04-0.5 ms less (2 % overall) in each of eight rounds of shuffled
    samples. Created with _thread: threading.Thread.start waits for the new
    thread to run (0.1 to 0.4 ms here, this thread idle).
    """

    __slots__ = ("_go", "_done", "_job", "_error")

    def __init__(self) -> None:
        self._go = threading.Lock()
        self._go.acquire()
        self._done = threading.Lock()
        self._done.acquire()
        self._job: Callable[[], None] | None = None
        self._error: BaseException | None = None
        _thread.start_new_thread(self._loop, ())

    def _loop(self) -> None:
        while True:
            self._go.acquire()
            job, self._job = self._job, None
            if job is None:  # retired
                return
            try:
                job()
            except BaseException as exc:  # handed to wait(); the helper lives on
                self._error = exc
            finally:
                self._done.release()

    def start(self, job: Callable[[], None] | None) -> None:
        """Run ``job()`` in this thread (None: the thread exits)."""
        self._job = job
        self._go.release()

    def wait(self) -> None:
        """Wait until the job has returned; raise what it raised."""
        self._done.acquire()
        error, self._error = self._error, None
        if error is not None:
            raise error


#: Parked helpers kept beyond this many are retired: the most two-core
#: callers need, with room for a few calls running at once.
_MAX_PARKED = 8
_parked: list[_Helper] = []
_parked_lock = threading.Lock()


def _forget_parked() -> None:
    """In a forked child: the parent's helper threads do not exist there."""
    global _parked, _parked_lock
    _parked, _parked_lock = [], threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_parked)


def _run_threads(fn: Callable[[], None], n: int, main: Callable[[], None] | None = None) -> None:
    """Run ``fn()`` in ``n - 1`` helper threads and ``main()`` (default ``fn``)
    in the calling thread, all at once; return when all have finished.

    The helpers are parked :class:`_Helper` threads from earlier calls (new
    ones when none is free, so nested and concurrent calls never wait for
    each other), parked again afterwards. ``fn`` should not raise; if it
    does, the first exception is re-raised here once every thread is done.
    """
    if n <= 1:
        (fn if main is None else main)()
        return
    with _parked_lock:
        helpers = [_parked.pop() for _ in range(min(n - 1, len(_parked)))]
    try:
        helpers += [_Helper() for _ in range(n - 1 - len(helpers))]
    except BaseException:  # no thread could be started: park again the ones taken
        with _parked_lock:
            _parked.extend(helpers)
        raise
    for helper in helpers:
        helper.start(fn)
    errors: list[BaseException] = []
    try:
        (fn if main is None else main)()
    finally:
        for helper in helpers:
            try:
                helper.wait()
            except BaseException as exc:
                errors.append(exc)
        with _parked_lock:
            keep = max(0, min(len(helpers), _MAX_PARKED - len(_parked)))
            _parked.extend(helpers[:keep])
        for helper in helpers[keep:]:
            helper.start(None)
    if errors:
        raise errors[0]


def map_ordered(
    fn: Callable[[_T], _R], items: Iterable[_T], *, workers: int = DEFAULT_WORKERS
) -> list[_R]:
    """``[fn(x) for x in items]`` on a thread pool, in input order.

    Useful for any of the public fitting functions: their kernels release
    the GIL, so two threads run two fits at once. Each worker thread (the
    calling thread is one of them) takes the next item index from a shared
    counter (no future per item), so the per-item overhead stays a few
    microseconds.

    Parameters
    ----------
    fn : callable
        Applied to each item.
    items : iterable
        The inputs.
    workers : int, optional
        Threads; 1 runs the plain serial loop in the calling thread.

    Returns
    -------
    list
        ``fn(item)`` for each item, in order.

    Raises
    ------
    TypeError, ValueError
        If ``workers`` is not an int >= 1. An exception raised by ``fn`` is
        re-raised: the one of the first failing item in input order (the
        remaining items are not started once a failure is seen).
    """
    n = _check_workers(workers)
    todo = list(items)
    if n == 1 or len(todo) <= 1:
        return [fn(x) for x in todo]
    results: list[Any] = [None] * len(todo)
    errors: dict[int, BaseException] = {}
    counter = itertools.count()  # next() is atomic under the GIL

    def worker() -> None:
        for i in iter(counter.__next__, None):
            if i >= len(todo) or errors:
                return
            try:
                results[i] = fn(todo[i])
            except BaseException as exc:  # re-raised in the caller, in order
                errors[i] = exc
                return

    _run_threads(worker, min(n, len(todo)))
    if errors:
        raise errors[min(errors)]
    return results


def results_equal(a: Any, b: Any) -> bool:
    """Whether two fit results are equal field by field (arrays bitwise, NaN == NaN).

    :class:`~dtalign.pipeline.PolylineFit` and
    :class:`~dtalign.LMRefineResult` compare by identity; this compares
    their contents, recursing into nested results and lists. ``timings_s``
    is ignored (wall times differ between runs).

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
            if f.name != "timings_s"
        )
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return bool(a == b)


def fit_many(
    products: ImageProducts,
    polylines: Iterable[Any],
    *,
    search_window_vu: Any,
    workers: int = DEFAULT_WORKERS,
    **options: Any,
) -> list[PolylineFit]:
    """Fit many polylines against one image's products, on ``workers`` threads.

    Parameters
    ----------
    products : ImageProducts
        From :func:`dtalign.pipeline.prepare_image`, shared (read-only) by
        every fit.
    polylines : iterable
        Each item has ``vertices_vu``, ``normals_vu`` and ``sigmas``
        attributes (like :class:`dtalign.scenes.Polyline`) or is a
        ``(vertices_vu, normals_vu, sigmas)`` sequence.
    search_window_vu : tuple of int
        Coarse-search margin ``(mv, mu)`` for every polyline.
    workers : int, optional
        Threads (default 2); 1 fits serially in the calling thread.
    **options
        Passed to :func:`dtalign.pipeline.fit_polyline_products` for every
        polyline (``fit_rotation``, ``trust_region_px``, ...).

    Returns
    -------
    list of PolylineFit
        One per polyline, in input order, equal to the serial calls'.

    Raises
    ------
    TypeError
        If ``products`` is not an ``ImageProducts``, a polyline has neither
        form, ``workers`` is not an int, or an option is unknown.
    ValueError
        If ``workers < 1``; any error of a fit (the first failing one).
    """
    if not isinstance(products, ImageProducts):
        raise TypeError(f"products must be an ImageProducts, got {type(products).__name__}")
    n = _check_workers(workers)
    _check_options(options)
    parts = [_polyline_parts(item, i) for i, item in enumerate(polylines)]
    fits = _fit_parts(products, parts, search_window_vu, options, n)
    log_fits(fits)  # failed and suspect fits at WARNING (dtalign.status)
    return fits


def _fit_parts(
    products: ImageProducts,
    parts: list[tuple[Any, Any, Any]],
    window: Any,
    options: dict[str, Any],
    workers: int,
) -> list[PolylineFit]:
    """Fit polylines with ``workers`` threads running one compiled loop over them.

    The first polyline is checked with everything the polylines share
    (:func:`dtalign._fitjobs.plan`), the others in bulk; the threads then
    take the polylines one at a time from a shared counter, with the GIL
    released, so a thread on a slower core fits fewer. The polylines before
    the first bad one are fitted, and the first error in input order is
    raised, as the serial loop would.
    """
    if not parts:
        return []
    shared, batch, error = _plan_batch(products, parts, window, options)
    fits = _fitjobs.fit_batch(shared, batch, workers=workers)
    if error is not None:
        raise error
    from .hypotheses import check_seeds

    seeds = check_seeds(options.get("seeds", _FIT_DEFAULTS["seeds"]))
    if options.get("ambiguity", _FIT_DEFAULTS["ambiguity"]) or seeds > 1:
        fits = _examine_all(shared, batch, fits, seeds, workers)
    return fits


def _examine_all(shared: Any, batch: Any, fits: list[PolylineFit], seeds: int,
                 workers: int) -> list[PolylineFit]:
    """The one-call pipeline's examination of rival basins
    (:func:`dtalign.hypotheses.examine`) for each fit, on ``workers`` threads
    (its scans and fits are compiled and release the GIL)."""
    from . import hypotheses

    bounds = batch.starts.tolist()

    def one(j: int) -> PolylineFit:
        s, e = bounds[j], bounds[j + 1]
        item = _fitjobs.Item(batch.pts[s:e], batch.nrm[s:e], batch.sig[s:e],
                             (float(batch.pivots[j, 0]), float(batch.pivots[j, 1])),
                             float(batch.distances[j]))
        return hypotheses.examine(
            fits[j], shared, item, seeds=seeds,
            refit=lambda seed: _fitjobs.fit_from(shared, item, seed),
        )

    if workers == 1 or len(fits) == 1:
        return [one(j) for j in range(len(fits))]
    with ThreadPoolExecutor(max_workers=workers) as pool:
        return list(pool.map(one, range(len(fits))))


def _plan_batch(
    products: ImageProducts, parts: list[tuple[Any, Any, Any]], window: Any,
    options: dict[str, Any],
) -> tuple[Any, Any, Exception | None]:
    """The checked plan and batch of a non-empty ``parts``, and the error of its
    first bad polyline (None if none): :func:`dtalign._fitjobs.plan`, then
    :func:`~dtalign._fitjobs.prepare`."""
    kw = {**_FIT_DEFAULTS, **options}
    # the one-call pipeline's examination of rival basins is not the compiled loop's
    kw.pop("seeds")
    kw.pop("ambiguity")
    shared, first = _fitjobs.plan(
        products, *parts[0], search_window_vu=window, fit_rotation=kw.pop("fit_rotation"),
        pivot_vu=kw.pop("pivot_vu"), pivot_distance_px=kw.pop("pivot_distance_px"),
        lm_options=kw,
    )
    batch, error = _fitjobs.prepare(shared, parts, first)
    return shared, batch, error


def _image_parts(item: Any, index: int) -> tuple[Any, float | None, list[tuple[Any, Any, Any]]]:
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
    return image, noise, [_polyline_parts(p, j) for j, p in enumerate(polys)]


def _fit_image(
    job: tuple[Any, float | None, list[tuple[Any, Any, Any]], Any, Any, dict[str, Any]],
) -> list[PolylineFit]:
    """One image: products, then its polylines serially (module level: picklable)."""
    image, noise, parts, window, config, options = job
    return _fit_parts(prepare_image(image, noise, config=config), parts, window, options, 1)


def fit_images(
    items: Iterable[Any],
    *,
    search_window_vu: Any,
    workers: int = DEFAULT_WORKERS,
    executor: str = "thread",
    config: ImageDerivativesConfig | None = None,
    **options: Any,
) -> list[list[PolylineFit]]:
    """Prepare and fit many images, one image per task.

    Parameters
    ----------
    items : iterable
        Each item is an ``(image, noise_sigma, polylines)`` sequence (or an
        object with those attributes, like :class:`dtalign.scenes.Scene`);
        ``noise_sigma`` may be None (estimated), ``polylines`` as in
        :func:`fit_many`.
    search_window_vu : tuple of int
        Coarse-search margin for every polyline.
    workers : int, optional
        Parallel tasks (default 2); 1 runs serially in the calling thread.
    executor : {"thread", "process"}, optional
        ``"thread"`` (default) shares memory and relies on the kernels
        releasing the GIL; ``"process"`` uses a process pool (each image
        and its results are pickled; workers load the compiled kernels
        from Numba's on-disk cache). Results are equal either way.
    config : ImageDerivativesConfig, optional
        Image-side tunables for every image.
    **options
        Passed to :func:`dtalign.pipeline.fit_polyline_products`.

    Returns
    -------
    list of list of PolylineFit
        Per image (input order), one fit per polyline (input order).

    Raises
    ------
    TypeError
        On a malformed item, a bad ``workers`` type or an unknown option.
    ValueError
        If ``workers < 1`` or ``executor`` is unknown; any error of a fit
        (the first failing image's).
    """
    n = _check_workers(workers)
    if executor not in _EXECUTORS:
        raise ValueError(f"executor must be one of {_EXECUTORS}, got {executor!r}")
    if config is not None and not isinstance(config, ImageDerivativesConfig):
        raise TypeError(f"config must be an ImageDerivativesConfig, got {type(config).__name__}")
    _check_options(options)
    jobs = [
        (*_image_parts(item, i), search_window_vu, config, options)
        for i, item in enumerate(items)
    ]
    if executor == "thread" or n == 1 or len(jobs) <= 1:
        out = map_ordered(_fit_image, jobs, workers=n)
    else:
        pool: Executor
        with ProcessPoolExecutor(max_workers=min(n, len(jobs), os.cpu_count() or 1)) as pool:
            out = list(pool.map(_fit_image, jobs))
    for i, fits in enumerate(out):  # logged here, in the caller's process
        log_fits(fits, f"items[{i}].polylines")
    return out
