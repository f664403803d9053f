"""Input checks and conversions shared by every public function.

Each helper checks one argument, names it in the message, and returns it
converted once to what the kernels assume: a C-contiguous, native-endian
float64 array (or a Python scalar). Kernels never validate, so everything a
kernel could trip on (a NaN cast to an index, a wrong trailing dimension)
must be refused here. The message fragments the contract quotes
(:ref:`contract-errors`) are part of the drop-in contract.

The one module of argument checks, in five parts: the per-argument
helpers (the search window in each form callers write it among them:
``search_window``); the whole-call checks of the fitting stages
(``check_lm_inputs`` and its siblings), shared by the compiled path and the
reference so that both check in the same order (which decides the message a
caller sees) and convert every array exactly once; the image side's checks;
the batch functions' own arguments; and the fields of a record read from
text or JSON (the campaign manifest's). A caller whose argument has another
name passes it, so that each message is right where it is made.
"""

from __future__ import annotations

import json
import math
import numbers
import re
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from .results import ImageDerivativesConfig

FloatArray = NDArray[np.float64]

_F8 = np.dtype(np.float64)


def readonly(arr: np.ndarray) -> np.ndarray:
    """A read-only view of ``arr`` (no copy).

    Every array a kernel receives as input is read-only: Numba compiles a
    separate specialisation for read-only and writable arrays, which costs a
    compile each and may round differently, so one calling convention keeps
    the result independent of the caller's array flags.
    """
    if not arr.flags.writeable:
        return arr
    view = arr.view()
    view.flags.writeable = False
    return view


def as_float_array(value: Any, name: str) -> FloatArray:
    """Convert to a C-contiguous, native float64, read-only array (same ndim).

    The common case (already such an array) is four attribute checks and a
    view: this runs several times per fit. An unaligned view (of a byte
    buffer, say) is copied: kernels then see one kind of array, and are
    compiled once for it.
    """
    if (type(value) is np.ndarray and value.dtype == _F8 and value.flags.c_contiguous
            and value.flags.aligned):
        return readonly(value)
    if isinstance(value, np.ndarray):
        probe = value
    else:
        try:
            probe = np.asarray(value)
        except Exception as exc:  # ragged sequences and the like
            raise TypeError(f"{name} must be a numeric array: {exc}") from exc
    if probe.dtype.kind not in "biuf":
        raise TypeError(f"{name} must be a real numeric array, got dtype {probe.dtype}")
    # asarray, not ascontiguousarray: the latter turns a 0-D scalar into 1-D
    arr = np.asarray(probe, dtype=np.float64)
    if not (arr.flags.c_contiguous and arr.flags.aligned):
        arr = arr.copy(order="C")
    return readonly(arr)


def require_finite(arr: FloatArray, name: str) -> None:
    """Refuse NaN and +/-inf entries, naming the argument."""
    if arr.size and not np.isfinite(arr).all():
        raise ValueError(f"{name} must be finite (found NaN or inf)")


def vertex_shape(value: Any, name: str, allow_empty: bool) -> FloatArray:
    arr = as_float_array(value, name)
    if arr.ndim != 2 or arr.shape[1] != 2 or (not allow_empty and arr.shape[0] == 0):
        what = "(N, 2) with N > 0" if not allow_empty else "(N, 2)"
        raise ValueError(f"{name} must have shape {what}; got {arr.shape}")
    return arr


def vertices(value: Any, name: str = "vertices_vu", *, allow_empty: bool = True) -> FloatArray:
    """``(N, 2)`` finite float64 vertices; ``N == 0`` only if ``allow_empty``."""
    arr = vertex_shape(value, name, allow_empty)
    require_finite(arr, name)
    return arr


def normals(value: Any, n_vertices: int) -> FloatArray:
    """Finite normals of the same ``(N, 2)`` shape as the vertices."""
    arr = normals_shape(value, n_vertices)
    require_finite(arr, "normals_vu")
    return arr


#: Image-sized arrays up to this many values are scanned for NaN/inf on
#: every call (a small part of a fit). Larger ones are checked where the
#: kernels read them: scanning a 1024 x 1024 DT and gradient costs several
#: times a whole LM fit, and a value never read cannot change a result.
#: Any non-finite value a kernel does read raises ValueError.
FULL_SCAN_MAX_SIZE = 1 << 16


def require_finite_if_small(arr: FloatArray, name: str) -> None:
    """Scan small image-sized arrays up front (see ``FULL_SCAN_MAX_SIZE``)."""
    if arr.size <= FULL_SCAN_MAX_SIZE:
        require_finite(arr, name)


def nonfinite_read(name: str) -> ValueError:
    """The error for a NaN or inf that a kernel read from ``name``."""
    return ValueError(f"{name} must be finite: the fit read a NaN or inf value from it")


def image2d(value: Any, name: str) -> FloatArray:
    """A non-empty 2-D float64 array (DT, gradient magnitude).

    Finiteness: see :data:`FULL_SCAN_MAX_SIZE`.
    """
    arr = as_float_array(value, name)
    if arr.ndim != 2:
        raise ValueError(f"{name} must be 2-D; got ndim={arr.ndim}")
    if arr.size == 0:
        raise ValueError(f"{name} must not be empty, got shape {arr.shape}")
    require_finite_if_small(arr, name)
    return arr


def gradient(value: Any, name: str = "image_gradient_vu") -> FloatArray:
    """An ``(H, W, 2)`` gradient-vector image (finiteness as :func:`image2d`)."""
    arr = as_float_array(value, name)
    if arr.ndim != 3 or arr.shape[2] != 2 or arr.shape[0] == 0 or arr.shape[1] == 0:
        raise ValueError(f"{name} must have shape (H, W, 2); got {arr.shape}")
    require_finite_if_small(arr, name)
    return arr


