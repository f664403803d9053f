"""Fits that say when they failed: status, reasons, the ``dtalign`` logger, the CLI exit code.

Each case is a fit that could fail silently: a polyline outside the image,
flipped or zero normals, a noise sigma so high no edge survives, a seed on
the window edge. Each would return the coarse seed with 0 inliers; the
status, its reasons and the log say so.
"""

from __future__ import annotations

import concurrent.futures
import json
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import dtalign
from dtalign import scenes
from dtalign.io import save_polyline_csv
from dtalign.pipeline import fit_polyline, fit_polyline_products, prepare_image
from dtalign.pipeline.batch import fit_images, fit_many
from dtalign.pipeline.status import FitReason, FitStatus
from dtalign.scenes import Polyline

TRUE = (3.4, -2.2)


@pytest.fixture(scope="module")
def scene():
    return scenes.disc_scene(shape=(200, 200), radius=50.0, n_vertices=100, offset_vu=TRUE)


@pytest.fixture(scope="module")
def products(scene):
    return prepare_image(scene.image, scene.noise_sigma)


def _fit(products, scene, vertices=None, normals=None, **kw):
    p = scene.polyline
    kw.setdefault("search_window_vu", (8, 8))
    return fit_polyline_products(
        products, p.vertices_vu if vertices is None else vertices,
        p.normals_vu if normals is None else normals, p.sigmas, **kw,
    )


def _warnings(caplog):
    return [r for r in caplog.records if r.name == "dtalign" and r.levelno == logging.WARNING]


def test_a_clean_fit_is_ok_and_logs_nothing(products, scene, caplog):
    caplog.set_level(logging.WARNING, logger="dtalign")
    fit = _fit(products, scene)
    assert fit.status == "ok" and fit.status is FitStatus.OK and not fit.failed
    # the LM ends at its damping bound on this small disc, but its pose has
    # settled there: no reason (not_converged means "not settled")
    assert not fit.lm.converged and fit.settled
    assert fit.settling is not None and fit.settling.shift_sigmas <= 0.25
    assert fit.reasons == ()
    assert fit.status_message == "ok"
    assert not _warnings(caplog)
    assert np.allclose(fit.offset_vu, TRUE, atol=0.1)


def test_polyline_outside_the_image_fails_with_a_warning(products, scene, caplog):
    caplog.set_level(logging.WARNING, logger="dtalign")
    fit = _fit(products, scene, vertices=scene.polyline.vertices_vu + 1000.0)
    assert fit.status == "failed" and fit.failed
    assert FitReason.DEGENERATE in fit.reasons
    (record,) = _warnings(caplog)
    assert "failed" in record.getMessage() and "degenerate" in record.getMessage()
    assert "inside the image" in fit.status_message
    # named as outside first, not blamed on the normals (tests/test_outside_image.py)
    assert fit.reasons == (FitReason.OUTSIDE_IMAGE, FitReason.DEGENERATE)
    assert "100 of 100 vertices lie outside the 200 x 200 image" in fit.status_message
    assert "polarity" not in fit.status_message


def test_flipped_normals_fail_every_vertex_polarity_rejected(products, scene, caplog):
    caplog.set_level(logging.WARNING, logger="dtalign")
    n = len(scene.polyline)
    # the overlap seed (no polarity in the search) lands on the edge itself,
    # where every flipped vertex is rejected
    kw = dict(search_window_vu=(30, 30), ambiguity=False)
    p = scene.polyline
    lm_only = fit_polyline_products(products, p.vertices_vu, -p.normals_vu, p.sigmas,
                                    use_polarity=False, **kw)
    fit = fit_polyline_products(products, p.vertices_vu, -p.normals_vu, p.sigmas, **kw)
    assert lm_only.lm.polarity_rejected_count == 0
    assert fit.status in ("failed", "suspect")
    assert fit.lm.polarity_rejected_count >= n - 2
    assert set(fit.reasons) & {FitReason.ALL_POLARITY_REJECTED, FitReason.MOST_POLARITY_REJECTED}
    record = _warnings(caplog)[-1]
    assert "normals" in record.getMessage() and "wrong way" in record.getMessage()


