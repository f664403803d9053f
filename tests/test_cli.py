"""The dtalign command line: demo, fit (single, batch, glob), bench, every error path, and
pairs of numbers given as one comma-joined word."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import types
from pathlib import Path

import numpy as np
import pytest

import dtalign
from dtalign import scenes
from dtalign.cli import main
from dtalign.io import save_polyline_csv

TRUE = (3.4, -2.2)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A small disc scene as .npy and .png, and its polyline CSV."""
    d = tmp_path_factory.mktemp("cli")
    scene = scenes.disc_scene(shape=(200, 200), radius=50.0, n_vertices=100, offset_vu=TRUE)
    np.save(d / "disc.npy", scene.image)
    save_polyline_csv(d / "disc.csv", scene.polyline)
    pil = pytest.importorskip("PIL.Image")
    grey = np.clip(np.rint(scene.image + 50.0), 0, 255).astype(np.uint8)
    pil.fromarray(np.dstack([grey] * 3)).save(d / "disc.png")  # RGB with R = G = B
    return d


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def assert_one_line_error(code, err, fragment):
    assert code != 0
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("dtalign: error: ")
    assert fragment in lines[0]
    assert "Traceback" not in err


# --------------------------------------------------------------------------- demo


def test_demo_prints_every_field(capsys):
    code, out, _ = run(capsys, "demo", "--n-vertices", "80")
    assert code == 0
    for field in ("true", "coarse", "fitted", "±", "wall time", "derivatives", "lm"):
        assert field in out
    assert "(7.300, -4.600)" in out


def test_demo_json_rotation_and_plot(capsys, tmp_path):
    pytest.importorskip("matplotlib")
    png = tmp_path / "demo.png"
    code, out, _ = run(capsys, "demo", "--n-vertices", "60", "--rotation", "0.01", "--json", "--plot", str(png))
    assert code == 0
    doc = json.loads(out)
    assert doc["true_rotation_rad"] == 0.01 and doc["fit"]["fit_rotation"] is True
    assert np.allclose(doc["fit"]["offset_vu"], doc["true_offset_vu"], atol=0.5)
    assert png.stat().st_size > 1000


def test_demo_bad_option(capsys):
    code, _, err = run(capsys, "demo", "--n-vertices", "1")
    assert_one_line_error(code, err, "--n-vertices")


# --------------------------------------------------------------------------- fit


@pytest.mark.parametrize("image", ["disc.npy", "disc.png"])
def test_fit_table(capsys, files, image):
    code, out, _ = run(capsys, "fit", str(files / image), str(files / "disc.csv"), "--window", "8")
    assert code == 0
    assert "offset" in out and "rank 2 of 2" in out and "100 vertices" in out


def test_fit_json_recovers_offset(capsys, files):
    code, out, _ = run(
        capsys, "fit", str(files / "disc.npy"), str(files / "disc.csv"),
        "--window", "8,6", "--noise-sigma", "2", "--trust-region", "5", "--json",
    )
    assert code == 0
    doc = json.loads(out)
    assert np.allclose(doc["offset_vu"], TRUE, atol=0.1)
    assert doc["search_window_vu"] == [8, 6] and doc["noise_sigma"] == 2.0


def test_fit_options_rotation_ridge_plot(capsys, files, tmp_path):
    pytest.importorskip("matplotlib")
    png = tmp_path / "fit.png"
    code, out, err = run(
        capsys, "fit", str(files / "disc.npy"), str(files / "disc.csv"), "--window", "8",
        "--rotation", "--ridge", "--tikhonov", "0.001", "--no-polarity", "--plot", str(png),
    )
    assert code == 0, err
    assert "rotation" in out and png.stat().st_size > 1000


def test_batch_continues_past_a_bad_image(capsys, files, tmp_path):
    (tmp_path / "bad.npy").write_bytes(b"not a numpy file")
    (tmp_path / "bad.csv").write_text((files / "disc.csv").read_text())
    listing = tmp_path / "list.txt"
    listing.write_text(
        f"# images to fit\n{files / 'disc.npy'}\nbad.npy\n{files / 'disc.png'} {files / 'disc.csv'}\n"
    )
    code, out, err = run(capsys, "fit", "--batch", str(listing), "--window", "8")
    assert code == 1
    assert "FAILED" in err and "bad.npy" in err and "1 of 3 image(s) failed" in err
    assert out.count(" ok") == 2 and "FAILED" in out
    code, out, _ = run(capsys, "fit", "--batch", str(listing), "--window", "8", "--json")
    assert code == 1
    doc = json.loads(out)
    assert [("error" in r) for r in doc] == [False, True, False]


