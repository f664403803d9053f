""":ref:`contract-surface` and §8: the names, constants, signatures and result dataclasses.

Written only against the contract (``docs/contract.rst``, §§1-5, §8, §9).
A ``§N`` in these files is section N of the contract. Every name is
looked up on the ``dtalign`` module inside the test, so a missing name fails
its own tests rather than the whole file.
"""

from __future__ import annotations

import dataclasses
import inspect
import re

import numpy as np
import pytest

import dtalign

pytestmark = pytest.mark.filterwarnings("error")

SECTION1_NAMES = [
    "DEFAULT_TUKEY_C", "DEFAULT_LM_DAMPING", "DEFAULT_LM_MAX_ITERATIONS",
    "DEFAULT_LM_STEP_TOLERANCE", "DEFAULT_PINVH_RCOND", "DEFAULT_RIDGE_HALF_WIDTH_PX",
    "DEFAULT_RIDGE_SAMPLE_STEP_PX", "DEFAULT_RIDGE_MAX_ITERATIONS",
    "DEFAULT_RIDGE_MAX_TOTAL_DISPLACEMENT_PX", "DEFAULT_IMAGE_GRADIENT_SIGMA_PX",
    "DEFAULT_EDGE_THRESHOLD_K_SIGMA", "DEFAULT_DT_HALF_WIDTH_PX",
    "coarse_ncc_search", "build_polyline_mask", "polarity_filter", "tukey_biweight_weights",
    "information_matrix_to_covariance", "lm_subpixel_refine", "gradient_ridge_refine",
    "LMRefineResult", "RidgeRefineResult",
    "sample_dt_bilinear", "apply_translation",
    "ImageDerivativesConfig", "compute_image_gradient_vu", "build_image_edge_dt",
    "compute_all_image_derivatives",
]

SECTION8_PUBLIC = [
    "DEFAULT_COARSE_MIN_SUPPORT_FRACTION", "CoarseSearchResult", "coarse_ncc_search_scored",
    "coarse_polarity_search_scored", "SecondaryBasin", "find_secondary_dt_minimum",
    "DTFitGateConfig", "DTFitGateVerdict", "evaluate_dt_fit_gates",
]

SECTION8_PRIVATE = ["_rotate_vertices", "_rotate_directions", "_INFINITY_DT_PENALTY_PX"]

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
    "DEFAULT_COARSE_MIN_SUPPORT_FRACTION": 0.5,
    "_INFINITY_DT_PENALTY_PX": 1e6,
}
INT_CONSTANTS = {"DEFAULT_LM_MAX_ITERATIONS", "DEFAULT_RIDGE_MAX_ITERATIONS"}


# ---------------------------------------------------------------- names

@pytest.mark.parametrize("name", SECTION1_NAMES + SECTION8_PUBLIC)
def test_public_name_importable_and_in_all(name):
    assert hasattr(dtalign, name), f"dtalign.{name} missing"
    assert name in dtalign.__all__
    ns: dict = {}
    exec(f"from dtalign import {name}", ns)
    assert ns[name] is getattr(dtalign, name)


@pytest.mark.parametrize("name", SECTION8_PRIVATE)
def test_private_name_importable_not_in_all(name):
    ns: dict = {}
    exec(f"from dtalign import {name}", ns)
    assert ns[name] is getattr(dtalign, name)
    assert name not in dtalign.__all__


def test_ridge_module_exposes_replaceable_stage():
    # §8.1: the ridge stage is reached through dtalign.ridge.gradient_ridge_refine
    import dtalign.ridge

    assert callable(dtalign.ridge.gradient_ridge_refine)


# ---------------------------------------------------------------- constants

@pytest.mark.parametrize("name,value", sorted(CONSTANTS.items()))
def test_constant_exact_value(name, value):
    got = getattr(dtalign, name)
    assert got == value
    if name in INT_CONSTANTS:
        assert isinstance(got, int) and not isinstance(got, bool)
    else:
        assert isinstance(got, float)


# ---------------------------------------------------------------- signatures

P = inspect.Parameter
_EMPTY = inspect.Parameter.empty


def _params(func):
    return list(inspect.signature(func).parameters.values())


