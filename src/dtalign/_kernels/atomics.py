"""Atomic operations on int64 array elements, for threads sharing one work list.

:func:`dtalign.batch.fit_many` runs the same compiled loop in several
threads over one list of polylines: each thread takes the next index with
:func:`fetch_add` (so a faster thread simply takes more), and the first
failing index is kept with :func:`fetch_min`; a finished polyline is flagged
with :func:`store`, which the wrapping thread reads with :func:`load`.
Sequentially consistent LLVM ``atomicrmw``, atomic loads and stores; the
arrays are C-contiguous int64.
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.extending import intrinsic

_I64 = ir.IntType(64)


def _int64_vector(arr):  # type: ignore[no-untyped-def]
    return isinstance(arr, types.Array) and arr.ndim == 1 and arr.dtype == types.int64


def _element(context, builder, arrtype, arr, i):  # type: ignore[no-untyped-def]
    a = context.make_array(arrtype)(context, builder, arr)
    return builder.gep(a.data, [i], inbounds=True)


def _rmw(op):  # type: ignore[no-untyped-def]
    @intrinsic
    def impl(typingctx, arr, i, value):  # type: ignore[no-untyped-def]
        if not _int64_vector(arr):
            return None

        def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
            ptr = _element(context, builder, signature.args[0], args[0], args[1])
            return builder.atomic_rmw(op, ptr, args[2], "seq_cst")

        return types.int64(arr, types.int64, types.int64), codegen

    return impl


#: ``arr[i] += value`` atomically; returns the old ``arr[i]``.
fetch_add = _rmw("add")
#: ``arr[i] = min(arr[i], value)`` atomically (signed); returns the old ``arr[i]``.
fetch_min = _rmw("min")


@intrinsic
def load(typingctx, arr, i):  # type: ignore[no-untyped-def]
    """``arr[i]``, read atomically (never cached in a register across a loop)."""
    if not _int64_vector(arr):
        return None

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        ptr = _element(context, builder, signature.args[0], args[0], args[1])
        return builder.load_atomic(ptr, "seq_cst", 8)

    return types.int64(arr, types.int64), codegen


@intrinsic
def store(typingctx, arr, i, value):  # type: ignore[no-untyped-def]
    """``arr[i] = value``, written atomically: every write this thread made
    before it is visible to a thread that then :func:`load` s the value."""
    if not _int64_vector(arr):
        return None

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        ptr = _element(context, builder, signature.args[0], args[0], args[1])
        builder.store_atomic(args[2], ptr, "seq_cst", 8)
        return context.get_dummy_value()

    return types.none(arr, types.int64, types.int64), codegen
