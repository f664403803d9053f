"""Developer sessions: ``nox -s tests``, ``lint``, ``typecheck``, ``docs``, ``bench``,
``boundscheck`` and ``coverage``.

Every session installs the package from this checkout into its own virtual
environment, so a session that passes here passes on a fresh machine.
"""

from __future__ import annotations

import nox

nox.options.sessions = ["tests", "lint"]
nox.options.reuse_existing_virtualenvs = True

PYTHON = ["3.11"]


@nox.session(python=PYTHON)
def tests(session: nox.Session) -> None:
    """The test suite, exactly as README and .ci/run run it."""
    session.install(".[test]")
    session.run("python", "-m", "pytest", *session.posargs)


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
    """Benchmark table: reference vs dtalign on SPEC section 7 workloads."""
    session.install(".[test]")
    session.run(
        "python", "-m", "dtalign.benchmarking", "--json", "benchmarks/results/latest.json",
        "--rst", "docs/_generated/bench_table.rst", "--readme", "README.md",
        *session.posargs,
    )


@nox.session(python=PYTHON)
def boundscheck(session: nox.Session) -> None:
    """Kernels with Numba's bounds checking on: an out-of-range index raises."""
    session.install(".[test]")
    session.run(
        "python", "-m", "pytest", "-p", "no:cacheprovider", *session.posargs,
        env={"NUMBA_BOUNDSCHECK": "1", "NUMBA_CACHE_DIR": str(session.create_tmp())},
    )


@nox.session(python=PYTHON)
def coverage(session: nox.Session) -> None:
    """Line coverage with the JIT disabled, so kernel bodies are measured as Python."""
    session.install("-e", ".[test]", "coverage[toml]")
    session.run(
        "python", "-m", "coverage", "run", "--source=dtalign", "-m", "pytest", *session.posargs,
        env={"NUMBA_DISABLE_JIT": "1"},
    )
    session.run("python", "-m", "coverage", "report", "--show-missing")
