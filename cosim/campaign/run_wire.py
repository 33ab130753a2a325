"""One run's arbitrated in-process bus in a batch (``cosim.campaign.batch_wire``): its wire, bus
faults, nodes' clients, runner's traffic, intrusion detector and scorer, the very objects its
session builds (``RunPlan.session``), driven as the session drives them, with the shortcuts a batch
takes where what they would do is known: a node's tick taken whole (``RunWire.intake``), the nodes'
answers heard at once (``Traffic.answered``), a tick scored whole (``RunWire._whole``).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

import can
import numpy as np

from cosim.analysis.metrics.scorer import Scorer
from cosim.bus.client import Client, TickFrames
from cosim.bus.codec import CONTROLLER, HEARTBEAT, NMT, SYNC, Decoded
from cosim.bus.control_frames import ControlAuth
from cosim.bus.inprocess import InProcessBus
from cosim.bus.secoc import Rejection
from cosim.bus.transport import allocate, drain, open_bus, send_all
from cosim.errors import CodecError
from cosim.log.metadata import SenderCounts
from cosim.log.topics import Signals, message_topic
from cosim.log.writer import read_back
from cosim.run.arbitration import Arbitration, Quiet
from cosim.run.busfaults import Applied
from cosim.run.node import node_client
from cosim.run.plan import RunPlan
from cosim.run.signing import forged, sign_control
from cosim.run.traffic import Traffic
from cosim.scenario.faults import build_bus_faults

Frame = tuple[can.Message, Decoded | None]
_SIGNED = (SYNC, NMT, HEARTBEAT)  # the control frames: their MAC is written when they are sent


class RunWire:
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
        # what the run's nodes' control frames verified to in this tick (``_verifies``)
        self.verified: dict[tuple[int, int, int], tuple[can.Message, bool]] = {}
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
        self.carried_whole = False  # whether the last tick carried its answers whole (``_carried_whole``)
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
        self.verified.clear()
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
        arrays) rather than part by part as the log would hold them: the tick is carried whole
        (``carried_whole``) and the scorer holds nothing else. Then every estimator's frames of tick
        k − 1 arrive in the tick, once each, with the values the batch computed (as they carry
        them), the detector's verdict on tick k − 1 follows, and nothing else the scorer reads comes."""
        scorer = self.scorer
        self.carried_whole = self._carried_whole(k, frames, quiet)
        return self.carried_whole and not scorer.pending and scorer.next_tick == k - 1 and scorer.expected_parts > 0

    def _carried_whole(self, k: int, frames: list[Frame], quiet: Quiet | None) -> bool:
        """Whether tick k carries tick k − 1's answers whole: its truth is held, the wire's tick k is
        quiet with the answers to tick k − 1 of every node on it, heard at once, the detector is to
        give tick k − 1, and none of the tick's other ``frames`` (the runner's, an intruder's) is of
        an estimator's message."""
        held = self.held
        return (
            quiet is not None
            and self.heard
            and held is not None
            and held[0] == k - 1
            and len(self.answering) == len(self.nodes)
            and (self.detector is None or self.detector.given == k - 1)
            and not any(decoded is not None and decoded.spec.name in self.estimated for _, decoded in frames[1:])
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
            not self._verifies(control, self.announced[0], k - 1)
            or any(not frames or not self._verifies(control, frames[-1], k) for frames in upstream)
        ):
            return None
        bus.discard()
        assembler.took_whole(k)
        return TickFrames(k, len(self.announced) - 1)

    def _verifies(self, control: ControlAuth, frame: can.Message, near: int) -> bool:
        """Whether a node's ``control`` verifies ``frame`` at its tick ``near``: a function of the
        frame, the tick and the sender's key alone (with the run's one codec, whose control ids
        every node's ``ControlAuth`` reads), so that the run's nodes holding that key (each the
        same, from the run's secret) share the answer, found once a tick: ``verified``, by the
        frame, the tick and the key's ``ShortCmac``. The memo holds the frame itself, so that no
        other frame can take its ``id`` before the next tick clears it."""
        key = (id(frame), near, id(control.key_of(frame)))
        found = self.verified.get(key)
        if found is None or found[0] is not frame:
            found = self.verified[key] = (frame, control.verify(frame, near) is None)
        return found[1]

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
        if decoded is not None and scored:
            score_estimate(self.scorer, tick, decoded)

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


def score_estimate(scorer: Scorer, tick: int, decoded: Decoded) -> None:
    """A frame delivered in ``tick``, to the scores if it is an estimator's (as they read it from the log)."""
    topic = message_topic(decoded.spec.name)
    if topic in scorer.owner and scorer.reads(topic):
        signals = Signals.read(read_back(Signals.payload(decoded)), tick)
        scorer.estimate(scorer.owner[topic], signals.tick, signals.values)


def _passed(frames: list[Frame], applied: Applied) -> bool:
    """Whether the bus faults let the runner's ``frames`` through as they were (SYNC aside, which
    they re-announce): none lost, changed, held, delayed or joined by an intruder's."""
    if applied.intruders or applied.delays_ns or len(applied.frames) != len(frames):
        return False
    return all(a is b for a, b in zip(applied.frames[1:], frames[1:]))