def pair(value: Any, name: str) -> tuple[float, float]:
    """A finite length-2 pair of real numbers (offsets, pivots)."""
    if type(value) in (tuple, list) and len(value) == 2:
        a, b = value
        if type(a) in _PLAIN_REALS and type(b) in _PLAIN_REALS:  # fast path
            fa, fb = float(a), float(b)
            if not (math.isfinite(fa) and math.isfinite(fb)):
                raise ValueError(f"{name} must be finite, got {(fa, fb)}")
            return fa, fb
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a length-2 sequence of numbers") from exc
    if arr.shape != (2,):
        raise ValueError(f"{name} must be a length-2 sequence of numbers, got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} must be finite, got {tuple(arr.tolist())}")
    return float(arr[0]), float(arr[1])


#: Exact types accepted without the (slow) numbers.Real ABC check.
_PLAIN_REALS = (float, int, np.float64)


def real(value: Any, name: str) -> float:
    """A real scalar (bool refused) as a Python float; finiteness not checked."""
    if type(value) in _PLAIN_REALS:
        return float(value)
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be a real number, got {type(value).__name__}")
    return float(value)


def finite_real(value: Any, name: str) -> float:
    """A finite real scalar."""
    out = real(value, name)
    if not math.isfinite(out):
        raise ValueError(f"{name} must be finite, got {out!r}")
    return out


def nonnegative_real(value: Any, name: str) -> float:
    """A finite real scalar >= 0."""
    out = real(value, name)
    if not (math.isfinite(out) and out >= 0.0):
        raise ValueError(f"{name} must be finite and >= 0, got {out!r}")
    return out


def positive_real(value: Any, name: str) -> float:
    """A finite real scalar > 0."""
    out = real(value, name)
    if not (math.isfinite(out) and out > 0.0):
        raise ValueError(f"{name} must be a finite positive number, got {out!r}")
    return out


def count(value: Any, name: str) -> int:
    """A non-negative integer (bool refused)."""
    if type(value) is int and value >= 0:
        return value
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name} must be an int, got {type(value).__name__}")
    out = int(value)
    if out < 0:
        raise ValueError(f"{name} must be non-negative, got {out}")
    return out


def shape2(value: Any, name: str = "shape_vu") -> tuple[int, int]:
    """A length-2 image shape of non-negative ints."""
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if not isinstance(value, (tuple, list)) or len(value) != 2:
        raise ValueError(f"{name} must be a length-2 sequence of ints, got {value!r}")
    return count(value[0], f"{name}[0]"), count(value[1], f"{name}[1]")


#: The forms a search window is written in, each with the wording its
#: writer reads: ``"argument"``, the drop-in functions' ``search_window_vu``
#: (a tuple or list of two ints, checked in the contract's order:
#: :ref:`contract-errors`); ``"option"``, a command-line option's text
#: (``N`` for both axes or ``V,U``); ``"field"``, a manifest field or a
#: campaign default (an int, a list of one or two ints, or that text, whose
#: two ints may also be separated by a space, as in a CSV cell).
WINDOW_FORMS = ("argument", "option", "field")

#: What separates the two ints of a window written as text.
_WINDOW_SEPARATOR = re.compile(r"\s*,\s*|\s+")


def search_window(value: Any, name: str = "search_window_vu", *,
                  form: str = "argument") -> tuple[int, int]:
    """The coarse-search margin ``(mv, mu)``: two non-negative ints.

    Parameters
    ----------
    value : Any
        The window as the caller wrote it (see :data:`WINDOW_FORMS`).
    name : str, optional
        How the messages name it (``search_window_vu``, ``--window``, a
        manifest's ``"manifest m.jsonl line 3: window"``).
    form : {"argument", "option", "field"}, optional
        The form ``value`` is written in, and so what is accepted:
        ``"argument"`` only a tuple or list of two ints, checked in the
        contract's order (the container, each entry's type, then the sign:
        a ``(-1, 2.0)`` window is a TypeError, as upstream); ``"option"``
        the text ``N`` or ``V,U``; ``"field"`` also an int or a list of one
        or two ints.

    Raises
    ------
    ValueError
        If ``value`` is not of its form, or a margin is negative.
    TypeError
        If an entry of an ``"argument"`` window is not an int.
    """
    if form == "argument":
        if not isinstance(value, (tuple, list)) or len(value) != 2:
            raise ValueError(f"{name} must be a length-2 sequence of ints; got {value!r}")
        for i, item in enumerate(value):
            if not _is_int(item):
                raise TypeError(f"{name}[{i}] must be int; got {type(item).__name__}")
        mv, mu = int(value[0]), int(value[1])
        if mv < 0 or mu < 0:
            raise ValueError(f"{name} must be non-negative; got {value!r}")
        return mv, mu
    if form not in WINDOW_FORMS:
        raise ValueError(f"form must be one of {WINDOW_FORMS}, got {form!r}")
    option = form == "option"
    if option or isinstance(value, str):
        parts = _WINDOW_SEPARATOR.split(str(value).strip())
        if option and len(parts) > 2:
            raise ValueError(f"{name} takes one or two ints (N or V,U), got {value!r}")
        try:
            entries: Any = [int(p) for p in parts]
        except ValueError:
            if option:
                raise ValueError(f"{name} takes ints (N or V,U), got {value!r}") from None
            raise ValueError(f"{name} takes one int or two separated by a comma or a space, "
                             f"got {value!r}") from None
    elif _is_int(value):
        entries = [value]
    else:
        entries = value
    if (not isinstance(entries, (list, tuple)) or len(entries) not in (1, 2)
            or not all(_is_int(v) for v in entries)):
        raise ValueError(f"{name} must be an int or a list of two ints, got {value!r}")
    mv, mu = int(entries[0]), int(entries[-1])
    if mv < 0 or mu < 0:
        shown = value if option else repr(value)
        raise ValueError(f"{name} must be non-negative, got {shown}")
    return mv, mu


