"""Many polylines against one image in one compiled loop: coarse search, then LM.

A pipeline fit is ~0.2 ms of compiled work; the Python around each call
(argument unboxing, result tuples) holds the GIL, which is what stops two
threads from fitting twice as fast. Here a whole list of polylines runs
with the GIL released, and several threads can run the same loop over
the same list: each takes the next polyline from a shared counter, so a
thread on a slower core simply fits fewer. The LM is exactly the kernel,
with exactly the argument types, that :func:`dtalign.lm_subpixel_refine`
calls; the coarse search scores the same pixel pairs as
:func:`dtalign.coarse.coarse_search_vertices`, from one index of the edge
mask (where the sparse search serves) instead of a scan of a box per
polyline. Results are bit-identical to fitting the polylines one by one.
"""

from __future__ import annotations

import numpy as np

from .._constants import DEFAULT_COARSE_MIN_SUPPORT_FRACTION as SEED_SUPPORT
from .._jit import kernel
from .atomics import fetch_add, fetch_min, load, store
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

#: ``tickets[NEXT]``: the next polyline to take; ``tickets[FIRST_ERROR]``:
#: the first polyline that failed (the count while none has).
NEXT = 0
FIRST_ERROR = 1


@kernel
def fit_polylines(
    edge, mv, mu, dt, grad, pts, nrm, sig, starts, pivots, distances,
    rotation0, use_polarity, fit_rotation, max_iterations, damping, step_tolerance, tukey_c,
    rcond, trust_region, tikhonov_alpha, ridge, ridge_half, ridge_sample_step,
    ridge_max_iterations, ridge_step_tolerance, ridge_max_displacement, use_libm, tickets,
    errors, finished, stop_at, coarse, poses, iterations, converged, covs, rms, raw_rms,
    inliers, degenerate, r_all, w_all,
):  # pragma: no cover - compiled
    """Fit polylines ``j`` (rows ``starts[j]:starts[j+1]`` of the concatenated
    ``pts, nrm, sig``) taken in turn from ``tickets`` (:data:`NEXT`), writing
    row ``j`` of the outputs, until none is left or one before it has failed.

    The coarse search is :func:`~dtalign._kernels.coarse.search_support`'s:
    dense where it serves, else against an index of the edge mask built on
    first need. A failing polyline gets its error
    code in ``errors[j]`` and lowers ``tickets[FIRST_ERROR]`` to ``j``; no
    thread then takes a polyline after it, and every polyline before it is
    fitted (each was taken before it), as the serial loop stops at the first
    raised error. A fitted polyline's ``finished[j]`` is set to 1 after its
    rows are written (see :func:`finished_until`). The call stops taking
    polylines once the next one is ``stop_at`` or later (``k``: once none is
    left; a thread that read the counter just before another took a ticket
    may take one past ``stop_at``). Returns the number of polylines it fitted.
    """
    k = starts.shape[0] - 1
    h, w = edge.shape
    edge_flat, _ = flat_words(edge)
    row_start = e_cols = np.zeros(0, dtype=np.int64)
    indexed = False
    done = 0
    while load(tickets, NEXT) < stop_at:
        j = fetch_add(tickets, NEXT, 1)
        if j >= k or j > load(tickets, FIRST_ERROR):
            return done
        a = starts[j]
        b = starts[j + 1]
        p = pts[a:b]
        if use_polarity:  # today's limb and terminator seed (issue 17)
            dv, du, _ = polarity_search(edge, grad, p, nrm[a:b], mv, mu, SEED_SUPPORT * (b - a))
        else:
            sv, su = support_of_vertices(p, h, w)
            floor = SEED_SUPPORT * sv.shape[0]
            if sv.shape[0] > 0 and dense_ok(sv.shape[0], mu):
                overlap = overlap_dense(sv, su, edge_flat, h, w, mv, mu)
                counts = in_image_counts(sv, su, h, w, mv, mu)
                dv, du, _ = best_scored(overlap, counts, sv.shape[0], mv, mu, floor)
            else:
                if not indexed:  # one scan of the edge mask for this thread's polylines
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
            dt, grad, p, nrm[a:b], sig[a:b], use_polarity, pose0, pivot, fit_rotation,
            distances[j], max_iterations, damping, step_tolerance, tukey_c, rcond, trust_region,
            tikhonov_alpha, ridge, ridge_half, ridge_sample_step, ridge_max_iterations,
            ridge_step_tolerance, ridge_max_displacement, use_libm,
        )
        done += 1
        if error != OK:
            errors[j] = error
            fetch_min(tickets, FIRST_ERROR, j)
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
        store(finished, j, 1)
    return done


@kernel
def finished_until(finished, start):  # pragma: no cover - compiled
    """The first ``j >= start`` whose ``finished[j]`` is not set: rows
    ``start:j`` of :func:`fit_polylines`' outputs are written and may be read
    while other threads still fit."""
    j = start
    while j < finished.shape[0] and load(finished, j) != 0:
        j += 1
    return j
