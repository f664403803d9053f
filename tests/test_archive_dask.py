"""dtalign.archive on a real Dask LocalCluster (worker processes, no mocks).

Every test compares the store with a serial run of the public pipeline,
item by item: each stored row equals the serial fit bit for bit, every
item is stored exactly once, and nothing that finished is missing. The
faults: a worker process killed while it holds tasks, a missing and a
corrupt image, Ctrl-C on the command line, and resumption.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

distributed = pytest.importorskip("distributed")
pytest.importorskip("pyarrow")

from dtalign import io, pipeline  # noqa: E402
from dtalign.archive import Store, make_example, read_manifest, run, write_manifest  # noqa: E402
from dtalign.archive.runner import (  # noqa: E402
    LOCAL_CLUSTER_CONFIG,
    _nanny_environ_restored,
    local_cluster,
)
from dtalign.archive.tasks import _status  # noqa: E402
from dtalign.cli import main  # noqa: E402

#: Bounds every wait on the cluster: far above what a loaded 2-core machine needs.
TIMEOUT_S = 120


@pytest.fixture(scope="module")
def cluster():
    """Two worker processes of one thread each, the LocalCluster ``dtalign archive`` starts
    (the variables a nanny sets again to replace a killed worker are put back at the end)."""
    with _nanny_environ_restored(), local_cluster(2) as c, distributed.Client(c) as client:
        yield c, client


def _worker_settings():
    """A worker's Dask settings, and its environment where they are environment variables."""
    import dask

    prefix = "distributed.nanny.pre-spawn-environ."
    return {k: os.environ.get(k[len(prefix):]) if k.startswith(prefix) else dask.config.get(k)
            for k in LOCAL_CLUSTER_CONFIG}


def _environ():
    """The calling process's environment (a worker's, through ``client.run``)."""
    return dict(os.environ)


def _expected_settings():
    prefix = "distributed.nanny.pre-spawn-environ."
    return {k: os.environ.get(k[len(prefix):], str(v)) if k.startswith(prefix) else v
            for k, v in LOCAL_CLUSTER_CONFIG.items()}


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    """Four synthetic frames (three polylines each), plus a missing and a corrupt image."""
    return make_example(tmp_path_factory.mktemp("frames"), frames=4, size=256, broken=True)


def campaign(frames, path, n, *, broken=False, noise=True):
    """A manifest of ``n`` items cycling over the example's frames (ids i000, i001, ...)."""
    base = [r for r in read_manifest(frames) if r.id not in ("missing", "corrupt")]
    records = []
    for k in range(n):
        src = base[k % len(base)]
        rec = {"id": f"i{k:03d}", "image": src.image_path, "polylines": list(src.polyline_paths),
               "options": src.options}
        if noise:
            rec["noise_sigma"] = src.noise_sigma
        records.append(rec)
    if broken:
        for item in read_manifest(frames):
            if item.id in ("missing", "corrupt"):
                records.append({"id": item.id, "image": item.image_path,
                                "polylines": list(item.polyline_paths)})
    return write_manifest(path, records)


_serial_cache: dict = {}


def serial_fits(item):
    """The serial loop: the public pipeline on one item (cached per distinct item)."""
    key = (item.image_path, item.polyline_paths, item.noise_sigma, item.window,
           tuple(sorted(item.options.items())))
    if key not in _serial_cache:
        products = pipeline.prepare_image(io.load_image(item.image_path), item.noise_sigma)
        fits = []
        for p in item.polyline_paths:
            poly = io.load_polyline_csv(p)
            fits.append(pipeline.fit_polyline_products(
                products, poly.vertices_vu, poly.normals_vu, poly.sigmas,
                search_window_vu=item.window, **item.options))
        _serial_cache[key] = fits
    return _serial_cache[key]


