"""The pipeline's fits: checks once per call, compiled work, light result wrapping.

:func:`dtalign.pipeline.fit_polyline_products` and
:func:`dtalign.pipeline.batch.fit_many` share this. The first polyline of a call
is checked exactly as the step-by-step pipeline checks it (its own
arrays, the window, the pivot, then every LM option and the products'
arrays, in that order): that fixes which error a bad call raises. What it
validated holds for every further polyline of the call, which then only
needs its own arrays checked (one compiled pass) and, when rotating, its
pivot spread. The polylines then run in one compiled loop with the GIL
released (:mod:`dtalign._kernels.pipeline`), which :mod:`dtalign.pipeline.batch`
runs on its threads; ``dtalign.pipeline.fit.wrap`` makes their results.

The kernels are imported on first use: importing :mod:`dtalign.pipeline`
must not import Numba.
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Sequence
from types import SimpleNamespace
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from ..api import checks as check
from ..api.constants import (
    DEFAULT_COARSE_MIN_SUPPORT_FRACTION,
)
from .products import ImageProducts

if TYPE_CHECKING:
    from ..api.checks import LMArgs

FloatArray = check.FloatArray


@functools.cache
def _deps() -> SimpleNamespace:
    """What the fits use from modules that import Numba, imported on first use
    (importing :mod:`dtalign.pipeline` must not import Numba) and then kept,
    so that no import statement runs again on each fit."""
    from .._kernels import coarse
    from .._kernels.checks import OK, polyline_status, polylines_status
    from .._kernels.pipeline import fit_polylines
    from .._kernels.polarity_search import polarity_search
    from ..api.checks import check_lm_inputs
    from ..api.lm import fit_checked, raise_for_code
    from ..api.options import gradient_of, lm_kernel_options

    return SimpleNamespace(
        check_lm_inputs=check_lm_inputs, coarse=coarse, OK=OK, polyline_status=polyline_status,
        polylines_status=polylines_status,
        fit_polylines=fit_polylines,
        gradient_of=gradient_of, lm_kernel_options=lm_kernel_options,
        fit_checked=fit_checked, raise_for_code=raise_for_code,
        polarity_search=polarity_search,
    )


class Plan(NamedTuple):
    """What every polyline of one call shares, validated once."""

    products: ImageProducts
    window: tuple[int, int]
    h: int
    w: int
    mv: int
    mu: int
    edge: np.ndarray
    lm: LMArgs
    pivot_vu: tuple[float, float] | None
    pivot_distance_px: float | None


class Item(NamedTuple):
    """One polyline's checked arrays and its resolved pivot."""

    vertices: FloatArray
    normals: FloatArray
    sigmas: FloatArray
    pivot: tuple[float, float]
    distance: float


#: The pipeline's coarse-search margin when a call gives none, px per axis:
#: wide enough for the pointing errors the navigation frames show (the
#: disc demo's offset is ~9 px), small enough that a 1024 x 1024 frame's
#: search stays a fraction of a millisecond. The command line's
#: ``--window`` default is the same value.
DEFAULT_SEARCH_WINDOW_VU: tuple[int, int] = (30, 30)


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


def _distance(products: ImageProducts, pivot: tuple[float, float], fit_rotation: bool,
              pivot_distance_px: Any) -> float:
    """The pivot distance the pipeline passes to the LM (see ``fit_polyline_products``)."""
    if pivot_distance_px is None:
        if not fit_rotation:
            return 0.0
        h, w = products.shape
        return max(math.hypot(pivot[0] - (h - 1) / 2.0, pivot[1] - (w - 1) / 2.0), 1.0)
    distance = check.finite_real(pivot_distance_px, "pivot_distance_px")
    if fit_rotation and distance <= 0.0:
        raise ValueError(
            f"fit_rotation=True requires a finite pivot_distance_px > 0, got {distance!r}"
        )
    return distance


