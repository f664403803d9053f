"""The drop-in surface of :ref:`contract-surface`, tested from ``dtalign`` alone.

Names, constants, signatures, result types, and every error type and
message fragment quoted in :ref:`contract-errors` (matched with
``pytest.raises(..., match=...)`` as callers do), plus the refusals
"beyond the reference" and the inputs that must *not* be errors. Inputs
are tiny arrays built here, with NumPy only.
"""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import re

import numpy as np
import pytest

import dtalign

CONSTANTS = {
    "DEFAULT_TUKEY_C": 4.685,
    "DEFAULT_LM_DAMPING": 1.0e-3,
    "DEFAULT_LM_MAX_ITERATIONS": 30,
    "DEFAULT_LM_STEP_TOLERANCE": 1.0e-3,
    "DEFAULT_PINVH_RCOND": 1.0e-9,
    "DEFAULT_RIDGE_HALF_WIDTH_PX": 3.0,
    "DEFAULT_RIDGE_SAMPLE_STEP_PX": 0.5,
    "DEFAULT_RIDGE_MAX_ITERATIONS": 10,
    "DEFAULT_RIDGE_MAX_TOTAL_DISPLACEMENT_PX": 1.5,
    "DEFAULT_IMAGE_GRADIENT_SIGMA_PX": 1.2,
    "DEFAULT_EDGE_THRESHOLD_K_SIGMA": 4.0,
    "DEFAULT_DT_HALF_WIDTH_PX": 64.0,
}
FUNCTIONS = [
    "coarse_ncc_search", "build_polyline_mask", "polarity_filter", "tukey_biweight_weights",
    "information_matrix_to_covariance", "lm_subpixel_refine", "gradient_ridge_refine",
    "sample_dt_bilinear", "apply_translation", "compute_image_gradient_vu",
    "build_image_edge_dt", "compute_all_image_derivatives",
]
CLASSES = ["LMRefineResult", "RidgeRefineResult", "ImageDerivativesConfig"]

P, K = inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY
NO = inspect.Parameter.empty
C = CONSTANTS
SIGNATURES = {
    # :ref:`contract-changes`: the support floor of today's techniques
    "coarse_ncc_search": [("edge_mask", P, NO), ("polyline_mask", P, NO), ("search_window_vu", P, NO),
                          ("min_support_fraction", K, 0.5)],
    "build_polyline_mask": [("vertices_vu", P, NO), ("shape_vu", P, NO)],
    "polarity_filter": [("vertices_vu", P, NO), ("normals_vu", P, NO),
                        ("image_gradient_vu", P, NO), ("offset_vu", K, (0.0, 0.0))],
    "tukey_biweight_weights": [("residuals", P, NO), ("c", K, C["DEFAULT_TUKEY_C"])],
    "information_matrix_to_covariance": [("jacobian", P, NO), ("weights", P, NO),
                                         ("rcond", K, C["DEFAULT_PINVH_RCOND"])],
    "sample_dt_bilinear": [("dt", P, NO), ("vertices_vu", P, NO)],
    "apply_translation": [("vertices_vu", P, NO), ("dv", P, NO), ("du", P, NO)],
    "compute_image_gradient_vu": [("image_ext", P, NO), ("sigma_px", K, 1.2)],
    "build_image_edge_dt": [("image_ext", P, NO), ("image_noise_sigma", P, NO), ("config", K, None)],
    "compute_all_image_derivatives": [("image_ext", P, NO), ("image_noise_sigma", P, NO),
                                      ("config", K, None)],
    "lm_subpixel_refine": [
        ("vertices_vu", K, NO), ("normals_vu", K, NO), ("sigma_normal_per_vertex_px", K, NO),
        ("image_edge_dt", K, NO), ("image_gradient_vu", K, None), ("initial_offset_vu", K, (0.0, 0.0)),
        ("initial_rotation_rad", K, 0.0), ("fit_rotation", K, False), ("pivot_vu", K, None),
        ("pivot_distance_px", K, 0.0), ("use_polarity", K, True),
        ("max_iterations", K, C["DEFAULT_LM_MAX_ITERATIONS"]), ("damping", K, C["DEFAULT_LM_DAMPING"]),
        ("step_tolerance_px", K, C["DEFAULT_LM_STEP_TOLERANCE"]), ("tukey_c", K, C["DEFAULT_TUKEY_C"]),
        ("pinvh_rcond", K, C["DEFAULT_PINVH_RCOND"]), ("trust_region_px", K, None),
        ("tikhonov_alpha", K, 0.0), ("final_gradient_ridge", K, False)],
    "gradient_ridge_refine": [
        ("vertices_vu", K, NO), ("normals_vu", K, NO), ("sigma_normal_per_vertex_px", K, NO),
        ("gradient_magnitude", K, NO), ("initial_offset_vu", K, NO), ("weight_mask", K, None),
        ("initial_rotation_rad", K, 0.0), ("fit_rotation", K, False), ("pivot_vu", K, None),
        ("pivot_distance_px", K, 0.0), ("max_iterations", K, C["DEFAULT_RIDGE_MAX_ITERATIONS"]),
        ("step_tolerance_px", K, C["DEFAULT_LM_STEP_TOLERANCE"]), ("tukey_c", K, C["DEFAULT_TUKEY_C"]),
        ("half_width_px", K, C["DEFAULT_RIDGE_HALF_WIDTH_PX"]),
        ("sample_step_px", K, C["DEFAULT_RIDGE_SAMPLE_STEP_PX"]),
        ("max_total_displacement_px", K, C["DEFAULT_RIDGE_MAX_TOTAL_DISPLACEMENT_PX"])],
}
LM_FIELDS = ["offset_vu", "rotation_rad", "covariance", "residuals_px", "weights", "rms_px",
             "raw_rms_px", "iterations", "converged", "inlier_count", "degenerate",
             "polarity_rejected_count"]  # :ref:`contract-changes`: the 12th field, last

