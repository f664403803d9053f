"""The command line end to end, each check through a real subprocess.

Options anywhere, same-named inputs, status lines and the progress bar,
output paths checked before the work, Ctrl-C, the first-run compile notice,
a sample input for ``fit``, and the plot zoom.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numba
import numpy as np
import pytest

import dtalign
from _pipe_reader import PipeReader
from dtalign import scenes
from dtalign.cli import COMPILE_NOTICE, main
from dtalign.io import save_polyline_csv

TRUE = (3.4, -2.2)
SRC = Path(dtalign.__file__).resolve().parents[1]


def _env(src: Path = SRC) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(src) + os.pathsep + env.get("PYTHONPATH", "")
    env.pop("DTALIGN_DEBUG", None)
    return env


def dtalign_cli(*argv: str, cwd: Path, timeout: float = 600) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "dtalign", *argv],
        capture_output=True, text=True, cwd=cwd, env=_env(), timeout=timeout,
    )


def _write_scene(folder: Path, name: str = "disc", offset=TRUE) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    scene = scenes.disc_scene(shape=(200, 200), radius=50.0, n_vertices=100, offset_vu=offset)
    np.save(folder / f"{name}.npy", scene.image)
    save_polyline_csv(folder / f"{name}.csv", scene.polyline)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli_ux")
    _write_scene(d)
    # Compile (or load) the kernels in this process, so the subprocesses
    # below start from a warm cache whatever ran before.
    assert main(["fit", str(d / "disc.npy"), str(d / "disc.csv"), "--window", "8", "--json"]) == 0
    return d


# --------------------------------------------------------------------------- options anywhere


@pytest.mark.parametrize(
    "argv",
    [
        ["fit", "--window", "8", "disc.npy", "disc.csv", "--json"],
        ["fit", "disc.npy", "--window", "8", "disc.csv", "--json"],
        ["fit", "--json", "--window", "8,6", "disc.npy", "disc.csv"],
    ],
)
def test_options_anywhere(files, argv):
    proc = dtalign_cli(*argv, cwd=files)
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout)
    assert np.allclose(doc["offset_vu"], TRUE, atol=0.3)
    assert doc["search_window_vu"] == ([8, 6] if "8,6" in argv else [8, 8])


# --------------------------------------------------------------------------- same-named inputs


def test_same_named_images_get_distinct_labels_and_plots(files, tmp_path):
    pytest.importorskip("matplotlib")
    _write_scene(tmp_path / "a")
    _write_scene(tmp_path / "b", offset=(-2.0, 1.5))
    (tmp_path / "out").mkdir()
    proc = dtalign_cli(
        "fit", "a/disc.npy", "a/disc.csv", "b/disc.npy", "b/disc.csv", "--window", "8",
        "--plot", "out/fit.png", "--no-progress", cwd=tmp_path,
    )
    assert proc.returncode == 0, proc.stderr
    rows = [line.split()[0] for line in proc.stdout.splitlines()[2:]]
    assert rows == ["a/disc.npy", "b/disc.npy"]
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["fit_a_disc.png", "fit_b_disc.png"]


# --------------------------------------------------------------------------- progress bar


def test_status_lines_do_not_land_on_the_progress_bar(files, tmp_path):
    pytest.importorskip("tqdm")
    pytest.importorskip("matplotlib")
    (tmp_path / "bad.npy").write_bytes(b"not a numpy file")
    shutil.copy(files / "disc.csv", tmp_path / "bad.csv")
    listing = tmp_path / "list.txt"
    listing.write_text(f"{files / 'disc.npy'}\nbad.npy\n{files / 'disc.npy'} {files / 'disc.csv'}\n")
    proc = dtalign_cli("fit", "--batch", "list.txt", "--window", "8", "--plot", "p.png", cwd=tmp_path)
    assert proc.returncode == 1
    err = proc.stderr
    assert "fitting" in err  # the bar was drawn
    messages = [m.start() for m in re.finditer(r"dtalign: FAILED|: wrote ", err)]
    assert len(messages) == 3, err
    for start in messages:
        line_start = max(err.rfind("\n", 0, start), err.rfind("\r", 0, start)) + 1
        assert "%|" not in err[line_start:start], f"message on the bar's line: {err!r}"


# --------------------------------------------------------------------------- output paths


@pytest.mark.parametrize(
    ("option", "target", "fragment"),
    [
        ("--plot", "missing/fit.png", "folder missing does not exist"),
        ("--output", "missing/fit.json", "folder missing does not exist"),
        ("--plot", ".", "is a directory"),
    ],
)
def test_output_paths_checked_before_the_work(files, option, target, fragment):
    proc = dtalign_cli("fit", "disc.npy", "disc.csv", "--window", "8", option, target, cwd=files)
    assert proc.returncode == 1
    assert proc.stdout == ""  # no fit was printed: the check came first
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("dtalign: error: ") and fragment in lines[0], proc.stderr


def test_output_file_receives_the_json(files, tmp_path):
    out = tmp_path / "fit.json"
    proc = dtalign_cli("fit", "disc.npy", "disc.csv", "--window", "8", "--json", "-o", str(out), cwd=files)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout == ""
    assert np.allclose(json.loads(out.read_text())["offset_vu"], TRUE, atol=0.3)


# --------------------------------------------------------------------------- Ctrl-C


_Reader = PipeReader


def _sigint_default() -> None:
    # A terminal's program gets SIGINT at its default; a test run started in
    # the background of a shell has it ignored (POSIX), and the CLI would
    # inherit that and rightly ignore the Ctrl-C this file sends.
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _start(argv: list[str], cwd: Path, src: Path = SRC) -> tuple[subprocess.Popen[str], _Reader]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "dtalign", *argv],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=cwd, env=_env(src),
        preexec_fn=_sigint_default if sys.platform != "win32" else None,
    )
    return proc, _Reader(proc.stderr)


def _interrupt(proc: subprocess.Popen[str], reader: _Reader) -> int:
    proc.send_signal(signal.SIGINT)
    try:
        code = proc.wait(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    reader.join()
    return code


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
def test_ctrl_c_exits_130(files, tmp_path):
    pytest.importorskip("tqdm")
    listing = tmp_path / "many.txt"
    listing.write_text(f"{files / 'disc.npy'} {files / 'disc.csv'}\n" * 20000)
    proc, reader = _start(["fit", "--batch", str(listing), "--window", "8"], cwd=tmp_path)
    assert reader.wait_for("fitting", timeout=120), reader.text
    code = _interrupt(proc, reader)
    # 130 from main(); now and then (about 1 run in 10 here, when the signal
    # lands while the kernels load) the interpreter instead ends by SIGINT
    # after main() returned, which a shell reports as 130 too.
    assert code in (130, -signal.SIGINT), reader.text
    assert "Traceback" not in reader.text and "dtalign: interrupted" in reader.text


# --------------------------------------------------------------------------- compile notice


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
@pytest.mark.skipif(
    numba.config.DISABLE_JIT, reason="NUMBA_DISABLE_JIT: nothing compiles, so no notice"
)
def test_compile_notice_before_a_cold_first_run(files, tmp_path):
    """A copy of the package has no compiled kernels: the notice comes first."""
    copy = tmp_path / "src"
    shutil.copytree(SRC / "dtalign", copy / "dtalign", ignore=shutil.ignore_patterns("__pycache__"))
    proc, reader = _start(
        ["fit", str(files / "disc.npy"), str(files / "disc.csv"), "--window", "8"], cwd=tmp_path, src=copy
    )
    try:
        assert reader.wait_for(COMPILE_NOTICE, timeout=120), reader.text
        assert proc.poll() is None  # printed before the compile, not after it
    finally:
        proc.kill()  # no need to wait minutes for the compile
        proc.wait(timeout=60)
        reader.join()
    assert reader.text.startswith(COMPILE_NOTICE), reader.text  # the first thing said


def test_no_compile_notice_with_a_warm_cache(files):
    proc = dtalign_cli("fit", "disc.npy", "disc.csv", "--window", "8", cwd=files)
    assert proc.returncode == 0, proc.stderr
    assert "compiling" not in proc.stderr


# --------------------------------------------------------------------------- sample input


def test_demo_save_writes_files_fit_reads(files, tmp_path):
    proc = dtalign_cli("demo", "--save", "sample", "--n-vertices", "100", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "dtalign fit sample/demo.npy sample/demo.csv" in proc.stderr
    proc = dtalign_cli("fit", "sample/demo.npy", "sample/demo.csv", "--window", "30", "--json", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert np.allclose(json.loads(proc.stdout)["offset_vu"], (7.3, -4.6), atol=0.3)


# --------------------------------------------------------------------------- zoom


def test_plot_zoom_adds_panels(files, tmp_path):
    image_module = pytest.importorskip("PIL.Image")
    pytest.importorskip("matplotlib")
    plain, zoomed = tmp_path / "plain.png", tmp_path / "zoomed.png"
    base = ["fit", "disc.npy", "disc.csv", "--window", "8"]
    assert dtalign_cli(*base, "--plot", str(plain), cwd=files).returncode == 0
    proc = dtalign_cli(
        *base, "--plot", str(zoomed), "--zoom", "50,100", "--zoom", "150,100", "--zoom-half", "10",
        cwd=files,
    )
    assert proc.returncode == 0, proc.stderr
    with image_module.open(plain) as a, image_module.open(zoomed) as b:
        assert b.size[0] > 1.3 * a.size[0]  # the zoom column widens the figure


def test_bad_zoom_is_a_one_line_error(files):
    proc = dtalign_cli("fit", "disc.npy", "disc.csv", "--plot", "x.png", "--zoom", "50", cwd=files)
    assert proc.returncode == 1
    assert proc.stderr.strip().splitlines() == [
        "dtalign: error: --zoom takes two numbers separated by a comma (e.g. 120,340), got '50'"
    ]


def test_no_compile_notice_when_the_jit_is_disabled(monkeypatch):
    """With Numba's JIT disabled the kernels run as Python: nothing compiles,
    so even a cold cache gets no notice (the CLI's error lines stay one line)."""
    from dtalign import cli

    said = []

    class Messages:
        def say(self, text):
            said.append(text)

    assert cli._jit_disabled() is bool(numba.config.DISABLE_JIT)
    monkeypatch.setattr(cli, "_kernel_cache_cold", lambda: True)
    monkeypatch.setattr(cli, "_jit_disabled", lambda: True)
    cli._compile_notice(Messages())
    assert said == []
    monkeypatch.setattr(cli, "_jit_disabled", lambda: False)
    cli._compile_notice(Messages())
    assert said == [COMPILE_NOTICE]