def _is_int(value: Any) -> bool:
    """An integral number that is not a bool."""
    return isinstance(value, numbers.Integral) and not isinstance(value, (bool, np.bool_))


def mask2d(value: Any, name: str) -> NDArray[np.bool_]:
    """A 2-D array read as a boolean mask (nonzero is True)."""
    arr = np.asarray(value)
    if arr.ndim != 2:
        raise ValueError(f"{name} must be 2-D, got {arr.ndim}-D")
    if arr.dtype.kind not in "biuf":
        raise TypeError(f"{name} must be a numeric or boolean array, got dtype {arr.dtype}")
    if arr.dtype == np.bool_:
        return np.ascontiguousarray(arr)  # no copy in the common case
    if arr.dtype.kind == "f" and arr.size and not np.isfinite(arr).all():
        raise ValueError(f"{name} must be finite (found NaN or inf)")
    return np.ascontiguousarray(arr != 0)


def mask_values(arr: np.ndarray, name: str) -> np.ndarray:
    """An edge mask whose values count: bool when they are all 0/1, else float64.

    The contract (:ref:`contract-coarse-scored`) sums the edge mask's values as float64; for 0/1 values that sum
    is a count, which the integer kernels compute exactly.
    """
    if arr.dtype == np.bool_:
        return np.ascontiguousarray(arr)
    if arr.dtype.kind not in "biuf":
        raise TypeError(f"{name} must be a numeric or boolean array, got dtype {arr.dtype}")
    values = np.ascontiguousarray(arr, dtype=np.float64)
    if values.size and not np.isfinite(values).all():
        raise ValueError(f"{name} must be finite (found NaN or inf)")
    if ((values == 0.0) | (values == 1.0)).all():
        return values != 0.0
    return values


def weight_mask(value: Any, n_vertices: int) -> FloatArray:
    """Optional per-vertex 0/1 mask for the ridge polish, as float64."""
    if value is None:
        return np.ones(n_vertices, dtype=np.float64)
    arr = np.asarray(value)
    if arr.ndim != 1 or arr.shape[0] != n_vertices:
        raise ValueError(
            f"weight_mask must be a 1-D vector of length {n_vertices}, got shape {arr.shape}"
        )
    if arr.dtype.kind not in "biuf":
        raise TypeError(f"weight_mask must be boolean or numeric, got dtype {arr.dtype}")
    if arr.dtype.kind == "f" and not np.isfinite(arr).all():
        raise ValueError("weight_mask must be finite (found NaN or inf)")
    return np.ascontiguousarray(arr != 0, dtype=np.float64)


def normals_shape(value: Any, n_vertices: int) -> FloatArray:
    arr = as_float_array(value, "normals_vu")
    if arr.shape != (n_vertices, 2):
        raise ValueError(f"normals_vu must match vertices_vu shape; got {arr.shape}")
    return arr


def sigmas_shape(value: Any, n_vertices: int, name: str = "sigma_normal_per_vertex_px") -> FloatArray:
    arr = as_float_array(value, name)
    if arr.ndim != 1 or arr.shape[0] != n_vertices:
        raise ValueError(f"{name} must be a 1-D vector matching vertices_vu; got {arr.shape}")
    return arr


def sigmas(value: Any, n_vertices: int, name: str = "sigma_normal_per_vertex_px") -> FloatArray:
    """Per-vertex prior sigmas: 1-D, length N, finite, > 0, with finite ``1/sigma^2``.

    The NumPy form of the checks :func:`polyline` runs compiled, for
    callers (the pipeline) whose argument has another name.
    """
    arr = sigmas_shape(value, n_vertices, name)
    with np.errstate(over="ignore", divide="ignore"):
        ok = bool(np.isfinite(arr).all() and (arr > 0.0).all()
                  and np.isfinite(1.0 / (arr * arr)).all())
    if not ok:
        raise ValueError(f"{name} must be finite and > 0 (and 1/sigma^2 representable)")
    return arr


_SIGMA_MESSAGE = (
    "sigma_normal_per_vertex_px entries must be finite and > 0 (and 1/sigma^2 representable)"
)


def polyline(
    vertices_vu: Any, normals_vu: Any, sigma_normal_per_vertex_px: Any
) -> tuple[FloatArray, FloatArray, FloatArray, tuple[float, float]]:
    """Vertices (N > 0), normals and sigmas: the first checks of LM and ridge.

    Shapes are checked here in the contract's order; values in one compiled pass (one
    call on every fit, where NumPy would make one per check), which also
    returns the vertex centroid, the default rotation pivot.
    """
    from .._kernels.checks import BAD_CENTROID, BAD_NORMALS, BAD_VERTICES, polyline_status

    verts = vertex_shape(vertices_vu, "vertices_vu", allow_empty=False)
    norms = normals_shape(normals_vu, verts.shape[0])
    sig = sigmas_shape(sigma_normal_per_vertex_px, verts.shape[0])
    status, c_v, c_u = polyline_status(verts, norms, sig)
    if status == BAD_VERTICES:
        raise ValueError("vertices_vu must be finite (found NaN or inf)")
    if status == BAD_CENTROID:
        raise ValueError(
            "vertices_vu must be finite and not so large that their centroid overflows"
        )
    if status == BAD_NORMALS:
        raise ValueError("normals_vu must be finite (found NaN or inf)")
    if status != 0:
        raise ValueError(_SIGMA_MESSAGE)
    return verts, norms, sig, (c_v, c_u)