def test_a_demo_disc_with_flipped_normals_is_failed_not_ambiguous():
    """``disc_scene(seed=2)`` with its normals negated: every vertex sees the
    gradient the wrong way, and the likeliest cause leads (a rival basin at
    (0, 0) with 1 inlier is no reason to call it ``ambiguous``)."""
    s = scenes.disc_scene(seed=2)
    p = s.polyline
    fit = fit_polyline(s.image, p.vertices_vu, -p.normals_vu, p.sigmas, search_window_vu=(30, 30))
    assert fit.status == "failed"
    assert str(fit.reasons[0]) == "most_polarity_rejected"
    assert fit.status_message.startswith(
        "failed: most vertices see the gradient the wrong way")


def test_zero_normals_fail(products, scene):
    fit = _fit(products, scene, normals=np.zeros_like(scene.polyline.normals_vu))
    assert fit.status == "failed" and "all_polarity_rejected" in fit.reasons


def test_noise_sigma_so_high_no_edge_survives_fails(scene, caplog):
    caplog.set_level(logging.WARNING, logger="dtalign")
    p = scene.polyline
    fit = fit_polyline(scene.image, p.vertices_vu, p.normals_vu, p.sigmas,
                       search_window_vu=(8, 8), noise_sigma=1e4)
    assert fit.status == "failed" and FitReason.DEGENERATE in fit.reasons
    assert "noise sigma 1e+04" in fit.status_message
    assert len(_warnings(caplog)) == 1


def test_most_vertices_polarity_rejected_fails_with_the_normals_reason_first(
        products, scene, caplog):
    # a fit whose polarity test rejects most vertices is failed (not
    # "suspect": its pose is no measurement), and the polarity reason comes first
    caplog.set_level(logging.WARNING, logger="dtalign")
    normals = scene.polyline.normals_vu.copy()
    normals[:70] *= -1.0
    fit = _fit(products, scene, normals=normals)
    assert fit.status == "failed" and fit.failed
    assert fit.reasons[0] is FitReason.MOST_POLARITY_REJECTED
    assert "70 of 100 polarity-rejected" in fit.status_message
    assert fit.status_message.startswith(
        "failed: most vertices see the gradient the wrong way")
    assert "are the normals pointing to the bright side?" in _warnings(caplog)[0].getMessage()


def test_seed_on_the_window_edge_fails(products, scene, caplog):
    caplog.set_level(logging.WARNING, logger="dtalign")
    fit = _fit(products, scene, search_window_vu=(2, 2))
    assert fit.at_window_edge
    assert fit.status == "failed" and FitReason.AT_WINDOW_EDGE in fit.reasons
    assert "widen search_window_vu" in _warnings(caplog)[0].getMessage()


def test_not_converged_is_a_note_logged_at_info(products, scene, caplog):
    caplog.set_level(logging.INFO, logger="dtalign")
    fit = _fit(products, scene, max_iterations=2)
    assert not fit.lm.converged and not fit.settled
    assert fit.reasons == (FitReason.NOT_CONVERGED,) and fit.status == "ok"
    assert "last 2 of 2 iterations" in fit.status_message
    assert not _warnings(caplog)
    assert any(r.levelno == logging.INFO and "not converged" in r.getMessage()
               for r in caplog.records)


def test_rank_deficient_ring_is_a_note():
    nav = scenes.navigation_scene(shape=(512, 512), radius=80.0)
    products = prepare_image(nav.image, nav.noise_sigma)
    ring = nav.polylines[2]
    fit = fit_polyline_products(products, ring.vertices_vu, ring.normals_vu, ring.sigmas,
                                search_window_vu=(12, 12), max_iterations=200)
    assert FitReason.RANK_DEFICIENT in fit.reasons and fit.status == "ok"
    assert "observable rank 1 of 2" in fit.status_message


