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

from typing import Any, NamedTuple

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


class LoopInputs(NamedTuple):
    """What every polyline of one :func:`fit_polylines` call reads."""

    edge: np.ndarray  #: the edge mask, bool (H, W)
    mv: int  #: the coarse margins, clipped to the image
    mu: int
    dt: np.ndarray  #: the edge DT
    grad: np.ndarray  #: the gradient (or a stand-in when polarity and ridge are off)
    pts: np.ndarray  #: every polyline's vertices, concatenated, (N, 2)
    nrm: np.ndarray  #: their normals
    sig: np.ndarray  #: their sigmas
    starts: np.ndarray  #: polyline j is rows starts[j]:starts[j+1]
    pivots: np.ndarray  #: (K, 2)
    distances: np.ndarray  #: (K,)
    rotation0: float  #: the initial rotation
    seed_support: float  #: the seed's support fraction
    opts: Any  #: the LM's options record (:func:`dtalign._kernels.fit.fit`'s)


class LoopOutputs(NamedTuple):
    """Row ``j`` of each array is polyline ``j``'s result (``r_all``, ``w_all``:
    its rows ``starts[j]:starts[j+1]``)."""

    coarse: np.ndarray  #: int64 (K, 2), the integer seed
    poses: np.ndarray  #: (K, 3)
    iterations: np.ndarray  #: int64 (K,)
    converged: np.ndarray  #: bool (K,)
    covs: np.ndarray  #: (K, P, P)
    rms: np.ndarray
    raw_rms: np.ndarray
    inliers: np.ndarray  #: int64 (K,)
    degenerate: np.ndarray  #: bool (K,)
    r_all: np.ndarray  #: (N,) residuals
    w_all: np.ndarray  #: (N,) weights


@kernel
def fit_polylines(inp, lo, hi, errors, out):
    """Fit polylines ``j`` in ``lo:hi`` of ``inp`` (a :class:`LoopInputs`),
    writing row ``j`` of ``out`` (a :class:`LoopOutputs`).

    The seed is the pipeline's (:func:`dtalign.pipeline.jobs.seed_of`): the
    polarity-weighted search with polarity, else the scored overlap search,
    dense where it serves, else against an index of the edge mask built on
    first need. A failing polyline gets its error code in ``errors[j]`` (its
    other rows are left as they were) and the loop goes on. Returns the first
    ``j`` that failed, ``hi`` if none did.
    """
    edge, mv, mu, pts, nrm, sig, starts = inp.edge, inp.mv, inp.mu, inp.pts, inp.nrm, inp.sig, inp.starts
    opts = inp.opts
    h, w = edge.shape
    edge_flat, _ = flat_words(edge)
    row_start = e_cols = np.zeros(0, dtype=np.int64)
    indexed = False
    first_failed = hi
    for j in range(lo, hi):
        a = starts[j]
        b = starts[j + 1]
        p = pts[a:b]
        if opts.use_polarity:  # the single polarity-gated seed of the drop-in pipeline
            dv, du, _ = polarity_search(edge, inp.grad, p, nrm[a:b], mv, mu,
                                        inp.seed_support * (b - a))
        else:
            sv, su = support_of_vertices(p, h, w)
            floor = inp.seed_support * sv.shape[0]
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
        pose0[2] = inp.rotation0
        pivot = np.empty(2)
        pivot[0] = inp.pivots[j, 0]
        pivot[1] = inp.pivots[j, 1]
        (error, pose, n_iter, conv, r, wt, _jac, cov, rms_j, raw_j, inl, deg, _rej) = fit(
            inp.dt, inp.grad, p, nrm[a:b], sig[a:b], pose0, pivot, inp.distances[j], opts,
        )
        errors[j] = error
        if error != OK:
            first_failed = min(first_failed, j)
            continue
        out.coarse[j, 0] = dv
        out.coarse[j, 1] = du
        out.poses[j, :] = pose
        out.iterations[j] = n_iter
        out.converged[j] = conv
        out.covs[j] = cov
        out.rms[j] = rms_j
        out.raw_rms[j] = raw_j
        out.inliers[j] = inl
        out.degenerate[j] = deg
        out.r_all[a:b] = r
        out.w_all[a:b] = wt
    return first_failed
