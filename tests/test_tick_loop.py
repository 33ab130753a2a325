"""The tick loop's order (``cosim.run.loop.run_ticks``): a tick's frames are made while the nodes
answer the tick before, and what making them raises ends the run where it did before, once the
tick before is closed."""

from __future__ import annotations

import pytest

from cosim.errors import CosimError
from cosim.run.loop import run_ticks


class Source:
    """Ticks whose frames fail at ``broken`` (a log cut there), recording every call."""

    def __init__(self, calls: list[str], ticks: int, broken: int | None = None) -> None:
        self.calls, self.ticks, self.broken = calls, ticks, broken

    def frames(self, k: int) -> list:
        self.calls.append(f"frames {k}")
        if k == self.broken:
            raise CosimError(f"the log ends at tick {k}")
        return [f"frame of {k}"]

    def advance(self, k: int, session: object) -> None:
        self.calls.append(f"advance {k}")


class Session:
    def __init__(self, calls: list[str]) -> None:
        self.calls = calls

    def begin(self, k: int) -> None:
        self.calls.append(f"begin {k}")

    def send(self, k: int, frames: list) -> None:
        assert frames == [f"frame of {k}"]  # tick k sends tick k's frames
        self.calls.append(f"send {k}")

    def end(self, k: int) -> None:
        self.calls.append(f"end {k}")


def test_the_next_ticks_frames_are_made_while_the_nodes_answer():
    calls: list[str] = []
    assert run_ticks(Source(calls, 3), Session(calls), lambda done: calls.append(f"done {done}")) == 3
    assert calls == [
        "frames 0",
        "begin 0", "send 0", "advance 0", "frames 1", "end 0", "done 1",
        "begin 1", "send 1", "advance 1", "frames 2", "end 1", "done 2",
        "begin 2", "send 2", "advance 2", "end 2", "done 3",
    ]  # fmt: skip


def test_a_failure_making_frames_ends_the_run_at_that_tick_after_the_tick_before_closed():
    calls: list[str] = []
    with pytest.raises(CosimError, match="the log ends at tick 2"):
        run_ticks(Source(calls, 5, broken=2), Session(calls), lambda done: calls.append(f"done {done}"))
    assert calls[-5:] == ["advance 1", "frames 2", "end 1", "done 2", "begin 2"]  # tick 1 answered, 2 never sent


def test_an_interrupt_while_making_frames_is_not_held_back():
    """Only errors wait for their tick; Ctrl-C (a BaseException) goes through at once."""

    class Interrupted(Source):
        def frames(self, k: int) -> list:
            if k == 2:
                self.calls.append("interrupted")
                raise KeyboardInterrupt
            return super().frames(k)

    calls: list[str] = []
    with pytest.raises(KeyboardInterrupt):
        run_ticks(Interrupted(calls, 5), Session(calls), lambda done: None)
    assert calls[-2:] == ["advance 1", "interrupted"]  # not after tick 1's end
