"""Every bad input refused clearly: the reliability matrix of the public functions.

Navigation runs unattended over whole archives, so each public function must
either refuse an input with the documented exception type and a message that
names the offending argument, or return a documented result; never an
IndexError/ZeroDivisionError/SystemError from inside a kernel and never NaN
from finite input. The reference shares the argument checks, so every refusal
below is also asserted for :mod:`dtalign.reference` (drop-in: same type and
message).

Non-finite values in image-sized arrays follow a deliberate design
(``_validation.FULL_SCAN_MAX_SIZE``): arrays of at most 65536 values are
scanned up front; larger ones are not scanned (a scan costs more than a fit),
the kernels detect any NaN/inf they actually read and the wrapper raises
ValueError naming the argument, and a value that is never read cannot change
the result. ``TestLargeArrayRegime`` tests both halves of that promise.
"""

from __future__ import annotations

import functools
import math
from types import SimpleNamespace

import numpy as np
import pytest

import dtalign
from dtalign import reference as ref
from dtalign.scenes import disc_scene

NAN, INF = math.nan, math.inf
LM, RIDGE = "lm_subpixel_refine", "gradient_ridge_refine"


@functools.cache
def _scene(shape: tuple[int, int] = (48, 48)) -> SimpleNamespace:
    """A small disc scene and its image products (computed once per shape)."""
    radius = min(shape) / 4.0
    sc = disc_scene(shape=shape, radius=radius, n_vertices=16, offset_vu=(1.3, -0.7), seed=1)
    mag, dt, grad = dtalign.compute_all_image_derivatives(sc.image, sc.noise_sigma)
    p = sc.polyline
    pmask = dtalign.build_polyline_mask(p.vertices_vu, shape)
    return SimpleNamespace(
        image=sc.image, v=p.vertices_vu, n=p.normals_vu, s=p.sigmas, dt=dt, grad=grad,
        mag=mag, edge=dt <= 0.5, pmask=pmask, shape=shape, offset=sc.true_offset_vu,
    )


def _base(fn: str) -> dict:
    b = _scene()
    v, n, s = b.v, b.n, b.s
    return {
        "coarse_ncc_search": dict(edge_mask=b.edge, polyline_mask=b.pmask, search_window_vu=(3, 3)),
        "build_polyline_mask": dict(vertices_vu=v, shape_vu=b.shape),
        "polarity_filter": dict(vertices_vu=v, normals_vu=n, image_gradient_vu=b.grad,
                                offset_vu=(1.0, -1.0)),
        "tukey_biweight_weights": dict(residuals=np.linspace(-6, 6, 9), c=4.685),
        "information_matrix_to_covariance": dict(
            jacobian=np.array([[1.0, 0.2], [0.1, 1.0], [0.5, 0.5]]), weights=np.ones(3),
            rcond=1e-9),
        "sample_dt_bilinear": dict(dt=b.dt, vertices_vu=v),
        "apply_translation": dict(vertices_vu=v, dv=1.0, du=-2.0),
        LM: dict(vertices_vu=v, normals_vu=n, sigma_normal_per_vertex_px=s, image_edge_dt=b.dt,
                 image_gradient_vu=b.grad, initial_offset_vu=(1.0, -1.0)),
        RIDGE: dict(vertices_vu=v, normals_vu=n, sigma_normal_per_vertex_px=s,
                    gradient_magnitude=b.mag, initial_offset_vu=b.offset),
        "compute_image_gradient_vu": dict(image_ext=b.image, sigma_px=1.2),
        "build_image_edge_dt": dict(image_ext=b.image, image_noise_sigma=2.0, config=None),
        "compute_all_image_derivatives": dict(image_ext=b.image, image_noise_sigma=2.0, config=None),
        "ImageDerivativesConfig": dict(),
    }[fn]


def _with(arr_name: str, fn: str, index, value):
    """A copy of base argument ``arr_name`` of ``fn`` with ``arr[index] = value``."""
    def make():
        arr = np.array(_base(fn)[arr_name], dtype=np.float64, copy=True)
        arr[index] = value
        return arr
    return make


def _call(impl, fn: str, **overrides):
    kw = _base(fn)
    kw.update({k: (v() if callable(v) else v) for k, v in overrides.items()})
    return getattr(impl, fn)(**kw)


# --------------------------------------------------------------------------
# The refusal matrix: (function, argument, bad value, exception, message regex)
# --------------------------------------------------------------------------

N = 16  # vertices of the base polyline
VERTEX_FNS = ["build_polyline_mask", "polarity_filter", "sample_dt_bilinear",
              "apply_translation", LM, RIDGE]
POSE_FNS = [LM, RIDGE]
CASES: list[tuple] = []


def _add(fns, arg, label, value, exc, match):
    for fn in fns if isinstance(fns, list) else [fns]:
        CASES.append(pytest.param(fn, arg, value, exc, match, id=f"{fn}-{arg}-{label}"))


