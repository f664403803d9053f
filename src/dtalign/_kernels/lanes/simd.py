"""Four vertices at a time: a small vector type for the LM's per-vertex loops.

Why this exists: the LM loop's cost is bilinear samples of the DT, five per
vertex per iteration, then weights and sums over the vertices; LLVM does
not vectorise these by itself (each sample is a gather from four
data-dependent addresses, which AVX2 machines do not gather quickly, and
the sums are ordered reductions). So the vector code is written out.

:data:`float4` is a Numba type whose value is an LLVM ``<4 x double>``, with
``+ - * /`` and a few named operations (loads and stores of four
consecutive elements, the Tukey weight, a select, lane-wise sums). Every
lane is computed by exactly the IEEE operation the scalar code performs, in
the same order, so a lane is bit-identical to the scalar result.
:mod:`.simd_image` reads images on this type.
"""

from __future__ import annotations

import operator

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic, models, overload, register_model

from ..._jit import inline_kernel

_F64 = ir.DoubleType()
_I32 = ir.IntType(32)
_I64 = ir.IntType(64)
_V4D = ir.VectorType(_F64, 4)
_V4I = ir.VectorType(_I32, 4)
_V2D = ir.VectorType(_F64, 2)
#: The one pointer type of opaque-pointer IR (llvmlite drops typed pointers).
_PTR = ir.PointerType()

#: Largest number of DT elements whose cell indices fit 32-bit lanes.
MAX_ELEMENTS = 2**31 - 1


class Float4Type(types.Type):  # type: ignore[misc]
    """Four float64 lanes held as one LLVM vector."""

    def __init__(self) -> None:
        super().__init__(name="float4")


float4 = Float4Type()


@register_model(Float4Type)
class _Float4Model(models.PrimitiveModel):  # type: ignore[misc]
    def __init__(self, dmm, fe_type):  # type: ignore[no-untyped-def]
        super().__init__(dmm, fe_type, _V4D)


def _k(k: int) -> ir.Constant:
    return ir.Constant(_I32, k)


def _vector(builder, values, vtype):  # type: ignore[no-untyped-def]
    out = ir.Constant(vtype, ir.Undefined)
    for k, x in enumerate(values):
        out = builder.insert_element(out, x, _k(k))
    return out


def _contiguous(arr, ndim):  # type: ignore[no-untyped-def]
    """Whether Numba types ``arr`` as a C-contiguous float64 array of ``ndim`` dimensions:
    the vector loads read consecutive elements, so any other layout must not compile."""
    return (
        isinstance(arr, types.Array) and arr.ndim == ndim and arr.layout == "C"
        and arr.dtype == types.float64
    )


def _align(arrtype):  # type: ignore[no-untyped-def]
    """The alignment a load from ``arrtype``'s data may assume: 8 bytes for
    float64 arrays NumPy aligned, 1 for unaligned views (of a byte buffer)."""
    return arrtype.dtype.bitwidth // 8 if arrtype.aligned else 1


def _opaque(builder, ptr):  # type: ignore[no-untyped-def]
    """``ptr`` as an opaque pointer: Numba still hands out typed ones, and the
    loads and stores below name the type they access instead (a no-op cast)."""
    return ptr if ptr.type.is_opaque else builder.bitcast(ptr, _PTR)


def _address(builder, base, index, etype=_F64):  # type: ignore[no-untyped-def]
    """The address of element ``index`` of type ``etype`` from ``base``."""
    return builder.gep(_opaque(builder, base), [index], inbounds=True, source_etype=etype)


def _store(builder, value, ptr, align):  # type: ignore[no-untyped-def]
    """``*ptr = value`` for a vector ``value``, through an opaque pointer.

    llvmlite's ``store`` insists that a typed pointer (which Numba still
    hands out) point to the value's type, which would take a typed-pointer
    cast; ``llvm.masked.store`` takes an opaque ``ptr``, and LLVM folds its
    all-true mask into an ordinary store.
    """
    lanes = value.type.count
    name = f"llvm.masked.store.v{lanes}{value.type.element.intrinsic_name}.p0"
    mask = ir.Constant(ir.VectorType(ir.IntType(1), lanes), [1] * lanes)
    fn = cgutils.get_or_insert_function(
        builder.module,
        ir.FunctionType(ir.VoidType(), [value.type, _PTR, _I32, mask.type]),
        name,
    )
    builder.call(fn, [value, ptr, _k(align), mask])


def _intrinsic_call(builder, name, vtype, *args):  # type: ignore[no-untyped-def]
    fn = cgutils.get_or_insert_function(
        builder.module, ir.FunctionType(vtype, [a.type for a in args]), name
    )
    return builder.call(fn, list(args))


# -- the vector type's operations -------------------------------------------------


def _binary(op_name):  # type: ignore[no-untyped-def]
    @intrinsic
    def impl(typingctx, a, b):  # type: ignore[no-untyped-def]
        if a is not float4 or b is not float4:
            return None

        def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
            return getattr(builder, op_name)(args[0], args[1])

        return float4(float4, float4), codegen

    return impl


_fadd = _binary("fadd")
_fsub = _binary("fsub")
_fmul = _binary("fmul")
_fdiv = _binary("fdiv")