def _check_signature(func, positional, keyword_only):
    """``positional``: names; ``keyword_only``: list of (name, default or _EMPTY)."""
    params = _params(func)
    names = [p.name for p in params]
    assert names == list(positional) + [k for k, _ in keyword_only]
    for p in params[: len(positional)]:
        assert p.kind == P.POSITIONAL_OR_KEYWORD, p
        assert p.default is _EMPTY, p
    for p, (_, default) in zip(params[len(positional):], keyword_only, strict=True):
        assert p.kind == P.KEYWORD_ONLY, p
        if default is _EMPTY:
            assert p.default is _EMPTY, p
        elif default is None:
            assert p.default is None, p
        else:
            assert p.default == default, p
            assert type(p.default) is type(default), p


def test_signature_coarse_ncc_search():
    _check_signature(dtalign.coarse_ncc_search, ["edge_mask", "polyline_mask", "search_window_vu"],
                     [("min_support_fraction", 0.5)])


def test_signature_coarse_ncc_search_scored():
    _check_signature(dtalign.coarse_ncc_search_scored,
                     ["edge_mask", "polyline_mask", "search_window_vu"],
                     [("min_support_fraction", 0.5)])


def test_signature_coarse_polarity_search_scored():
    _check_signature(dtalign.coarse_polarity_search_scored,
                     ["edge_mask", "image_gradient_vu", "vertices_vu", "normals_vu",
                      "search_window_vu"],
                     [("min_support_fraction", 0.5)])


def test_signature_find_secondary_dt_minimum():
    _check_signature(dtalign.find_secondary_dt_minimum, ["image_edge_dt", "vertices_vu"],
                     [("converged_offset_vu", _EMPTY), ("search_window_vu", _EMPTY),
                      ("exclude_radius_px", _EMPTY), ("min_support_fraction", 0.5)])


def test_signature_evaluate_dt_fit_gates():
    _check_signature(dtalign.evaluate_dt_fit_gates, ["lm_result", "gate_config"],
                     [("coarse_peak_fraction", _EMPTY), ("total_vertex_count", _EMPTY),
                      ("use_polarity", _EMPTY)])


def test_signature_rotate_helpers():
    _check_signature(dtalign._rotate_vertices, ["vertices_vu", "pivot_vu", "theta"], [])
    _check_signature(dtalign._rotate_directions, ["directions_vu", "theta"], [])


def test_signature_build_polyline_mask():
    _check_signature(dtalign.build_polyline_mask, ["vertices_vu", "shape_vu"], [])


def test_signature_polarity_filter():
    _check_signature(dtalign.polarity_filter, ["vertices_vu", "normals_vu", "image_gradient_vu"],
                     [("offset_vu", (0.0, 0.0))])


def test_signature_tukey():
    _check_signature(dtalign.tukey_biweight_weights, ["residuals"], [("c", 4.685)])


def test_signature_covariance():
    _check_signature(dtalign.information_matrix_to_covariance, ["jacobian", "weights"],
                     [("rcond", 1.0e-9)])


def test_signature_sampling():
    _check_signature(dtalign.sample_dt_bilinear, ["dt", "vertices_vu"], [])
    _check_signature(dtalign.apply_translation, ["vertices_vu", "dv", "du"], [])


def test_signature_image_side():
    _check_signature(dtalign.compute_image_gradient_vu, ["image_ext"], [("sigma_px", 1.2)])
    _check_signature(dtalign.build_image_edge_dt, ["image_ext", "image_noise_sigma"],
                     [("config", None)])
    _check_signature(dtalign.compute_all_image_derivatives, ["image_ext", "image_noise_sigma"],
                     [("config", None)])


def test_signature_lm_subpixel_refine():
    _check_signature(dtalign.lm_subpixel_refine, [], [
        ("vertices_vu", _EMPTY), ("normals_vu", _EMPTY), ("sigma_normal_per_vertex_px", _EMPTY),
        ("image_edge_dt", _EMPTY), ("image_gradient_vu", None), ("initial_offset_vu", (0.0, 0.0)),
        ("initial_rotation_rad", 0.0), ("fit_rotation", False), ("pivot_vu", None),
        ("pivot_distance_px", 0.0), ("use_polarity", True), ("max_iterations", 30),
        ("damping", 1.0e-3), ("step_tolerance_px", 1.0e-3), ("tukey_c", 4.685),
        ("pinvh_rcond", 1.0e-9), ("trust_region_px", None), ("tikhonov_alpha", 0.0),
        ("final_gradient_ridge", False),
    ])