# --- tiny inputs: a horizontal edge at row 5 of a 12 x 12 image ------------
H = W = 12
VERTS = np.column_stack([np.full(5, 6.0), np.arange(5) + 3.0])
NORMALS = np.tile([1.0, 0.0], (5, 1))
SIGMAS = np.ones(5)
DT = np.abs(np.arange(H, dtype=float)[:, None] - 5.0) * np.ones((1, W))
GRAD = np.zeros((H, W, 2))
GRAD[..., 0] = 1.0  # n . g = 1 > 0: every vertex passes polarity
MAG = np.exp(-0.5 * (np.arange(H, dtype=float)[:, None] - 5.0) ** 2) * np.ones((1, W))
IMAGE = np.where(np.arange(H)[:, None] >= 5, 100.0, 0.0) * np.ones((1, W))
EDGE = DT <= 0.5
POLY = np.zeros((H, W), dtype=bool)
POLY[6, 3:8] = True


def lm(**over):
    kw = dict(vertices_vu=VERTS, normals_vu=NORMALS, sigma_normal_per_vertex_px=SIGMAS,
              image_edge_dt=DT, image_gradient_vu=GRAD)
    kw.update(over)
    return dtalign.lm_subpixel_refine(**kw)


def ridge(**over):
    kw = dict(vertices_vu=VERTS, normals_vu=NORMALS, sigma_normal_per_vertex_px=SIGMAS,
              gradient_magnitude=MAG, initial_offset_vu=(0.0, 0.0))
    kw.update(over)
    return dtalign.gradient_ridge_refine(**kw)


def nan_at(arr, index, value=np.nan):
    out = np.array(arr, dtype=float)
    out[index] = value
    return out


# --------------------------------------------------------------------------
# Names, constants, signatures, result types
# --------------------------------------------------------------------------


@pytest.mark.parametrize("name", [*CONSTANTS, *FUNCTIONS, *CLASSES])
def test_name_importable_and_exported(name):
    assert name in dtalign.__all__
    ns: dict = {}
    exec(f"from dtalign import {name}", ns)
    assert ns[name] is getattr(dtalign, name)


def test_star_import_gives_every_name():
    ns: dict = {}
    exec("from dtalign import *", ns)
    assert {*CONSTANTS, *FUNCTIONS, *CLASSES} <= set(ns)


def test_dir_lists_the_public_names_only():
    # the same before and after a lazy name is loaded, or a subpackage imported
    before = dir(dtalign)
    assert before == sorted({*dtalign.__all__, "__version__"})
    for helper in ("Any", "TYPE_CHECKING", "annotations", "importlib", "_LAZY", "_PRIVATE_LAZY",
                   "api", "pipeline", "_rotate_vertices"):
        assert helper not in before, helper
    importlib.import_module("dtalign.pipeline")  # binds the subpackage on the package
    dtalign.fit_polyline, dtalign._rotate_vertices  # noqa: B018  (loads them lazily)
    assert dir(dtalign) == before
    assert all(hasattr(dtalign, name) for name in before)


@pytest.mark.parametrize("name", CONSTANTS)
def test_constant_exact_value(name):
    value = getattr(dtalign, name)
    assert value == CONSTANTS[name]
    assert type(value) is type(CONSTANTS[name])  # 30 and 10 are ints, the rest floats


