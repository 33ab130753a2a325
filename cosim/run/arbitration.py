"""Arbitrated timing (``[bus] timing = "arbitrated"``): what the run's receivers get, and when.

The run's python-can channel carries frames instantly; the simulated wire (``cosim.bus.wire``)
says when each would have arrived on a real bus. ``Arbitration`` joins the two, tick by tick, in
lockstep (it needs every answer of a tick before it can schedule the next):

1. at t_k the runner queues SYNC(k) and its data frames of tick k; the nodes' answers to tick
   k − 1 were queued at q_{k−1}, the moment those nodes had their inputs (below); the periodic
   traffic of ``[[bus.traffic]]`` is queued at its own times;
2. the wire is planned up to t_{k+1}: the runner's data frames delivered by then are tick k's
   inputs; SYNC(k) announces how many (its own length depends on that number through its stuff
   bits, so the count is found by iterating to a fixed point) and they go on the channel now;
   the others stay queued: they go on the channel when the wire delivers them, late (receivers
   ignore a frame of an earlier tick), or never, when the next tick's frame of the same id
   replaces them first;
3. q_k, when the receivers have tick k's inputs, is the delivery of SYNC(k) or of the last input
   delivered, whichever is later (t_{k+1} when SYNC(k) itself is not through by then); the wire
   is committed up to q_k (what follows depends on the answers, which are not known yet) and every
   committed frame is logged at its delivery time, with its passage on ``/cosim/wire``.

SYNC, NMT and heartbeats are the co-simulation's protocol: they take their time on the wire like
any frame, but the channel carries them as today, so lockstep never waits for a frame the wire
holds. The controller node's commands are applied in the tick they answer (their latency is
logged); the nodes read each other's frames on the channel without the wire's delay.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import can
import numpy as np

import faults as fm
from cosim.bus.codec import RUNNER, Codec, Decoded
from cosim.bus.timing import frame_bits_rows
from cosim.bus.wire import Transmission, Wire, WireFrame, dlc_of
from cosim.errors import CodecError
from cosim.run.busfaults import counted_by_receivers

#: Spawn key of the periodic traffic's payload streams (the faults and disturbances use others).
_TRAFFIC = 0xB5

Frame = tuple[can.Message, Decoded | None]


@dataclass(frozen=True)
class Periodic:
    """One ``[[bus.traffic]]`` node: a frame of ``length`` bytes on ``frame_id`` every ``period_ns``."""

    name: str
    frame_id: int
    period_ns: int
    length: int
    start_ns: int
    end_ns: int
    fd: bool
    rng: np.random.Generator = field(compare=False)

    def _first(self, begin_ns: int) -> int:
        """The number of its first frame queued at or after ``begin_ns`` (0: the one at its start)."""
        return -(-(max(self.start_ns, begin_ns) - self.start_ns) // self.period_ns)

    def due(self, begin_ns: int, end_ns: int) -> bool:
        """Whether it queues a frame in [begin_ns, end_ns) (``frames`` would give one)."""
        return self.start_ns + self._first(begin_ns) * self.period_ns < min(end_ns, self.end_ns)

    def frames(self, begin_ns: int, end_ns: int) -> list[can.Message]:
        """Its frames queued in [begin_ns, end_ns), stamped with their queue time (``timestamp``, s).
        A frame's payload is the first ``length`` bytes of ⌈length / 4⌉ uniform 32-bit words of its
        stream, little-endian (the bytes ``integers(0, 256, length, dtype=uint8)`` gives, frame by
        frame: ``tests/test_quiet_wire.py``), drawn for the interval's frames at once."""
        first = self._first(begin_ns)
        count = max(0, -(-(min(end_ns, self.end_ns) - self.start_ns) // self.period_ns) - first)
        if count == 0:
            return []
        words = -(-self.length // 4)
        drawn = self.rng.integers(0, 2**32, (count, words), dtype=np.uint32).astype("<u4", copy=False)
        payloads = drawn.view(np.uint8).reshape(count, 4 * words)[:, : self.length].tobytes()
        out = []
        for i in range(count):
            data = payloads[i * self.length : (i + 1) * self.length]
            message = can.Message(arbitration_id=self.frame_id, is_extended_id=False, data=data, is_fd=self.fd)
            message.timestamp = (self.start_ns + (first + i) * self.period_ns) / 1e9
            out.append(message)
        return out


@dataclass
class Step:
    """What one tick of arbitration gives the session: frames to put on the channel now (in order)
    and the wire's committed passages, to log."""

    send: list[Frame]
    passed: list[Transmission]
    forged: set[int] = field(default_factory=set)
    """Frames of ``send`` an intruder queued in an earlier tick (by ``id()``): they go as forged."""


@dataclass
class Quiet:
    """What a quiet tick of arbitration gives (``quiet_ticks``): the frames to put on the channel
    now, in order, and the frames the wire delivered, each with its delivery (ns), in the order of
    the passages ``Arbitration.tick`` would give."""

    send: list[Frame]
    delivered: list[tuple[int, Frame]]


class Arbitration:
    """The run's wire, fed tick by tick (see the module's docstring)."""

    def __init__(
        self,
        codec: Codec,
        bitrate: int,
        data_bitrate: int,
        dt_ns: int,
        traffic: list[Periodic] | None = None,
        authenticated: bool = False,
    ) -> None:
        self.codec = codec
        # SYNC announces the frames receivers count (``cosim.run.busfaults.counted_by_receivers``): one counted that
        # they do not take would leave them waiting for it.
        self.authenticated = authenticated
        self.wire = Wire(bitrate, data_bitrate)
        self.dt_ns = dt_ns
        self.traffic = traffic or []
        self._answers: list[Frame] = []
        self._delays: dict[int, int] = {}
        self._senders: dict[int, str] = {}
        self._on_channel: set[int] = set()  # runner frames already on the channel, by id()
        self._runner: set[int] = set()  # the runner's data frames still on the wire, by id()
        self._forged: set[int] = set()  # of those, an intruder's (``senders``), by id()
        self._inputs_ns = 0  # q_{k−1}: when the receivers had the previous tick's inputs

    def answer(self, tick: int, t: float, t_ns: int, frame: can.Message, decoded: Decoded | None) -> None:
        """A frame the runner heard (through ``Traffic.flush``, in canonical order): onto the wire
        at the next tick, as queued when its sender had its inputs."""
        self._answers.append((frame, decoded))

    def _wire_frame(self, frame: Frame, queued_ns: int, deadline_ns: int, sender: str) -> WireFrame:
        message, decoded = frame
        sender = decoded.spec.sender if decoded is not None else sender
        data = bytes(message.data)
        at = _mac_at(self.codec, message.arbitration_id, message.is_extended_id)
        if at is not None:
            data = data[:at] + bytes(len(data[at:]))  # a frame too short for its MAC (a fuzzer's) as it is
        return WireFrame(
            message.arbitration_id,
            message.is_extended_id,
            message.is_fd,
            message.bitrate_switch,
            data,
            sender,
            queued_ns,
            deadline_ns,
            frame,
        )

    def _runner_frame(self, frame: Frame, t_ns: int, deadline: int) -> WireFrame:
        wire_frame = self._wire_frame(frame, t_ns + self._delays.get(id(frame), 0), deadline, RUNNER)
        wire_frame.sender = self._sender(frame, self._senders)
        return wire_frame

    def tick(
        self,
        k: int,
        frames: list[Frame],
        delays_ns: dict[int, int] | None = None,
        senders: dict[int, str] | None = None,
    ) -> Step:
        """Tick k's frames of the runner (SYNC(k) first): schedule them, commit the wire up to q_k.
        ``delays_ns``: frames queued that much after t_k; ``senders``: frames of another sender
        than their id's owner (an intruder), both by ``id()`` of the frame."""
        self._delays, self._senders = delays_ns or {}, senders or {}
        t_ns, deadline = k * self.dt_ns, (k + 1) * self.dt_ns
        wire = self.wire
        for answer in self._answers:  # the answers to tick k − 1, due by t_k
            wire.offer(self._wire_frame(answer, self._inputs_ns, t_ns, "unknown"))
        self._answers = []
        for source in self.traffic:
            for message in source.frames(t_ns, deadline):
                queued = round(message.timestamp * 1e9)
                wire.offer(self._wire_frame((message, None), queued, queued + source.period_ns, source.name))
        # what starts before t_k is decided: no frame offered from here on is queued before it, so
        # the plan (and the wire) goes on from there, without simulating those passages twice
        early = wire.run(t_ns)
        data = frames[1:]
        sync, inputs, planned, offered = self._plan(k, data, t_ns, deadline)
        for wire_frame in offered:  # as the plan offered them: its passages are the wire's to come
            wire.offer(wire_frame)
        sync_at = next((p.delivered_ns for p in planned if p.frame.payload is sync and p.dropped is None), None)
        if sync_at is None or sync_at > deadline:
            self._inputs_ns = deadline
        else:
            self._inputs_ns = max([sync_at, *(p.delivered_ns for p in planned if id(p.frame.payload) in inputs)])
        passed = early + wire.commit(planned, min(self._inputs_ns, deadline))
        now = [frame for frame in data if id(frame) in inputs]
        self._on_channel.update(inputs)
        self._runner.update(id(frame) for frame in data)
        self._forged.update(id(frame) for frame in data if id(frame) in self._senders)
        late, forged = [], set()
        for p in passed:
            payload = p.frame.payload
            if p.dropped is None and id(payload) in self._runner and id(payload) not in self._on_channel:
                late.append(payload)  # a runner frame the wire delivers after its tick: on the channel now
                if id(payload) in self._forged:
                    forged.add(id(payload))
            self._on_channel.discard(id(payload))
            self._runner.discard(id(payload))
            self._forged.discard(id(payload))
        return Step([sync, *now, *late], passed, forged)

    def _plan(
        self, k: int, data: list[Frame], t_ns: int, deadline: int
    ) -> tuple[Frame, set[int], list[Transmission], list[WireFrame]]:
        """SYNC(k) announcing the data frames through by the deadline, those frames (by id()), the
        planned passages and the wire frames they were planned with (SYNC's first)."""
        counted = counted_by_receivers(data, self._senders, self.authenticated, k % self.codec.tick_modulus)
        count, seen = len(counted), []
        while True:
            message = self.codec.sync(k, count)
            sync: Frame = (message, self.codec.decode(message))
            trial = self.wire.fork()
            offered = [self._runner_frame(frame, t_ns, deadline) for frame in [sync, *data]]
            for wire_frame in offered:
                trial.offer(wire_frame)
            planned = trial.run(deadline)
            through = {id(p.frame.payload) for p in planned if p.dropped is None and p.delivered_ns <= deadline}
            inputs = [id(f) for f in counted if id(f) in through]
            seen.append(count)
            if len(inputs) == count or len(seen) > 4:
                # no fixed point (SYNC's stuff bits tip one frame over the deadline and back): the
                # smaller count is announced and the frames past it are held back as late
                uncounted = {id(f) for f in data if id(f) in through} - {id(f) for f in counted}
                return sync, set(inputs[:count]) | uncounted, planned, offered
            count = min(count, len(inputs)) if len(inputs) in seen else len(inputs)

    def quiet(self, k: int, frames: list[Frame], senders: dict[int, str]) -> tuple[bool, ...] | None:
        """Which data frames of the runner's ``frames`` (SYNC first; none delayed; ``senders``: the
        intruders' frames, by ``id()``) its receivers count, if tick k is quiet on this wire
        (``quiet_ticks``); None if it is not: something from before still on the wire, answers to
        tick k − 1 on one id, a background frame due in the tick, or two frames of the tick (SYNC
        included) on one id from one sender (the newer replaces the older)."""
        t_ns, data = k * self.dt_ns, frames[1:]
        ids = [message.arbitration_id for message, _ in self._answers]
        if (
            self.wire.queue
            or self._runner
            or self._on_channel
            or any(a >= b for a, b in zip(ids, ids[1:]))
            or any(source.due(t_ns, t_ns + self.dt_ns) for source in self.traffic)
        ):
            return None
        owners = {(self._sender(frame, senders), frame[0].arbitration_id) for frame in frames}
        if len(owners) < len(frames):  # SYNC's included: an intruder may send on its id in its name
            return None
        counted = counted_by_receivers(data, senders, self.authenticated, k % self.codec.tick_modulus)
        kept = {id(frame) for frame in counted}
        return tuple(id(frame) in kept for frame in data)

    @staticmethod
    def _sender(frame: Frame, senders: dict[int, str]) -> str:
        """Who a frame of the runner's is sent by on the wire (``_runner_frame``)."""
        if id(frame) in senders:
            return senders[id(frame)]
        return frame[1].spec.sender if frame[1] is not None else RUNNER

    def settle(self, offered: int, idle_ns: int, inputs_ns: int) -> None:
        """The state ``tick`` leaves after a quiet tick in which ``offered`` frames went out, the
        last one's receivers having it at ``inputs_ns`` and the wire idle from ``idle_ns`` (its
        queue and the runner's frames in flight stay empty)."""
        self.wire.idle_ns, self.wire._seq = idle_ns, self.wire._seq + offered
        self._inputs_ns, self._answers = inputs_ns, []

    def finish(self) -> list[Transmission]:
        """The end of the run: the answers heard last and everything still queued go out."""
        for answer in self._answers:
            self.wire.offer(self._wire_frame(answer, self._inputs_ns, self._inputs_ns + self.dt_ns, "unknown"))
        self._answers = []
        return self.wire.drain()


def _mac_at(codec: Codec, frame_id: int, extended: bool) -> int | None:
    """Where a control frame's MAC starts (None: no control frame): the wire times it with the MAC
    at 0, so that a run's (random) key changes no timing."""
    control = None if extended else codec.control_macs.get(frame_id)
    return None if control is None else control[1].mac[0]


def quiet_ticks(
    arbitrations: Sequence[Arbitration],
    k: int,
    frames_of: Sequence[list[Frame] | None],
    senders_of: Sequence[dict[int, str]] | None = None,
) -> list[Quiet | None]:
    """Tick k of the wires of K runs of one design (a batch) that are quiet, on arrays: for each,
    what ``Arbitration.tick`` gives and leaves, or None where it must be run (``frames_of``: each
    run's frames, SYNC first, none delayed; None: a run to leave out; ``senders_of``: each run's
    intruders' frames, by ``id()``, as ``tick`` takes them).

    A tick is quiet when the wire holds nothing from before, the answers to tick k − 1 (all
    queued at q_{k−1}) are on ids of their own and start before t_k, no background frame is due,
    and SYNC(k) and every frame of the runner's (all queued at t_k) are delivered by t_{k+1}.
    Every contest is then between frames all queued when the wire falls idle, so the wire sends
    them by (id, offer), each from the end of the one before: the answers' passages from
    max(idle, q_{k−1}), the runner's from the later of their end and t_k, as cumulative sums of
    the frames' durations (``frame_bits_rows``, their stuff bits on arrays). SYNC(k) announces
    the frames the receivers count (the fixed point of ``_plan`` at once: all are through), q_k
    is the last delivery, and the wire is committed to it with nothing late or left queued."""
    out: list[Quiet | None] = [None] * len(arbitrations)
    groups: dict[tuple[Any, ...], list[int]] = {}
    for r, (arbitration, frames) in enumerate(zip(arbitrations, frames_of)):
        if frames is None:
            continue
        counted = arbitration.quiet(k, frames, senders_of[r] if senders_of is not None else {})
        if counted is not None:
            wire = arbitration.wire  # one design's runs share these; the key holds them all the same
            design = (id(arbitration.codec), wire.bitrate, wire.data_bitrate, arbitration.dt_ns)
            key = (design, _layout(arbitration._answers), _layout(frames[1:]), counted)
            groups.setdefault(key, []).append(r)
    for (_, _, _, counted), rows in groups.items():
        found = _quiet_rows(k, [arbitrations[r] for r in rows], [frames_of[r] or [] for r in rows], counted)
        for r, quiet in zip(rows, found):
            out[r] = quiet
    return out


def _layout(frames: list[Frame]) -> tuple[tuple[int, bool, bool, bool, int], ...]:
    """What a frame's time on the wire depends on, but for its payload's bits."""
    return tuple((m.arbitration_id, m.is_extended_id, m.is_fd, m.bitrate_switch, len(m.data)) for m, _ in frames)


def _quiet_rows(
    k: int, arbitrations: list[Arbitration], frames_of: list[list[Frame]], counted: tuple[bool, ...]
) -> list[Quiet | None]:
    """``quiet_ticks`` of runs whose answers and frames have one layout (``_layout``), the same of
    whose data frames ``counted``."""
    first = arbitrations[0]
    codec, wire, t_ns = first.codec, first.wire, k * first.dt_ns
    answers = len(first._answers)
    try:
        syncs = codec.syncs(k, sum(counted), len(frames_of))
    except CodecError:  # more frames than a SYNC can announce: each run's ``tick`` says so
        return [None] * len(arbitrations)
    sync_decoded = codec.decode(syncs[0])  # the same bytes in every run (each its own frame: it is signed)
    sent = [[(sync, sync_decoded), *frames[1:]] for sync, frames in zip(syncs, frames_of)]
    rows = [
        [m for m, _ in arbitration._answers] + [m for m, _ in frames] for arbitration, frames in zip(arbitrations, sent)
    ]
    idle = np.array([arbitration.wire.idle_ns for arbitration in arbitrations], dtype=np.int64)
    queued = np.array([arbitration._inputs_ns for arbitration in arbitrations], dtype=np.int64)
    order = answers + np.argsort([m.arbitration_id for m in rows[0][answers:]], kind="stable")
    ok, delivered_at, ends_at = quiet_schedule(
        wire, t_ns, first.dt_ns, _bits_of_columns(codec, rows), idle, queued, answers, order
    )
    delivered, ends = delivered_at.tolist(), ends_at.tolist()
    out: list[Quiet | None] = []
    for r, arbitration in enumerate(arbitrations):
        if not ok[r]:
            out.append(None)
            continue
        frames = [*arbitration._answers, *(sent[r][j - answers] for j in order.tolist())]
        arbitration.settle(len(rows[r]), ends[r], delivered[r][-1])
        out.append(Quiet(sent[r], list(zip(delivered[r], frames))))
    return out


def quiet_schedule(
    wire: Wire,
    t_ns: int,
    dt_ns: int,
    bits: tuple[np.ndarray, np.ndarray],
    idle: np.ndarray,
    queued: np.ndarray,
    answers: int,
    order: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The passages of a quiet tick k (``quiet_ticks``) of R wires laid out alike: frames of
    ``bits`` (nominal, data-rate; each (R, F)), the first ``answers`` of them the answers to tick
    k − 1 (queued at ``queued``, in the order they go), the others the runner's, which go in
    ``order`` (their columns, by id); each wire idle from ``idle`` (R,). Whether each is quiet,
    each frame's delivery (ns, (R, F): the answers', then the runner's in ``order``) and when the
    wire falls idle again, as ``Arbitration.tick`` finds them."""
    total, delivery = wire.durations_rows(*bits)
    starts = np.maximum(idle, queued)[:, None] + np.cumsum(total[:, :answers], axis=1) - total[:, :answers]
    idle = starts[:, -1] + total[:, answers - 1] if answers else idle
    ahead = np.cumsum(total[:, order], axis=1) - total[:, order]
    runner = np.maximum(idle, t_ns)[:, None] + ahead
    arrivals = runner + delivery[:, order]  # in the order they go: q_k is the last
    ok = arrivals[:, -1] <= t_ns + dt_ns
    if answers:
        ok &= starts[:, -1] < t_ns  # the answers all went out before t_k
    delivered = np.concatenate([starts + delivery[:, :answers], arrivals], axis=1)
    return ok, delivered, runner[:, -1] + total[:, order[-1]]


def _bits_of_columns(codec: Codec, rows: list[list[can.Message]]) -> tuple[np.ndarray, np.ndarray]:
    """(nominal, data-rate) bits of frames laid out alike in every row (R, F) (``bits_of_payloads``)."""
    heads = [(m.arbitration_id, m.is_extended_id, m.is_fd, m.bitrate_switch, len(m.data)) for m in rows[0]]
    payloads = [
        np.frombuffer(b"".join(bytes(row[c].data) for row in rows), dtype=np.uint8).reshape(len(rows), heads[c][4])
        for c in range(len(heads))
    ]
    return bits_of_payloads(codec, heads, payloads)


def bits_of_payloads(
    codec: Codec, heads: Sequence[tuple[int, bool, bool, bool, int]], payloads: Sequence[np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    """(nominal, data-rate) bits of R rows of frames laid out alike (R, F): frame c has the id,
    extended flag, FD and BRS flags and length of ``heads[c]`` and the payloads ``payloads[c]``
    (R, length) uint8, a control frame's MAC at 0 (as ``Arbitration._wire_frame`` times it): the
    columns of one kind and length at once (``frame_bits_rows``)."""
    by_kind: dict[tuple[bool, bool, int], list[int]] = {}
    for c, (_, _, fd, brs, length) in enumerate(heads):
        by_kind.setdefault((fd, brs, length), []).append(c)
    runs = len(payloads[0]) if payloads else 0
    nominal = np.empty((runs, len(heads)), dtype=np.int64)
    fast = np.empty_like(nominal)
    for (fd, brs, length), columns in by_kind.items():
        data = np.stack([payloads[c] for c in columns]).astype(np.uint8)  # (C, R, length), a copy
        for i, c in enumerate(columns):
            at = _mac_at(codec, heads[c][0], heads[c][1])
            if at is not None:
                data[i, :, at:] = 0
        bits, fast_bits = frame_bits_rows(
            [heads[c][0] for c in columns],
            [heads[c][1] for c in columns],
            [dlc_of(length)] * len(columns),
            data,
            fd,
            brs,
        )
        nominal[:, columns] = bits.T
        fast[:, columns] = fast_bits.T
    return nominal, fast


def build_traffic(scenario: object, babblers: list[fm.BabblingNode] | None = None) -> list[Periodic]:
    """The scenario's ``[[bus.traffic]]`` nodes and babbling-node faults, payloads drawn from its seed."""
    s = scenario
    out = []
    for j, babbler in enumerate(babblers or []):
        out.append(
            Periodic(
                babbler.label,
                babbler.frame_id,
                max(1, round(babbler.period * 1e9)),
                babbler.length,
                round(babbler.start * 1e9),
                2**62 if babbler.end == float("inf") else round(babbler.end * 1e9),
                bool(s.bus.fd),  # type: ignore[attr-defined]
                np.random.default_rng(np.random.SeedSequence(s.seed, spawn_key=(_TRAFFIC, 0x100 + j))),  # type: ignore[attr-defined]
            )
        )
    for i, spec in enumerate(s.bus.traffic):  # type: ignore[attr-defined]
        end_ns = 2**62 if spec.end == float("inf") else round(spec.end * 1e9)
        rng = np.random.default_rng(np.random.SeedSequence(s.seed, spawn_key=(_TRAFFIC, i)))  # type: ignore[attr-defined]
        out.append(
            Periodic(
                spec.name,
                spec.id,
                round(spec.period * 1e9),
                spec.length,
                round(spec.start * 1e9),
                end_ns,
                bool(s.bus.fd),  # type: ignore[attr-defined]
                rng,
            )
        )
    return out
