"""Interrupted command-line batches keep what they finished.

``dtalign fit`` on many image/CSV pairs, interrupted with Ctrl-C (SIGINT),
prints or writes the rows finished before it and exits 130; a Ctrl-C sent
to the whole process group during ``fit_images(..., executor="process")``
leaves the parent's one line on stderr, not a traceback per worker.

The children start with SIGINT at its default, as a terminal's program
does (a test run in the background of a shell has it ignored, and a child
would inherit that). The moment to interrupt is known, not guessed: the
batch's second pair is missing, so its FAILED line on stderr comes after
the first pair's fit has finished.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import dtalign
from _pipe_reader import PipeReader
from dtalign import scenes
from dtalign.cli import main
from dtalign.io import save_polyline_csv

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")

SRC = Path(dtalign.__file__).resolve().parents[1]
#: Pairs after the first two: far more than get fitted before the interrupt.
MANY = 20000
#: Per wait for the child: its start and a first fit take seconds, minutes
#: only under heavy load. Never a timing assertion.
TIMEOUT_S = 300


def _env() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["PYTHONPATH"] = str(SRC)
    return env


def _sigint_default() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


_Reader = PipeReader


def _stop(proc: subprocess.Popen[str], readers: list[_Reader], *, group: bool = False) -> int:
    if group:
        os.killpg(proc.pid, signal.SIGINT)
    else:
        proc.send_signal(signal.SIGINT)
    try:
        code = proc.wait(timeout=TIMEOUT_S)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    for r in readers:
        r.join()
    return code


@pytest.fixture(scope="module")
def listing(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli_interrupts")
    scene = scenes.disc_scene(shape=(200, 200), radius=50.0, n_vertices=100, offset_vu=(2.3, -1.6))
    np.save(d / "disc.npy", scene.image)
    save_polyline_csv(d / "disc.csv", scene.polyline)
    # warm the kernels in this process, so the children load them
    assert main(["fit", str(d / "disc.npy"), str(d / "disc.csv"), "--window", "8", "--json"]) == 0
    good = f"{d / 'disc.npy'} {d / 'disc.csv'}\n"
    path = d / "many.txt"
    path.write_text(good + f"{d / 'gone.npy'} {d / 'disc.csv'}\n" + good * MANY)
    return path


def _interrupted_fit(listing: Path, tmp_path: Path, *extra: str) -> tuple[int, str, str]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "dtalign", "fit", "--batch", str(listing), "--window", "8",
         "--no-progress", *extra],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path, env=_env(),
        preexec_fn=_sigint_default,
    )
    out, err = _Reader(proc.stdout), _Reader(proc.stderr)
    assert err.wait_for("FAILED", timeout=TIMEOUT_S), err.text
    code = _stop(proc, [out, err])
    return code, out.text, err.text


def _check_rows(rows: list[dict], err: str) -> None:
    assert 2 <= len(rows) < MANY + 2
    assert "error" not in rows[0] and np.allclose(rows[0]["offset_vu"], (2.3, -1.6), atol=0.3)
    assert "gone.npy" in rows[1]["error"]
    assert all("error" in r or r["status"] for r in rows)
    assert f"dtalign: interrupted after {len(rows)} of {MANY + 2} image(s)" in err
    assert "Traceback" not in err


def test_interrupted_json_batch_prints_the_finished_rows(listing, tmp_path):
    code, out, err = _interrupted_fit(listing, tmp_path, "--json")
    assert code == 130, err
    _check_rows(json.loads(out), err)


def test_interrupted_batch_writes_the_finished_rows_to_output(listing, tmp_path):
    code, out, err = _interrupted_fit(listing, tmp_path, "--json", "--output", "rows.json")
    assert code == 130, err
    _check_rows(json.loads((tmp_path / "rows.json").read_text()), err)
    assert out == ""


def test_interrupted_table_batch_prints_the_finished_rows(listing, tmp_path):
    code, out, err = _interrupted_fit(listing, tmp_path)
    assert code == 130, err
    lines = out.strip().splitlines()
    rows = lines[2:]  # after the header and its rule
    assert len(rows) >= 2 and "FAILED" not in rows[0] and "gone.npy" in rows[1]
    assert f"dtalign: interrupted after {len(rows)} of {MANY + 2} image(s)" in err


SCRIPT = textwrap.dedent(
    """
    import sys
    import numpy as np
    from dtalign import scenes
    from dtalign.pipeline.batch import fit_images

    scene = scenes.disc_scene(shape=(160, 160), radius=40.0, n_vertices=80, offset_vu=(2.3, -1.6))
    p = scene.polyline
    items = [(scene.image, scene.noise_sigma, [(p.vertices_vu, p.normals_vu, p.sigmas)])] * 400

    def tell(done, total):
        print(f"DONE {done}", flush=True)

    try:
        fit_images(items, search_window_vu=(6, 6), workers=2, executor="process", progress=tell)
    except KeyboardInterrupt:
        print("batch interrupted", file=sys.stderr)
        sys.exit(130)
    print("NOT INTERRUPTED", flush=True)
    """
)


def test_process_group_ctrl_c_leaves_one_line(tmp_path):
    """Ctrl-C reaches every process of the group: the workers ignore it, the
    parent's KeyboardInterrupt is the one report."""
    script = tmp_path / "pool.py"
    script.write_text(SCRIPT)
    proc = subprocess.Popen(
        [sys.executable, str(script)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        cwd=tmp_path, env=_env(), preexec_fn=_sigint_default, start_new_session=True,
    )
    out, err = _Reader(proc.stdout), _Reader(proc.stderr)
    assert out.wait_for("DONE 2\n", timeout=TIMEOUT_S), (out.text[-500:], err.text)
    code = _stop(proc, [out, err], group=True)
    assert "NOT INTERRUPTED" not in out.text
    assert code == 130, err.text
    assert err.text.splitlines() == ["batch interrupted"]
