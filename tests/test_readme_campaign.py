"""The README's campaign lines, run as written.

The shell line of the README's "Campaigns on Dask" section (without its
``pip install`` step, which the test environment has done) and its
``pandas.read_parquet(...)`` read are taken from README.md itself, so a
change to either is tested as the reader sees it. The test skips only when
an optional dependency of the ``dask`` extra is absent.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

import dtalign

ROOT = Path(__file__).resolve().parents[1]
SRC = Path(dtalign.__file__).resolve().parents[1]


def _section() -> str:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    start = text.index("## Campaigns on Dask")
    return text[start:text.index("\n## ", start + 1)]


def _commands() -> list[list[str]]:
    """The section's shell commands, split on ``&&``, without ``pip install``."""
    (block,) = re.findall(r"```bash\n(.*?)```", _section(), re.S)
    commands = []
    for part in " ".join(block.split("\\\n")).split("&&"):
        argv = shlex.split(part)
        if argv and argv[:4] != ["python", "-m", "pip", "install"]:
            commands.append(argv)
    return commands


def _read_line() -> str:
    (expr,) = re.findall(r"`(pandas\.read_parquet\([^`]*\))`", _section())
    return expr


def test_the_readme_names_the_extra_that_installs_pandas():
    tomllib = pytest.importorskip("tomllib")  # Python 3.11+

    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"][
        "optional-dependencies"]
    assert '".[dask]"' in _section()
    for extra in ("dask", "test"):
        assert any(req.startswith("pandas") for req in extras[extra]), extra


def test_readme_campaign_lines_run_as_written(tmp_path):
    for module in ("dask", "distributed", "pyarrow", "pandas"):
        pytest.importorskip(module)
    commands = _commands()
    assert [c[:2] for c in commands] == [["dtalign", "archive"], ["dtalign", "archive"]]
    env = dict(os.environ)
    env["PYTHONPATH"] = str(SRC) + os.pathsep + env.get("PYTHONPATH", "")
    statuses = []
    for argv in commands:
        # "dtalign" is the console script; python -m dtalign is the same entry point
        proc = subprocess.run([sys.executable, "-m", "dtalign", *argv[1:]], cwd=tmp_path,
                              env=env, capture_output=True, text=True, timeout=900)
        statuses.append(proc.returncode)
        assert proc.returncode in (0, 3), proc.stderr
    # the README: "It exits with status 3 ... the ring edge of frame f000"
    assert statuses == [0, 3]
    import pandas

    old = Path.cwd()
    os.chdir(tmp_path)
    try:
        frame = eval(_read_line(), {"pandas": pandas})  # the README's line, as written
    finally:
        os.chdir(old)
    assert len(frame) == 24  # eight frames, three polylines each
    assert {"status", "reasons"} <= set(frame.columns)
    failed = frame[frame["status"] == "failed"]
    assert len(failed) >= 1
