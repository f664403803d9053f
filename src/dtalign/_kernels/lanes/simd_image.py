"""Image reads four vertices at a time, on :mod:`.simd`'s vector type.

* :func:`positions4`, :func:`bilinear4` and :func:`state4` are the pose
  transform, :func:`dtalign._kernels.sampling.bilinear`, and the sample
  with the central differences of the translation Jacobian, for four
  consecutive vertices.
  The four corners of a cell are read as two 16-byte loads (the corner
  pairs ``(v0, u0), (v0, u0 + 1)`` and the row below are adjacent in a
  C-contiguous array): half the loads, and no per-corner index work. That
  needs every cell of the four vertices to lie inside the image (no
  clamped corner); otherwise the samples are read corner by corner, with
  the clamped indices, as the scalar code reads them.
* :func:`stage_state` / :func:`finish_state` split :func:`state4` in two
  (see below).
* :func:`polarity4` is :func:`dtalign._kernels.robust.polarity` of four
  vertices.

Every lane is bit-identical to the scalar code's result (same operations,
same order). Preconditions (the callers check them once): ``dt`` and the
gradient image are C-contiguous float64 with fewer than
:data:`~.simd.MAX_ELEMENTS` elements, ``dt`` with at least two rows and
columns; ``pts`` and ``nrm`` are C-contiguous ``(n, 2)`` float64 arrays and
``i + 3 < n``.
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from .simd import (
    _F64,
    _I32,
    _I64,
    _V2D,
    _V4D,
    _V4I,
    _address,
    _align,
    _contiguous,
    _intrinsic_call,
    _k,
    _store,
    _vector,
    float4,
)


def _pairs_at(b, base, lanes, align):  # type: ignore[no-untyped-def]
    """``(x[i], x[i + 1])`` at the four lane indices ``i`` of a float64 buffer,
    as two vectors, from four 16-byte loads."""
    loads = [b.load(_address(b, base, i), typ=_V2D, align=align) for i in lanes]
    x = b.shuffle_vector(loads[0], loads[1], ir.Constant(_V4I, [0, 1, 2, 3]))
    y = b.shuffle_vector(loads[2], loads[3], ir.Constant(_V4I, [0, 1, 2, 3]))
    return (b.shuffle_vector(x, y, ir.Constant(_V4I, [0, 2, 4, 6])),
            b.shuffle_vector(x, y, ir.Constant(_V4I, [1, 3, 5, 7])))


def _lanes_of_pairs(context, b, arrtype, value, i):  # type: ignore[no-untyped-def]
    """Columns 0 and 1 of rows ``i..i+3`` of an ``(n, 2)`` C array, one 64-byte load."""
    a = context.make_array(arrtype)(context, b, value)
    p = _address(b, a.data, b.mul(i, ir.Constant(_I64, 2)))
    ld = b.load(p, typ=ir.VectorType(_F64, 8), align=_align(arrtype))
    return (b.shuffle_vector(ld, ld, ir.Constant(_V4I, [0, 2, 4, 6])),
            b.shuffle_vector(ld, ld, ir.Constant(_V4I, [1, 3, 5, 7])))


class _Image:
    """IR for cells of a 2-D C-contiguous float64 array, four lanes at a time."""

    def __init__(self, context, builder, arrtype, value):  # type: ignore[no-untyped-def]
        self.b = builder
        a = context.make_array(arrtype)(context, builder, value)
        h, w = cgutils.unpack_tuple(builder, a.shape, 2)
        self.data = a.data
        self.align = _align(arrtype)
        self.data_below = _address(builder, a.data, w)  # one row down
        self.w = self._splat_i(builder.trunc(w, _I32))
        self.last_v = builder.sub(h, ir.Constant(_I64, 1))
        self.last_u = builder.sub(w, ir.Constant(_I64, 1))
        self.last_row = self._splat_i(builder.trunc(builder.mul(self.last_v, w), _I32))
        self.last_col = self._splat_i(builder.trunc(self.last_u, _I32))

    def _splat_i(self, x):  # type: ignore[no-untyped-def]
        return _vector(self.b, [x] * 4, _V4I)

    def axis(self, x, last, scale):  # type: ignore[no-untyped-def]
        """Clamp, floor and fraction of four coordinates, as ``sampling.cell``.

        Returns ``(i0 * scale, i1 * scale, f, 1 - f)`` with ``i1 = min(i0 + 1,
        last)``: rows are scaled by the row length, columns by 1.
        """
        b = self.b
        zero = ir.Constant(_V4D, [0.0] * 4)
        hi = _vector(b, [b.sitofp(last, _F64)] * 4, _V4D)
        x = b.select(b.fcmp_ordered(">", x, zero), x, zero)
        x = b.select(b.fcmp_ordered("<", x, hi), x, hi)
        fl = _intrinsic_call(b, "llvm.floor.v4f64", _V4D, x)
        frac = b.fsub(x, fl)
        i0 = b.fptosi(fl, _V4I)
        i1 = b.add(i0, ir.Constant(_V4I, [1] * 4))
        cap = self._splat_i(b.trunc(last, _I32))
        i1 = b.select(b.icmp_signed("<", i1, cap), i1, cap)
        if scale is not None:
            i0 = b.mul(i0, scale)
            i1 = b.mul(i1, scale)
        return i0, i1, frac, b.fsub(ir.Constant(_V4D, [1.0] * 4), frac)

    def state_cells(self, v, u, eps):  # type: ignore[no-untyped-def]
        """Cells of ``(v, u), (v + e, u), (v - e, u), (v, u + e), (v, u - e)``:
        six axes for five samples, not ten."""
        b = self.b
        e = _vector(b, [eps] * 4, _V4D)
        row, col = self.rows(v), self.cols(u)
        up, down = self.rows(b.fadd(v, e)), self.rows(b.fsub(v, e))
        right, left = self.cols(b.fadd(u, e)), self.cols(b.fsub(u, e))
        return [(row, col), (up, col), (down, col), (row, right), (row, left)]

    def rows(self, v):  # type: ignore[no-untyped-def]
        return self.axis(v, self.last_v, self.w)

    def cols(self, u):  # type: ignore[no-untyped-def]
        return self.axis(u, self.last_u, None)

    def _gather(self, idx):  # type: ignore[no-untyped-def]
        b = self.b
        out = ir.Constant(_V4D, ir.Undefined)
        for k in range(4):
            i = b.zext(b.extract_element(idx, _k(k)), _I64)
            ld = b.load(_address(b, self.data, i), typ=_F64, align=self.align)
            out = b.insert_element(out, ld, _k(k))
        return out

    def _blend(self, a, bb, c, d, fv, gv, fu, gu):  # type: ignore[no-untyped-def]
        """``sampling.blend``: the corners weighted in the order of :ref:`contract-numerics`
        (``gv = 1 - fv``, ``gu = 1 - fu``)."""
        b = self.b
        s = b.fmul(b.fmul(a, gv), gu)
        s = b.fadd(s, b.fmul(b.fmul(bb, gv), fu))
        s = b.fadd(s, b.fmul(b.fmul(c, fv), gu))
        return b.fadd(s, b.fmul(b.fmul(d, fv), fu))

    def _inside(self, cells):  # type: ignore[no-untyped-def]
        """Whether no cell of any lane is clamped (its corners are two adjacent pairs)."""
        b = self.b
        ok = None
        for rw, cl in cells:
            m = b.and_(
                b.icmp_signed("<", rw[0], self.last_row), b.icmp_signed("<", cl[0], self.last_col)
            )
            ok = m if ok is None else b.and_(ok, m)
        return b.icmp_unsigned("==", b.bitcast(ok, ir.IntType(4)), ir.Constant(ir.IntType(4), 15))

    def samples(self, cells):  # type: ignore[no-untyped-def]
        """Bilinear samples at the ``(rows, cols)`` cells, four lanes each."""
        b = self.b
        with b.if_else(self._inside(cells), likely=True) as (inside, edge):
            with inside:
                fast = []
                for rw, cl in cells:
                    idx = b.add(rw[0], cl[0])
                    lanes = [b.zext(b.extract_element(idx, _k(k)), _I64) for k in range(4)]
                    fast.append(self._inner(lanes, rw[2], rw[3], cl[2], cl[3]))
                fast_block = b.block
            with edge:
                slow = []
                for rw, cl in cells:
                    a = self._gather(b.add(rw[0], cl[0]))
                    bb = self._gather(b.add(rw[0], cl[1]))
                    c = self._gather(b.add(rw[1], cl[0]))
                    d = self._gather(b.add(rw[1], cl[1]))
                    slow.append(self._blend(a, bb, c, d, rw[2], rw[3], cl[2], cl[3]))
                slow_block = b.block
        out = []
        for x, y in zip(fast, slow, strict=True):
            phi = b.phi(_V4D)
            phi.add_incoming(x, fast_block)
            phi.add_incoming(y, slow_block)
            out.append(phi)
        return out

    def _inner(self, lanes, fv, gv, fu, gu):  # type: ignore[no-untyped-def]
        """A sample whose cell is inside the image, from its corner's flat indices."""
        a, bb = _pairs_at(self.b, self.data, lanes, self.align)
        c, d = _pairs_at(self.b, self.data_below, lanes, self.align)
        return self._blend(a, bb, c, d, fv, gv, fu, gu)

    def stage(self, cells, cell_buf, frac_buf, slot):  # type: ignore[no-untyped-def]
        """Store the cells' corner indices and fractions in slot ``slot`` of the
        buffers (:func:`stage_state`); returns whether all are inside."""
        b = self.b
        for c, (rw, cl) in enumerate(cells):
            at = b.add(b.mul(slot, ir.Constant(_I64, CELLS_PER_SLOT)), ir.Constant(_I64, 4 * c))
            _store(b, b.add(rw[0], cl[0]), _address(b, cell_buf, at, _I32), 4)
            at = b.add(b.mul(slot, ir.Constant(_I64, FRACS_PER_SLOT)), ir.Constant(_I64, 8 * c))
            for j, f in enumerate((rw[2], cl[2])):
                _store(b, f, _address(b, frac_buf, b.add(at, ir.Constant(_I64, 4 * j))), 8)
        return self._inside(cells)

    def finish(self, count, cell_buf, frac_buf, slot):  # type: ignore[no-untyped-def]
        """The ``count`` samples staged in slot ``slot`` (all inside the image).

        The indices are read back as scalars, which is what the loads need:
        no vector-to-register moves, and the loads no longer wait on the
        coordinate arithmetic of the same vertices.
        """
        b = self.b
        one = ir.Constant(_V4D, [1.0] * 4)
        out = []
        for c in range(count):
            at = b.add(b.mul(slot, ir.Constant(_I64, CELLS_PER_SLOT)), ir.Constant(_I64, 4 * c))
            lanes = [
                b.zext(b.load(_address(b, cell_buf, b.add(at, ir.Constant(_I64, k)), _I32), typ=_I32), _I64)
                for k in range(4)
            ]
            at = b.add(b.mul(slot, ir.Constant(_I64, FRACS_PER_SLOT)), ir.Constant(_I64, 8 * c))
            fr = []
            for j in range(2):
                ptr = _address(b, frac_buf, b.add(at, ir.Constant(_I64, 4 * j)))
                fr.append(b.load(ptr, typ=_V4D, align=8))
            fv, fu = fr
            out.append(self._inner(lanes, fv, b.fsub(one, fv), fu, b.fsub(one, fu)))
        return out


