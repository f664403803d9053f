"""How a scaling row (2 workers against 1) is judged: against its target, or its control.

A scaling row's ratio is one worker's time over two workers' time, both
measured in the same run, alternated with controls: GIL-free work run the
same two ways on the same pool (SHA-256 of 512 KiB; compiled work bound by
floating-point throughput, :mod:`~dtalign.benchmarking.fpload`). The
ratio ``c`` of the row's own control (:data:`CONTROLS`) is what the
machine allowed such work at that moment. On a machine whose second core
other processes hold, no code reaches a target its control cannot reach.
So a row passes by one of two rules:

* ``target``: its ratio reaches its target;
* ``control-bound``: its ratio reaches its fraction (:data:`CONTROLS`) of
  what its control predicts for it, and :data:`FLOOR` whatever the
  control did.

The prediction is Amdahl's: of a row whose share ``s`` of one worker's
time can run on both workers (``s`` = 1 unless the row measures it), two
workers get ``1 / ((1 - s) + s / c)``. A row of 64 fits on one image is
mostly Python under the GIL (the settling and the conclusions of each
fit) around a compiled loop, and its share is that loop's time alone
over the row's, measured in the same run.

A regression that serialises the work (a lock, a kernel holding the GIL)
reads about 1x: on a row of share 1 it fails whenever the control scaled
past ``1 / fraction`` (1.25x). On a loaded machine, where the control
reads about 1x too, no ratio can tell the two apart, and the row passes
control-bound. The figures the fractions and the floor rest on are in
docs/benchmarks.rst ("Scaling rows").
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

__all__ = ["CONTROLS", "CONTROL_FRACTION", "FLOOR", "Control", "Verdict", "expected_ratio",
           "judge"]

#: The fraction of its control's prediction a row below its target must
#: reach: below the lowest fraction healthy runs gave, above the 1x of
#: serialised work beside a control that scaled.
CONTROL_FRACTION = 0.8
#: A row below this ratio fails whatever its control read: two workers that
#: take more than 1/FLOOR times one worker's time contend for something
#: (a lock, the GIL), which another process's load does not explain.
FLOOR = 0.7


class Control(NamedTuple):
    """A scaling row's own control: ``key``, the row's key of the control's
    ratio; ``fraction``, of the control's prediction the row must reach."""

    key: str
    fraction: float


#: Each scaling row's own control: the one whose work scales as the row's
#: does. The 64 fits' compiled loop is bound by floating-point throughput,
#: as :mod:`~dtalign.benchmarking.fpload` is; their Python, run by two
#: workers that contend for the GIL, is slower than on one, so the row
#: reads below Amdahl's prediction from its share, and is held to less of
#: it. Whole images and frames (derivatives, then fits) scale past the
#: floating-point control, and as far as the SHA-256 one.
CONTROLS = {
    "batch_64_fits": Control("fp_control_ratio", 0.7),
    "batch_images": Control("control_ratio", CONTROL_FRACTION),
    "archive_32_frames": Control("control_ratio", CONTROL_FRACTION),
}


@dataclass(frozen=True)
class Verdict:
    """A scaling row's judgement.

    Attributes
    ----------
    passed : bool
        Whether the row passed.
    rule : str
        ``"target"`` or ``"control-bound"`` (the rule it passed by), else
        ``"below target"`` (no control), ``"below control"`` or
        ``"below floor"`` (why it failed).
    required : float
        The ratio the row had to reach: its target, or the control-bound
        bound when that is lower (never below :data:`FLOOR`).
    """

    passed: bool
    rule: str
    required: float


def expected_ratio(control: float, share: float = 1.0) -> float:
    """Two workers' speed-up of work whose ``share`` runs on both, when the
    control's speed-up was ``control`` (Amdahl's law)."""
    return 1.0 / ((1.0 - share) + share / control)


def judge(ratio: float, target: float, control: float | None, share: float = 1.0,
          fraction: float = CONTROL_FRACTION) -> Verdict:
    """Judge a scaling row's ``ratio`` against its ``target`` and the same
    run's ``control`` ratio (None: the target alone).

    Parameters
    ----------
    ratio : float
        One worker's time over two workers' time.
    target : float
        The ratio asked of the row on a machine with two free cores.
    control : float or None
        The row's own control's ratio in the same run.
    share : float
        The share of one worker's time that can run on both (0 to 1).
    fraction : float
        The fraction of the control's prediction the row must reach.
    """
    if ratio >= target:
        return Verdict(True, "target", target)
    if control is None or control <= 0.0:
        return Verdict(False, "below target", target)
    bound = fraction * expected_ratio(control, min(max(share, 0.0), 1.0))
    required = max(FLOOR, min(target, bound))
    if ratio >= required:
        return Verdict(True, "control-bound", required)
    return Verdict(False, "below floor" if ratio < FLOOR else "below control", required)
