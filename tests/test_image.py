"""Tests of :mod:`dtalign.api.image` against the NumPy/SciPy specification.

The compiled image side must be a drop-in for
:mod:`dtalign.reference.image` (:ref:`contract-surface` and :ref:`contract-image`): same checks and
messages, edge masks and distance transforms identical, gradients within
1e-10 relative. On x86-64 (where SciPy's C filters and glibc's ``hypot``
do not use FMA) every output is asserted bit-identical as well, which is
what the kernels are written for.
"""

from __future__ import annotations

import os
import platform
import threading
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
import scipy.ndimage
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from dtalign._kernels import image as kernels
from dtalign.api import image as cimage
from dtalign.api.image import (
    ImageDerivativesConfig,
    build_image_edge_dt,
    compute_all_image_derivatives,
    compute_image_gradient_vu,
)
from dtalign.api.results import ImageDerivativesConfig as SharedConfig
from dtalign.reference import image as rimage
from dtalign.scenes import disc_scene, navigation_scene

#: SciPy wheels and glibc use no FMA on x86-64, so bits are reproducible.
BITWISE = platform.machine().lower() in {"x86_64", "amd64"}

CONFIG_FIELDS = ("image_gradient_sigma_px", "edge_threshold_k_sigma", "dt_half_width_px")


# --------------------------------------------------------------------------- helpers


def assert_close_or_same(actual: np.ndarray, expected: np.ndarray) -> None:
    """Gradient-like arrays: bit-identical where reproducible, else 1e-10 relative."""
    assert actual.dtype == np.float64 and actual.shape == expected.shape
    if BITWISE:
        # Compare bit patterns: also tells -0.0 from 0.0.
        np.testing.assert_array_equal(actual.view(np.int64), expected.view(np.int64))
    else:
        scale = float(np.max(np.abs(expected), initial=0.0))
        np.testing.assert_allclose(actual, expected, rtol=1e-10, atol=1e-10 * scale)


def assert_parity(image, noise, config=None):
    """Compiled vs reference on one input; returns the compiled outputs."""
    got = compute_all_image_derivatives(image, noise, config=config)
    want = rimage.compute_all_image_derivatives(image, noise, config=config)
    magnitude, edge_dt, grad = got
    assert_close_or_same(grad, want[2])
    assert_close_or_same(magnitude, want[0])
    # The edge mask and the DT must be identical, not close.
    np.testing.assert_array_equal(edge_dt <= 0.5, want[1] <= 0.5)
    np.testing.assert_array_equal(edge_dt, want[1])
    return got