def assert_store_matches_serial(store_path, manifest, *, expect_all=True):
    """Each stored row equals the serial fit; each item is stored once, whole; returns the ids."""
    items = {i.id: i for i in read_manifest(manifest)}
    t = Store(store_path).results().to_pylist()
    keys = [(r["item_id"], r["polyline_index"]) for r in t]
    assert len(keys) == len(set(keys)), "a row was written twice"
    by_item: dict[str, list] = {}
    for r in t:
        by_item.setdefault(r["item_id"], []).append(r)
    for item_id, rows in by_item.items():
        item = items[item_id]
        fits = serial_fits(item)
        assert sorted(r["polyline_index"] for r in rows) == list(range(len(fits))), item_id
        for r in rows:
            fit = fits[r["polyline_index"]]
            cov = np.asarray(fit.covariance)
            assert r["polyline"] == item.polylines[r["polyline_index"]]
            assert (r["offset_v"], r["offset_u"]) == fit.offset_vu, item_id
            assert r["rotation_rad"] == fit.rotation_rad
            assert (r["sigma_v"], r["sigma_u"]) == fit.sigma_vu
            assert (r["cov_vv"], r["cov_vu"], r["cov_uu"]) == (cov[0, 0], cov[0, 1], cov[1, 1])
            assert (r["coarse_dv"], r["coarse_du"]) == fit.coarse_offset_vu
            assert r["iterations"] == fit.lm.iterations and r["rms_px"] == fit.lm.rms_px
            assert r["inlier_count"] == fit.lm.inlier_count
            assert r["noise_sigma"] == fit.noise_sigma
            assert r["item_fingerprint"] == item.fingerprint
            assert (r["status"], r["reasons"]) == _status(fit)
    good = {k for k, i in items.items() if k not in ("missing", "corrupt")}
    if expect_all:
        assert set(by_item) == good
    return set(by_item)


# --------------------------------------------------------------------------- runs


def test_run_stores_every_item_once_and_records_bad_images(cluster, frames, tmp_path):
    _, client = cluster
    manifest = campaign(frames, tmp_path / "m.jsonl", 12, broken=True)
    store = tmp_path / "store"
    summary = run(manifest, store, client, progress=False, flush_items=5)
    assert (summary.done, summary.failed, summary.rows) == (12, 2, 36)
    assert summary.store_parts >= 3 and not summary.interrupted
    assert_store_matches_serial(store, manifest)
    failures = {r["item_id"]: r for r in Store(store).failures().to_pylist()}
    assert set(failures) == {"missing", "corrupt"}
    assert failures["missing"]["error_type"] == "FileNotFoundError"
    assert "missing.npy" in failures["missing"]["error"]
    assert "corrupt.npy" in failures["corrupt"]["error"]
    workers = set(Store(store).results(["worker"])["worker"].to_pylist())
    assert workers <= set(client.nthreads())

    # Resumption: nothing to do; failed items stay failed until asked.
    again = run(manifest, store, client, progress=False)
    assert (again.submitted, again.skipped_done, again.skipped_failed) == (0, 12, 2)
    missing = read_manifest(manifest)[-2]
    shutil.copy(read_manifest(frames)[0].image_path, missing.image_path)
    try:
        retry = run(manifest, store, client, progress=False, retry_failed=True)
    finally:
        os.unlink(missing.image_path)
    assert (retry.submitted, retry.done, retry.failed) == (2, 1, 1)
    assert Store(store).failed_ids() == {"corrupt"}
    assert len(Store(store).failures(open_only=False)) == 3  # the history stays
    rows = Store(store).results().to_pylist()
    assert sum(r["item_id"] == "missing" for r in rows) == 3


def test_tasks_of_several_items_store_the_same(cluster, frames, tmp_path):
    """items_per_task: good and bad images share tasks; each item is stored once, as serially."""
    _, client = cluster
    manifest = campaign(frames, tmp_path / "m.jsonl", 10, broken=True)
    store = tmp_path / "store"
    summary = run(manifest, store, client, progress=False, flush_items=4, items_per_task=5)
    assert (summary.done, summary.failed, summary.rows) == (10, 2, 30)
    assert_store_matches_serial(store, manifest)
    assert Store(store).failed_ids() == {"missing", "corrupt"}
    with pytest.raises(ValueError, match="items_per_task must be an int >= 1"):
        run(manifest, tmp_path / "other", client, progress=False, items_per_task=0)


def test_default_tasks_hold_a_few_items(cluster, frames, tmp_path):
    """Without items_per_task a run puts 4 items in a task (34 items on 2 workers: the last
    task holds 2), and stores every item once, as serially."""
    _, client = cluster
    manifest = campaign(frames, tmp_path / "m.jsonl", 34)
    summary = run(manifest, tmp_path / "store", client, progress=False)
    assert (summary.items_per_task, summary.done, summary.failed) == (4, 34, 0)
    assert "4 item(s) a task" in str(summary)
    assert_store_matches_serial(tmp_path / "store", manifest)


def test_resume_runs_only_the_missing_items(cluster, frames, tmp_path):
    _, client = cluster
    manifest = campaign(frames, tmp_path / "m.jsonl", 10)
    items = read_manifest(manifest)
    store = tmp_path / "store"
    first = run(items[:4], store, client, progress=False)
    assert first.done == 4
    second = run(manifest, store, client, progress=False)
    assert (second.skipped_done, second.submitted, second.done) == (4, 6, 6)
    assert_store_matches_serial(store, manifest)
    run_ids = {r["item_id"]: r["run_id"] for r in Store(store).results().to_pylist()}
    assert {run_ids[i.id] for i in items[:4]} == {first.run_id}
    assert {run_ids[i.id] for i in items[4:]} == {second.run_id}