SHAPE_V = "vertices_vu must have shape"
for label, value in [("1d", np.zeros(4)), ("trailing3", np.zeros((N, 3))),
                     ("trailing1", np.zeros((N, 1))), ("3d", np.zeros((N, 2, 1))),
                     ("scalar", 3.0)]:
    _add(VERTEX_FNS, "vertices_vu", label, value, ValueError, SHAPE_V)
_add(POSE_FNS, "vertices_vu", "empty", np.zeros((0, 2)), ValueError, r"vertices_vu must have shape \(N, 2\) with N > 0")
for label, idx, val in [("nan", (0, 0), NAN), ("inf", (3, 1), INF), ("-inf", (15, 0), -INF)]:
    for fn in VERTEX_FNS:
        _add(fn, "vertices_vu", label, _with("vertices_vu", fn, idx, val), ValueError,
             "vertices_vu must be finite")
_add(VERTEX_FNS, "vertices_vu", "strings", np.full((N, 2), "a"), TypeError, "vertices_vu must be a real")
_add(VERTEX_FNS, "vertices_vu", "ragged", [[1.0, 2.0], [3.0]], TypeError, "vertices_vu must be a numeric")
_add(VERTEX_FNS, "vertices_vu", "complex", np.zeros((N, 2), complex), TypeError, "vertices_vu")

NORMAL_FNS = ["polarity_filter", LM, RIDGE]
for label, value in [("short", np.ones((N - 1, 2))), ("trailing3", np.ones((N, 3))),
                     ("1d", np.ones(2 * N)), ("empty", np.ones((0, 2)))]:
    _add(NORMAL_FNS, "normals_vu", label, value, ValueError, "normals_vu must match vertices_vu shape")
for label, idx, val in [("nan", (2, 0), NAN), ("inf", (5, 1), INF), ("-inf", (0, 0), -INF)]:
    for fn in NORMAL_FNS:
        _add(fn, "normals_vu", label, _with("normals_vu", fn, idx, val), ValueError,
             "normals_vu must be finite")

SIG = "sigma_normal_per_vertex_px"
for label, value in [("2d", np.ones((N, 1))), ("short", np.ones(N - 1)), ("long", np.ones(N + 1)),
                     ("empty", np.ones(0)), ("scalar", 1.0)]:
    _add(POSE_FNS, SIG, label, value, ValueError, "sigma_normal_per_vertex_px must be a 1-D vector")
for label, val in [("zero", 0.0), ("negative", -1.0), ("nan", NAN), ("inf", INF), ("-inf", -INF),
                   ("tiny", 1e-200), ("-0.0", -0.0)]:
    for fn in POSE_FNS:
        _add(fn, SIG, label, _with(SIG, fn, 4, val), ValueError, "must be finite and > 0")

# image-sized arrays (all scanned: 48 x 48 is below FULL_SCAN_MAX_SIZE)
for fn, arg in [(LM, "image_edge_dt"), ("sample_dt_bilinear", "dt"), (RIDGE, "gradient_magnitude")]:
    _add(fn, arg, "1d", np.ones(9), ValueError, f"{arg} must be 2-D")
    _add(fn, arg, "3d", np.ones((4, 4, 1)), ValueError, f"{arg} must be 2-D")
    _add(fn, arg, "empty", np.ones((0, 5)), ValueError, f"{arg} must not be empty")
    _add(fn, arg, "empty-w", np.ones((5, 0)), ValueError, f"{arg} must not be empty")
    _add(fn, arg, "strings", np.full((4, 4), "x"), TypeError, arg)
    for label, idx, val in [("nan-far", (47, 47), NAN), ("inf-far", (0, 0), INF),
                            ("-inf-far", (0, 47), -INF)]:
        _add(fn, arg, label, _with(arg, fn, idx, val), ValueError, f"{arg} must be finite")
for fn in ["polarity_filter", LM]:
    arg = "image_gradient_vu"
    for label, value in [("2d", np.ones((8, 8))), ("trailing3", np.ones((8, 8, 3))),
                         ("trailing1", np.ones((8, 8, 1))), ("empty", np.ones((0, 8, 2))),
                         ("4d", np.ones((8, 8, 2, 1)))]:
        _add(fn, arg, label, value, ValueError, "image_gradient_vu must have shape")
    for label, idx, val in [("nan-far", (47, 47, 0), NAN), ("inf-far", (0, 0, 1), INF),
                            ("-inf-far", (0, 47, 0), -INF)]:
        _add(fn, arg, label, _with(arg, fn, idx, val), ValueError, "image_gradient_vu must be finite")

