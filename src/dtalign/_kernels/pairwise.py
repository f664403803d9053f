"""NumPy's pairwise float64 summation, reproduced operation for operation.

:ref:`contract-today` fixes two scores as NumPy computes them: the polarity-weighted
coarse score (``np.sum`` of the weights) and the secondary-basin cost
(``.mean()`` of the samples). Equal scores must compare equal exactly as in
the reference (ties decide the winner), so these sums are not just
accurate: they follow NumPy's own summation tree
(``numpy/_core/src/umath/loops_utils.h.src``, ``pairwise_sum``): a block
of fewer than 8 values is summed left to right from 0; a block of up to
128 values in 8 interleaved accumulators, combined as
``((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))``, then its
remainder left to right; a longer run splits at half its length rounded
down to a multiple of 8. A contiguous float64 ``np.add.reduce`` starts
from the identity 0.0 and adds that tree's total (checked against
``np.sum`` for every length up to 300 and for long runs, in the tests).
"""

from __future__ import annotations

import numpy as np

from .._jit import kernel

#: Longest run NumPy sums as one block of eight accumulators (``PW_BLOCKSIZE``).
BLOCK = 128
#: NumPy's unroll factor: the number of interleaved accumulators of a block.
UNROLL = 8


@kernel
def block_sum(a, start, n):
    """NumPy's sum of ``a[start:start + n]`` for ``n <= BLOCK``."""
    if n < UNROLL:
        res = 0.0
        for i in range(n):
            res += a[start + i]
        return res
    r0 = a[start]
    r1 = a[start + 1]
    r2 = a[start + 2]
    r3 = a[start + 3]
    r4 = a[start + 4]
    r5 = a[start + 5]
    r6 = a[start + 6]
    r7 = a[start + 7]
    limit = n - n % UNROLL
    i = UNROLL
    while i < limit:
        j = start + i
        r0 += a[j]
        r1 += a[j + 1]
        r2 += a[j + 2]
        r3 += a[j + 3]
        r4 += a[j + 4]
        r5 += a[j + 5]
        r6 += a[j + 6]
        r7 += a[j + 7]
        i += UNROLL
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[start + i]
        i += 1
    return res


#: Depth bound of the summation tree: each level halves the run, so a run
#: of fewer than 2**63 values needs at most 63 levels above its blocks.
MAX_DEPTH = 64


@kernel
def pairwise_sum(a, start, n):
    """NumPy's pairwise sum of ``a[start:start + n]`` (without the leading ``0.0 +``).

    NumPy recurses; this walks the same tree with an explicit stack (Numba's
    cached code cannot call itself), adding each node's halves in the same
    order: ``left + right``.
    """
    if n <= BLOCK:
        return block_sum(a, start, n)
    half = n // 2
    half -= half % UNROLL
    if n - half <= BLOCK:
        # one split into two blocks (n up to 2 * BLOCK): the tree's root, without
        # the stack's four allocations, which cost more than the sum itself
        return block_sum(a, start, half) + block_sum(a, start + half, n - half)
    run_start = np.empty(MAX_DEPTH, dtype=np.int64)
    run_len = np.empty(MAX_DEPTH, dtype=np.int64)
    left = np.empty(MAX_DEPTH)  # a node's finished left half, while its right one runs
    stage = np.zeros(MAX_DEPTH, dtype=np.int64)  # 0: split, 1: left done
    top = 0
    run_start[0] = start
    run_len[0] = n
    value = 0.0
    while top >= 0:
        m = run_len[top]
        if m <= BLOCK:
            value = block_sum(a, run_start[top], m)
            top -= 1
        elif stage[top] == 0:
            stage[top] = 1
            half = m // 2
            half -= half % UNROLL
            run_start[top + 1] = run_start[top]
            run_len[top + 1] = half
            stage[top + 1] = 0
            top += 1
            continue
        elif stage[top] == 1:
            stage[top] = 2
            left[top] = value
            half = m // 2
            half -= half % UNROLL
            run_start[top + 1] = run_start[top] + half
            run_len[top + 1] = m - half
            stage[top + 1] = 0
            top += 1
            continue
        else:
            value = left[top] + value
            top -= 1
    return value


@kernel
def numpy_sum(a, n):
    """``np.sum(a[:n])`` for a contiguous float64 ``a``, bit for bit."""
    return 0.0 + pairwise_sum(a, 0, n)