def pose(
    verts: FloatArray,
    *,
    fit_rotation: bool,
    pivot_vu: Any,
    pivot_distance_px: Any,
    initial_offset_vu: Any,
    initial_rotation_rad: Any,
    centroid: tuple[float, float] | None = None,
) -> tuple[tuple[float, float], float, tuple[float, float], float]:
    """The pose arguments LM and ridge share, after the field check.

    Returns the initial offset, the initial rotation, the resolved pivot
    (``centroid`` -- or the vertex mean if not given -- unless the caller
    gives a pivot) and the pivot distance.
    """
    distance = real(pivot_distance_px, "pivot_distance_px")
    if fit_rotation and not (math.isfinite(distance) and distance > 0.0):
        raise ValueError(
            "fit_rotation=True requires pivot_distance_px > 0 for the convergence test; "
            f"got {distance!r}"
        )
    if not math.isfinite(distance):
        raise ValueError(f"pivot_distance_px must be finite, got {distance!r}")
    offset = pair(initial_offset_vu, "initial_offset_vu")
    rotation = finite_real(initial_rotation_rad, "initial_rotation_rad")
    if pivot_vu is None and centroid is not None:
        pivot = centroid
    else:
        pivot = resolve_pivot(verts, pivot_vu)
    if pivot_vu is not None and (fit_rotation or rotation != 0.0):
        pivot_spread(verts, pivot)
    return offset, rotation, pivot, distance


def pivot_spread(verts: FloatArray, pivot: tuple[float, float]) -> None:
    """Refuse a pivot so far from the vertices that rotating about it overflows
    (``vertex - pivot`` must stay finite, with a factor 2 to spare)."""
    with np.errstate(over="ignore", invalid="ignore"):
        spread = 2.0 * (verts - np.asarray(pivot))
    if not np.isfinite(spread).all():
        raise ValueError(
            "pivot_vu is so far from vertices_vu that the rotated positions overflow"
        )


def resolve_pivot(verts: FloatArray, pivot_vu: Any) -> tuple[float, float]:
    """The rotation pivot: the vertex centroid unless the caller gives one.

    The mean is NumPy's; :func:`polyline` computes the same value in its
    compiled pass (a sequential sum over the rows, which is what
    ``mean(axis=0)`` does for an ``(N, 2)`` C array: tested bit-for-bit).
    """
    if pivot_vu is None:
        with np.errstate(over="ignore", invalid="ignore"):
            centroid = verts.mean(axis=0)
        if not np.isfinite(centroid).all():
            raise ValueError(
                "vertices_vu must be finite and not so large that their centroid overflows"
            )
        return float(centroid[0]), float(centroid[1])
    return pair(pivot_vu, "pivot_vu")


# ---------------------------------------------------------------------------
# Ranges that keep a call bounded. Each is checked after the contract-ordered
# checks of its function and names the argument.
# ---------------------------------------------------------------------------

#: Largest accepted iteration count: the kernels count iterations in an
#: int64 (a larger Python int fails Numba's typing after a compile).
MAX_ITERATIONS = 2**63 - 1


def iteration_count(value: Any, name: str = "max_iterations") -> int:
    """A non-negative int (as :func:`count`) of at most ``2**63 - 1``."""
    out = count(value, name)
    if out > MAX_ITERATIONS:
        raise ValueError(
            f"{name} must be at most 2**63 - 1 (iterations are counted in int64), got {out}"
        )
    return out


#: Most samples of one ridge profile, ``2 * round(half_width_px /
#: sample_step_px) + 1``. Every iteration reads each vertex's profile (three
#: times when fitting rotation), so this bounds the work at ~30,000 bilinear
#: reads per vertex and iteration, and the profile buffers at 80 kB; the
#: default profile (3.0 px at 0.5 px) has 13 samples.
MAX_RIDGE_PROFILE_SAMPLES = 10_001


def ridge_profile_size(half_width_px: float, sample_step_px: float) -> None:
    """Refuse a ridge profile of more than :data:`MAX_RIDGE_PROFILE_SAMPLES` samples."""
    ratio = half_width_px / sample_step_px
    if not math.isfinite(ratio) or 2 * round(ratio) + 1 > MAX_RIDGE_PROFILE_SAMPLES:
        raise ValueError(
            "half_width_px / sample_step_px must round to at most "
            f"{(MAX_RIDGE_PROFILE_SAMPLES - 1) // 2}: a profile of at most "
            f"{MAX_RIDGE_PROFILE_SAMPLES} samples per vertex "
            f"(got half_width_px={half_width_px!r}, sample_step_px={sample_step_px!r})"
        )


#: The Gaussian smoothing sigma may reach the image's longer side, and at
#: least this many pixels on small images (where any sigma is cheap).
#: Beyond the longer side ``L`` the result is a nearly constant image (the
#: reflect-extended image has period ``2 L``: its fundamental is damped
#: below 1 %), while the cost grows with sigma: the 1-D kernels have
#: ``2 * int(4 * sigma + 0.5) + 1`` taps, so the cap bounds the work at
#: about ``16 * max(L, 32)`` multiply-adds per pixel.
MIN_SIGMA_CAP_PX = 32.0


def smoothing_sigma(sigma: float, shape: tuple[int, ...], name: str = "sigma_px") -> None:
    """Refuse a (checked, positive) smoothing sigma wider than the image allows."""
    cap = max(float(max(shape[0], shape[1])), MIN_SIGMA_CAP_PX)
    if sigma > cap:
        raise ValueError(
            f"{name} must be at most the image's longer side ({cap:g} px for shape "
            f"{tuple(shape)}; at least {MIN_SIGMA_CAP_PX:g} px): a wider Gaussian gives a "
            f"nearly flat image at a cost that grows with sigma; got {sigma!r}"
        )


# ---------------------------------------------------------------------------
# Whole-call checks of the fitting stages (the reference runs the same ones)
# ---------------------------------------------------------------------------


def tukey_c_value(c: Any, name: str = "c") -> float:
    """The biweight cutoff: a finite number > 0."""
    value = real(c, name)
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"{name} must be a positive finite number; got {c!r}")
    return value


def _nonnegative_or_inf(value: Any, name: str) -> float:
    """A bound that may be +inf (no bound) but not NaN or negative."""
    out = real(value, name)
    if math.isnan(out) or out < 0.0:
        raise ValueError(f"{name} must be >= 0 (NaN refused), got {out!r}")
    return out


