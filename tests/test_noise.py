"""The compiled noise estimate equals its NumPy definition; the one-call path checks the image once."""

from __future__ import annotations

import logging

import numpy as np
import pytest

import dtalign
from dtalign import reference, scenes
from dtalign._kernels import noise as kernels
from dtalign.pipeline.products import estimate_noise_sigma, prepare_image


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
    # finite pixels whose responses overflow: the median and MAD 0, the mean inf
    spikes = np.zeros((200, 200))
    spikes[5, 5] = spikes[50, 60] = 1.7e308
    spikes[5, 6] = spikes[51, 60] = -1.7e308
    yield "overflowing responses", spikes


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

    def counting(arr, *name):  # prepare_image passes the name its messages use
        calls.append(1)
        return original(arr, *name)

    for module in (checks, image, products):
        monkeypatch.setattr(module, "check_image", counting)
    scene = scenes.disc_scene(shape=(200, 200), radius=50.0, n_vertices=60)
    p = scene.polyline
    fit = pipeline.fit_polyline(
        scene.image, p.vertices_vu, p.normals_vu, p.sigmas, search_window_vu=(8, 8)
    )
    assert len(calls) == 1
    assert fit.noise_sigma == reference.estimate_noise_sigma(scene.image)


def test_benchmark_rows_exist_and_agree():
    from dtalign.benchmarking import workloads

    assert "estimate_noise_sigma" in workloads.TARGETS and "fit_polyline" in workloads.TARGETS
    assert "noise_overhead" in workloads.SECTIONS and workloads.NOISE_OVERHEAD_TARGET == 1.3
    scene = scenes.disc_scene(shape=(200, 200), radius=50.0, n_vertices=60)
    p = scene.polyline
    lm = {
        "lm_n200": {
            "vertices_vu": p.vertices_vu,
            "normals_vu": p.normals_vu,
            "sigma_normal_per_vertex_px": p.sigmas,
        }
    }
    inputs = workloads.Inputs(scene.image, scene.noise_sigma, None, None, None, None, lm, None)
    for name in ("estimate_noise_sigma", "fit_polyline"):
        ref = workloads.workload_call(name, reference, inputs)()
        jit = workloads.workload_call(name, dtalign, inputs)()
        assert workloads._same(ref, jit), name


# -- the one-pass selection ---------------------------------------------------


def _exact(image):
    """``(k0, k1, median, mad)`` of the image's responses, by NumPy."""
    r = reference.noise.immerkaer_interior(np.ascontiguousarray(image, dtype=np.float64))
    n = r.size
    k1 = n // 2
    k0 = k1 if n % 2 else k1 - 1
    c = float(np.median(r))
    return k0, k1, c, float(np.median(np.abs(r - c)))


def _one_pass_images():
    rng = np.random.default_rng(21)
    yield "disc", scenes.disc_scene(shape=(300, 300), radius=80.0).image
    yield "navigation", scenes.navigation_scene(shape=(256, 320), radius=60.0).image
    yield "gaussian", rng.normal(100.0, 3.0, (257, 263))
    yield "odd count", rng.normal(0.0, 1.0, (131, 129))
    yield "integer DN", np.round(rng.normal(200.0, 3.0, (300, 300)))
    yield "integer DN, low noise", np.round(rng.normal(20.0, 0.7, (300, 300)))
    yield "quarter steps", np.round(rng.normal(0.0, 1.0, (300, 300)) * 4.0) / 4.0
    yield "two levels", np.where(rng.random((300, 300)) < 0.5, 0.0, 1e3)
    yield "laplace", rng.laplace(0.0, 1.0, (200, 200))
    yield "cauchy", rng.standard_cauchy((200, 200))
    yield "exponential", rng.exponential(1.0, (200, 200))
    yield "sorted", np.sort(rng.normal(0.0, 1.0, 300 * 300)).reshape(300, 300)
    yield "huge", rng.normal(0.0, 1e150, (200, 200))


@pytest.mark.parametrize(
    ("name", "image"), list(_one_pass_images()), ids=[n for n, _ in _one_pass_images()]
)
def test_one_pass_takes_these_images_and_is_exact(name, image):
    """The one pass succeeds on ordinary images (the speed) and gives NumPy's medians."""
    arr = np.ascontiguousarray(image, dtype=np.float64)
    k0, k1, c, mad = _exact(arr)
    n = (arr.shape[0] - 2) * (arr.shape[1] - 2)
    found, *bounds = kernels._one_pass_bounds(kernels._sample_responses(arr), n, k0, k1)
    assert found
    assert kernels._one_pass_medians(arr, k0, k1, tuple(bounds)) == (True, c, mad)
    assert kernels.noise_statistics(arr)[:2] == (c, mad)