def test_glob_mode_uses_same_stem_csv(capsys, files):
    code, out, err = run(capsys, "fit", "--glob", str(files / "disc.*"), "--window", "8", "--json")
    assert code == 0, err
    doc = json.loads(out)
    assert len(doc) == 2 and all(np.allclose(r["offset_vu"], TRUE, atol=0.3) for r in doc)


def test_several_pairs_and_plain_progress(capsys, files, monkeypatch):
    monkeypatch.setitem(sys.modules, "tqdm", None)  # tqdm is optional
    code, out, err = run(
        capsys, "fit", str(files / "disc.npy"), str(files / "disc.csv"),
        str(files / "disc.png"), str(files / "disc.csv"), "--window", "8",
    )
    assert code == 0
    assert "[1/2]" in err and "[2/2]" in err and out.count(" ok") == 2


# --------------------------------------------------------------------------- errors


def test_missing_image(capsys, files, tmp_path):
    code, _, err = run(capsys, "fit", str(tmp_path / "nope.npy"), str(files / "disc.csv"))
    assert_one_line_error(code, err, "image file not found")


def test_missing_polyline(capsys, files, tmp_path):
    code, _, err = run(capsys, "fit", str(files / "disc.npy"), str(tmp_path / "nope.csv"))
    assert_one_line_error(code, err, "polyline file not found")


def test_bad_csv_columns(capsys, files, tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("v,u,nv,nu\n1,2,0,1\n")
    code, _, err = run(capsys, "fit", str(files / "disc.npy"), str(bad))
    assert_one_line_error(code, err, "missing column(s) sigma")


@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        ("v,u,nv,nu,sigma\n1,2,0,1\n", "line 2: 4 cell(s)"),
        ("v,u,nv,nu,sigma\n1,2,0,x,1\n", "column nu is not a number"),
        ("v,u,nv,nu,sigma\n1,2,0,1,0\n", "column sigma must be > 0"),
        ("v,u,nv,nu,sigma\n", "no vertex rows"),
        ("", "is empty"),
    ],
)
def test_bad_csv_values(capsys, files, tmp_path, text, fragment):
    bad = tmp_path / "bad.csv"
    bad.write_text(text)
    code, _, err = run(capsys, "fit", str(files / "disc.npy"), str(bad))
    assert_one_line_error(code, err, fragment)


def test_image_shape_mismatch(capsys, files, tmp_path):
    cube = tmp_path / "cube.npy"
    np.save(cube, np.zeros((4, 5, 6)))
    code, _, err = run(capsys, "fit", str(cube), str(files / "disc.csv"))
    assert_one_line_error(code, err, "must be 2-D")


def test_corrupt_image(capsys, files, tmp_path):
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"\x89PNG not really")
    code, _, err = run(capsys, "fit", str(bad), str(files / "disc.csv"))
    assert_one_line_error(code, err, "cannot read image")


@pytest.mark.parametrize(
    ("argv", "fragment"),
    [
        (["fit"], "fit needs IMAGE POLYLINE"),
        (["fit", "a.npy"], "odd number of files"),
        (["fit", "a.npy", "a.csv", "--window", "1,2,3"], "--window takes one or two"),
        (["fit", "a.npy", "a.csv", "--window", "x"], "--window takes ints"),
        (["fit", "a.npy", "a.csv", "--window", "-1"], "non-negative"),
        (["fit", "--glob", "/nonexistent-dir/*.npy"], "no image matches"),
        (["fit", "--batch", "/nonexistent-list.txt"], "batch list not found"),
    ],
)
def test_usage_errors(capsys, argv, fragment):
    code, _, err = run(capsys, *argv)
    assert_one_line_error(code, err, fragment)


def test_argparse_error_exit_status(capsys):
    code, _, err = run(capsys, "fit", "a", "b", "--noise-sigma", "x")
    assert code == 2 and "invalid float value" in err


def test_no_command_prints_help(capsys):
    code, out, _ = run(capsys)
    assert code == 2 and "demo" in out and "fit" in out and "bench" in out


def test_version(capsys):
    code, out, _ = run(capsys, "--version")
    assert code == 0 and dtalign.__version__ in out


# --------------------------------------------------------------------------- bench