# offsets, rotation, pivot
for fn, arg in [(LM, "initial_offset_vu"), (RIDGE, "initial_offset_vu"),
                ("polarity_filter", "offset_vu"), (LM, "pivot_vu"), (RIDGE, "pivot_vu")]:
    for label, value in [("nan", (NAN, 0.0)), ("inf", (0.0, INF)), ("-inf", (-INF, 1.0))]:
        _add(fn, arg, label, value, ValueError, f"{arg} must be finite")
    for label, value in [("len1", (1.0,)), ("len3", (1.0, 2.0, 3.0)), ("scalar", 1.0),
                         ("2d", np.ones((2, 1))), ("text", "ab")]:
        _add(fn, arg, label, value, ValueError, f"{arg} must be a length-2 sequence")
    _add(fn, arg, "none-in", (None, 1.0), ValueError, f"{arg} must be finite")  # None -> NaN
for label, value, exc, match in [
    ("nan", NAN, ValueError, "initial_rotation_rad must be finite"),
    ("inf", INF, ValueError, "initial_rotation_rad must be finite"),
    ("-inf", -INF, ValueError, "initial_rotation_rad must be finite"),
    ("text", "0.1", TypeError, "initial_rotation_rad must be a real number"),
    ("bool", True, TypeError, "initial_rotation_rad must be a real number"),
    ("array", np.array([0.1]), TypeError, "initial_rotation_rad must be a real number"),
]:
    _add(POSE_FNS, "initial_rotation_rad", label, value, exc, match)
_add(POSE_FNS, "pivot_distance_px", "nan", NAN, ValueError, "pivot_distance_px must be finite")
_add(POSE_FNS, "pivot_distance_px", "inf", INF, ValueError, "pivot_distance_px must be finite")
_add(POSE_FNS, "pivot_distance_px", "text", "1", TypeError, "pivot_distance_px must be a real")
for label, val in [("zero", 0.0), ("negative", -2.0), ("nan", NAN), ("inf", INF)]:
    for fn in POSE_FNS:
        CASES.append(pytest.param(fn, "fit_rotation", {"fit_rotation": True, "pivot_distance_px": val},
                                  ValueError, "pivot_distance_px > 0", id=f"{fn}-rotation-distance-{label}"))

# LM scalars and flags
for arg in ["damping", "step_tolerance_px", "tikhonov_alpha"]:
    for label, val in [("nan", NAN), ("negative", -1e-3), ("inf", INF), ("-inf", -INF)]:
        _add(LM, arg, label, val, ValueError, f"{arg} must be finite and >= 0")
    _add(LM, arg, "text", "1", TypeError, f"{arg} must be a real number")
for label, val in [("nan", NAN), ("negative", -1.0), ("-inf", -INF)]:
    _add(LM, "trust_region_px", label, val, ValueError, "trust_region_px must be >= 0")
for label, val in [("nan", NAN), ("negative", -1e-9), ("inf", INF)]:
    _add(LM, "pinvh_rcond", label, val, ValueError, "pinvh_rcond must be finite and >= 0")
for fn in POSE_FNS:
    for label, val in [("zero", 0.0), ("negative", -4.0), ("nan", NAN), ("inf", INF)]:
        _add(fn, "tukey_c", label, val, ValueError, "tukey_c must be a positive finite")
    _add(fn, "tukey_c", "bool", True, TypeError, "tukey_c must be a real number")
    _add(fn, "max_iterations", "negative", -1, ValueError, "max_iterations must be non-negative")
    for label, val in [("float", 3.0), ("bool", True), ("text", "3"), ("none", None)]:
        _add(fn, "max_iterations", label, val, TypeError, "max_iterations must be an int")
CASES.append(pytest.param(LM, "final_gradient_ridge",
                          {"final_gradient_ridge": True, "image_gradient_vu": None, "use_polarity": False},
                          ValueError, "final_gradient_ridge=True requires image_gradient_vu",
                          id="lm-ridge-without-gradient"))
_add(LM, "image_gradient_vu", "missing-with-polarity", None, ValueError,
     "use_polarity=True requires image_gradient_vu")

# ridge scalars and weight mask
for arg in ["half_width_px", "sample_step_px"]:
    for label, val in [("zero", 0.0), ("negative", -0.5), ("nan", NAN), ("inf", INF)]:
        _add(RIDGE, arg, label, val, ValueError, f"{arg} must be a finite positive number")
_add(RIDGE, "half_width_px", "below-half-step", 0.2, ValueError, "half_width_px / sample_step_px must round to at least 1")
# round(0.5) == 0 (Python rounds half to even): exactly half a step is refused too
CASES.append(pytest.param(RIDGE, "half_width_px", {"half_width_px": 0.5, "sample_step_px": 1.0}, ValueError,
                          "half_width_px / sample_step_px must round to at least 1", id="ridge-half-width-exactly-half-step"))
for label, val in [("nan", NAN), ("negative", -1.0)]:
    _add(RIDGE, "max_total_displacement_px", label, val, ValueError, "max_total_displacement_px must be >= 0")
for label, value in [("short", np.ones(N - 1, bool)), ("2d", np.ones((N, 1), bool)),
                     ("scalar", True), ("empty", np.ones(0, bool))]:
    _add(RIDGE, "weight_mask", label, value, ValueError, "weight_mask must be a 1-D vector")
