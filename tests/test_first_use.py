"""The first compile is announced by the library, and ``dtalign.warm_up()`` does it ahead.

A tiny module compiled with :func:`dtalign._jit.kernel` (the decorator of
every dtalign kernel, so the same cache machinery, at a fraction of the
package's compile time) runs in fresh subprocesses: the first compiles and
logs the notice once at INFO on the ``dtalign`` logger, the second loads
the cache and says nothing.
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numba
import pytest

import dtalign

pytestmark = pytest.mark.skipif(
    numba.config.DISABLE_JIT, reason="NUMBA_DISABLE_JIT: nothing compiles, nothing to announce"
)

SRC = Path(dtalign.__file__).resolve().parents[1]

MODULE = textwrap.dedent(
    """
    from dtalign._jit import kernel


    @kernel
    def twice(x):
        return 2.0 * x


    @kernel
    def thrice(x):
        return 3.0 * x
    """
)

RUNNER = textwrap.dedent(
    """
    import logging, sys
    logging.basicConfig(level=logging.INFO, stream=sys.stderr,
                        format="LOG %(name)s %(levelname)s %(message)s")
    sys.path.insert(0, sys.argv[1])
    import tinyfirst
    print(tinyfirst.twice(1.5) + tinyfirst.thrice(1.0))
    """
)


def _run(folder: Path) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "PYTHONPATH")}
    env["PYTHONPATH"] = str(SRC)
    proc = subprocess.run([sys.executable, "-W", "error", str(folder / "runner.py"), str(folder)],
                          capture_output=True, text=True, timeout=600, env=env, cwd=folder)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "6.0"
    return proc


def test_the_first_compile_is_announced_once_at_info_and_a_warm_cache_is_silent(tmp_path):
    (tmp_path / "tinyfirst.py").write_text(MODULE)
    (tmp_path / "runner.py").write_text(RUNNER)
    cold = _run(tmp_path)
    notices = [line for line in cold.stderr.splitlines()
               if line.startswith("LOG dtalign INFO compiling dtalign's kernels for first use")]
    assert len(notices) == 1, cold.stderr  # two kernels compiled, one notice
    assert "dtalign.warm_up()" in notices[0]
    warm = _run(tmp_path)
    assert "compiling" not in warm.stderr, warm.stderr


def test_warm_up_is_public_and_returns_its_wall_time(caplog):
    caplog.set_level(logging.INFO, logger="dtalign")
    assert "warm_up" in dtalign.__all__
    seconds = dtalign.warm_up()
    assert seconds > 0.0
    assert any("kernels ready" in r.getMessage() for r in caplog.records)
    # what the pipeline does next compiles nothing more
    from dtalign import _numba_cache

    heard: list[str] = []
    _numba_cache.compile_listeners.append(heard.append)
    try:
        announced = _numba_cache._announced
        _numba_cache._announced = False
        try:
            dtalign.warm_up()
        finally:
            _numba_cache._announced = announced
    finally:
        _numba_cache.compile_listeners.remove(heard.append)
    assert heard == []