@pytest.mark.parametrize("name", SIGNATURES)
def test_signature(name):
    params = list(inspect.signature(getattr(dtalign, name)).parameters.values())
    got = [(p.name, p.kind, p.default) for p in params]
    assert got == SIGNATURES[name]
    for p, (_, _, default) in zip(params, SIGNATURES[name], strict=True):
        assert type(p.default) is type(default)


def test_lm_result_fields_and_frozen():
    assert [f.name for f in dataclasses.fields(dtalign.LMRefineResult)] == LM_FIELDS
    res = lm()
    with pytest.raises(dataclasses.FrozenInstanceError):
        res.rms_px = 0.0
    for name in ("covariance", "residuals_px", "weights"):
        arr = getattr(res, name)
        assert isinstance(arr, np.ndarray) and not arr.flags.writeable
        with pytest.raises(ValueError):
            arr[0] = 1.0
    assert isinstance(res.offset_vu, tuple) and len(res.offset_vu) == 2
    assert all(type(x) is float for x in res.offset_vu)
    assert type(res.rotation_rad) is float and type(res.rms_px) is float
    assert type(res.raw_rms_px) is float and type(res.iterations) is int
    assert type(res.inlier_count) is int
    assert type(res.converged) is bool and type(res.degenerate) is bool
    assert res.covariance.shape == (2, 2) and res.residuals_px.shape == res.weights.shape == (5,)


def _lm_result_kwargs(**over):
    kw = dict(offset_vu=(0.0, 0.0), rotation_rad=0.0, covariance=np.eye(2),
              residuals_px=np.zeros(3), weights=np.ones(3), rms_px=0.0, raw_rms_px=0.0,
              iterations=0, converged=False, inlier_count=3, degenerate=False)
    kw.update(over)
    return kw


def test_lm_result_built_by_hand_is_read_only():
    res = dtalign.LMRefineResult(**_lm_result_kwargs())
    for name in ("covariance", "residuals_px", "weights"):
        assert not getattr(res, name).flags.writeable


@pytest.mark.parametrize("field", ["covariance", "residuals_px", "weights"])
def test_lm_result_refuses_non_ndarray(field):
    with pytest.raises(TypeError):
        dtalign.LMRefineResult(**_lm_result_kwargs(**{field: [[1.0, 0.0], [0.0, 1.0]]}))


def test_ridge_result_fields_and_frozen():
    names = [f.name for f in dataclasses.fields(dtalign.RidgeRefineResult)]
    assert names == ["offset_vu", "rotation_rad", "iterations", "converged", "applied"]
    res = ridge()
    assert isinstance(res, dtalign.RidgeRefineResult)
    with pytest.raises(dataclasses.FrozenInstanceError):
        res.applied = True
    assert isinstance(res.offset_vu, tuple) and len(res.offset_vu) == 2
    assert type(res.iterations) is int and type(res.converged) is bool and type(res.applied) is bool


def test_image_config_fields_defaults_frozen():
    fields = dataclasses.fields(dtalign.ImageDerivativesConfig)
    assert [(f.name, f.default) for f in fields] == [
        ("image_gradient_sigma_px", 1.2), ("edge_threshold_k_sigma", 4.0), ("dt_half_width_px", 64.0)]
    cfg = dtalign.ImageDerivativesConfig()
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.dt_half_width_px = 3.0


def test_return_types_of_the_pieces():
    dv, du = dtalign.coarse_ncc_search(EDGE, POLY, (3, 3))
    assert type(dv) is int and type(du) is int and (dv, du) == (-1, 0)
    mask = dtalign.build_polyline_mask(VERTS, (H, W))
    assert mask.dtype == np.bool_ and mask.shape == (H, W)
    pol = dtalign.polarity_filter(VERTS, NORMALS, GRAD)
    assert pol.dtype == np.bool_ and pol.shape == (5,) and pol.all()
    w = dtalign.tukey_biweight_weights(np.zeros(4))
    assert w.dtype == np.float64 and w.shape == (4,)
    cov = dtalign.information_matrix_to_covariance(np.eye(3), np.ones(3))
    assert cov.dtype == np.float64 and cov.shape == (3, 3)
    s = dtalign.sample_dt_bilinear(DT, VERTS)
    assert s.dtype == np.float64 and s.shape == (5,)
    moved = dtalign.apply_translation(VERTS, 1.5, -2.0)
    assert moved is not VERTS and moved.shape == (5, 2)
    np.testing.assert_array_equal(moved, VERTS + [1.5, -2.0])
    assert VERTS[0, 0] == 6.0  # the input is untouched
    g = dtalign.compute_image_gradient_vu(IMAGE)
    assert g.dtype == np.float64 and g.shape == (H, W, 2)
    two = dtalign.build_image_edge_dt(IMAGE, 1.0)
    assert len(two) == 2 and all(a.shape == (H, W) for a in two)
    three = dtalign.compute_all_image_derivatives(IMAGE, 1.0, config=dtalign.ImageDerivativesConfig())
    assert len(three) == 3 and three[2].shape == (H, W, 2)