@intrinsic
def positions4(typingctx, pts, i, dv, du, theta, cos_t, sin_t, pv, pu):  # type: ignore[no-untyped-def]
    """``sampling.transform`` of ``pts[i:i + 4]``: their ``(v, u)`` lanes at a pose."""
    if not _contiguous(pts, 2):
        return None
    sig = types.UniTuple(float4, 2)(pts, types.int64, *([types.float64] * 7))

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        b = builder
        v, u = _lanes_of_pairs(context, b, signature.args[0], args[0], args[1])
        dv_, du_, c, s, pv_, pu_ = (_vector(b, [x] * 4, _V4D) for x in (args[2], args[3], *args[5:9]))
        # rotation about the pivot in transform()'s order; at theta == 0 exactly
        # transform() uses no trigonometry, and neither does the lane it selects
        rel_v = b.fsub(v, pv_)
        rel_u = b.fsub(u, pu_)
        rv = b.fsub(b.fadd(pv_, b.fmul(c, rel_v)), b.fmul(s, rel_u))
        ru = b.fadd(b.fadd(pu_, b.fmul(s, rel_v)), b.fmul(c, rel_u))
        flat = b.fcmp_ordered("==", args[4], ir.Constant(_F64, 0.0))
        v = b.fadd(b.select(flat, v, rv), dv_)
        u = b.fadd(b.select(flat, u, ru), du_)
        return context.make_tuple(b, signature.return_type, [v, u])

    return sig, codegen


