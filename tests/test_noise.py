"""The compiled noise estimate equals its NumPy definition; the one-call path checks the image once."""

from __future__ import annotations

import numpy as np
import pytest

import dtalign
from dtalign import reference, scenes
from dtalign._kernels import noise as kernels
from dtalign.pipeline.products import estimate_noise_sigma


def _images():
    rng = np.random.default_rng(15)
    yield "disc", scenes.disc_scene(shape=(300, 300), radius=80.0).image
    yield "navigation", scenes.navigation_scene(shape=(256, 320), radius=60.0).image
    yield "gaussian", rng.normal(100.0, 3.0, (257, 263))
    yield "odd count", rng.normal(0.0, 1.0, (131, 129))  # 127 * 129 values: one middle
    yield "tiny", rng.normal(0.0, 1.0, (3, 3))
    yield "small", rng.normal(0.0, 1.0, (7, 9))
    yield "quantised", rng.integers(0, 4, (300, 200)).astype(np.float64)
    yield "many ties", np.round(rng.normal(0.0, 0.2, (400, 400)))
    yield "constant", np.full((60, 50), 7.0)
    yield "planar", np.add.outer(np.arange(100.0), 0.5 * np.arange(90.0))
    yield "uint8", rng.integers(0, 256, (120, 140), dtype=np.uint8)
    yield "fortran", np.asfortranarray(rng.normal(0.0, 2.0, (150, 170)))
    # values sorted along the rows: a stride sample sees them in order
    yield "sorted", np.sort(rng.normal(0.0, 1.0, 300 * 300)).reshape(300, 300)
    yield "two levels", np.where(rng.random((300, 300)) < 0.5, 0.0, 1e3)
    yield "huge", rng.normal(0.0, 1e150, (200, 200))


@pytest.mark.parametrize(("name", "image"), list(_images()), ids=[n for n, _ in _images()])
def test_compiled_estimate_equals_the_numpy_definition(name, image):
    got = estimate_noise_sigma(image)
    want = reference.estimate_noise_sigma(image)
    assert got == pytest.approx(want, rel=1e-12, abs=0.0)


@pytest.mark.parametrize(("name", "image"), list(_images())[:8], ids=[n for n, _ in _images()][:8])
def test_filter_is_bit_identical_to_scipy(name, image):
    arr = np.ascontiguousarray(image, dtype=np.float64)
    out = np.empty((arr.shape[0] - 2) * (arr.shape[1] - 2))
    kernels.immerkaer_interior(arr, out)
    assert np.array_equal(out, reference.noise.immerkaer_interior(arr))


def test_medians_are_exact_order_statistics():
    rng = np.random.default_rng(3)
    for n in (1, 2, 5, 16384, 16385, 40001, 100000):
        x = rng.standard_normal(n) * rng.choice([1.0, 1e-3, 1e3], n)
        k1 = n // 2
        k0 = k1 if n % 2 else k1 - 1
        work = np.empty(n)
        s = np.sort(x)
        assert kernels._order_pair(x, k0, k1, 0.0, False, work) == (s[k0], s[k1])
        c = float(np.median(x))
        d = np.sort(np.abs(x - c))
        assert kernels._order_pair(x, k0, k1, c, True, work) == (d[k0], d[k1])


def test_the_top_level_name_is_the_compiled_one():
    assert dtalign.estimate_noise_sigma is estimate_noise_sigma
    assert estimate_noise_sigma(np.ones((2, 5))) == 0.0


def test_bad_images_are_refused_by_name():
    with pytest.raises(ValueError, match="finite"):
        estimate_noise_sigma(np.full((5, 5), np.nan))
    with pytest.raises(TypeError, match="2-D"):
        estimate_noise_sigma(np.zeros(5))


def test_fit_polyline_checks_the_image_once(monkeypatch):
    """prepare_image checked it, then estimate_noise_sigma and the derivatives again."""
    from dtalign import pipeline
    from dtalign.api import checks, image
    from dtalign.pipeline import products

    calls = []
    original = checks.check_image

    def counting(arr):
        calls.append(1)
        return original(arr)

    for module in (checks, image, products):
        monkeypatch.setattr(module, "check_image", counting)
    scene = scenes.disc_scene(shape=(200, 200), radius=50.0, n_vertices=60)
    p = scene.polyline
    fit = pipeline.fit_polyline(scene.image, p.vertices_vu, p.normals_vu, p.sigmas,
                                search_window_vu=(8, 8))
    assert len(calls) == 1
    assert fit.noise_sigma == reference.estimate_noise_sigma(scene.image)


def test_benchmark_rows_exist_and_agree():
    from dtalign.benchmarking import workloads

    assert "estimate_noise_sigma" in workloads.TARGETS and "fit_polyline" in workloads.TARGETS
    assert "noise_overhead" in workloads.SECTIONS and workloads.NOISE_OVERHEAD_TARGET == 1.3
    scene = scenes.disc_scene(shape=(200, 200), radius=50.0, n_vertices=60)
    p = scene.polyline
    lm = {"lm_n200": {"vertices_vu": p.vertices_vu, "normals_vu": p.normals_vu,
                      "sigma_normal_per_vertex_px": p.sigmas}}
    inputs = workloads.Inputs(scene.image, scene.noise_sigma, None, None, None, None, lm, None)
    for name in ("estimate_noise_sigma", "fit_polyline"):
        ref = workloads.workload_call(name, reference, inputs)()
        jit = workloads.workload_call(name, dtalign, inputs)()
        assert workloads._same(ref, jit), name