# --------------------------------------------------------------------------
# Errors of the drop-in surface (:ref:`contract-errors`): type and message fragment
# --------------------------------------------------------------------------

E = ValueError
SPEC_ERRORS = [
    # coarse_ncc_search
    ("coarse-edge-1d", lambda: dtalign.coarse_ncc_search(EDGE[0], POLY, (1, 1)), E, "must be 2-D"),
    ("coarse-poly-3d", lambda: dtalign.coarse_ncc_search(EDGE, POLY[..., None], (1, 1)), E, "must be 2-D"),
    ("coarse-shapes", lambda: dtalign.coarse_ncc_search(EDGE, POLY[:5], (1, 1)), E, "shape mismatch"),
    ("coarse-ndarray", lambda: dtalign.coarse_ncc_search(EDGE, POLY, np.array([1, 1])), E,
     "length-2 sequence of ints"),
    ("coarse-len3", lambda: dtalign.coarse_ncc_search(EDGE, POLY, (1, 1, 1)), E, "length-2 sequence of ints"),
    ("coarse-scalar", lambda: dtalign.coarse_ncc_search(EDGE, POLY, 3), E, "length-2 sequence of ints"),
    ("coarse-bool", lambda: dtalign.coarse_ncc_search(EDGE, POLY, (True, 1)), TypeError,
     "search_window_vu[0] must be int"),
    ("coarse-float", lambda: dtalign.coarse_ncc_search(EDGE, POLY, [1, 2.0]), TypeError,
     "search_window_vu[1] must be int"),
    ("coarse-negative", lambda: dtalign.coarse_ncc_search(EDGE, POLY, (1, -1)), E, "must be non-negative"),
    # polarity_filter
    ("pol-verts", lambda: dtalign.polarity_filter(np.zeros((5, 3)), NORMALS, GRAD), E,
     "vertices_vu must have shape"),
    ("pol-verts-1d", lambda: dtalign.polarity_filter(np.zeros(5), NORMALS, GRAD), E,
     "vertices_vu must have shape"),
    ("pol-normals", lambda: dtalign.polarity_filter(VERTS, NORMALS[:4], GRAD), E,
     "normals_vu must match vertices_vu shape"),
    ("pol-grad-2d", lambda: dtalign.polarity_filter(VERTS, NORMALS, DT), E, "image_gradient_vu must have shape"),
    ("pol-grad-3ch", lambda: dtalign.polarity_filter(VERTS, NORMALS, np.zeros((H, W, 3))), E,
     "image_gradient_vu must have shape"),
    # tukey_biweight_weights
    *[(f"tukey-c-{c}", (lambda c=c: dtalign.tukey_biweight_weights(np.zeros(3), c=c)), E,
       "c must be a positive finite") for c in (0.0, -1.0, np.nan, np.inf)],
    ("tukey-2d", lambda: dtalign.tukey_biweight_weights(np.zeros((3, 1))), E, "residuals must be 1-D"),
    # information_matrix_to_covariance
    ("cov-jac-1d", lambda: dtalign.information_matrix_to_covariance(np.ones(3), np.ones(3)), E,
     "jacobian must be 2-D"),
    ("cov-w-2d", lambda: dtalign.information_matrix_to_covariance(np.ones((3, 2)), np.ones((3, 1))), E,
     "must be a 1-D vector"),
    ("cov-w-len", lambda: dtalign.information_matrix_to_covariance(np.ones((3, 2)), np.ones(4)), E,
     "must be a 1-D vector"),
    ("cov-w-neg", lambda: dtalign.information_matrix_to_covariance(np.ones((3, 2)), [1.0, -1e-300, 1.0]),
     E, "weights must be non-negative"),
    # sampling
    ("sample-dt-1d", lambda: dtalign.sample_dt_bilinear(DT[0], VERTS), E, "dt must be 2-D"),
    ("sample-dt-3d", lambda: dtalign.sample_dt_bilinear(GRAD, VERTS), E, "dt must be 2-D"),
    ("sample-verts", lambda: dtalign.sample_dt_bilinear(DT, np.zeros((5, 3))), E,
     "vertices_vu must have shape (N, 2)"),
    ("translate-verts", lambda: dtalign.apply_translation(np.zeros(4), 1.0, 1.0), E,
     "vertices_vu must have shape (N, 2)"),
    # lm_subpixel_refine
    ("lm-verts", lambda: lm(vertices_vu=np.zeros((5, 3))), E, "vertices_vu must have shape"),
    ("lm-verts-empty", lambda: lm(vertices_vu=np.zeros((0, 2)), normals_vu=np.zeros((0, 2)),
                                  sigma_normal_per_vertex_px=np.zeros(0)), E, "vertices_vu must have shape"),
    ("lm-normals", lambda: lm(normals_vu=NORMALS[:4]), E, "normals_vu must match"),
    ("lm-sigma-2d", lambda: lm(sigma_normal_per_vertex_px=np.ones((5, 1))), E,
     "sigma_normal_per_vertex_px must be a 1-D vector"),
    ("lm-sigma-len", lambda: lm(sigma_normal_per_vertex_px=np.ones(4)), E,
     "sigma_normal_per_vertex_px must be a 1-D vector"),
    *[(f"lm-sigma-{s}", (lambda s=s: lm(sigma_normal_per_vertex_px=[1.0, 1.0, s, 1.0, 1.0])), E,
       "must be finite and > 0") for s in (0.0, -1.0, np.nan, np.inf)],
    ("lm-dt-1d", lambda: lm(image_edge_dt=DT[0]), E, "image_edge_dt must be 2-D"),
    ("lm-dt-3d", lambda: lm(image_edge_dt=GRAD), E, "image_edge_dt must be 2-D"),
    *[(f"lm-pivot-distance-{d}", (lambda d=d: lm(fit_rotation=True, pivot_distance_px=d)), E,
       "pivot_distance_px > 0") for d in (0.0, -3.0)],
    ("lm-ridge-no-grad", lambda: lm(image_gradient_vu=None, use_polarity=False, final_gradient_ridge=True),
     E, "final_gradient_ridge=True requires image_gradient_vu"),
    ("lm-polarity-no-grad", lambda: lm(image_gradient_vu=None), E,
     "use_polarity=True requires image_gradient_vu"),
    # gradient_ridge_refine
    ("ridge-verts", lambda: ridge(vertices_vu=np.zeros((5, 1))), E, "vertices_vu must have shape"),
    ("ridge-normals", lambda: ridge(normals_vu=np.zeros((4, 2))), E, "normals_vu must match"),
    ("ridge-sigma-len", lambda: ridge(sigma_normal_per_vertex_px=np.ones(6)), E,
     "sigma_normal_per_vertex_px must be a 1-D vector"),
    ("ridge-sigma-0", lambda: ridge(sigma_normal_per_vertex_px=np.zeros(5)), E, "must be finite and > 0"),
    ("ridge-rotation", lambda: ridge(fit_rotation=True), E, "pivot_distance_px > 0"),
    ("ridge-mag-3d", lambda: ridge(gradient_magnitude=GRAD), E, "gradient_magnitude must be 2-D"),
    ("ridge-mag-1d", lambda: ridge(gradient_magnitude=MAG[0]), E, "gradient_magnitude must be 2-D"),
    # image side
    *[(f"image-{fn}-{nd}d", (lambda fn=fn, nd=nd: getattr(dtalign, fn)(
        *([np.zeros((4,) * nd)] + ([1.0] if fn != "compute_image_gradient_vu" else [])))),
       TypeError, "image_ext must be 2-D")
      for fn in ("compute_image_gradient_vu", "build_image_edge_dt", "compute_all_image_derivatives")
      for nd in (1, 3)],
    *[(f"image-{fn}-{bad}", (lambda fn=fn, bad=bad: getattr(dtalign, fn)(
        *([nan_at(IMAGE, (2, 3), bad)] + ([1.0] if fn != "compute_image_gradient_vu" else [])))),
       E, "finite")
      for fn in ("compute_image_gradient_vu", "build_image_edge_dt", "compute_all_image_derivatives")
      for bad in (np.nan, np.inf, -np.inf)],
    *[(f"sigma-px-{s}", (lambda s=s: dtalign.compute_image_gradient_vu(IMAGE, sigma_px=s)), E,
       "sigma_px must be a finite positive number") for s in (0.0, -1.0, np.nan, np.inf)],
    *[(f"noise-{fn}-{s}", (lambda fn=fn, s=s: getattr(dtalign, fn)(IMAGE, s)), E,
       "image_noise_sigma must be finite and >= 0")
      for fn in ("build_image_edge_dt", "compute_all_image_derivatives") for s in (-1.0, np.nan, np.inf)],
    *[(f"config-{field}-{v}", (lambda field=field, v=v: dtalign.compute_all_image_derivatives(
        IMAGE, 1.0, config=dtalign.ImageDerivativesConfig(**{field: v}))), E,
       f"{field} must be a finite positive number")
      for field in ("image_gradient_sigma_px", "edge_threshold_k_sigma", "dt_half_width_px")
      for v in (0.0, -2.0, np.nan, np.inf)],
]


