"""A pipe read in a thread, for the tests that drive the CLI in a subprocess."""

from __future__ import annotations

import threading
import time
from typing import IO


class PipeReader:
    """Collect a pipe's text in a thread, so the test can wait for a line."""

    def __init__(self, pipe: IO[str]) -> None:
        self.text = ""
        self._thread = threading.Thread(target=self._run, args=(pipe,), daemon=True)
        self._thread.start()

    def _run(self, pipe: IO[str]) -> None:
        for chunk in iter(lambda: pipe.read(1), ""):
            self.text += chunk

    def wait_for(self, fragment: str, timeout: float) -> bool:
        """Whether ``fragment`` arrived within ``timeout`` seconds."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and fragment not in self.text:
            time.sleep(0.05)
        return fragment in self.text

    def join(self) -> None:
        self._thread.join(timeout=30)