for label, idx, val in [("nan", 3, NAN), ("inf", 0, INF), ("-inf", 15, -INF)]:
    _add(RIDGE, "weight_mask", label, (lambda i=idx, x=val: np.where(np.arange(N) == i, x, 1.0)),
         ValueError, "weight_mask must be finite")
_add(RIDGE, "weight_mask", "strings", np.full(N, "y"), TypeError, "weight_mask must be boolean or numeric")

# coarse search and the polyline mask
for arg in ["edge_mask", "polyline_mask"]:
    # :ref:`contract-errors`: one message names both masks
    _add("coarse_ncc_search", arg, "1d", np.ones(48, bool), ValueError,
         "edge_mask and polyline_mask must be 2-D")
    _add("coarse_ncc_search", arg, "3d", np.ones((48, 48, 1), bool), ValueError,
         "edge_mask and polyline_mask must be 2-D")
    _add("coarse_ncc_search", arg, "shape", np.ones((48, 47), bool), ValueError, "shape mismatch")
    _add("coarse_ncc_search", arg, "nan", np.where(np.eye(48) > 0, NAN, 0.0), ValueError,
         f"{arg} must be finite")
    _add("coarse_ncc_search", arg, "inf", np.where(np.eye(48) > 0, INF, 0.0), ValueError,
         f"{arg} must be finite")
    _add("coarse_ncc_search", arg, "strings", np.full((48, 48), "a"), TypeError, arg)
WIN = "search_window_vu"
for label, value in [("ndarray", np.array([3, 3])), ("len1", (3,)), ("len3", (1, 2, 3)),
                     ("int", 3), ("text", "33"), ("none", None), ("set", {3, 4})]:
    _add("coarse_ncc_search", WIN, label, value, ValueError, "length-2 sequence of ints")
for label, value, which in [("float0", (3.0, 3), 0), ("float1", (3, 2.5), 1), ("bool0", (True, 3), 0),
                            ("npbool1", (3, np.bool_(True)), 1), ("npfloat1", (3, np.float64(3)), 1),
                            ("text0", ("3", 3), 0), ("none1", (3, None), 1)]:
    _add("coarse_ncc_search", WIN, label, value, TypeError, rf"search_window_vu\[{which}\] must be int")
for label, value in [("neg0", (-1, 3)), ("neg1", [3, -2]), ("npneg", (np.int64(-5), 0))]:
    _add("coarse_ncc_search", WIN, label, value, ValueError, "must be non-negative")
for label, value, exc, match in [
    ("len1", (48,), ValueError, "shape_vu must be a length-2 sequence"),
    ("len3", (4, 4, 4), ValueError, "shape_vu must be a length-2 sequence"),
    ("int", 48, ValueError, "shape_vu must be a length-2 sequence"),
    ("negative", (-1, 48), ValueError, r"shape_vu\[0\] must be non-negative"),
    ("float", (48, 48.0), TypeError, r"shape_vu\[1\] must be an int"),
    ("bool", (True, 4), TypeError, r"shape_vu\[0\] must be an int"),
]:
    _add("build_polyline_mask", "shape_vu", label, value, exc, match)

# Tukey, covariance, translation
_add("tukey_biweight_weights", "residuals", "2d", np.ones((3, 2)), ValueError, "residuals must be 1-D")
CASES.append(pytest.param(
    "tukey_biweight_weights", "residuals", 1.0, ValueError, "residuals must be 1-D",
    id="tukey_biweight_weights-residuals-scalar"))
_add("tukey_biweight_weights", "residuals", "strings", np.array(["a"]), TypeError, "residuals")
for label, val in [("zero", 0.0), ("negative", -1.0), ("nan", NAN), ("inf", INF)]:
    _add("tukey_biweight_weights", "c", label, val, ValueError, "c must be a positive finite")
_add("tukey_biweight_weights", "c", "bool", True, TypeError, "c must be a real number")
COV = "information_matrix_to_covariance"
_add(COV, "jacobian", "1d", np.ones(3), ValueError, "jacobian must be 2-D")
_add(COV, "jacobian", "3d", np.ones((3, 2, 1)), ValueError, "jacobian must be 2-D")
_add(COV, "weights", "2d", np.ones((3, 1)), ValueError, "must be a 1-D vector")
_add(COV, "weights", "short", np.ones(2), ValueError, "must be a 1-D vector")
_add(COV, "weights", "negative", np.array([1.0, -1e-12, 1.0]), ValueError, "weights must be non-negative")
_add(COV, "weights", "-inf", np.array([1.0, -INF, 1.0]), ValueError, "weights must be")
for label, val in [("nan", NAN), ("inf", INF)]:
    _add(COV, "weights", label, np.array([1.0, val, 1.0]), ValueError, "weights must be finite")
    _add(COV, "jacobian", label, np.array([[1.0, val], [0.0, 1.0], [1.0, 1.0]]), ValueError,
         "jacobian must be finite")
