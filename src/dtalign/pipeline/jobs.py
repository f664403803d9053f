"""The pipeline's fits: a call's checks once, each polyline's once, compiled work.

:func:`check_options` checks a call's :class:`~dtalign.api.options.FitOptions`
once, with no polyline and no image: the search window, the pivot, the
pivot distance, then every LM option as :func:`dtalign.lm_subpixel_refine`
checks them. :func:`plan` adds an image's products (trusted: their arrays
were checked when :func:`~dtalign.pipeline.products.prepare_image` made
them). Each polyline is then checked once: :func:`item` checks one
(:func:`dtalign.pipeline.fit_polyline_products`), ``prepare`` many in bulk
(:func:`dtalign.pipeline.batch.fit_many`), both in one compiled pass over
the values; a polyline that fails it gets its error from
``polyline_error``, NumPy's checks in their order. The polylines run in
one compiled loop with the GIL released (``dtalign.api.loop.fit_polylines``:
``loop_inputs``, ``fit_polylines``), which :mod:`dtalign.pipeline.batch`
runs on its threads; ``dtalign.pipeline.fit.wrap`` makes their results.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np

from ..api import checks as check
from ..api import loop
from ..api.checks import LMArgs
from ..api.constants import DEFAULT_COARSE_MIN_SUPPORT_FRACTION
from ..api.lm import raise_for_code
from ..api.options import (
    DEFAULT_SEARCH_WINDOW_VU,
    FitOptions,
    gradient_of,
    lm_kernel_options,
)
from ..api.options import n_params as _n_params
from .products import ImageProducts

__all__ = ["DEFAULT_SEARCH_WINDOW_VU", "Batch", "Checked", "Item", "Plan", "check_options",
           "item", "plan", "prepare"]

FloatArray = check.FloatArray


class Checked(NamedTuple):
    """A call's checked options: the search window and the LM's arguments
    without a polyline or an image (their arrays empty; ``pivot`` the given
    pivot, else (0, 0); ``pivot_distance`` the given distance, else 0)."""

    window: tuple[int, int]
    lm: LMArgs
    options: FitOptions


class Plan(NamedTuple):
    """What every polyline of one call on one image shares, validated once."""

    products: ImageProducts
    window: tuple[int, int]
    mv: int
    mu: int
    lm: LMArgs
    options: FitOptions


class Item(NamedTuple):
    """One polyline's checked arrays and its resolved pivot."""

    vertices: FloatArray
    normals: FloatArray
    sigmas: FloatArray
    pivot: tuple[float, float]
    distance: float


def broadcast_sigmas(vertices_vu: Any, sigmas: Any) -> Any:
    """A scalar ``sigmas`` applied to every vertex; anything else as given.

    A real number (not a bool) becomes ``np.full(N, sigmas)`` when
    ``vertices_vu`` has the shape ``(N, 2)``; the usual checks then judge
    it (a negative or non-finite scalar is refused as ``sigmas``). The
    drop-in :func:`dtalign.lm_subpixel_refine` keeps its per-vertex
    contract and does not do this.
    """
    if isinstance(sigmas, bool | np.bool_) or not (
            isinstance(sigmas, int | float | np.integer | np.floating)
            or (isinstance(sigmas, np.ndarray) and sigmas.ndim == 0
                and sigmas.dtype.kind in "iuf")):
        return sigmas
    shape = np.shape(vertices_vu)
    if len(shape) != 2:
        return sigmas
    return np.full(shape[0], float(sigmas))


_NO_POINTS = check.readonly(np.zeros((0, 2)))


def check_options(options: FitOptions) -> Checked:
    """Check a call's options once, in the pipeline's order: the window, the
    pivot, the pivot distance, then the LM's own checks as
    :func:`dtalign.lm_subpixel_refine` runs them (its initial rotation, then
    ``dtalign.api.checks.lm_options``)."""
    window = check.search_window(options.search_window_vu)
    fit_rotation = bool(options.fit_rotation)
    pivot = (0.0, 0.0) if options.pivot_vu is None else check.pair(options.pivot_vu, "pivot_vu")
    distance = 0.0
    if options.pivot_distance_px is not None:
        distance = check.finite_real(options.pivot_distance_px, "pivot_distance_px")
        if fit_rotation and distance <= 0.0:
            raise ValueError(
                f"fit_rotation=True requires a finite pivot_distance_px > 0, got {distance!r}"
            )
    keywords = options.lm_keywords()
    rotation = check.finite_real(keywords["initial_rotation_rad"], "initial_rotation_rad")
    lm = LMArgs(vertices=_NO_POINTS, normals=_NO_POINTS, sigmas=_NO_POINTS[:, 0],
                dt=_NO_POINTS, gradient=None, offset=(0.0, 0.0), rotation=rotation,
                fit_rotation=fit_rotation, pivot=pivot, pivot_distance=distance,
                **check.lm_options(keywords))
    return Checked(window, lm, options)