def plan(
    products: Any, vertices_vu: Any, normals_vu: Any, sigmas: Any, *, search_window_vu: Any,
    fit_rotation: bool, pivot_vu: Any, pivot_distance_px: Any, lm_options: dict[str, Any],
) -> tuple[Plan, Item]:
    """Check the first polyline and everything shared, in the pipeline's order.

    ``lm_options`` are the keywords passed on to ``lm_subpixel_refine``
    (``use_polarity``, ``trust_region_px``, ...).
    """
    d = _deps()
    if not isinstance(products, ImageProducts):
        raise TypeError(f"products must be an ImageProducts, got {type(products).__name__}")
    # The polyline's values in one compiled pass; on any fault, the NumPy
    # checks in their order, which raise the pipeline's error.
    try:
        verts = check.vertex_shape(vertices_vu, "vertices_vu", allow_empty=False)
        norms = check.normals_shape(normals_vu, verts.shape[0])
        sig = check.sigmas_shape(sigmas, verts.shape[0], "sigmas")
        status, c_v, c_u = d.polyline_status(verts, norms, sig)
    except (TypeError, ValueError):
        status = -1
    if status != d.OK:
        verts = check.vertices(vertices_vu, "vertices_vu", allow_empty=False)
        norms = check.normals(normals_vu, verts.shape[0])
        sig = check.sigmas(sigmas, verts.shape[0], "sigmas")
    window = check.search_window(search_window_vu)
    fit_rotation = bool(fit_rotation)
    # the centroid of polyline_status is bit-identical to resolve_pivot's mean
    pivot = (c_v, c_u) if status == d.OK and pivot_vu is None else check.resolve_pivot(verts, pivot_vu)
    distance = _distance(products, pivot, fit_rotation, pivot_distance_px)
    edge = check.mask2d(products.edge_mask, "edge_mask")
    # The LM's own checks, as lm_subpixel_refine runs them; any finite
    # offset stands for the coarse seed (always a pair of ints). A polyline
    # that passed the compiled pass above passes the LM's polyline check
    # (the same shape checks and pass), which is then not run again.
    lm = d.check_lm_inputs({
        "vertices_vu": verts, "normals_vu": norms, "sigma_normal_per_vertex_px": sig,
        "image_edge_dt": products.edge_dt, "image_gradient_vu": products.gradient_vu,
        "initial_offset_vu": (0.0, 0.0), "fit_rotation": fit_rotation, "pivot_vu": pivot,
        "pivot_distance_px": distance, **lm_options,
    }, (verts, norms, sig, (c_v, c_u)) if status == d.OK else None)
    h, w = edge.shape
    shared = Plan(
        products=products, window=window, h=h, w=w,
        mv=min(window[0], max(h - 1, 0)), mu=min(window[1], max(w - 1, 0)),
        edge=edge, lm=lm,
        pivot_vu=None if pivot_vu is None else pivot, pivot_distance_px=pivot_distance_px,
    )
    return shared, Item(lm.vertices, lm.normals, lm.sigmas, pivot, distance)


def recheck(shared: Plan, vertices_vu: Any, normals_vu: Any, sigmas: Any) -> None:
    """Raise what fitting this polyline alone would raise (it failed a bulk check).

    Runs :func:`plan`'s exact sequence with the call's options.
    """
    lm = shared.lm
    options = {name: getattr(lm, field) for name, field in _LM_OPTION_FIELDS.items()}
    plan(shared.products, vertices_vu, normals_vu, sigmas, search_window_vu=shared.window,
         fit_rotation=lm.fit_rotation, pivot_vu=shared.pivot_vu,
         pivot_distance_px=shared.pivot_distance_px, lm_options=options)
    raise AssertionError("unreachable: the bulk checks and plan() disagree")  # pragma: no cover


class Batch(NamedTuple):
    """Checked polylines of one call, concatenated for the compiled loop."""

    n: int
    pts: FloatArray
    nrm: FloatArray
    sig: FloatArray
    starts: np.ndarray
    pivots: FloatArray
    distances: FloatArray


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