def no_information_covariance(n_params: int) -> FloatArray:
    """The all-``+inf`` covariance that marks an LM fit with no information
    (:ref:`contract-lm`; ``information_matrix_to_covariance`` itself
    returns zeros there)."""
    return np.full((n_params, n_params), np.inf)


def check_covariance_inputs(jacobian: Any, weights: Any, rcond: Any) -> tuple[FloatArray, FloatArray, float]:
    """Checks of :func:`information_matrix_to_covariance`."""
    jac = as_float_array(jacobian, "jacobian")
    if jac.ndim != 2:
        raise ValueError(f"jacobian must be 2-D; got ndim={jac.ndim}")
    w = as_float_array(weights, "weights")
    if w.ndim != 1 or w.shape[0] != jac.shape[0]:
        raise ValueError(
            "weights must be a 1-D vector matching the Jacobian rows; "
            f"got weights {w.shape}, jacobian {jac.shape}"
        )
    require_finite(jac, "jacobian")
    require_finite(w, "weights")
    if (w < 0.0).any():
        raise ValueError("weights must be non-negative")
    return jac, w, nonnegative_real(rcond, "rcond")


def min_support_fraction_value(value: Any) -> float:
    """The coarse search's support floor (:ref:`contract-coarse-scored`): a real number in ``[0, 1]`` (NaN refused)."""
    fraction = real(value, "min_support_fraction")
    if not 0.0 <= fraction <= 1.0:
        raise ValueError(f"min_support_fraction must be in [0, 1]; got {value!r}")
    return fraction


def _clip_window(mv: int, mu: int, shape: tuple[int, ...]) -> tuple[int, int]:
    """A shift of H or more rows moves every pixel of the image off it:
    margins beyond the image change no result of a mask search."""
    return min(mv, max(shape[0] - 1, 0)), min(mu, max(shape[1] - 1, 0))


def _clip_window_for(verts: FloatArray, mv: int, mu: int, shape: tuple[int, ...]) -> tuple[int, int]:
    """Margins beyond which no vertex (in the image or off it) can land in it:
    a shift larger than ``max |coordinate| + size`` changes no result."""
    if verts.shape[0] == 0:
        return min(mv, 0), min(mu, 0)
    if mv <= shape[0] + 1 and mu <= shape[1] + 1:
        return mv, mu  # within the bound whatever the vertices: no need to read them
    reach = np.abs(verts).max(axis=0)
    return (min(mv, int(reach[0]) + shape[0] + 1), min(mu, int(reach[1]) + shape[1] + 1))


def check_coarse_inputs(
    edge_mask: Any, polyline_mask: Any, search_window_vu: Any, min_support_fraction: Any = 0.0
) -> tuple[np.ndarray, NDArray[np.bool_], int, int, float]:
    """Checks of ``coarse_ncc_search[_scored]`` in the contract's order (:ref:`contract-coarse-scored`).

    Returns the edge mask (bool when its values are 0/1, else its float64
    values, which the overlap sums), the polyline mask as bool, the window
    clipped to the image, and the support fraction.
    """
    e = np.asarray(edge_mask)
    p = np.asarray(polyline_mask)
    if e.ndim != 2 or p.ndim != 2:
        raise ValueError(
            f"edge_mask and polyline_mask must be 2-D; got ndims {e.ndim}, {p.ndim}"
        )
    if e.shape != p.shape:
        raise ValueError(f"shape mismatch: edge_mask {e.shape} vs polyline_mask {p.shape}")
    mv, mu = search_window(search_window_vu)
    fraction = min_support_fraction_value(min_support_fraction)
    edge = mask_values(e, "edge_mask")
    poly = mask2d(p, "polyline_mask")
    mv, mu = _clip_window(mv, mu, e.shape)
    return edge, poly, mv, mu, fraction


#: Bounds on a vertex scan's work after its window is clipped: at most this
#: many shifts, and at most this many (shift row or column) x vertex table
#: entries (the basin scan's axis tables, ~17 bytes each). Far beyond any
#: real search (a +-50 window over 20,000 vertices is 2e6 entries); they keep
#: a polyline thrown far off the frame with a huge window from running for
#: hours or exhausting memory.
MAX_SCAN_SHIFTS = 1 << 26
MAX_SCAN_TABLE = 1 << 26


def _check_scan_size(mv: int, mu: int, n_vertices: int) -> None:
    shifts = (2 * mv + 1) * (2 * mu + 1)
    lines = 2 * mv + 2 * mu + 2
    table = lines * n_vertices
    # Name the figure over its cap (both, if both are): the other one is no
    # help to a caller deciding what to shrink.
    over = []
    if shifts > MAX_SCAN_SHIFTS:
        over.append(f"{shifts} shifts (at most {MAX_SCAN_SHIFTS})")
    if table > MAX_SCAN_TABLE:
        over.append(
            f"{table} shift-vertex pairs per axis ({lines} shift rows and columns x "
            f"{n_vertices} vertices; at most {MAX_SCAN_TABLE})"
        )
    if over:
        raise ValueError(
            f"search_window_vu is too large for this polyline: {' and '.join(over)}"
        )


class PolaritySearchArgs(NamedTuple):
    """Validated arguments of ``coarse_polarity_search_scored``."""

    edge: NDArray[np.bool_]
    gradient: FloatArray
    vertices: FloatArray
    normals: FloatArray
    mv: int
    mu: int
    fraction: float