for _op, _impl in (
    (operator.add, _fadd), (operator.iadd, _fadd), (operator.sub, _fsub),
    (operator.isub, _fsub), (operator.mul, _fmul), (operator.imul, _fmul),
    (operator.truediv, _fdiv), (operator.itruediv, _fdiv),
):
    def _make(impl):  # type: ignore[no-untyped-def]
        def ov(a, b):  # type: ignore[no-untyped-def]
            if a is float4 and b is float4:
                return lambda a, b: impl(a, b)
            return None

        return ov

    overload(_op)(_make(_impl))


@intrinsic
def splat(typingctx, x):  # type: ignore[no-untyped-def]
    """``x`` in all four lanes."""
    if not isinstance(x, types.Float):
        return None

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        return _vector(builder, [args[0]] * 4, _V4D)

    return float4(types.float64), codegen


@intrinsic
def load4(typingctx, arr, i):  # type: ignore[no-untyped-def]
    """``arr[i:i + 4]`` of a C-contiguous 1-D float64 array."""
    if not _contiguous(arr, 1):
        return None

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        a = context.make_array(signature.args[0])(context, builder, args[0])
        return builder.load(_address(builder, a.data, args[1]), typ=_V4D,
                            align=_align(signature.args[0]))

    return float4(arr, types.int64), codegen


@intrinsic
def store4(typingctx, arr, i, x):  # type: ignore[no-untyped-def]
    """``arr[i:i + 4] = x`` for a C-contiguous 1-D float64 array."""
    if not (_contiguous(arr, 1) and x is float4):
        return None

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        a = context.make_array(signature.args[0])(context, builder, args[0])
        _store(builder, args[2], _address(builder, a.data, args[1]), _align(signature.args[0]))
        return context.get_dummy_value()

    return types.none(arr, types.int64, float4), codegen


@intrinsic
def hsum(typingctx, x):  # type: ignore[no-untyped-def]
    """``(x0 + x1) + (x2 + x3)``: the lanes of a lane-wise sum, combined."""
    if x is not float4:
        return None

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        e = [builder.extract_element(args[0], _k(k)) for k in range(4)]
        return builder.fadd(builder.fadd(e[0], e[1]), builder.fadd(e[2], e[3]))

    return types.float64(float4), codegen


@intrinsic
def sqrt4(typingctx, x):  # type: ignore[no-untyped-def]
    """Correctly rounded square root of every lane (as ``np.sqrt``)."""
    if x is not float4:
        return None

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        return _intrinsic_call(builder, "llvm.sqrt.v4f64", _V4D, args[0])

    return float4(float4), codegen


@intrinsic
def tukey4(typingctx, x, c):  # type: ignore[no-untyped-def]
    """:func:`dtalign._kernels.robust.tukey` of every lane."""
    if x is not float4:
        return None

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        s = builder.fdiv(args[0], _vector(builder, [args[1]] * 4, _V4D))
        t = builder.fsub(ir.Constant(_V4D, [1.0] * 4), builder.fmul(s, s))
        inside = builder.fcmp_ordered(
            "<=", _intrinsic_call(builder, "llvm.fabs.v4f64", _V4D, s), ir.Constant(_V4D, [1.0] * 4)
        )
        return builder.select(inside, builder.fmul(t, t), ir.Constant(_V4D, [0.0] * 4))

    return float4(float4, types.float64), codegen


@intrinsic
def where_nonzero(typingctx, p, x, y):  # type: ignore[no-untyped-def]
    """Per lane, ``x if p != 0.0 else y``."""
    if p is not float4 or x is not float4 or y is not float4:
        return None

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        nz = builder.fcmp_unordered("!=", args[0], ir.Constant(_V4D, [0.0] * 4))
        return builder.select(nz, args[1], args[2])

    return float4(float4, float4, float4), codegen


@intrinsic
def positive_ones(typingctx, x):  # type: ignore[no-untyped-def]
    """Per lane, 1.0 if ``x > 0`` else 0.0 (a count of positive lanes, summed)."""
    if x is not float4:
        return None

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        pos = builder.fcmp_ordered(">", args[0], ir.Constant(_V4D, [0.0] * 4))
        return builder.select(pos, ir.Constant(_V4D, [1.0] * 4), ir.Constant(_V4D, [0.0] * 4))

    return float4(float4), codegen


def _mask_test(name, pred, ordered, reduce_all):  # type: ignore[no-untyped-def]
    @intrinsic
    def impl(typingctx, x, y):  # type: ignore[no-untyped-def]
        if x is not float4 or y is not float4:
            return None

        def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
            cmp = builder.fcmp_ordered if ordered else builder.fcmp_unordered
            bits = builder.bitcast(cmp(pred, args[0], args[1]), ir.IntType(4))
            want = ir.Constant(ir.IntType(4), 15 if reduce_all else 0)
            op = "==" if reduce_all else "!="
            return builder.icmp_unsigned(op, bits, want)

        return types.boolean(float4, float4), codegen

    impl.__name__ = name
    return impl


#: Whether any lane of ``x`` is greater than the same lane of ``y`` (NaN is not).
any_greater = _mask_test("any_greater", ">", True, False)
#: Whether every lane of ``x`` equals the same lane of ``y`` (NaN does not).
_all_equal = _mask_test("_all_equal", "==", True, True)


@inline_kernel
def all_finite(x):
    """Whether every lane of ``x`` is finite (``x - x`` is NaN for NaN and inf)."""
    return _all_equal(x - x, splat(0.0))
