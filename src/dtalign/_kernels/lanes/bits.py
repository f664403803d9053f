"""Word-at-a-time helpers for scanning sparse byte masks.

A boolean mask is read as uint64 words: a word that is zero holds eight
False pixels, and a nonzero word's True bytes are found by folding each
byte onto its lowest bit and counting trailing zeros (one instruction),
so no branch is taken per byte. The branch a byte-by-byte scan takes on
each pixel of a sparse mask is mispredicted on almost every True pixel.
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from ..._jit import inline_kernel, kernel
from . import plain

#: The lowest bit of every byte.
LOW_BITS = np.uint64(0x0101010101010101)
ALL_BITS = np.uint64(0xFFFFFFFFFFFFFFFF)
#: Words OR-ed together before one branch: 256 bytes, a few vector ORs.
BLOCK = 32


@intrinsic
def trailing_zeros(typingctx, x):  # type: ignore[no-untyped-def]
    """Index of the lowest set bit of a nonzero uint64 (LLVM ``cttz``)."""
    if x != types.uint64:
        return None

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        return builder.cttz(args[0], ir.Constant(ir.IntType(1), 0))

    return types.uint64(types.uint64), codegen


@inline_kernel
def byte_bits(x):
    """Bit ``8k`` set exactly where byte ``k`` of ``x`` is nonzero; all other bits clear.

    Right shifts by 4, 2 and 1 (7 in all) fold each byte onto its lowest bit
    without reaching the next byte's.
    """
    x |= x >> np.uint64(4)
    x |= x >> np.uint64(2)
    x |= x >> np.uint64(1)
    return x & LOW_BITS


@inline_kernel
def from_byte(b):
    """Bits of bytes ``b..7`` of a word (``0 <= b < 8``)."""
    return ALL_BITS << np.uint64(8 * b)


@kernel
def emit(bits, base, out, k):
    """Write ``base + k`` for every byte flagged in ``bits`` (see :func:`byte_bits`)
    from ``out[k]`` on; returns the new count (indices past ``out``'s end are
    counted, not written)."""
    cap = out.shape[0]
    while bits != 0:
        t = np.int64(trailing_zeros(bits))
        if k < cap:
            out[k] = base + (t >> 3)
        k += 1
        bits &= bits - np.uint64(1)
    return k


@kernel
def fill(flat, words, start, stop, out, k):
    """Write the indices of the nonzero bytes of ``flat[start:stop]`` from ``out[k]``.

    ``words`` views the whole words of the same buffer as uint64. Returns
    the new count; indices past ``out``'s end are counted, not written. The
    middle of the run is tested :data:`BLOCK` words at a time (a loop LLVM
    turns into vector ORs); the partial words at both ends are masked.
    """
    if start >= stop:
        return k
    j = start // 8
    jend = stop // 8
    if j >= words.shape[0]:
        return plain.fill(flat, words, start, stop, out, k)  # no whole word: byte by byte
    head = from_byte(start - 8 * j)
    if j == jend:
        return emit(byte_bits(words[j]) & head & ~from_byte(stop - 8 * j), 8 * j, out, k)
    x = words[j]
    if x != 0:
        k = emit(byte_bits(x) & head, 8 * j, out, k)
    j += 1
    n_blocks = (jend - j) // BLOCK
    # a slice indexed from 0 lets LLVM see non-negative indices and vectorise
    mid = words[j : j + n_blocks * BLOCK]
    for blk in range(n_blocks):
        acc = np.uint64(0)
        for b in range(BLOCK):
            acc |= mid[blk * BLOCK + b]
        if acc != 0:
            for b in range(BLOCK):
                x = mid[blk * BLOCK + b]
                if x != 0:
                    k = emit(byte_bits(x), 8 * (j + blk * BLOCK + b), out, k)
    for jj in range(j + n_blocks * BLOCK, jend):
        x = words[jj]
        if x != 0:
            k = emit(byte_bits(x), 8 * jj, out, k)
    if stop > 8 * jend:
        if jend < words.shape[0]:
            x = words[jend]
            if x != 0:
                k = emit(byte_bits(x) & ~from_byte(stop - 8 * jend), 8 * jend, out, k)
        else:
            k = plain.fill(flat, words, 8 * jend, stop, out, k)  # the bytes past the last word
    return k
