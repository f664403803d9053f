"""Compiled floating-point-bound work: the batch benchmark's control.

:func:`fp_throughput` keeps the floating-point pipes busy, as the LM's
four-lane sampling does, with nothing of dtalign in it; two threads of it
tell what two threads of such code can scale on this machine
(:mod:`dtalign.benchmarking.fpload` explains why that differs from the
SHA-256 control).
"""

from __future__ import annotations

import numpy as np

from .._jit import kernel

#: Independent multiply-add chains: eight AVX2 registers' worth, more than
#: the floating-point pipes retire per cycle, so the loop is bound by their
#: throughput, not by the latency of one chain.
LANES = 32


@kernel
def fp_throughput(rounds):
    """``LANES`` independent chains of ``x * (1 + 1e-7) + 1e-9``, ``rounds`` times.

    Returns their sum (so the work cannot be optimised away).
    """
    acc = np.ones(LANES)
    for _ in range(rounds):
        for k in range(LANES):
            acc[k] = acc[k] * 1.0000001 + 1e-9
    return acc.sum()
