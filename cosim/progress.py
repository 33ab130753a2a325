"""What slow work says while nothing else shows that a command is busy (an estimator's design, an
FMU's loading, the nodes starting), and the one way a command listens to it.

Work that may take seconds names itself in a ``step``; steps nest, the outermost first:

    with progress.step(f"estimator {name} ({kind}), 1 of 7"):
        with progress.step("designing (stored in the design cache)"):
            solve()

A command that shows them listens while it works (``cosim.cli.common.preparing`` shows them on a
terminal, as plain lines otherwise, and nothing with ``-q``):

    with progress.listening(show):  # show(steps): the steps under way, outermost first; () at the end
        Run(...)

The listener is a context variable: steps taken in another thread, or with no one listening, cost a
lookup and say nothing. This module imports nothing of cosim, so that every room can report here.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar

#: Called with the steps under way, outermost first, whenever they change (() once none is).
Listener = Callable[[tuple[str, ...]], None]

_listener: ContextVar[Listener | None] = ContextVar("cosim_progress_listener", default=None)
_steps: ContextVar[tuple[str, ...]] = ContextVar("cosim_progress_steps", default=())


@contextmanager
def step(what: str) -> Iterator[None]:
    """``what`` is under way while the block runs (said to the listener, if there is one)."""
    listener = _listener.get()
    if listener is None:
        yield
        return
    outer = _steps.get()
    token = _steps.set((*outer, what))
    listener((*outer, what))
    try:
        yield
    finally:
        _steps.reset(token)
        listener(outer)


@contextmanager
def listening(listener: Listener) -> Iterator[None]:
    """Every step taken in this context (this thread) while the block runs is said to ``listener``."""
    token, steps = _listener.set(listener), _steps.set(())
    try:
        yield
    finally:
        _steps.reset(steps)
        _listener.reset(token)
