"""The mask scan (word at a time when compiled, see ``_kernels.lanes``) against
``np.flatnonzero`` (any run, any buffer)."""

from __future__ import annotations

import numpy as np
import pytest

from dtalign._kernels import coarse, lanes


def _words(flat: np.ndarray) -> np.ndarray:
    return flat[: flat.size // 8 * 8].view(np.uint64)


@pytest.mark.parametrize("seed", range(6))
def test_fill_matches_flatnonzero_on_every_run(seed: int) -> None:
    rng = np.random.default_rng(seed)
    for _ in range(150):
        n = int(rng.integers(1, 700))  # odd sizes leave bytes past the last word
        density = rng.choice([0.0, 0.002, 0.05, 0.5, 1.0])
        flat = np.where(rng.random(n) < density, rng.integers(1, 256, n), 0).astype(np.uint8)
        start = int(rng.integers(0, n + 1))
        stop = int(rng.integers(start, n + 1))
        expected = start + np.flatnonzero(flat[start:stop])
        out = np.full(n + 1, -1, dtype=np.int64)
        k = lanes.fill(flat, _words(flat), start, stop, out, 0)
        assert k == expected.size
        np.testing.assert_array_equal(out[:k], expected)


def test_fill_counts_past_a_full_buffer_without_writing() -> None:
    flat = np.ones(300, dtype=np.uint8)
    out = np.full(10, -1, dtype=np.int64)
    assert lanes.fill(flat, _words(flat), 3, 290, out, 0) == 287
    np.testing.assert_array_equal(out, np.arange(3, 13))


@pytest.mark.parametrize("box", [(0, 63, 0, 99), (5, 40, 10, 90), (5, 40, 30, 34), (63, 63, 99, 99)])
@pytest.mark.parametrize("density", [0.01, 0.3])
def test_nonzero_in_box_whole_rows_and_per_row(box: tuple[int, int, int, int], density: float) -> None:
    # boxes of a quarter of the width or more are scanned as whole rows and filtered
    rng = np.random.default_rng(7)
    mask = rng.random((64, 100)) < density
    flat = mask.reshape(-1).view(np.uint8)
    r_lo, r_hi, c_lo, c_hi = box
    rows, cols = coarse.nonzero_in_box(flat, _words(flat), 100, r_lo, r_hi, c_lo, c_hi)
    er, ec = np.nonzero(mask[r_lo : r_hi + 1, c_lo : c_hi + 1])
    np.testing.assert_array_equal(rows, er + r_lo)
    np.testing.assert_array_equal(cols, ec + c_lo)


def test_nonzero_in_box_dense_mask_takes_the_second_pass() -> None:
    mask = np.ones((128, 128), dtype=bool)  # 16384 pixels: more than the first buffer
    flat = mask.reshape(-1).view(np.uint8)
    rows, cols = coarse.nonzero_in_box(flat, _words(flat), 128, 0, 127, 0, 127)
    assert rows.size == mask.size
    np.testing.assert_array_equal(rows * 128 + cols, np.arange(mask.size))
