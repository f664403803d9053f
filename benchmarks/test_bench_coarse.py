"""Coarse integer search on the 200-pixel limb, +-30 and +-50 (targets >= 300x)."""

from __future__ import annotations

import pytest


@pytest.mark.parametrize("name", ["coarse_30", "coarse_50"])
def test_coarse(run_workload, name):
    assert run_workload(name) == (7, -5)