def test_bench_passes_arguments_through(capsys, monkeypatch):
    seen = {}
    fake = types.ModuleType("dtalign.benchmarking")

    def fake_main(argv):
        seen["argv"] = argv
        print("| table |")
        return 0

    fake.main = fake_main
    monkeypatch.setitem(sys.modules, "dtalign.benchmarking", fake)
    code, out, _ = run(capsys, "bench", "--quick", "-n", "3")
    assert code == 0 and seen["argv"] == ["--quick", "-n", "3"] and "| table |" in out


def test_bench_without_module(capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "dtalign.benchmarking", None)
    code, _, err = run(capsys, "bench")
    assert_one_line_error(code, err, "benchmarks are not available")


# --------------------------------------------------------------------------- subprocess


def _python_m(*argv, cwd):
    env = dict(os.environ)
    src = str(Path(dtalign.__file__).resolve().parents[1])
    env["PYTHONPATH"] = src + os.pathsep + env.get("PYTHONPATH", "")
    return subprocess.run(
        [sys.executable, "-m", "dtalign", *argv],
        capture_output=True, text=True, cwd=cwd, env=env, timeout=300,
    )


def test_python_m_dtalign_fit_and_error(files, tmp_path):
    proc = _python_m("fit", "disc.npy", "disc.csv", "--window", "8", "--json", cwd=files)
    assert proc.returncode == 0, proc.stderr
    assert np.allclose(json.loads(proc.stdout)["offset_vu"], TRUE, atol=0.1)
    proc = _python_m("fit", "missing.npy", "disc.csv", cwd=files)
    assert proc.returncode == 1
    assert proc.stderr.strip().splitlines() == ["dtalign: error: image file not found: missing.npy"]


# --------------------------------------------------------------------------- overlay


def test_overlay_then_fit_a_cassini_frame(capsys, tmp_path):
    repo = Path(__file__).resolve().parents[1]
    data = Path(os.environ.get("DTALIGN_CASSINI_DIR", repo.parent / "shared" / "data" / "cassini"))
    png = data / "N1634226853_1_CALIB.png"
    if not png.is_file():
        pytest.skip("Cassini frames not present")
    img, csv = tmp_path / "t.npy", tmp_path / "t.csv"
    code, out, err = run(
        capsys, "overlay", str(png), "--shape", "limb", "--displace", "6,-4",
        "--image", str(img), "--polyline", str(csv),
    )
    assert code == 0, err
    assert "vertices on 1 curve(s)" in out
    code, out, err = run(capsys, "fit", str(img), str(csv), "--window", "15", "--json")
    assert code == 0, err
    # The overlay sits within the operator's 1 px of the limb.
    assert np.allclose(json.loads(out)["offset_vu"], (6.0, -4.0), atol=1.0)


def test_overlay_missing_png(capsys, tmp_path):
    code, _, err = run(
        capsys, "overlay", str(tmp_path / "x.png"), "--shape", "limb",
        "--image", str(tmp_path / "i.npy"), "--polyline", str(tmp_path / "p.csv"),
    )
    assert_one_line_error(code, err, "Cassini frame not found")


def test_fits_image(capsys, files, tmp_path, monkeypatch):
    image = np.load(files / "disc.npy")
    path = tmp_path / "disc.fits"
    try:
        from astropy.io import fits
    except ImportError:
        path.write_bytes(b"SIMPLE  =                    T")
        code, _, err = run(capsys, "fit", str(path), str(files / "disc.csv"))
        assert_one_line_error(code, err, "pip install astropy")
        return
    fits.PrimaryHDU(image).writeto(path)
    code, out, _ = run(capsys, "fit", str(path), str(files / "disc.csv"), "--window", "8", "--json")
    assert code == 0 and np.allclose(json.loads(out)["offset_vu"], TRUE, atol=0.1)
    monkeypatch.setitem(sys.modules, "astropy.io", None)
    code, _, err = run(capsys, "fit", str(path), str(files / "disc.csv"))
    assert_one_line_error(code, err, "pip install astropy")


# --------------------------------------------------------------------------- labels