for label, val in [("nan", NAN), ("negative", -1.0)]:
    _add(COV, "rcond", label, val, ValueError, "rcond must be finite and >= 0")
for arg in ["dv", "du"]:
    for label, val in [("nan", NAN), ("inf", INF), ("-inf", -INF)]:
        _add("apply_translation", arg, label, val, ValueError, f"{arg} must be finite")
    for label, val in [("text", "1"), ("bool", False), ("array", np.ones(2)), ("none", None)]:
        _add("apply_translation", arg, label, val, TypeError, f"{arg} must be a real number")

# image side
IMAGE_FNS = ["compute_image_gradient_vu", "build_image_edge_dt", "compute_all_image_derivatives"]
for label, value in [("1d", np.ones(16)), ("3d", np.ones((4, 4, 1))), ("scalar", 1.0)]:
    _add(IMAGE_FNS, "image_ext", label, value, TypeError, "image_ext must be 2-D")
_add(IMAGE_FNS, "image_ext", "strings", np.full((4, 4), "a"), TypeError, "image_ext")
_add(IMAGE_FNS, "image_ext", "complex", np.ones((4, 4), complex), TypeError, "image_ext")
for label, value in [("empty", np.ones((0, 4))), ("empty-w", np.ones((4, 0)))]:
    _add(IMAGE_FNS, "image_ext", label, value, ValueError, "image_ext must not be empty")
for label, idx, val in [("nan", (47, 0), NAN), ("inf", (0, 47), INF), ("-inf", (20, 20), -INF)]:
    for fn in IMAGE_FNS:
        _add(fn, "image_ext", label, _with("image_ext", fn, idx, val), ValueError, "finite")
for label, val in [("zero", 0.0), ("negative", -1.0), ("nan", NAN), ("inf", INF), ("text", "1"),
                   ("bool", True), ("none", None)]:
    _add("compute_image_gradient_vu", "sigma_px", label, val, ValueError,
         "sigma_px must be a finite positive number")
for label, val in [("negative", -1.0), ("nan", NAN), ("inf", INF), ("text", "2"), ("none", None)]:
    _add(IMAGE_FNS[1:], "image_noise_sigma", label, val, ValueError,
         "image_noise_sigma must be finite and >= 0")
for label, val in [("dict", lambda: {"dt_half_width_px": 3.0}), ("text", "default")]:
    _add(IMAGE_FNS[1:], "config", label, val, TypeError, "config must be an ImageDerivativesConfig")
for field in ["image_gradient_sigma_px", "edge_threshold_k_sigma", "dt_half_width_px"]:
    for label, val in [("zero", 0.0), ("negative", -1.0), ("nan", NAN), ("inf", INF), ("bool", True),
                       ("text", "1.0"), ("none", None)]:
        _add("ImageDerivativesConfig", field, label, val, ValueError,
             f"{field} must be a finite positive number")


@pytest.mark.parametrize(("fn", "arg", "value", "exc", "match"), CASES)
def test_refused_with_documented_error(fn, arg, value, exc, match):
    overrides = dict(value) if isinstance(value, dict) else {arg: value}
    with pytest.raises(exc, match=match):
        _call(dtalign, fn, **overrides)
    if hasattr(ref, fn):  # drop-in: the reference refuses identically
        with pytest.raises(exc, match=match):
            _call(ref, fn, **overrides)


def test_matrix_covers_every_public_function():
    spec = {"coarse_ncc_search", "build_polyline_mask", "polarity_filter", "tukey_biweight_weights",
            "information_matrix_to_covariance", "sample_dt_bilinear", "apply_translation", LM, RIDGE,
            "compute_image_gradient_vu", "build_image_edge_dt", "compute_all_image_derivatives",
            "ImageDerivativesConfig"}  # :ref:`contract-surface` (result types: test below)
    assert spec <= set(dtalign.__all__)
    assert {p.values[0] for p in CASES} == spec


def test_result_types_refuse_non_arrays():
    kw = dict(offset_vu=(0.0, 0.0), rotation_rad=0.0, rms_px=1.0, raw_rms_px=1.0, iterations=1,
              converged=True, inlier_count=1, degenerate=False)
    for name in ["covariance", "residuals_px", "weights"]:
        arrays = dict(covariance=np.eye(2), residuals_px=np.zeros(1), weights=np.ones(1))
        arrays[name] = [1.0]
        with pytest.raises(TypeError, match=name):
            dtalign.LMRefineResult(**kw, **arrays)


# --------------------------------------------------------------------------
# Documented results on legal edge cases, finite and equal to the reference
# --------------------------------------------------------------------------


