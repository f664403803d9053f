"""Image side: compute_all_image_derivatives on the 1024 x 1024 disc (target >= 5x)."""

from __future__ import annotations


def test_derivatives_1024(run_workload):
    magnitude, edge_dt, gradient = run_workload("derivatives_1024")
    assert edge_dt.shape == (1024, 1024)
