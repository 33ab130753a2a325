"""The arbitrated in-process bus of a batch (``[bus] timing = "arbitrated"``): each run's own wire,
bus faults, nodes' protocol and intrusion detector, fed tick by tick with exactly the frames the run
puts on its bus alone.

Alone, an arbitrated in-process run (``cosim.run.session.Session._send_arbitrated``) sends, at each
tick k, the runner's frames through its ``BusFaultStage`` onto its ``Arbitration``, whose wire also
carries the nodes' answers to tick k − 1 (as its ``Traffic`` heard them, in canonical order) and the
periodic traffic (``[[bus.traffic]]``, babbling nodes); the frames the wire lets through in their
tick go on the in-process channel with SYNC(k) announcing them, the late ones after, and each node
takes what it needs (``Client.feed``: its ``TickAssembler``, SYNC's and upstream heartbeats' MACs).
What the wire delivers is logged at its delivery time: the intrusion detector checks it there, and
the scores read the estimators' frames from there.

A batch keeps, per run, those very objects (``_RunWire``, built as ``RunPlan.session`` builds them)
and drives them as the session does: the runner's frames (``runner_frames``) through the stage,
``Arbitration.tick``, the control frames signed (``sign_control``), the frames on an in-process
channel of the run's own. Each node is its ``Client`` on that channel (``node_client``, its keys
and upstream from its ``NodeSpec``): it takes its tick as alone (which readings, which commands,
late frames and second copies, what its heartbeat counts as missed), then publishes what the batch
computed for it on arrays (``Client.publish``, ``done``: its frames, saturated or not, and its
heartbeat), which the run's ``Traffic`` hears, counts and hands to the wire at the next tick. The
wire's deliveries go to the run's ``IntrusionDetector`` and, for the estimators' frames, to its
``Scorer`` (``Scorer.estimate``, ``verdict``, ``state``, ``faults``), in the order its log would
hold them: a frame the wire replaced never reaches the scores, as alone.

Not built, as a batched run builds no log: the frames' and passages' records, the bus load, the
foreign frames' records. A run whose nodes would not complete a tick, or whose runner would reject
a node's frame, leaves the batch (and runs alone).
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from typing import Any

import can
import numpy as np

from cosim.analysis.metrics.scorer import BusVerdicts, Scorer, TickBatch
from cosim.bus.client import Client, TickFrames
from cosim.bus.codec import CONTROLLER, HEARTBEAT, NMT, SYNC, Codec, Decoded, MessageSpec
from cosim.bus.inprocess import InProcessBus
from cosim.bus.secoc import Rejection
from cosim.bus.transport import allocate, drain, open_bus, send_all
from cosim.errors import CodecError, CosimError
from cosim.log.metadata import SenderCounts
from cosim.log.recorder import IDS_CHECKS
from cosim.log.topics import Signals, message_topic
from cosim.log.writer import read_back
from cosim.run.arbitration import Arbitration, Quiet, quiet_ticks
from cosim.run.busfaults import Applied
from cosim.run.loop import runner_frames
from cosim.run.node import node_client
from cosim.run.plan import RunPlan
from cosim.run.signing import forged, sign_control
from cosim.run.traffic import Traffic
from cosim.scenario.faults import build_bus_faults

Frame = tuple[can.Message, Decoded | None]
_SIGNED = (SYNC, NMT, HEARTBEAT)  # the control frames: their MAC is written when they are sent


def refusal(plan: RunPlan) -> str | None:
    """Why a batch cannot give the arbitrated bus of ``plan``'s runs (None: it can)."""
    if plan.authenticated:
        return "its frames are authenticated (SecOC) on an arbitrated wire"
    return None


