"""The one place where dtalign sets Numba compilation flags.

* On-disk cache: compiled machine code is written beside the source (or,
  when the package directory is read-only, to Numba's user-wide cache
  directory; ``NUMBA_CACHE_DIR`` overrides both), so a new process does not
  pay the compile time again. This is Numba's ``cache=True`` with
  :class:`dtalign._numba_cache.CheckedFunctionCache`: a damaged entry is a
  cache miss (recompiled and replaced), a read-only pre-warmed folder is
  read, and with no usable folder kernels compile in memory; each is logged
  on the ``dtalign`` logger (see ``docs/caching.rst``).
* ``nogil=True``: kernels release the GIL, so the public functions scale in
  a ``ThreadPoolExecutor``.
* ``fastmath=False``: every kernel's result is compared bit-for-bit or to
  1e-9 with the NumPy specification; reassociation would break that.
* ``error_model="numpy"``: a division by zero gives inf/nan as in NumPy
  instead of raising from inside a kernel (the wrappers validate first).

Nothing here touches Numba's global configuration (threading layer,
thread count): that belongs to the application. Kernels carry no explicit
signatures, so compilation is lazy and ``import dtalign`` stays fast.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, TypeVar

import numba
import numpy as np

from ._numba_cache import attach_cache

F = TypeVar("F", bound=Callable[..., Any])

JIT_OPTIONS: dict[str, Any] = {
    "nogil": True,
    "fastmath": False,
    "error_model": "numpy",
}


def kernel(fn: F) -> F:
    """Compile ``fn`` lazily with the project's Numba flags."""
    return _as_compiled(attach_cache(numba.njit(**JIT_OPTIONS)(fn)))


def inline_kernel(fn: F) -> F:
    """:func:`kernel`, inlined into its callers at Numba's IR level.

    For the few per-sample helpers of the hot loops (bilinear sampling,
    pose transform, magnitude lookup): LLVM's own inliner does not always
    take them, and a call per sample costs more than the sample.
    """
    return attach_cache(numba.njit(inline="always", **JIT_OPTIONS)(fn))  # type: ignore[no-any-return]


# -- kernels as Python (NUMBA_DISABLE_JIT=1) ---------------------------------
#
# With the JIT disabled, numba.njit returns the Python function itself, whose
# NumPy scalar arithmetic warns on a division by zero, an overflow or an
# invalid operation where the compiled code (error_model="numpy") silently
# gives inf or nan. Such a kernel runs under np.errstate(all="ignore"): the
# same values as compiled, and no warning the compiled code would not give.
# (Inline kernels are only called from kernels, inside that state.)


def _as_compiled(fn: F) -> F:
    if not numba.config.DISABLE_JIT:  # type: ignore[attr-defined]
        return fn

    @functools.wraps(fn)
    def run(*args: Any) -> Any:
        with np.errstate(all="ignore"):
            return fn(*args)

    return run  # type: ignore[return-value]