def test_images_the_one_pass_cannot_take_get_the_same_value():
    """Most values tied at the median (MAD 0): no MAD band, the two-pass selection runs."""
    rng = np.random.default_rng(22)
    image = np.round(rng.normal(0.0, 0.2, (400, 400)))
    arr = np.ascontiguousarray(image, dtype=np.float64)
    k0, k1, c, mad = _exact(arr)
    n = (arr.shape[0] - 2) * (arr.shape[1] - 2)
    found, *_ = kernels._one_pass_bounds(kernels._sample_responses(arr), n, k0, k1)
    assert not found
    assert kernels.noise_statistics(arr)[:2] == (c, mad)
    assert estimate_noise_sigma(image) == reference.estimate_noise_sigma(image)


def _bounds_around(rng, r, dev, k0, k1, c, mad):
    """Bounds for :func:`_one_pass_medians`, from tight (sitting on the
    median, the MAD and tied values) to wrong (missing either)."""
    n = r.size

    def at(sorted_values, k):
        return float(sorted_values[min(max(k, 0), n - 1)])

    def jitter(x):
        # on a value, an ulp or two off it, or a little further
        kind = rng.integers(0, 4)
        if kind == 0:
            return x
        if kind == 1:
            return float(np.nextafter(x, np.inf if rng.random() < 0.5 else -np.inf))
        if kind == 2:
            return x + float(rng.choice([-1, 1])) * 2.0 * np.spacing(abs(x) + 1e-300)
        return x + float(rng.normal(0.0, 0.05 * (mad + 1e-12)))

    spread = int(rng.choice([0, 1, 3, 30, n // 20]))
    c_lo = jitter(at(r, k0 - int(rng.integers(-2, spread + 1))))
    c_hi = jitter(at(r, k1 + int(rng.integers(-2, spread + 1))))
    centre = (
        jitter(c)
        if rng.random() < 0.7
        else jitter(at(r, k0 + int(rng.integers(-spread - 1, spread + 2))))
    )
    d_lo = jitter(at(dev, k0 - int(rng.integers(-2, spread + 1))))
    d_hi = jitter(at(dev, k1 + int(rng.integers(-2, spread + 1))))
    widen = abs(float(rng.normal(0.0, 0.02 * (mad + 1e-12)))) if rng.random() < 0.5 else 0.0
    return (
        c_lo,
        c_hi,
        jitter(centre - d_hi - widen),
        jitter(centre - d_lo + widen),
        jitter(centre + d_lo - widen),
        jitter(centre + d_hi + widen),
    )


def test_one_pass_is_exact_whatever_the_bounds():
    """The bounds decide only whether the pass succeeds: when it does, the
    medians are NumPy's, bit for bit, including bounds that sit exactly on
    the median, on ``median -+ MAD`` and on tied (quantised) values."""
    rng = np.random.default_rng(23)
    images = [
        rng.normal(0.0, 1.0, (41, 43)),
        np.round(rng.normal(50.0, 1.5, (40, 40))),  # integer responses, many ties
        np.round(rng.normal(0.0, 1.0, (42, 40)) * 4.0) / 4.0,
        rng.standard_cauchy((40, 41)),
        rng.exponential(1.0, (40, 40)) + 1e6,  # responses with rounding in them
        np.where(rng.random((40, 40)) < 0.5, 0.0, 1e3),
    ]
    successes = 0
    trials = 0
    for image in images:
        k0, k1, c, mad = _exact(image)
        r = np.sort(reference.noise.immerkaer_interior(image))
        dev = np.sort(np.abs(r - c))
        for _ in range(150):
            bounds = _bounds_around(rng, r, dev, k0, k1, c, mad)
            ok, got_c, got_mad = kernels._one_pass_medians(image, k0, k1, bounds)
            trials += 1
            if ok:
                successes += 1
                assert (got_c, got_mad) == (c, mad), bounds
    # the cases must include both outcomes in number, or they test nothing
    assert 0.1 * trials < successes < 0.9 * trials


def test_quantised_noise_estimate_is_said(caplog):
    from dtalign.pipeline.products import QUANTISED_NOISE_STEP, quantised_noise_steps

    assert quantised_noise_steps(0.4942) == 2.0  # both Cassini frames' estimate
    assert QUANTISED_NOISE_STEP * 2 == pytest.approx(0.4942, abs=1e-12)
    assert quantised_noise_steps(2.006) is None
    caplog.set_level(logging.INFO, logger="dtalign")
    rng = np.random.default_rng(0)
    image = np.round(50.0 + 0.5 * rng.standard_normal((64, 64)))  # 8-bit-like, ~0.5 DN
    products = prepare_image(image)
    assert quantised_noise_steps(products.noise_sigma) is not None
    assert any("MAD of quantised pixels" in r.getMessage() for r in caplog.records)
