"""The bus side of a run: the participants it supervises, the frames it hears, the log it writes.

A ``Session`` holds what one run or replay needs while its ticks go: the log (``McapLog`` and its
``RunRecorder``), the open bus, the participants (node processes, in-process nodes, external
clients), the frame accounting (``Traffic``) and Ctrl-C handling. Opened as a context manager, it
closes all of them whatever ends the run. The tick loop (``cosim.run.loop``) drives it through a
few phases per tick: ``begin``, ``send``, ``commands`` (closed loop), ``end``; ``finish`` stops
the nodes and writes how the run ended.

Frames of one tick are logged in a canonical order: the runner's own frames as sent, then the
frames received during the tick by arbitration id (lowest first, as a CAN bus arbitrates frames
pending together); the wall-clock arrival order of UDP datagrams from several processes is not
deterministic, this order is.
"""

from __future__ import annotations

import os
import tempfile
import time
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import can
import numpy as np

from cosim.bus.codec import CONTROLLER, NMT_STOP, Codec, Decoded
from cosim.bus.control_frames import ControlAuth
from cosim.bus.registry import Registration
from cosim.bus.secoc import Rejection, SecOC
from cosim.bus.transport import BusConfig, drain, drain_silent, open_bus, send_all, silent
from cosim.bus.udp import ForeignDatagram
from cosim.bus.wire import Transmission, bits_of
from cosim.errors import CosimError
from cosim.log.metadata import BUS, RESULT, ResultRecord
from cosim.log.recorder import RunRecorder
from cosim.log.writer import LogSink, McapLog, RecordSink, SinkLog
from cosim.run.arbitration import Arbitration
from cosim.run.busfaults import Applied, BusFaultStage
from cosim.run.detector import IntrusionDetector
from cosim.run.foreign_traffic import ForeignTraffic
from cosim.run.interrupts import DeferredInterrupts
from cosim.run.launcher import Participant, remove_stale_workdirs
from cosim.run.outcome import NodeFailure, Progress, RunResult, fell_behind, kernel_drops, last_words
from cosim.run.signing import forged, sign_control
from cosim.run.traffic import Traffic

_POLL = 0.05  # s: how often a waiting runner checks for Ctrl-C and dead nodes
_HEALTH = 0.25  # s: how often it asks its participants whether they are still alive
_LEFT_GRACE = 1.0  # s: a participant whose stopped heartbeat is this old and that answers no more has left
_STOP, _STOP_HURRY = 5.0, 0.5  # s: how long a node may take to exit after the stop command (hurried: 2nd Ctrl-C)
_FLUSH_SIMULATED, _FLUSH_TICKS = 1.0, 50  # chunks put on disk every 1 s of simulated time and 50 ticks, at least
_PENDING = 20_000  # frames held unlogged at most, whatever floods the bus
_BEHIND = 0.02  # s: a realtime tick starting this much (or a period, if longer) after its time is late
_LAST_FRAMES = 1.0  # s: how long the frames still arriving after the stop command are taken, at most


@dataclass(frozen=True)
class Timing:
    """How a session paces its ticks: ``lockstep`` (wait for every node) or ``realtime`` at
    ``speed``, with the lockstep time a node may take and the time to join."""

    sample_time: float
    mode: str = "lockstep"
    speed: float = 1.0
    node_timeout: float = 10.0
    join_timeout: float = 30.0

    @property
    def realtime(self) -> bool:
        return self.mode == "realtime"

    @property
    def period(self) -> float:
        """Wall-clock seconds per tick in realtime."""
        return self.sample_time / self.speed