def test_status_values_are_documented_strings():
    # in order of severity; "ambiguous": a rival basin across the edge
    assert [s.value for s in FitStatus] == ["ok", "suspect", "ambiguous", "failed"]
    assert {r.value for r in FitReason} == {
        "degenerate", "all_polarity_rejected", "at_window_edge", "most_polarity_rejected",
        "ambiguous", "not_converged", "ambiguous_along_edge", "rank_deficient",
        # the profile refinement's
        "profile_rejected", "soft_edge", "flat_profile_vertices", "profile_misfit",
        # a declared terminator's
        "terminator_without_profile", "terminator_imprecise", "night_side_lit",
        # vertices outside the image
        "outside_image", "outside_image_weighted", "partly_outside_image",
        # vertices on the image's bad pixels
        "masked_pixels",
    }
    assert str(FitReason.DEGENERATE) == "degenerate" and FitStatus.FAILED == "failed"


def test_to_dict_carries_the_status(products, scene):
    d = _fit(products, scene, normals=np.zeros_like(scene.polyline.normals_vu)).to_dict()
    assert d["status"] == "failed"
    # the likeliest cause first
    assert d["reasons"] == ["all_polarity_rejected", "degenerate"]
    json.dumps(d)


def test_drop_in_functions_stay_silent(products, scene, caplog):
    caplog.set_level(logging.DEBUG, logger="dtalign")
    p = scene.polyline
    result = dtalign.lm_subpixel_refine(
        vertices_vu=p.vertices_vu, normals_vu=-p.normals_vu, sigma_normal_per_vertex_px=p.sigmas,
        image_edge_dt=products.edge_dt, image_gradient_vu=products.gradient_vu,
        initial_offset_vu=(3.0, -2.0),
    )
    assert result.degenerate
    assert not [r for r in caplog.records if r.name.startswith("dtalign")]


def test_fit_many_reports_each_bad_polyline(products, scene, caplog):
    caplog.set_level(logging.WARNING, logger="dtalign")
    p = scene.polyline
    good = (p.vertices_vu, p.normals_vu, p.sigmas)
    bad = (p.vertices_vu, np.zeros_like(p.normals_vu), p.sigmas)  # no vertex can match
    fits = fit_many(products, [good, bad, good], search_window_vu=(8, 8), workers=2)
    assert [f.status for f in fits] == ["ok", "failed", "ok"]
    (record,) = _warnings(caplog)
    assert record.getMessage().startswith("polylines[1] failed")


def test_fit_images_reports_in_the_calling_process(scene, caplog):
    caplog.set_level(logging.WARNING, logger="dtalign")
    p = scene.polyline
    flipped = Polyline("zero", p.vertices_vu, np.zeros_like(p.normals_vu), p.sigmas)
    items = [(scene.image, scene.noise_sigma, [p]), (scene.image, scene.noise_sigma, [p, flipped])]
    out = fit_images(items, search_window_vu=(8, 8), workers=2)
    assert [[f.status for f in fits] for fits in out] == [["ok"], ["ok", "failed"]]
    (record,) = _warnings(caplog)
    assert record.getMessage().startswith("items[1].polylines[1] failed")


@pytest.mark.parametrize("call", ["fit_many", "fit_images"])
def test_batch_warnings_are_logged_off_the_calling_thread(scene, products, caplog, call):
    """The calling thread only waits: logging drops an exception raised inside
    a handler's emit, so a timeout landing there while the batch logged its
    warnings was lost (the call returned as if no signal had come)."""
    caplog.set_level(logging.WARNING, logger="dtalign")
    p = scene.polyline
    bad = (p.vertices_vu, np.zeros_like(p.normals_vu), p.sigmas)
    good = (p.vertices_vu, p.normals_vu, p.sigmas)
    if call == "fit_many":
        fit_many(products, [good, bad], search_window_vu=(8, 8), workers=2)
    else:
        fit_images([(scene.image, scene.noise_sigma, [good, bad])], search_window_vu=(8, 8),
                   workers=2)
    (record,) = _warnings(caplog)
    assert record.threadName != threading.main_thread().name
    assert threading.current_thread() is threading.main_thread()