@pytest.mark.parametrize("call, exc, fragment", [e[1:] for e in SPEC_ERRORS], ids=[e[0] for e in SPEC_ERRORS])
def test_spec_error(call, exc, fragment):
    with pytest.raises(exc, match=re.escape(fragment)):
        call()


# Two faults at once: the one checked first (:ref:`contract-errors`) is reported.
LM_ORDER = [
    ("vertices>normals", dict(vertices_vu=np.zeros((5, 3)), normals_vu=np.zeros((2, 2))),
     "vertices_vu must have shape"),
    ("normals>sigmas", dict(normals_vu=np.zeros((2, 2)), sigma_normal_per_vertex_px=np.ones(2)),
     "normals_vu must match"),
    ("sigma-shape>dt", dict(sigma_normal_per_vertex_px=np.ones((5, 2)), image_edge_dt=DT[0]),
     "sigma_normal_per_vertex_px must be a 1-D vector"),
    ("sigma-value>dt", dict(sigma_normal_per_vertex_px=-SIGMAS, image_edge_dt=DT[0]),
     "must be finite and > 0"),
    ("dt>rotation", dict(image_edge_dt=DT[0], fit_rotation=True), "image_edge_dt must be 2-D"),
    ("rotation>ridge", dict(fit_rotation=True, image_gradient_vu=None, final_gradient_ridge=True),
     "pivot_distance_px > 0"),
    ("ridge>polarity", dict(image_gradient_vu=None, final_gradient_ridge=True),
     "final_gradient_ridge=True requires image_gradient_vu"),
    ("all-faults", dict(vertices_vu=np.zeros((0, 2)), normals_vu=np.zeros((3, 3)),
                        sigma_normal_per_vertex_px=np.zeros(2), image_edge_dt=DT[0], fit_rotation=True,
                        image_gradient_vu=None, final_gradient_ridge=True),
     "vertices_vu must have shape"),
]