def step_image(shape, rng):
    """A noisy bright rectangle: straight and corner edges in every sector."""
    h, w = shape
    img = rng.normal(0.0, 1.0, shape)
    img[h // 4 : max(h // 4 + 1, 3 * h // 4), w // 3 : max(w // 3 + 1, 2 * w // 3)] += 50.0
    return img


def make_small(kind, shape, seed=0):
    rng = np.random.default_rng(seed)
    if kind == "noise":
        return rng.normal(0.0, 10.0, shape)
    if kind == "impulses":  # dense isolated edges: many DT sites per row
        return (rng.random(shape) < 0.15) * 100.0
    if kind == "step":
        return step_image(shape, rng)
    if kind == "uint8":
        return rng.integers(0, 256, shape).astype(np.uint8)
    raise AssertionError(kind)


# --------------------------------------------------------------------------- scene parity


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_disc_scene_parity(seed):
    sc = disc_scene(seed=seed)
    _, edge_dt, _ = assert_parity(sc.image, sc.noise_sigma)
    assert (edge_dt == 0.0).sum() > 500  # the limb is found


def test_disc_scene_non_square_parity():
    sc = disc_scene(shape=(300, 420), radius=90.0, seed=7)
    assert_parity(sc.image, sc.noise_sigma)


def test_navigation_scene_parity():
    sc = navigation_scene()
    assert_parity(sc.image, sc.noise_sigma)


@pytest.mark.parametrize("half_width", [0.3, 1.0, 2.5, 7.0, 64.0, 1e12])
@pytest.mark.parametrize("sigma", [0.7, 1.2, 3.0])
def test_disc_scene_configs(sigma, half_width):
    sc = disc_scene(shape=(200, 230), radius=60.0, seed=3)
    cfg = ImageDerivativesConfig(sigma, 4.0, half_width)
    assert_parity(sc.image, sc.noise_sigma, cfg)


# --------------------------------------------------------------------------- small and odd shapes

SHAPES = [(1, 1), (1, 2), (2, 1), (1, 9), (9, 1), (2, 2), (3, 7), (7, 3), (5, 5), (16, 1), (31, 17)]
CONFIGS = [
    ImageDerivativesConfig(1.2, 4.0, 64.0),
    ImageDerivativesConfig(1e-20, 1.0, 1.5),  # SciPy skips a sigma <= 1e-15
    ImageDerivativesConfig(0.3, 0.5, 0.4),  # radius-1 kernel, sub-pixel clip
    ImageDerivativesConfig(4.0, 0.1, 3.0),  # radius longer than the image
    ImageDerivativesConfig(25.0, 1.0, 1e12),  # reflect across many periods
]


@pytest.mark.parametrize("kind", ["noise", "impulses", "step", "uint8"])
@pytest.mark.parametrize("shape", SHAPES, ids=lambda s: f"{s[0]}x{s[1]}")
def test_small_shapes_parity(shape, kind):
    image = make_small(kind, shape, seed=shape[0] * 100 + shape[1])
    for cfg in CONFIGS:
        for noise in (0.0, 0.5):
            assert_parity(image, noise, cfg)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    h=st.integers(1, 24),
    w=st.integers(1, 24),
    seed=st.integers(0, 2**32 - 1),
    scale=st.sampled_from([1e-3, 1.0, 100.0, 1e6]),
    sparse=st.booleans(),
    sigma=st.sampled_from([0.2, 0.5, 1.0, 1.2, 2.2, 6.0]),
    k=st.sampled_from([0.25, 1.0, 4.0]),
    half_width=st.sampled_from([0.5, 1.0, 1.7, 3.0, 10.0, 64.0, 1e9]),
    noise=st.sampled_from([0.0, 0.3, 2.0]),
)
def test_random_images_parity(h, w, seed, scale, sparse, sigma, k, half_width, noise):
    rng = np.random.default_rng(seed)
    image = rng.normal(0.0, scale, (h, w))
    if sparse:
        image *= rng.random((h, w)) < 0.2
    assert_parity(image, noise, ImageDerivativesConfig(sigma, k, half_width))
    assert_close_or_same(
        compute_image_gradient_vu(image, sigma_px=sigma),
        rimage.compute_image_gradient_vu(image, sigma_px=sigma),
    )


@pytest.mark.parametrize("half_width", [1.0, 1.9999999, 2.0, 2.0000001, 2.5, 3.0, 5.0])
def test_dt_clip_at_and_near_integers(half_width):
    # Isolated edge pixels put exact integer and sqrt-of-integer distances
    # right at the clip: the column-distance cap must not change any value.
    image = make_small("impulses", (40, 45), seed=11) * (make_small("noise", (40, 45)) > 12)
    cfg = ImageDerivativesConfig(0.5, 1.0, half_width)
    _, edge_dt, _ = assert_parity(image, 0.1, cfg)
    assert edge_dt.max() == half_width


# --------------------------------------------------------------------------- semantics


