"""A damaged or unusable Numba cache never stops dtalign.

Each case runs a tiny module compiled with :func:`dtalign._jit.kernel` (the
same decorator as every dtalign kernel, so the same cache machinery, at a
fraction of the package's compile time) in fresh subprocesses with a
timeout, and reads back what the dispatcher did: the result, cache hits and
misses, the cache folder, and what went to the ``dtalign`` logger. Children
run with ``-W error``: a ``warnings.warn`` would fail them.

Where permissions matter the child runs as the ``nobody`` user (uid 65534)
with the one capability CAP_DAC_READ_SEARCH: it can read every file (the
interpreter lives under ``/root`` on the CI machine) but write only where
``nobody`` may, which is what a service user in a container with a
read-only install sees.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import textwrap
from collections.abc import Iterator
from pathlib import Path

import numba
import pytest

import dtalign

# Under NUMBA_DISABLE_JIT nothing is compiled, so there is no cache to damage
# or to find: these tests are about compiled code only.
pytestmark = pytest.mark.skipif(
    numba.config.DISABLE_JIT, reason="NUMBA_DISABLE_JIT: no compiled code, no cache"
)

#: The children import the same dtalign as this process (source tree or install).
SRC = Path(dtalign.__file__).resolve().parents[1]

#: Per child process: Numba's import plus one tiny compile takes a few
#: seconds here, minutes only under extreme load. Never a timing assertion.
TIMEOUT_S = 600

MODULE = textwrap.dedent(
    """
    from dtalign._jit import inline_kernel, kernel


    @inline_kernel
    def _square(x):
        return x * x


    @kernel
    def total(a):
        s = 0.0
        for i in range(a.shape[0]):
            s += _square(a[i])
        return s
    """
)

RUNNER = textwrap.dedent(
    """
    import json, logging, sys
    logging.basicConfig(level=logging.WARNING, stream=sys.stderr,
                        format="LOG %(name)s %(levelname)s %(message)s")
    sys.path.insert(0, sys.argv[1])
    import numpy as np
    import tinyk
    kind = sys.argv[2]
    a = np.arange(10.0) if kind == "float" else np.arange(10)
    result = tinyk.total(a)
    st = tinyk.total.stats
    print(json.dumps({"result": float(result),
                      "hits": sum(st.cache_hits.values()),
                      "misses": sum(st.cache_misses.values()),
                      "path": st.cache_path}))
    """
)

EXPECTED = float(sum(i * i for i in range(10)))
NOBODY = 65534


@pytest.fixture
def module_dir() -> Iterator[Path]:
    """A world-readable folder with the tiny module (pytest's tmp_path is 0700)."""
    root = Path(tempfile.mkdtemp(prefix="dtalign-cache-"))
    root.chmod(0o755)
    (root / "tinyk.py").write_text(MODULE)
    (root / "runner.py").write_text(RUNNER)
    for f in root.iterdir():
        f.chmod(0o644)
    try:
        yield root
    finally:
        for dirpath, dirnames, _ in os.walk(root):
            for d in dirnames:
                os.chmod(os.path.join(dirpath, d), 0o755)
        os.chmod(root, 0o755)
        shutil.rmtree(root, ignore_errors=True)


def _env(home: str | None = None) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items()
           if k not in ("NUMBA_CACHE_DIR", "XDG_CACHE_HOME", "PYTHONPATH")}
    env["PYTHONPATH"] = str(SRC)
    if home is not None:
        env["HOME"] = home
    return env


def _nobody_prefix() -> list[str]:
    """Command prefix that runs a child as an unprivileged user, or skip."""
    if os.geteuid() != 0:
        return []  # already unprivileged: permissions apply as they are
    setpriv = shutil.which("setpriv")
    if setpriv is None:
        pytest.skip("running as root and setpriv (util-linux) is not installed: "
                    "cannot drop to an unprivileged user")
    prefix = [setpriv, f"--reuid={NOBODY}", f"--regid={NOBODY}", "--clear-groups",
              "--inh-caps=+dac_read_search", "--ambient-caps=+dac_read_search"]
    probe = subprocess.run(prefix + [sys.executable, "-c", "import os; print(os.geteuid())"],
                           capture_output=True, text=True, timeout=TIMEOUT_S)
    if probe.returncode != 0 or probe.stdout.strip() != str(NOBODY):
        pytest.skip(f"cannot run the interpreter as uid {NOBODY} here: {probe.stderr.strip()}")
    return prefix


