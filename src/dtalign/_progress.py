"""Progress reports: one tqdm bar and one ``callback(done, total)`` counter.

The batch (:mod:`dtalign.pipeline.batch`), the command line and the
campaign (:mod:`dtalign.archive`) all report progress through these. tqdm
is optional (the ``cli`` extra): :func:`tqdm_bar` returns None without it
and each caller says what it does then.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

__all__ = ["Progress", "reporter", "tqdm_bar", "tqdm_progress"]


def tqdm_bar(total: int, *, unit: str, **options: Any) -> Any:
    """A tqdm bar of ``total`` items on standard error, or None without tqdm.

    ``options`` are tqdm's (``desc``, ``dynamic_ncols``, ...). The caller
    closes the bar.
    """
    try:
        from tqdm import tqdm
    except ImportError:
        return None
    return tqdm(total=total, unit=unit, file=sys.stderr, **options)


class Progress:
    """``callback(done, total)`` once per item done, ``done`` = 1, 2, ..., ``total``.

    Only the thread that waits for the items calls :meth:`advance`, so the
    callback needs no lock.
    """

    def __init__(self, callback: Callable[[int, int], Any], total: int) -> None:
        self.callback, self.total, self.done = callback, total, 0

    def advance(self, k: int = 1) -> None:
        """``k`` more items are done: one call of the callback each."""
        for _ in range(k):
            self.done += 1
            self.callback(self.done, self.total)


@contextmanager
def tqdm_progress(total: int, *, unit: str) -> Iterator[Progress | None]:
    """A :class:`Progress` that drives a tqdm bar, closed on the way out (None
    without tqdm); dtalign's first-compile notice is written above the bar
    while it is shown, not through it."""
    bar = tqdm_bar(total, unit=unit)
    if bar is None:
        yield None
        return
    from ._numba_cache import compile_listeners

    def note(text: str) -> None:
        bar.write(f"dtalign: {text}", file=sys.stderr)

    compile_listeners.append(note)
    try:
        yield Progress(lambda done, _: bar.update(done - bar.n), total)
    finally:
        compile_listeners.remove(note)
        bar.close()


@contextmanager
def reporter(progress: Callable[[int, int], Any] | bool | None, total: int,
             unit: str) -> Iterator[Progress | None]:
    """The :class:`Progress` of a batch's checked ``progress`` argument: None
    without one, a tqdm bar for True, else the callback's."""
    if progress is None or progress is False:
        yield None
    elif progress is True:
        with tqdm_progress(total, unit=unit) as report:
            if report is None:
                raise ModuleNotFoundError("progress=True needs tqdm (pip install tqdm); or "
                                          "pass a callable progress(done, total)")
            yield report
    else:
        yield Progress(progress, total)