def assert_lm_sane(res, n: int, p: int) -> None:
    """Every field of an LMRefineResult finite, except the documented sentinels."""
    assert all(math.isfinite(x) for x in res.offset_vu) and math.isfinite(res.rotation_rad)
    assert res.residuals_px.shape == (n,) and np.isfinite(res.residuals_px).all()
    assert res.weights.shape == (n,) and np.isfinite(res.weights).all() and (res.weights >= 0).all()
    # :ref:`contract-changes`: the RMS over the polarity-accepted vertices, +inf when none is
    if res.polarity_rejected_count == n:
        assert res.raw_rms_px == INF and res.degenerate
    else:
        assert math.isfinite(res.raw_rms_px) and res.raw_rms_px >= 0
    assert res.inlier_count == np.count_nonzero(res.weights > 0)
    assert isinstance(res.iterations, int) and res.iterations >= 0
    assert res.covariance.shape == (p, p)
    if res.degenerate:  # documented +inf sentinels
        assert res.rms_px == INF and np.isposinf(res.covariance).all() and res.inlier_count == 0
    else:
        assert math.isfinite(res.rms_px) and np.isfinite(res.covariance).all()


def assert_lm_parity(c, r) -> None:
    """The parity bar of ``test_parity`` (see test_reliability_hypothesis for the tolerances)."""
    assert (c.iterations, c.converged, c.degenerate, c.inlier_count) == (
        r.iterations, r.converged, r.degenerate, r.inlier_count)
    np.testing.assert_allclose(c.offset_vu, r.offset_vu, rtol=0, atol=1e-6)
    assert abs(c.rotation_rad - r.rotation_rad) <= 1e-9
    fin = np.isfinite(r.covariance)
    assert (fin == np.isfinite(c.covariance)).all()
    if fin.any():
        scale = np.abs(r.covariance[fin]).max()
        np.testing.assert_allclose(c.covariance[fin], r.covariance[fin], rtol=1e-9, atol=1e-9 * scale)


def _both(fn, **kw):
    return _call(dtalign, fn, **kw), _call(ref, fn, **kw)


OUTSIDE = np.array([[-40.0, -40.0], [-41.0, -39.5], [200.0, 5.0]])
LM_EDGE_CASES = {
    "outside-with-polarity": dict(vertices_vu=OUTSIDE, normals_vu=np.ones((3, 2)),
                                  sigma_normal_per_vertex_px=np.ones(3)),
    "outside-no-polarity": dict(vertices_vu=OUTSIDE, normals_vu=np.ones((3, 2)),
                                sigma_normal_per_vertex_px=np.ones(3), use_polarity=False),
    "outside-rotation-ridge": dict(vertices_vu=OUTSIDE, normals_vu=np.ones((3, 2)),
                                   sigma_normal_per_vertex_px=np.ones(3), fit_rotation=True,
                                   pivot_distance_px=5.0, final_gradient_ridge=True),
    "n1": dict(vertices_vu=lambda: _scene().v[:1], normals_vu=lambda: _scene().n[:1],
               sigma_normal_per_vertex_px=np.ones(1)),
    "n1-rotation": dict(vertices_vu=lambda: _scene().v[:1], normals_vu=lambda: _scene().n[:1],
                        sigma_normal_per_vertex_px=np.ones(1), fit_rotation=True, pivot_distance_px=3.0),
    "polarity-rejects-all": dict(normals_vu=lambda: -_scene().n),
    "max-iterations-0": dict(max_iterations=0),
    "max-iterations-0-rotation": dict(max_iterations=0, fit_rotation=True, pivot_distance_px=10.0),
    "trust-region-0": dict(trust_region_px=0.0),
    "trust-region-inf": dict(trust_region_px=INF),
    "damping-0": dict(damping=0.0, tikhonov_alpha=0.5),
    "flat-dt": dict(image_edge_dt=np.full((48, 48), 3.0), use_polarity=False),
    "zero-dt": dict(image_edge_dt=np.zeros((48, 48)), fit_rotation=True, pivot_distance_px=4.0),
    "dt-1x1": dict(image_edge_dt=np.full((1, 1), 0.5), image_gradient_vu=np.ones((1, 1, 2))),
    "dt-1xW": dict(image_edge_dt=np.abs(np.arange(-24.0, 24.0))[None, :], use_polarity=False),
    "dt-Hx1": dict(image_edge_dt=np.abs(np.arange(-24.0, 24.0))[:, None], use_polarity=False),
    "collinear-rotation": dict(vertices_vu=np.column_stack([np.full(8, 11.0), np.arange(8.0) + 20]),
                               normals_vu=np.tile([1.0, 0.0], (8, 1)),
                               sigma_normal_per_vertex_px=np.ones(8), fit_rotation=True,
                               pivot_distance_px=20.0, use_polarity=False),
    "far-start-ridge": dict(initial_offset_vu=(20.0, -20.0), final_gradient_ridge=True),
    "huge-sigma": dict(sigma_normal_per_vertex_px=np.full(N, 1e100)),
    "zero-step-tolerance": dict(step_tolerance_px=0.0, pinvh_rcond=0.0),
}