@pytest.mark.parametrize("faults, fragment", [o[1:] for o in LM_ORDER], ids=[o[0] for o in LM_ORDER])
def test_lm_check_order(faults, fragment):
    with pytest.raises(ValueError, match=re.escape(fragment)):
        lm(**faults)


def test_ridge_check_order():
    with pytest.raises(ValueError, match=re.escape("normals_vu must match")):
        ridge(normals_vu=np.zeros((2, 2)), sigma_normal_per_vertex_px=np.ones(3))
    with pytest.raises(ValueError, match=re.escape("must be finite and > 0")):
        ridge(sigma_normal_per_vertex_px=-SIGMAS, gradient_magnitude=MAG[0])


# --------------------------------------------------------------------------
# Beyond the reference: clear ValueErrors naming the argument
# --------------------------------------------------------------------------

BIG = 300  # 90000 values: more than dtalign scans up front, so the NaN sits where the fit reads
BIG_VERTS = np.column_stack([np.full(5, 150.0), np.arange(5) + 100.0])
BIG_DT = np.abs(np.arange(BIG, dtype=float)[:, None] - 149.0) * np.ones((1, BIG))
BIG_GRAD = np.zeros((BIG, BIG, 2))
BIG_GRAD[..., 0] = 1.0
BIG_MAG = np.exp(-0.5 * (np.arange(BIG, dtype=float)[:, None] - 149.0) ** 2) * np.ones((1, BIG))
NAN_VERTS = nan_at(VERTS, (2, 1))
NAN_NORMALS = nan_at(NORMALS, (1, 0))