@intrinsic
def bilinear4(typingctx, dt, v, u):  # type: ignore[no-untyped-def]
    """``sampling.bilinear(dt, v, u)`` of four lanes."""
    if not (_contiguous(dt, 2) and v is float4 and u is float4):
        return None

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        img = _Image(context, builder, signature.args[0], args[0])
        return img.samples([(img.rows(args[1]), img.cols(args[2]))])[0]

    return float4(dt, float4, float4), codegen


@intrinsic
def state4(typingctx, dt, v, u, eps, two_eps):  # type: ignore[no-untyped-def]
    """The DT and its central differences at four lanes ``(v, u)``:
    ``B(v, u)``, ``(B(v + e, u) - B(v - e, u)) / (2e)`` and
    ``(B(v, u + e) - B(v, u - e)) / (2e)``, the five samples sharing the
    clamping of their common coordinates."""
    if not (_contiguous(dt, 2) and v is float4 and u is float4):
        return None
    sig = types.UniTuple(float4, 3)(dt, float4, float4, types.float64, types.float64)

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        img = _Image(context, builder, signature.args[0], args[0])
        samples = img.samples(img.state_cells(args[1], args[2], args[3]))
        return _with_differences(context, builder, signature.return_type, samples, args[4])

    return sig, codegen


def _with_differences(context, builder, tuple_type, samples, two_eps):  # type: ignore[no-untyped-def]
    """``(s0, (s1 - s2) / 2e, (s3 - s4) / 2e)`` as a tuple of three vectors."""
    two_e = _vector(builder, [two_eps] * 4, _V4D)
    j_v = builder.fdiv(builder.fsub(samples[1], samples[2]), two_e)
    j_u = builder.fdiv(builder.fsub(samples[3], samples[4]), two_e)
    return context.make_tuple(builder, tuple_type, [samples[0], j_v, j_u])