@pytest.mark.parametrize("half_width", [0.5, 3.0, 64.0, 1e300])
@pytest.mark.parametrize("shape", [(1, 1), (4, 9), (64, 64)])
def test_image_without_edges(shape, half_width):
    cfg = ImageDerivativesConfig(dt_half_width_px=half_width)
    # All zero: no gradient anywhere (a constant c != 0 is not edge-free:
    # Sobel's cval = 0 border sees a step of c).
    magnitude, edge_dt, grad = assert_parity(np.zeros(shape), 0.0, cfg)
    assert np.all(grad == 0.0) and np.all(magnitude == 0.0)
    assert np.all(edge_dt == half_width)
    # Gradients everywhere, all below the threshold.
    noisy = np.random.default_rng(1).normal(0.0, 0.01, shape)
    _, edge_dt, _ = assert_parity(noisy, 100.0, cfg)
    assert np.all(edge_dt == half_width)


@pytest.mark.parametrize("value", [-3.0, 42.0, 1e9])
def test_constant_image_parity(value):
    magnitude, edge_dt, _ = assert_parity(np.full((12, 17), value), 1.0)
    assert np.all(magnitude[2:-2, 2:-2] == 0.0)  # edges only at the cval-0 border


def test_threshold_is_strict():
    # With k = 1 the threshold is the noise sigma itself: a magnitude equal
    # to it is not an edge, the next float below it lets the maximum in.
    image = step_image((40, 40), np.random.default_rng(5))
    cfg = ImageDerivativesConfig(edge_threshold_k_sigma=1.0, dt_half_width_px=10.0)
    top = float(compute_all_image_derivatives(image, 1.0, config=cfg)[0].max())
    _, edge_dt, _ = assert_parity(image, top, cfg)
    assert np.all(edge_dt == 10.0)
    _, edge_dt, _ = assert_parity(image, float(np.nextafter(top, 0.0)), cfg)
    assert (edge_dt == 0.0).sum() >= 1


def test_zero_noise_uses_the_floor():
    image = step_image((30, 30), np.random.default_rng(2)) * 1e-6
    a = compute_all_image_derivatives(image, 0.0)
    b = compute_all_image_derivatives(image, 1e-6)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)


def test_output_types_and_consistency():
    sc = disc_scene(shape=(64, 80), radius=20.0)
    cfg = ImageDerivativesConfig(image_gradient_sigma_px=1.7)
    magnitude, edge_dt, grad = compute_all_image_derivatives(sc.image, 2.0, config=cfg)
    assert grad.shape == (64, 80, 2) and magnitude.shape == edge_dt.shape == (64, 80)
    for arr in (magnitude, edge_dt, grad):
        assert arr.dtype == np.float64 and arr.flags.c_contiguous and arr.flags.writeable
    np.testing.assert_array_equal(magnitude, np.hypot(grad[..., 0], grad[..., 1]))
    np.testing.assert_array_equal(grad, compute_image_gradient_vu(sc.image, sigma_px=1.7))
    m2, dt2 = build_image_edge_dt(sc.image, 2.0, config=cfg)
    np.testing.assert_array_equal(m2, magnitude)
    np.testing.assert_array_equal(dt2, edge_dt)
    assert np.all((edge_dt >= 0.0) & (edge_dt <= cfg.dt_half_width_px))


def test_default_sigma_is_the_contract_default():
    image = make_small("step", (20, 24))
    np.testing.assert_array_equal(
        compute_image_gradient_vu(image), compute_image_gradient_vu(image, sigma_px=1.2)
    )
    assert ImageDerivativesConfig() == ImageDerivativesConfig(1.2, 4.0, 64.0)
    # One config type for both paths: a caller's config works with either.
    assert cimage.ImageDerivativesConfig is SharedConfig


