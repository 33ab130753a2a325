"""How far a run has got and how it ended: ``Progress`` while it goes, ``RunResult`` once it is over."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cosim.errors import CosimError


class NodeFailure(CosimError):
    """A node or client died, hung or left during the run."""


@dataclass(frozen=True)
class Progress:
    tick: int
    ticks: int
    sim_time: float
    wall_time: float
    frames: int
    deadline_misses: int = 0

    @property
    def realtime_factor(self) -> float:
        return self.sim_time / self.wall_time if self.wall_time > 0 else float("inf")


@dataclass(frozen=True)
class RunResult:
    path: Path | None
    """The log (None: the run wrote none, ``cosim.api.run(scenario, None)``)."""
    status: str
    ticks: int
    frames: int
    frames_lost: int
    wall_time: float
    sim_time: float
    error: str = ""
    deadline_misses: int = 0
    senders: dict[str, dict[str, int]] = field(default_factory=dict)
    startup_time: float = 0.0
    """Wall time from the start until every node had joined."""
    loop_time: float = 0.0
    """Wall time of the ticks themselves (from tick 0 to the end of the last one)."""
    failed: dict[str, str] = field(default_factory=dict)
    """Estimator nodes that failed during the run, and why in a line (the run went on without them)."""
    late_ticks: int = 0
    """Realtime: ticks that started late (by a period or 20 ms or more: the run fell behind)."""
    contested_ticks: int = 0
    """Ticks during which another program sent on the runner's own ids (sensor, command, SYNC, NMT):
    their estimates may rest on forged frames (``cosim run`` exits with status 3)."""
    kernel_dropped: int = 0
    """Datagrams the kernel dropped before the runner read them (its receive buffer was full)."""
    warnings: list[str] = field(default_factory=list)
    """What the run found worth saying (also the log's warning events)."""
    metrics: Any = None
    """The log's metrics (a ``cosim.analysis.metrics.RunMetrics``, which the runner's room does not
    import), scored while the run wrote it: ``cosim.api.run(..., measure=True)``."""

    @property
    def realtime_factor(self) -> float:
        """Simulated over wall-clock time of the ticks: the start-up (nodes joining, a viewer's
        wait) is not the run's pace and does not count."""
        elapsed = self.loop_time if self.loop_time > 0 else self.wall_time
        return self.sim_time / elapsed if elapsed > 0 else float("inf")


def fell_behind(late_ticks: int, ticks: int, speed: float, achieved: float, behind_s: float) -> list[str]:
    """A realtime run's warning when ticks started late (by a period or ``behind_s`` or more)."""
    if not late_ticks:
        return []
    return [
        f"realtime at {speed:g}x fell behind: {late_ticks} of {ticks} ticks started late (by a period or "
        f"{behind_s * 1e3:g} ms or more); it ran at {achieved:.1f}x (lower --speed, or use lockstep)"
    ]


#: Arrivals per second the run did not send from which they are called a flood.
FLOOD_RATE = 1000.0


def flood_report(arrivals: int, elapsed: float, dropped: int, last: str) -> str | None:
    """Another program's flood, named (how many arrived, how fast, the last, what the kernel
    dropped) when it is one: the likely cause of a failure, rather than the participant it delayed."""
    rate = arrivals / elapsed if elapsed > 0 else 0.0
    if rate < FLOOD_RATE and not dropped:
        return None
    return (
        f"another program flooded the bus: {arrivals} frames and datagrams the run did not send, {rate:.0f}/s, the "
        f"last {last}; the kernel dropped {dropped} datagrams: the flood, not the participant, is the likely cause"
    )


def kernel_drops(dropped: int) -> list[str]:
    """The warning when the kernel dropped datagrams the runner never read."""
    if not dropped:
        return []
    return [
        f"the kernel dropped {dropped} datagrams before the runner read them (its receive buffer was full: a "
        "flood on the bus?); the participants' frames among them count as lost"
    ]


def ending(exc: BaseException) -> tuple[str, str]:
    """The status and error a log records for what stopped a run: Ctrl-C or SIGTERM (interrupted),
    a CosimError (its message) or anything else (its type and message)."""
    if isinstance(exc, KeyboardInterrupt):
        return "interrupted", getattr(exc, "detail", "")
    if isinstance(exc, CosimError):
        return "error", str(exc)
    return "error", f"{type(exc).__name__}: {exc}"


def last_words(output: str) -> str:
    """A failed node's output (a Python traceback, usually) in one line: the exception, and where
    in the user's code it was raised (the innermost frame outside cosim and the libraries)."""
    lines = [line.strip() for line in output.splitlines() if line.strip()]
    if not lines:
        return "no output"
    frames = [line for line in lines if line.startswith('File "')]
    own = [f for f in frames if "/site-packages/" not in f and "/cosim/" not in f and "/estimators/" not in f]
    where = f" ({own[-1].split(', in ')[0]})" if own else ""
    return f"{lines[-1]}{where}"