def prepare(
    shared: Plan, parts: Sequence[tuple[Any, Any, Any]], first: Item | None = None
) -> tuple[Batch, Exception | None]:
    """Check polylines of a call whose first polyline passed :func:`plan`.

    ``first``, when given, is that polyline, already checked: it stands
    for ``parts[0]``. Shapes are checked in bulk when every polyline is
    float64 arrays, else per polyline; values in one compiled pass over all
    of them. Returns the polylines up to the first bad one, and the error
    that one raises alone (None if all pass).
    """
    lm = shared.lm
    verts: list[FloatArray] = []
    norms: list[FloatArray] = []
    sigs: list[FloatArray] = []
    if first is not None:
        verts, norms, sigs = [first.vertices], [first.normals], [first.sigmas]
    bad = len(parts)
    start = len(verts)
    bulk = None
    if len(parts) > start:
        vs, ns, ss = zip(*parts[start:], strict=True)
        bulk = _concatenated(verts + list(vs), norms + list(ns), sigs + list(ss))
    if bulk is not None:
        pts, nrm, sig, lens = bulk
    else:
        for k in range(start, len(parts)):
            v, n, s = parts[k]
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
        lens = list(map(len, verts))
    pts, nrm, sig = check.readonly(pts), check.readonly(nrm), check.readonly(sig)
    # (np.cumsum of the list converts it first: twice the time)
    starts = np.fromiter(itertools.accumulate(lens, initial=0), np.int64, len(lens) + 1)
    n_ok, _, centroids = _deps().polylines_status(pts, nrm, sig, starts)
    bad = min(bad, int(n_ok))
    pivots = centroids[:bad]
    if shared.pivot_vu is not None:
        pivots[:] = shared.pivot_vu
    elif first is not None:
        pivots[0] = first.pivot
    # Without rotation the distance is the same for every polyline (0, or
    # the one given), and no pivot spread can overflow.
    distances = np.full(bad, _distance(shared.products, (0.0, 0.0), False,
                                       shared.pivot_distance_px))
    if lm.fit_rotation or lm.rotation != 0.0:
        for k, pivot in enumerate(map(tuple, pivots.tolist())):
            distances[k] = _distance(shared.products, pivot, lm.fit_rotation,
                                     shared.pivot_distance_px)
            if k == 0 and first is not None:
                continue  # checked by plan()
            try:  # the pivot-spread check of a rotating fit
                check.pose(pts[starts[k] : starts[k + 1]], fit_rotation=lm.fit_rotation,
                           pivot_vu=pivot, pivot_distance_px=distances[k],
                           initial_offset_vu=(0.0, 0.0), initial_rotation_rad=lm.rotation)
            except (TypeError, ValueError):
                bad = k
                break
    error: Exception | None = None
    if bad < len(parts):
        try:
            recheck(shared, *parts[bad])
        except (TypeError, ValueError) as exc:  # raised by the caller after the fits before it
            error = exc  # (anything else, e.g. a signal handler's exception, propagates now)
    end = int(starts[bad])
    return Batch(bad, pts[:end], nrm[:end], sig[:end], starts[: bad + 1], pivots[:bad],
                 distances[:bad]), error


#: lm_subpixel_refine keyword -> LMArgs field, for re-running plan() on a polyline.
_LM_OPTION_FIELDS = {
    "use_polarity": "use_polarity", "max_iterations": "max_iterations", "damping": "damping",
    "step_tolerance_px": "step_tolerance", "tukey_c": "tukey_c", "pinvh_rcond": "pinvh_rcond",
    "trust_region_px": "trust_region_px", "tikhonov_alpha": "tikhonov_alpha",
    "final_gradient_ridge": "final_gradient_ridge", "initial_rotation_rad": "rotation",
}


def at_window_edge(dv: int, du: int, window: tuple[int, int]) -> bool:
    """Whether the coarse seed lies on the boundary of a non-zero search margin."""
    return (window[0] > 0 and abs(dv) >= window[0]) or (window[1] > 0 and abs(du) >= window[1])


