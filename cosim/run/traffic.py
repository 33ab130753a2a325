"""What the runner hears on the bus during a run: frames taken as they arrive, accounted for (lost,
late, foreign, rejected) and logged tick by tick in a canonical order."""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable

import can

from cosim.bus.codec import BOOTUP, CLIENT, COMMAND, CONTROL, ESTIMATE, HEARTBEAT, OPERATIONAL, STOPPED, Codec, Decoded
from cosim.bus.control_frames import ControlAuth
from cosim.bus.secoc import Rejection, SecOC
from cosim.errors import CodecError
from cosim.log.metadata import SenderCounts
from cosim.log.recorder import RunRecorder


def own_ids(codec: Codec, own_senders: tuple[str, ...]) -> set[int]:
    """The ids of the frames the runner itself sends (those of ``own_senders``, DBC nodes)."""
    return {spec.frame_id for spec in codec.specs.values() if spec.sender in own_senders}


def contests(frames: list[can.Message], own: set[int], authenticated: bool) -> bool:
    """Whether an intruder's ``frames`` contest their tick: on the runner's ``own`` ids and
    unauthenticated, a receiver cannot tell them from the runner's."""
    return not authenticated and any(frame.arbitration_id in own for frame in frames)


class Traffic(can.Listener):
    """What the runner hears during a run, with the bookkeeping behind loss, lateness and trust.

    Frames are taken as they arrive and logged tick by tick (``flush``). Heartbeats are decoded on
    arrival, since the runner waits for them, and so are the controller node's commands;
    everything else is decoded when logged. The runner's own frames come back on udp_multicast
    (loopback): each is matched against what the runner sent, and not logged twice; a frame on one
    of the runner's own ids that it did not send (a forged SYNC or NMT, another co-simulation on the
    same group and port) is foreign: logged as such, never used. A node's heartbeat closing tick j
    says how many frames it sent for j; frames of it missing at that point are counted as lost,
    and the nodes report in their heartbeats how many of the runner's frames they found missing.
    """

    def __init__(
        self,
        codec: Codec,
        recorder: RunRecorder | None,
        own_senders: tuple[str, ...],
        commands: bool = False,
        echoes: bool = False,
        on_foreign: Callable[[can.Message, str], None] | None = None,
        secoc: SecOC | None = None,
        on_rejected: Callable[[can.Message, Rejection], None] | None = None,
        control: ControlAuth | None = None,
        deliver: Callable[[int, float, int, can.Message, Decoded | None], None] | None = None,
        decode: Callable[[can.Message], Decoded | None] | None = None,
    ) -> None:
        self.codec = codec
        #: What a frame decodes to (None: not decodable): the codec's, or a batch's run's, which
        #: knows what its nodes' frames decode to (``cosim.campaign.batch_wire``)
        self._decoder = decode or self._decode_frame
        # Control frames' MACs and SecOC: every node's frame is verified on arrival (the runner's
        # own, at sending); a rejected one is logged as it came, never used or counted as its sender's
        self.secoc, self.control, self._on_rejected = secoc, control, on_rejected
        self.rejected = 0
        self.pending: list[tuple[can.Message, Decoded | None]] = []  # arrival order
        self.closed: dict[str, int] = {}  # node -> last tick whose heartbeat arrived
        self.joined: set[str] = set()
        self.left: dict[str, float] = {}  # node -> when its stopped heartbeat arrived (wall clock)
        self.lost: Counter[str] = Counter()  # node -> frames of it the runner did not get
        self.late: Counter[str] = Counter()  # node -> data frames of it logged after their tick
        self.data: Counter[str] = Counter()  # node -> data frames received
        self.missed_by: dict[str, int] = {}  # node -> runner frames it reported missing
        self._lost_carried: dict[str, int] = {}  # node -> its last heartbeat's count of them (mod 2^8)
        self.received: Counter[str] = Counter()
        self.echoes = 0
        self.repeated_bootups = 0
        self.foreign_frames = 0
        self.own_foreign = 0  # of those, frames on the runner's own ids (SYNC, NMT, sensors, commands)
        #: Ticks during which a frame on one of the runner's own ids came that the runner did not send:
        #: without authentication a receiver cannot tell it from the runner's, so the tick is contested.
        self.contested: set[int] = set()
        self._counts: Counter[tuple[str, int]] = Counter()
        self._own = own_ids(codec, own_senders)
        self._heartbeats = {spec.frame_id for spec in codec.messages(role=HEARTBEAT)}
        self._commands = {spec.frame_id for spec in codec.messages(role=COMMAND)} if commands else set()
        self.commands: dict[int, dict[str, float]] = {}  # tick counter -> the controller node's commands
        self._echoes = echoes
        self._sent: Counter[tuple[int, bytes]] = Counter()  # the runner's frames whose echo is still due
        self._sent_ticks: list[list[tuple[int, bytes]]] = []
        self._on_foreign = on_foreign
        self.current = 0  # the tick whose frames the runner sent last
        self._distrusted: set[int] = set()  # pending frames found foreign on arrival: logged raw, never counted
        #: Where ``flush`` puts a tick's frames: the log, or, on an arbitrated bus, the wire (which logs them);
        #: a batch's run (``cosim.campaign.batch_wire``), which logs nothing, gives its wire alone.
        found = deliver or (recorder.frame if recorder is not None else None)
        if found is None:
            raise ValueError("Traffic needs a recorder or where to deliver the frames it flushes")
        self.deliver: Callable[[int, float, int, can.Message, Decoded | None], None] = found

    def sent(self, frames: list[can.Message]) -> None:
        """The runner sent these (one tick's): their echoes are its own, anything else on its ids is not."""
        if not self._echoes:
            return
        keys = [(frame.arbitration_id, bytes(frame.data)) for frame in frames]
        self._sent.update(keys)
        self._sent_ticks.append(keys)
        if len(self._sent_ticks) > 256:  # an echo later than that was lost on the way: forget it
            self._sent.subtract(self._sent_ticks.pop(0))
            self._sent += Counter()  # drop counts at zero or below

    def on_message_received(self, msg: can.Message) -> None:
        identifier = None if msg.is_extended_id else msg.arbitration_id
        if identifier in self._own:
            key = (msg.arbitration_id, bytes(msg.data))
            if self._sent[key] > 0:
                self._sent[key] -= 1
                self.echoes += 1
            else:
                self.own_foreign += 1
                self._foreign(msg, "a frame on one of the runner's own ids that the runner did not send")
                if not self.verify(msg):  # no authentication dropped it: receivers may have taken it
                    self.contested.add(self.current)
            return
        if self.verify(msg):
            self._distrusted.add(id(msg))
            self.pending.append((msg, None))
            return
        decoded = None
        if identifier in self._heartbeats:
            decoded = self._decoder(msg)
            if decoded is not None:
                decoded = self.codec.with_full_tick(decoded, self.current)
                sender, state = decoded.spec.sender, decoded.values["state"]
                if state == BOOTUP and sender in self.joined:
                    # A node repeats its boot-up until tick 0 (Client.announce); how often depends on
                    # how long the others take to start, so the repeats are counted, not logged.
                    self.repeated_bootups += 1
                    return
                if state == BOOTUP:
                    self.joined.add(sender)
                elif state == STOPPED:
                    self.left[sender] = time.perf_counter()
                elif state == OPERATIONAL and decoded.tick > self.current:
                    self._foreign(msg, f"a heartbeat of {sender} closing tick {decoded.tick}, which has not started")
                    self._distrusted.add(id(msg))
                    decoded = None
                elif state == OPERATIONAL and self.closed.get(sender) == decoded.tick:
                    # a node closes a tick once: a second heartbeat would count its frames as lost again
                    self._foreign(msg, f"a second heartbeat of {sender} closing tick {decoded.tick}")
                    self._distrusted.add(id(msg))
                    decoded = None
                elif state == OPERATIONAL:
                    if sender in self.left:  # it answers on: that stopped heartbeat was not its own
                        del self.left[sender]
                        self._foreign(
                            msg, f"{sender} answers after a stopped heartbeat in its name: that one was forged"
                        )
                    self.closed[sender] = decoded.tick
        elif identifier in self._commands:
            decoded = self._decoder(msg)
            if decoded is not None:
                channel = decoded.spec.channels[0]
                self.commands.setdefault(decoded.tick, {})[channel.name] = decoded.values[decoded.spec.signals[0]]
        self.pending.append((msg, decoded))

    def injected(self, tick: int, frames: list[can.Message]) -> None:
        """Frames a simulated intruder (a bus fault) put on the bus during ``tick``: on the runner's own
        ids and unauthenticated, a receiver cannot tell them from the runner's, so the tick is contested."""
        if contests(frames, self._own, self.secoc is not None):
            self.contested.add(tick)

    def contested_warning(self) -> list[str]:
        """What the contested ticks mean, in a line (none without any)."""
        if not self.contested:
            return []
        return [
            f"{len(self.contested)} contested ticks (from tick {min(self.contested)}): another program sent on the "
            "runner's own ids, so the estimates of those ticks may rest on forged frames (authenticate the bus: "
            'bus.authentication = "secoc")'
        ]

    def verify(self, frame: can.Message) -> bool:
        """Whether this frame fails its authentication (reported): a control frame's MAC, or SecOC's
        trailer of a data frame; frames of unsecured ids pass."""
        rejection = None if self.control is None else self.control.verify(frame, self.current)
        if rejection is None and self.secoc is not None:
            rejection = self.secoc.verify(frame, self.current)
        if rejection is None:
            return False
        self.rejected += 1
        if self._on_rejected is not None:
            self._on_rejected(frame, rejection)
        return True

    def _foreign(self, frame: can.Message, reason: str) -> None:
        self.foreign_frames += 1
        if self._on_foreign is not None:
            self._on_foreign(frame, reason)

    def _decode_frame(self, frame: can.Message) -> Decoded | None:
        try:
            return self.codec.decode(frame)
        except CodecError:
            return None  # logged raw, as an unknown frame

    def flush(self, tick: int, t: float, t_ns: int) -> None:
        """Account for the frames received during tick k, then log them by arbitration id."""
        taken: list[tuple[can.Message, Decoded | None]] = []
        counter_now = tick % self.codec.tick_modulus
        for frame, decoded in self.pending:
            if id(frame) in self._distrusted:
                taken.append((frame, None))
                continue
            if decoded is None:
                decoded = self._decoder(frame)
            taken.append((frame, decoded))
            if decoded is None:
                unknown = self.codec.spec_of(frame) is None
                self._foreign(
                    frame, "an id outside the run's database" if unknown else "cannot be decoded (its length or bits)"
                )
                continue
            sender, role = decoded.spec.sender, decoded.spec.role
            self.received[sender] += 1
            if role in (ESTIMATE, CLIENT, COMMAND, CONTROL):
                self._counts[(sender, decoded.tick)] += 1
                self.data[sender] += 1
                self.late[sender] += decoded.tick % self.codec.tick_modulus != counter_now
            elif role == HEARTBEAT and decoded.values["state"] == OPERATIONAL:
                counter = decoded.tick % self.codec.tick_modulus
                self.lost[sender] += max(0, int(decoded.values["frames"]) - self._counts.pop((sender, counter), 0))
                # the heartbeat carries the node's count mod 2^8: what it adds since the last one counts
                carried = int(decoded.values["lost"])
                self.missed_by[sender] = (
                    self.missed_by.get(sender, 0) + (carried - self._lost_carried.get(sender, 0)) % 256
                )
                self._lost_carried[sender] = carried
        self.pending.clear()
        self._distrusted.clear()
        for frame, decoded in sorted(taken, key=lambda item: item[0].arbitration_id):
            self.deliver(tick, t, t_ns, frame, decoded)

    def answered(self, closings: list[list[tuple[can.Message, Decoded | None]]], t: float, t_ns: int) -> bool:
        """The answers of lockstep nodes to the current tick, heard and flushed at once: each node's
        data frames and then the heartbeat closing them, as its client sent them, each with what it
        decodes to (the heartbeat's tick as it carries it), in the order they came. Where each is
        what it says (its sender's data frames of the tick; a heartbeat that verifies, announces
        them and closes the tick for the first time, of a node that has not left) and nothing is
        pending, hearing them one by one (``on_message_received``) and ``flush`` would count each
        received, each data frame as its sender's and in time, none lost, close the node's tick,
        carry on the runner's frames it found missing, and deliver them all by id: that is done,
        and True returned. False, with nothing done, where it is not so: hear them one by one."""
        tick = self.current
        if self.pending or self._distrusted or self._echoes or self.secoc is not None:
            return False
        answers = [self._closing(frames, tick) for frames in closings]
        heard = [answer for answer in answers if answer is not None]
        if len(heard) < len(answers):
            return False
        taken: list[tuple[can.Message, Decoded | None]] = []
        for sender, ours, closing in heard:
            self.closed[sender] = tick
            for frame, data in ours:
                if frame.arbitration_id in self._commands:
                    channel = data.spec.channels[0]
                    self.commands.setdefault(data.tick, {})[channel.name] = data.values[data.spec.signals[0]]
            self.data[sender] += len(ours)  # Counters: none late, none lost (a count of 0 is none)
            self.received[sender] += len(ours) + 1
            carried = int(closing[1].values["lost"])
            self.missed_by[sender] = self.missed_by.get(sender, 0) + (carried - self._lost_carried.get(sender, 0)) % 256
            self._lost_carried[sender] = carried
            taken += [*ours, closing]
        for frame, decoded in sorted(taken, key=lambda item: item[0].arbitration_id):
            self.deliver(tick, t, t_ns, frame, decoded)
        return True

    def _closing(
        self, frames: list[tuple[can.Message, Decoded | None]], tick: int
    ) -> tuple[str, list[tuple[can.Message, Decoded]], tuple[can.Message, Decoded]] | None:
        """A node's answer to ``tick`` (``answered``): its sender, its data frames and its heartbeat
        (its tick in full), where each is what it says; None where not."""
        counter = tick % self.codec.tick_modulus
        if not frames or frames[-1][0].is_extended_id or frames[-1][0].arbitration_id not in self._heartbeats:
            return None
        message, decoded = frames[-1]
        if decoded is None:
            return None
        decoded = self.codec.with_full_tick(decoded, tick)
        sender = decoded.spec.sender
        if (
            decoded.tick != tick
            or decoded.values["state"] != OPERATIONAL
            or sender in self.left
            or self.closed.get(sender) == tick
            or (sender, counter) in self._counts
            or int(decoded.values["frames"]) != len(frames) - 1
            or (self.control is not None and self.control.verify(message, tick) is not None)
        ):
            return None
        data: list[tuple[can.Message, Decoded]] = []
        for frame, found in frames[:-1]:
            if (
                found is None
                or frame.is_extended_id
                or found.spec.sender != sender
                or found.spec.role not in (ESTIMATE, CLIENT, COMMAND, CONTROL)
                or found.tick != counter
                or frame.arbitration_id in self._own
                or frame.arbitration_id in self._heartbeats
            ):
                return None
            data.append((frame, found))
        return sender, data, (message, decoded)

    def missing(self, sender: str, ticks: int) -> int:
        """Data frames of a node that answers every tick which never arrived, over ``ticks`` ticks."""
        expected = ticks * len(self.codec.data_messages(sender))
        return max(self.lost[sender], expected - self.data[sender])

    def sender_counts(self, k: int, senders: list[str], answering: set[str]) -> dict[str, SenderCounts]:
        """Per sender: frames received, lost on the way (of a node ``answering`` every tick: every
        frame of k ticks not received), the runner's frames it missed, and those logged late."""
        return {
            name: SenderCounts(
                self.received[name],
                self.missing(name, k) if name in answering else self.lost[name],
                self.missed_by.get(name, 0),
                self.late[name],
            )
            for name in senders
        }
