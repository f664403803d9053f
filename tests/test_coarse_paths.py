"""The coarse search's two correlations: dense window rows and sparse edge pixels.

Both must give the same integer overlap table for every shift (the result
is then identical by construction); the public search must take the sparse
path for wide windows and huge polylines and still agree with the NumPy
specification.
"""

from __future__ import annotations

import numpy as np
import pytest

import dtalign
from dtalign import reference as ref
from dtalign._kernels import coarse


@pytest.mark.parametrize("seed", range(4))
def test_dense_and_sparse_overlap_agree(seed: int) -> None:
    rng = np.random.default_rng(seed)
    for _ in range(100):
        h, w = (int(x) for x in rng.integers(1, 90, 2))  # windows wider than the image too
        edge = rng.random((h, w)) < rng.uniform(0.0, 0.4)
        flat_px = np.unique(rng.integers(0, h * w, int(rng.integers(1, 60))))
        pv, pu = flat_px // w, flat_px % w
        mv, mu = (int(x) for x in rng.integers(0, 70, 2))
        ef, ew = coarse.flat_words(edge)
        er, ec = coarse.nonzero_in_box(ef, ew, w, 0, h - 1, 0, w - 1)
        sparse = coarse.overlap_sparse(pv, pu, coarse.row_starts(er, h), ec, h, w, mv, mu)
        dense = coarse.overlap_dense(pv, pu, ef, h, w, mv, mu)
        np.testing.assert_array_equal(dense, sparse)


@pytest.mark.parametrize(("shape", "window", "full"), [
    ((120, 300), (5, 100), False),  # 201 column shifts: the sparse path
    ((190, 190), (3, 4), True),  # 36,100 polyline pixels: int16 counts could overflow
])
def test_public_search_on_the_sparse_path_matches_the_reference(shape, window, full) -> None:
    rng = np.random.default_rng(7)
    edge = rng.random(shape) < 0.2
    poly = np.ones(shape, dtype=bool) if full else rng.random(shape) < 0.01
    assert not (np.count_nonzero(poly) <= coarse.DENSE_MAX_PIXELS
                and 2 * window[1] + 1 <= coarse.DENSE_MAX_COLUMNS)
    assert dtalign.coarse_ncc_search(edge, poly, window) == tuple(
        int(x) for x in ref.coarse_ncc_search(edge, poly, window))
