"""End to end on the navigation scene (target >= 10x).

Derivatives of the 1024 x 1024 image, then for each of the three polylines
(limb, terminator arc, straight ring edge): polyline mask, coarse search
+-30 and LM with the production trust region of 1 px.
"""

from __future__ import annotations


def test_end_to_end(run_workload):
    fits = run_workload("end_to_end")
    assert len(fits) == 3