def check_polarity_search_inputs(
    edge_mask: Any, image_gradient_vu: Any, vertices_vu: Any, normals_vu: Any,
    search_window_vu: Any, min_support_fraction: Any,
) -> PolaritySearchArgs:
    """Checks of ``coarse_polarity_search_scored`` in the contract's order (:ref:`contract-polarity-search`).

    The gradient may hold NaN (such a vertex's weight, and its shift's
    score, is NaN, which never wins); vertices and normals must be finite.
    """
    e = np.asarray(edge_mask)
    if e.ndim != 2:
        raise ValueError(f"edge_mask must be 2-D; got ndim={e.ndim}")
    grad = as_float_array(image_gradient_vu, "image_gradient_vu")
    if grad.ndim != 3 or grad.shape[2] != 2:
        raise ValueError(f"image_gradient_vu must have shape (H, W, 2); got {grad.shape}")
    if grad.shape[:2] != e.shape:
        raise ValueError(
            f"shape mismatch: edge_mask {e.shape} vs image_gradient_vu {grad.shape[:2]}"
        )
    verts = vertices(vertices_vu, "vertices_vu")
    norms = normals(normals_vu, verts.shape[0])
    mv, mu = search_window(search_window_vu)
    fraction = min_support_fraction_value(min_support_fraction)
    mv, mu = _clip_window_for(verts, mv, mu, e.shape)
    _check_scan_size(mv, mu, verts.shape[0])
    return PolaritySearchArgs(mask2d(e, "edge_mask"), grad, verts, norms, mv, mu, fraction)


class BasinArgs(NamedTuple):
    """Validated arguments of ``find_secondary_dt_minimum``."""

    dt: FloatArray
    vertices: FloatArray
    converged: tuple[float, float]
    mv: int
    mu: int
    exclude_radius: float
    fraction: float


def check_basin_inputs(
    image_edge_dt: Any, vertices_vu: Any, converged_offset_vu: Any, search_window_vu: Any,
    exclude_radius_px: Any, min_support_fraction: Any,
) -> BasinArgs:
    """Checks of ``find_secondary_dt_minimum`` (the reference checks nothing:
    what it accepts gives the same result here; non-finite or mis-shaped input
    is refused naming the argument). Margins are ``int()`` of the window
    entries, as the contract says (:ref:`contract-basin`); a negative one scans nothing."""
    dt = image2d(image_edge_dt, "image_edge_dt")
    verts = vertices(vertices_vu, "vertices_vu")
    converged = pair(converged_offset_vu, "converged_offset_vu")
    wv, wu = pair(search_window_vu, "search_window_vu")
    radius = finite_real(exclude_radius_px, "exclude_radius_px")
    fraction = min_support_fraction_value(min_support_fraction)
    # int() as the reference takes it, after bounding what no vertex can use
    mv, mu = (int(max(min(m, float(1 << 53)), -1.0)) for m in (wv, wu))
    if mv >= 0 and mu >= 0:
        mv, mu = _clip_window_for(verts, mv, mu, dt.shape)
        _check_scan_size(mv, mu, verts.shape[0])
    return BasinArgs(dt, verts, converged, mv, mu, radius, fraction)


def _pose_keywords(
    verts: FloatArray, kw: Mapping[str, Any], fit_rotation: bool, centroid: tuple[float, float],
) -> tuple[tuple[float, float], float, tuple[float, float], float]:
    """:func:`pose` of the keywords LM and the ridge polish share."""
    return pose(
        verts,
        fit_rotation=fit_rotation,
        pivot_vu=kw["pivot_vu"],
        pivot_distance_px=kw["pivot_distance_px"],
        initial_offset_vu=kw["initial_offset_vu"],
        initial_rotation_rad=kw["initial_rotation_rad"],
        centroid=centroid,
    )


class LMArgs(NamedTuple):
    """Validated, converted arguments of ``lm_subpixel_refine``."""

    vertices: FloatArray
    normals: FloatArray
    sigmas: FloatArray
    dt: FloatArray
    gradient: FloatArray | None
    offset: tuple[float, float]
    rotation: float
    fit_rotation: bool
    pivot: tuple[float, float]
    pivot_distance: float
    use_polarity: bool
    max_iterations: int
    damping: float
    step_tolerance: float
    tukey_c: float
    pinvh_rcond: float
    trust_region_px: float | None
    tikhonov_alpha: float
    final_gradient_ridge: bool


def check_lm_inputs(kw: Mapping[str, Any]) -> LMArgs:
    """Check ``lm_subpixel_refine``'s keywords in the contract's order (:ref:`contract-errors`)."""
    verts, norms, sig, centroid = polyline(
        kw["vertices_vu"], kw["normals_vu"], kw["sigma_normal_per_vertex_px"]
    )
    dt = image2d(kw["image_edge_dt"], "image_edge_dt")
    fit_rotation = bool(kw["fit_rotation"])
    offset, rotation, pivot, distance = _pose_keywords(verts, kw, fit_rotation, centroid)
    has_gradient = kw["image_gradient_vu"] is not None
    if kw["final_gradient_ridge"] and not has_gradient:
        raise ValueError("final_gradient_ridge=True requires image_gradient_vu")
    if kw["use_polarity"] and not has_gradient:
        raise ValueError("use_polarity=True requires image_gradient_vu")
    grad = gradient(kw["image_gradient_vu"]) if has_gradient else None
    return LMArgs(
        vertices=verts, normals=norms, sigmas=sig, dt=dt, gradient=grad, offset=offset,
        rotation=rotation, fit_rotation=fit_rotation, pivot=pivot, pivot_distance=distance,
        **lm_options(kw),
    )


def lm_options(kw: Mapping[str, Any]) -> dict[str, Any]:
    """The LM's options among ``kw`` (``lm_subpixel_refine``'s keywords from
    ``use_polarity`` on), checked in the contract's order, as :class:`LMArgs`
    fields: the last of :func:`check_lm_inputs`' checks, and the part of them
    that needs no polyline and no image."""
    trust = kw["trust_region_px"]
    return {
        "use_polarity": bool(kw["use_polarity"]),
        "max_iterations": iteration_count(kw["max_iterations"], "max_iterations"),
        "damping": nonnegative_real(kw["damping"], "damping"),
        "step_tolerance": nonnegative_real(kw["step_tolerance_px"], "step_tolerance_px"),
        "tukey_c": tukey_c_value(kw["tukey_c"], "tukey_c"),
        "pinvh_rcond": nonnegative_real(kw["pinvh_rcond"], "pinvh_rcond"),
        "trust_region_px": None if trust is None else _nonnegative_or_inf(trust,
                                                                          "trust_region_px"),
        "tikhonov_alpha": nonnegative_real(kw["tikhonov_alpha"], "tikhonov_alpha"),
        "final_gradient_ridge": bool(kw["final_gradient_ridge"]),
    }