def seed_of(shared: Plan, it: Item) -> tuple[int, int]:
    """The pipeline's integer seed, as today's techniques take it: the
    polarity-weighted search where polarity is on (limb, terminator), else
    the overlap search of the rasterised polyline (rings), both with the
    support floor (``DEFAULT_COARSE_MIN_SUPPORT_FRACTION``) and the window
    clipped to the image."""
    d = _deps()
    floor = DEFAULT_COARSE_MIN_SUPPORT_FRACTION
    if shared.lm.use_polarity:
        assert shared.lm.gradient is not None  # the LM checks refused polarity without it
        dv, du, _ = d.polarity_search(
            shared.edge, shared.lm.gradient, it.vertices, it.normals, shared.mv, shared.mu,
            floor * it.vertices.shape[0],
        )
    else:
        # (plan() refused an empty image: the LM checks need a non-empty DT)
        sv, su = d.coarse.support_of_vertices(it.vertices, shared.h, shared.w)
        dv, du, _ = d.coarse.search_support_scored(
            shared.edge, sv, su, shared.mv, shared.mu, floor * sv.shape[0]
        )
    return int(dv), int(du)


def loop_inputs(
    shared: Plan, batch: Batch
) -> tuple[tuple[Any, ...], np.ndarray, tuple[np.ndarray, ...]]:
    """:func:`dtalign._kernels.pipeline.fit_polylines`' arguments for ``batch``
    with fresh outputs: ``(args, errors, outputs)``; the call for polylines
    ``lo:hi`` is ``fit_polylines(*args, lo, hi, errors, *outputs)``."""
    d = _deps()
    k = batch.n
    a = shared.lm
    n_params = 3 if a.fit_rotation else 2
    n_pts = batch.pts.shape[0]
    errors = np.zeros(k, dtype=np.int64)
    out = (np.zeros((k, 2), dtype=np.int64), np.zeros((k, 3)), np.zeros(k, dtype=np.int64),
           np.zeros(k, dtype=np.bool_), np.zeros((k, n_params, n_params)), np.zeros(k),
           np.zeros(k), np.zeros(k, dtype=np.int64), np.zeros(k, dtype=np.bool_),
           np.zeros(n_pts), np.zeros(n_pts))
    args = (
        shared.edge, shared.mv, shared.mu, a.dt, d.gradient_of(a), batch.pts, batch.nrm,
        batch.sig, batch.starts, batch.pivots, batch.distances, a.rotation,
        DEFAULT_COARSE_MIN_SUPPORT_FRACTION, d.lm_kernel_options(a),
    )
    return args, errors, out


def run_loop(args: tuple[Any, ...], lo: int, hi: int, errors: np.ndarray,
             out: tuple[np.ndarray, ...]) -> int:
    """Polylines ``lo:hi`` of :func:`loop_inputs`' ``(args, errors, out)``
    through the compiled loop (GIL released); returns the first that failed,
    ``hi`` if none did. What :func:`dtalign.pipeline.batch.fit_many` runs on
    each thread, without its Python around it (the benchmark's control)."""
    return int(_deps().fit_polylines(*args, lo, hi, errors, *out))


def readonly_views(out: tuple[np.ndarray, ...]) -> tuple[np.ndarray, ...]:
    """Read-only views of :func:`loop_inputs`' outputs, for the fits to keep
    slices of (the caller then locks the outputs themselves, so that no
    view can be made writable again)."""
    views = tuple(arr.view() for arr in out)
    for view in views:
        view.flags.writeable = False
    return views


def raise_for(error: int) -> None:
    """Raise the ValueError of a :func:`~dtalign._kernels.pipeline.fit_polylines` error code."""
    _deps().raise_for_code(error)


#: Independent chains of :func:`fp_throughput` (see ``dtalign._kernels.fpload``).
FP_LANES = 32


def fp_throughput(rounds: int) -> float:
    """``FP_LANES`` independent multiply-add chains run ``rounds`` times, compiled
    with the kernels' flags (GIL released); returns their sum.

    Floating-point-bound compiled work with nothing of dtalign in it: how
    two threads of it scale beside :func:`run_loop`'s tells whether the
    machine, not the loop, limits a batch (the batch benchmark's control,
    :mod:`dtalign.benchmarking.fpload`).
    """
    from .._kernels.fpload import LANES
    from .._kernels.fpload import fp_throughput as compiled

    assert LANES == FP_LANES
    return float(compiled(rounds))