@pytest.mark.parametrize("case", sorted(LM_EDGE_CASES))
def test_lm_edge_case_is_finite_and_matches_reference(case):
    kw = LM_EDGE_CASES[case]
    c, r = _both(LM, **kw)
    n = (kw["vertices_vu"]() if callable(kw.get("vertices_vu")) else _base(LM)["vertices_vu"]
         if "vertices_vu" not in kw else kw["vertices_vu"]).shape[0]
    assert_lm_sane(c, n, 3 if kw.get("fit_rotation") else 2)
    assert_lm_parity(c, r)
    if case.startswith("outside-with") or case == "polarity-rejects-all":
        # :ref:`contract-surface`: a polyline entirely outside the image is a legal, degenerate fit
        assert c.degenerate and c.iterations == 0 and c.offset_vu == (1.0, -1.0)
        assert (c.residuals_px == 1e6).all()
    if case.startswith("max-iterations-0"):
        assert c.iterations == 0 and c.offset_vu == (1.0, -1.0) and not c.converged
    if case == "trust-region-0":
        assert c.offset_vu == (1.0, -1.0) and not c.converged


RIDGE_EDGE_CASES = {
    "all-false-mask": dict(weight_mask=np.zeros(N, bool)),
    "outside": dict(vertices_vu=OUTSIDE, normals_vu=np.ones((3, 2)), sigma_normal_per_vertex_px=np.ones(3)),
    "n1": dict(vertices_vu=lambda: _scene().v[:1], normals_vu=lambda: _scene().n[:1],
               sigma_normal_per_vertex_px=np.ones(1)),
    "mag-1x1": dict(gradient_magnitude=np.ones((1, 1))),
    "mag-1xW": dict(gradient_magnitude=np.exp(-np.arange(-20.0, 20.0) ** 2)[None, :]),
    "max-iterations-0": dict(max_iterations=0),
    "rotation": dict(fit_rotation=True, pivot_distance_px=12.0),
    "zero-magnitude": dict(gradient_magnitude=np.zeros((48, 48)), fit_rotation=True, pivot_distance_px=1.0),
    "no-displacement-allowed": dict(max_total_displacement_px=0.0),
    "three-samples": dict(half_width_px=1.0, sample_step_px=1.0),
}


@pytest.mark.parametrize("case", sorted(RIDGE_EDGE_CASES))
def test_ridge_edge_case_is_finite_and_matches_reference(case):
    c, r = _both(RIDGE, **RIDGE_EDGE_CASES[case])
    assert all(math.isfinite(x) for x in [*c.offset_vu, c.rotation_rad])
    assert (c.iterations, c.converged, c.applied) == (r.iterations, r.converged, r.applied)
    np.testing.assert_allclose(c.offset_vu, r.offset_vu, rtol=0, atol=1e-6)
    if not c.applied:  # :ref:`contract-ridge`: the inputs come back unchanged
        assert c.offset_vu == tuple(_scene().offset) and c.rotation_rad == 0.0
    if case in ("all-false-mask", "max-iterations-0", "outside"):
        assert c.iterations == 0 and not c.applied


def test_ridge_weight_mask_nonzero_means_true():
    """A numeric weight mask is read as ``!= 0`` (negative entries count as True)."""
    mask = np.arange(N) % 3 != 0
    as_bool = _call(dtalign, RIDGE, weight_mask=mask)
    numeric = np.where(mask, -2.5, 0.0)
    assert _call(dtalign, RIDGE, weight_mask=numeric) == as_bool
    assert _call(dtalign, RIDGE, weight_mask=mask.astype(np.uint8)) == as_bool


def test_coarse_documented_results():
    b = _scene()
    f = dtalign.coarse_ncc_search
    clipped = f(b.edge, b.pmask, (47, 47))
    assert f(b.edge, b.pmask, (10**6, 2**40)) == clipped == ref.coarse_ncc_search(b.edge, b.pmask, (47, 47))
    assert f(b.edge, np.zeros_like(b.pmask), (5, 5)) == (0, 0)  # empty polyline
    assert f(np.zeros_like(b.edge), b.pmask, (5, 5)) == (0, 0)  # every score 0: the tie-break
    assert f(b.edge, b.pmask, (0, 0)) == (0, 0)
    assert f(b.edge, b.pmask, [np.int64(3), np.uint8(3)]) == f(b.edge, b.pmask, (3, 3))
    for e, p in [(np.ones((1, 1)), np.ones((1, 1))), (np.zeros((0, 5)), np.zeros((0, 5))),
                 (np.eye(1, 9, 4), np.eye(1, 9, 1)), (np.eye(9, 1, -6), np.eye(9, 1, -2))]:
        got = f(e, p, (3, 3))
        assert got == ref.coarse_ncc_search(e, p, (3, 3))
        assert all(type(x) is int for x in got)
    assert f(np.eye(1, 9, 4), np.eye(1, 9, 1), (3, 3)) == (0, 3)
    # numeric masks: a 0/1 edge mask (any dtype) is the boolean one; the polyline
    # mask's nonzero pixels count; other edge values are summed (:ref:`contract-coarse-scored`)
    assert f(b.edge.astype(np.float32), b.pmask.astype(np.int16) * -3, (3, 3)) == f(b.edge, b.pmask, (3, 3))
    weighted = b.edge.astype(np.float32) * -3
    assert f(weighted, b.pmask, (3, 3)) == ref.coarse_ncc_search(weighted, b.pmask, (3, 3))