# -- the same in two stages ------------------------------------------------------------
#
# A group's sampling is a long dependency chain (coordinates, cell indices,
# loads, blend) of ~200 instructions: a core's reorder window holds about
# one such group, so one group's loads wait on its own arithmetic. Staging
# the cells of a block of groups first (stage_*: coordinates only, indices
# and fractions stored to a small buffer) and sampling them after
# (finish_*: loads and blends only) overlaps the groups again. A group
# whose cells are not all inside the image is not staged: stage_* returns
# False and the caller samples it with state4.

#: int32 corner indices and float64 fractions per staged group (five cells).
CELLS_PER_SLOT = 20
FRACS_PER_SLOT = 40


def _buffers(context, builder, sig_args, args):  # type: ignore[no-untyped-def]
    cells = context.make_array(sig_args[0])(context, builder, args[0])
    fracs = context.make_array(sig_args[1])(context, builder, args[1])
    return cells.data, fracs.data


def _staging_buffers(cells, fracs):  # type: ignore[no-untyped-def]
    return (
        isinstance(cells, types.Array) and cells.ndim == 1 and cells.layout == "C"
        and cells.dtype == types.int32 and _contiguous(fracs, 1)
    )


@intrinsic
def stage_state(typingctx, dt, v, u, eps, cells, fracs, slot):  # type: ignore[no-untyped-def]
    """Stage :func:`state4` at ``(v, u)`` in ``slot``; False if not staged."""
    if not (_contiguous(dt, 2) and v is float4 and u is float4 and _staging_buffers(cells, fracs)):
        return None
    sig = types.boolean(dt, float4, float4, types.float64, cells, fracs, types.int64)

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        img = _Image(context, builder, signature.args[0], args[0])
        cell_buf, frac_buf = _buffers(context, builder, signature.args[4:6], args[4:6])
        return img.stage(img.state_cells(args[1], args[2], args[3]), cell_buf, frac_buf, args[6])

    return sig, codegen