def run(module_dir: Path, kind: str = "float", *, prefix: list[str] | None = None,
        home: str | None = None) -> tuple[dict, str]:
    cmd = (prefix or []) + [sys.executable, "-W", "error", str(module_dir / "runner.py"),
                            str(module_dir), kind]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=TIMEOUT_S,
                          env=_env(home), cwd=module_dir)
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1]), proc.stderr


def _warnings(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if line.startswith("LOG dtalign WARNING")]


def _cache_files(module_dir: Path) -> tuple[Path, Path]:
    folder = module_dir / "__pycache__"
    (index,) = folder.glob("tinyk.total-*.nbi")
    (data,) = folder.glob("tinyk.total-*.1.nbc")
    return index, data


def _truncate(path: Path, size: int) -> None:
    path.write_bytes(path.read_bytes()[:size])


def _flip_middle(path: Path) -> None:
    raw = bytearray(path.read_bytes())
    raw[len(raw) // 2] ^= 0xFF
    path.write_bytes(bytes(raw))


def _garble_tail(path: Path) -> None:
    raw = bytearray(path.read_bytes())
    start = len(raw) // 3
    raw[start:] = bytes((b * 37 + 11) % 256 for b in raw[start:])
    path.write_bytes(bytes(raw))


DAMAGE = {
    "index truncated": lambda index, data: _truncate(index, 20),
    "index emptied": lambda index, data: _truncate(index, 0),
    "index garbled": lambda index, data: _garble_tail(index),
    "data truncated": lambda index, data: _truncate(data, 100),
    "data emptied": lambda index, data: _truncate(data, 0),
    "data garbled": lambda index, data: _garble_tail(data),
    # still unpickles on plain Numba: machine code with one flipped byte
    "data one flipped byte": lambda index, data: _flip_middle(data),
}


@pytest.mark.parametrize("damage", sorted(DAMAGE))
def test_damaged_cache_entry_is_a_miss_and_is_replaced(module_dir: Path, damage: str) -> None:
    first, err = run(module_dir)
    assert (first["result"], first["misses"]) == (EXPECTED, 1)
    assert first["path"] == str(module_dir / "__pycache__")
    assert not _warnings(err)
    index, data = _cache_files(module_dir)
    DAMAGE[damage](index, data)

    healed, err = run(module_dir)
    assert healed["result"] == EXPECTED
    assert (healed["hits"], healed["misses"]) == (0, 1)  # recompiled once
    (warning,) = _warnings(err)
    assert str(module_dir / "__pycache__") in warning
    assert "recompiling" in warning

    again, err = run(module_dir)  # the entry was replaced: a clean hit
    assert (again["result"], again["hits"], again["misses"]) == (EXPECTED, 1, 0)
    assert not _warnings(err)


def test_no_writable_cache_location_compiles_in_memory(module_dir: Path) -> None:
    prefix = _nobody_prefix()
    module_dir.chmod(0o555)  # a read-only install; HOME does not exist
    out, err = run(module_dir, prefix=prefix, home="/nonexistent/dtalign-home")
    assert out["result"] == EXPECTED
    assert out["path"] is None  # Numba's in-memory cache: nothing written
    assert not (module_dir / "__pycache__").exists()
    (warning,) = _warnings(err)
    assert "compiling in memory" in warning and str(module_dir) in warning


def test_read_only_prewarmed_cache_is_read(module_dir: Path) -> None:
    prefix = _nobody_prefix()
    warm, _ = run(module_dir)  # the image build step, as its owner
    assert warm["misses"] == 1
    folder = module_dir / "__pycache__"
    for f in folder.iterdir():
        f.chmod(0o444)
    folder.chmod(0o555)
    module_dir.chmod(0o555)
    home = "/nonexistent/dtalign-home"
    before = sorted(p.name for p in folder.iterdir())

    out, err = run(module_dir, prefix=prefix, home=home)
    assert (out["result"], out["hits"], out["misses"]) == (EXPECTED, 1, 0)
    assert out["path"] == str(folder)
    assert not _warnings(err)

    # A signature the warm cache lacks compiles in memory; the write is refused.
    other, err = run(module_dir, "int", prefix=prefix, home=home)
    assert (other["result"], other["misses"]) == (EXPECTED, 1)
    (warning,) = _warnings(err)
    assert "cannot write the Numba cache in " + str(folder) in warning
    assert sorted(p.name for p in folder.iterdir()) == before


def test_every_package_kernel_has_the_checked_cache() -> None:
    """Every dispatcher in dtalign goes through dtalign._jit (decoration only, no compile)."""
    import importlib
    import pkgutil

    from numba.core.dispatcher import Dispatcher

    from dtalign._numba_cache import CheckedFunctionCache, UncachedFunctionCache

    found = 0
    for info in pkgutil.walk_packages(dtalign.__path__, "dtalign."):
        if not info.name.startswith(("dtalign._kernels", "dtalign.benchmarking")):
            continue
        module = importlib.import_module(info.name)
        for name, value in vars(module).items():
            if isinstance(value, Dispatcher) and value.__module__ == info.name:
                found += 1
                assert isinstance(value._cache, (CheckedFunctionCache, UncachedFunctionCache)), name
    assert found > 20


# ---------------------------------------------------------------------------
# A Numba without what the checked cache needs
# ---------------------------------------------------------------------------


def test_installed_numba_has_what_the_checked_cache_needs() -> None:
    """The checked cache subclasses private numba.core.caching classes: a Numba
    release that renames or drops one must be noticed here, not in the field."""
    from dtalign import _numba_cache

    assert not _numba_cache.MISSING, (
        f"Numba {numba.__version__} lacks {', '.join(_numba_cache.MISSING)} of "
        "numba.core.caching: dtalign's kernels fall back to Numba's plain cache=True "
        "(no checksums, no read-only fallback). Adapt dtalign/_numba_cache.py to this "
        "Numba, or cap numba in pyproject.toml."
    )


def _fresh_cache_module() -> object:
    """A second copy of dtalign._numba_cache, resolved against numba.core.caching as it is now."""
    import importlib.util

    from dtalign import _numba_cache

    spec = importlib.util.spec_from_file_location("_dtalign_numba_cache_probe", _numba_cache.__file__)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _probe_total(a):  # compiled by the fallback test, cached by plain Numba
    s = 0.0
    for i in range(a.shape[0]):
        s += a[i] * a[i]
    return s


def _probe_twice(a):
    return 2.0 * a.sum()


def test_missing_numba_names_fall_back_to_plain_cache(monkeypatch, caplog, tmp_path) -> None:
    """Names that an older or newer Numba lacks: the package still imports and
    caches through Numba's own cache=True, with one WARNING for all kernels."""
    import logging

    import numpy as np
    from numba.core import caching

    with monkeypatch.context() as m:
        # numba 0.59 had neither zip locator name; a method can go too.
        for name in ("ZipCacheLocator", "_ZipCacheLocator"):
            m.delattr(caching, name, raising=False)
        m.delattr(caching.IndexDataCacheFile, "_open_for_write")
        probe = _fresh_cache_module()
    assert probe.MISSING == ("ZipCacheLocator or _ZipCacheLocator",
                             "IndexDataCacheFile._open_for_write")

    monkeypatch.setattr(numba.config, "CACHE_DIR", str(tmp_path))
    caplog.set_level(logging.DEBUG, logger="dtalign")
    kernels = [probe.attach_cache(numba.njit(f)) for f in (_probe_total, _probe_twice)]
    for k in kernels:
        assert type(k._cache) is caching.FunctionCache  # Numba's own, as cache=True gives
    a = np.arange(10.0)
    assert kernels[0](a) == EXPECTED and kernels[1](a) == 90.0
    assert sorted(p.suffix for p in tmp_path.rglob("*.nb?")) == [".nbc", ".nbc", ".nbi", ".nbi"]
    warned = [r.getMessage() for r in caplog.records
              if r.name == "dtalign" and r.levelno == logging.WARNING]
    assert len(warned) == 1, warned
    assert f"Numba {numba.__version__} lacks ZipCacheLocator or _ZipCacheLocator" in warned[0]
    assert "plain cache=True" in warned[0]
