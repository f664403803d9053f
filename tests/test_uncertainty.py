"""Honest uncertainty: no finite sigma along an unobservable direction; a calibrated scaled one."""

from __future__ import annotations

import logging
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import dtalign
from dtalign import scenes
from dtalign.io import save_polyline_csv
from dtalign.pipeline import fit_polyline, fit_polyline_products, prepare_image


@pytest.fixture(scope="module")
def nav():
    return scenes.navigation_scene(shape=(512, 512), radius=80.0)


@pytest.fixture(scope="module")
def ring_fit(nav):
    products = prepare_image(nav.image, nav.noise_sigma)
    ring = nav.polylines[2]
    return fit_polyline_products(products, ring.vertices_vu, ring.normals_vu, ring.sigmas,
                                 search_window_vu=(12, 12), trust_region_px=1.0)


def test_ring_sigma_vu_is_inf_along_the_edge(ring_fit):
    assert ring_fit.observable_rank == 1
    sv, su = ring_fit.sigma_vu
    assert math.isfinite(sv) and 0.0 < sv < 0.5
    assert su == math.inf  # the DT covariance alone said ~1 px here
    assert math.isfinite(float(np.sqrt(ring_fit.covariance[1, 1])))
    assert ring_fit.uncertainty.sigma_vu_scaled[1] == math.inf
    assert ring_fit.sigma_along((0.0, 1.0)) == math.inf
    assert ring_fit.sigma_along((1.0, 0.0)) == pytest.approx(sv)
    ((e, x, s),) = ring_fit.observable_offset()
    assert e == (1.0, 0.0) and x == ring_fit.offset_vu[0] and s == pytest.approx(sv)


def test_full_rank_sigmas_are_the_covariance_diagonal(nav):
    products = prepare_image(nav.image, nav.noise_sigma)
    limb = nav.polylines[0]
    fit = fit_polyline_products(products, limb.vertices_vu, limb.normals_vu, limb.sigmas,
                                search_window_vu=(12, 12))
    assert fit.observable_rank == 2
    assert fit.sigma_vu == tuple(float(x) for x in np.sqrt(np.diag(fit.covariance)))


def test_circle_rotation_sigma_is_inf():
    scene = scenes.disc_scene(shape=(300, 300), radius=80.0, rotation_rad=0.01)
    p = scene.polyline
    fit = fit_polyline(scene.image, p.vertices_vu, p.normals_vu, p.sigmas, search_window_vu=(10, 10),
                       fit_rotation=True, pivot_vu=scene.pivot_vu,
                       pivot_distance_px=scene.pivot_distance_px)
    assert fit.observable_rank == 2
    assert fit.sigma_rotation_rad == math.inf
    assert all(math.isfinite(s) for s in fit.sigma_vu)


def test_variance_factor_is_the_reduced_chi_square(nav):
    products = prepare_image(nav.image, nav.noise_sigma)
    limb = nav.polylines[0]
    fit = fit_polyline_products(products, limb.vertices_vu, limb.normals_vu, 0.5 * limb.sigmas,
                                search_window_vu=(12, 12))
    w, r = np.asarray(fit.lm.weights), np.asarray(fit.lm.residuals_px)
    kept = w > 0
    assert fit.uncertainty.variance_factor == pytest.approx(np.sum(w[kept] * r[kept] ** 2) / (kept.sum() - 2))
    assert np.allclose(fit.uncertainty.covariance_scaled, fit.uncertainty.covariance_mestimator * fit.uncertainty.variance_factor)
    s = math.sqrt(fit.uncertainty.variance_factor)
    m_sigmas = np.sqrt(np.diag(fit.uncertainty.covariance_mestimator))
    assert fit.uncertainty.sigma_vu_scaled == pytest.approx(tuple(x * s for x in m_sigmas))
    d = np.array([0.6, 0.8])
    assert fit.sigma_along(d, scaled=True) == pytest.approx(
        math.sqrt(d @ fit.uncertainty.covariance_mestimator @ d) * s)


def test_degenerate_fit_has_infinite_sigmas(nav):
    products = prepare_image(nav.image, nav.noise_sigma)
    limb = nav.polylines[0]
    fit = fit_polyline_products(products, limb.vertices_vu, 0 * limb.normals_vu, limb.sigmas,
                                search_window_vu=(12, 12))  # zero normals: nothing matches
    assert fit.lm.degenerate and fit.uncertainty.variance_factor == math.inf
    assert fit.sigma_vu == (math.inf, math.inf) == fit.uncertainty.sigma_vu_scaled
    assert np.isinf(fit.uncertainty.covariance_scaled).all()
    assert fit.observable_offset() == []