def test_store_made_with_other_settings_is_refused(cluster, frames, tmp_path):
    _, client = cluster
    manifest = campaign(frames, tmp_path / "m.jsonl", 2)
    run(manifest, tmp_path / "store", client, progress=False)
    with pytest.raises(ValueError, match="different manifest entry"):
        run(read_manifest(manifest, window=12), tmp_path / "store", client, progress=False)


def test_a_cluster_of_its_own_leaves_the_environment_as_it_was(frames, tmp_path, monkeypatch):
    """Dask's nannies set their workers' variables (OMP_NUM_THREADS=1, malloc settings,
    PYTHONHASHSEED) in this process's environment; they are put back, a user's value
    included, once the workers run and once run()'s own cluster closes."""
    for name in ("MALLOC_TRIM_THRESHOLD_", "MALLOC_MMAP_THRESHOLD_", "PYTHONHASHSEED",
                 "__DASK_PARENT_PID", "MKL_NUM_THREADS"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("OMP_NUM_THREADS", "3")  # the user's own: the workers take it
    before = dict(os.environ)
    with local_cluster(1) as c, distributed.Client(c) as client:
        assert dict(os.environ) == before
        worker_env = client.run(_environ).popitem()[1]
        assert (worker_env["OMP_NUM_THREADS"], worker_env["MALLOC_TRIM_THRESHOLD_"]) == (
            "3", str(2**30))
    manifest = campaign(frames, tmp_path / "m.jsonl", 2)
    assert run(manifest, tmp_path / "store", workers=1, progress=False).done == 2
    assert dict(os.environ) == before


def test_cli_on_an_existing_scheduler(cluster, frames, tmp_path, capsys):
    c, _ = cluster
    manifest = campaign(frames, tmp_path / "m.jsonl", 4, broken=True)
    argv = ["archive", str(manifest), "--out", str(tmp_path / "store"),
            "--scheduler", c.scheduler_address, "--no-progress"]
    assert main(argv) == 1  # two items failed
    out, err = capsys.readouterr()
    # "in error" for items: "failed" is a fit's status, not an item's
    assert "4 item(s) done, 2 item(s) in error (12 result rows)" in out
    assert "FAILED missing: image file not found" in err
    assert_store_matches_serial(tmp_path / "store", manifest)
    assert main([*argv, "--workers", "2"]) == 1
    assert "--workers starts a local cluster" in capsys.readouterr().err
    # No failed item: 3 exactly when some stored fit's status is "failed", as dtalign fit.
    good = campaign(frames, tmp_path / "good.jsonl", 4)
    code = main(["archive", str(good), "--out", str(tmp_path / "good"),
                 "--scheduler", c.scheduler_address, "--no-progress"])
    statuses = Store(tmp_path / "good").results(["status"])["status"].to_pylist()
    assert len(statuses) == 12
    assert code == (3 if "failed" in statuses else 0)


# --------------------------------------------------------------------------- faults


@pytest.mark.parametrize("per_task", [1, 3])
def test_killed_worker_costs_only_its_tasks(cluster, frames, tmp_path, per_task):
    """Kill one worker process while it holds tasks: they are retried, nothing else is lost."""
    _, client = cluster
    manifest = campaign(frames, tmp_path / "m.jsonl", 80, noise=False)
    store = tmp_path / "store"
    killed: dict = {}

    def killer():
        deadline = time.monotonic() + TIMEOUT_S
        while time.monotonic() < deadline and not killed:
            if not Store(store).parts():  # wait until results flow
                time.sleep(0.02)
                continue
            pids = client.run(os.getpid)
            for address, pid in pids.items():
                if not client.processing([address]).get(address):
                    continue
                # Freeze it, let messages already sent land, then read what it
                # still holds: a stopped process can finish nothing more.
                os.kill(pid, signal.SIGSTOP)
                time.sleep(0.5)
                held = client.processing([address]).get(address, ())
                if not held:
                    os.kill(pid, signal.SIGCONT)
                    continue
                os.kill(pid, signal.SIGKILL)
                killed.update(address=address, keys=list(held), at=time.time())
                break
            time.sleep(0.01)

    thread = threading.Thread(target=killer, daemon=True)
    thread.start()
    summary = run(manifest, store, client, progress=False, flush_items=1,
                  items_per_task=per_task)
    thread.join(TIMEOUT_S)
    assert killed, "the run ended before a worker could be killed"
    assert (summary.done, summary.failed) == (80, 0)
    assert_store_matches_serial(store, manifest)
    rows = Store(store).results().to_pylist()
    finisher = {r["item_id"]: r["worker"] for r in rows}
    # keys are dtalign-fit-<run>-<index of the task's first item>: the items the dead worker held
    first = [int(str(k).rsplit("-", 1)[1]) for k in killed["keys"]]
    held = {f"i{i:03d}" for f in first for i in range(f, min(f + per_task, 80))}
    assert held and all(finisher[i] != killed["address"] for i in held)
    after = [r for r in rows if r["worker"] == killed["address"]
             and r["finished_at"].timestamp() > killed["at"]]
    assert after == []
    assert client.wait_for_workers(2, timeout=TIMEOUT_S) is None  # the nanny replaced it
    # ...with the cluster's Dask settings, as the workers it started with
    settings = client.run(_worker_settings)
    assert killed["address"] not in settings and len(settings) == 2
    assert all(v == _expected_settings() for v in settings.values()), settings


def test_rows_still_on_a_killed_worker_are_computed_again(cluster, frames, tmp_path):
    """Rows wait on their worker until their part is fetched: a worker killed while it holds
    finished tasks' rows loses none of them (Dask computes them again elsewhere)."""
    _, client = cluster
    # 60 items: the kill comes once a worker holds 2 finished tasks, long before the end.
    manifest = campaign(frames, tmp_path / "m.jsonl", 60, noise=False)
    store = tmp_path / "store"
    killed: dict = {}

    def killer():
        deadline = time.monotonic() + TIMEOUT_S
        while time.monotonic() < deadline and not killed:
            for address, keys in client.has_what().items():  # keys in each worker's memory
                ours = [k for k in keys if str(k).startswith("dtalign-fit-")]
                if len(ours) >= 2:
                    pid = client.run(os.getpid, workers=[address])[address]
                    os.kill(pid, signal.SIGKILL)
                    killed.update(address=address, keys=ours)
                    break
            time.sleep(0.005)

    thread = threading.Thread(target=killer, daemon=True)
    thread.start()
    # One part at the end: every finished task's rows stay on its worker until then.
    summary = run(manifest, store, client, progress=False, flush_items=1000,
                  flush_seconds=1000.0, items_per_task=1)
    thread.join(TIMEOUT_S)
    assert killed, "the run ended before a worker held finished rows"
    assert (summary.done, summary.failed, summary.store_parts) == (60, 0, 1)
    assert_store_matches_serial(store, manifest)
    finisher = {r["item_id"]: r["worker"] for r in Store(store).results().to_pylist()}
    lost = {f"i{int(str(k).rsplit('-', 1)[1]):03d}" for k in killed["keys"]}
    assert all(finisher[i] != killed["address"] for i in lost)
    assert client.wait_for_workers(2, timeout=TIMEOUT_S) is None  # the nanny replaced it


def test_ctrl_c_stops_cleanly_and_the_rerun_completes(cluster, frames, tmp_path):
    """SIGINT to the command's process group (as Ctrl-C in a terminal): exit 130, every
    finished item stored once, whole; the same command then completes the campaign."""
    _, client = cluster
    manifest = campaign(frames, tmp_path / "m.jsonl", 200, noise=False)
    store = tmp_path / "store"
    cmd = [sys.executable, "-m", "dtalign", "archive", str(manifest), "--out", str(store),
           "--workers", "2", "--flush-every", "1", "--no-progress"]
    # SIGINT at its default, as a terminal's program has it: a test run started
    # in the background of a shell has it ignored (POSIX), and the command
    # would inherit that and rightly ignore the Ctrl-C sent below
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        deadline = time.monotonic() + TIMEOUT_S
        while time.monotonic() < deadline and proc.poll() is None:
            if (store / "results").is_dir() and len(Store(store).parts()) >= 3:
                break
            time.sleep(0.02)
        assert proc.poll() is None, proc.communicate()
        os.killpg(proc.pid, signal.SIGINT)
        out, err = proc.communicate(timeout=TIMEOUT_S)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 130, out + err
    assert "interrupted" in err and "Traceback" not in err, err
    stored = assert_store_matches_serial(store, manifest, expect_all=False)
    assert 3 <= len(stored) < 200
    rest = run(manifest, store, client, progress=False)
    assert rest.skipped_done == len(stored) and rest.done == 200 - len(stored)
    assert_store_matches_serial(store, manifest)
