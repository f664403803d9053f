"""The LM's four-lane fast path and its plain twin, behind one switch.

The LM spends its time in a few per-vertex loops (the DT and its central
differences at every vertex, the weights and the sums of the normal
equations), the polarity test, and the coarse search's mask scan. Each of
those kernels exists twice, with the same name and arguments:

* :mod:`.vector`: four vertices at a time on hand-written LLVM vector code
  (:mod:`.simd`, :mod:`.simd_image`) and a word-at-a-time mask scan
  (:mod:`.bits`), which is what makes the compiled LM fast;
* :mod:`.plain`: one vertex (one byte) at a time in ordinary Numba/Python,
  with the same operations in the same order, so every result has the same
  bits (``tests/test_lanes_twin.py`` runs whole fits both ways).

:data:`VECTOR` is the switch: the rest of the package imports these names
from here and gets the vector kernels when Numba compiles normally, and the
plain ones under ``NUMBA_DISABLE_JIT=1`` (LLVM intrinsics cannot run as
Python) and under ``NUMBA_BOUNDSCHECK=1`` (a vector load is one wide read
that bounds checking cannot see into; the plain code's reads are indexed).
It is decided once, at import, from Numba's own configuration only, so that
code cached for one choice is never loaded for the other (Numba's cache key
does not cover a callee's identity; the bounds-checked pass uses a fresh
cache directory, and nothing is cached with the JIT disabled). Tests take
either path explicitly from :mod:`.vector` and :mod:`.plain`.
"""

from __future__ import annotations

from types import ModuleType

from numba.core import config

from . import plain
from .plain import EPS_R, EPS_T, PENALTY

#: Whether the package's kernels run the four-lane vector code (see above).
VECTOR: bool = not (config.DISABLE_JIT or config.BOUNDSCHECK)  # type: ignore[attr-defined]

_twin: ModuleType = plain
if VECTOR:
    from . import vector

    _twin = vector

# the kernels of the chosen twin, under the names both twins give them
fill = _twin.fill
lane_cost = _twin.lane_cost
lane_sums = _twin.lane_sums
polarity = _twin.polarity
sample_state = _twin.sample_state
staging_buffers = _twin.staging_buffers
summary_lanes = _twin.summary_lanes

__all__ = [
    "EPS_R", "EPS_T", "PENALTY", "VECTOR", "fill", "lane_cost", "lane_sums", "polarity",
    "sample_state", "staging_buffers", "summary_lanes",
]
