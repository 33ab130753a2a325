"""Stop a run between ticks, never in the middle of writing the log.

A KeyboardInterrupt raised at an arbitrary bytecode could land inside the MCAP writer while it
compresses or appends a chunk and leave it inconsistent. While ``DeferredInterrupts`` is active,
SIGINT (Ctrl-C) and SIGTERM only set a flag; the runner calls ``check()`` between ticks, which
raises KeyboardInterrupt there. A second signal raises at once, for a run that no longer reaches
a tick boundary.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable
from types import FrameType
from typing import Any

#: What ``signal.signal`` takes and returns: a handler, SIG_DFL or SIG_IGN, or None (not set from Python).
_Handler = Callable[[int, FrameType | None], Any] | int | signal.Handlers | None


class Interrupted(KeyboardInterrupt):
    """A run stopped by a signal; ``signum`` says which (the CLI exits with 128 + signum)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


class DeferredInterrupts:
    def __init__(self) -> None:
        self.requested: int | None = None
        self._previous: dict[int, _Handler] = {}

    def __enter__(self) -> DeferredInterrupts:
        if threading.current_thread() is threading.main_thread():
            for signum in (signal.SIGINT, signal.SIGTERM):
                self._previous[signum] = signal.signal(signum, self._handle)
        return self

    def __exit__(self, *exc: object) -> None:
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)
        self._previous.clear()

    def _handle(self, signum: int, frame: object) -> None:
        if self.requested is not None:
            raise Interrupted(signum)
        self.requested = signum

    def check(self) -> None:
        """Raise KeyboardInterrupt if a signal arrived since the run started."""
        if self.requested is not None:
            raise Interrupted(self.requested)
