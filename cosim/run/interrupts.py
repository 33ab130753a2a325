"""Stop a run between ticks, never in the middle of writing the log.

A KeyboardInterrupt raised at an arbitrary bytecode could land inside the MCAP writer while it
compresses or appends a chunk and leave it inconsistent. While ``DeferredInterrupts`` is active,
SIGINT (Ctrl-C) and SIGTERM only set a flag; the runner calls ``check()`` between ticks and in
every wait, which raises KeyboardInterrupt there. A second signal raises at once, for a run that
no longer reaches a tick boundary, if it comes ``GRACE`` seconds or more after the first (a run
that still ticks stops well within that). Any other further signal only asks the run to ``hurry``
(stop its nodes without waiting for them): one within ``GRACE`` of the first (Ctrl-C pressed twice
in a row), one while the run is ``stopping`` (a signal has been raised, and the run is on its way
out through its ``except`` and ``finally`` blocks) and one while it is ``shielded`` (stopping its
nodes and writing how it ended). None of them may cut the writing of the log or its result short, so
every stop leaves a log with its result.
"""

from __future__ import annotations

import signal
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from cosim.errors import Interruption

GRACE = 0.5  # s: a second signal sooner than this after the first only hurries the run


class Interrupted(Interruption):
    """A run stopped by a signal between ticks (or by SIGTERM before its session, in
    ``terminate_like_ctrl_c``); ``signum`` says which (the CLI exits with 128 + signum)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)


@contextmanager
def terminate_like_ctrl_c() -> Iterator[None]:
    """In the block, SIGTERM raises ``Interrupted(SIGTERM)`` where it comes, as Ctrl-C raises
    KeyboardInterrupt (Python's default for SIGINT): a command stopped before its run's
    ``DeferredInterrupts`` exist (while the plan is made) goes through its ``finally`` blocks (an
    FMU's host process is killed) and says so in one line, where SIGTERM's default ends the process
    without a word. Only in the main thread (elsewhere a handler cannot be set)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handle(signum: int, frame: object) -> None:
        raise Interrupted(signum)

    previous = signal.signal(signal.SIGTERM, handle)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


class DeferredInterrupts:
    def __init__(self) -> None:
        self.requested: int | None = None
        self._requested_at = 0.0
        self.stopping = False  # a signal has been raised: the run is ending
        self.hurry = False
        self._shielded = 0
        self._previous: dict[int, Any] = {}

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
            if self._shielded or self.stopping or time.monotonic() - self._requested_at < GRACE:
                self.hurry = True
                return
            self.stopping = True
            raise Interrupted(signum)
        self.requested, self._requested_at = signum, time.monotonic()

    @contextmanager
    def shielded(self) -> Iterator[None]:
        """No signal raises inside: the second one sets ``hurry`` instead."""
        self._shielded += 1
        try:
            yield
        finally:
            self._shielded -= 1

    def check(self) -> None:
        """Raise KeyboardInterrupt if a signal arrived since the run started (not while shielded)."""
        if self.requested is not None and not self._shielded:
            self.stopping = True
            raise Interrupted(self.requested)