@pytest.mark.skipif(not hasattr(signal, "setitimer"), reason="POSIX interval timers")
def test_a_timeout_while_waiting_for_a_process_pool_is_not_an_images_error(scene):
    """On a process pool the calling thread waits on the images'
    futures; a handler's exception raised in that wait propagates, even with
    ``errors="collect"`` (it used to be collected as that image's error).

    CPython loses a handler's exception raised inside a gc or weakref
    callback (Hypothesis installs a gc callback in this process): such a
    trial is reported as unraisable and tried again.
    """

    class Timeout(Exception):
        pass

    handled = []

    def on_alarm(signum, frame):
        handled.append(frame)
        raise Timeout

    p = scene.polyline
    items = [(scene.image, scene.noise_sigma, [p])] * 40  # long enough to be waited on
    lost = []
    previous = signal.signal(signal.SIGALRM, on_alarm)
    hook, sys.unraisablehook = sys.unraisablehook, lambda u: lost.append(u.exc_type)
    # A pool of the caller's, started beforehand: an alarm inside a pool's
    # own start-up is another case (its shutdown raises "cannot join thread
    # before it is started"), tested below for the pool fit_images starts.
    pool = concurrent.futures.ProcessPoolExecutor(2)
    try:
        pool.submit(int).result()
        for _ in range(5):
            del handled[:], lost[:]
            signal.setitimer(signal.ITIMER_REAL, 0.05)
            try:
                out = fit_images(items, search_window_vu=(8, 8), executor=pool,
                                 errors="collect")
            except Timeout:
                break
            finally:
                signal.setitimer(signal.ITIMER_REAL, 0)
            # returned: never with the timeout as an image's error, and only
            # when CPython lost it in a callback
            assert not any(isinstance(r, Timeout) for r in out)
            assert handled and Timeout in lost, f"returned; handler ran: {bool(handled)}"
        else:
            pytest.fail("the timeout was lost in a callback in every trial")
    finally:
        sys.unraisablehook = hook
        signal.signal(signal.SIGALRM, previous)
        pool.shutdown(wait=True, cancel_futures=True)


# --------------------------------------------------------------------------- CLI


def _python_m(*argv, cwd):
    env = dict(os.environ)
    src = str(Path(dtalign.__file__).resolve().parents[1])
    env["PYTHONPATH"] = src + os.pathsep + env.get("PYTHONPATH", "")
    return subprocess.run([sys.executable, "-m", "dtalign", *argv], capture_output=True,
                          text=True, cwd=cwd, env=env, timeout=300)


@pytest.fixture(scope="module")
def files(tmp_path_factory, scene):
    d = tmp_path_factory.mktemp("status_cli")
    np.save(d / "disc.npy", scene.image)
    p = scene.polyline
    save_polyline_csv(d / "disc.csv", p)
    save_polyline_csv(d / "flipped.csv", Polyline("flipped", p.vertices_vu, -p.normals_vu, p.sigmas))
    save_polyline_csv(d / "zero.csv", Polyline("zero", p.vertices_vu, 0 * p.normals_vu, p.sigmas))
    return d


def test_cli_exits_3_and_prints_the_reason_when_a_fit_failed(files):
    proc = _python_m("fit", "disc.npy", "zero.csv", "--window", "8", cwd=files)
    assert proc.returncode == 3, proc.stderr
    status = [line for line in proc.stdout.splitlines() if line.startswith("status")]
    assert len(status) == 1 and "failed" in status[0] and "polarity-rejected" in status[0]
    assert "dtalign: warning: disc.npy: fit failed" in proc.stderr
    assert "1 of 1 fit(s) failed" in proc.stderr