class Session:
    """One run's bus, participants, accounting and log, from before tick 0 until the log is closed.

    ``own_senders`` are the DBC nodes whose frames the runner itself sends (they come back on a
    multicast bus and are not logged twice); with ``commands`` the controller node's command
    frames are collected for ``commands``. ``registration`` (the run's entry for clients and
    monitors) is written while the session is open; ``sink`` (the live view) gets everything the
    log gets. With ``out`` None the run writes no file: its ``sink`` (a ``RecordSink``, the live
    scorer) gets what the log would have got, through a ``SinkLog``.
    """

    def __init__(
        self,
        out: Path | None,
        config: BusConfig,
        codec: Codec,
        timing: Timing,
        *,
        recorder: dict[str, Any],
        own_senders: tuple[str, ...],
        commands: bool = False,
        registration: Registration | None = None,
        sink: LogSink | RecordSink | None = None,
        arbitration: Arbitration | None = None,
        bus_faults: BusFaultStage | None = None,
        secoc: SecOC | None = None,
        control: ControlAuth | None = None,
        detector: IntrusionDetector | None = None,
    ) -> None:
        self.out, self.config, self.codec, self.timing = out, config, codec, timing
        self.detector = detector  # the key-less intrusion detector: every frame logged, and the foreign ones
        self.secoc = secoc  # authentication = "secoc": the runner signs its frames and verifies everyone's
        self.control = control  # the control frames' keys: the runner signs NMT and SYNC, verifies heartbeats
        self.arbitration = arbitration  # arbitrated timing: the simulated wire decides what arrives when
        self.bus_faults = bus_faults  # what the scenario's bus faults do to the runner's frames, and intruders
        self._sink = sink  # the live view: the log tees every channel and message to it
        self._recorder_args, self._own, self._with_commands = recorder, own_senders, commands
        self._registration = registration
        self.participants: list[Participant] = []
        self.misses = 0
        self.warnings: list[str] = []
        self.failed: dict[str, str] = {}  # estimator nodes out of the run, and why
        self.late_ticks = 0  # realtime: ticks that started a whole period after their time
        self.result: RunResult | None = None
        self.start = time.perf_counter()
        self.tick_start: float | None = None
        self._marker = (0, 0.0, 0)  # the tick whose received frames are still to be logged
        self._stack = ExitStack()
        self._flushed = 0  # the tick at which the log last put its chunk on disk

    def __enter__(self) -> Session:
        stack = self._stack
        remove_stale_workdirs()
        try:
            self.interrupts = stack.enter_context(DeferredInterrupts())
            log: McapLog | SinkLog = (
                McapLog(self.out, sink=cast(LogSink | None, self._sink))
                if self.out is not None
                else SinkLog(self._record_sink())
            )
            stack.push(log.__exit__)
            self.log = log
            self.bus = stack.enter_context(open_bus(self.config, on_foreign=self._foreign_datagram))
            self.workdir = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix=f"cosim-nodes-{os.getpid()}-")))
            if self._registration is not None:
                stack.enter_context(self._registration)
            self.recorder = RunRecorder(self.log, self.codec, **self._recorder_args)
            self.foreign = ForeignTraffic(self.recorder, self.codec, lambda: self._marker[0], self.time)
            self.traffic = Traffic(
                self.codec,
                self.recorder,
                self._own,
                self._with_commands,
                echoes=self.config.interface == "udp_multicast",
                on_foreign=self._foreign_heard,
                secoc=self.secoc,
                on_rejected=self._rejected,
                control=self.control,
            )
            self.traffic.deliver = self._log_frame
            self.log.metadata(BUS, {key: str(value) for key, value in self.config.to_dict().items()})
        except BaseException:  # undo what was entered (signal handlers, the log, the bus), as __exit__ would
            stack.close()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        self._stack.close()

    def _record_sink(self) -> RecordSink:
        """The sink of a run that writes no log: what it hands everything to instead."""
        if not hasattr(self._sink, "message"):
            raise CosimError("a run without a log needs a sink that takes its records (its metrics: measure=True)")
        return cast(RecordSink, self._sink)

    # -- time ---------------------------------------------------------------------------------

    def time(self, k: int) -> tuple[float, int]:
        """t_k in seconds and in nanoseconds."""
        t_ns = k * round(self.timing.sample_time * 1e9)
        return t_ns / 1e9, t_ns

    def begin_log(self, detail: str, warnings: tuple[str, ...] | list[str] = ()) -> None:
        """The run's first events: how it starts, and the warnings known before tick 0."""
        self.event(0, "start", detail)
        for warning in warnings:
            self.event(0, "warning", warning, "warning")

    def event(self, k: int, event: str, detail: str = "", level: str = "info") -> None:
        self.recorder.event(k, *self.time(k), event, detail, level)

    # -- what does not belong -------------------------------------------------------------------

    def _foreign_datagram(self, datagram: ForeignDatagram) -> None:
        self.foreign.datagram(datagram)

    # -- waiting --------------------------------------------------------------------------------

    def wait(self, done: Callable[[], bool], deadline: float, on_timeout: Callable[[], None]) -> None:
        """Receive into the traffic until ``done()`` or the wall-clock ``deadline``, servicing the
        in-process participants and checking on the others."""
        last_check = time.perf_counter()
        while not done():
            self.interrupts.check()
            for participant in self.participants:
                participant.service()
            now = time.perf_counter()
            if now >= deadline:
                on_timeout()
                return
            for frame in drain(self.bus, min(_POLL, deadline - now)):
                self.traffic(frame)
            if len(self.traffic.pending) > _PENDING:  # a flood: log what came so far, keep memory bounded
                self.traffic.flush(*self._marker)
            if time.perf_counter() - last_check > _HEALTH:
                last_check = time.perf_counter()
                self._check_health()
        for frame in drain(self.bus):  # what else has arrived (a monitor's frames, late echoes)
            self.traffic(frame)

    def _check_health(self) -> None:
        for participant in list(self.participants):
            if (reason := participant.failure()) is None:
                continue
            if not participant.estimator_failed:  # died, killed, stopped: the run cannot be trusted
                raise NodeFailure(self._after_foreign(reason))
            self._drop(participant, reason)
        now = time.perf_counter()
        for participant in self.participants:
            stopped = self.traffic.left.get(participant.name)
            if participant.lockstep and stopped is not None and now - stopped > _LEFT_GRACE:
                raise NodeFailure(
                    f"{participant.kind} {participant.name} left the bus at tick {self._marker[0]} "
                    f"(stopped heartbeat) and answers no more"
                )

    def _drop(self, participant: Participant, reason: str) -> None:
        """An estimator node whose estimator raised leaves the run, which goes on without it: its
        estimates end at this tick, and the log and the result say why."""
        k = self._marker[0]
        self.participants.remove(participant)
        participant.stop(timeout=0.0)
        self.failed[participant.name] = f"failed at tick {k}: {last_words(reason)}"
        self.event(k, "node failed", reason, "error")
        self.warnings.append(
            f"estimator {participant.name} {self.failed[participant.name]}; the run went on without it"
        )

    @property
    def kernel_dropped(self) -> int:
        """Datagrams the kernel dropped before the runner read them (only a udp_multicast bus counts)."""
        return getattr(self.bus, "kernel_dropped", 0)

    def _after_foreign(self, reason: str) -> str:
        return self.foreign.report(reason, time.perf_counter() - self.start, self.kernel_dropped)

    def join(self) -> None:
        """Wait for the participants: every one must join (its boot-up heartbeat) before tick 0."""
        participants = self.participants
        expected = {p.name for p in participants}
        timeout = self.timing.join_timeout

        def late() -> None:
            self._check_health()
            missing = ", ".join(f"{p.kind} {p.name}" for p in participants if p.name not in self.traffic.joined)
            raise NodeFailure(
                f"{missing} did not join the bus {self.config.describe()} within {timeout:g} s "
                f"(raise [timing] join_timeout if it starts slowly)"
            )

        self.wait(lambda: expected <= self.traffic.joined, time.perf_counter() + timeout, late)
        self._refuse_a_second_runner()
        self.traffic.flush(*self._marker)  # the boot-up heartbeats
        if self.arbitration is not None:  # from tick 0 on, what the runner hears goes over the wire
            self.traffic.deliver = self.arbitration.answer
        self.tick_start = time.perf_counter()

    def _refuse_a_second_runner(self) -> None:
        """Before tick 0 nothing may arrive on the runner's own ids: if it does, another
        co-simulation sends on this group and port, and both runs would corrupt each other."""
        if self.traffic.own_foreign:  # frames on other ids before tick 0 are a flood's or a program's, counted
            raise CosimError(
                f"another co-simulation sends on {self.config.describe()} (frames on this run's SYNC, sensor or "
                f"command ids arrive that this run did not send: {self.foreign.last}); give this run another port, or "
                f"leave port and channel empty for fresh ones"
            )

    def _hung(self, tick: int, name: str | None = None) -> None:
        waiting = [
            p
            for p in self.participants
            if p.lockstep and self.traffic.closed.get(p.name, -1) < tick and name in (None, p.name)
        ]
        if any(p.name == CONTROLLER for p in waiting):
            waiting = [p for p in waiting if p.name == CONTROLLER]  # the others wait for its commands
        raise NodeFailure(self._after_foreign(waiting[0].hung(tick, self.timing.node_timeout)))

    def _deadline(self, k: int) -> float:
        """The wall-clock time by which tick k must be over (realtime)."""
        assert self.tick_start is not None
        return self.tick_start + k * self.timing.period

    # -- the phases of a tick ---------------------------------------------------------------------

    def begin(self, k: int) -> None:
        """Tick k starts: Ctrl-C is taken here; in realtime, not before its time."""
        self.interrupts.check()
        if self.timing.realtime:
            if time.perf_counter() > self._deadline(k) + max(self.timing.period, _BEHIND):
                self.late_ticks += 1
            self.wait(lambda: False, self._deadline(k), lambda: None)

    def send(self, k: int, frames: list[tuple[can.Message, Decoded | None]]) -> None:
        """Put the runner's frames of tick k on the bus; while the nodes work on them, log what the
        previous tick brought and these frames."""
        if self.secoc is not None:  # signed by their sender, before anything on the bus touches them
            for frame, _ in frames:
                self.secoc.sign(frame, k)
        applied = self._bus_faults(k, frames)
        frames = applied.frames if applied is not None else frames
        sign_control(self.control, k, frames, forged(applied))
        if applied is not None and applied.intruders:
            self.traffic.injected(k, [item[0] for item in frames if id(item) in applied.intruders])
        if self.secoc is not None:  # the runner hears these too: intruders' frames fail
            self.traffic.current = k
            for frame, _ in frames:
                self.traffic.verify(frame)
        if self.arbitration is not None:
            self._send_arbitrated(k, frames, applied)
            return
        self.traffic.current = k
        self.traffic.sent([frame for frame, _ in frames])
        send_all(self.bus, [frame for frame, _ in frames])
        self.traffic.flush(*self._marker)
        self.foreign.close_tick()
        t, t_ns = self.time(k)
        if k - self._flushed >= _FLUSH_TICKS and t - self.time(self._flushed)[0] >= _FLUSH_SIMULATED:
            self._flushed = k  # on disk whatever kills the runner later; at ticks, not wall time: deterministic
            self.log.flush()
        self._marker = (k, t, t_ns)
        for item in frames:
            self._log_frame(k, t, t_ns, *item)
            if applied is not None and id(item) in applied.intruders:
                self._intruder(item[0], applied.intruders[id(item)])
        self._verdicts(k)

    def _bus_faults(self, k: int, frames: list[tuple[can.Message, Decoded | None]]) -> Applied | None:
        """Tick k's frames through the bus faults; what they did goes to /truth/bus_faults."""
        if self.bus_faults is None:
            return None
        applied = self.bus_faults.apply(k, frames)
        t, t_ns = self.time(k)
        for event in applied.events:
            self.recorder.bus_fault(k, t, t_ns, vars(event))
        return applied

    def _log_frame(
        self, tick: int, t: float, t_ns: int, frame: can.Message, decoded: Decoded | None, sender: str | None = None
    ) -> None:
        """A frame into the log, at its arrival; the intrusion detector sees it there."""
        if sender is None:
            self.recorder.frame(tick, t, t_ns, frame, decoded)
        else:
            self.recorder.frame(tick, t, t_ns, frame, decoded, sender)
        if self.detector is not None:
            self.detector.frame(tick, t_ns, frame, decoded)

    def _foreign_heard(self, frame: can.Message, reason: str) -> None:
        """A frame the runner heard that nobody in the run sent (not a fault's intruder, which the
        detector must find by itself)."""
        if self.detector is not None:
            self.detector.foreign(self.traffic.current, frame)
        self.foreign.frame(frame, reason)

    def _rejected(self, frame: can.Message, rejection: Rejection) -> None:
        """A frame SecOC dropped, on /cosim/security at the tick the runner is in."""
        k = self.traffic.current
        spec = self.codec.spec_of(frame)
        self.recorder.security(
            k,
            *self.time(k),
            rejection.frame_id,
            spec.name if spec is not None else None,
            rejection.sender,
            rejection.reason,
            rejection.freshness,
            bytes(frame.data),
        )

    def _intruder(self, frame: can.Message, label: str) -> None:
        """An intruder's frame, just logged: foreign, whatever its id (the run knows it did not come
        from the id's owner), its record naming the fault (``source``) and the frame's place on /can/frames."""
        reason = f"sent by an intruder (fault {label}), not by the owner of its id"
        self.foreign.frame(frame, reason, self.recorder.frames - 1, label)

    def _send_arbitrated(
        self, k: int, frames: list[tuple[can.Message, Decoded | None]], applied: Applied | None
    ) -> None:
        """As ``send``, through the wire: the previous tick's answers join it first, then the wire
        says which of these frames arrive in this tick (``cosim.run.arbitration``)."""
        assert self.arbitration is not None
        self.traffic.current = k
        self.traffic.flush(*self._marker)
        self.foreign.close_tick()
        step = self.arbitration.tick(
            k, frames, applied.delays_ns if applied else None, applied.intruders if applied else None
        )
        # timed on the wire with the MAC at 0: no key changes timing
        sign_control(self.control, k, step.send, forged(applied, step.forged))
        self.traffic.sent([frame for frame, _ in step.send])
        send_all(self.bus, [frame for frame, _ in step.send])
        t, t_ns = self.time(k)
        if k - self._flushed >= _FLUSH_TICKS and t - self.time(self._flushed)[0] >= _FLUSH_SIMULATED:
            self._flushed = k
            self.log.flush()
        self._marker = (k, t, t_ns)
        self._log_passages(step.passed)
        self._verdicts(k)

    def _verdicts(self, k: int) -> None:
        """The detector's verdicts on the ticks before k: every frame of theirs is in the log."""
        if self.detector is not None:
            self.detector.publish(self.recorder, k, self.timing.sample_time)

    def _log_passages(self, passed: list[Transmission]) -> None:
        """Frames through the wire, at their delivery (the tick is the one it falls in), and every
        passage on /cosim/wire."""
        dt_ns = self.time(1)[1]
        for p in passed:
            message, decoded = p.frame.payload
            tick = p.delivered_ns // dt_ns
            if p.dropped is None:
                self._log_frame(tick, p.delivered_ns / 1e9, p.delivered_ns, message, decoded, p.frame.sender)
                if self.bus_faults is not None and p.frame.sender in self.bus_faults.intruder_labels:
                    self._intruder(message, p.frame.sender)
            bits = sum(bits_of(p.frame))
            self.recorder.wire(
                tick,
                p.delivered_ns,
                p.frame.frame_id,
                decoded.spec.name if decoded is not None else None,
                p.frame.sender,
                (p.frame.queued_ns, p.start_ns, p.delivered_ns),
                p.late,
                bits,
                p.dropped,
            )

    def commands(self, k: int, actuators: tuple[str, ...], held: np.ndarray) -> np.ndarray:
        """The controller node's commands of tick k: waited for (lockstep), or until the tick's
        deadline (realtime), where a late or missing command holds the actuator's last one."""
        traffic = self.traffic
        arrived = lambda: traffic.closed.get(CONTROLLER, -1) >= k  # noqa: E731
        if self.timing.realtime:
            self.wait(arrived, self._deadline(k + 1), lambda: None)
            if not arrived():
                self._miss(k, CONTROLLER)
        else:
            self.wait(arrived, time.perf_counter() + self.timing.node_timeout, lambda: self._hung(k, CONTROLLER))
        modulus = self.codec.tick_modulus
        got = traffic.commands.pop(k % modulus, {})
        for old in [tick for tick in traffic.commands if (k - tick) % modulus < modulus // 2]:
            del traffic.commands[old]
        return np.array([got.get(name, u) for name, u in zip(actuators, held)])

    def _miss(self, k: int, node: str) -> None:
        self.misses += 1
        self.recorder.deadline_miss(k, *self.time(k), node, self.misses)

    def end(self, k: int) -> None:
        """Tick k is over once every lockstep participant has answered it (lockstep, within the node
        timeout) or at its deadline (realtime, where each missing answer is a deadline miss)."""
        closed = self.traffic.closed
        if self.timing.realtime:
            self.wait(lambda: False, self._deadline(k + 1), lambda: None)
            for name in [p.name for p in self.participants if p.lockstep]:
                if closed.get(name, -1) < k and name != CONTROLLER:
                    self._miss(k, name)
        else:
            self.wait(  # over the participants still in the run: one that failed meanwhile is not waited for
                lambda: all(closed.get(p.name, -1) >= k for p in self.participants if p.lockstep),
                time.perf_counter() + self.timing.node_timeout,
                lambda: self._hung(k),
            )

    def progress(self, k: int, ticks: int) -> Progress:
        """Where the run is after ``k`` ticks."""
        since = self.tick_start if self.tick_start is not None else self.start  # a viewer's wait does not count
        return Progress(k, ticks, self.time(k)[0], time.perf_counter() - since, self.recorder.frames, self.misses)

    # -- the end --------------------------------------------------------------------------------

    def finish(self, k: int, status: str, error: str, senders: list[str]) -> RunResult:
        """End the run at tick k, however it ends: log what has arrived, stop the nodes (NMT stop),
        log what they sent until then and how the run ended (``cosim.result``). Signals do not
        interrupt this; a second one only makes it stop the nodes without waiting for them."""
        with self.interrupts.shielded():
            return self._finish(k, status, error, senders)

    def _finish(self, k: int, status: str, error: str, senders: list[str]) -> RunResult:
        loop = time.perf_counter() - self.tick_start if self.tick_start is not None else 0.0
        startup = self.tick_start - self.start if self.tick_start is not None else 0.0
        t_end, t_end_ns = self.time(k)
        self._stop_nodes(k, t_end, t_end_ns, status)
        self.traffic.flush(k, t_end, t_end_ns)
        if self.arbitration is not None:
            self._log_passages(self.arbitration.finish())
        self._verdicts(k)
        self.foreign.close_tick()
        contested, dropped = len(self.traffic.contested), self.kernel_dropped
        achieved = t_end / loop if loop > 0 else float("inf")
        self.warnings += self.traffic.contested_warning() + [
            *fell_behind(self.late_ticks, k, self.timing.speed, achieved, _BEHIND),
            *kernel_drops(dropped),
        ]
        for warning in self.warnings:
            self.event(k, "warning", warning, "warning")
        counts = self.traffic.sender_counts(k, senders, {p.name for p in self.participants if p.lockstep})
        lost = sum(c.lost + c.runner_frames_missed for c in counts.values())
        self.event(
            k, "stop", status if not error else f"{status}: {error}", "info" if status == "completed" else "error"
        )
        self.log.metadata(
            RESULT,
            ResultRecord(
                status,
                k,
                self.recorder.frames,
                lost,
                self.misses,
                error,
                counts,
                self.foreign.counts,
                self.failed,
                self.late_ticks,
                contested,
                dropped,
            ).to_metadata(),
        )
        self.result = RunResult(
            self.out,
            status,
            k,
            self.recorder.frames,
            lost,
            time.perf_counter() - self.start,
            t_end,
            error,
            self.misses,
            {name: vars(c) for name, c in counts.items()},
            startup,
            loop,
            dict(self.failed),
            self.late_ticks,
            contested,
            dropped,
            list(self.warnings),
        )
        return self.result

    def _stop_nodes(self, k: int, t_end: float, t_end_ns: int, status: str) -> None:
        """Log what came before the stop command, send it (NMT stop), wait for the nodes to exit and
        take the frames they still send, while they come."""
        traffic, codec = self.traffic, self.codec
        for frame in drain(self.bus):  # what is already here came before the stop command
            traffic(frame)
        traffic.flush(*self._marker)
        stop = codec.nmt(NMT_STOP)
        if self.control is not None:
            self.control.sign(stop, k)
        traffic.sent([stop])
        try:
            self.bus.send(stop)
        except can.CanError:
            pass
        self.recorder.frame(k, t_end, t_end_ns, stop, codec.decode(stop))
        for participant in self.participants:
            warning = participant.stop(timeout=_STOP_HURRY if self.interrupts.hurry else _STOP)
            if warning is not None and status == "completed":
                self.warnings.append(warning)
        if silent(self.bus):  # no other bus is open on the in-process channel: what it holds is all
            for frame in drain_silent(self.bus):
                traffic(frame)
            return
        quiet_until, end = time.perf_counter() + 0.1, time.perf_counter() + _LAST_FRAMES
        while (now := time.perf_counter()) < min(quiet_until, end):
            for frame in drain(self.bus, min(0.02, end - now)):
                traffic(frame)
                quiet_until = time.perf_counter() + 0.1