class RidgeArgs(NamedTuple):
    """Validated, converted arguments of ``gradient_ridge_refine``."""

    vertices: FloatArray
    normals: FloatArray
    sigmas: FloatArray
    magnitude: FloatArray
    offset: tuple[float, float]
    rotation: float
    fit_rotation: bool
    pivot: tuple[float, float]
    pivot_distance: float
    weight_mask: FloatArray
    max_iterations: int
    step_tolerance: float
    tukey_c: float
    half_width: float
    sample_step: float
    max_total_displacement: float


def check_ridge_inputs(kw: Mapping[str, Any]) -> RidgeArgs:
    """Check ``gradient_ridge_refine``'s keywords (LM's order for the shared ones)."""
    verts, norms, sig, centroid = polyline(
        kw["vertices_vu"], kw["normals_vu"], kw["sigma_normal_per_vertex_px"]
    )
    magnitude = image2d(kw["gradient_magnitude"], "gradient_magnitude")
    fit_rotation = bool(kw["fit_rotation"])
    offset, rotation, pivot, distance = _pose_keywords(verts, kw, fit_rotation, centroid)
    half_width = positive_real(kw["half_width_px"], "half_width_px")
    sample_step = positive_real(kw["sample_step_px"], "sample_step_px")
    ratio = half_width / sample_step
    if math.isfinite(ratio) and round(ratio) < 1:
        raise ValueError(
            "half_width_px / sample_step_px must round to at least 1: the profile "
            f"needs three samples (got {half_width!r} and {sample_step!r})"
        )
    ridge_profile_size(half_width, sample_step)
    return RidgeArgs(
        vertices=verts,
        normals=norms,
        sigmas=sig,
        magnitude=magnitude,
        offset=offset,
        rotation=rotation,
        fit_rotation=fit_rotation,
        pivot=pivot,
        pivot_distance=distance,
        weight_mask=weight_mask(kw["weight_mask"], verts.shape[0]),
        max_iterations=iteration_count(kw["max_iterations"], "max_iterations"),
        step_tolerance=nonnegative_real(kw["step_tolerance_px"], "step_tolerance_px"),
        tukey_c=tukey_c_value(kw["tukey_c"], "tukey_c"),
        half_width=half_width,
        sample_step=sample_step,
        max_total_displacement=_nonnegative_or_inf(
            kw["max_total_displacement_px"], "max_total_displacement_px"
        ),
    )


# ---------------------------------------------------------------------------
# The image side (:ref:`contract-surface` and :ref:`contract-image`)
# ---------------------------------------------------------------------------


def resolve_config(config: Any) -> ImageDerivativesConfig:
    """``None`` means the defaults; anything else must be the config type."""
    if config is None:
        return ImageDerivativesConfig()
    if not isinstance(config, ImageDerivativesConfig):
        raise TypeError(
            f"config must be an ImageDerivativesConfig or None, got {type(config).__name__}"
        )
    return config


def check_image(image_ext: Any, name: str = "image_ext") -> FloatArray:
    """A non-empty, finite 2-D image as C-contiguous float64 (``name``: the
    argument's name in the messages, the drop-in functions' ``image_ext``)."""
    arr = np.asarray(image_ext)
    if arr.ndim != 2:
        raise TypeError(f"{name} must be 2-D; got ndim={arr.ndim}")
    if arr.dtype.kind not in "biuf":
        raise TypeError(f"{name} must be a real numeric array, got dtype {arr.dtype}")
    if arr.size == 0:
        raise ValueError(f"{name} must not be empty, got shape {arr.shape}")
    out = np.ascontiguousarray(arr, dtype=np.float64)
    if not np.isfinite(out).all():
        raise ValueError(
            f"{name} must contain only finite values; NaN or +/-inf would propagate "
            "through gaussian_filter / sobel and poison every derivative downstream"
        )
    return readonly(out)


def check_sigma_px(sigma_px: Any) -> float:
    """The Gaussian sigma: finite and > 0."""
    try:
        value = real(sigma_px, "sigma_px")
    except TypeError as exc:
        raise ValueError(f"sigma_px must be a finite positive number; got {sigma_px!r}") from exc
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"sigma_px must be a finite positive number; got {sigma_px!r}")
    return value


def check_noise_sigma(image_noise_sigma: Any, name: str = "image_noise_sigma") -> float:
    """The image noise sigma: finite and >= 0 (``name``: the argument's name
    in the messages, the drop-in functions' ``image_noise_sigma``)."""
    try:
        value = real(image_noise_sigma, name)
    except TypeError as exc:
        raise ValueError(
            f"{name} must be finite and >= 0; got {image_noise_sigma!r}"
        ) from exc
    if not (math.isfinite(value) and value >= 0.0):
        raise ValueError(f"{name} must be finite and >= 0; got {value!r}")
    return value


