""":ref:`contract-errors`: every error text, verbatim, and the order of checks of §§1, 3, 4 and 8.

Each text is matched with ``pytest.raises(..., match=re.escape(text))`` with
its placeholders filled as an f-string would fill them. Order tests build an
input with two faults and assert which message wins.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

import dtalign

pytestmark = pytest.mark.filterwarnings("error")


def raises(exc, text):
    return pytest.raises(exc, match=re.escape(text))


# ---------------------------------------------------------------- fixtures

H, W = 6, 7
EDGE = np.zeros((H, W), dtype=bool)
EDGE[2, 3] = True
POLY = np.zeros((H, W), dtype=bool)
POLY[3, 3] = True
GRAD = np.zeros((H, W, 2))
GRAD[..., 0] = 1.0
VERTS = np.array([[2.0, 3.0], [3.0, 4.0], [2.5, 2.0]])
NORMS = np.array([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
SIGMAS = np.ones(3)
DT = np.ones((H, W))


def ncc(window, edge=EDGE, poly=POLY, **kw):
    return dtalign.coarse_ncc_search(edge, poly, window, **kw)


def ncc_scored(window, edge=EDGE, poly=POLY, **kw):
    return dtalign.coarse_ncc_search_scored(edge, poly, window, **kw)


def pol_scored(window, edge=EDGE, grad=GRAD, verts=VERTS, norms=NORMS, **kw):
    return dtalign.coarse_polarity_search_scored(edge, grad, verts, norms, window, **kw)


SEARCHES = {"coarse_ncc_search": ncc, "coarse_ncc_search_scored": ncc_scored,
            "coarse_polarity_search_scored": pol_scored}


# ---------------------------------------------------------------- search window (all coarse searches)

BAD_LENGTH_WINDOWS = [(1, 2, 3), (1,), [], [1, 2, 3], np.array([1, 2]), 5, "ab", None,
                      {0: 1, 1: 2}, range(2)]


@pytest.mark.parametrize("search", sorted(SEARCHES))
@pytest.mark.parametrize("window", BAD_LENGTH_WINDOWS, ids=repr)
def test_window_not_length_2_sequence(search, window):
    with raises(ValueError, f"search_window_vu must be a length-2 sequence of ints; got {window!r}"):
        SEARCHES[search](window)


@pytest.mark.parametrize("search", sorted(SEARCHES))
@pytest.mark.parametrize("window,index,tname", [
    ((1.0, 2), 0, "float"), ((True, 2), 0, "bool"), (("1", 2), 0, "str"),
    ((1, 2.0), 1, "float"), ((1, False), 1, "bool"), ([1, None], 1, "NoneType"),
    ((1.0, 2.0), 0, "float"),  # entry 0 is checked before entry 1
    ((-1, 2.5), 1, "float"),  # types are checked before signs
])
def test_window_entry_not_int(search, window, index, tname):
    with raises(TypeError, f"search_window_vu[{index}] must be int; got {tname}"):
        SEARCHES[search](window)


@pytest.mark.parametrize("search", sorted(SEARCHES))
@pytest.mark.parametrize("window", [(-1, 2), (2, -1), [-3, -3], [0, -1]], ids=repr)
def test_window_negative(search, window):
    with raises(ValueError, f"search_window_vu must be non-negative; got {window!r}"):
        SEARCHES[search](window)


@pytest.mark.parametrize("search", sorted(SEARCHES))
def test_window_length_checked_before_entry_types(search):
    window = (1.5, 2.5, 3.5)
    with raises(ValueError, f"search_window_vu must be a length-2 sequence of ints; got {window!r}"):
        SEARCHES[search](window)


@pytest.mark.parametrize("search", sorted(SEARCHES))
def test_window_lists_and_zero_accepted(search):
    SEARCHES[search]([0, 0])
    SEARCHES[search]((0, 2))
    SEARCHES[search]([50, 50])  # larger than the arrays: clipped, not an error


# ---------------------------------------------------------------- min_support_fraction

@pytest.mark.parametrize("search", sorted(SEARCHES))
@pytest.mark.parametrize("fraction", [-0.1, 1.5, float("nan"), float("inf"), -1e-300, 1.0000000000000002])
def test_min_support_fraction_out_of_range(search, fraction):
    with raises(ValueError, f"min_support_fraction must be in [0, 1]; got {fraction!r}"):
        SEARCHES[search]((1, 1), min_support_fraction=fraction)


@pytest.mark.parametrize("search", sorted(SEARCHES))
@pytest.mark.parametrize("fraction", [0.0, 1.0, 0.5, 0, 1])
def test_min_support_fraction_bounds_accepted(search, fraction):
    SEARCHES[search]((1, 1), min_support_fraction=fraction)


@pytest.mark.parametrize("search", sorted(SEARCHES))
def test_window_checked_before_fraction(search):
    with raises(ValueError, "search_window_vu must be non-negative; got (-1, 0)"):
        SEARCHES[search]((-1, 0), min_support_fraction=2.0)
    with raises(TypeError, "search_window_vu[0] must be int; got float"):
        SEARCHES[search]((1.0, 0), min_support_fraction=float("nan"))


# ---------------------------------------------------------------- coarse_ncc_search[_scored]

@pytest.mark.parametrize("search", ["coarse_ncc_search", "coarse_ncc_search_scored"])
def test_ncc_masks_not_2d(search):
    f = SEARCHES[search]
    e1 = np.zeros(5, dtype=bool)
    p3 = np.zeros((2, 3, 4), dtype=bool)
    with raises(ValueError, "edge_mask and polyline_mask must be 2-D; got ndims 1, 2"):
        f((1, 1), edge=e1, poly=POLY)
    with raises(ValueError, "edge_mask and polyline_mask must be 2-D; got ndims 2, 3"):
        f((1, 1), edge=EDGE, poly=p3)
    with raises(ValueError, "edge_mask and polyline_mask must be 2-D; got ndims 0, 1"):
        f((1, 1), edge=np.array(True), poly=e1)


@pytest.mark.parametrize("search", ["coarse_ncc_search", "coarse_ncc_search_scored"])
def test_ncc_shape_mismatch(search):
    p = np.zeros((H, W + 1), dtype=bool)
    with raises(ValueError, f"shape mismatch: edge_mask {(H, W)} vs polyline_mask {(H, W + 1)}"):
        SEARCHES[search]((1, 1), poly=p)


@pytest.mark.parametrize("search", ["coarse_ncc_search", "coarse_ncc_search_scored"])
def test_ncc_check_order(search):
    f = SEARCHES[search]
    # 2-D before shape
    with raises(ValueError, "edge_mask and polyline_mask must be 2-D; got ndims 2, 1"):
        f((1, 1), poly=np.zeros(4, dtype=bool))
    # shape before window
    p = np.zeros((H + 1, W), dtype=bool)
    with raises(ValueError, f"shape mismatch: edge_mask {(H, W)} vs polyline_mask {(H + 1, W)}"):
        f((1, 2, 3), poly=p)
    # 2-D before window
    with raises(ValueError, "edge_mask and polyline_mask must be 2-D; got ndims 1, 2"):
        f((1.0, 1), edge=np.zeros(3, dtype=bool))
    # shape before fraction
    with raises(ValueError, f"shape mismatch: edge_mask {(H, W)} vs polyline_mask {(H + 1, W)}"):
        f((1, 1), poly=p, min_support_fraction=5.0)


# ---------------------------------------------------------------- coarse_polarity_search_scored

def test_polarity_search_edge_not_2d():
    with raises(ValueError, "edge_mask must be 2-D; got ndim=3"):
        pol_scored((1, 1), edge=np.zeros((H, W, 1), dtype=bool))
    with raises(ValueError, "edge_mask must be 2-D; got ndim=1"):
        pol_scored((1, 1), edge=np.zeros(W, dtype=bool))


@pytest.mark.parametrize("shape", [(H, W), (H, W, 3), (H, W, 2, 1), (2,)])
def test_polarity_search_gradient_shape(shape):
    with raises(ValueError, f"image_gradient_vu must have shape (H, W, 2); got {shape}"):
        pol_scored((1, 1), grad=np.zeros(shape))


def test_polarity_search_gradient_mask_mismatch():
    g = np.zeros((H + 1, W, 2))
    with raises(ValueError, f"shape mismatch: edge_mask {(H, W)} vs image_gradient_vu {(H + 1, W)}"):
        pol_scored((1, 1), grad=g)


@pytest.mark.parametrize("shape", [(3, 3), (3,), (2, 2, 2), (2, 1)])
def test_polarity_search_vertices_shape(shape):
    with raises(ValueError, f"vertices_vu must have shape (N, 2); got {shape}"):
        pol_scored((1, 1), verts=np.zeros(shape), norms=np.zeros(shape))


@pytest.mark.parametrize("shape", [(2, 2), (3, 3), (3,)])
def test_polarity_search_normals_shape(shape):
    with raises(ValueError, f"normals_vu must match vertices_vu shape; got {shape}"):
        pol_scored((1, 1), norms=np.zeros(shape))


def test_polarity_search_check_order():
    bad_edge = np.zeros(W, dtype=bool)
    bad_grad = np.zeros((H, W, 3))
    mism_grad = np.zeros((H + 1, W, 2))
    bad_verts = np.zeros((3, 3))
    bad_norms = np.zeros((2, 2))
    # edge 2-D before gradient shape
    with raises(ValueError, "edge_mask must be 2-D; got ndim=1"):
        pol_scored((1, 1), edge=bad_edge, grad=bad_grad)
    # gradient shape before the (H, W) comparison (a (H, W, 3) gradient has matching H, W)
    with raises(ValueError, f"image_gradient_vu must have shape (H, W, 2); got {(H + 1, W, 3)}"):
        pol_scored((1, 1), grad=np.zeros((H + 1, W, 3)))
    # (H, W) comparison before vertices
    with raises(ValueError, f"shape mismatch: edge_mask {(H, W)} vs image_gradient_vu {(H + 1, W)}"):
        pol_scored((1, 1), grad=mism_grad, verts=bad_verts)
    # vertices before normals
    with raises(ValueError, "vertices_vu must have shape (N, 2); got (3, 3)"):
        pol_scored((1, 1), verts=bad_verts, norms=bad_norms)
    # normals before window
    with raises(ValueError, "normals_vu must match vertices_vu shape; got (2, 2)"):
        pol_scored((-1, 1), norms=bad_norms)
    # window before fraction
    with raises(ValueError, "search_window_vu must be a length-2 sequence of ints; got (1,)"):
        pol_scored((1,), min_support_fraction=-1.0)
    # edge 2-D before everything else
    with raises(ValueError, "edge_mask must be 2-D; got ndim=1"):
        pol_scored((1.0,), edge=bad_edge, grad=bad_grad, verts=bad_verts, norms=bad_norms,
                   min_support_fraction=9.0)


def test_polarity_search_empty_vertices_checked_window():
    # the window check still runs for N == 0
    empty = np.zeros((0, 2))
    with raises(ValueError, "search_window_vu must be non-negative; got (0, -1)"):
        pol_scored((0, -1), verts=empty, norms=empty)


# ---------------------------------------------------------------- polarity_filter

@pytest.mark.parametrize("shape", [(3, 3), (3,), (1, 2, 2)])
def test_polarity_filter_vertices_shape(shape):
    with raises(ValueError, f"vertices_vu must have shape (N, 2); got {shape}"):
        dtalign.polarity_filter(np.zeros(shape), np.zeros(shape), GRAD)


def test_polarity_filter_normals_shape():
    with raises(ValueError, "normals_vu must match vertices_vu shape; got (2, 2)"):
        dtalign.polarity_filter(VERTS, np.zeros((2, 2)), GRAD)


@pytest.mark.parametrize("shape", [(H, W), (H, W, 3), (H, W, 2, 1)])
def test_polarity_filter_gradient_shape(shape):
    with raises(ValueError, f"image_gradient_vu must have shape (H, W, 2); got {shape}"):
        dtalign.polarity_filter(VERTS, NORMS, np.zeros(shape))


def test_polarity_filter_check_order():
    with raises(ValueError, "vertices_vu must have shape (N, 2); got (3,)"):
        dtalign.polarity_filter(np.zeros(3), np.zeros((2, 2)), np.zeros((H, W)))
    with raises(ValueError, "normals_vu must match vertices_vu shape; got (4, 2)"):
        dtalign.polarity_filter(VERTS, np.zeros((4, 2)), np.zeros((H, W)))


# ---------------------------------------------------------------- lm_subpixel_refine

def lm(**over):
    kw = dict(vertices_vu=VERTS, normals_vu=NORMS, sigma_normal_per_vertex_px=SIGMAS,
              image_edge_dt=DT, image_gradient_vu=GRAD)
    kw.update(over)
    return dtalign.lm_subpixel_refine(**kw)


def ridge(**over):
    kw = dict(vertices_vu=VERTS, normals_vu=NORMS, sigma_normal_per_vertex_px=SIGMAS,
              gradient_magnitude=DT, initial_offset_vu=(0.0, 0.0))
    kw.update(over)
    return dtalign.gradient_ridge_refine(**kw)


FITTERS = {"lm_subpixel_refine": lm, "gradient_ridge_refine": ridge}


@pytest.mark.parametrize("fitter", sorted(FITTERS))
@pytest.mark.parametrize("shape", [(0, 2), (3, 3), (3,), (2, 2, 2)])
def test_fit_vertices_shape(fitter, shape):
    with raises(ValueError, f"vertices_vu must have shape (N, 2) with N > 0; got {shape}"):
        FITTERS[fitter](vertices_vu=np.zeros(shape), normals_vu=np.zeros(shape))


@pytest.mark.parametrize("fitter", sorted(FITTERS))
@pytest.mark.parametrize("shape", [(2, 2), (3,), (3, 3)])
def test_fit_normals_shape(fitter, shape):
    with raises(ValueError, f"normals_vu must match vertices_vu shape; got {shape}"):
        FITTERS[fitter](normals_vu=np.zeros(shape))


@pytest.mark.parametrize("fitter", sorted(FITTERS))
@pytest.mark.parametrize("shape", [(2,), (4,), (3, 1), ()])
def test_fit_sigma_shape(fitter, shape):
    text = ("sigma_normal_per_vertex_px must be a 1-D vector matching vertices_vu; "
            f"got {shape}")
    with raises(ValueError, text):
        FITTERS[fitter](sigma_normal_per_vertex_px=np.ones(shape))


@pytest.mark.parametrize("fitter", sorted(FITTERS))
@pytest.mark.parametrize("bad", [0.0, -1.0, math.nan, math.inf, -math.inf])
def test_fit_sigma_entries(fitter, bad):
    s = np.array([1.0, bad, 1.0])
    with raises(ValueError, "sigma_normal_per_vertex_px entries must be finite and > 0"):
        FITTERS[fitter](sigma_normal_per_vertex_px=s)


@pytest.mark.parametrize("fitter", sorted(FITTERS))
@pytest.mark.parametrize("dist", [0.0, -2.0])
def test_fit_rotation_requires_pivot_distance(fitter, dist):
    with raises(ValueError,
                "fit_rotation=True requires pivot_distance_px > 0 for the convergence test"):
        FITTERS[fitter](fit_rotation=True, pivot_distance_px=dist)


@pytest.mark.parametrize("fitter", sorted(FITTERS))
def test_fit_rotation_default_distance_refused(fitter):
    with raises(ValueError,
                "fit_rotation=True requires pivot_distance_px > 0 for the convergence test"):
        FITTERS[fitter](fit_rotation=True)


@pytest.mark.parametrize("shape", [(H,), (H, W, 1), ()])
def test_lm_dt_not_2d(shape):
    with raises(ValueError, f"image_edge_dt must be 2-D; got ndim={len(shape)}"):
        lm(image_edge_dt=np.ones(shape))


def test_lm_final_ridge_requires_gradient():
    with raises(ValueError, "final_gradient_ridge=True requires image_gradient_vu"):
        lm(image_gradient_vu=None, final_gradient_ridge=True, use_polarity=False)


def test_lm_use_polarity_requires_gradient():
    with raises(ValueError, "use_polarity=True requires image_gradient_vu"):
        lm(image_gradient_vu=None)
    with raises(ValueError, "use_polarity=True requires image_gradient_vu"):
        lm(image_gradient_vu=None, use_polarity=True)


def test_lm_no_gradient_fine_without_polarity():
    r = lm(image_gradient_vu=None, use_polarity=False)
    assert isinstance(r, dtalign.LMRefineResult)


def test_lm_check_order():
    bad_v = np.zeros((3, 3))
    bad_n = np.zeros((2, 2))
    bad_s = np.ones(2)
    nan_s = np.array([1.0, math.nan, 1.0])
    bad_dt = np.ones(5)
    # vertices before normals
    with raises(ValueError, "vertices_vu must have shape (N, 2) with N > 0; got (3, 3)"):
        lm(vertices_vu=bad_v, normals_vu=bad_n)
    # normals before sigma shape
    with raises(ValueError, "normals_vu must match vertices_vu shape; got (2, 2)"):
        lm(normals_vu=bad_n, sigma_normal_per_vertex_px=bad_s)
    # sigma shape before (nothing else to check for entries: shape wins over dt)
    with raises(ValueError, "sigma_normal_per_vertex_px must be a 1-D vector matching "
                            "vertices_vu; got (2,)"):
        lm(sigma_normal_per_vertex_px=bad_s, image_edge_dt=bad_dt)
    # sigma entries before dt
    with raises(ValueError, "sigma_normal_per_vertex_px entries must be finite and > 0"):
        lm(sigma_normal_per_vertex_px=nan_s, image_edge_dt=bad_dt)
    # dt before rotation
    with raises(ValueError, "image_edge_dt must be 2-D; got ndim=1"):
        lm(image_edge_dt=bad_dt, fit_rotation=True, pivot_distance_px=0.0)
    # rotation before final ridge / polarity gradient checks
    with raises(ValueError,
                "fit_rotation=True requires pivot_distance_px > 0 for the convergence test"):
        lm(fit_rotation=True, image_gradient_vu=None, final_gradient_ridge=True)
    # final ridge before polarity
    with raises(ValueError, "final_gradient_ridge=True requires image_gradient_vu"):
        lm(image_gradient_vu=None, final_gradient_ridge=True, use_polarity=True)
    # the first check wins over all the others
    with raises(ValueError, "vertices_vu must have shape (N, 2) with N > 0; got (0, 2)"):
        lm(vertices_vu=np.zeros((0, 2)), normals_vu=bad_n, sigma_normal_per_vertex_px=nan_s,
           image_edge_dt=bad_dt, fit_rotation=True, image_gradient_vu=None,
           final_gradient_ridge=True)


@pytest.mark.parametrize("shape", [(H,), (H, W, 2), ()])
def test_ridge_gradient_magnitude_not_2d(shape):
    with raises(ValueError, f"gradient_magnitude must be 2-D; got ndim={len(shape)}"):
        ridge(gradient_magnitude=np.ones(shape))


def test_ridge_check_order():
    bad_gm = np.ones(4)
    with raises(ValueError, "vertices_vu must have shape (N, 2) with N > 0; got (3,)"):
        ridge(vertices_vu=np.zeros(3), normals_vu=np.zeros((2, 2)), gradient_magnitude=bad_gm)
    with raises(ValueError, "normals_vu must match vertices_vu shape; got (2, 2)"):
        ridge(normals_vu=np.zeros((2, 2)), sigma_normal_per_vertex_px=np.ones(2),
              gradient_magnitude=bad_gm)
    with raises(ValueError, "sigma_normal_per_vertex_px must be a 1-D vector matching "
                            "vertices_vu; got (5,)"):
        ridge(sigma_normal_per_vertex_px=np.ones(5), gradient_magnitude=bad_gm)
    with raises(ValueError, "sigma_normal_per_vertex_px entries must be finite and > 0"):
        ridge(sigma_normal_per_vertex_px=np.array([1.0, 0.0, 1.0]), gradient_magnitude=bad_gm)


# ---------------------------------------------------------------- tukey

@pytest.mark.parametrize("c", [0.0, -1.0, math.nan, math.inf, -math.inf])
def test_tukey_c_invalid(c):
    with raises(ValueError, f"c must be a positive finite number; got {c!r}"):
        dtalign.tukey_biweight_weights(np.zeros(3), c=c)


@pytest.mark.parametrize("shape", [(2, 2), (), (1, 3, 1)])
def test_tukey_residuals_not_1d(shape):
    with raises(ValueError, f"residuals must be 1-D; got ndim={len(shape)}"):
        dtalign.tukey_biweight_weights(np.zeros(shape))


def test_tukey_check_order():
    with raises(ValueError, "c must be a positive finite number; got -2.0"):
        dtalign.tukey_biweight_weights(np.zeros((2, 2)), c=-2.0)


# ---------------------------------------------------------------- covariance

@pytest.mark.parametrize("shape", [(3,), (2, 2, 2), ()])
def test_covariance_jacobian_not_2d(shape):
    with raises(ValueError, f"jacobian must be 2-D; got ndim={len(shape)}"):
        dtalign.information_matrix_to_covariance(np.zeros(shape), np.ones(3))


@pytest.mark.parametrize("wshape", [(2,), (4,), (3, 1), ()])
def test_covariance_weights_shape(wshape):
    j = np.ones((3, 2))
    w = np.ones(wshape)
    text = ("weights must be a 1-D vector matching the Jacobian rows; "
            f"got weights {w.shape}, jacobian {j.shape}")
    with raises(ValueError, text):
        dtalign.information_matrix_to_covariance(j, w)


def test_covariance_negative_weight():
    with raises(ValueError, "weights must be non-negative"):
        dtalign.information_matrix_to_covariance(np.ones((3, 2)), np.array([1.0, -1e-300, 0.0]))


def test_covariance_check_order():
    with raises(ValueError, "jacobian must be 2-D; got ndim=1"):
        dtalign.information_matrix_to_covariance(np.ones(3), np.ones((2, 2)))
    with raises(ValueError, "weights must be a 1-D vector matching the Jacobian rows; "
                            "got weights (2,), jacobian (3, 2)"):
        dtalign.information_matrix_to_covariance(np.ones((3, 2)), np.array([-1.0, 1.0]))


# ---------------------------------------------------------------- sampling

@pytest.mark.parametrize("shape", [(4,), (2, 2, 2), ()])
def test_sample_dt_not_2d(shape):
    with raises(ValueError, f"dt must be 2-D; got ndim={len(shape)}"):
        dtalign.sample_dt_bilinear(np.ones(shape), VERTS)


@pytest.mark.parametrize("shape", [(3, 3), (3,), (1, 2, 2)])
def test_sample_dt_vertices_shape(shape):
    with raises(ValueError, f"vertices_vu must have shape (N, 2); got {shape}"):
        dtalign.sample_dt_bilinear(DT, np.zeros(shape))


def test_sample_dt_check_order():
    with raises(ValueError, "dt must be 2-D; got ndim=1"):
        dtalign.sample_dt_bilinear(np.ones(4), np.zeros(3))


@pytest.mark.parametrize("shape", [(3, 3), (3,), (1, 2, 2)])
def test_apply_translation_vertices_shape(shape):
    with raises(ValueError, f"vertices_vu must have shape (N, 2); got {shape}"):
        dtalign.apply_translation(np.zeros(shape), 1.0, 2.0)


# ---------------------------------------------------------------- image side

IMAGE_FUNCS = {
    "compute_image_gradient_vu": lambda img: dtalign.compute_image_gradient_vu(img),
    "build_image_edge_dt": lambda img: dtalign.build_image_edge_dt(img, 1.0),
    "compute_all_image_derivatives": lambda img: dtalign.compute_all_image_derivatives(img, 1.0),
}

FINITE_TEXT = ("image_ext must contain only finite values; NaN or +/-inf would propagate "
               "through gaussian_filter / sobel and poison every derivative downstream")


@pytest.mark.parametrize("func", sorted(IMAGE_FUNCS))
@pytest.mark.parametrize("shape", [(8,), (4, 4, 3), ()])
def test_image_not_2d(func, shape):
    with raises(TypeError, f"image_ext must be 2-D; got ndim={len(shape)}"):
        IMAGE_FUNCS[func](np.zeros(shape))


@pytest.mark.parametrize("func", sorted(IMAGE_FUNCS))
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_image_not_finite(func, bad):
    img = np.zeros((8, 8))
    img[3, 4] = bad
    with raises(ValueError, FINITE_TEXT):
        IMAGE_FUNCS[func](img)


@pytest.mark.parametrize("func", sorted(IMAGE_FUNCS))
def test_image_ndim_checked_before_finite(func):
    img = np.full((4, 4, 2), math.nan)
    with raises(TypeError, "image_ext must be 2-D; got ndim=3"):
        IMAGE_FUNCS[func](img)


@pytest.mark.parametrize("sigma", [0.0, -1.2, math.nan, math.inf])
def test_gradient_sigma_invalid(sigma):
    with raises(ValueError, f"sigma_px must be a finite positive number; got {sigma!r}"):
        dtalign.compute_image_gradient_vu(np.zeros((8, 8)), sigma_px=sigma)


@pytest.mark.parametrize("func", ["build_image_edge_dt", "compute_all_image_derivatives"])
@pytest.mark.parametrize("noise", [-1.0, math.nan, math.inf, -math.inf, -1e-300])
def test_noise_sigma_invalid(func, noise):
    f = getattr(dtalign, func)
    with raises(ValueError, f"image_noise_sigma must be finite and >= 0; got {noise!r}"):
        f(np.zeros((8, 8)), noise)


@pytest.mark.parametrize("func", ["build_image_edge_dt", "compute_all_image_derivatives"])
def test_noise_sigma_zero_accepted(func):
    getattr(dtalign, func)(np.zeros((8, 8)), 0.0)


@pytest.mark.parametrize("field", ["image_gradient_sigma_px", "edge_threshold_k_sigma",
                                   "dt_half_width_px"])
@pytest.mark.parametrize("value", [0.0, -1.0, math.nan, math.inf])
def test_image_config_field_invalid(field, value):
    with raises(ValueError, f"{field} must be a finite positive number; got {value!r}"):
        dtalign.ImageDerivativesConfig(**{field: value})


# ---------------------------------------------------------------- DTFitGateConfig

GATE_FIELDS = ["lm_unconverged_confidence_cap", "spurious_max_polarity_rejection_fraction",
               "spurious_unconverged_polarity_rejection_fraction",
               "spurious_min_coarse_peak_fraction"]


@pytest.mark.parametrize("index", range(4))
@pytest.mark.parametrize("value", [1.5, -0.1, math.nan, math.inf, -math.inf, 2, np.float32(1.25),
                                   "1.5"], ids=repr)
def test_gate_config_field_invalid(index, value):
    values = [0.84, 0.35, 0.10, 0.05]
    values[index] = value
    text = f"DTFitGateConfig.{GATE_FIELDS[index]} must be in [0, 1]; got {float(value)!r}"
    with raises(ValueError, text):
        dtalign.DTFitGateConfig(*values)


def test_gate_config_validation_in_field_order():
    with raises(ValueError, f"DTFitGateConfig.{GATE_FIELDS[1]} must be in [0, 1]; got 3.0"):
        dtalign.DTFitGateConfig(0.5, 3, -1.0, math.nan)
    with raises(ValueError, f"DTFitGateConfig.{GATE_FIELDS[2]} must be in [0, 1]; got -1.0"):
        dtalign.DTFitGateConfig(0.5, 0.5, -1, math.nan)
    with raises(ValueError, f"DTFitGateConfig.{GATE_FIELDS[0]} must be in [0, 1]; got nan"):
        dtalign.DTFitGateConfig(math.nan, 3, -1.0, math.nan)


def test_gate_from_tuning_validates():
    tuning = dict(zip(GATE_FIELDS, [0.84, 0.35, "1.25", 0.05], strict=True))
    with raises(ValueError, f"DTFitGateConfig.{GATE_FIELDS[2]} must be in [0, 1]; got 1.25"):
        dtalign.DTFitGateConfig.from_tuning(tuning)


# ---------------------------------------------------------------- §1: refusals beyond the reference
# (no §9 text: the message must name the argument)

NAN = math.nan


@pytest.mark.parametrize("arg,value", [
    ("vertices_vu", np.array([[2.0, 3.0], [NAN, 4.0], [2.5, 2.0]])),
    ("vertices_vu", np.array([[2.0, 3.0], [3.0, math.inf], [2.5, 2.0]])),
    ("normals_vu", np.array([[1.0, 0.0], [NAN, 0.0], [0.0, 1.0]])),
    ("image_edge_dt", np.full((H, W), NAN)),
    ("image_edge_dt", np.where(np.eye(H, W) > 0, math.inf, 1.0)),
    ("image_gradient_vu", np.where(GRAD == 1.0, NAN, 0.0)),
    ("initial_offset_vu", (NAN, 0.0)),
    ("initial_offset_vu", (0.0, math.inf)),
    ("initial_offset_vu", (0.0, 0.0, 0.0)),
    ("initial_offset_vu", (1.0,)),
    ("initial_rotation_rad", NAN),
    ("pivot_vu", (NAN, 1.0)),
    ("pivot_vu", (1.0, 2.0, 3.0)),
    ("trust_region_px", NAN),
    ("trust_region_px", -1.0),
    ("tikhonov_alpha", NAN),
    ("tikhonov_alpha", -0.5),
    ("damping", NAN),
    ("damping", -1e-3),
    ("step_tolerance_px", NAN),
    ("step_tolerance_px", -1e-3),
    ("max_iterations", -1),
], ids=lambda x: x if isinstance(x, str) else None)
def test_lm_refuses_beyond_reference(arg, value):
    with pytest.raises(ValueError, match=re.escape(arg)):
        lm(**{arg: value})


@pytest.mark.parametrize("arg,value", [
    ("vertices_vu", np.array([[2.0, 3.0], [NAN, 4.0], [2.5, 2.0]])),
    ("normals_vu", np.array([[1.0, 0.0], [math.inf, 0.0], [0.0, 1.0]])),
    ("gradient_magnitude", np.full((H, W), NAN)),
    ("initial_offset_vu", (NAN, 0.0)),
    ("initial_offset_vu", (0.0, 0.0, 1.0)),
    ("initial_rotation_rad", math.inf),
    ("pivot_vu", (0.0, NAN)),
    ("sample_step_px", 0.0),
    ("sample_step_px", -0.5),
    ("half_width_px", 0.0),
    ("half_width_px", -3.0),
    ("step_tolerance_px", NAN),
    ("max_iterations", -2),
], ids=lambda x: x if isinstance(x, str) else None)
def test_ridge_refuses_beyond_reference(arg, value):
    with pytest.raises(ValueError, match=re.escape(arg)):
        ridge(**{arg: value})


def test_polarity_filter_refuses_non_finite():
    with pytest.raises(ValueError, match="vertices_vu"):
        dtalign.polarity_filter(np.array([[NAN, 1.0]]), np.array([[1.0, 0.0]]), GRAD)
    with pytest.raises(ValueError, match="normals_vu"):
        dtalign.polarity_filter(np.array([[1.0, 1.0]]), np.array([[NAN, 0.0]]), GRAD)
    with pytest.raises(ValueError, match="offset_vu"):
        dtalign.polarity_filter(VERTS, NORMS, GRAD, offset_vu=(NAN, 0.0))
    with pytest.raises(ValueError, match="offset_vu"):
        dtalign.polarity_filter(VERTS, NORMS, GRAD, offset_vu=(0.0, 1.0, 2.0))


def test_sample_dt_refuses_non_finite():
    with pytest.raises(ValueError, match="vertices_vu"):
        dtalign.sample_dt_bilinear(DT, np.array([[NAN, 1.0]]))
    with pytest.raises(ValueError, match="dt"):
        dtalign.sample_dt_bilinear(np.full((H, W), NAN), VERTS)


def test_polarity_search_refuses_non_finite_vertices():
    with pytest.raises(ValueError, match="vertices_vu"):
        pol_scored((1, 1), verts=np.array([[NAN, 1.0], [1.0, 1.0], [2.0, 2.0]]))


@pytest.mark.parametrize("func", sorted(IMAGE_FUNCS))
@pytest.mark.parametrize("shape", [(0, 5), (4, 0), (0, 0)])
def test_empty_image_refused(func, shape):
    with pytest.raises(ValueError, match="image_ext"):
        IMAGE_FUNCS[func](np.zeros(shape))