@intrinsic
def finish_state(typingctx, dt, cells, fracs, slot, two_eps):  # type: ignore[no-untyped-def]
    """:func:`state4` of the group staged in ``slot``."""
    if not (_contiguous(dt, 2) and _staging_buffers(cells, fracs)):
        return None
    sig = types.UniTuple(float4, 3)(dt, cells, fracs, types.int64, types.float64)

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        img = _Image(context, builder, signature.args[0], args[0])
        cell_buf, frac_buf = _buffers(context, builder, signature.args[1:3], args[1:3])
        samples = img.finish(5, cell_buf, frac_buf, args[3])
        return _with_differences(context, builder, signature.return_type, samples, args[4])

    return sig, codegen


@intrinsic
def polarity4(typingctx, pts, nrm, grad, i, dv, du):  # type: ignore[no-untyped-def]
    """:func:`dtalign._kernels.robust.polarity` of vertices ``i..i+3``.

    Returns ``(accepted, bad)``: the four 1.0/0.0 flags, and whether a
    gradient vector the group read (one inside the image) is not finite.
    Lanes outside the image read element 0 (there is one: the gradient
    image is not empty) and are masked out.
    """
    if not (_contiguous(pts, 2) and _contiguous(nrm, 2) and _contiguous(grad, 3)):
        return None
    sig = types.Tuple((float4, types.boolean))(pts, nrm, grad, types.int64, types.float64, types.float64)

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        b = builder
        zero = ir.Constant(_V4D, [0.0] * 4)
        v, u = _lanes_of_pairs(context, b, signature.args[0], args[0], args[3])
        nv, nu = _lanes_of_pairs(context, b, signature.args[1], args[1], args[3])
        g = context.make_array(signature.args[2])(context, b, args[2])
        h, w, _ = cgutils.unpack_tuple(b, g.shape, 3)
        hv = _vector(b, [b.sitofp(h, _F64)] * 4, _V4D)
        wv = _vector(b, [b.sitofp(w, _F64)] * 4, _V4D)
        rint = "llvm.rint.v4f64"
        iv = _intrinsic_call(b, rint, _V4D, b.fadd(v, _vector(b, [args[4]] * 4, _V4D)))
        iu = _intrinsic_call(b, rint, _V4D, b.fadd(u, _vector(b, [args[5]] * 4, _V4D)))
        inside = b.and_(
            b.and_(b.fcmp_ordered(">=", iv, zero), b.fcmp_ordered("<", iv, hv)),
            b.and_(b.fcmp_ordered(">=", iu, zero), b.fcmp_ordered("<", iu, wv)),
        )
        # (row * W + col) * 2 is exact in float64 and in int32 (checked size)
        flat = b.fmul(b.fadd(b.fmul(b.select(inside, iv, zero), wv), b.select(inside, iu, zero)),
                      ir.Constant(_V4D, [2.0] * 4))
        idx = b.fptosi(flat, _V4I)
        lanes = [b.zext(b.extract_element(idx, _k(k)), _I64) for k in range(4)]
        gv, gu = _pairs_at(b, g.data, lanes, _align(signature.args[2]))
        inf = ir.Constant(_V4D, [float("inf")] * 4)
        fabs = "llvm.fabs.v4f64"
        # |x| >= inf, or unordered: x is inf or NaN
        nonfinite = b.or_(
            b.fcmp_unordered(">=", _intrinsic_call(b, fabs, _V4D, gv), inf),
            b.fcmp_unordered(">=", _intrinsic_call(b, fabs, _V4D, gu), inf),
        )
        bad = b.and_(inside, nonfinite)
        any_bad = b.icmp_unsigned("!=", b.bitcast(bad, ir.IntType(4)), ir.Constant(ir.IntType(4), 0))
        dot = b.fadd(b.fmul(nv, gv), b.fmul(nu, gu))
        up = b.and_(inside, b.fcmp_ordered(">", dot, zero))
        flags = b.select(up, ir.Constant(_V4D, [1.0] * 4), zero)
        return context.make_tuple(b, signature.return_type, [flags, any_bad])

    return sig, codegen
