"""Many polylines against one image in one compiled call: coarse search, then LM.

A pipeline fit is ~0.2 ms of compiled work; the Python around each call
(argument unboxing, result tuples) holds the GIL, which is what stops two
threads from fitting twice as fast. Here a whole chunk of polylines runs
with the GIL released. The LM is exactly the kernel, with exactly the
argument types, that :func:`dtalign.lm_subpixel_refine` calls; the coarse
search scores the same pixel pairs as
:func:`dtalign.coarse.coarse_search_vertices`, from one index of the edge
mask for the whole chunk instead of a scan of a box per polyline. Results
are bit-identical to fitting the polylines one by one.
"""

from __future__ import annotations

import numpy as np

from .._jit import kernel
from .coarse import edge_index, search_index, support_of_vertices
from .fit import OK, fit


@kernel
def fit_polylines(
    edge, index_rows, index_cols, mv, mu, dt, grad, pts, nrm, sig, starts, pivots, distances,
    rotation0, use_polarity, fit_rotation, max_iterations, damping, step_tolerance, tukey_c,
    rcond, trust_region, tikhonov_alpha, ridge, ridge_half, ridge_sample_step,
    ridge_max_iterations, ridge_step_tolerance, ridge_max_displacement, use_libm,
):  # pragma: no cover - compiled
    """Fit polylines ``j = 0, 1, ...`` (rows ``starts[j]:starts[j+1]`` of the
    concatenated ``pts, nrm, sig``) until one fails. ``index_rows,
    index_cols`` is :func:`~dtalign._kernels.coarse.edge_index` of ``edge``,
    or empty to build it here.

    Returns ``(done, error, coarse, pose, iterations, converged, cov, rms,
    raw_rms, inliers, degenerate, r, w)``: ``done`` polylines have results
    (per-polyline rows; ``r, w`` concatenated like ``pts``); ``error`` is
    :data:`dtalign._kernels.fit.OK`, or the error code of polyline ``done``,
    which stopped the loop (as the serial loop stops at a raised error).
    """
    k = starts.shape[0] - 1
    n_params = 3 if fit_rotation else 2
    coarse = np.zeros((k, 2), dtype=np.int64)
    poses = np.zeros((k, 3))
    iterations = np.zeros(k, dtype=np.int64)
    converged = np.zeros(k, dtype=np.bool_)
    covs = np.zeros((k, n_params, n_params))
    rms = np.zeros(k)
    raw_rms = np.zeros(k)
    inliers = np.zeros(k, dtype=np.int64)
    degenerate = np.zeros(k, dtype=np.bool_)
    r_all = np.zeros(pts.shape[0])
    w_all = np.zeros(pts.shape[0])
    h, w = edge.shape
    if index_rows.shape[0] == 0:  # one scan of the edge mask for the whole chunk
        row_start, e_cols = edge_index(edge)
    else:  # or the caller's, shared by its chunks
        row_start, e_cols = index_rows, index_cols
    for j in range(k):
        a = starts[j]
        b = starts[j + 1]
        p = pts[a:b]
        sv, su = support_of_vertices(p, h, w)
        dv, du = search_index(row_start, e_cols, sv, su, h, w, mv, mu)
        # fresh writable arrays, as lm_subpixel_refine's wrapper passes them
        pose0 = np.empty(3)
        pose0[0] = float(dv)
        pose0[1] = float(du)
        pose0[2] = rotation0
        pivot = np.empty(2)
        pivot[0] = pivots[j, 0]
        pivot[1] = pivots[j, 1]
        (error, pose, n_iter, conv, r, wt, _jac, cov, rms_j, raw_j, inl, deg) = fit(
            dt, grad, p, nrm[a:b], sig[a:b], use_polarity, pose0, pivot, fit_rotation,
            distances[j], max_iterations, damping, step_tolerance, tukey_c, rcond, trust_region,
            tikhonov_alpha, ridge, ridge_half, ridge_sample_step, ridge_max_iterations,
            ridge_step_tolerance, ridge_max_displacement, use_libm,
        )
        if error != OK:
            return (j, error, coarse, poses, iterations, converged, covs, rms, raw_rms, inliers,
                    degenerate, r_all, w_all)
        coarse[j, 0] = dv
        coarse[j, 1] = du
        poses[j, :] = pose
        iterations[j] = n_iter
        converged[j] = conv
        covs[j] = cov
        rms[j] = rms_j
        raw_rms[j] = raw_j
        inliers[j] = inl
        degenerate[j] = deg
        r_all[a:b] = r
        w_all[a:b] = wt
    return (k, OK, coarse, poses, iterations, converged, covs, rms, raw_rms, inliers, degenerate,
            r_all, w_all)
