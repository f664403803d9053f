"""A control for the batch rows: floating-point throughput on two threads.

The SHA-256 control tells whether the second core was free. It cannot tell
whether two threads of floating-point-heavy code each run as fast as one
does alone. SHA-256 is a chain of dependent rounds: one thread leaves most
of a core's execution units idle. Two virtual CPUs that share one physical
core (as SMT siblings on the host would, whatever the guest's ``lscpu``
says) then still scale nearly 2x on it, while code that keeps the
floating-point pipes busy, as the LM's four-lane bilinear sampling does,
scales far less. So this control runs many independent multiply-add
chains, bound by the pipes' throughput as the fits are: it is what two
threads of such code get from the machine at that moment, and
:func:`~dtalign.pipeline.batch.fit_many`'s compiled loop alone follows it where a
single chain does not (docs/benchmarks.rst, "What was tried").
"""

from __future__ import annotations

from ..api import loop
from ..api.loop import FP_LANES as LANES

__all__ = ["LANES", "ROUNDS", "fp_throughput", "unit"]

#: Rounds per work unit: about the compiled work of one fit of the batch row.
ROUNDS = 18_000


def fp_throughput(rounds: int) -> float:
    """``LANES`` independent multiply-add chains run ``rounds`` times, compiled
    with the kernels' flags (GIL released); returns their sum: floating-point
    bound compiled work with nothing of dtalign in it."""
    return float(loop.fp_throughput(rounds))


def unit() -> float:
    """One work unit of the control (GIL released while it runs)."""
    return fp_throughput(ROUNDS)