BEYOND = [
    ("lm-vertices-nan", lambda: lm(vertices_vu=NAN_VERTS), "vertices_vu"),
    ("lm-vertices-inf", lambda: lm(vertices_vu=VERTS + [[np.inf, 0.0]] * 5), "vertices_vu"),
    ("lm-normals-nan", lambda: lm(normals_vu=NAN_NORMALS), "normals_vu"),
    ("lm-offset-nan", lambda: lm(initial_offset_vu=(0.0, np.nan)), "initial_offset_vu"),
    ("lm-offset-inf", lambda: lm(initial_offset_vu=(np.inf, 0.0)), "initial_offset_vu"),
    ("lm-offset-len3", lambda: lm(initial_offset_vu=(0.0, 0.0, 0.0)), "initial_offset_vu"),
    ("lm-offset-len1", lambda: lm(initial_offset_vu=(0.0,)), "initial_offset_vu"),
    ("lm-rotation-nan", lambda: lm(initial_rotation_rad=np.nan), "initial_rotation_rad"),
    ("lm-rotation-inf", lambda: lm(initial_rotation_rad=np.inf, fit_rotation=True, pivot_distance_px=5.0),
     "initial_rotation_rad"),
    ("lm-pivot-nan", lambda: lm(pivot_vu=(np.nan, 1.0)), "pivot_vu"),
    ("lm-pivot-len3", lambda: lm(pivot_vu=(1.0, 1.0, 1.0)), "pivot_vu"),
    ("lm-pivot-distance-nan", lambda: lm(pivot_distance_px=np.nan), "pivot_distance_px"),
    ("lm-pivot-distance-inf", lambda: lm(pivot_distance_px=np.inf, fit_rotation=True), "pivot_distance_px"),
    ("lm-dt-nan-small", lambda: lm(image_edge_dt=nan_at(DT, (0, 0))), "image_edge_dt"),
    ("lm-dt-inf-small", lambda: lm(image_edge_dt=DT + np.where(DT > 5, np.inf, 0.0)), "image_edge_dt"),
    ("lm-grad-nan-small", lambda: lm(image_gradient_vu=nan_at(GRAD, (11, 11, 1))), "image_gradient_vu"),
    ("lm-dt-empty", lambda: lm(image_edge_dt=np.zeros((0, 4))), "image_edge_dt"),
    ("lm-dt-nan-read", lambda: lm(vertices_vu=BIG_VERTS, image_edge_dt=nan_at(BIG_DT, (150, 102)),
                                  image_gradient_vu=BIG_GRAD), "image_edge_dt"),
    ("lm-grad-nan-read", lambda: lm(vertices_vu=BIG_VERTS, image_edge_dt=BIG_DT,
                                    image_gradient_vu=nan_at(BIG_GRAD, (150, 101, 0))), "image_gradient_vu"),
    ("lm-ridge-grad-nan-read", lambda: lm(vertices_vu=BIG_VERTS, image_edge_dt=BIG_DT, use_polarity=False,
                                          image_gradient_vu=nan_at(BIG_GRAD, (150, 101, 1)),
                                          final_gradient_ridge=True), "image_gradient_vu"),
    *[(f"lm-{name}-{v}", (lambda name=name, v=v: lm(**{name: v})), name)
      for name in ("trust_region_px", "tikhonov_alpha", "damping", "step_tolerance_px")
      for v in (np.nan, -1.0)],
    ("lm-max-iterations", lambda: lm(max_iterations=-1), "max_iterations"),
    ("ridge-vertices-nan", lambda: ridge(vertices_vu=NAN_VERTS), "vertices_vu"),
    ("ridge-normals-inf", lambda: ridge(normals_vu=nan_at(NORMALS, (0, 1), np.inf)), "normals_vu"),
    ("ridge-offset-nan", lambda: ridge(initial_offset_vu=(np.nan, 0.0)), "initial_offset_vu"),
    ("ridge-offset-len3", lambda: ridge(initial_offset_vu=(0.0, 0.0, 1.0)), "initial_offset_vu"),
    ("ridge-rotation-nan", lambda: ridge(initial_rotation_rad=np.nan), "initial_rotation_rad"),
    ("ridge-pivot-inf", lambda: ridge(pivot_vu=(0.0, np.inf)), "pivot_vu"),
    ("ridge-mag-nan-small", lambda: ridge(gradient_magnitude=nan_at(MAG, (0, 11))), "gradient_magnitude"),
    ("ridge-mag-empty", lambda: ridge(gradient_magnitude=np.zeros((3, 0))), "gradient_magnitude"),
    ("ridge-mag-nan-read", lambda: ridge(vertices_vu=BIG_VERTS, gradient_magnitude=nan_at(BIG_MAG, (149, 102))),
     "gradient_magnitude"),
    *[(f"ridge-sample-step-{v}", (lambda v=v: ridge(sample_step_px=v)), "sample_step_px") for v in (0.0, -0.5)],
    *[(f"ridge-half-width-{v}", (lambda v=v: ridge(half_width_px=v)), "half_width_px") for v in (0.0, -3.0)],
    ("ridge-max-iterations", lambda: ridge(max_iterations=-2), "max_iterations"),
    ("sample-vertices-nan", lambda: dtalign.sample_dt_bilinear(DT, NAN_VERTS), "vertices_vu"),
    ("sample-dt-nan-small", lambda: dtalign.sample_dt_bilinear(nan_at(DT, (3, 3)), VERTS), r"\bdt\b"),
    ("sample-dt-nan-read", lambda: dtalign.sample_dt_bilinear(nan_at(BIG_DT, (150, 100)), BIG_VERTS), r"\bdt\b"),
    ("sample-dt-empty", lambda: dtalign.sample_dt_bilinear(np.zeros((0, 0)), VERTS), r"\bdt\b"),
    ("translate-vertices-inf", lambda: dtalign.apply_translation(-np.inf * VERTS, 0.0, 0.0), "vertices_vu"),
    ("translate-dv-nan", lambda: dtalign.apply_translation(VERTS, np.nan, 0.0), r"\bdv\b"),
    ("translate-du-inf", lambda: dtalign.apply_translation(VERTS, 0.0, np.inf), r"\bdu\b"),
    ("polarity-vertices-nan", lambda: dtalign.polarity_filter(NAN_VERTS, NORMALS, GRAD), "vertices_vu"),
    ("polarity-normals-nan", lambda: dtalign.polarity_filter(VERTS, NAN_NORMALS, GRAD), "normals_vu"),
    ("polarity-offset-nan", lambda: dtalign.polarity_filter(VERTS, NORMALS, GRAD, offset_vu=(np.nan, 0)),
     "offset_vu"),
    ("polarity-offset-len3", lambda: dtalign.polarity_filter(VERTS, NORMALS, GRAD, offset_vu=(0, 0, 0)),
     "offset_vu"),
    ("polarity-grad-nan-small", lambda: dtalign.polarity_filter(VERTS, NORMALS, nan_at(GRAD, (0, 0, 0))),
     "image_gradient_vu"),
    ("polarity-grad-nan-read", lambda: dtalign.polarity_filter(BIG_VERTS, NORMALS, nan_at(BIG_GRAD, (150, 104, 1))),
     "image_gradient_vu"),
    ("mask-vertices-nan", lambda: dtalign.build_polyline_mask(NAN_VERTS, (H, W)), "vertices_vu"),
    ("mask-shape-len1", lambda: dtalign.build_polyline_mask(VERTS, (H,)), "shape_vu"),
    ("mask-shape-len3", lambda: dtalign.build_polyline_mask(VERTS, (H, W, 2)), "shape_vu"),
    ("image-empty", lambda: dtalign.compute_all_image_derivatives(np.zeros((0, 5)), 1.0), "image_ext"),
    ("image-empty-gradient", lambda: dtalign.compute_image_gradient_vu(np.zeros((4, 0))), "image_ext"),
]