def test_signature_gradient_ridge_refine():
    _check_signature(dtalign.gradient_ridge_refine, [], [
        ("vertices_vu", _EMPTY), ("normals_vu", _EMPTY), ("sigma_normal_per_vertex_px", _EMPTY),
        ("gradient_magnitude", _EMPTY), ("initial_offset_vu", _EMPTY), ("weight_mask", None),
        ("initial_rotation_rad", 0.0), ("fit_rotation", False), ("pivot_vu", None),
        ("pivot_distance_px", 0.0), ("max_iterations", 10), ("step_tolerance_px", 1.0e-3),
        ("tukey_c", 4.685), ("half_width_px", 3.0), ("sample_step_px", 0.5),
        ("max_total_displacement_px", 1.5),
    ])


# ---------------------------------------------------------------- dataclasses

def _field_spec(cls):
    out = []
    for f in dataclasses.fields(cls):
        if f.default is not dataclasses.MISSING:
            out.append((f.name, f.default))
        elif f.default_factory is not dataclasses.MISSING:  # pragma: no cover - not expected
            out.append((f.name, f.default_factory()))
        else:
            out.append((f.name, _EMPTY))
    return out


def _assert_frozen(instance, field_name, value):
    with pytest.raises(dataclasses.FrozenInstanceError):
        setattr(instance, field_name, value)


def test_image_derivatives_config_fields():
    cls = dtalign.ImageDerivativesConfig
    assert dataclasses.is_dataclass(cls)
    assert _field_spec(cls) == [("image_gradient_sigma_px", 1.2),
                                ("edge_threshold_k_sigma", 4.0),
                                ("dt_half_width_px", 64.0)]
    cfg = cls()
    _assert_frozen(cfg, "dt_half_width_px", 3.0)
    assert cls(2.0, 3.0, 5.0) == cls(image_gradient_sigma_px=2.0, edge_threshold_k_sigma=3.0,
                                     dt_half_width_px=5.0)


LM_FIELDS = ["offset_vu", "rotation_rad", "covariance", "residuals_px", "weights", "rms_px",
             "raw_rms_px", "iterations", "converged", "inlier_count", "degenerate",
             "polarity_rejected_count"]


def _lm_kwargs(**over):
    kw = dict(offset_vu=(1.0, 2.0), rotation_rad=0.0, covariance=np.eye(2),
              residuals_px=np.zeros(3), weights=np.ones(3), rms_px=0.0, raw_rms_px=0.0,
              iterations=1, converged=True, inlier_count=3, degenerate=False)
    kw.update(over)
    return kw


def test_lm_refine_result_fields_and_defaults():
    cls = dtalign.LMRefineResult
    assert dataclasses.is_dataclass(cls)
    spec = _field_spec(cls)
    assert [n for n, _ in spec] == LM_FIELDS
    # the first eleven are required; the 12th defaults to 0
    assert all(d is _EMPTY for _, d in spec[:11])
    assert spec[11] == ("polarity_rejected_count", 0)
    r = cls(**_lm_kwargs())
    assert r.polarity_rejected_count == 0
    r7 = cls(**_lm_kwargs(), polarity_rejected_count=7)
    assert r7.polarity_rejected_count == 7
    _assert_frozen(r, "rms_px", 1.0)
    _assert_frozen(r, "polarity_rejected_count", 1)


def test_lm_refine_result_positional_order():
    cls = dtalign.LMRefineResult
    kw = _lm_kwargs()
    r = cls(*[kw[n] for n in LM_FIELDS[:11]], 5)
    assert r.offset_vu == (1.0, 2.0)
    assert r.inlier_count == 3
    assert r.degenerate is False
    assert r.polarity_rejected_count == 5


@pytest.mark.parametrize("name", ["covariance", "residuals_px", "weights"])
def test_lm_refine_result_arrays_must_be_ndarray(name):
    bad = [[1.0, 0.0], [0.0, 1.0]] if name == "covariance" else [0.0, 0.0, 0.0]
    with pytest.raises(TypeError, match=re.escape(f"LMRefineResult.{name} must be an ndarray")):
        dtalign.LMRefineResult(**_lm_kwargs(**{name: bad}))


def test_lm_refine_result_arrays_read_only():
    r = dtalign.LMRefineResult(**_lm_kwargs())
    for name in ("covariance", "residuals_px", "weights"):
        arr = getattr(r, name)
        assert isinstance(arr, np.ndarray)
        assert not arr.flags.writeable
        with pytest.raises(ValueError):
            arr[0] = 5.0


def test_ridge_refine_result_fields():
    cls = dtalign.RidgeRefineResult
    assert dataclasses.is_dataclass(cls)
    assert [n for n, _ in _field_spec(cls)] == ["offset_vu", "rotation_rad", "iterations",
                                                "converged", "applied"]
    r = cls((0.5, 0.25), 0.0, 2, True, True)
    assert r.offset_vu == (0.5, 0.25) and r.applied is True
    _assert_frozen(r, "applied", False)


