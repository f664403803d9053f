"""Session fixtures of the pytest-benchmark suite.

Run with ``python -m pytest benchmarks --benchmark-only``. The inputs of
every workload are built once per session by
:func:`dtalign.benchmarking.build_inputs` (the derivatives the LM and coarse
workloads read are computed once, by the NumPy specification), so the
reference and dtalign benchmarks of a workload read identical arrays. Each
benchmark is paired: ``[reference]`` and ``[dtalign]`` share a group.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest

import dtalign
import dtalign.reference
from dtalign import benchmarking

IMPLEMENTATIONS = {"reference": dtalign.reference, "dtalign": dtalign}


@pytest.fixture(scope="session")
def bench_inputs() -> benchmarking.Inputs:
    """The scenes of :ref:`contract-scenes` and their derivatives, built once."""
    return benchmarking.build_inputs()


@pytest.fixture(params=sorted(IMPLEMENTATIONS), ids=sorted(IMPLEMENTATIONS))
def impl(request: pytest.FixtureRequest) -> str:
    """The implementation under test: ``reference`` or ``dtalign``."""
    return str(request.param)


@pytest.fixture
def run_workload(
    benchmark: Any, bench_inputs: benchmarking.Inputs, impl: str
) -> Callable[[str], Any]:
    """Benchmark workload ``name`` with the current implementation.

    The call is made once before timing, so Numba compilation (or the
    cache load) is not measured; the group is the workload name and the
    target ratio is recorded in ``extra_info``.
    """

    def run(name: str) -> Any:
        fn = benchmarking.workload_call(name, IMPLEMENTATIONS[impl], bench_inputs)
        fn()
        benchmark.group = name
        benchmark.extra_info["target_ratio"] = benchmarking.TARGETS[name]
        benchmark.extra_info["implementation"] = impl
        return benchmark(fn)

    return run
