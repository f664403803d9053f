"""The Dask worker plugin that warms Numba's cache once per worker (imports distributed)."""

from __future__ import annotations

import asyncio
from typing import Any

from distributed import WorkerPlugin

#: The plugin's name on the cluster: registering it again replaces it.
PLUGIN_NAME = "dtalign-warm-numba"


class WarmNumba(WorkerPlugin):
    """Runs :func:`dtalign.archive.tasks.warm_up` when a worker starts.

    Registered once, it runs on every worker there is and on every worker
    that joins later, a replacement for a killed one included, so the first
    task on a worker does not pay for loading (or compiling) the kernels.
    The warm-up runs in a thread: the worker keeps answering the scheduler
    (a cold compile can take minutes on a loaded machine).
    """

    name = PLUGIN_NAME

    async def setup(self, worker: Any) -> None:  # noqa: D102 - WorkerPlugin's hook
        from .tasks import warm_up

        await asyncio.get_running_loop().run_in_executor(None, warm_up)


def dask_setup(worker: Any) -> None:
    """Worker preload of the LocalCluster :func:`~dtalign.archive.run` starts: ignore Ctrl-C.

    A terminal's Ctrl-C reaches every process of its group, the workers
    too. The client is the one to handle it (store what has arrived, then
    close the cluster); a worker that died of it first would only print
    tracebacks. Imported when each worker process starts (a replacement
    for a killed one included), in its main thread.
    """
    import signal
    import threading

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