def plan(products: ImageProducts, checked: Checked) -> Plan:
    """The call's ``Plan`` on one image's ``products``; on a region's
    (:mod:`dtalign.pipeline.region`), a given pivot in the crop's pixels."""
    h, w = products.shape
    window = checked.window
    lm = checked.lm._replace(dt=products.edge_dt, gradient=products.gradient_vu)
    if products.region is not None and checked.options.pivot_vu is not None:
        v0, u0 = products.region.origin_vu
        lm = lm._replace(pivot=(lm.pivot[0] - v0, lm.pivot[1] - u0))
    return Plan(products=products, window=window, mv=min(window[0], max(h - 1, 0)),
                mu=min(window[1], max(w - 1, 0)), lm=lm, options=checked.options)


def _distance(shared: Plan, pivot: tuple[float, float]) -> float:
    """The pivot distance the pipeline passes to the LM: the given one, else
    with rotation the pivot's distance to the image centre, floored at 1."""
    if shared.options.pivot_distance_px is not None or not shared.lm.fit_rotation:
        return shared.lm.pivot_distance
    region = shared.products.region
    if region is None:
        h, w = shared.products.shape
        return max(math.hypot(pivot[0] - (h - 1) / 2.0, pivot[1] - (w - 1) / 2.0), 1.0)
    (h, w), (v0, u0) = region.frame_shape, region.origin_vu  # the frame's centre, in the crop
    return max(math.hypot(pivot[0] - ((h - 1) / 2.0 - v0), pivot[1] - ((w - 1) / 2.0 - u0)),
               1.0)


def _in_crop(shared: Plan, points: FloatArray) -> FloatArray:
    """Frame pixels ``points`` in the pixels of the products' crop (exact:
    the crop's origin is a whole number below every point it holds)."""
    region = shared.products.region
    if region is None:
        return points
    return check.readonly(points - np.asarray(region.origin_vu, dtype=np.float64))


def _rotating(shared: Plan) -> bool:
    """Whether the fits rotate (the pivot spread is then checked per polyline)."""
    return shared.lm.fit_rotation or shared.lm.rotation != 0.0


def item(shared: Plan, vertices_vu: Any, normals_vu: Any, sigmas: Any) -> Item:
    """Check one polyline of a call: its shapes, its values in one compiled pass
    (on a fault, ``polyline_error`` raises), its pivot and distance, and
    when rotating the pivot spread."""
    try:
        verts = check.vertex_shape(vertices_vu, "vertices_vu", allow_empty=False)
        norms = check.normals_shape(normals_vu, verts.shape[0])
        sig = check.sigmas_shape(sigmas, verts.shape[0], "sigmas")
        status, c_v, c_u = loop.polyline_status(verts, norms, sig)
    except (TypeError, ValueError):
        status = -1
    if status != loop.OK:
        raise polyline_error(vertices_vu, normals_vu, sigmas)
    # the compiled centroid is bit-identical to NumPy's mean (resolve_pivot)
    verts = _in_crop(shared, verts)
    if shared.options.pivot_vu is not None:
        pivot = shared.lm.pivot
    elif shared.products.region is None:
        pivot = (c_v, c_u)
    else:
        v0, u0 = shared.products.region.origin_vu
        pivot = (c_v - v0, c_u - u0)
    if _rotating(shared):
        check.pivot_spread(verts, pivot)
    return Item(verts, norms, sig, pivot, _distance(shared, pivot))


def polyline_error(vertices_vu: Any, normals_vu: Any, sigmas: Any) -> Exception:
    """The error of a polyline the compiled pass refused: NumPy's checks of its
    arrays in order (the centroid's last), which name the argument."""
    try:
        verts = check.vertices(vertices_vu, "vertices_vu", allow_empty=False)
        check.normals(normals_vu, verts.shape[0])
        check.sigmas(sigmas, verts.shape[0], "sigmas")
        check.resolve_pivot(verts, None)
    except (TypeError, ValueError) as exc:
        return exc
    raise AssertionError("the compiled and NumPy polyline checks disagree")  # pragma: no cover


class Batch(NamedTuple):
    """Checked polylines of one call, concatenated for the compiled loop."""

    n: int
    pts: FloatArray
    nrm: FloatArray
    sig: FloatArray
    starts: np.ndarray
    pivots: FloatArray
    distances: FloatArray

    def item(self, j: int) -> Item:
        """Polyline ``j``'s :class:`Item`: views of its rows."""
        s, e = int(self.starts[j]), int(self.starts[j + 1])
        return Item(self.pts[s:e], self.nrm[s:e], self.sig[s:e],
                    (float(self.pivots[j, 0]), float(self.pivots[j, 1])),
                    float(self.distances[j]))


