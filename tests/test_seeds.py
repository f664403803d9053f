"""Top-K coarse seeds: the first is the single search's result exactly, on
every parity scene; the rest are distinct local maxima."""

from __future__ import annotations

import math

import numpy as np
import pytest

import dtalign
from dtalign.pipeline.seeds import top_k_seeds
from test_parity_scans import SEEDS, _scene


@pytest.mark.parametrize("seed", SEEDS)
def test_first_seed_is_the_single_search(seed):
    s = _scene(seed)
    edge = np.asarray(s["edge"]) != 0  # the seeds read the mask as nonzero
    window, fraction = s["window"], s["fraction"]
    polarity = top_k_seeds(
        edge, s["verts"], window, k=4, normals_vu=s["normals"], image_gradient_vu=s["grad"],
        min_support_fraction=fraction,
    )
    assert polarity[0] == dtalign.coarse_polarity_search_scored(
        edge, s["grad"], s["verts"], s["normals"], window, min_support_fraction=fraction
    )
    overlap = top_k_seeds(edge, s["verts"], window, k=4, min_support_fraction=fraction)
    mask = dtalign.build_polyline_mask(s["verts"], edge.shape)
    if mask.any():
        assert overlap[0] == dtalign.coarse_ncc_search_scored(
            edge, mask, window, min_support_fraction=fraction
        )
    for seeds in (polarity, overlap):
        assert 1 <= len(seeds) <= 4
        for i, a in enumerate(seeds):
            for b in seeds[i + 1:]:
                assert math.dist(a.offset_vu, b.offset_vu) >= 3.0
                assert a.score >= b.score > 0.0


def test_two_parallel_edges_give_two_seeds():
    """Two same-polarity straight edges 7 px apart: both are seeds, the
    nearer one (of equal score) first; a shift on no edge is no seed."""
    img = np.zeros((80, 80))
    img[:, 30:] = 100.0
    img[:, 38:] = 200.0
    _, dt, grad = dtalign.compute_all_image_derivatives(img, 1.0)
    v = np.arange(10.0, 70.0, 2.0)
    verts = np.stack([v, np.full_like(v, 27.5)], axis=1)  # the model 2 px left of the first edge
    normals = np.tile([0.0, 1.0], (len(v), 1))
    seeds = top_k_seeds(dt <= 0.5, verts, (0, 15), k=3, normals_vu=normals, image_gradient_vu=grad)
    assert [s.offset_vu for s in seeds] == [(0, 2), (0, 9)]  # edges at columns 30 and 37
    assert seeds == top_k_seeds(dt <= 0.5, verts, (0, 15), k=3)  # aligned: polarity agrees


def test_checks():
    edge = np.zeros((10, 10), bool)
    with pytest.raises(ValueError, match="k must be a positive int"):
        top_k_seeds(edge, np.zeros((1, 2)), (2, 2), k=0)
    with pytest.raises(ValueError, match="go together"):
        top_k_seeds(edge, np.zeros((1, 2)), (2, 2), normals_vu=np.ones((1, 2)))
    with pytest.raises(ValueError, match="min_separation_px must be finite"):
        top_k_seeds(edge, np.zeros((1, 2)), (2, 2), min_separation_px=math.nan)
    assert top_k_seeds(edge, np.zeros((0, 2)), (2, 2)) == (dtalign.CoarseSearchResult((0, 0), 0.0),)