def test_coarse_search_result_fields():
    cls = dtalign.CoarseSearchResult
    assert dataclasses.is_dataclass(cls)
    assert _field_spec(cls) == [("offset_vu", _EMPTY), ("score", _EMPTY)]
    r = cls((1, -2), 0.5)
    assert r.offset_vu == (1, -2) and r.score == 0.5
    assert r == cls(offset_vu=(1, -2), score=0.5)
    _assert_frozen(r, "score", 1.0)


def test_secondary_basin_fields():
    cls = dtalign.SecondaryBasin
    assert dataclasses.is_dataclass(cls)
    assert _field_spec(cls) == [("offset_vu", _EMPTY), ("distance_px", _EMPTY),
                                ("cost_px", _EMPTY), ("converged_cost_px", _EMPTY)]
    r = cls((3, 4), 5.0, 0.5, 0.25)
    assert (r.offset_vu, r.distance_px, r.cost_px, r.converged_cost_px) == ((3, 4), 5.0, 0.5, 0.25)
    _assert_frozen(r, "cost_px", 1.0)


def test_gate_config_fields():
    cls = dtalign.DTFitGateConfig
    assert dataclasses.is_dataclass(cls)
    assert _field_spec(cls) == [("lm_unconverged_confidence_cap", _EMPTY),
                                ("spurious_max_polarity_rejection_fraction", _EMPTY),
                                ("spurious_unconverged_polarity_rejection_fraction", _EMPTY),
                                ("spurious_min_coarse_peak_fraction", _EMPTY)]
    cfg = cls(0.84, 0.35, 0.10, 0.05)
    _assert_frozen(cfg, "lm_unconverged_confidence_cap", 0.5)


def test_gate_verdict_fields_and_spurious_property():
    cls = dtalign.DTFitGateVerdict
    assert dataclasses.is_dataclass(cls)
    assert [n for n, _ in _field_spec(cls)] == ["spurious_reasons", "confidence_cap",
                                                "polarity_rejection_fraction",
                                                "coarse_peak_fraction", "lm_converged"]
    v = cls(("coarse_peak_fraction",), None, 0.0, 0.01, True)
    assert v.spurious is True
    v0 = cls((), 0.84, 0.1, 0.5, False)
    assert v0.spurious is False
    _assert_frozen(v, "confidence_cap", 0.5)
    # ``spurious`` is a property, not a field
    assert isinstance(inspect.getattr_static(cls, "spurious"), property)


# ---------------------------------------------------------------- §8.6 rotation helpers

def test_rotate_vertices_zero_returns_input_object():
    verts = np.array([[1.0, 2.0], [3.0, -4.0]])
    out = dtalign._rotate_vertices(verts, (0.5, 0.5), 0.0)
    assert out is verts


def test_rotate_directions_zero_returns_input_object():
    dirs = np.array([[1.0, 0.0], [0.0, 1.0]])
    assert dtalign._rotate_directions(dirs, 0.0) is dirs


def test_rotate_vertices_formula():
    verts = np.array([[1.0, 2.0], [3.0, -4.0], [10.5, 7.25]])
    pv, pu = 2.0, -1.0
    theta = 0.3
    c, s = np.cos(theta), np.sin(theta)
    dv, du = verts[:, 0] - pv, verts[:, 1] - pu
    expected = np.stack([pv + c * dv - s * du, pu + s * dv + c * du], axis=1)
    out = np.asarray(dtalign._rotate_vertices(verts, (pv, pu), theta))
    assert out.shape == (3, 2)
    np.testing.assert_allclose(out, expected, rtol=1e-14, atol=1e-14)
    # the input is not modified
    np.testing.assert_array_equal(verts, [[1.0, 2.0], [3.0, -4.0], [10.5, 7.25]])


def test_rotate_directions_formula():
    dirs = np.array([[1.0, 0.0], [0.0, 1.0], [0.6, -0.8]])
    theta = -1.1
    c, s = np.cos(theta), np.sin(theta)
    expected = np.stack([c * dirs[:, 0] - s * dirs[:, 1], s * dirs[:, 0] + c * dirs[:, 1]], axis=1)
    out = np.asarray(dtalign._rotate_directions(dirs, theta))
    np.testing.assert_allclose(out, expected, rtol=1e-14, atol=1e-14)