def test_threads_give_identical_results():
    # Kernels allocate their own scratch, so concurrent calls cannot interfere.
    images = [disc_scene(shape=(160, 170), radius=50.0, seed=s).image for s in range(4)]
    expected = [compute_all_image_derivatives(im, 2.0) for im in images]
    results: list = [None] * 4

    def work(i):
        results[i] = compute_all_image_derivatives(images[i], 2.0)

    threads = [threading.Thread(target=work, args=(i,)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for got, want in zip(results, expected, strict=True):
        for x, y in zip(got, want, strict=True):
            np.testing.assert_array_equal(x, y)


# --------------------------------------------------------------------------- dtypes and layouts


@pytest.fixture(scope="module")
def base_image():
    return disc_scene(shape=(90, 110), radius=30.0, seed=4).image


def _layout_variants(base):
    rng = np.random.default_rng(9)
    ints = np.rint(base).astype(np.int64)
    readonly = base.copy()
    readonly.flags.writeable = False
    big = np.pad(base, 3)
    return {
        "float32": base.astype(np.float32),
        "int16": ints.astype(np.int16),
        "int64": ints,
        "uint8": np.clip(ints, 0, 255).astype(np.uint8),
        "bool": base > 50.0,
        "fortran": np.asfortranarray(base),
        "strided": np.ascontiguousarray(np.repeat(base, 2, axis=1))[:, ::2],
        "reversed": base[::-1, ::-1],
        "transposed": np.ascontiguousarray(base.T).T,
        "padded_view": big[3:-3, 3:-3],
        "readonly": readonly,
        "big_endian": base.astype(">f8"),
        "big_endian_int": ints.astype(">i4"),
        "list": (rng.normal(size=(5, 6)) * 10).tolist(),
    }


@pytest.mark.parametrize(
    "name",
    [
        "float32", "int16", "int64", "uint8", "bool", "fortran", "strided", "reversed",
        "transposed", "padded_view", "readonly", "big_endian", "big_endian_int", "list",
    ],
)  # fmt: skip
def test_layouts_equal_c_float64(base_image, name):
    image = _layout_variants(base_image)[name]
    as_c = np.ascontiguousarray(np.asarray(image), dtype=np.float64)
    got = assert_parity(image, 2.0)
    for x, y in zip(got, compute_all_image_derivatives(as_c, 2.0), strict=True):
        np.testing.assert_array_equal(x.view(np.int64), y.view(np.int64))
    np.testing.assert_array_equal(compute_image_gradient_vu(image), compute_image_gradient_vu(as_c))
    if isinstance(image, np.ndarray):
        # The caller's array is never written.
        np.testing.assert_array_equal(_layout_variants(base_image)[name], image)


# --------------------------------------------------------------------------- errors

FUNCS = {
    "gradient": lambda mod, im: mod.compute_image_gradient_vu(im),
    "edge_dt": lambda mod, im: mod.build_image_edge_dt(im, 1.0),
    "all": lambda mod, im: mod.compute_all_image_derivatives(im, 1.0),
}
BAD_IMAGES = [
    (np.ones(5), TypeError, "image_ext must be 2-D"),
    (np.ones((2, 3, 4)), TypeError, "image_ext must be 2-D"),
    (np.float64(3.0), TypeError, "image_ext must be 2-D"),
    (np.array([[1.0, np.nan]]), ValueError, "finite"),
    (np.array([[1.0], [np.inf]]), ValueError, "finite"),
    (np.array([[-np.inf]]), ValueError, "finite"),
    (np.ones((2, 2), dtype=complex), TypeError, "real numeric"),
    (np.zeros((0, 5)), ValueError, "empty"),
    (np.zeros((5, 0)), ValueError, "empty"),
    (np.zeros((0, 0)), ValueError, "empty"),
]


@pytest.mark.parametrize("module", [cimage, rimage], ids=["compiled", "reference"])
@pytest.mark.parametrize("func", list(FUNCS))
@pytest.mark.parametrize("bad", BAD_IMAGES, ids=lambda b: b[2].replace(" ", "_"))
def test_bad_image_refused(module, func, bad):
    image, exc, fragment = bad
    with pytest.raises(exc, match=fragment):
        FUNCS[func](module, image)


@pytest.mark.parametrize("module", [cimage, rimage], ids=["compiled", "reference"])
@pytest.mark.parametrize("sigma", [0.0, -1.0, np.nan, np.inf, -np.inf, None, "1.2", True])
def test_bad_sigma_px(module, sigma):
    with pytest.raises(ValueError, match="sigma_px must be a finite positive number"):
        module.compute_image_gradient_vu(np.ones((4, 4)), sigma_px=sigma)


@pytest.mark.parametrize("module", [cimage, rimage], ids=["compiled", "reference"])
@pytest.mark.parametrize("noise", [-1e-9, -1.0, np.nan, np.inf, None, "2"])
@pytest.mark.parametrize("func", ["build_image_edge_dt", "compute_all_image_derivatives"])
def test_bad_noise_sigma(module, func, noise):
    with pytest.raises(ValueError, match="image_noise_sigma must be finite and >= 0"):
        getattr(module, func)(np.ones((4, 4)), noise)


@pytest.mark.parametrize("field", CONFIG_FIELDS)
@pytest.mark.parametrize("value", [0.0, -2.0, np.nan, np.inf, True, "1.0", None])
def test_bad_config_field(field, value):
    with pytest.raises(ValueError, match=f"{field} must be a finite positive number"):
        ImageDerivativesConfig(**{field: value})


def test_bad_config_type():
    for module in (cimage, rimage):
        with pytest.raises(TypeError, match="ImageDerivativesConfig"):
            module.compute_all_image_derivatives(np.ones((3, 3)), 1.0, config={"x": 1})


def test_checks_run_before_any_work():
    # The image is checked first, then the noise, as in the reference.
    with pytest.raises(TypeError, match="image_ext must be 2-D"):
        compute_all_image_derivatives(np.ones(3), -1.0)
    with pytest.raises(ValueError, match="image_noise_sigma"):
        compute_all_image_derivatives(np.ones((3, 3)), -1.0, config="bad")


# --------------------------------------------------------------------------- building blocks


@pytest.mark.parametrize("sigma", [0.1, 0.3, 0.5, 1.0, 1.2, 2.0, 3.3, 7.9, 20.0])
def test_gaussian_weights_match_scipy(sigma):
    private = getattr(scipy.ndimage._filters, "_gaussian_kernel1d", None)
    ours = cimage._gaussian_weights(sigma)
    radius = int(4.0 * sigma + 0.5)
    assert ours.shape == (2 * radius + 1,)
    if private is None:
        pytest.skip("SciPy's private _gaussian_kernel1d moved")
    want = private(sigma, 0, radius)[::-1]
    np.testing.assert_array_equal(ours.view(np.int64), want.view(np.int64))


def test_hypot_matches_numpy_bitwise():
    rng = np.random.default_rng(3)
    n = 200_000
    x = np.concatenate(
        [
            rng.normal(size=n),
            rng.normal(size=n) * np.exp(rng.normal(size=n) * 30.0),
            rng.integers(-500, 500, n).astype(float),
            [0.0, -0.0, 5e-324, -1e-310, 1e308, 2.0**511, 2.0**512, 2.0**-511, 2.0**-512],
            [np.inf, -np.inf, np.nan, 3.0, 1.0, 1.0, 1e-300, 1e154, 7.0],
        ]
    )
    y = np.concatenate(
        [
            rng.normal(size=n),
            rng.normal(size=n),
            rng.integers(-500, 500, n).astype(float),
            [0.0, 0.0, 5e-324, 1e-310, 1e308, 2.0**511, 1.0, 2.0**-511, 2.0**-512],
            [1.0, np.nan, 2.0, 4.0, 2.0**-54, 2.0**-53, 1e-300, 1e154, -0.0],
        ]
    )
    out = np.empty_like(x)
    kernels.hypot_row(x, y, out, cimage._use_libm_hypot())
    np.testing.assert_array_equal(out.view(np.int64), np.hypot(x, y).view(np.int64))
    kernels.hypot_row(x, y, out, True)  # the libm fallback path
    np.testing.assert_array_equal(out, np.hypot(x, y))


def test_column_cap_bounds():
    assert cimage._column_cap(64.0, (1024, 1024)) == 65.0
    assert cimage._column_cap(2.5, (10, 10)) == 3.0
    assert cimage._column_cap(1e300, (10, 12)) == 22.0
    for hw in (0.1, 1.0, 3.999, 17.0):
        assert cimage._column_cap(hw, (500, 500)) > hw


def test_no_image_sized_numpy_temporaries():
    # Beyond the three outputs (4 image-sized float64 arrays) nothing
    # image-sized is allocated for a C float64 input; the kernels' own
    # scratch is a few rows (not visible to tracemalloc, checked by review).
    image = disc_scene(shape=(512, 512), radius=100.0).image
    compute_all_image_derivatives(image, 2.0)  # compile / warm up
    tracemalloc.start()
    try:
        out = compute_all_image_derivatives(image, 2.0)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert sum(a.nbytes for a in out) == 4 * image.nbytes
    assert peak < 4.25 * image.nbytes


# --------------------------------------------------------------------------- Cassini frames


def _cassini_dir() -> Path:
    env = os.environ.get("DTALIGN_CASSINI_DIR")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[2] / "shared" / "data" / "cassini"


def load_cassini_grey(name: str, header_rows: int = 0) -> np.ndarray:
    """Grey channel of a summary PNG with the red overlay painted out.

    Overlay pixels are the non-grey ones (``R, G, B`` not all equal: the
    red polyline, labels and their anti-aliasing); each is replaced by the
    median of the grey pixels in the smallest window around it that has any.
    """
    image_mod = pytest.importorskip("PIL.Image")
    path = _cassini_dir() / name
    if not path.is_file():
        pytest.skip(f"Cassini frame not found: {path}")
    rgb = np.asarray(image_mod.open(path).convert("RGB")).astype(np.int16)[header_rows:]
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    overlay = (r != g) | (g != b)
    grey = g.astype(np.float64)
    cleaned = grey.copy()
    for v, u in zip(*np.nonzero(overlay), strict=True):
        radius = 2
        while True:
            win = (
                slice(max(v - radius, 0), v + radius + 1),
                slice(max(u - radius, 0), u + radius + 1),
            )
            keep = ~overlay[win]
            if keep.any():
                cleaned[v, u] = np.median(grey[win][keep])
                break
            radius += 1
    return cleaned


def mad_sigma(patch: np.ndarray) -> float:
    """Robust noise sigma; floored at the 8-bit quantisation sigma 1/sqrt(12)."""
    mad = float(np.median(np.abs(patch - np.median(patch))))
    return max(1.4826 * mad, 1.0 / np.sqrt(12.0))


CASSINI = [
    # name, header rows to drop, background region for the noise MAD
    ("N1634226853_1_CALIB.png", 0, (slice(0, 120), slice(0, 120))),  # Tethys: dark sky
    ("N1863268207_1_CALIB.png", 96, (slice(150, 350), slice(50, 250))),  # Keeler: ring
]


@pytest.mark.cassini
@pytest.mark.slow
@pytest.mark.parametrize("name,header,region", CASSINI, ids=["tethys", "keeler"])
def test_cassini_frames_parity(name, header, region):
    image = load_cassini_grey(name, header)
    assert image.shape == (1024, 1024)
    noise = mad_sigma(image[region])
    _, edge_dt, _ = assert_parity(image, noise)
    assert (edge_dt == 0.0).sum() > 1000
    # Zero noise: the densest edge set (a quarter of the pixels on Tethys).
    assert_parity(image, 0.0, ImageDerivativesConfig(dt_half_width_px=20.0))
    # The uint8 grey frame as a caller would pass it.
    assert_parity(np.rint(image).astype(np.uint8), noise)