def _plain(v: Any, n: Any, s: Any) -> bool:
    """Whether a polyline is float64 arrays of the right shapes (no conversion
    needed; ``np.concatenate`` copies any layout)."""
    if not (type(v) is np.ndarray and type(n) is np.ndarray and type(s) is np.ndarray):
        return False
    shape = v.shape
    # native float64 is one dtype instance: identity, no dtype comparison
    return (
        v.dtype is _F8 and n.dtype is _F8 and s.dtype is _F8 and len(shape) == 2
        and shape[1] == 2 and shape[0] > 0 and n.shape == shape and s.shape == (shape[0],)
    )


_F8 = np.dtype(np.float64)


def _concatenated(
    vs: list[Any], ns: list[Any], ss: list[Any]
) -> tuple[FloatArray, FloatArray, FloatArray, list[int]] | None:
    """``np.concatenate`` of each list, and the polylines' lengths, if every
    ``(vs[i], ns[i], ss[i])`` passes :func:`_plain`; None otherwise.

    Checked per list, not per polyline: the casting rule ``"no"`` refuses
    any dtype but native float64, the concatenation any mix of dimensions,
    and the results' shapes and the lengths do the rest: a few calls per
    list rather than :func:`_plain`'s six attribute reads per polyline.
    """
    if set(map(type, vs + ns + ss)) != {np.ndarray}:
        return None
    try:
        pts = np.concatenate(vs, dtype=_F8, casting="no")
        nrm = np.concatenate(ns, dtype=_F8, casting="no")
        sig = np.concatenate(ss, dtype=_F8, casting="no")
    except (TypeError, ValueError):
        return None
    lens = list(map(len, vs))
    if (pts.ndim != 2 or pts.shape[1] != 2 or nrm.ndim != 2 or nrm.shape[1] != 2
            or sig.ndim != 1 or list(map(len, ns)) != lens or list(map(len, ss)) != lens
            or min(lens) == 0):
        return None
    return pts, nrm, sig, lens


def _stacked(parts: Sequence[tuple[Any, Any, Any]]
             ) -> tuple[FloatArray, FloatArray, FloatArray, list[int], int]:
    """The polylines' arrays concatenated, their lengths, and the first whose
    shapes are wrong (``len(parts)`` if none): in bulk when every polyline is
    float64 arrays (:func:`_concatenated`), else one by one."""
    if parts:
        bulk = _concatenated(*(list(x) for x in zip(*parts, strict=True)))
        if bulk is not None:
            return (*bulk, len(parts))
    verts: list[FloatArray] = []
    norms: list[FloatArray] = []
    sigs: list[FloatArray] = []
    bad = len(parts)
    for k, (v, n, s) in enumerate(parts):
        if not _plain(v, n, s):
            try:
                v = check.vertex_shape(v, "vertices_vu", allow_empty=False)
                n = check.normals_shape(n, v.shape[0])
                s = check.sigmas_shape(s, v.shape[0], "sigmas")
            except (TypeError, ValueError):
                bad = k
                break
        verts.append(v)
        norms.append(n)
        sigs.append(s)
    empty = np.zeros((0, 2))
    pts = np.concatenate(verts) if verts else empty
    nrm = np.concatenate(norms) if norms else empty
    sig = np.concatenate(sigs) if sigs else empty[:, 0]
    return pts, nrm, sig, list(map(len, verts)), bad


def prepare(shared: Plan, parts: Sequence[tuple[Any, Any, Any]]) -> tuple[Batch, Exception | None]:
    """Check polylines of a call as :func:`item` checks each, in bulk.

    Shapes are checked in bulk when every polyline is float64 arrays, else
    per polyline; values in one compiled pass over all of them; when
    rotating, each pivot's spread. Returns the polylines up to the first
    bad one, and the error :func:`item` raises for that one (None if all pass).
    """
    pts, nrm, sig, lens, bad = _stacked(parts)
    pts, nrm, sig = check.readonly(pts), check.readonly(nrm), check.readonly(sig)
    # (np.cumsum of the list converts it first: twice the time)
    starts = np.fromiter(itertools.accumulate(lens, initial=0), np.int64, len(lens) + 1)
    n_ok, _, centroids = loop.polylines_status(pts, nrm, sig, starts)
    bad = min(bad, int(n_ok))
    pts = _in_crop(shared, pts)
    pivots = centroids[:bad]
    if shared.products.region is not None:
        pivots = pivots - np.asarray(shared.products.region.origin_vu, dtype=np.float64)
    if shared.options.pivot_vu is not None:
        pivots[:] = shared.lm.pivot
    distances = np.full(bad, shared.lm.pivot_distance)
    if _rotating(shared):
        for k, pivot in enumerate(map(tuple, pivots.tolist())):
            distances[k] = _distance(shared, pivot)
            try:
                check.pivot_spread(pts[starts[k] : starts[k + 1]], pivot)
            except ValueError:
                bad = k
                break
    error: Exception | None = None
    if bad < len(parts):
        try:
            item(shared, *parts[bad])
        except (TypeError, ValueError) as exc:  # raised by the caller after the fits before it
            error = exc  # (anything else, e.g. a signal handler's exception, propagates now)
        else:  # pragma: no cover
            raise AssertionError("the bulk and the per-polyline checks disagree")
    end = int(starts[bad])
    return Batch(bad, pts[:end], nrm[:end], sig[:end], starts[: bad + 1], pivots[:bad],
                 distances[:bad]), error