@pytest.mark.parametrize("call, name", [b[1:] for b in BEYOND], ids=[b[0] for b in BEYOND])
def test_refused_beyond_the_reference(call, name):
    with pytest.raises(ValueError, match=name):
        call()


# --------------------------------------------------------------------------
# Not errors
# --------------------------------------------------------------------------


def test_search_window_larger_than_arrays_is_clipped():
    big = dtalign.coarse_ncc_search(EDGE, POLY, (1000, 5000))
    assert big == dtalign.coarse_ncc_search(EDGE, POLY, (H - 1, W - 1)) == (-1, 0)
    assert dtalign.coarse_ncc_search(EDGE[:1, :1], POLY[:1, :1], (50, 50)) == (0, 0)


def test_polyline_entirely_outside_the_image_is_a_degenerate_fit():
    far = VERTS + [500.0, -700.0]
    res = lm(vertices_vu=far)  # polarity rejects every vertex outside the image
    assert res.degenerate and res.inlier_count == 0
    assert res.rms_px == np.inf and np.all(res.covariance == np.inf)
    assert res.offset_vu == (0.0, 0.0) and res.iterations == 0
    free = lm(vertices_vu=far, use_polarity=False)  # samples clamp to the border: legal
    assert isinstance(free, dtalign.LMRefineResult)
    assert isinstance(ridge(vertices_vu=far), dtalign.RidgeRefineResult)
    assert not dtalign.polarity_filter(far, NORMALS, GRAD).any()
    assert not dtalign.build_polyline_mask(far, (H, W)).any()
    np.testing.assert_array_equal(dtalign.sample_dt_bilinear(DT, far), np.full(5, DT[H - 1, 0]))


def test_valid_edge_values_are_accepted():
    assert lm(trust_region_px=0.0, tikhonov_alpha=0.0, damping=0.0, step_tolerance_px=0.0,
              max_iterations=0).iterations == 0
    assert lm(trust_region_px=np.inf).iterations >= 1
    assert dtalign.build_image_edge_dt(IMAGE, 0.0)[1].shape == (H, W)  # noise sigma 0 is allowed
    assert dtalign.coarse_ncc_search(EDGE, POLY, [0, 0]) == (0, 0)  # a list works too