#: Scenes of the calibration test, and the factor the one-sigma must be within.
N_SCENES = 120
FACTOR = 2.0


def test_scaled_sigma_matches_the_real_scatter_over_seeded_scenes(caplog):
    """Over 120 seeded disc scenes (noise 1, 2 and 4 DN, random sub-pixel
    offsets, production trust region) the scaled one-sigma is within a
    factor 2 of the real RMS error on each axis, and so is the pipeline's
    own (``sigma_vu``); the M-estimator's prior one is not.

    Measured when written: scaled / real 1.21 (v) and 1.25 (u); prior / real
    4.3 and 4.5.
    """
    caplog.set_level(logging.ERROR, logger="dtalign")
    err, prior, scaled, honest = [], [], [], []
    for k in range(N_SCENES):
        rng = np.random.default_rng(k)
        offset = tuple(float(x) for x in rng.uniform(-6.0, 6.0, 2))
        noise = (1.0, 2.0, 4.0)[k % 3]
        scene = scenes.disc_scene(shape=(320, 320), radius=100.0, n_vertices=200,
                                  offset_vu=offset, noise_sigma=noise, seed=k)
        p = scene.polyline
        fit = fit_polyline(scene.image, p.vertices_vu, p.normals_vu, p.sigmas,
                           search_window_vu=(10, 10), noise_sigma=noise, trust_region_px=1.0)
        assert not fit.failed
        err.append(np.subtract(fit.offset_vu, offset))
        prior.append(np.sqrt(np.diag(fit.uncertainty.covariance_mestimator)))
        scaled.append(fit.uncertainty.sigma_vu_scaled)
        honest.append(fit.sigma_vu)
    rms = lambda a: np.sqrt(np.mean(np.square(a), axis=0))  # noqa: E731
    real, prior_rms, scaled_rms = rms(err), rms(prior), rms(scaled)
    ratio = scaled_rms / real
    assert np.all(ratio < FACTOR) and np.all(ratio > 1.0 / FACTOR), ratio
    assert np.all(prior_rms / real > FACTOR)  # why the scaled option exists
    ratio = rms(honest) / real
    assert np.all(ratio < FACTOR) and np.all(ratio > 1.0 / FACTOR), ratio


# --------------------------------------------------------------------------- CLI


def _python_m(*argv, cwd):
    env = dict(os.environ)
    src = str(Path(dtalign.__file__).resolve().parents[1])
    env["PYTHONPATH"] = src + os.pathsep + env.get("PYTHONPATH", "")
    return subprocess.run([sys.executable, "-m", "dtalign", *argv], capture_output=True,
                          text=True, cwd=cwd, env=env, timeout=300)


def test_cli_main_line_leads_with_the_observable_reading(nav, tmp_path):
    np.save(tmp_path / "nav.npy", nav.image)
    save_polyline_csv(tmp_path / "ring.csv", nav.polylines[2])
    proc = _python_m("fit", "nav.npy", "ring.csv", "--window", "12", "--trust-region", "1",
                     cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    (line,) = [x for x in proc.stdout.splitlines() if x.startswith("offset")]
    assert "rank 1 of 2: along (1.0000, 0.0000):" in line
    assert "not measured along (0.0000, 1.0000)" in line
    # the only "±" on the line is the observed direction's
    assert line.count("±") == 1 and line.index("±") < line.index("not measured")


def test_demo_runs_production_settings_and_explains_converged():
    proc = _python_m("demo", "--json", cwd=None)
    assert proc.returncode == 0, proc.stderr
    import json

    out = json.loads(proc.stdout)
    scene = scenes.disc_scene()
    p = scene.polyline
    fit = fit_polyline(scene.image, p.vertices_vu, p.normals_vu, p.sigmas, noise_sigma=2.0,
                       search_window_vu=(30, 30), trust_region_px=1.0)
    assert out["fit"]["offset_vu"] == list(fit.offset_vu)
    proc = _python_m("demo", cwd=None)
    assert proc.returncode == 0, proc.stderr
    lm_line = proc.stdout[proc.stdout.index("LM "):]
    # the LM stops at the cap, but its pose has settled there, so
    # the demo says so in a few words and carries no not_converged reason
    assert "iterations (cap 30), settled (moved " in lm_line
    assert "status    : ok\n" in proc.stdout
    assert "scaled    :" in proc.stdout
