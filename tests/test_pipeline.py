"""One-call pipeline: fit_polyline, shared image products, noise, covariance readings."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from dtalign import pipeline, scenes
from dtalign.pipeline import (
    ImageProducts,
    PolylineFit,
    covariance_with_unobservable_inf,
    estimate_noise_sigma,
    fit_polyline,
    fit_polyline_products,
    normal_information_covariance,
    null_directions,
    observable_rank,
    prepare_image,
)


@pytest.fixture(scope="module")
def disc():
    return scenes.disc_scene()


@pytest.fixture(scope="module")
def disc_fit(disc):
    p = disc.polyline
    return fit_polyline(disc.image, p.vertices_vu, p.normals_vu, p.sigmas, search_window_vu=(30, 30))


@pytest.fixture(scope="module")
def small():
    """A 256 x 256 disc: fast enough for the many validation tests."""
    return scenes.disc_scene(shape=(256, 256), radius=60.0, n_vertices=120, offset_vu=(3.4, -2.2))


@pytest.fixture(scope="module")
def small_products(small):
    return prepare_image(small.image, small.noise_sigma)


def _fit_small(products, scene, **kw):
    p = scene.polyline
    kw.setdefault("search_window_vu", (10, 10))
    return fit_polyline_products(products, p.vertices_vu, p.normals_vu, p.sigmas, **kw)


# --------------------------------------------------------------------------- accuracy


def test_fit_polyline_recovers_disc_offset(disc, disc_fit):
    fit = disc_fit
    assert isinstance(fit, PolylineFit)
    err = np.subtract(fit.offset_vu, disc.true_offset_vu)
    assert np.all(np.abs(err) < 0.1), err
    # The coarse seed is the nearest integer shift (or next to it).
    assert np.all(np.abs(np.subtract(fit.coarse_offset_vu, disc.true_offset_vu)) <= 1.0)
    # A sensible sigma: finite, sub-pixel, larger than the bare error would need.
    assert all(0.01 < s < 1.0 for s in fit.sigma_vu)
    assert fit.sigma_vu == pytest.approx(tuple(np.sqrt(np.diag(fit.covariance))))
    assert not fit.at_window_edge and not fit.lm.degenerate
    assert fit.observable_rank == 2 and fit.unobservable_directions.shape == (0, 2)
    assert fit.noise_sigma == pytest.approx(2.0, rel=0.1)  # estimated
    assert fit.lm.inlier_count == len(disc.polyline)
    assert not fit.polarity_rejected.any() and not fit.tukey_rejected.any()


def test_fitted_pose_lands_model_on_the_limb(disc, disc_fit):
    p = disc.polyline
    moved = disc_fit.transform(p.vertices_vu)
    centre = np.array([511.5, 511.5])
    radii = np.hypot(*(moved - centre).T)
    assert np.abs(radii - 150.0).max() < 1.0


def test_shared_products_give_identical_results(small, small_products):
    p = small.polyline
    one_call = fit_polyline(
        small.image, p.vertices_vu, p.normals_vu, p.sigmas, search_window_vu=(10, 10),
        noise_sigma=small.noise_sigma,
    )
    shared = _fit_small(small_products, small)
    assert shared.offset_vu == one_call.offset_vu
    assert shared.coarse_offset_vu == one_call.coarse_offset_vu
    np.testing.assert_array_equal(shared.covariance, one_call.covariance)
    np.testing.assert_array_equal(shared.lm.residuals_px, one_call.lm.residuals_px)
    np.testing.assert_array_equal(shared.lm.weights, one_call.lm.weights)
    # Fitting again from the same products does not change them.
    again = _fit_small(small_products, small)
    assert again.offset_vu == shared.offset_vu


def test_several_polylines_share_one_image():
    scene = scenes.navigation_scene(shape=(400, 400), radius=70.0, n_vertices=100)
    products = prepare_image(scene.image, scene.noise_sigma)
    fits = {
        p.name: fit_polyline_products(
            products, p.vertices_vu, p.normals_vu, p.sigmas, search_window_vu=(12, 12)
        )
        for p in scene.polylines
    }
    for name in ("limb", "terminator"):
        err = np.subtract(fits[name].offset_vu, scene.true_offset_vu)
        assert np.all(np.abs(err) < 0.3), (name, err)
    # The straight ring edge (normals all (1, 0)) measures v only: rank 1,
    # unobservable along u, and the inf reading says so for u.
    ring = fits["ring"]
    # The scene draws the ring band from row ceil(ring_top) but puts the
    # model edge at ring_top - 0.5, up to a pixel apart: only ~1 px here.
    assert abs(ring.offset_vu[0] - scene.true_offset_vu[0]) < 1.0
    assert ring.observable_rank == 1
    np.testing.assert_allclose(np.abs(ring.unobservable_directions), [[0.0, 1.0]], atol=1e-12)
    sv, su = ring.sigma_vu
    assert math.isfinite(sv) and su == math.inf
    assert ring.sigma_along((1.0, 0.0)) == pytest.approx(ring.sigma_vu[0])


def test_products_are_read_only_and_consistent(small, small_products):
    pr = small_products
    assert isinstance(pr, ImageProducts)
    assert pr.shape == small.image.shape and pr.noise_sigma == small.noise_sigma
    assert not pr.noise_sigma_estimated
    np.testing.assert_array_equal(pr.edge_mask, pr.edge_dt <= 0.5)
    assert pr.gradient_vu.shape == (*small.image.shape, 2)
    for arr in (pr.edge_dt, pr.edge_mask, pr.gradient_vu, pr.gradient_magnitude):
        with pytest.raises(ValueError):
            arr[0, 0] = 1
    estimated = prepare_image(small.image)
    assert estimated.noise_sigma_estimated
    assert estimated.noise_sigma == pytest.approx(small.noise_sigma, rel=0.1)


def test_at_window_edge_when_truth_is_outside_the_window(small_products, small):
    fit = _fit_small(small_products, small, search_window_vu=(2, 2))
    assert fit.at_window_edge
    assert max(abs(c) for c in fit.coarse_offset_vu) == 2
    # A zero margin is not searched, so it never flags.
    fit0 = _fit_small(small_products, small, search_window_vu=(0, 5))
    assert fit0.coarse_offset_vu[0] == 0 and fit0.at_window_edge is (abs(fit0.coarse_offset_vu[1]) == 5)


def test_rotation_defaults_pivot_and_distance(small_products, small):
    fit = _fit_small(small_products, small, fit_rotation=True)
    p = small.polyline
    assert fit.pivot_vu == pytest.approx(tuple(p.vertices_vu.mean(axis=0)))
    centre = (np.array(small.image.shape) - 1) / 2.0
    assert fit.pivot_distance_px == pytest.approx(max(np.hypot(*(fit.pivot_vu - centre)), 1.0))
    assert fit.sigma_rotation_rad is not None and fit.covariance.shape == (3, 3)
    # A circle turned about its centre looks the same: rotation is unobservable.
    assert fit.observable_rank == 2
    given = _fit_small(small_products, small, fit_rotation=True, pivot_vu=(100.0, 100.0), pivot_distance_px=50.0)
    assert given.pivot_vu == (100.0, 100.0) and given.pivot_distance_px == 50.0


def test_lm_options_pass_through(small_products, small):
    fit = _fit_small(small_products, small, trust_region_px=1.0, max_iterations=0)
    assert fit.lm.iterations == 0
    assert fit.offset_vu == tuple(float(c) for c in fit.coarse_offset_vu)
    ridge = _fit_small(small_products, small, final_gradient_ridge=True, tikhonov_alpha=1e-3)
    assert np.all(np.abs(np.subtract(ridge.offset_vu, small.true_offset_vu)) < 0.5)
    nopol = _fit_small(small_products, small, use_polarity=False)
    assert not nopol.polarity_rejected.any()


def test_to_dict_is_json(disc_fit):
    d = json.loads(json.dumps(disc_fit.to_dict()))
    assert d["offset_vu"] == list(disc_fit.offset_vu)
    assert d["observable_rank"] == 2 and d["n_vertices"] == 200
    assert set(d["timings_s"]) >= {"derivatives", "coarse", "lm"}


def test_polyline_outside_the_image_is_degenerate_not_an_error(small_products):
    verts = np.array([[-500.0, -500.0], [-501.0, -500.0], [-502.0, -500.0]])
    normals = np.tile([1.0, 0.0], (3, 1))
    fit = fit_polyline_products(
        small_products, verts, normals, np.ones(3), search_window_vu=(3, 3), use_polarity=False
    )
    assert fit.coarse_offset_vu == (0, 0)
    d = json.loads(json.dumps(fit.to_dict()))
    assert isinstance(d, dict)


# --------------------------------------------------------------------------- noise


@pytest.mark.parametrize("sigma", [0.5, 2.0, 5.0])
def test_noise_estimate_on_disc_scene(sigma):
    scene = scenes.disc_scene(noise_sigma=sigma, seed=3)
    assert estimate_noise_sigma(scene.image) == pytest.approx(sigma, rel=0.1)


def test_noise_estimate_ignores_smooth_shading():
    rng = np.random.default_rng(1)
    vv, uu = np.mgrid[0:200, 0:200]
    image = 0.5 * vv + 0.2 * uu + rng.normal(0.0, 1.5, (200, 200))
    assert estimate_noise_sigma(image) == pytest.approx(1.5, rel=0.1)


def test_noise_estimate_edge_cases():
    assert estimate_noise_sigma(np.full((50, 50), 7.0)) == 0.0
    assert estimate_noise_sigma(np.zeros((2, 40))) == 0.0
    with pytest.raises(TypeError, match="image_ext must be 2-D"):
        estimate_noise_sigma(np.zeros((3, 3, 3)))
    with pytest.raises(ValueError, match="finite"):
        estimate_noise_sigma(np.array([[0.0, np.nan], [1.0, 2.0]]))


# --------------------------------------------------------------------------- covariance


def test_inf_mapping_of_a_rank_one_covariance():
    cov = np.array([[0.0, 0.0], [0.0, 0.04]])
    out = covariance_with_unobservable_inf(cov)
    assert out[0, 0] == math.inf and out[1, 1] == pytest.approx(0.04)
    assert out[0, 1] == 0.0 and out[1, 0] == 0.0
    assert observable_rank(cov) == 1
    np.testing.assert_allclose(np.abs(null_directions(cov)), [[1.0, 0.0]])
    # A diagonal edge: its along-edge direction involves both axes.
    e = np.array([1.0, 1.0]) / math.sqrt(2.0)
    n = np.array([1.0, -1.0]) / math.sqrt(2.0)
    diag_cov = 0.01 * np.outer(n, n)
    out = covariance_with_unobservable_inf(diag_cov)
    assert np.all(np.isinf(out)) and out[0, 0] > 0 and out[0, 1] > 0
    assert observable_rank(diag_cov) == 1
    np.testing.assert_allclose(np.abs(null_directions(diag_cov)[0]), np.abs(e), atol=1e-12)


def test_inf_mapping_leaves_full_rank_and_degenerate_alone():
    cov = np.array([[0.02, 0.005], [0.005, 0.03]])
    np.testing.assert_allclose(covariance_with_unobservable_inf(cov), cov, rtol=1e-12)
    assert observable_rank(cov) == 2
    inf = np.full((2, 2), np.inf)
    assert np.all(covariance_with_unobservable_inf(inf) == np.inf)
    assert observable_rank(inf) == 0
    assert np.all(covariance_with_unobservable_inf(np.zeros((3, 3))) == np.inf)
    # Extra null directions project the finite part out.
    out = covariance_with_unobservable_inf(cov, null_directions=[[0.0, 2.0]])
    assert out[1, 1] == math.inf and out[0, 0] == pytest.approx(0.02)
    with pytest.raises(ValueError, match="square"):
        covariance_with_unobservable_inf(np.zeros((2, 3)))
    with pytest.raises(ValueError, match="NaN"):
        covariance_with_unobservable_inf(np.array([[np.nan, 0.0], [0.0, 1.0]]))
    with pytest.raises(ValueError, match="rcond"):
        observable_rank(cov, rcond=-1.0)


def test_normal_information_covariance():
    verts = np.column_stack([np.full(50, 10.0), np.arange(50.0)])
    normals = np.tile([1.0, 0.0], (50, 1))
    cov = normal_information_covariance(verts, normals, np.ones(50))
    assert cov[0, 0] == pytest.approx(1.0 / 50) and abs(cov[1, 1]) < 1e-15
    assert observable_rank(cov) == 1
    cov3 = normal_information_covariance(verts, normals, np.ones(50), fit_rotation=True)
    assert cov3.shape == (3, 3) and observable_rank(cov3) == 2
    assert np.all(np.isinf(normal_information_covariance(verts, normals, np.zeros(50))))
    with pytest.raises(ValueError, match="weights"):
        normal_information_covariance(verts, normals, -np.ones(50))


# --------------------------------------------------------------------------- validation


@pytest.mark.parametrize(
    ("kwargs", "exc", "match"),
    [
        ({"vertices_vu": np.zeros((5, 3))}, ValueError, "vertices_vu must have shape"),
        ({"vertices_vu": np.zeros((0, 2))}, ValueError, "vertices_vu must have shape"),
        ({"normals_vu": np.zeros((4, 2))}, ValueError, "normals_vu must match"),
        ({"sigmas": np.ones(4)}, ValueError, "sigmas must be a 1-D vector"),
        ({"sigmas": -np.ones(120)}, ValueError, "sigmas must be finite and > 0"),
        ({"search_window_vu": np.array([3, 3])}, ValueError, "length-2 sequence of ints"),
        ({"search_window_vu": (3.0, 3)}, TypeError, r"search_window_vu\[0\] must be int"),
        ({"search_window_vu": (3, -1)}, ValueError, "must be non-negative"),
        ({"fit_rotation": True, "pivot_distance_px": 0.0}, ValueError, "pivot_distance_px > 0"),
        ({"pivot_vu": (1.0, np.nan)}, ValueError, "pivot_vu must be finite"),
        ({"trust_region_px": -1.0}, ValueError, "trust_region_px"),
        ({"tikhonov_alpha": np.nan}, ValueError, "tikhonov_alpha"),
    ],
)
def test_fit_validation(small_products, small, kwargs, exc, match):
    p = small.polyline
    args = {
        "vertices_vu": p.vertices_vu,
        "normals_vu": p.normals_vu,
        "sigmas": p.sigmas,
        "search_window_vu": (5, 5),
    }
    args.update(kwargs)
    with pytest.raises(exc, match=match):
        fit_polyline_products(
            small_products, args.pop("vertices_vu"), args.pop("normals_vu"), args.pop("sigmas"), **args
        )


def test_image_and_products_validation(small):
    p = small.polyline
    with pytest.raises(TypeError, match="products must be an ImageProducts"):
        fit_polyline_products(small.image, p.vertices_vu, p.normals_vu, p.sigmas, search_window_vu=(1, 1))
    # (H, W, 3 or 4) is a colour image, converted to grey; (H, W, 2) is not an image
    with pytest.raises(TypeError, match="image must be 2-D"):
        fit_polyline(np.zeros((4, 4, 2)), p.vertices_vu, p.normals_vu, p.sigmas, search_window_vu=(1, 1))
    with pytest.raises(ValueError, match="image must not be empty"):
        prepare_image(np.zeros((0, 5)))
    with pytest.raises(ValueError, match="noise_sigma must be finite and >= 0"):
        prepare_image(small.image, -1.0)
    with pytest.raises(TypeError, match="config"):
        prepare_image(small.image, 1.0, config={"image_gradient_sigma_px": 2.0})


def test_public_names_listed():
    for name in pipeline.__all__:
        assert hasattr(pipeline, name)


def test_subpackages_reexport_their_modules_names():
    # dtalign.pipeline re-exports the one-call fit, the products and the
    # observability helpers; dtalign.io re-exports the file functions of
    # dtalign.io.files (the Cassini helpers of dtalign.io.cassini build on
    # them and are not imported by the package: CHANGELOG, Unreleased).
    from dtalign import io
    from dtalign.io import files
    from dtalign.pipeline import fit, observability

    for module in (fit, observability, products_module()):
        for name in module.__all__:
            assert name in pipeline.__all__ and getattr(pipeline, name) is getattr(module, name)
    assert sorted(io.__all__) == sorted(files.__all__)
    for name in files.__all__:
        assert getattr(io, name) is getattr(files, name)


def products_module():
    from dtalign.pipeline import products

    return products


def test_image_products_names_reexported_from_pipeline():
    # estimate_noise_sigma, ImageProducts and prepare_image moved to
    # dtalign.pipeline.products; pipeline and the top-level package re-export the same objects.
    import dtalign
    from dtalign.pipeline import ImageProducts as ImageProductsFromPipeline
    from dtalign.pipeline import estimate_noise_sigma as estimate_from_pipeline
    from dtalign.pipeline import prepare_image as prepare_from_pipeline
    from dtalign.pipeline import products

    assert sorted(products.__all__) == ["ImageProducts", "estimate_noise_sigma", "prepare_image"]
    for name in products.__all__:
        assert name in pipeline.__all__
        assert getattr(pipeline, name) is getattr(products, name)
        assert getattr(dtalign, name) is getattr(products, name)
        assert getattr(products, name).__module__ == "dtalign.pipeline.products"
    assert prepare_from_pipeline is products.prepare_image
    assert ImageProductsFromPipeline is products.ImageProducts
    assert estimate_from_pipeline is products.estimate_noise_sigma
    assert prepare_image is products.prepare_image and ImageProducts is products.ImageProducts
    assert estimate_noise_sigma is products.estimate_noise_sigma


def test_importing_pipeline_compiles_nothing_and_the_root_stays_lazy():
    # Plain imports at the top of each module, lazy loading only at the
    # package root. `import dtalign` imports no Numba; importing the
    # pipeline imports the kernels' modules but compiles none of them
    # (compilation is lazy: on a kernel's first call).
    script = (
        "import sys, dtalign; root = 'numba' in sys.modules; "
        "import dtalign.pipeline, dtalign.pipeline.products; "
        "from numba.core.registry import CPUDispatcher; "
        "kernels = [m for n, m in sys.modules.items() if n.startswith('dtalign._kernels')]; "
        "compiled = sorted(f'{m.__name__}.{k}' for m in kernels for k, v in vars(m).items() "
        "if isinstance(v, CPUDispatcher) and v.signatures); "
        "print(root, len(kernels) > 0, compiled)"
    )
    src = os.path.abspath(os.path.join(os.path.dirname(pipeline.__file__), os.pardir))
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([src, env.get("PYTHONPATH", "")])
    env.pop("NUMBA_DISABLE_JIT", None)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "False True []"


def test_results_compare_by_identity(disc_fit, small_products):
    assert disc_fit == disc_fit and disc_fit != small_products
    assert len({disc_fit, small_products}) == 2


@pytest.fixture(scope="module")
def scene():
    """A 200 x 200 disc of radius 50 px, its 100-vertex limb displaced by (3.4, -2.2) px."""
    return scenes.disc_scene(shape=(200, 200), radius=50.0, n_vertices=100, offset_vu=(3.4, -2.2))


def test_json_writes_infinite_sigmas_as_null_and_from_dict_round_trips(scene):
    import json

    from dtalign.pipeline import PolylineFit

    p = scene.polyline
    fit = fit_polyline(scene.image, p.vertices_vu, p.normals_vu, p.sigmas, search_window_vu=(8, 8),
                       fit_rotation=True, max_iterations=3)  # a circle: rotation sigma inf
    d = fit.to_dict(arrays=True)
    text = json.dumps(d, allow_nan=False)  # strict JSON: no Infinity, no NaN
    assert d["sigma_rotation_rad"] is None and '"inf"' not in text
    back = PolylineFit.from_dict(json.loads(text))
    assert back.to_dict(arrays=True) == d
    assert back.status == fit.status and back.reasons == fit.reasons
    assert back.sigma_vu == fit.sigma_vu and back.sigma_rotation_rad == fit.sigma_rotation_rad
    with pytest.raises(ValueError, match="to_dict\\(arrays=True\\)"):
        PolylineFit.from_dict(fit.to_dict())
