"""Result equality for the tests and the benchmark rows: batch results equal serial ones."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

__all__ = ["results_equal"]

#: The fields of a result that hold wall times, which :func:`results_equal` skips.
_WALL_TIMES = frozenset({"timings_s", "time_s"})


def results_equal(a: Any, b: Any) -> bool:
    """Whether two fit results are equal field by field (arrays bitwise, NaN == NaN).

    :class:`~dtalign.pipeline.PolylineFit` and
    :class:`~dtalign.LMRefineResult` compare by identity; this compares
    their contents, recursing into nested results and lists. ``timings_s``
    and a profile refinement's ``time_s`` are ignored (wall times differ
    between runs).

    Parameters
    ----------
    a, b : object
        Results, lists of results, arrays or plain values.

    Returns
    -------
    bool
    """
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(results_equal(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        x, y = np.asarray(a), np.asarray(b)
        return x.shape == y.shape and x.dtype == y.dtype and bool(
            np.array_equal(x, y, equal_nan=x.dtype.kind in "fc")
        )
    if dataclasses.is_dataclass(a) and not isinstance(a, type):
        if type(a) is not type(b):
            return False
        return all(
            results_equal(getattr(a, f.name), getattr(b, f.name))
            for f in dataclasses.fields(a)
            if f.name not in _WALL_TIMES
        )
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return bool(a == b)
