"""Real Cassini frames: the fit brings a displaced model back (skipped without the data).

Data: ``<repo>/../shared/data/cassini`` or ``$DTALIGN_CASSINI_DIR`` (see its
README). The overlay of each summary PNG is the navigation model as the
pipeline drew it; we trace it into a polyline, fit it as drawn (the *base*
fit, where the image's edges are relative to the drawing), then fit it
displaced by a known offset: the fit must return base + displacement.

Tolerances, from the data:

* Displacement recovery, 0.25 px: the DT and the model are the same in
  both fits, so a correct coarse seed leads LM to the same minimum; on
  these frames the difference is below 0.01 px. 0.25 px still catches a
  seed in the wrong basin (those are off by a pixel or more).
* Tethys base offset, 1 px: the sidecar YAML gives the operator-verified
  pointing with ``offset_uncertainty_px: 1.0``, and the overlay is drawn
  at it, so the image limb must lie within ~1 px of the drawing (we
  measure ~0.5 px).
* Keeler ring, 0.5 px across the edge: only the normal component is
  observable. Along the edge nothing is measured (rank 1).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest

from dtalign import io, pipeline
from dtalign.io import cassini

pytestmark = pytest.mark.cassini

TETHYS = "N1634226853_1_CALIB.png"
KEELER = "N1863268207_1_CALIB.png"


def _data_dir() -> Path | None:
    env = os.environ.get("DTALIGN_CASSINI_DIR")
    repo = Path(__file__).resolve().parents[1]
    for cand in (env, repo.parent / "shared" / "data" / "cassini"):
        if cand and (Path(cand) / TETHYS).is_file() and (Path(cand) / KEELER).is_file():
            return Path(cand)
    return None


DATA = _data_dir()
if DATA is None:
    pytest.skip("Cassini frames not present (shared/data/cassini)", allow_module_level=True)


def _setup(name, shape, n_lines):
    frame = cassini.load_cassini_overlay_frame(DATA / name)
    lines = cassini.overlay_polylines(frame, shape=shape, n_lines=n_lines)
    model = io.concatenate_polylines(lines)
    products = pipeline.prepare_image(frame.image)
    return frame, lines, model, products


def _fit(products, model, displacement, window):
    verts = model.vertices_vu - np.asarray(displacement)
    return pipeline.fit_polyline_products(
        products, verts, model.normals_vu, model.sigmas, search_window_vu=window
    )


@pytest.fixture(scope="module")
def tethys():
    frame, lines, model, products = _setup(TETHYS, "limb", 1)
    base = _fit(products, model, (0.0, 0.0), (15, 15))
    return frame, lines, model, products, base


@pytest.fixture(scope="module")
def keeler():
    frame, lines, model, products = _setup(KEELER, "lines", 2)
    base = _fit(products, model, (0.0, 0.0), (30, 30))
    return frame, lines, model, products, base


def test_frames_load_and_overlay_is_removed(tethys, keeler):
    t_frame, k_frame = tethys[0], keeler[0]
    assert t_frame.image.shape == (1024, 1024) and t_frame.header_rows == 0
    assert k_frame.image.shape == (1024, 1024) and k_frame.header_rows == 96
    for frame in (t_frame, k_frame):
        assert frame.overlay_mask.sum() > 1000
        # Overlay pixels were replaced by grey neighbours: no red-level values.
        replaced = frame.image[frame.overlay_mask]
        assert replaced.max() <= frame.image[~frame.overlay_mask].max()


def test_tethys_limb_trace(tethys):
    _, lines, model, *_ = tethys
    assert len(lines) == 1 and len(model) > 1500
    # Ordered by angle around the disc: consecutive vertices are close.
    steps = np.hypot(*np.diff(model.vertices_vu, axis=0).T)
    assert np.median(steps) < 1.5
    # Normals point into the (bright) body: toward the vertex centroid.
    inward = (model.vertices_vu.mean(axis=0) - model.vertices_vu) * model.normals_vu
    assert (inward.sum(axis=1) > 0).mean() > 0.99


def test_tethys_base_fit_is_within_operator_uncertainty(tethys):
    base = tethys[-1]
    assert math.hypot(*base.offset_vu) <= 1.0
    assert base.observable_rank == 2 and not base.at_window_edge
    assert all(0.0 < s < 0.2 for s in base.sigma_vu)
    assert base.lm.inlier_count > 0.95 * len(tethys[2])


@pytest.mark.parametrize("displacement", [(6.0, -4.0), (-9.5, 3.25)])
def test_tethys_displaced_limb_comes_back(tethys, displacement):
    _, _, model, products, base = tethys
    fit = _fit(products, model, displacement, (15, 15))
    err = np.subtract(fit.offset_vu, displacement) - base.offset_vu
    assert np.all(np.abs(err) <= 0.25), err
    assert fit.observable_rank == 2
    assert all(math.isfinite(s) for s in fit.sigma_vu)


def test_keeler_edges_are_two_parallel_lines(keeler):
    _, lines, *_ = keeler
    assert len(lines) == 2 and all(len(p) > 900 for p in lines)
    n0, n1 = lines[0].normals_vu[0], lines[1].normals_vu[0]
    # Parallel, facing away from the dark gap between them (to the ring).
    assert abs(n0[0] * n1[1] - n0[1] * n1[0]) < 1e-12 and n0 @ n1 < 0
    gap_side = lines[1].vertices_vu.mean(axis=0) - lines[0].vertices_vu.mean(axis=0)
    assert n0 @ gap_side < 0


@pytest.mark.parametrize("displacement", [(5.0, 7.0), (-6.0, -2.5)])
def test_keeler_displaced_edges_come_back_across_the_edge(keeler, displacement):
    _, lines, model, products, base = keeler
    fit = _fit(products, model, displacement, (30, 30))
    n = lines[0].normals_vu[0]
    err = np.subtract(fit.offset_vu, displacement) - base.offset_vu
    assert abs(float(err @ n)) <= 0.5, err


def test_keeler_covariance_reports_the_along_edge_direction_unobservable(keeler):
    _, lines, _, _, fit = keeler
    n = lines[0].normals_vu[0]
    along = np.array([n[1], -n[0]])
    # The geometry is rank 1 and its null direction is the edge direction.
    assert fit.observable_rank == 1
    (e,) = fit.unobservable_directions
    assert abs(abs(float(e @ along)) - 1.0) < 1e-9
    # The pseudoinverse reports ~0 variance along the edge ...
    cov = np.asarray(fit.uncertainty.normal_covariance)
    across_var = float(n @ cov @ n)
    assert 0.0 < across_var < 0.01
    assert abs(float(along @ cov @ along)) <= 1e-9 * across_var
    # ... and the inf reading says "unobservable": both axes involve it.
    assert fit.sigma_vu == (math.inf, math.inf)
    assert np.all(np.isinf(fit.uncertainty.covariance_unobservable_inf))
    # The across-edge uncertainty stays finite and sub-pixel.
    assert 0.0 < fit.sigma_along(n) < 0.2