def test_polyline_mask_documented_results():
    f = dtalign.build_polyline_mask
    assert not f(OUTSIDE, (48, 48)).any()
    assert f(np.zeros((0, 2)), (4, 5)).shape == (4, 5)
    assert f(np.ones((3, 2)), (0, 0)).shape == (0, 0)
    m = f(np.array([[0.5, 1.5], [2.5, -0.5], [-0.6, 0.0], [3.49, 4.5]]), np.array([4, 5]))
    expected = np.zeros((4, 5), bool)
    expected[0, 2] = expected[2, 0] = expected[3, 4] = True  # round half to even; -0.6 dropped
    np.testing.assert_array_equal(m, expected)
    assert m.dtype == np.bool_


def test_small_function_documented_results():
    g = np.zeros((3, 3, 2))
    g[..., 0] = 1.0
    assert dtalign.polarity_filter(np.zeros((0, 2)), np.zeros((0, 2)), g).shape == (0,)
    out = dtalign.polarity_filter(np.array([[1.0, 1.0], [9.0, 1.0]]), np.array([[1.0, 0.0], [1.0, 0.0]]), g)
    np.testing.assert_array_equal(out, [True, False])  # the second vertex is outside
    assert dtalign.polarity_filter([[0.0, 0.0]], [[0.0, 1.0]], np.ones((1, 1, 2))).tolist() == [True]
    assert dtalign.polarity_filter([[0.0, 0.0]], [[1.0, -1.0]], np.ones((1, 1, 2))).tolist() == [False]
    w = dtalign.tukey_biweight_weights(np.array([NAN, INF, -INF, 4.685, -4.685, 0.0, 1e308]))
    np.testing.assert_array_equal(w, [0, 0, 0, 0, 0, 1, 0])  # non-finite residuals get weight 0
    assert dtalign.tukey_biweight_weights(np.zeros(0)).shape == (0,)
    cov = dtalign.information_matrix_to_covariance
    # :ref:`contract-numerics`: no information is the zero matrix (the LM's degenerate result keeps +inf)
    assert not cov(np.zeros((0, 3)), np.zeros(0)).any() and cov(np.zeros((0, 3)), np.zeros(0)).shape == (3, 3)
    assert not cov(np.ones((4, 2)), np.zeros(4)).any()
    assert cov(np.zeros((3, 0)), np.ones(3)).shape == (0, 0)
    rank1 = cov(np.array([[1.0, 0.0], [2.0, 0.0]]), np.ones(2))
    np.testing.assert_allclose(rank1, [[0.2, 0.0], [0.0, 0.0]], rtol=1e-12)  # :ref:`contract-decisions`: null direction 0
    np.testing.assert_array_equal(dtalign.sample_dt_bilinear(np.full((1, 1), 2.0), [[-5.0, 7.0], [0.3, 0.2]]), [2, 2])
    row = np.arange(5.0)[None, :]
    np.testing.assert_array_equal(dtalign.sample_dt_bilinear(row, [[3.0, 1.25], [-1, 99]]), [1.25, 4.0])
    assert dtalign.sample_dt_bilinear(row, np.zeros((0, 2))).shape == (0,)
    assert dtalign.apply_translation(np.zeros((0, 2)), 1.0, 2.0).shape == (0, 2)


@pytest.mark.parametrize("shape", [(1, 1), (1, 9), (9, 1), (2, 2), (3, 40)])
def test_tiny_images_match_reference(shape):
    rng = np.random.default_rng(sum(shape))
    image = rng.normal(size=shape) * 30.0
    for fn, args in [("compute_image_gradient_vu", (image,)),
                     ("compute_all_image_derivatives", (image, 1.0)),
                     ("build_image_edge_dt", (image, 0.0))]:
        got = getattr(dtalign, fn)(*args)
        want = getattr(ref, fn)(*args)
        for g, w in zip(got if isinstance(got, tuple) else (got,), want if isinstance(want, tuple) else (want,), strict=True):
            assert np.isfinite(g).all()
            np.testing.assert_array_equal(g, w)


def test_constant_image_has_no_edges():
    cfg = dtalign.ImageDerivativesConfig(dt_half_width_px=7.5)
    # zero, not any constant: Sobel's cval=0 makes the border of a constant image an edge
    mag, edt = dtalign.build_image_edge_dt(np.zeros((20, 30)), 0.0, config=cfg)
    assert (mag == 0).all() and (edt == 7.5).all()
    assert cfg == dtalign.ImageDerivativesConfig(1.2, 4.0, 7.5) and isinstance(cfg.edge_threshold_k_sigma, float)
    with pytest.raises(AttributeError):
        cfg.dt_half_width_px = 3.0  # frozen
