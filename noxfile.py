"""Developer sessions: ``nox -s tests``, ``lint``, ``typecheck``, ``docs``, ``bench``,
``boundscheck``, ``coverage``, ``floors``, ``sweeps`` and ``validate``.

Every session installs the package from this checkout into its own virtual
environment, so a session that passes here passes on a fresh machine.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import nox

nox.options.sessions = ["tests", "lint"]
nox.options.reuse_existing_virtualenvs = True

PYTHON = ["3.11"]


@nox.session(python=PYTHON)
def tests(session: nox.Session) -> None:
    """The test suite, exactly as README and .ci/run run it."""
    session.install(".[test]")
    session.run("python", "-m", "pytest", *session.posargs)


def _listed(path: str) -> list[str]:
    """The non-comment lines of a file under .ci/."""
    lines = Path(path).read_text(encoding="utf-8").splitlines()
    return [line.strip() for line in lines if line.strip() and not line.startswith("#")]


@nox.session(python=PYTHON)
def floors(session: nox.Session) -> None:
    """The declared floor of every runtime dependency, pinned (``.ci/floors.txt``;
    llvmlite as numba resolves it), on the floor Python, with the tests of
    ``.ci/floor-tests.txt``: every compiled path and the parity with the
    reference (the whole suite with ``nox -s floors -- tests``). As .ci/run's
    floor step; the Numba cache is compiled afresh in the session's install.
    """
    session.install(".[test]", "-c", ".ci/floors.txt")
    session.run(
        "python", "-c",
        "import numba, llvmlite, numpy, scipy; print('floors: numba', numba.__version__, "
        "'llvmlite', llvmlite.__version__, 'numpy', numpy.__version__, 'scipy', scipy.__version__)",
    )
    session.run(
        "python", "-m", "pytest", "-q", "-p", "no:cacheprovider",
        *(session.posargs or _listed(".ci/floor-tests.txt")),
    )


@nox.session(python=PYTHON)
def sweeps(session: nox.Session) -> None:
    """The profile refinement's property sweeps (``tests/test_profile_sweeps.py``) at
    thousands of draws instead of the suite's few dozen: ``DTALIGN_SWEEP_EXAMPLES``
    (default 3000; about 1 s a draw on one core), from seed 0 unless
    ``DTALIGN_SWEEP_SEED`` names a seed; ``DTALIGN_SWEEP_LOG=path`` writes one JSON
    line per draw. Arguments go to pytest.
    """
    session.install(".[test]")
    env = {"DTALIGN_SWEEP_EXAMPLES": os.environ.get("DTALIGN_SWEEP_EXAMPLES", "3000")}
    session.run(
        "python", "-m", "pytest", "-q", "-p", "no:cacheprovider", "tests/test_profile_sweeps.py",
        *session.posargs, env=env,
    )


@nox.session(python=PYTHON)
def validate(session: nox.Session) -> None:
    """The validation harness on Mitsuba 3 and GalSim renders (``benchmarks/validate``,
    docs/validation.rst): the renderer's checks, then every family's scenes fitted
    and scored. Arguments go to ``python -m benchmarks.validate`` (``--scenes N``,
    ``--seed S``, ``--families ...``); ``-- fixtures`` rewrites the test's cached
    renders instead.
    """
    session.install(".[validate,test]")
    if session.posargs[:1] == ["fixtures"]:
        session.run("python", "-m", "benchmarks.validate.fixtures")
        return
    session.run("python", "-m", "benchmarks.validate", *session.posargs)


@nox.session(python=PYTHON)
def lint(session: nox.Session) -> None:
    """Ruff over the package, tests and benchmarks."""
    session.install("ruff")
    session.run("ruff", "check", "src", "tests", "benchmarks", "noxfile.py")


@nox.session(python=PYTHON)
def typecheck(session: nox.Session) -> None:
    """mypy over the package."""
    session.install(".", "mypy")
    session.run("mypy")


@nox.session(python=PYTHON)
def docs(session: nox.Session) -> None:
    """Sphinx HTML build with warnings as errors."""
    session.install(".[docs]")
    session.run("python", "-m", "sphinx", "-W", "--keep-going", "-b", "html", "docs", "docs/_build/html")


@nox.session(python=PYTHON)
def bench(session: nox.Session) -> None:
    """Benchmark table: reference vs dtalign on :ref:`contract-scenes` workloads."""
    session.install(".[test]")
    session.run(
        "python", "-m", "dtalign.benchmarking", "--json", "benchmarks/results/latest.json",
        "--rst", "docs/_generated/bench_table.rst", "--readme", "README.md",
        *session.posargs,
    )


@nox.session(python=PYTHON)
def boundscheck(session: nox.Session) -> None:
    """Kernels with Numba's bounds checking on: an out-of-range index raises.

    The package then runs the plain twin of the four-lane kernels
    (``dtalign._kernels.lanes``), whose reads are all indexed and checked.
    """
    session.install(".[test]")
    session.run(
        "python", "-m", "pytest", "-p", "no:cacheprovider", *session.posargs,
        env={"NUMBA_BOUNDSCHECK": "1", "NUMBA_CACHE_DIR": str(session.create_tmp())},
    )


@nox.session(python=PYTHON)
def coverage(session: nox.Session) -> None:
    """Line coverage with the JIT disabled, so kernel bodies are measured as Python
    (the plain twin of the four-lane kernels among them).

    The four-lane vector code is LLVM IR built by Python at compile time, and
    the checked Numba cache (``dtalign._numba_cache``) only runs when there
    is compiled code to cache, so a second, appended run compiles afresh with
    the JIT on (a new cache directory: a cache hit would skip the IR builders),
    and a third runs the quick benchmark.
    """
    session.install("-e", ".[test]", "coverage[toml]")
    session.run(
        "python", "-m", "coverage", "run", "--source=dtalign", "-m", "pytest", *session.posargs,
        env={"NUMBA_DISABLE_JIT": "1"},
    )
    session.run("python", "-m", "coverage", "report")
    session.run(
        "python", "-m", "coverage", "run", "--append", "--source=dtalign", "-m", "pytest", "-q",
        "tests/test_lanes.py", "tests/test_lanes_twin.py", "tests/test_mask_scan.py",
        "tests/test_faults_cache.py",
        env={"NUMBA_CACHE_DIR": tempfile.mkdtemp(prefix="dtalign-numba-")},
    )
    # The benchmark runner is package code that the tests only touch at its
    # edges (report formatting): its measurements run as CI runs them
    # (.ci/bench_check.py's quick run), compiled, since with the JIT off a
    # run would time Python, not the package.
    session.run(
        "python", "-m", "coverage", "run", "--append", "--source=dtalign",
        # coverage's tracing slows the timed code: its ratios are not the point here
        "-m", "dtalign.benchmarking", "--quick", "--allow-fail",
    )
    session.run("python", "-m", "coverage", "report", "--show-missing")
