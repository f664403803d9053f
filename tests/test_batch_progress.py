"""dtalign.pipeline.batch progress: ``progress(done, total)`` once per completed item,
from the calling thread, ending at ``total``; a raising callback stops the
batch cleanly; results are the same with or without it (issue 15, paper cuts)."""

from __future__ import annotations

import dataclasses
import multiprocessing
import sys
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

import _batch_scene
from _batch_scene import WINDOW
from dtalign import scenes
from dtalign.benchmarking.compare import results_equal
from dtalign.pipeline import batch, prepare_image
from dtalign.pipeline import jobs as _fitjobs
from dtalign.pipeline.batch import fit_images, fit_many

nav = _batch_scene.nav  # the shared scene (a module-scoped fixture)
products = _batch_scene.products


@pytest.fixture(scope="module")
def polylines(nav):
    """Twelve distinct polylines: the scene's three, shifted by whole and half pixels."""
    out = []
    for k in range(12):
        p = nav.polylines[k % 3]
        shift = np.array([0.5 * (k // 3), -0.25 * (k // 3)])
        out.append((p.vertices_vu + shift, p.normals_vu, p.sigmas))
    return out


@pytest.fixture(scope="module")
def images(nav):
    other = scenes.navigation_scene(shape=(256, 256), radius=50.0, n_vertices=60,
                                    offset_vu=(-2.6, 1.7), seed=3)
    return [nav, (other.image, None, other.polylines), (nav.image, 2.0, nav.polylines[:1]),
            other, (nav.image, nav.noise_sigma, nav.polylines[1:])]


class Recorder:
    """A progress callback that records ``(done, total, thread)`` of each call."""

    def __init__(self, raise_at=None, exc=None):
        self.calls = []
        self.raise_at, self.exc = raise_at, exc
        self.raised = threading.Event()

    def __call__(self, done, total):
        self.calls.append((done, total, threading.get_ident()))
        if done == self.raise_at:
            self.raised.set()
            raise self.exc

    def counts(self):
        return [(d, t) for d, t, _ in self.calls]

    def threads(self):
        return {t for _, _, t in self.calls}


def _each(n):
    return [(i, n) for i in range(1, n + 1)]


def _nan(item):
    v = item[0].copy()
    v[2, 1] = np.nan
    return (v, item[1], item[2])


@pytest.mark.parametrize("ambiguity", [True, False])  # with and without the examination pass
@pytest.mark.parametrize("workers", [1, 2])
def test_fit_many_reports_each_polyline_from_the_calling_thread(products, polylines, workers,
                                                                ambiguity):
    expected = fit_many(products, polylines, search_window_vu=WINDOW, workers=workers,
                        ambiguity=ambiguity)
    rec = Recorder()
    got = fit_many(products, polylines, search_window_vu=WINDOW, workers=workers,
                   ambiguity=ambiguity, progress=rec)
    assert results_equal(got, expected)
    assert rec.counts() == _each(len(polylines))  # monotone, one per polyline, ends at total
    assert rec.threads() == {threading.get_ident()}


@pytest.mark.parametrize("executor", ["thread", "process"])
@pytest.mark.parametrize("workers", [1, 2])
def test_fit_images_reports_each_image_from_the_calling_thread(images, executor, workers):
    expected = fit_images(images, search_window_vu=WINDOW, workers=workers, executor=executor)
    rec = Recorder()
    got = fit_images(images, search_window_vu=WINDOW, workers=workers, executor=executor,
                     progress=rec)
    assert results_equal(got, expected)
    assert rec.counts() == _each(len(images))
    assert rec.threads() == {threading.get_ident()}


def test_fit_images_on_the_callers_executor(images):
    expected = fit_images(images, search_window_vu=WINDOW, workers=1)
    rec = Recorder()
    with ThreadPoolExecutor(max_workers=2) as pool:
        got = fit_images(images, search_window_vu=WINDOW, executor=pool, progress=rec)
    assert results_equal(got, expected)
    assert rec.counts() == _each(len(images))
    assert rec.threads() == {threading.get_ident()}


def test_called_from_another_thread_reports_in_that_thread(products, polylines, images):
    expected = fit_many(products, polylines, search_window_vu=WINDOW, workers=2)

    def call():
        rec = Recorder()
        got = fit_many(products, polylines, search_window_vu=WINDOW, workers=2, progress=rec)
        return got, rec, threading.get_ident()

    with ThreadPoolExecutor(max_workers=1) as pool:
        got, rec, ident = pool.submit(call).result()
    assert ident != threading.get_ident()
    assert results_equal(got, expected)
    assert rec.counts() == _each(len(polylines))
    assert rec.threads() == {ident}


def test_empty_batches_report_nothing(products):
    rec = Recorder()
    assert fit_many(products, [], search_window_vu=WINDOW, progress=rec) == []
    assert fit_images([], search_window_vu=WINDOW, progress=rec) == []
    assert rec.calls == []


@pytest.mark.parametrize("ambiguity", [True, False])
@pytest.mark.parametrize("workers", [1, 2])
def test_collect_counts_failed_polylines_as_done(nav, workers, ambiguity):
    # bad data (caught by the checks) and a fit that reads a NaN (caught in the kernel)
    scene = scenes.navigation_scene(shape=(288, 288), radius=60.0, n_vertices=80,
                                    offset_vu=(3.4, -2.2), search_window=12)
    products = prepare_image(scene.image, scene.noise_sigma)
    h, w = products.shape
    dt = np.array(products.edge_dt)
    dt[h - 40 :, w - 40 :] = np.nan
    broken = dataclasses.replace(products, edge_dt=dt)
    corner = np.array([h - 16.0, w - 16.0]) + np.arange(8.0)[:, None] * np.array([1.0, 1.2])
    reads_nan = (corner, np.tile([1.0, 0.0], (8, 1)), np.ones(8))
    polys = [(p.vertices_vu, p.normals_vu, p.sigmas) for p in scene.polylines] * 4
    polys[0], polys[5], polys[6], polys[11] = _nan(polys[0]), _nan(polys[5]), reads_nan, reads_nan
    expected = fit_many(broken, polys, search_window_vu=WINDOW, workers=workers,
                        errors="collect", ambiguity=ambiguity)
    rec = Recorder()
    got = fit_many(broken, polys, search_window_vu=WINDOW, workers=workers, errors="collect",
                   ambiguity=ambiguity, progress=rec)
    assert [i for i, r in enumerate(got) if isinstance(r, Exception)] == [0, 5, 6, 11]
    assert results_equal([r for r in got if not isinstance(r, Exception)],
                         [r for r in expected if not isinstance(r, Exception)])
    assert rec.counts() == _each(len(polys))


@pytest.mark.parametrize("executor", ["thread", "process"])
def test_collect_counts_failed_images_as_done(images, tmp_path, executor):
    jobs = list(images)
    jobs[1] = (tmp_path / "missing.npy", None, images[0].polylines)
    rec = Recorder()
    got = fit_images(jobs, search_window_vu=WINDOW, workers=2, executor=executor,
                     errors="collect", progress=rec)
    assert isinstance(got[1], Exception) and got[1].index == 1
    assert rec.counts() == _each(len(jobs))


def test_raise_mode_stops_reporting_at_the_first_failure(products, polylines):
    bad = list(polylines)
    bad[5] = _nan(bad[5])
    for workers in (1, 2):
        rec = Recorder()
        with pytest.raises(ValueError, match=r"^vertices_vu") as info:
            fit_many(products, bad, search_window_vu=WINDOW, workers=workers, progress=rec)
        assert info.value.__notes__ == ["polylines[5]"]
        done = [d for d, _ in rec.counts()]
        assert done == list(range(1, len(done) + 1))  # monotone, from 1
        assert len(done) <= 5  # the polylines before the bad one, at most


@pytest.fixture
def gated(monkeypatch):
    """Every compiled fit but the first waits (GIL released) until the
    callback has raised: the batch is still running when it raises.
    Returns the list of fits started."""
    deps = _fitjobs  # the module whose fit_polylines the batch calls
    compiled, started, gate = deps.fit_polylines, [], threading.Event()

    def fit_polylines(*args):
        started.append(None)
        if len(started) > 1:
            gate.wait(30.0)
        return compiled(*args)

    monkeypatch.setattr(deps, "fit_polylines", fit_polylines)
    return started, gate


@pytest.mark.parametrize("workers", [1, 2])
def test_a_raising_callback_stops_fit_many_cleanly(products, polylines, gated, workers):
    started, gate = gated
    items = polylines * 4  # 48
    before = threading.active_count()
    boom = RuntimeError("stop here")
    rec = Recorder(raise_at=1, exc=boom)
    rec.raised = gate  # the gated fits go on once the callback has raised
    with pytest.raises(RuntimeError) as info:
        fit_many(products, items, search_window_vu=WINDOW, workers=workers, ambiguity=False,
                 progress=rec)
    assert info.value is boom  # unchanged, not named after an item
    assert not hasattr(boom, "index")
    assert rec.counts() == [(1, len(items))]
    # no fit starts once the stop is seen: each worker finishes the one it holds
    assert len(started) <= 1 + 2 * workers
    assert threading.active_count() == before
    gate.set()
    assert results_equal(
        fit_many(products, items, search_window_vu=WINDOW, workers=workers, ambiguity=False),
        fit_many(products, items, search_window_vu=WINDOW, workers=1, ambiguity=False))


@pytest.mark.parametrize("errors", ["raise", "collect"])
def test_a_raising_callback_is_not_collected(products, polylines, errors):
    before = threading.active_count()
    rec = Recorder(raise_at=3, exc=ValueError("from the callback"))
    with pytest.raises(ValueError, match="^from the callback$"):
        fit_many(products, polylines, search_window_vu=WINDOW, workers=2, errors=errors,
                 progress=rec)
    assert rec.counts() == _each(len(polylines))[:3]
    assert threading.active_count() == before


def test_keyboard_interrupt_in_the_callback_propagates(products, polylines, images):
    before = threading.active_count()
    with pytest.raises(KeyboardInterrupt):
        fit_many(products, polylines, search_window_vu=WINDOW, workers=2,
                 progress=Recorder(raise_at=2, exc=KeyboardInterrupt()))
    with pytest.raises(KeyboardInterrupt):
        fit_images(images, search_window_vu=WINDOW, workers=2,
                   progress=Recorder(raise_at=1, exc=KeyboardInterrupt()))
    assert threading.active_count() == before


def test_a_raising_callback_stops_fit_images_cleanly(images, monkeypatch):
    gate, started = threading.Event(), []
    fit_image = batch._fit_image

    def gated(job, abort=None):
        started.append(job)
        if len(started) > 1:
            gate.wait(30.0)
        return fit_image(job, abort)

    monkeypatch.setattr(batch, "_fit_image", gated)
    items = images * 3  # 15 images
    before = threading.active_count()
    rec = Recorder(raise_at=1, exc=RuntimeError("stop"))
    rec.raised = gate
    with pytest.raises(RuntimeError, match="^stop$"):
        fit_images(items, search_window_vu=WINDOW, workers=2, progress=rec)
    assert len(started) <= 1 + 2 * 2
    assert threading.active_count() == before


@pytest.mark.parametrize("executor", ["process", "pool"])
def test_a_raising_callback_on_an_executor_propagates(images, executor):
    rec = Recorder(raise_at=2, exc=RuntimeError("stop"))
    if executor == "process":
        with pytest.raises(RuntimeError, match="^stop$"):
            fit_images(images, search_window_vu=WINDOW, workers=2, executor="process",
                       progress=rec)
        assert multiprocessing.active_children() == []  # the call's pool is shut down
    else:
        with ThreadPoolExecutor(max_workers=2) as pool:
            with pytest.raises(RuntimeError, match="^stop$"):
                fit_images(images, search_window_vu=WINDOW, executor=pool, progress=rec)
            # the caller's pool is left running, the call's futures cancelled or done
            assert pool.submit(lambda: 7).result() == 7
    assert rec.counts() == _each(len(images))[:2]


def test_progress_true_shows_a_tqdm_bar(products, polylines, images, capsys):
    pytest.importorskip("tqdm")
    expected = fit_many(products, polylines, search_window_vu=WINDOW, workers=2)
    got = fit_many(products, polylines, search_window_vu=WINDOW, workers=2, progress=True)
    assert results_equal(got, expected)
    err = capsys.readouterr().err
    assert f"{len(polylines)}/{len(polylines)}" in err and "polyline" in err
    fit_images(images, search_window_vu=WINDOW, workers=2, progress=True)
    err = capsys.readouterr().err
    assert f"{len(images)}/{len(images)}" in err and "image" in err


def test_progress_false_or_none_reports_nothing(products, polylines, capsys):
    expected = fit_many(products, polylines, search_window_vu=WINDOW, workers=2)
    for progress in (None, False):
        got = fit_many(products, polylines, search_window_vu=WINDOW, workers=2,
                       progress=progress)
        assert results_equal(got, expected)
    assert capsys.readouterr().err == ""


def test_progress_true_without_tqdm_says_so_before_any_fit(products, polylines, gated,
                                                          monkeypatch):
    started, gate = gated
    gate.set()
    monkeypatch.setitem(sys.modules, "tqdm", None)  # import tqdm raises ImportError
    with pytest.raises(ModuleNotFoundError, match=r"progress=True needs tqdm"):
        fit_many(products, polylines, search_window_vu=WINDOW, progress=True)
    with pytest.raises(ModuleNotFoundError, match=r"progress=True needs tqdm"):
        fit_images([(np.zeros((8, 8)), 1.0, polylines)], search_window_vu=WINDOW,
                   progress=True)
    assert started == []


@pytest.mark.parametrize("progress", [3, "yes", 1.0, [print]])
def test_a_progress_that_is_not_callable_is_a_type_error(products, polylines, progress):
    with pytest.raises(TypeError, match=r"^progress must be a callable progress\(done, total\)"):
        fit_many(products, polylines, search_window_vu=WINDOW, progress=progress)
    with pytest.raises(TypeError, match=r"^progress must be a callable"):
        fit_images([], search_window_vu=WINDOW, progress=progress)
