"""Array layouts and dtypes: every layout gives the C-contiguous float64 result, bit for bit.

Callers hand over float32 images, integer products, boolean masks, views with
steps, Fortran-order slices, read-only buffers and big-endian arrays read from
FITS files. The wrappers convert each array once to C-contiguous native
float64, so every layout must give a result *bit-identical* to the same
numbers passed as C-contiguous float64, and no call may modify its inputs.

Each variant is compared with ``np.array(variant, dtype=float64)`` (the same
values, canonical layout), so a dtype that rounds the data (float32, uint8)
is compared with its own rounded values, not with the original data.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
from types import SimpleNamespace

import numpy as np
import pytest

import dtalign
from dtalign.scenes import disc_scene

# --------------------------------------------------------------------------
# Layout variants
# --------------------------------------------------------------------------


def _strided(arr: np.ndarray) -> np.ndarray:
    """The same values as a step-2 view into a larger buffer."""
    big = np.zeros(tuple(2 * s + 1 for s in arr.shape), dtype=arr.dtype)
    view = big[tuple(slice(1, None, 2) for _ in arr.shape)]
    view[...] = arr
    assert not view.flags.c_contiguous or arr.size <= 1
    return view


def _reversed(arr: np.ndarray) -> np.ndarray:
    """The same values through a negative-stride view (axis 0)."""
    return np.ascontiguousarray(arr[::-1])[::-1]


def _readonly(arr: np.ndarray) -> np.ndarray:
    out = np.array(arr, copy=True)
    out.flags.writeable = False
    return out


def _unaligned(arr: np.ndarray) -> np.ndarray:
    """C-contiguous native float64 at an address that is not 8-byte aligned."""
    a = np.asarray(arr, dtype=np.float64)
    buf = bytearray(a.nbytes + 4)
    out = np.frombuffer(buf, dtype=np.float64, count=a.size, offset=4).reshape(a.shape)
    out[...] = a
    assert not out.flags.aligned or a.size == 0
    return out


def _rounded(dtype):
    info = np.iinfo(dtype)
    return lambda a: np.clip(np.rint(a), info.min, info.max).astype(dtype)


VARIANTS = {
    "float32": lambda a: a.astype(np.float32),
    "int32": _rounded(np.int32),
    "int64": _rounded(np.int64),
    "uint8": _rounded(np.uint8),
    "uint16": _rounded(np.uint16),
    "bool": lambda a: a != 0,
    "strided": _strided,
    "reversed": _reversed,
    "fortran": np.asfortranarray,
    "readonly": _readonly,
    "unaligned": _unaligned,
    ">f8": lambda a: a.astype(">f8"),
    ">f4": lambda a: a.astype(">f4"),
    ">i2": lambda a: _rounded(np.int16)(a).astype(">i2"),
    "nasty": lambda a: _strided(np.asfortranarray(a.astype(">f4"))),
    "list": lambda a: a.tolist(),
    "tuple": lambda a: tuple(map(tuple, a)) if a.ndim == 2 else tuple(a.tolist()),
}
GEOMETRY = ["float32", "strided", "reversed", "fortran", "readonly", "unaligned", ">f8", ">f4", "nasty", "list", "tuple"]
VERTEX = [*GEOMETRY, "int32", ">i2"]
SIGMA = [*GEOMETRY, "int64", "uint8"]
FIELD = ["float32", "strided", "reversed", "fortran", "readonly", "unaligned", ">f8", ">f4", "nasty",
         "uint8", "uint16", "int32", ">i2"]
GRADIENT = ["float32", "strided", "reversed", "fortran", "readonly", "unaligned", ">f8", ">f4", "nasty",
            "int32", ">i2"]
MASK = ["bool", "uint8", "int32", "float32", "strided", "reversed", "fortran", "readonly", ">f8",
        "nasty", "list"]
IMAGE = [*FIELD, "bool", "int64", "list"]


def canonical(value):
    """The same numbers as a C-contiguous native float64 array."""
    return np.array(value, dtype=np.float64, order="C")


# --------------------------------------------------------------------------
# Inputs and calls
# --------------------------------------------------------------------------


@functools.cache
def _scene() -> SimpleNamespace:
    sc = disc_scene(shape=(40, 44), radius=11.0, n_vertices=14, offset_vu=(1.3, -0.7), seed=3)
    mag, dt, grad = dtalign.compute_all_image_derivatives(sc.image, sc.noise_sigma)
    p = sc.polyline
    return SimpleNamespace(
        image=sc.image, v=p.vertices_vu, n=p.normals_vu, s=np.linspace(0.8, 1.5, len(p)), dt=dt,
        grad=grad, mag=mag, edge=(dt <= 0.5).astype(np.float64), poly=dtalign.build_polyline_mask(
            p.vertices_vu, dt.shape).astype(np.float64), pivot=sc.pivot_vu,
    )


def _calls():
    """``name -> (function, kwargs)``; the array arguments and layouts are in ``_TABLE``."""
    b = _scene()
    lm = dict(vertices_vu=b.v, normals_vu=b.n, sigma_normal_per_vertex_px=b.s, image_edge_dt=b.dt,
              image_gradient_vu=b.grad, initial_offset_vu=(1.0, -1.0))
    rot = dict(lm, fit_rotation=True, pivot_vu=b.pivot, pivot_distance_px=20.0,
               initial_rotation_rad=0.01)
    ridge = dict(vertices_vu=b.v, normals_vu=b.n, sigma_normal_per_vertex_px=b.s, gradient_magnitude=b.mag,
                 initial_offset_vu=(1.3, -0.7))
    jac = np.column_stack([np.cos(np.arange(9.0)), np.sin(np.arange(9.0)), np.arange(9.0) / 9])
    return {
        "coarse": (dtalign.coarse_ncc_search, dict(edge_mask=b.edge, polyline_mask=b.poly,
                                                  search_window_vu=(4, 5))),
        "polyline_mask": (dtalign.build_polyline_mask, dict(vertices_vu=b.v, shape_vu=(40, 44))),
        "polarity": (dtalign.polarity_filter, dict(vertices_vu=b.v, normals_vu=b.n, image_gradient_vu=b.grad,
                                                   offset_vu=(1.0, -1.0))),
        "tukey": (dtalign.tukey_biweight_weights, dict(residuals=np.linspace(-6.0, 6.0, 13))),
        "covariance": (dtalign.information_matrix_to_covariance,
                       dict(jacobian=jac, weights=np.linspace(0, 2, 9))),
        "sample": (dtalign.sample_dt_bilinear, dict(dt=b.dt, vertices_vu=b.v)),
        "translate": (dtalign.apply_translation, dict(vertices_vu=b.v, dv=1.25, du=-3.5)),
        "lm": (dtalign.lm_subpixel_refine, lm),
        "lm-rotation": (dtalign.lm_subpixel_refine, rot),
        "lm-ridge": (dtalign.lm_subpixel_refine, dict(rot, final_gradient_ridge=True, trust_region_px=3.0)),
        "ridge": (dtalign.gradient_ridge_refine,
                  dict(ridge, weight_mask=(np.arange(len(b.v)) % 4 != 1).astype(np.float64))),
        "ridge-rotation": (dtalign.gradient_ridge_refine, dict(ridge, fit_rotation=True, pivot_distance_px=15.0)),
        "gradient": (dtalign.compute_image_gradient_vu, dict(image_ext=b.image)),
        "edge_dt": (dtalign.build_image_edge_dt, dict(image_ext=b.image, image_noise_sigma=2.0)),
        "derivatives": (dtalign.compute_all_image_derivatives, dict(image_ext=b.image * 7.0, image_noise_sigma=2.0)),
    }


CALL_NAMES = ["coarse", "polyline_mask", "polarity", "tukey", "covariance", "sample", "translate", "lm",
              "lm-rotation", "lm-ridge", "ridge", "ridge-rotation", "gradient", "edge_dt", "derivatives"]
# (call, array argument) -> the layouts that make sense for it
_TABLE = {
    "coarse": {"edge_mask": MASK, "polyline_mask": MASK},
    "polyline_mask": {"vertices_vu": VERTEX},
    "polarity": {"vertices_vu": VERTEX, "normals_vu": GEOMETRY, "image_gradient_vu": GRADIENT},
    "tukey": {"residuals": [*GEOMETRY, "int32", "int64", ">i2"]},
    "covariance": {"jacobian": GEOMETRY, "weights": [*GEOMETRY, "bool", "uint8"]},
    "sample": {"dt": FIELD, "vertices_vu": VERTEX},
    "translate": {"vertices_vu": VERTEX},
    **{k: {"vertices_vu": VERTEX, "normals_vu": GEOMETRY, "sigma_normal_per_vertex_px": SIGMA,
           "image_edge_dt": FIELD, "image_gradient_vu": GRADIENT} for k in ("lm", "lm-rotation", "lm-ridge")},
    "ridge": {"vertices_vu": VERTEX, "normals_vu": GEOMETRY, "sigma_normal_per_vertex_px": SIGMA,
              "gradient_magnitude": FIELD, "weight_mask": [*MASK, "int64"]},
    "ridge-rotation": {"gradient_magnitude": FIELD, "vertices_vu": VERTEX},
    **{k: {"image_ext": IMAGE} for k in ("gradient", "edge_dt", "derivatives")},
}
PARAMS = [pytest.param(c, a, lay, id=f"{c}-{a}-{lay}")
          for c in CALL_NAMES for a, lays in _TABLE[c].items() for lay in lays]


def assert_identical(got, want) -> None:
    """Bit-identical results: same types, dtypes, shapes and bytes."""
    assert type(got) is type(want)
    if isinstance(got, np.ndarray):
        assert got.dtype == want.dtype and got.shape == want.shape
        assert np.ascontiguousarray(got).tobytes() == np.ascontiguousarray(want).tobytes()
    elif dataclasses.is_dataclass(got):
        for f in dataclasses.fields(got):
            assert_identical(getattr(got, f.name), getattr(want, f.name))
    elif isinstance(got, tuple):
        assert len(got) == len(want)
        for g, w in zip(got, want, strict=True):
            assert_identical(g, w)
    else:
        assert got == want or (got != got and want != want), (got, want)
        if isinstance(got, float):
            assert np.float64(got).tobytes() == np.float64(want).tobytes()


def snapshot(value):
    """A deep copy that also records dtype, strides and flags of arrays."""
    if isinstance(value, np.ndarray):
        return (value.copy(), value.dtype, value.strides, value.flags.writeable)
    return copy.deepcopy(value)


def assert_unchanged(before, value) -> None:
    if isinstance(value, np.ndarray):
        data, dtype, strides, writeable = before
        assert value.dtype == dtype and value.strides == strides and value.flags.writeable == writeable
        assert data.tobytes() == np.array(value, copy=True).tobytes()
    else:
        assert before == value


@pytest.mark.parametrize(("call", "arg", "layout"), PARAMS)
def test_layout_gives_bit_identical_result_and_leaves_input_alone(call, arg, layout):
    fn, kw = _calls()[call]
    variant = VARIANTS[layout](np.asarray(kw[arg]))
    want = fn(**dict(kw, **{arg: canonical(variant)}))
    before = {k: snapshot(v) for k, v in kw.items()}
    before_variant = snapshot(variant)
    got = fn(**dict(kw, **{arg: variant}))
    assert_identical(got, want)
    assert_unchanged(before_variant, variant)
    for k, v in kw.items():
        if k != arg:
            assert_unchanged(before[k], v)


@pytest.mark.parametrize("layout", ["float32", "strided", "fortran", "readonly", ">f8", ">f4", "nasty"])
@pytest.mark.parametrize("call", ["polarity", "sample", "lm", "lm-rotation", "lm-ridge", "ridge", "covariance"])
def test_every_array_in_one_layout_at_once(call, layout):
    fn, kw = _calls()[call]
    variants = {a: VARIANTS[layout](np.asarray(kw[a])) for a in _TABLE[call]}
    snaps = {a: snapshot(v) for a, v in variants.items()}
    got = fn(**dict(kw, **variants))
    want = fn(**dict(kw, **{a: canonical(v) for a, v in variants.items()}))
    assert_identical(got, want)
    for a, v in variants.items():
        assert_unchanged(snaps[a], v)


SMALL_ARGS = [
    ("lm", "initial_offset_vu", [(1.0, -1.0), [1.0, -1.0], np.array([1.0, -1.0]), np.array([1, -1]),
                                 np.array([1.0, -1.0], dtype=">f4"), (np.float32(1.0), np.int8(-1))]),
    ("lm-rotation", "pivot_vu", [None, list(_scene().pivot), np.array(_scene().pivot),
                                 np.array(_scene().pivot).astype(">f8"), tuple(np.float64(x) for x in _scene().pivot)]),
    ("lm-rotation", "initial_rotation_rad", [0.01, np.float64(0.01), np.float32(0.01), 0]),
    ("lm-rotation", "pivot_distance_px", [20.0, 20, np.int32(20), np.float32(20.0)]),
    ("lm", "max_iterations", [30, np.int64(30), np.uint8(30)]),
    ("lm", "tukey_c", [4.685, np.float64(4.685), 4, np.int16(4)]),
    ("lm", "trust_region_px", [None, 2.0, 2, np.float32(2.0)]),
    ("ridge", "initial_offset_vu", [(1.3, -0.7), [1.3, -0.7], np.array([1.3, -0.7]), np.array([1.3, -0.7], ">f8")]),
    ("polarity", "offset_vu", [(1.0, -1.0), [1, -1], np.array([1.0, -1.0]), np.array([1.0, -1.0], "<f4")]),
    ("coarse", "search_window_vu", [(4, 5), [4, 5], (np.int64(4), np.uint8(5)), [np.int32(4), 5]]),
    ("polyline_mask", "shape_vu", [(40, 44), [40, 44], np.array([40, 44]), (np.int64(40), np.uint16(44))]),
    ("translate", "dv", [1.25, np.float64(1.25), np.float32(1.25), 1, np.int8(1)]),
    ("gradient", "sigma_px", [1.2, np.float64(1.2), np.float32(1.2), 2, np.int64(2)]),
    ("edge_dt", "image_noise_sigma", [2.0, 2, np.float32(2.0), np.uint8(2)]),
]


@pytest.mark.parametrize(("call", "arg", "values"), SMALL_ARGS, ids=[f"{c}-{a}" for c, a, _ in SMALL_ARGS])
def test_small_arguments_accept_any_real_spelling(call, arg, values):
    """Lists, tuples, arrays and NumPy scalars mean the same Python numbers."""
    fn, kw = _calls()[call]

    def plain(v):
        if v is None:
            return None
        if isinstance(v, (tuple, list, np.ndarray)):
            return tuple(int(x) if isinstance(x, (int, np.integer)) else float(x) for x in np.asarray(v).tolist()) \
                if call in ("coarse", "polyline_mask") else tuple(float(x) for x in np.asarray(v, dtype=float))
        return int(v) if isinstance(v, (int, np.integer)) and arg in ("max_iterations",) else float(v)

    for v in values:
        if v is None and arg == "pivot_vu":
            want = fn(**dict(kw, pivot_vu=tuple(np.asarray(kw["vertices_vu"]).mean(axis=0).tolist())))
        else:
            want = fn(**dict(kw, **{arg: plain(v)}))
        before = snapshot(v)
        assert_identical(fn(**dict(kw, **{arg: v})), want)
        assert_unchanged(before, v) if isinstance(v, np.ndarray) else None


def test_image_config_accepts_numpy_scalars():
    b = _scene()
    cfg = dtalign.ImageDerivativesConfig(np.float32(1.5), np.int64(3), 20)
    assert all(type(getattr(cfg, f.name)) is float for f in dataclasses.fields(cfg))
    want = dtalign.compute_all_image_derivatives(b.image, 2.0, config=dtalign.ImageDerivativesConfig(
        float(np.float32(1.5)), 3.0, 20.0))
    assert_identical(dtalign.compute_all_image_derivatives(b.image, 2.0, config=cfg), want)


def test_results_are_fresh_arrays_and_lm_arrays_read_only():
    b = _scene()
    v = b.v.copy()
    out = dtalign.apply_translation(v, 0.0, 0.0)
    assert not np.shares_memory(out, v) and out.flags.c_contiguous
    assert not np.shares_memory(dtalign.tukey_biweight_weights(b.s), b.s)
    dt = b.dt.copy()
    assert not np.shares_memory(dtalign.sample_dt_bilinear(dt, v), dt)
    res = dtalign.lm_subpixel_refine(vertices_vu=v, normals_vu=b.n, sigma_normal_per_vertex_px=b.s,
                                     image_edge_dt=dt, image_gradient_vu=b.grad, initial_offset_vu=(1.0, -1.0))
    for name in ("covariance", "residuals_px", "weights"):
        arr = getattr(res, name)
        assert not arr.flags.writeable
        with pytest.raises(ValueError):
            arr[...] = 0.0
        for inp in (v, dt, b.s, b.n, b.grad):
            assert not np.shares_memory(arr, inp)
    img = b.image.copy()
    for out in dtalign.compute_all_image_derivatives(img, 2.0):
        assert out.dtype == np.float64 and out.flags.c_contiguous and not np.shares_memory(out, img)


def test_large_non_contiguous_dt_with_nan_outside_the_view():
    """A view of a big buffer: NaNs in the parent outside the view are irrelevant."""
    b = _scene()
    parent = np.full((2 * b.dt.shape[0] + 1, 2 * b.dt.shape[1] + 1), np.nan)
    view = parent[1::2, 1::2]
    view[...] = b.dt
    kw = dict(vertices_vu=b.v, normals_vu=b.n, sigma_normal_per_vertex_px=b.s, image_gradient_vu=b.grad,
              initial_offset_vu=(1.0, -1.0))
    assert_identical(dtalign.lm_subpixel_refine(image_edge_dt=view, **kw),
                     dtalign.lm_subpixel_refine(image_edge_dt=b.dt.copy(), **kw))
