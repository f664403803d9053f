"""dtalign.archive without a cluster: the manifest, the store's atomic parts, the task body,
and that the rest of the package never imports Dask."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from dtalign import io, pipeline
from dtalign.archive import Item, Store, StoreBusyError, fit_item, make_example, read_manifest
from dtalign.archive.manifest import write_manifest

pa = pytest.importorskip("pyarrow")
pq = pytest.importorskip("pyarrow.parquet")


@pytest.fixture(scope="module")
def example(tmp_path_factory):
    d = tmp_path_factory.mktemp("archive-example")
    return make_example(d, frames=2, size=192, broken=True)


# --------------------------------------------------------------------------- imports


def test_package_imports_no_dask():
    code = (
        "import sys, dtalign, dtalign.pipeline, dtalign.pipeline.batch, dtalign.cli, dtalign.archive\n"
        "dtalign.cli.build_parser()\n"
        "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('dask', 'distributed'))\n"
        "print(bad)\n"
        "sys.exit(1 if bad else 0)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr


# --------------------------------------------------------------------------- manifest


def test_manifest_jsonl_resolves_paths_and_merges_defaults(tmp_path):
    path = write_manifest(tmp_path / "m.jsonl", [
        {"image": "a.npy", "polylines": "a.csv"},
        {"id": "b", "image": "/abs/b.npy", "polylines": ["b1.csv", "b2.csv"], "noise_sigma": 2.5,
         "window": [10, 20], "options": {"fit_rotation": True}},
    ])
    a, b = read_manifest(path, window=12, options={"trust_region_px": 1.0})
    assert a.id == "a.npy" and a.polylines == ("a.csv",)
    assert a.image_path == str(tmp_path.resolve() / "a.npy")
    assert a.window == (12, 12) and a.noise_sigma is None
    assert a.options == {"trust_region_px": 1.0}
    assert b.image_path == "/abs/b.npy" and b.polylines == ("b1.csv", "b2.csv")
    assert b.window == (10, 20) and b.noise_sigma == 2.5
    assert b.options == {"trust_region_px": 1.0, "fit_rotation": True}


def test_manifest_csv(tmp_path):
    (tmp_path / "m.csv").write_text(
        "# a campaign\n"
        "id,image,polylines,noise_sigma,window,options\n"
        'f0,f0.npy,f0-a.csv;f0-b.csv,2.0,30 20,"{""use_polarity"": false}"\n'
        "f1,f1.npy,f1.csv,,,\n"
    )
    f0, f1 = read_manifest(tmp_path / "m.csv")
    assert f0.polylines == ("f0-a.csv", "f0-b.csv") and f0.window == (30, 20)
    assert f0.noise_sigma == 2.0 and f0.options == {"use_polarity": False}
    assert f1.window == (30, 30) and f1.noise_sigma is None and f1.options == {}


@pytest.mark.parametrize(("line", "fragment"), [
    ('{"polylines": "a.csv"}', "image must be a non-empty path"),
    ('{"image": "a.npy"}', "polylines is missing"),
    ('{"image": "a.npy", "polylines": []}', "one or more non-empty paths"),
    ('{"image": "a.npy", "polylines": "a.csv", "colour": 1}', "unknown field(s) 'colour'"),
    ('{"image": "a.npy", "polylines": "a.csv", "options": {"speed": 2}}', "unknown fit option(s) 'speed'"),
    ('{"image": "a.npy", "polylines": "a.csv", "window": [1, 2, 3]}', "window must be"),
    ('{"image": "a.npy", "polylines": "a.csv", "window": -1}', "window must be non-negative"),
    ('{"image": "a.npy", "polylines": "a.csv", "noise_sigma": -1}', "noise_sigma must be finite"),
    ('{"image": "a.npy", "polylines": "a.csv", "config": {"blur": 1}}', "unknown config field(s)"),
    ('{"image": "a.npy", "polylines": "a.csv"', "not JSON"),
    ('[1, 2]', "a record must be an object"),
])
def test_manifest_errors_name_the_line(tmp_path, line, fragment):
    path = tmp_path / "m.jsonl"
    path.write_text('{"image": "ok.npy", "polylines": "ok.csv"}\n\n' + line + "\n")
    with pytest.raises(ValueError, match="line 3") as info:
        read_manifest(path)
    assert fragment in str(info.value)


def test_manifest_duplicate_ids_and_empty(tmp_path):
    path = tmp_path / "m.jsonl"
    path.write_text('{"image": "a.npy", "polylines": "a.csv"}\n{"id": "a.npy", "image": "b.npy", '
                    '"polylines": "b.csv"}\n')
    with pytest.raises(ValueError, match="duplicate id 'a.npy' \\(first on line 1\\)"):
        read_manifest(path)
    (tmp_path / "e.jsonl").write_text("# nothing\n")
    with pytest.raises(ValueError, match="has no items"):
        read_manifest(tmp_path / "e.jsonl")
    with pytest.raises(FileNotFoundError, match="manifest not found"):
        read_manifest(tmp_path / "nope.jsonl")
    (tmp_path / "m.txt").write_text("x\n")
    with pytest.raises(ValueError, match="unknown format"):
        read_manifest(tmp_path / "m.txt")


def test_fingerprint_follows_what_the_item_asks_for(tmp_path):
    path = write_manifest(tmp_path / "m.jsonl", [{"image": "a.npy", "polylines": "a.csv"}])
    (a,) = read_manifest(path)
    (same,) = read_manifest(path)
    (wider,) = read_manifest(path, window=40)
    (other,) = read_manifest(path, options={"fit_rotation": True})
    assert a.fingerprint == same.fingerprint
    assert len({a.fingerprint, wider.fingerprint, other.fingerprint}) == 3


# --------------------------------------------------------------------------- task body


def test_fit_item_matches_the_public_pipeline(example):
    from dtalign.archive.tasks import _status

    items = read_manifest(example)
    item = items[0]
    out = fit_item(item, "r1")
    assert out["failure"] is None and len(out["results"]) == 3
    image = io.load_image(item.image_path)
    products = pipeline.prepare_image(image, item.noise_sigma)
    for row, path in zip(out["results"], item.polyline_paths, strict=True):
        poly = io.load_polyline_csv(path)
        fit = pipeline.fit_polyline_products(
            products, poly.vertices_vu, poly.normals_vu, poly.sigmas,
            search_window_vu=item.window, **item.options)
        cov = np.asarray(fit.covariance)
        assert (row["offset_v"], row["offset_u"]) == fit.offset_vu
        assert (row["cov_vv"], row["cov_vu"], row["cov_uu"]) == (cov[0, 0], cov[0, 1], cov[1, 1])
        assert row["iterations"] == fit.lm.iterations and row["run_id"] == "r1"
        # recorded when the fit result has a status (None before it does)
        assert row["status"] == _status(fit)[0] and row["reasons"] == _status(fit)[1]


def test_fit_item_records_a_missing_or_corrupt_image(example):
    by_id = {i.id: i for i in read_manifest(example)}
    missing = fit_item(by_id["missing"])
    assert missing["results"] == []
    assert missing["failure"]["stage"] == "read"
    assert missing["failure"]["error_type"] == "FileNotFoundError"
    assert "missing.npy" in missing["failure"]["error"]
    corrupt = fit_item(by_id["corrupt"])["failure"]
    assert corrupt["stage"] == "read" and "corrupt.npy" in corrupt["error"]


def test_fit_item_names_the_polyline_of_a_bad_option(example):
    item = read_manifest(example)[0]
    bad = Item(**{**item.__dict__, "options": {"trust_region_px": -1.0}})
    failure = fit_item(bad)["failure"]
    assert failure["stage"] == "fit" and failure["error_type"] == "ValueError"
    assert item.polylines[0] in failure["error"] and "trust_region_px" in failure["error"]


# --------------------------------------------------------------------------- store


def _rows(item_id, n=2):
    return [{"item_id": item_id, "image": f"{item_id}.npy", "polyline": f"p{k}.csv",
             "polyline_index": k, "offset_v": 1.0 + k, "offset_u": -2.0} for k in range(n)]


def test_store_appends_parts_and_reads_them_back(tmp_path):
    store = Store(tmp_path / "s")
    with store.lock():
        store.append(_rows("a"), [])
        store.append(_rows("b"), [{"item_id": "c", "error": "boom", "polylines": ["x.csv"]}])
    assert len(store.parts("results")) == 2 and len(store.parts("failures")) == 1
    t = store.results()
    assert t.num_rows == 4 and t.schema == store.results().schema
    assert t["item_id"].to_pylist() == ["a", "a", "b", "b"]
    assert store.done_ids() == {"a", "b"} and store.failed_ids() == {"c"}
    # the folders read directly, as pandas.read_parquet("STORE/results") does
    assert pq.read_table(tmp_path / "s" / "results").num_rows == 4


def test_store_retried_item_is_no_longer_failed(tmp_path):
    store = Store(tmp_path / "s")
    store.append([], [{"item_id": "a", "error": "first"}])
    assert store.failed_ids() == {"a"}
    store.append(_rows("a"), [])
    assert store.failed_ids() == set()
    assert store.failures().num_rows == 0
    assert store.failures(open_only=False)["error"].to_pylist() == ["first"]


def test_store_write_interrupted_leaves_no_part(tmp_path, monkeypatch):
    store = Store(tmp_path / "s")
    store.append(_rows("a"), [])

    def crash(table, where, **kw):
        where.write(b"PAR1 half a file")
        raise KeyboardInterrupt

    monkeypatch.setattr(pq, "write_table", crash)
    with pytest.raises(KeyboardInterrupt):
        store.append(_rows("b"), [])
    monkeypatch.undo()
    files = sorted(p.name for p in (tmp_path / "s" / "results").iterdir())
    assert len(files) == 1 and files[0].startswith("part-")
    assert store.done_ids() == {"a"}


def test_store_ignores_and_cleans_a_dead_runs_temporary_file(tmp_path):
    store = Store(tmp_path / "s")
    store.append(_rows("a"), [])
    stale = tmp_path / "s" / "results" / ".tmp-part-123.parquet"
    stale.write_bytes(b"PAR1 torn")
    assert store.results().num_rows == 2
    assert pq.read_table(tmp_path / "s" / "results").num_rows == 2
    with store.lock():
        assert not stale.exists()


def test_store_lock_refuses_a_second_writer(tmp_path):
    with Store(tmp_path / "s").lock():
        with pytest.raises(StoreBusyError, match="another run"):
            with Store(tmp_path / "s").lock():
                pass
    with Store(tmp_path / "s").lock():  # released
        pass


def test_store_path_must_be_a_folder(tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(ValueError, match="not a folder"):
        Store(tmp_path / "f")


def test_make_example_writes_a_manifest_the_reader_accepts(example):
    items = read_manifest(example)
    assert [i.id for i in items] == ["f000", "f001", "missing", "corrupt"]
    for item in items[:2]:
        assert Path(item.image_path).is_file()
        assert all(Path(p).is_file() for p in item.polyline_paths)
    truth = [json.loads(x) for x in (Path(example).parent / "truth.jsonl").read_text().splitlines()]
    assert [t["id"] for t in truth] == ["f000", "f001"]


def test_docs_list_every_store_column():
    from dtalign.archive.store import FAILURE_COLUMNS, RESULT_COLUMNS

    page = (Path(__file__).resolve().parents[1] / "docs" / "campaign.rst")
    if not page.is_file():
        pytest.skip("docs/ not shipped with this install")
    text = page.read_text()
    missing = [name for name, _, _ in RESULT_COLUMNS + FAILURE_COLUMNS if f"``{name}``" not in text]
    assert missing == []


def test_cli_make_example_then_usage_errors(tmp_path, capsys):
    from dtalign.cli import main

    assert main(["archive", "--make-example", str(tmp_path / "c"), "--frames", "1"]) == 0
    out = capsys.readouterr().out
    assert "dtalign archive" in out and (tmp_path / "c" / "manifest.jsonl").is_file()
    assert main(["archive", str(tmp_path / "c" / "manifest.jsonl")]) == 1
    assert "needs MANIFEST and --out STORE" in capsys.readouterr().err
    assert main(["archive", "nope.jsonl", "--out", str(tmp_path / "s")]) == 1
    assert "manifest not found: nope.jsonl" in capsys.readouterr().err


def test_cli_window_is_checked(tmp_path, capsys):
    from dtalign.cli import main

    manifest = write_manifest(tmp_path / "m.jsonl", [{"image": "a.npy", "polylines": "a.csv"}])
    assert main(["archive", str(manifest), "--out", str(tmp_path / "s"), "--window", "x"]) == 1
    assert "--window takes one int or two" in capsys.readouterr().err
    assert main(["archive", str(manifest), "--out", str(tmp_path / "s"), "--window", "1,2,3"]) == 1
    assert "window must be an int or a list of two ints" in capsys.readouterr().err


def test_a_task_logs_no_per_fit_warnings(example, caplog):
    import logging

    from dtalign.archive.tasks import warm_up

    item = read_manifest(example)[0]
    bad = Item(**{**item.__dict__, "window": (1, 1)})  # seeds on the window edge: flagged fits
    with caplog.at_level(logging.INFO, logger="dtalign"):
        rows = fit_item(bad)["results"]
        warm_up()
    assert rows and any(r["status"] not in (None, "ok") for r in rows)
    assert [r for r in caplog.records if r.levelno >= logging.WARNING] == []
    logging.getLogger("dtalign").warning("still reported outside a task")
    assert caplog.records[-1].getMessage() == "still reported outside a task"


def test_cli_exit_codes_agree_with_dtalign_fit():
    from dtalign import cli
    from dtalign.archive import cli as archive_cli

    assert archive_cli.EXIT_FIT_FAILED == cli.EXIT_FIT_FAILED
    assert archive_cli.EXIT_INTERRUPTED == cli.EXIT_INTERRUPTED


@pytest.mark.parametrize(("items", "threads", "expected"), [
    (32, 2, 4),      # the benchmark campaign: 8 tasks of 4 for 2 workers
    (100_000, 64, 4),  # an archive: never more than 4 a task
    (31, 2, 3), (16, 2, 2), (15, 2, 1),  # short campaigns: 4 tasks per worker thread first
    (5, 8, 1), (1, 1, 1),
    (12, 0, 3),      # no workers yet (an adaptive cluster): counted as one thread
])
def test_auto_items_per_task(items, threads, expected):
    from dtalign.archive.runner import auto_items_per_task

    assert auto_items_per_task(items, threads) == expected