class _RunWire:
    """One run's bus in a batch: its wire, bus faults, detector, runner's traffic and nodes' clients."""

    def __init__(self, plan: RunPlan, scorer: Scorer) -> None:
        s = plan.scenario
        self.codec, self.dt_ns, self.scorer = plan.codec, s.dt_ns, scorer
        models = build_bus_faults(s)  # one list for both, as the session has it
        arbitration = plan.arbitration(models)
        assert arbitration is not None
        self.arbitration: Arbitration = arbitration
        self.stage = plan.bus_fault_stage(models)
        self.detector = plan.intrusion_detector()
        self.control = plan.control()
        self.rejected = ""
        # the frames on the run's channel since its last tick began (the runner's, its nodes'),
        # decoded once for all who take them, by id(): a frame held here keeps its id its own
        self.decoded: dict[int, Frame] = {}
        config = allocate("virtual")  # a channel of its own
        self.bus = open_bus(config)
        self.traffic = Traffic(
            self.codec,
            None,
            plan.own_senders,
            plan.controller is not None,
            on_foreign=self._foreign,
            on_rejected=self._rejected,
            control=self.control,
            deliver=self._logged,
            decode=self._decode,
        )
        names = [*plan.estimators, *([CONTROLLER] if plan.controller is not None else [])]
        self.nodes: dict[str, Client] = {}
        for name in names:
            client = self.nodes[name] = node_client(plan.node_spec(name, config), self.codec, open_bus(config), name)
            client.decoded = self.decoded  # what its frames decode to, for the runner and the other nodes
            client.join()
        self._hear()
        self.traffic.flush(0, 0.0, 0)  # the boot-ups, as the session logs them when its nodes have joined
        self.traffic.deliver = self.arbitration.answer  # from tick 0 on, what the runner hears goes over the wire
        self.marker = 0  # the tick whose heard frames are still to be handed on (``Session._marker``)
        self.untouched = False  # whether the bus faults let the runner's frames of this tick through as built
        self.clean = -1  # the last tick whose frames went on the channel as the runner built them, all in time
        self.announced: list[can.Message] = []  # the frames the runner put on the channel in its last tick
        self.sync: Decoded | None = None  # their SYNC, decoded, where the tick is clean
        self.answering: list[str] = []  # the nodes that answered the runner's last tick, in order
        self.heard = False  # whether the answers to the last tick were heard at once (``_heard_answers``)
        # a tick's truth not given to the scorer yet: (tick, states (K, states), the run's row, their
        # names, its active faults); held until the next tick's frames say whether it is scored whole
        self.held: tuple[int, np.ndarray, int, Sequence[str], tuple[str, ...]] | None = None
        #: The messages whose frames the scorer reads (the estimators')
        self.estimated = {name for name in self.codec.specs if message_topic(name) in scorer.owner}

    def prepare(self, k: int, frames: list[Frame]) -> tuple[list[Frame], Applied | None]:
        """Tick k's frames of the runner (SYNC first) through its bus faults, and the answers to tick
        k − 1 onto the wire, as ``Session.send`` has them on an arbitrated bus: the frames for the
        wire, and what the bus faults did."""
        applied = self.stage.apply(k, frames) if self.stage is not None else None
        self.untouched = applied is None or _passed(frames, applied)
        if applied is not None:
            frames = applied.frames
            if applied.intruders:
                self.traffic.injected(k, [item[0] for item in frames if id(item) in applied.intruders])
        self.heard = self._heard_answers(k)
        if not self.heard:
            self._hear()
            self.traffic.current = k
            self.traffic.flush(self.marker, 0.0, 0)  # the answers to tick k − 1 onto the wire
        self.traffic.current = k
        return frames, applied

    def _heard_answers(self, k: int) -> bool:
        """The nodes' answers to tick k − 1 heard and handed to the wire at once, where the runner's
        channel holds exactly those, in the order the nodes answered (``Traffic.answered``)."""
        if self.marker != k - 1 or not isinstance(self.bus, InProcessBus):
            return False
        closings = [self.nodes[name].closing for name in self.answering]
        if [id(frame) for frame in self.bus.waiting()] != [id(frame) for frames in closings for frame in frames]:
            return False
        self.traffic.current = k - 1
        answers = [[(frame, self._decode(frame)) for frame in frames] for frames in closings]
        if not self.traffic.answered(answers, 0.0, 0):
            return False
        self.bus.discard()
        self.traffic.commands.clear()  # as ``_hear``
        return True

    def send(self, k: int, frames: list[Frame], applied: Applied | None, quiet: Quiet | None) -> dict[str, int] | None:
        """The wire's tick k (``quiet``, or ``Arbitration.tick``): what it lets through goes on the
        run's channel, what it delivered to the detector and the scores. Where tick k − 1 is scored
        whole (``_whole``), the detector's verdict on it (each check's count; ``{}`` without a
        detector) is returned instead, for the batch to score the tick (``TickBatch``); None where
        its parts went to the scorer."""
        whole = self._whole(k, frames, quiet)
        if not whole:
            self._give_truth()
        self.clean = k if quiet is not None and self.untouched else -1
        step = None
        if quiet is None:
            step = self.arbitration.tick(
                k, frames, applied.delays_ns if applied else None, applied.intruders if applied else None
            )
            quiet = Quiet(step.send, [(p.delivered_ns, p.frame.payload) for p in step.passed if p.dropped is None])
        sign_control(self.control, k, quiet.send, forged(applied, step.forged if step is not None else ()))
        # what a receiver decodes from each data frame (the wire's payload; a control frame, signed
        # just now, is decoded as it is sent): decoded once for all the run's nodes. Everything
        # heard of the last tick is taken (``prepare``)
        self.decoded.clear()
        self.decoded.update((id(f[0]), f) for f in quiet.send if f[1] is None or f[1].spec.role not in _SIGNED)
        self.announced = [frame for frame, _ in quiet.send]
        self.answering = []
        self.sync = quiet.send[0][1] if self.clean == k else None
        send_all(self.bus, self.announced)
        self.marker = k
        self._passages(quiet.delivered, scored=not whole)
        if not whole:
            self._verdicts(k)
            return None
        self.held = None
        return self.detector.verdicts(k)[0][1] if self.detector is not None else {}

    def _whole(self, k: int, frames: list[Frame], quiet: Quiet | None) -> bool:
        """Whether tick k − 1's scores are given whole at tick k (``TickBatch``, on the batch's
        arrays) rather than part by part as the log would hold them: its truth is held and the
        scorer holds nothing else, the wire's tick k is quiet with the answers to tick k − 1 of
        every node on it, heard at once, and none of the tick's other ``frames`` (the runner's, an
        intruder's) is of an estimator's message. Then every estimator's frames of tick k − 1 arrive
        in the tick, once each, with the values the batch computed (as they carry them), the
        detector's verdict on tick k − 1 follows, and nothing else the scorer reads comes."""
        scorer, held = self.scorer, self.held
        return (
            quiet is not None
            and not any(decoded is not None and decoded.spec.name in self.estimated for _, decoded in frames[1:])
            and self.heard
            and held is not None
            and held[0] == k - 1
            and not scorer.pending
            and scorer.next_tick == k - 1
            and scorer.expected_parts > 0
            and len(self.answering) == len(self.nodes)
            and (self.detector is None or self.detector.given == k - 1)
        )

    def _give_truth(self) -> None:
        """The held truth to the scorer, as ``PlantSource.advance`` logs it."""
        if self.held is not None:
            k, x, r, states, active = self.held
            self.held = None
            self.scorer.state(k, dict(zip(states, x[r].tolist())))
            self.scorer.faults(k, list(active))

    def intake(self, name: str, k: int) -> TickFrames | None:
        """Node ``name``'s tick k, where what its frames would do is known without taking them one by
        one (``take``): its readings are the runner's values of the tick and its commands the
        runner's or its upstream node's, as their frames carry them (the batch has those on
        arrays), and the one thing they change in its client is the last SYNC it took. None where
        that is not so (``take`` then).

        So it is when: the tick's frames went on the channel as the runner built them, none held
        back by the wire or touched by a bus fault (``clean``); the client is between ticks, took
        SYNC(k − 1) and holds nothing of its upstream nodes (lag 0 only: the nodes that answer tick k
        before it, as the controller answers before the estimators); the frames it wants on its
        channel are exactly those the runner sent in the tick and then its upstream nodes' answers
        to it (by identity), SYNC announcing every data frame; and the control frames among them
        verify under its keys. Then SYNC(k) opens tick k, each reading and command fills it, the
        upstream frames and heartbeats make it ready, and it closes, with nothing counted lost,
        contested or distrusted (``TickAssembler.push``). The ``TickFrames`` returned holds the tick
        and its count only (what its answer needs): its values are the batch's arrays."""
        client = self.nodes[name]
        assembler, bus, sync = client.assembler, client.bus, self.sync
        if (
            self.clean != k
            or client.stopped
            or client.secoc is not None
            or not isinstance(bus, InProcessBus)
            or not assembler.between(k - 1)
            or any(lag != 0 or node not in self.answering for node, lag in assembler.upstream.items())
            or sync is None
            or sync.tick != k
            or int(sync.values["frames"]) != len(self.announced) - 1
        ):
            return None
        upstream = [self.nodes[node].closing for node in assembler.upstream]
        expected = [*self.announced, *(frame for frames in upstream for frame in frames)]
        wanted = [frame for frame in bus.waiting() if client.wants(frame)]
        if len(wanted) != len(expected) or any(a is not b for a, b in zip(wanted, expected)):
            return None
        control = client.control
        if control is not None and (
            control.verify(self.announced[0], k - 1) is not None
            or any(not frames or control.verify(frames[-1], k) is not None for frames in upstream)
        ):
            return None
        bus.discard()
        assembler.took_whole(k)
        return TickFrames(k, len(self.announced) - 1)

    def take(self, name: str) -> list[TickFrames]:
        """The ticks node ``name`` completes with what its channel brought (as ``_Node.service``)."""
        client = self.nodes[name]
        return [
            tick
            for frame in drain(client.bus, limit=sys.maxsize)
            if client.wants(frame)
            for tick in client.take(frame, self._decode(frame))
        ]

    def _decode(self, frame: can.Message) -> Decoded | None:
        """What ``Client.feed`` decodes from ``frame`` (None: nothing of the run's, or not decodable)."""
        found = self.decoded.get(id(frame))
        if found is None:
            try:
                decoded = self.codec.decode(frame)
            except CodecError:
                decoded = None
            found = self.decoded[id(frame)] = (frame, decoded)
        return found[1]

    def publish(self, name: str, tick: TickFrames, values: dict[str, float], saturate: bool) -> None:
        """Node ``name``'s answer to ``tick``: its frames, then the heartbeat closing it (``_Node._publish``)."""
        self.nodes[name].publish(tick, values, saturate=saturate)
        self._done(name, tick)

    def publish_encoded(self, name: str, tick: TickFrames, frames: list[tuple[can.Message, Decoded]]) -> None:
        """``publish`` of frames the batch encoded (``Client.publish_encoded``)."""
        self.nodes[name].publish_encoded(frames)
        self._done(name, tick)

    def _done(self, name: str, tick: TickFrames) -> None:
        self.nodes[name].done(tick)
        self.answering.append(name)

    def truth(self, k: int, x: np.ndarray, r: int, states: Sequence[str], active: tuple[str, ...]) -> None:
        """Tick k's truth (its states, row r of x, the faults active), held for the scores (``send``)."""
        self._give_truth()
        self.held = (k, x, r, states, active)

    def finish(self, ticks: int, senders: list[str]) -> tuple[int, dict[str, SenderCounts]]:
        """The run's end after ``ticks`` ticks (``Session.finish``): the last answers and whatever
        the wire still holds delivered, the verdicts of every tick given; its contested ticks and
        what each of ``senders`` sent, lost and found missing."""
        self._give_truth()
        self._hear()
        self.traffic.flush(self.marker, 0.0, 0)
        self._passages([(p.delivered_ns, p.frame.payload) for p in self.arbitration.finish() if p.dropped is None])
        self._verdicts(ticks)
        return len(self.traffic.contested), self.traffic.sender_counts(ticks, senders, set(self.nodes))

    def close(self) -> None:
        for client in self.nodes.values():
            client.bus.shutdown()
        self.bus.shutdown()

    def _hear(self) -> None:
        """What the runner's bus holds: into its traffic (``Session.wait``)."""
        for frame in drain(self.bus, limit=sys.maxsize):
            self.traffic(frame)
        self.traffic.commands.clear()  # the plant's commands are the batch's (the controller's, as carried)

    def _logged(
        self, tick: int, t: float, t_ns: int, frame: can.Message, decoded: Decoded | None, scored: bool = True
    ) -> None:
        """A frame at its arrival (``Session._log_frame``): the detector sees it; an estimator's
        frame is a part of its tick's scores, as the scorer reads it from the log (unless its tick
        is ``scored`` whole)."""
        if self.detector is not None:
            self.detector.frame(tick, t_ns, frame, decoded)
        if decoded is None or not scored:
            return
        topic = message_topic(decoded.spec.name)
        scorer = self.scorer
        if topic in scorer.owner and scorer.reads(topic):
            signals = Signals.read(read_back(Signals.payload(decoded)), tick)
            scorer.estimate(scorer.owner[topic], signals.tick, signals.values)

    def _passages(self, delivered: list[tuple[int, Frame]], scored: bool = True) -> None:
        """Frames through the wire, at their delivery (ns) (``Session._log_passages``)."""
        dt_ns = self.dt_ns
        for at, (message, decoded) in delivered:
            self._logged(at // dt_ns, at / 1e9, at, message, decoded, scored)

    def _verdicts(self, until: int) -> None:
        if self.detector is not None:
            for tick, checks, _ in self.detector.verdicts(until):
                self.scorer.verdict(tick, any(checks.values()), checks)

    def _foreign(self, frame: can.Message, reason: str) -> None:
        if self.detector is not None:  # ``Session._foreign_heard``
            self.detector.foreign(self.traffic.current, frame)

    def _rejected(self, frame: can.Message, rejection: Rejection) -> None:
        why = f"the runner rejected a frame of 0x{rejection.frame_id:03X} ({rejection.reason})"
        self.rejected = self.rejected or why


def _encoded_runs(
    codec: Codec, k: int, rows: np.ndarray, names: list[str], values: np.ndarray, sent: np.ndarray | None = None
) -> dict[int, list[tuple[can.Message, Decoded]]]:
    """The frames of messages ``names`` for tick k of the runs ``rows`` (by run), encoded on arrays
    (``Codec.encode_rows``): ``values`` (R, every message's signals in turn), ``sent`` (R,
    messages) which each run sends (None: all). A run with a value its frame cannot carry (NaN, out
    of range) is left out, and all of them where a message is not packed on arrays: their own path
    encodes them and names what it refuses."""
    found = codec.encode_rows(names, k, values, sent)
    if found is None:
        return {}
    return {r: frames for r, frames in zip(rows.tolist(), found) if frames is not None}


def _passed(frames: list[Frame], applied: Applied) -> bool:
    """Whether the bus faults let the runner's ``frames`` through as they were (SYNC aside, which
    they re-announce): none lost, changed, held, delayed or joined by an intruder's."""
    if applied.intruders or applied.delays_ns or len(applied.frames) != len(frames):
        return False
    return all(a is b for a, b in zip(applied.frames[1:], frames[1:]))


def _undelayed(applied: Applied | None) -> bool:
    """Whether the bus faults of a tick delayed no frame (its wire may be quiet)."""
    return applied is None or not applied.delays_ns


class WireBatch:
    """The arbitrated buses of K runs of one design (``cosim.campaign.batch._Batch``), tick by tick:
    ``send`` the runner's frames, ``inputs`` what a node takes of its tick, ``answer`` its frames,
    ``truth`` the tick's truth for the scores, ``finish`` the end."""

    def __init__(
        self,
        plans: Sequence[RunPlan],
        scores: TickBatch,
        sensor_specs: Sequence[MessageSpec],
        command_specs: Sequence[MessageSpec],
        leave: Callable[[int, int, str], None],
    ) -> None:
        plan = plans[0]
        self.codec, self.scenario, self.plan = plan.codec, plan.scenario, plan
        self.sensor_specs, self.command_specs, self.leave = list(sensor_specs), list(command_specs), leave
        self.closed = plan.controller is not None
        self.scores = scores
        self.runs = [_RunWire(each, scorer) for each, scorer in zip(plans, scores.scorers)]
        self._truth: tuple[int, np.ndarray, Sequence[tuple[str, ...]], Sequence[np.ndarray]] | None = None

    def active(self, t: float) -> list[tuple[str, ...]]:
        """Each run's bus faults active at t, by label (what its ``/truth/faults`` adds)."""
        return [tuple(run.stage.active(t)) if run.stage is not None else () for run in self.runs]

    def send(self, k: int, measured: np.ndarray, sent: np.ndarray, commands: np.ndarray, alive: np.ndarray) -> None:
        """Tick k's frames of each run alive: its ``measured`` readings that are ``sent``, and in an
        open loop its ``commands`` (the input signals, as given). A run whose frames its bus cannot
        carry (a forged value outside its range) leaves the batch."""
        codec, sensors, actuators = self.codec, self.sensor_specs, [] if self.closed else self.command_specs
        prepared: list[tuple[list[Frame], Applied | None] | None] = [None] * len(self.runs)
        rows = np.flatnonzero(alive)
        built = self._runner_frames(k, measured, sent, commands, rows) if len(rows) else {}
        for r in rows.tolist():
            try:
                given = [] if self.closed else commands[r].tolist()
                frames = built.get(r) or runner_frames(
                    codec, k, sensors, measured[r].tolist(), sent[r].tolist(), actuators, given
                )
                prepared[r] = self.runs[r].prepare(k, frames)
            except (CodecError, CosimError) as error:
                self._leave(r, k, str(error), alive)
        plain = [item[0] if item is not None and _undelayed(item[1]) else None for item in prepared]
        senders = [item[1].intruders if item is not None and item[1] is not None else {} for item in prepared]
        quiet = quiet_ticks([run.arbitration for run in self.runs], k, plain, senders)
        whole: list[tuple[int, dict[str, int]]] = []
        for r, item in enumerate(prepared):
            if item is None:
                continue
            run = self.runs[r]
            try:
                verdict = run.send(k, *item, quiet[r])
            except (CodecError, CosimError) as error:
                self._leave(r, k, str(error), alive)
                continue
            if run.rejected:
                self._leave(r, k, run.rejected, alive)
            elif verdict is not None:
                whole.append((r, verdict))
            else:
                self.scores.forget(r)  # its scorer took the tick's parts
        if whole:
            self._scored_whole(k - 1, whole)

    def _scored_whole(self, k: int, verdicts: list[tuple[int, dict[str, int]]]) -> None:
        """Tick k of the runs scored whole (``_RunWire._whole``), from the batch's arrays: their
        truth, their estimators' values as their frames carried them, the detector's ``verdicts``
        on the tick (each check's count, by run), as ``Scorer.verdict`` takes them."""
        assert self._truth is not None and self._truth[0] == k
        _, x, active, values = self._truth
        rows = np.array([r for r, _ in verdicts])
        bus = None
        if self.runs[verdicts[0][0]].detector is not None:
            ids = np.zeros((len(self.runs), 1 + len(IDS_CHECKS)))
            for r, checks in verdicts:
                counts = [checks[check] for check in IDS_CHECKS]
                ids[r] = [float(any(counts)), *(float(count > 0) for count in counts)]
            bus = BusVerdicts(ids, [()] * len(self.runs))
        self.scores.tick(k, rows, x, active, values, bus)

    def _runner_frames(
        self, k: int, measured: np.ndarray, sent: np.ndarray, commands: np.ndarray, rows: np.ndarray
    ) -> dict[int, list[Frame]]:
        """``runner_frames`` of the runs ``rows`` whose values their frames carry, their data frames
        encoded on arrays (``Codec.encode_rows``), by run; the others are left out (``runner_frames``
        refuses them, naming the value)."""
        codec, specs = self.codec, [*self.sensor_specs, *([] if self.closed else self.command_specs)]
        values, on = measured[rows], sent[rows]
        if not self.closed:
            values = np.concatenate([values, commands[rows]], axis=1)
            on = np.concatenate([on, np.ones((len(rows), len(self.command_specs)), dtype=bool)], axis=1)
        out: dict[int, list[Frame]] = {}
        # Their SYNC is one per count, shared: the wire announces a SYNC of its own, which is the one
        # signed and sent (``quiet_ticks``, ``Arbitration.tick``, the bus faults' ``apply``)
        syncs: dict[int, Frame] = {}
        for r, data in _encoded_runs(codec, k, rows, [spec.name for spec in specs], values, on).items():
            sync = syncs.get(len(data))
            if sync is None:
                try:
                    message = codec.sync(k, len(data))
                except CodecError:  # more frames than a SYNC announces: ``runner_frames`` says so, for that run
                    continue
                sync = syncs[len(data)] = (message, codec.decode(message))
            out[r] = [sync, *data]
        return out

    def inputs(
        self, k: int, name: str, alive: np.ndarray, carried: tuple[np.ndarray, np.ndarray]
    ) -> tuple[list[TickFrames | None], np.ndarray, np.ndarray]:
        """Node ``name``'s tick k in each run alive (None in the others), with its readings (K,
        sensors; NaN: missing) and the commands it took (K, actuators; NaN: none came). ``carried``:
        the readings and commands its frames carry in a run where nothing but the runner and the
        nodes before it touched them (the runner's sensor values that are sent; its input signals,
        or the commands of its upstream controller node; NaN where no frame is due), which it takes
        as they are in a run where its tick is that (``_RunWire.intake``). A run whose node would not
        complete tick k (alone, the runner would wait for it in vain) leaves."""
        s = self.scenario
        ticks: list[TickFrames | None] = [None] * len(self.runs)
        readings = np.full((len(self.runs), len(s.sensors)), np.nan)
        commands = np.full((len(self.runs), len(s.actuators)), np.nan)
        for r in np.flatnonzero(alive).tolist():
            run = self.runs[r]
            whole = run.intake(name, k)
            if whole is not None:
                ticks[r] = whole
                readings[r], commands[r] = carried[0][r], carried[1][r]
                continue
            done = run.take(name)
            if [tick.tick for tick in done] != [k]:
                why = f"its node {name} would not complete tick {k} (frames announced by SYNC missing)"
                self._leave(r, k, why, alive)
                continue
            tick = ticks[r] = done[0]
            readings[r] = [tick.sensors.get(sensor, np.nan) for sensor in s.sensors]
            commands[r] = [tick.commands.get(actuator, np.nan) for actuator in s.actuators]
        return ticks, readings, commands

    def answer(
        self,
        name: str,
        ticks: Sequence[TickFrames | None],
        signals: Sequence[str],
        values: np.ndarray,
        alive: np.ndarray,
        saturate: bool,
    ) -> None:
        """Node ``name``'s frames of the ticks it completed, ``values`` (K, signals) by ``signals``
        as it computed them (before saturation and quantization: its client does both, or the
        batch on arrays, each run's frames as its client encodes them: ``_encoded``)."""
        rows = np.flatnonzero(alive)
        encoded = self._encoded(name, ticks, signals, values, rows, saturate) if len(rows) else {}
        for r in rows.tolist():
            tick = ticks[r]
            assert tick is not None  # a run whose node completed no tick has left
            try:
                if r in encoded:
                    self.runs[r].publish_encoded(name, tick, encoded[r])
                else:
                    self.runs[r].publish(name, tick, dict(zip(signals, values[r].tolist())), saturate)
            except (CodecError, CosimError) as error:
                self._leave(r, tick.tick, str(error), alive)

    def _encoded(
        self,
        name: str,
        ticks: Sequence[TickFrames | None],
        signals: Sequence[str],
        values: np.ndarray,
        rows: np.ndarray,
        saturate: bool,
    ) -> dict[int, list[tuple[can.Message, Decoded]]]:
        """Node ``name``'s frames of tick k in the runs ``rows``, encoded on arrays (``Codec.encode_rows``),
        by run: its messages in order, each value saturated (``saturated``'s bound where it crossed
        one) and in range. A run with a value its frame cannot carry (NaN, or out of range unsaturated),
        or a node whose messages are not packed on arrays, is left out: its client encodes (and refuses) it."""
        k = next(tick.tick for r in rows.tolist() if (tick := ticks[r]) is not None)
        if any(getattr(ticks[r], "tick", None) != k for r in rows.tolist()):
            return {}
        messages = self.runs[int(rows[0])].nodes[name].messages
        if any(signal not in signals for spec in messages for signal in spec.signals):
            return {}  # its client names what is missing, run by run
        columns = [signals.index(signal) for spec in messages for signal in spec.signals]
        v = values[rows][:, columns]
        if saturate:
            channels = [c for spec in messages for c in spec.channels]
            low, high = np.array([c.minimum for c in channels]), np.array([c.maximum for c in channels])
            v = np.where(np.isnan(v), v, np.minimum(np.maximum(v, low), high))
        return _encoded_runs(self.codec, k, rows, [spec.name for spec in messages], v)

    def truth(
        self,
        k: int,
        x: np.ndarray,
        states: Sequence[str],
        active: Sequence[tuple[str, ...]],
        rows: Any,
        values: Sequence[np.ndarray],
    ) -> None:
        """Tick k's truth of the runs ``rows``: their states (K, states) and active faults, with
        their estimators' values (each (K, signals), as their frames carry them), for the scores."""
        x = x.copy()
        self._truth = (k, x, active, values)
        for r in rows:
            self.runs[r].truth(k, x, r, states, active[r])

    def finish(self, r: int, ticks: int) -> tuple[int, dict[str, SenderCounts]]:
        """Run r's end after ``ticks`` ticks: its contested ticks and what each node sent and missed."""
        return self.runs[r].finish(ticks, self.plan.senders)

    def close(self) -> None:
        """Every run's channel closed."""
        for run in self.runs:
            run.close()

    def _leave(self, r: int, k: int, why: str, alive: np.ndarray) -> None:
        self.leave(r, k, why)
        alive[r] = False
