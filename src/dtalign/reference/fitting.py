"""Plain NumPy fitting: the executable specification of the contract's fitting rules
(:ref:`contract-numerics`, :ref:`contract-lm`, :ref:`contract-ridge`).

This module is written to be read next to the contract, one function per rule.
It is what the compiled path is tested against and benchmarked against, so
it stays vectorised NumPy of the kind the navigation techniques run today:
no Numba, no cleverness, no shortcuts that change a floating-point result.
Argument checks are the package's shared ones, so both paths refuse the
same inputs with the same messages.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.linalg

from ..api import checks as check
from ..api.checks import (
    FloatArray,
    check_basin_inputs,
    check_coarse_inputs,
    check_covariance_inputs,
    check_lm_inputs,
    check_polarity_search_inputs,
    check_ridge_inputs,
    no_information_covariance,
    tukey_c_value,
)
from ..api.constants import (
    DEFAULT_COARSE_MIN_SUPPORT_FRACTION,
    DEFAULT_LM_DAMPING,
    DEFAULT_LM_MAX_ITERATIONS,
    DEFAULT_LM_STEP_TOLERANCE,
    DEFAULT_PINVH_RCOND,
    DEFAULT_RIDGE_HALF_WIDTH_PX,
    DEFAULT_RIDGE_MAX_ITERATIONS,
    DEFAULT_RIDGE_MAX_TOTAL_DISPLACEMENT_PX,
    DEFAULT_RIDGE_SAMPLE_STEP_PX,
    DEFAULT_TUKEY_C,
    JACOBIAN_ROTATION_EPS_RAD,
    JACOBIAN_TRANSLATION_EPS_PX,
    LM_DAMPING_MAX,
    LM_DAMPING_MIN,
    POLARITY_PENALTY_RESIDUAL,
    RIDGE_CURVATURE_EPS,
)
from ..api.results import CoarseSearchResult, LMRefineResult, RidgeRefineResult, SecondaryBasin

# --------------------------------------------------------------------------
# Sampling and pose (:ref:`contract-numerics`: bilinear sampler, pose transform)
# --------------------------------------------------------------------------


def sample_dt_bilinear(dt: Any, vertices_vu: Any) -> FloatArray:
    """Bilinear sample of ``dt`` at ``vertices_vu``, clamped to the image."""
    dt = check.image2d(dt, "dt")
    pts = check.vertices(vertices_vu, "vertices_vu")
    return _sample(dt, pts)


def _sample(dt: FloatArray, pts: FloatArray) -> FloatArray:
    h, w = dt.shape
    v = np.clip(pts[:, 0], 0.0, h - 1)
    u = np.clip(pts[:, 1], 0.0, w - 1)
    v0 = np.floor(v).astype(np.int64)
    u0 = np.floor(u).astype(np.int64)
    v1 = np.minimum(v0 + 1, h - 1)
    u1 = np.minimum(u0 + 1, w - 1)
    fv = v - v0
    fu = u - u0
    a = dt[v0, u0]
    b = dt[v0, u1]
    c = dt[v1, u0]
    d = dt[v1, u1]
    return a * (1 - fv) * (1 - fu) + b * (1 - fv) * fu + c * fv * (1 - fu) + d * fv * fu


def apply_translation(vertices_vu: Any, dv: float, du: float) -> FloatArray:
    """A shifted copy of the vertices."""
    pts = check.vertices(vertices_vu, "vertices_vu")
    dv = check.finite_real(dv, "dv")
    du = check.finite_real(du, "du")
    out = pts.copy()
    out[:, 0] += dv
    out[:, 1] += du
    return out


def _transform(pts: FloatArray, pose: FloatArray, pivot: tuple[float, float]) -> FloatArray:
    """Rotate about the pivot by ``pose[2]`` (if any), then translate."""
    theta = pose[2]
    if theta == 0.0:
        v = pts[:, 0]
        u = pts[:, 1]
    else:
        pv, pu = pivot
        c = np.cos(theta)
        s = np.sin(theta)
        v = pv + c * (pts[:, 0] - pv) - s * (pts[:, 1] - pu)
        u = pu + s * (pts[:, 0] - pv) + c * (pts[:, 1] - pu)
    return np.stack([v + pose[0], u + pose[1]], axis=1)


def _rotate_normals(normals: FloatArray, theta: float) -> FloatArray:
    if theta == 0.0:
        return normals
    c = np.cos(theta)
    s = np.sin(theta)
    return np.stack(
        [c * normals[:, 0] - s * normals[:, 1], s * normals[:, 0] + c * normals[:, 1]],
        axis=1,
    )


def _with_rotation(pose: FloatArray, theta: float) -> FloatArray:
    out = pose.copy()
    out[2] = theta
    return out


def _residuals_and_jacobian(
    dt: FloatArray, pts: FloatArray, pose: FloatArray, pivot: tuple[float, float], fit_rotation: bool
) -> tuple[FloatArray, FloatArray]:
    pos = _transform(pts, pose, pivot)
    r = _sample(dt, pos)
    eps = JACOBIAN_TRANSLATION_EPS_PX
    ev = np.array([eps, 0.0])
    eu = np.array([0.0, eps])
    cols = [
        (_sample(dt, pos + ev) - _sample(dt, pos - ev)) / (2 * eps),
        (_sample(dt, pos + eu) - _sample(dt, pos - eu)) / (2 * eps),
    ]
    if fit_rotation:
        h = JACOBIAN_ROTATION_EPS_RAD
        plus = _sample(dt, _transform(pts, _with_rotation(pose, pose[2] + h), pivot))
        minus = _sample(dt, _transform(pts, _with_rotation(pose, pose[2] - h), pivot))
        cols.append((plus - minus) / (2 * h))
    return r, np.stack(cols, axis=1)


def _step_norm(step: FloatArray, pivot_distance_px: float) -> float:
    if step.shape[0] == 2:
        return float(np.hypot(step[0], step[1]))
    return float(np.sqrt(step[0] ** 2 + step[1] ** 2 + (step[2] * pivot_distance_px) ** 2))


def _solve_normal_equations(matrix: FloatArray, rhs: FloatArray, rcond: float) -> FloatArray:
    """``-solve(matrix, rhs)``, the pseudoinverse when the solve is singular."""
    try:
        step = -np.linalg.solve(matrix, rhs)
    except np.linalg.LinAlgError:
        step = -(scipy.linalg.pinvh(matrix, rtol=rcond) @ rhs)
    return np.asarray(step, dtype=np.float64)


# --------------------------------------------------------------------------
# Coarse search (:ref:`contract-numerics`: polyline mask, coarse search)
# --------------------------------------------------------------------------


def build_polyline_mask(vertices_vu: Any, shape_vu: Any) -> np.ndarray:
    """Rasterise vertices (round half to even) into a boolean mask."""
    pts = check.vertices(vertices_vu, "vertices_vu")
    h, w = check.shape2(shape_vu)
    mask = np.zeros((h, w), dtype=bool)
    iv = np.rint(pts[:, 0])
    iu = np.rint(pts[:, 1])
    keep = (iv >= 0) & (iv < h) & (iu >= 0) & (iu < w)
    mask[iv[keep].astype(np.int64), iu[keep].astype(np.int64)] = True
    return mask


def coarse_ncc_search(
    edge_mask: Any,
    polyline_mask: Any,
    search_window_vu: Any,
    *,
    min_support_fraction: float = DEFAULT_COARSE_MIN_SUPPORT_FRACTION,
) -> tuple[int, int]:
    """Integer shift maximising the per-vertex edge match fraction (:ref:`contract-changes`)."""
    return coarse_ncc_search_scored(
        edge_mask, polyline_mask, search_window_vu, min_support_fraction=min_support_fraction
    ).offset_vu


def _shift_key(dv: int, du: int) -> tuple[int, int, int, int]:
    """The tie order of equal scores (:ref:`contract-numerics`)."""
    return (abs(dv) + abs(du), abs(dv), dv, du)


def coarse_ncc_search_scored(
    edge_mask: Any,
    polyline_mask: Any,
    search_window_vu: Any,
    *,
    min_support_fraction: float = DEFAULT_COARSE_MIN_SUPPORT_FRACTION,
) -> CoarseSearchResult:
    """The best integer shift and its score (:ref:`contract-coarse-scored`)."""
    edge, poly, mv, mu, fraction = check_coarse_inputs(
        edge_mask, polyline_mask, search_window_vu, min_support_fraction
    )
    pv, pu = np.nonzero(poly)
    if pv.size == 0:
        return CoarseSearchResult((0, 0), 0.0)
    values = edge.astype(np.float64)  # a bool mask sums to a count
    h, w = values.shape
    min_support = fraction * pv.size
    best = -1.0
    best_offset = (0, 0)
    for dv in range(-mv, mv + 1):
        for du in range(-mu, mu + 1):
            sv = pv + dv
            su = pu + du
            inside = (sv >= 0) & (sv < h) & (su >= 0) & (su < w)
            n = int(np.count_nonzero(inside))
            if n == 0 or n < min_support:
                continue
            score = float(values[sv[inside], su[inside]].sum() / n)
            if score > best or (score == best and _shift_key(dv, du) < _shift_key(*best_offset)):
                best = score
                best_offset = (dv, du)
    return CoarseSearchResult(best_offset, max(best, 0.0))


def coarse_polarity_search_scored(
    edge_mask: Any,
    image_gradient_vu: Any,
    vertices_vu: Any,
    normals_vu: Any,
    search_window_vu: Any,
    *,
    min_support_fraction: float = DEFAULT_COARSE_MIN_SUPPORT_FRACTION,
) -> CoarseSearchResult:
    """Coarse search weighted by normal/gradient agreement (:ref:`contract-polarity-search`)."""
    a = check_polarity_search_inputs(
        edge_mask, image_gradient_vu, vertices_vu, normals_vu, search_window_vu,
        min_support_fraction,
    )
    edge, grad, pts, nrm = a.edge, a.gradient, a.vertices, a.normals
    n_vertices = pts.shape[0]
    if n_vertices == 0:
        return CoarseSearchResult((0, 0), 0.0)
    h, w = edge.shape
    base_v = np.rint(pts[:, 0])
    base_u = np.rint(pts[:, 1])
    norm = np.hypot(nrm[:, 0], nrm[:, 1])
    norm = np.where(norm == 0.0, 1.0, norm)  # a zero normal stays zero: it never matches
    nv_hat = nrm[:, 0] / norm
    nu_hat = nrm[:, 1] / norm
    min_support = a.fraction * n_vertices
    best = -1.0
    best_offset = (0, 0)
    for dv in range(-a.mv, a.mv + 1):
        for du in range(-a.mu, a.mu + 1):
            sv = base_v + dv
            su = base_u + du
            inside = (sv >= 0) & (sv < h) & (su >= 0) & (su < w)
            n = int(np.count_nonzero(inside))
            if n == 0 or n < min_support:
                continue
            iv = sv[inside].astype(np.int64)
            iu = su[inside].astype(np.int64)
            g = grad[iv, iu]
            s = np.hypot(g[:, 0], g[:, 1])
            s = np.where(s == 0.0, 1.0, s)
            with np.errstate(invalid="ignore", over="ignore"):  # a NaN score never wins
                cos = (nv_hat[inside] * g[:, 0] + nu_hat[inside] * g[:, 1]) / s
            weights = np.where(edge[iv, iu], np.maximum(cos, 0.0), 0.0)
            score = float(weights.sum() / n)
            if score > best or (score == best and _shift_key(dv, du) < _shift_key(*best_offset)):
                best = score
                best_offset = (dv, du)
    return CoarseSearchResult(best_offset, max(best, 0.0))


def _basin_cost(dt: FloatArray, pts: FloatArray, ov: float, ou: float, min_support: float) -> float | None:
    """Mean DT sample of the in-bounds shifted vertices; None when undefined."""
    h, w = dt.shape
    shifted = pts + np.array([ov, ou])
    inside = (
        (shifted[:, 0] >= 0) & (shifted[:, 0] <= h - 1)
        & (shifted[:, 1] >= 0) & (shifted[:, 1] <= w - 1)
    )
    k = int(np.count_nonzero(inside))
    if k == 0 or k < min_support:
        return None
    return float(_sample(dt, shifted[inside]).mean())


def find_secondary_dt_minimum(
    image_edge_dt: Any,
    vertices_vu: Any,
    *,
    converged_offset_vu: Any,
    search_window_vu: Any,
    exclude_radius_px: float,
    min_support_fraction: float = DEFAULT_COARSE_MIN_SUPPORT_FRACTION,
) -> SecondaryBasin | None:
    """The best integer shift outside the converged basin (:ref:`contract-basin`)."""
    a = check_basin_inputs(
        image_edge_dt, vertices_vu, converged_offset_vu, search_window_vu, exclude_radius_px,
        min_support_fraction,
    )
    pts = a.vertices
    if pts.shape[0] == 0:
        return None
    min_support = a.fraction * pts.shape[0]
    cdv, cdu = a.converged
    converged_cost = _basin_cost(a.dt, pts, cdv, cdu, min_support)
    if converged_cost is None:
        return None
    best: tuple[float, float, int, int] | None = None
    for dv in range(-a.mv, a.mv + 1):
        for du in range(-a.mu, a.mu + 1):
            distance = float(np.hypot(dv - cdv, du - cdu))
            if distance <= a.exclude_radius:
                continue
            cost = _basin_cost(a.dt, pts, dv, du, min_support)
            if cost is None:
                continue
            if best is None or (cost, distance) < (best[0], best[1]):
                best = (cost, distance, dv, du)
    if best is None:
        return None
    return SecondaryBasin((best[2], best[3]), best[1], best[0], converged_cost)


# --------------------------------------------------------------------------
# Polarity, Tukey, covariance (:ref:`contract-numerics`)
# --------------------------------------------------------------------------


def polarity_filter(
    vertices_vu: Any, normals_vu: Any, image_gradient_vu: Any, *, offset_vu: Any = (0.0, 0.0)
) -> np.ndarray:
    """Accept a vertex iff its normal points up the gradient at its pixel."""
    pts = check.vertices(vertices_vu, "vertices_vu")
    nrm = check.normals(normals_vu, pts.shape[0])
    grad = check.gradient(image_gradient_vu)
    dv, du = check.pair(offset_vu, "offset_vu")
    return _polarity(pts, nrm, grad, dv, du)


def _polarity(pts: FloatArray, nrm: FloatArray, grad: FloatArray, dv: float, du: float) -> np.ndarray:
    h, w = grad.shape[:2]
    iv = np.rint(pts[:, 0] + dv)
    iu = np.rint(pts[:, 1] + du)
    inside = (iv >= 0) & (iv < h) & (iu >= 0) & (iu < w)
    accept = np.zeros(pts.shape[0], dtype=bool)
    jv = iv[inside].astype(np.int64)
    ju = iu[inside].astype(np.int64)
    g = grad[jv, ju]
    dot = nrm[inside, 0] * g[:, 0] + nrm[inside, 1] * g[:, 1]
    accept[inside] = dot > 0.0
    return accept


def tukey_biweight_weights(residuals: Any, *, c: float = DEFAULT_TUKEY_C) -> FloatArray:
    """Holland-Welsch biweight of (already scaled) residuals."""
    c = tukey_c_value(c)
    r = check.as_float_array(residuals, "residuals")
    if r.ndim != 1:
        raise ValueError(f"residuals must be 1-D; got ndim={r.ndim}")
    return _tukey(r, c)


def _tukey(r: FloatArray, c: float) -> FloatArray:
    # a huge |r / c| overflows only where the biweight is 0 anyway
    with np.errstate(over="ignore"):
        s = r / c
        return np.where(np.abs(s) <= 1.0, (1.0 - s * s) ** 2, 0.0)


def information_matrix_to_covariance(
    jacobian: Any, weights: Any, *, rcond: float = DEFAULT_PINVH_RCOND
) -> FloatArray:
    """Pseudoinverse of the M-estimator information matrix ``J^T W J``."""
    jac, w, rcond = check_covariance_inputs(jacobian, weights, rcond)
    if jac.shape[0] == 0 or not (w > 0).any():
        # :ref:`contract-numerics`: no information is the zero matrix here (a caller's s2 * cov
        # with s2 == 0 must stay 0); the +inf sentinel is the LM's (:ref:`contract-lm`)
        return np.zeros((jac.shape[1], jac.shape[1]))
    a = np.sqrt(w)[:, None] * jac
    info = a.T @ a
    cov = scipy.linalg.pinvh(info, rtol=rcond)
    return 0.5 * (cov + cov.T)


# --------------------------------------------------------------------------
# Levenberg-Marquardt with Tukey IRLS (:ref:`contract-lm`)
# --------------------------------------------------------------------------


def lm_subpixel_refine(
    *,
    vertices_vu: Any,
    normals_vu: Any,
    sigma_normal_per_vertex_px: Any,
    image_edge_dt: Any,
    image_gradient_vu: Any = None,
    initial_offset_vu: Any = (0.0, 0.0),
    initial_rotation_rad: float = 0.0,
    fit_rotation: bool = False,
    pivot_vu: Any = None,
    pivot_distance_px: float = 0.0,
    use_polarity: bool = True,
    max_iterations: int = DEFAULT_LM_MAX_ITERATIONS,
    damping: float = DEFAULT_LM_DAMPING,
    step_tolerance_px: float = DEFAULT_LM_STEP_TOLERANCE,
    tukey_c: float = DEFAULT_TUKEY_C,
    pinvh_rcond: float = DEFAULT_PINVH_RCOND,
    trust_region_px: float | None = None,
    tikhonov_alpha: float = 0.0,
    final_gradient_ridge: bool = False,
) -> LMRefineResult:
    """Robust sub-pixel LM fit of the polyline to the DT (:ref:`contract-lm`)."""
    a = check_lm_inputs(locals())
    pts, nrm, sig, dt, grad = a.vertices, a.normals, a.sigmas, a.dt, a.gradient
    dv0, du0 = a.offset
    pivot = a.pivot

    if a.use_polarity:
        assert grad is not None  # check_lm_inputs refused use_polarity without it
        polarity = _polarity(pts, nrm, grad, dv0, du0)
    else:
        polarity = np.ones(pts.shape[0], dtype=bool)
    inv_var = 1.0 / sig**2

    def evaluate(p: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        r, jac = _residuals_and_jacobian(dt, pts, p, pivot, a.fit_rotation)
        r = np.where(polarity, r, POLARITY_PENALTY_RESIDUAL)
        w = inv_var * _tukey(r / sig, a.tukey_c) * polarity
        return r, w, jac

    def tikhonov_cost(p: FloatArray, t: float) -> float:
        return t * ((p[0] - dv0) ** 2 + (p[1] - du0) ** 2)

    pose = np.array([dv0, du0, a.rotation])  # theta stays fixed unless fitted
    n_params = 3 if a.fit_rotation else 2
    lam = a.damping
    iterations = 0
    converged = False
    state = None  # (r, w, J): the last state computed
    while iterations < a.max_iterations:
        # Step 2a samples the state at the current pose on every iteration,
        # as the design's loop does (after an accepted step it was also
        # computed in step 2f of :ref:`contract-lm`: the same values, again).
        state = evaluate(pose)
        r, w, jac = state
        if not (w > 0).any():
            break
        cost = float(np.sum(w * r * r))
        sw = np.sqrt(w)
        amat = sw[:, None] * jac
        hess = amat.T @ amat
        grad_vec = amat.T @ (sw * r)
        t = 0.0
        if a.tikhonov_alpha > 0:
            t = a.tikhonov_alpha * float(np.sum(w))
            hess[0, 0] += t
            hess[1, 1] += t
            grad_vec[0] += t * (pose[0] - dv0)
            grad_vec[1] += t * (pose[1] - du0)
            cost += tikhonov_cost(pose, t)
        damped = hess + lam * np.diag(np.diag(hess))
        step = _solve_normal_equations(damped, grad_vec, a.pinvh_rcond)
        trial = pose.copy()
        trial[:n_params] += step
        if a.trust_region_px is not None and np.hypot(trial[0] - dv0, trial[1] - du0) > a.trust_region_px:
            lam = min(2 * lam, LM_DAMPING_MAX)
            iterations += 1
            if lam >= LM_DAMPING_MAX:
                break
            continue
        r_trial = _sample(dt, _transform(pts, trial, pivot))
        r_trial = np.where(polarity, r_trial, POLARITY_PENALTY_RESIDUAL)
        trial_cost = float(np.sum(w * r_trial * r_trial))
        if a.tikhonov_alpha > 0:
            trial_cost += tikhonov_cost(trial, t)
        if trial_cost < cost:
            pose = trial
            lam = max(lam / 2, LM_DAMPING_MIN)
            iterations += 1
            state = evaluate(pose)  # step 2f: the state at the accepted pose
            if _step_norm(step, a.pivot_distance) < a.step_tolerance:
                converged = True
                break
        else:
            lam = min(2 * lam, LM_DAMPING_MAX)
            iterations += 1
            if lam >= LM_DAMPING_MAX:
                break
    if state is None:
        state = evaluate(pose)
    r, w, jac = state

    if a.final_gradient_ridge and (w > 0).any():
        assert grad is not None  # check_lm_inputs refused the ridge without it
        # :ref:`contract-changes`: through the module attribute, so a caller may replace it
        ridge = gradient_ridge_refine(
            vertices_vu=pts,
            normals_vu=nrm,
            sigma_normal_per_vertex_px=sig,
            gradient_magnitude=np.hypot(grad[:, :, 0], grad[:, :, 1]),
            initial_offset_vu=(float(pose[0]), float(pose[1])),
            weight_mask=polarity.astype(np.float64),
            initial_rotation_rad=float(pose[2]),
            fit_rotation=a.fit_rotation,
            pivot_vu=pivot,
            pivot_distance_px=a.pivot_distance,
            tukey_c=a.tukey_c,
        )
        if ridge.applied:
            pose = np.array([*ridge.offset_vu, ridge.rotation_rad])
            r, w, jac = evaluate(pose)
            converged = bool(converged or ridge.converged)

    inlier_count = int(np.count_nonzero(w > 0))
    total_weight = float(np.sum(w))
    degenerate = inlier_count == 0 or total_weight == 0.0
    if degenerate:
        rms = float("inf")
        cov = no_information_covariance(n_params)
    else:
        rms = float(np.sqrt(np.sum(w * r * r) / total_weight))
        cov = information_matrix_to_covariance(jac, w, rcond=a.pinvh_rcond)
    # :ref:`contract-changes`: over the vertices the seed polarity mask accepted
    accepted_r = r[polarity]
    raw_rms = float(np.sqrt(np.mean(accepted_r * accepted_r))) if accepted_r.size else float("inf")
    return LMRefineResult(
        offset_vu=(float(pose[0]), float(pose[1])),
        rotation_rad=float(pose[2]),
        covariance=cov,
        residuals_px=r,
        weights=w,
        rms_px=rms,
        raw_rms_px=raw_rms,
        iterations=iterations,
        converged=converged,
        inlier_count=inlier_count,
        degenerate=degenerate,
        polarity_rejected_count=int(np.count_nonzero(~polarity)),
    )


# --------------------------------------------------------------------------
# Gradient-ridge polish (:ref:`contract-ridge`)
# --------------------------------------------------------------------------


def gradient_ridge_refine(
    *,
    vertices_vu: Any,
    normals_vu: Any,
    sigma_normal_per_vertex_px: Any,
    gradient_magnitude: Any,
    initial_offset_vu: Any,
    weight_mask: Any = None,
    initial_rotation_rad: float = 0.0,
    fit_rotation: bool = False,
    pivot_vu: Any = None,
    pivot_distance_px: float = 0.0,
    max_iterations: int = DEFAULT_RIDGE_MAX_ITERATIONS,
    step_tolerance_px: float = DEFAULT_LM_STEP_TOLERANCE,
    tukey_c: float = DEFAULT_TUKEY_C,
    half_width_px: float = DEFAULT_RIDGE_HALF_WIDTH_PX,
    sample_step_px: float = DEFAULT_RIDGE_SAMPLE_STEP_PX,
    max_total_displacement_px: float = DEFAULT_RIDGE_MAX_TOTAL_DISPLACEMENT_PX,
) -> RidgeRefineResult:
    """Gauss-Newton polish onto the gradient-magnitude ridge (:ref:`contract-ridge`)."""
    a = check_ridge_inputs(locals())
    dv0, du0 = a.offset
    pose = np.array([dv0, du0, a.rotation])
    return _ridge(
        a.vertices, a.normals, a.sigmas, a.magnitude, pose, a.fit_rotation, a.pivot,
        a.pivot_distance,
        a.weight_mask, a.tukey_c, a.max_iterations, a.step_tolerance, a.half_width,
        a.sample_step, a.max_total_displacement,
    )


def _ridge_offsets(
    magnitude: FloatArray, pts: FloatArray, nrm: FloatArray, pose: FloatArray,
    pivot: tuple[float, float], t: np.ndarray, step: float,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Sub-pixel peak offset ``t*`` along each normal, validity, and normals."""
    n_rot = _rotate_normals(nrm, pose[2])
    pos = _transform(pts, pose, pivot)
    k_count = t.shape[0]
    samples = pos[:, None, :] + t[None, :, None] * n_rot[:, None, :]
    prof = _sample(magnitude, samples.reshape(-1, 2)).reshape(pts.shape[0], k_count)
    k_star = np.argmax(prof, axis=1)
    valid = (k_star > 0) & (k_star < k_count - 1)
    kc = np.clip(k_star, 1, k_count - 2)
    rows = np.arange(pts.shape[0])
    y_minus = prof[rows, kc - 1]
    y0 = prof[rows, kc]
    y_plus = prof[rows, kc + 1]
    d = y_minus - 2 * y0 + y_plus
    peak = d < -RIDGE_CURVATURE_EPS
    delta = np.where(peak, 0.5 * (y_minus - y_plus) / np.where(peak, d, 1.0), 0.0)
    delta = np.clip(delta, -0.5, 0.5)
    return t[kc] + delta * step, valid, n_rot