@pytest.mark.parametrize(
    ("pairs", "expected"),
    [
        ([("d/disc.npy", "d/disc.csv"), ("d/disc.png", "d/disc.csv")],
         [("disc.npy", "disc.npy"), ("disc.png", "disc.png")]),
        ([("f.npy", "limb.csv"), ("f.npy", "ring.csv")],
         [("f.npy + limb.csv", "f+limb"), ("f.npy + ring.csv", "f+ring")]),
        ([("a/x/f.npy", "f.csv"), ("b/x/f.npy", "f.csv"), ("g.npy", "g.csv")],
         [("a/x/f.npy", "a_x_f"), ("b/x/f.npy", "b_x_f"), ("g.npy", "g")]),
        ([("f.npy", "f.csv"), ("f.npy", "f.csv")],
         [("f.npy + f.csv#1", "f+f_1"), ("f.npy + f.csv#2", "f+f_2")]),
        ([("my frame.npy", "f.csv")], [("my frame.npy", "my_frame")]),
    ],
)
def test_job_labels_and_plot_names_are_distinct(pairs, expected):
    from dtalign.cli import _Job, _label_jobs

    jobs = [_Job(Path(a), Path(b)) for a, b in pairs]
    _label_jobs(jobs)
    assert [(j.label, j.plot_name) for j in jobs] == expected


# --------------------------------------------------------------------------- compile notice


def _fake_kernels(tmp_path, tag):
    import pickle

    kernels = tmp_path / "_kernels"
    (kernels / "__pycache__").mkdir(parents=True)
    src = kernels / "lm.py"
    src.write_text("# kernel source\n")
    index = kernels / "__pycache__" / "lm.run-10.py311.nbi"
    index.write_bytes(pickle.dumps(tag) + b"payload")
    return src, index


def test_cache_check_warm_when_indexes_are_current(tmp_path):
    from dtalign.cli import _cache_tag, _kernel_cache_cold

    src, index = _fake_kernels(tmp_path, _cache_tag())
    os.utime(src, (1_000_000, 1_000_000))
    assert _kernel_cache_cold(src.parent) is False
    os.utime(src, (2**31 - 1, 2**31 - 1))  # the source edited after its index was written
    assert _kernel_cache_cold(src.parent) is True


def test_cache_check_cold_without_indexes_or_with_another_format(tmp_path):
    from dtalign.cli import _cache_tag, _kernel_cache_cold

    assert _kernel_cache_cold(tmp_path / "nowhere") is True
    (tmp_path / "empty" / "__pycache__").mkdir(parents=True)
    assert _kernel_cache_cold(tmp_path / "empty") is True
    if _cache_tag() is not None:
        src, _ = _fake_kernels(tmp_path / "old", ("0.1.0", "plain-numba"))
        os.utime(src, (1_000_000, 1_000_000))
        assert _kernel_cache_cold(src.parent) is True


# --------------------------------------------------------------------------- pairs of numbers


@pytest.mark.parametrize(("argv", "written"), [
    (["overlay", "x.png", "--shape", "limb", "--image", "i.npy", "--polyline", "p.csv",
      "--displace", "3", "-2"], "--displace 3,-2, not --displace 3 -2"),
    (["fit", "a.npy", "a.csv", "--window", "30", "20"], "--window 30,20, not --window 30 20"),
    (["fit", "a.npy", "a.csv", "--plot", "x.png", "--zoom", "50", "100"],
     "--zoom 50,100, not --zoom 50 100"),
])
def test_two_word_pairs_are_refused_with_the_comma_form(argv, written, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "takes its two numbers as one word, joined by a comma" in err and written in err
    assert "odd number of files" not in err


def test_displace_takes_a_comma_pair_negative_first_too(tmp_path, capsys, monkeypatch):
    from dtalign.io import cassini

    # a stand-in frame and overlay: the option's parsing is what is tested
    monkeypatch.setattr(cassini, "load_cassini_overlay_frame", lambda path: _FakeFrame())
    monkeypatch.setattr(cassini, "overlay_polylines", lambda f, shape, n_lines: [
        scenes.Polyline("l", np.array([[10.0, 10.0], [10.0, 20.0], [20.0, 20.0]]),
                        np.array([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0]]), np.ones(3))])
    code = main(["overlay", "x.png", "--shape", "limb", "--image", str(tmp_path / "i.npy"),
                 "--polyline", str(tmp_path / "p.csv"), "--displace", "-2,3"])
    assert code == 0, capsys.readouterr().err
    from dtalign.io import load_polyline_csv

    moved = load_polyline_csv(tmp_path / "p.csv")
    assert np.allclose(moved.vertices_vu[0], (12.0, 7.0))  # moved by -(-2, 3)
    assert main(["overlay", "x.png", "--shape", "limb", "--image", str(tmp_path / "i.npy"),
                 "--polyline", str(tmp_path / "p.csv"), "--displace", "3"]) == 1
    assert "--displace takes two numbers separated by a comma (e.g. 3,-2)" \
        in capsys.readouterr().err


class _FakeFrame:
    image = np.zeros((30, 30))
    header_rows = 0