def at_window_edge(dv: int, du: int, window: tuple[int, int]) -> bool:
    """Whether the coarse seed lies on the boundary of a non-zero search margin."""
    return (window[0] > 0 and abs(dv) >= window[0]) or (window[1] > 0 and abs(du) >= window[1])


def seed_of(shared: Plan, it: Item, *, surface: bool = False
            ) -> tuple[tuple[int, int], np.ndarray | None]:
    """The pipeline's integer seed (:func:`dtalign.api.loop.pipeline_seed`):
    polarity-weighted where polarity is on, with the support floor
    ``DEFAULT_COARSE_MIN_SUPPORT_FRACTION`` and the window clipped to the
    image; and, with ``surface``, the score surface it is the best of."""
    return loop.pipeline_seed(
        shared.products.edge_mask, shared.lm.gradient if shared.lm.use_polarity else None,
        it.vertices, it.normals, shared.mv, shared.mu, DEFAULT_COARSE_MIN_SUPPORT_FRACTION,
        surface=surface,
    )


def loop_inputs(shared: Plan, batch: Batch) -> tuple[loop.LoopInputs, np.ndarray, loop.LoopOutputs]:
    """The compiled loop's inputs for ``batch`` with fresh outputs:
    ``(inputs, errors, outputs)``; the call for polylines ``lo:hi`` is
    :data:`fit_polylines` ``(inputs, lo, hi, errors, outputs)``."""
    k = batch.n
    a = shared.lm
    n_params = int(_n_params(a.fit_rotation))
    n_pts = batch.pts.shape[0]
    errors = np.zeros(k, dtype=np.int64)
    out = loop.LoopOutputs(
        coarse=np.zeros((k, 2), dtype=np.int64), poses=np.zeros((k, 3)),
        iterations=np.zeros(k, dtype=np.int64), converged=np.zeros(k, dtype=np.bool_),
        covs=np.zeros((k, n_params, n_params)), rms=np.zeros(k), raw_rms=np.zeros(k),
        inliers=np.zeros(k, dtype=np.int64), degenerate=np.zeros(k, dtype=np.bool_),
        r_all=np.zeros(n_pts), w_all=np.zeros(n_pts),
    )
    inputs = loop.LoopInputs(
        edge=shared.products.edge_mask, mv=shared.mv, mu=shared.mu, dt=a.dt,
        grad=gradient_of(a), pts=batch.pts, nrm=batch.nrm, sig=batch.sig, starts=batch.starts,
        pivots=batch.pivots, distances=batch.distances, rotation0=a.rotation,
        seed_support=DEFAULT_COARSE_MIN_SUPPORT_FRACTION, opts=lm_kernel_options(a),
    )
    return inputs, errors, out


#: The compiled loop's code of a polyline that fitted (any other is an error:
#: :func:`kernel_error`).
OK = loop.OK


#: The compiled loop the batch calls (a module attribute, so that a test can
#: wrap it to watch or gate the batch's compiled calls).
fit_polylines = loop.fit_polylines


def readonly_views(out: loop.LoopOutputs) -> loop.LoopOutputs:
    """Read-only views of :func:`loop_inputs`' outputs, for the fits to keep
    slices of (the caller then locks the outputs themselves, so that no
    view can be made writable again)."""
    views = [arr.view() for arr in out]
    for view in views:
        view.flags.writeable = False
    return loop.LoopOutputs(*views)


def kernel_error(code: int) -> ValueError:
    """The ValueError of a compiled loop's error code."""
    try:
        raise_for_code(code)
    except ValueError as exc:
        return exc
    raise AssertionError(f"error code {code} raised nothing")  # pragma: no cover