def _ridge(
    pts: FloatArray, nrm: FloatArray, sig: FloatArray, magnitude: FloatArray, pose: FloatArray,
    fit_rotation: bool, pivot: tuple[float, float], pivot_distance: float, weight_mask: FloatArray, tukey_c: float,
    max_iterations: int, step_tolerance: float, half_width: float, sample_step: float,
    max_total_displacement: float, *, detect_cycles: bool = True,
) -> RidgeRefineResult:
    """The polish loop; ``detect_cycles=False`` is the plain loop (tests compare the two)."""
    start = pose.copy()
    n = round(half_width / sample_step)
    t = np.arange(-n, n + 1) * sample_step
    iterations = 0
    converged = False
    # An iteration is a function of the pose alone: a pose that comes back
    # bit for bit repeats for ever. Brent's cycle detection (one saved pose,
    # saved again each time the count since it reaches a doubling power)
    # finds the period; then only the iterations that select the pose the
    # full count ends on are run (:ref:`contract-ridge`): the plain loop's
    # result, in time bounded by the cycle rather than by max_iterations.
    saved, power, since, cycling = pose.tobytes(), 1, 0, False
    limit = max_iterations
    while iterations < limit:
        r, valid, n_rot = _ridge_offsets(magnitude, pts, nrm, pose, pivot, t, sample_step)
        w = (1.0 / sig**2) * _tukey(r / sig, tukey_c) * valid * weight_mask
        if not (w > 0).any():
            break
        cols = [-n_rot[:, 0], -n_rot[:, 1]]
        if fit_rotation:
            h = JACOBIAN_ROTATION_EPS_RAD
            plus = _ridge_offsets(magnitude, pts, nrm, _with_rotation(pose, pose[2] + h), pivot, t, sample_step)[0]
            minus = _ridge_offsets(magnitude, pts, nrm, _with_rotation(pose, pose[2] - h), pivot, t, sample_step)[0]
            cols.append((plus - minus) / (2 * h))
        jac = np.stack(cols, axis=1)
        sw = np.sqrt(w)
        amat = sw[:, None] * jac
        step = _solve_normal_equations(amat.T @ amat, amat.T @ (sw * r), DEFAULT_PINVH_RCOND)
        pose = pose.copy()
        pose[: step.shape[0]] += step
        iterations += 1
        if _step_norm(step, pivot_distance) < step_tolerance:
            converged = True
            break
        if detect_cycles and not cycling:
            since += 1
            if pose.tobytes() == saved:
                cycling = True
                limit = iterations + (max_iterations - iterations) % since
            elif since == power:
                saved, power, since = pose.tobytes(), power * 2, 0
    if cycling:
        iterations = max_iterations
    moved = np.hypot(pose[0] - start[0], pose[1] - start[1])
    applied = iterations > 0 and not moved > max_total_displacement
    final = pose if applied else start
    return RidgeRefineResult(
        offset_vu=(float(final[0]), float(final[1])),
        rotation_rad=float(final[2]),
        iterations=iterations,
        converged=converged,
        applied=applied,
    )