def positive_int(value: Any, name: str) -> int:
    """A positive int (bool refused); ValueError naming ``name`` otherwise."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name} must be a positive int; got {value!r}")
    return int(value)


def check_seeds(seeds: Any) -> int:
    """The number of starts of a multi-start fit: a positive int."""
    return positive_int(seeds, "seeds")


# ---------------------------------------------------------------------------
# The batch functions' own arguments (fit_many, fit_images, map_ordered)
# ---------------------------------------------------------------------------

#: The accepted values of ``errors``: raise the first error, or collect each.
ERROR_MODES = ("raise", "collect")


def workers(value: Any) -> int:
    """A worker count: an int >= 1 (bool refused)."""
    if not _is_int(value):
        raise TypeError(f"workers must be an int >= 1, got {type(value).__name__}")
    if value < 1:
        raise ValueError(f"workers must be >= 1, got {value}")
    return int(value)


def int_at_least(value: Any, name: str, low: int = 1) -> int:
    """An int (bool refused) of at least ``low``; any fault is one ValueError
    (the campaign's settings: ``flush_items``, ``frames`` ...)."""
    if not _is_int(value) or value < low:
        raise ValueError(f"{name} must be an int >= {low}, got {value!r}")
    return int(value)


def collect_errors(errors: Any) -> bool:
    """Whether ``errors`` (one of :data:`ERROR_MODES`) asks to collect (else raise)."""
    if not isinstance(errors, str) or errors not in ERROR_MODES:
        raise ValueError(f"errors must be one of {ERROR_MODES}, got {errors!r}")
    return errors == "collect"


def progress_callback(progress: Any) -> Callable[[int, int], Any] | bool | None:
    """``progress``: a callable ``progress(done, total)``, True (a tqdm bar) or None."""
    if progress is None or isinstance(progress, bool) or callable(progress):
        return progress
    raise TypeError(
        f"progress must be a callable progress(done, total), True (a tqdm bar) or None, "
        f"got {type(progress).__name__}"
    )


# ---------------------------------------------------------------------------
# Fields of a record written as text or JSON (the campaign manifest's)
#
# ``name`` says where the value was read (``"manifest m.jsonl line 3:
# noise_sigma"``), so each message names the field and its line as written.
# ---------------------------------------------------------------------------


def blank(value: Any) -> bool:
    """No value: absent (None) or an empty CSV cell."""
    return value is None or (isinstance(value, str) and not value.strip())


def known_names(given: Iterable[str], accepted: Sequence[str], what: str, where: str = "") -> None:
    """Refuse names outside ``accepted``, listing the unknown ones and the accepted ones.

    The message reads ``"{where}: unknown {what}(s) 'a', 'b'; accepted: ..."``.
    """
    unknown = sorted(set(given) - set(accepted))
    if unknown:
        raise ValueError(f"{where + ': ' if where else ''}unknown {what}(s) "
                         f"{', '.join(map(repr, unknown))}; accepted: {', '.join(accepted)}")


def path_text(value: Any, name: str) -> str:
    """A non-empty path, stripped of surrounding blanks."""
    if not isinstance(value, str) or not value.strip():
        raise ValueError(f"{name} must be a non-empty path")
    return value.strip()


def path_list(value: Any, name: str, separator: str) -> tuple[str, ...]:
    """One or more non-empty paths: a list, or text separated by ``separator``."""
    paths: Sequence[Any]
    if value is None:
        raise ValueError(f"{name} is missing")
    if isinstance(value, str):
        paths = [p.strip() for p in value.split(separator)]
    elif isinstance(value, (list, tuple)):
        paths = value
    else:
        raise ValueError(f"{name} must be a path or a list of paths")
    if not paths or any(not isinstance(p, str) or not p.strip() for p in paths):
        raise ValueError(f"{name} must hold one or more non-empty paths")
    return tuple(p.strip() for p in paths)


def flag(value: Any, name: str) -> bool:
    """A yes/no field: a JSON bool, or ``true``/``false`` in a CSV cell; False when blank."""
    if blank(value):
        return False
    if isinstance(value, bool):
        return value
    if isinstance(value, str) and value.strip().lower() in ("true", "false"):
        return value.strip().lower() == "true"
    raise ValueError(f"{name} must be true or false, got {value!r}")


def label(value: Any, name: str, default: str) -> str:
    """A name (a string, or an int written as one); ``default`` when blank."""
    if blank(value):
        return default
    if not isinstance(value, (str, int)) or isinstance(value, bool):
        raise ValueError(f"{name} must be a string, got {type(value).__name__}")
    return str(value).strip()


def optional_nonnegative(value: Any, name: str) -> float | None:
    """None when blank, else a finite number >= 0 (text is read as a number)."""
    if blank(value):
        return None
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(out) or out < 0.0:
        raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
    return out


def json_object(value: Any, name: str) -> dict[str, Any]:
    """A mapping, or JSON text of an object; empty when blank."""
    if blank(value):
        return {}
    if isinstance(value, str):
        try:
            value = json.loads(value)
        except json.JSONDecodeError as exc:
            raise ValueError(f"{name} is not a JSON object: {exc.msg}") from None
    if not isinstance(value, Mapping):
        raise ValueError(f"{name} must be an object, got {type(value).__name__}")
    return dict(value)


def json_list(value: Any, length: int, name: str, per: str) -> list[Any]:
    """A list of ``length`` entries (one per ``per``), or JSON text of one; empty when blank."""
    if blank(value):
        return []
    if isinstance(value, str):
        try:
            value = json.loads(value)
        except json.JSONDecodeError as exc:
            raise ValueError(f"{name} is not a JSON list: {exc.msg}") from None
    if not isinstance(value, (list, tuple)) or len(value) != length:
        raise ValueError(f"{name} must be a list of {length} entries (one per {per}, "
                         "null for none)")
    return list(value)


def keywords(value: Any, name: str, keys: Sequence[str], required: Sequence[str]) -> dict[str, Any]:
    """An object of keyword arguments: only ``keys``, all of ``required``."""
    if not isinstance(value, Mapping):
        raise ValueError(f"{name} must be an object or null")
    unknown = sorted(set(value) - set(keys))
    missing = [key for key in required if key not in value]
    if unknown or missing:
        raise ValueError(
            f"{name}: "
            + (f"unknown key(s) {', '.join(map(repr, unknown))}; " if unknown else "")
            + (f"missing {', '.join(missing)}; " if missing else "")
            + f"keys: {', '.join(keys)}"
        )
    return dict(value)
