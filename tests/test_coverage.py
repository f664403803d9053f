"""The coverage harness (:mod:`dtalign.benchmarking.coverage`) counts what it says."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dtalign.benchmarking import coverage as cov


@pytest.fixture(scope="module")
def rows_by_reading():
    readings = {
        "huge": lambda fit: 1e6 * np.eye(2),
        "tiny": lambda fit: 1e-12 * np.eye(2),
        "inf": lambda fit: np.full((2, 2), np.inf),
        "prior": cov.READINGS["prior"],
    }
    return cov.evaluate(cov.plain_fit, ["crater_rim", "sphere_limb"], range(3), readings)


def test_a_huge_ellipse_covers_everything_and_a_tiny_one_nothing(rows_by_reading) -> None:
    for row in rows_by_reading:
        assert row.fits == 3
        assert row.ok + round(row.flagged * row.fits) == row.fits
        assert row.ok > 0, row
        assert row.coverage["huge"][:2] == (1.0, 1.0)
        assert row.coverage["tiny"][:2] == (0.0, 0.0)
        # an infinite covariance makes no claim: counted inside
        assert row.coverage["inf"][:2] == (1.0, 1.0)
        assert math.isinf(row.coverage["inf"][2])
        assert row.coverage["huge"][2] == pytest.approx(1e3)


def test_the_median_error_is_the_fits_error(rows_by_reading) -> None:
    limb = next(r for r in rows_by_reading if r.family == "sphere_limb")
    # the plain fit of a lit limb is pulled away from the sun by a few tenths
    assert 0.05 < limb.median_error_px < 1.0
    table = cov.format_table(rows_by_reading)
    assert "| sphere_limb | 3 |" in table
    assert "prior 95 %" in table.splitlines()[0]


def test_an_error_along_an_unobserved_direction_makes_no_claim() -> None:
    across = (1.0, 0.0)
    d2, sigma = cov._inside(np.array([0.3, 5.0]), np.diag([0.01, 0.0]), across)
    assert d2 == pytest.approx(9.0)
    assert sigma == pytest.approx(0.1)
    d2, _ = cov._inside(np.array([0.3, 5.0]), np.diag([0.01, 0.0]), None)
    assert d2 == pytest.approx(9.0)  # the zero-variance direction is left out


def test_unknown_family_is_named() -> None:
    with pytest.raises(ValueError, match="families: unknown family 'nope'"):
        cov.evaluate(cov.plain_fit, ["nope"], range(1))


def test_sphere_cases_are_seeded_and_noisy_enough() -> None:
    a, b = cov.FAMILIES["sphere_terminator"](4), cov.FAMILIES["sphere_terminator"](4)
    np.testing.assert_array_equal(a.image, b.image)
    assert a.extra["edge"] == "terminator"
    assert 35.0 <= a.extra["phase_deg"] <= 150.0
    assert a.noise_sigma > 0.0
