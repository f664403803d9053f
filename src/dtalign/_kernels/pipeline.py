"""Many polylines against one image in one compiled loop: coarse search, then LM.

A pipeline fit is ~0.1 ms of compiled work; the Python around each call
(argument unboxing, result tuples) holds the GIL. Here a range of
polylines runs with the GIL released, from the coarse search to the LM's
results, so threads of :func:`dtalign.pipeline.batch.fit_many` fit in parallel and
hold the GIL only to call this loop and wrap its results. The LM is exactly
the kernel, with exactly the argument types, that
:func:`dtalign.lm_subpixel_refine` calls; the coarse search scores the same
pixel pairs as :func:`dtalign.api.coarse.coarse_search_vertices`, from one index
of the edge mask (where the sparse search serves) instead of a scan of a box
per polyline. Results are bit-identical to fitting the polylines one by one.
"""

from __future__ import annotations

import numpy as np

from .._jit import kernel
from .coarse import (
    best_scored,
    dense_ok,
    edge_index,
    flat_words,
    in_image_counts,
    overlap_dense,
    search_index_scored,
    support_of_vertices,
)
from .fit import OK, fit
from .polarity_search import polarity_search


@kernel
def fit_polylines(
    edge, mv, mu, dt, grad, pts, nrm, sig, starts, pivots, distances, rotation0, seed_support,
    opts, lo, hi, errors, coarse, poses, iterations, converged, covs, rms, raw_rms, inliers,
    degenerate, r_all, w_all,
):
    """Fit polylines ``j`` in ``lo:hi`` (rows ``starts[j]:starts[j+1]`` of the
    concatenated ``pts, nrm, sig``), writing row ``j`` of the outputs.

    ``opts`` is the LM's options record (:func:`dtalign._kernels.fit.fit`'s);
    ``seed_support`` the seed's support fraction (the pipeline passes
    ``DEFAULT_COARSE_MIN_SUPPORT_FRACTION``).

    The seed is the pipeline's (:func:`dtalign.pipeline.jobs.seed_of`): the
    polarity-weighted search with polarity, else the scored overlap search,
    dense where it serves, else against an index of the edge mask built on
    first need. A failing polyline gets its error code in ``errors[j]`` (its
    other rows are left as they were) and the loop goes on. Returns the first
    ``j`` that failed, ``hi`` if none did.
    """
    h, w = edge.shape
    edge_flat, _ = flat_words(edge)
    row_start = e_cols = np.zeros(0, dtype=np.int64)
    indexed = False
    first_failed = hi
    for j in range(lo, hi):
        a = starts[j]
        b = starts[j + 1]
        p = pts[a:b]
        if opts.use_polarity:  # today's limb and terminator seed (issue 17)
            dv, du, _ = polarity_search(edge, grad, p, nrm[a:b], mv, mu, seed_support * (b - a))
        else:
            sv, su = support_of_vertices(p, h, w)
            floor = seed_support * sv.shape[0]
            if sv.shape[0] > 0 and dense_ok(sv.shape[0], mu):
                overlap = overlap_dense(sv, su, edge_flat, h, w, mv, mu)
                counts = in_image_counts(sv, su, h, w, mv, mu)
                dv, du, _ = best_scored(overlap, counts, sv.shape[0], mv, mu, floor)
            else:
                if not indexed:  # one scan of the edge mask for the range's polylines
                    row_start, e_cols = edge_index(edge)
                    indexed = True
                dv, du, _ = search_index_scored(row_start, e_cols, sv, su, h, w, mv, mu, floor)
        # fresh writable arrays, as lm_subpixel_refine's wrapper passes them
        pose0 = np.empty(3)
        pose0[0] = float(dv)
        pose0[1] = float(du)
        pose0[2] = rotation0
        pivot = np.empty(2)
        pivot[0] = pivots[j, 0]
        pivot[1] = pivots[j, 1]
        (error, pose, n_iter, conv, r, wt, _jac, cov, rms_j, raw_j, inl, deg, _rej) = fit(
            dt, grad, p, nrm[a:b], sig[a:b], pose0, pivot, distances[j], opts,
        )
        errors[j] = error
        if error != OK:
            first_failed = min(first_failed, j)
            continue
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
    return first_failed