def test_cli_batch_exits_3_with_the_reason_on_the_fit_line(files):
    proc = _python_m("fit", "disc.npy", "disc.csv", "disc.npy", "zero.csv", "--window", "8",
                     "--no-progress", cwd=files)
    assert proc.returncode == 3, proc.stderr
    rows = [line for line in proc.stdout.splitlines() if line.startswith("disc.npy")]
    assert len(rows) == 2
    assert rows[0].split("  ")[-1].startswith("ok")
    assert "failed (all_polarity_rejected, degenerate)" in rows[1]


def test_cli_exits_3_when_the_normals_are_flipped(files):
    """Flipped normals: the polarity-weighted seed finds a shift where a few
    vertices agree, but most vertices are rejected. The pose is not a
    measurement, so it is ``failed`` (exit 3, not ``suspect``'s 4), the
    polarity reason first and no offset presented."""
    proc = _python_m("fit", "disc.npy", "flipped.csv", "--window", "8", cwd=files)
    assert proc.returncode == 3, proc.stderr
    assert "fit failed: most vertices see the gradient the wrong way" in proc.stderr
    assert "are the normals pointing to the bright side?" in proc.stderr
    (offset,) = [line for line in proc.stdout.splitlines() if line.startswith("offset")]
    assert "not measured" in offset and "±" not in offset


def test_cli_exits_4_when_a_fit_is_ambiguous(tmp_path):
    """Two parallel edges of one polarity: a rival basin fits as well."""
    from dtalign.robustness import parallel_rings

    sc = parallel_rings(0)
    np.save(tmp_path / "rings.npy", sc.image)
    save_polyline_csv(tmp_path / "rings.csv", sc.polyline)
    proc = _python_m("fit", "rings.npy", "rings.csv", "--no-polarity", cwd=tmp_path)
    assert proc.returncode == 4, proc.stderr
    assert "suspect or ambiguous" in proc.stderr
    # the status names itself once (not "ambiguous: ambiguous: a rival ...")
    (status,) = [line for line in proc.stdout.splitlines() if line.startswith("status")]
    assert "ambiguous: a rival basin" in status and "ambiguous: ambiguous" not in status


def test_cli_exits_0_for_a_sound_fit(files):
    proc = _python_m("fit", "disc.npy", "disc.csv", "--window", "8", "--json", cwd=files)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["status"] == "ok"
    assert "warning" not in proc.stderr


def test_an_interrupt_while_the_process_pool_starts_is_the_callers(scene, monkeypatch):
    """An interrupt that lands in ``Thread.start``'s wait for the pool's manager
    thread used to surface as the pool's shutdown error ("cannot join thread
    before it is started"); it propagates, and the worker processes stop."""
    import concurrent.futures.process as cfp
    import multiprocessing

    real_start = cfp._ExecutorManagerThread.start
    timers = []

    def interrupted_start(thread):
        # the thread starts a moment later, as after an interrupted wait
        timer = threading.Timer(0.2, real_start, (thread,))
        timers.append(timer)
        timer.start()
        raise KeyboardInterrupt

    before = set(multiprocessing.active_children())
    monkeypatch.setattr(cfp._ExecutorManagerThread, "start", interrupted_start)
    p = scene.polyline
    items = [(scene.image, scene.noise_sigma, [p])] * 2
    with pytest.raises(KeyboardInterrupt):
        fit_images(items, search_window_vu=(8, 8), workers=2, executor="process")
    assert timers and not timers[0].is_alive()  # the shutdown waited for the start
    deadline = time.monotonic() + 30
    while set(multiprocessing.active_children()) - before and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not set(multiprocessing.active_children()) - before, "worker processes left running"
