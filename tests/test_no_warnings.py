"""The drop-in surface never warns.

Today's techniques run their tests with warnings as errors, so a
``RuntimeWarning`` from an overflow, a ``0 * inf`` or an empty mean inside
dtalign fails them. Every drop-in function runs here on ordinary,
degenerate and extreme inputs the reference accepts, with every warning an
error.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import dtalign

pytestmark = pytest.mark.filterwarnings("error")

H = W = 40


def _inputs(seed: int) -> dict:
    rng = np.random.default_rng(seed)
    scale = [1.0, 1e-300, 1e150, 1e300][seed % 4]
    img = rng.normal(size=(H, W)) * scale
    if seed % 5 == 0:
        img = np.zeros((H, W))  # no edge at all: a flat DT
    n = int(rng.integers(1, 30))
    verts = rng.uniform(-10, H + 10, size=(n, 2))
    if seed % 7 == 0:
        verts += 1e6  # every vertex far off the frame
    normals = rng.normal(size=(n, 2))
    normals[rng.random(n) < 0.2] = 0.0
    sigmas = rng.uniform(1e-3, 1e3, size=n)
    return dict(rng=rng, img=img, noise=scale, verts=verts, normals=normals, sigmas=sigmas)


@pytest.mark.parametrize("seed", range(40))
def test_drop_in_functions_do_not_warn(seed):
    s = _inputs(seed)
    img, verts, normals, sigmas = s["img"], s["verts"], s["normals"], s["sigmas"]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mag, dt, grad = dtalign.compute_all_image_derivatives(img, s["noise"])
        dtalign.compute_image_gradient_vu(img)
        dtalign.build_image_edge_dt(img, 0.0)
        edge = dt <= 0.5
        mask = dtalign.build_polyline_mask(verts, dt.shape)
        seed_vu = dtalign.coarse_ncc_search(edge, mask, (5, 5))
        scored = dtalign.coarse_ncc_search_scored(edge, mask, (5, 5), min_support_fraction=0.0)
        dtalign.coarse_ncc_search_scored(edge * 0.25, mask, (3, 3))
        nan_grad = grad.copy()
        nan_grad[::3, ::5] = np.nan
        nan_grad[1::7, ::3] = np.inf
        pol = dtalign.coarse_polarity_search_scored(edge, nan_grad, verts, normals, (4, 4))
        dtalign.polarity_filter(verts, normals, grad, offset_vu=(0.5, -0.5))
        dtalign.sample_dt_bilinear(dt, verts)
        dtalign.apply_translation(verts, 1e300, -1e300)
        dtalign.tukey_biweight_weights(np.array([0.0, 1e300, -1e300, np.nan, np.inf]))
        jac = s["rng"].normal(size=(len(verts), 2))
        for w in (np.zeros(len(verts)), sigmas, np.full(len(verts), 1e300)):
            cov = dtalign.information_matrix_to_covariance(jac, w)
            _ = 0.0 * cov  # a caller's s2 * cov with s2 == 0
        dtalign.information_matrix_to_covariance(np.zeros((0, 2)), np.zeros(0))
        for kw in (
            {},
            {"use_polarity": False, "trust_region_px": 1.0, "tikhonov_alpha": 0.5},
            {"fit_rotation": True, "pivot_distance_px": 20.0, "final_gradient_ridge": True},
            {"max_iterations": 0},
        ):
            fit = dtalign.lm_subpixel_refine(
                vertices_vu=verts, normals_vu=normals, sigma_normal_per_vertex_px=sigmas,
                image_edge_dt=dt, image_gradient_vu=grad,
                initial_offset_vu=(float(seed_vu[0]), float(seed_vu[1])), **kw,
            )
            # a degenerate fit's covariance is the +inf sentinel (:ref:`contract-lm`), by design
            assert np.isinf(fit.covariance).all() == fit.degenerate
        dtalign.gradient_ridge_refine(
            vertices_vu=verts, normals_vu=normals, sigma_normal_per_vertex_px=sigmas,
            gradient_magnitude=mag, initial_offset_vu=(0.0, 0.0),
        )
        basin = dtalign.find_secondary_dt_minimum(
            dt, verts, converged_offset_vu=(0.3, -0.2), search_window_vu=(4, 4),
            exclude_radius_px=1.0, min_support_fraction=0.0,
        )
        dtalign.find_secondary_dt_minimum(
            dt, verts[:0], converged_offset_vu=(0.0, 0.0), search_window_vu=(4, 4),
            exclude_radius_px=1.0,
        )
        config = dtalign.DTFitGateConfig(0.84, 0.35, 0.10, 0.05)
        for total in (0, len(verts)):
            dtalign.evaluate_dt_fit_gates(
                fit, config, coarse_peak_fraction=float("nan") if total else scored.score,
                total_vertex_count=total, use_polarity=True,
            )
        big = verts * 1e300
        dtalign._rotate_vertices(big, (0.0, 0.0), 0.5)
        dtalign._rotate_directions(big, 0.5)
    assert pol.score >= 0.0 and (basin is None or basin.cost_px >= 0.0)
