"""Coarse integer searches on the 200-pixel limb, +-30 and +-50 (targets >= 300x),
and the competing-basin scan (:ref:`contract-today`)."""

from __future__ import annotations

import pytest


@pytest.mark.parametrize("name", ["coarse_30", "coarse_50"])
def test_coarse(run_workload, name):
    assert run_workload(name) == (7, -5)


def test_coarse_scored(run_workload):
    assert run_workload("coarse_scored_30").offset_vu == (7, -5)


def test_polarity_search(run_workload):
    assert run_workload("polarity_search_30").offset_vu == (7, -5)


def test_secondary_basin(run_workload):
    rival = run_workload("secondary_basin_30")
    assert rival is not None and rival.distance_px > 3.0
