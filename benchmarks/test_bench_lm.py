"""LM refinement workloads of :ref:`contract-scenes` (inputs: the coarse seed of each polyline)."""

from __future__ import annotations

import pytest


@pytest.mark.parametrize(
    "name",
    [
        "lm_n200",  # target >= 50x
        "lm_trust_region",  # >= 50x
        "lm_rotation",  # >= 50x
        "lm_ridge",  # >= 40x
        "lm_n2000",  # informational
        "lm_n20000",  # >= 30x
        "lm_outliers",  # informational
    ],
)
def test_lm(run_workload, name):
    result = run_workload(name)
    assert abs(result.offset_vu[0] - 7.3) < 0.5 and abs(result.offset_vu[1] + 4.6) < 0.5
