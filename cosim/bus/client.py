"""Join a running co-simulation from your own program: decoded signals in, your messages out.

A few lines are enough::

    from cosim.bus.client import Client

    with Client.attach("lsq") as client:           # a client declared in the run's scenario
        for tick in client.ticks():                # tick k's sensor readings and commands
            y = tick.sensors
            client.publish(tick, {"x1": (2 * y["x1"] + y["x2"] + y["x1_minus_x2"]) / 3,
                                  "x2": (y["x1"] + 2 * y["x2"] - y["x1_minus_x2"]) / 3})

(``examples/least_squares_client.py`` is this client, complete.)

``attach`` finds the running co-simulation (``cosim run`` registers it), opens its bus and builds
the codec from its DBC. A client declared in the scenario's ``[[clients]]`` has its own messages
in the DBC and, with ``lockstep = true``, the runner waits for it: it must join before tick 0 and
answer every tick (iterating ``ticks()`` does that: the heartbeat that closes tick k goes out when
the loop body returns). Any other name joins as a passive listener, e.g. a monitor.

The built-in estimator nodes are clients too (``cosim/node.py``): the protocol is the same.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field

import can

from cosim.bus import registry
from cosim.bus.codec import (
    BOOTUP,
    COMMAND,
    CONTROLLER,
    HEARTBEAT,
    NMT,
    NMT_STOP,
    OPERATIONAL,
    RUNNER,
    SENSOR,
    STOPPED,
    SYNC,
    Codec,
    Decoded,
    saturated,
)
from cosim.bus.control_frames import ControlAuth
from cosim.bus.secoc import SecOC
from cosim.bus.transport import BusConfig, drain, open_bus, send_all
from cosim.errors import CodecError, CosimError

_WAIT = 0.2  # s: how long a client waits for a frame before it checks its own timeout


@dataclass
class TickFrames:
    """The decoded inputs of one tick: sensor readings and commands that arrived, by channel name.

    ``expected`` is the number of data frames SYNC announced and ``received`` how many arrived;
    ``t`` is the simulated time t_k = k τ when the sample time is known. ``upstream`` holds what
    the nodes this one listens to published (by node, then signal), for the tick each is read at.
    """

    tick: int
    expected: int
    sensors: dict[str, float] = field(default_factory=dict)
    commands: dict[str, float] = field(default_factory=dict)
    received: int = 0
    t: float | None = None
    upstream: dict[str, dict[str, float]] = field(default_factory=dict)
    messages: set[str] = field(default_factory=set)
    """The data messages of the tick that arrived (a second copy of one is not counted again)."""

    @property
    def complete(self) -> bool:
        return self.received >= self.expected


class TickAssembler:
    """Groups incoming frames by tick: SYNC(k) opens tick k and announces its data frames.

    ``push`` returns the tick once all its announced frames arrived. If SYNC(k+1) arrives while
    tick k is still incomplete, tick k is returned incomplete and the missing frames are counted
    in ``lost`` (in lockstep this cannot happen without frame loss on the transport).

    A second copy of a sensor or command message in one tick means that someone else sent it too
    (spoofing, on a bus without authentication): neither copy is trusted. The reading becomes NaN
    (missing), the command is held at its previous value, and ``contested`` counts the copies.

    ``upstream`` maps nodes whose frames this participant needs to a lag L: tick k is complete only
    once the node's frames of tick k − L are in, which its heartbeat closing that tick announces.
    With L = 0 the node answers the same tick first (estimators read the ``controller`` node's
    commands of tick k); with L = 1 its previous answer is used (the controller reads a diagnosis
    node's report of tick k − 1). Commands go to ``commands``, every other upstream signal to
    ``upstream[node]`` by signal name.
    """

    def __init__(self, codec: Codec, sample_time: float | None = None, upstream: dict[str, int] | None = None) -> None:
        self.codec = codec
        self.sample_time = sample_time
        self.pending: TickFrames | None = None
        self.lost = 0
        self.last_sync: int | None = None  # the tick of the last SYNC taken: ticks only go forward
        self.distrusted = 0  # SYNC frames ignored because they would take the run back
        self.contested = 0  # second copies of a tick's sensor or command message
        self.upstream = dict(upstream or {})
        self._heard: dict[str, dict[int, _Heard]] = {node: {} for node in self.upstream}

    def push(self, decoded: Decoded) -> list[TickFrames]:
        done: list[TickFrames] = []
        role, sender = decoded.spec.role, decoded.spec.sender
        if sender in self.upstream:
            self._hear(decoded)
        elif role == SYNC:
            if self.last_sync is not None and decoded.tick <= self.last_sync:
                self.distrusted += 1  # an old or repeated tick: not the runner's next SYNC
                return done
            self.last_sync = decoded.tick
            if self.pending is not None:
                self.lost += self.pending.expected - self.pending.received
                done.append(self._close(self.pending))
            t = None if self.sample_time is None else decoded.tick * self.sample_time
            self.pending = TickFrames(decoded.tick, int(decoded.values["frames"]), t=t)
        elif role in (SENSOR, COMMAND) and self.pending is not None:
            pending = self.pending
            if decoded.tick != pending.tick % self.codec.tick_modulus:
                self.lost += 1  # a late frame of an earlier tick
                return done
            target = pending.sensors if role == SENSOR else pending.commands
            if decoded.spec.name in pending.messages:  # another sender's copy: neither is trusted
                self.contested += 1
                for channel in decoded.spec.channels:
                    if role == SENSOR:
                        target[channel.name] = math.nan
                    else:
                        target.pop(channel.name, None)
                return done
            pending.messages.add(decoded.spec.name)
            for channel, signal in zip(decoded.spec.channels, decoded.spec.signals):
                target[channel.name] = decoded.values[signal]
            pending.received += 1
        if self.pending is not None and self.pending.complete and self._upstream_ready(self.pending.tick):
            done.append(self._close(self.pending))
            self.pending = None
        return done

    def between(self, k: int) -> bool:
        """Whether it is between ticks k and k + 1: it took SYNC(k) last, completed that tick, and
        holds nothing of its upstream nodes (``TickFrames`` of tick k + 1 start from nothing)."""
        return self.pending is None and self.last_sync == k and not any(self._heard.values())

    def took_whole(self, k: int) -> None:
        """Tick k taken whole, from ``between(k − 1)``, its upstream nodes all of lag 0: SYNC(k), every
        data frame it announced (the tick's counter, one per message) and then each upstream node's
        frames of tick k and heartbeat (theirs, announcing them), in that order. That leaves one
        thing changed, the last SYNC taken: the tick is closed, its upstream frames forgotten, nothing
        counted lost, contested or distrusted (``push``, frame by frame). A batch whose runs step
        alike has the tick's values on arrays (``cosim.campaign.batch_wire``)."""
        assert self.between(k - 1) and not any(self.upstream.values())
        self.last_sync = k

    def _hear(self, decoded: Decoded) -> None:
        heard = self._heard[decoded.spec.sender].setdefault(decoded.tick % self.codec.tick_modulus, _Heard())
        if decoded.spec.role == HEARTBEAT:
            if decoded.values["state"] == OPERATIONAL:
                heard.announced = int(decoded.values["frames"])
            return
        if decoded.spec.role == COMMAND:
            heard.commands.update(
                {c.name: decoded.values[s] for c, s in zip(decoded.spec.channels, decoded.spec.signals)}
            )
        else:
            heard.values.update({s: decoded.values[s] for s in decoded.spec.signals})
        heard.frames += 1

    def _upstream_ready(self, tick: int) -> bool:
        for node, lag in self.upstream.items():
            if tick - lag < 0:
                continue
            heard = self._heard[node].get((tick - lag) % self.codec.tick_modulus)
            if heard is None or heard.announced is None or heard.frames < heard.announced:
                return False
        return True

    def _close(self, tick: TickFrames) -> TickFrames:
        modulus = self.codec.tick_modulus
        for node, lag in self.upstream.items():
            by_tick = self._heard[node]
            heard = by_tick.get((tick.tick - lag) % modulus, _Heard())
            tick.commands.update(heard.commands)
            tick.upstream[node] = dict(heard.values)
            for counter in [c for c in by_tick if (tick.tick - lag - c) % modulus < modulus // 2]:
                del by_tick[counter]  # this tick's and older ones are never needed again
        return tick


@dataclass
class _Heard:
    """What an upstream node sent for one tick: its signal values, commands (from the controller
    node), data frames so far, and the data frames its heartbeat announced (None before it)."""

    values: dict[str, float] = field(default_factory=dict)
    commands: dict[str, float] = field(default_factory=dict)
    frames: int = 0
    announced: int | None = None


class Client:
    """A participant on a co-simulation's bus.

    ``name`` is the node's name in the DBC (an estimator or a declared client); a participant that
    has messages there publishes them and, if ``lockstep``, closes every tick with a heartbeat.
    ``bus`` is an open python-can bus; the client does not close it unless it opened it itself.
    ``secoc`` (on a bus with ``authentication = "secoc"``): the keys it signs its frames with and
    verifies the frames it takes with; what fails is dropped and counted in ``rejections``
    ((id, reason) → frames). ``control``: the control-frame keys (``cosim.bus.control_frames``):
    its heartbeats are signed, and a SYNC, an NMT or an upstream node's heartbeat is taken only if
    its MAC verifies (else counted in ``rejections`` too); without them, a client signs nothing and
    takes every control frame as it comes.
    """

    def __init__(
        self,
        name: str | None,
        codec: Codec,
        bus: can.BusABC,
        *,
        lockstep: bool = True,
        sample_time: float | None = None,
        owns_bus: bool = False,
        upstream: dict[str, int] | None = None,
        secoc: SecOC | None = None,
        control: ControlAuth | None = None,
    ) -> None:
        self.name = name
        self.secoc = secoc
        self.control = control
        self.rejections: Counter[tuple[int, str]] = Counter()
        self.codec = codec
        self.bus = bus
        #: The node this client is on the bus: its name, where the DBC declares it; else None.
        self._node = name if name is not None and name in codec.node_ids else None
        self.declared = self._node is not None
        self.lockstep = lockstep and self.declared
        self.messages = codec.data_messages(self._node) if self._node is not None else []
        if upstream is None and CONTROLLER in codec.node_ids and name != CONTROLLER:
            upstream = {CONTROLLER: 0}  # closed loop: the commands of tick k come from the controller node
        self.assembler = TickAssembler(codec, sample_time, upstream)
        self.stopped = False
        self._owns_bus = owns_bus
        self._published = 0
        self._outbox: list[can.Message] = []  # a lockstep node's frames of the tick, until its heartbeat
        #: What a lockstep node sent closing its last tick: its frames, then its heartbeat.
        self.closing: list[can.Message] = []
        self._joined = False
        self._announced = 0.0
        #: Where a participant that shares its process with its receivers (a batch's run:
        #: ``cosim.campaign.batch_wire``) leaves what each data frame it publishes decodes to, by
        #: ``id()`` of the frame, so that they take it without decoding the frame again; None: nowhere.
        self.decoded: dict[int, tuple[can.Message, Decoded | None]] | None = None
        # Only these frames concern a participant; telling them by id spares decoding the rest
        # (other nodes' frames, and our own frames that come back on udp_multicast).
        self._wanted = {
            s.frame_id
            for s in codec.specs.values()
            if s.role in (SYNC, NMT, SENSOR, COMMAND) or s.sender in self.assembler.upstream
        }

    # -- life cycle -----------------------------------------------------------------------------

    @classmethod
    def attach(cls, name: str | None = None, run: str | None = None, *, lockstep: bool = True) -> Client:
        """Join the running co-simulation (the only one, or the one whose id starts with ``run``)."""
        info = registry.find(run)
        codec = Codec.from_dbc(info["dbc"])
        keys = info.get("control_keys", {})
        control = ControlAuth.from_hex(codec, {s: keys[s] for s in (RUNNER, CONTROLLER, name or "") if s in keys})
        bus = open_bus(BusConfig.from_dict(info["bus"]))
        client = cls(
            name, codec, bus, lockstep=lockstep, sample_time=info["sample_time"], owns_bus=True, control=control
        )
        client.join()
        return client

    def join(self) -> None:
        """Announce this node (its boot-up heartbeat); the runner waits for it before tick 0. Until
        the first tick arrives, ``announce`` repeats it: a boot-up lost in a burst on the bus
        costs a second, not the run."""
        if self._node is not None and not self._joined:
            self._heartbeat(BOOTUP)
            self._joined = True
            self._announced = time.monotonic()

    def announce(self, every: float = 0.5) -> None:
        """Repeat the boot-up heartbeat every ``every`` seconds until the run's first SYNC arrives."""
        if self._node is not None and self._joined and self.assembler.last_sync is None and not self.stopped:
            if time.monotonic() - self._announced >= every:
                self._heartbeat(BOOTUP)
                self._announced = time.monotonic()

    def close(self) -> None:
        """Leave the bus (a stopped heartbeat, then the bus is closed if the client opened it)."""
        if self._node is not None and self._joined and not self.stopped:
            self._heartbeat(STOPPED)
        self.stopped = True
        if self._owns_bus:
            self.bus.shutdown()
            self._owns_bus = False

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- receiving ------------------------------------------------------------------------------

    def feed(self, frame: can.Message) -> list[TickFrames]:
        """Take one frame from the bus; returns the ticks it completes."""
        if not self.wants(frame):
            return []
        try:
            decoded = self.codec.decode(frame)
        except CodecError:
            return []  # not decodable: someone else's frame with a clashing id
        return self.take(frame, decoded)

    def wants(self, frame: can.Message) -> bool:
        """Whether ``frame`` concerns this participant, by its id (it is not decoded otherwise)."""
        return not frame.is_extended_id and frame.arbitration_id in self._wanted

    def take(self, frame: can.Message, decoded: Decoded | None) -> list[TickFrames]:
        """A frame it ``wants``, with what the codec decodes from it (None: nothing of the run's
        database, or not decodable), as ``feed`` takes it: the ticks it completes (a batch hands a
        run's node each frame decoded once for all its nodes: ``cosim.campaign.batch_wire``)."""
        if decoded is None or decoded.spec.sender == self.name:  # unknown id, or our own frame back
            return []
        if decoded.spec.role in (SYNC, NMT, HEARTBEAT):
            near = self.assembler.last_sync or 0
            rejection = None if self.control is None else self.control.verify(frame, near)
            if rejection is not None:  # forged, or another run's: it neither stops nor moves this node
                self.rejections[(rejection.frame_id, rejection.reason)] += 1
                return []
            decoded = self.codec.with_full_tick(decoded, near)
        if self.secoc is not None:
            rejection = self.secoc.verify(frame, self.assembler.last_sync or 0)
            if rejection is not None:  # dropped before it counts: SYNC announces genuine frames only
                self.rejections[(rejection.frame_id, rejection.reason)] += 1
                return []
        if decoded.spec.role == NMT:
            node = int(decoded.values["node"])
            ours = self._node is not None and node == self.codec.node_ids[self._node]
            if decoded.values["command"] == NMT_STOP and (node == 0 or ours):
                self.stopped = True
            return []
        return self.assembler.push(decoded)

    def ticks(self, timeout: float | None = None) -> Iterator[TickFrames]:
        """Tick after tick until the run stops (NMT stop); each tick closes when the loop body
        returns. ``timeout``: give up after that many seconds without a tick."""
        last = time.monotonic()
        while not self.stopped:
            self.announce()
            for frame in drain(self.bus, _WAIT):
                for tick in self.feed(frame):
                    last = time.monotonic()
                    yield tick
                    self.done(tick)
                if self.stopped:
                    return
            if timeout is not None and time.monotonic() - last > timeout:
                raise CosimError(f"no tick for {timeout:g} s: is the co-simulation still running?")

    def frames(self, timeout: float | None = None) -> Iterator[Decoded]:
        """Every decoded frame on the bus (for monitors), until the run stops."""
        last = time.monotonic()
        while not self.stopped:
            for frame in drain(self.bus, _WAIT):
                last = time.monotonic()
                try:
                    decoded = self.codec.decode(frame)
                except CodecError:
                    continue
                if decoded is None:
                    continue
                if (
                    decoded.spec.role == NMT
                    and decoded.values["command"] == NMT_STOP
                    and decoded.values["node"] == 0
                    and (self.control is None or self.control.verify(frame, 0) is None)
                ):
                    self.stopped = True
                yield decoded
                if self.stopped:
                    return
            if timeout is not None and time.monotonic() - last > timeout:
                return

    # -- sending --------------------------------------------------------------------------------

    def publish(self, tick: TickFrames | int, values: Mapping[str, float], *, saturate: bool = False) -> None:
        """Send this node's messages for a tick, with ``values`` by signal name (all of them).

        A value outside its signal's declared range is a CodecError naming it, or, with
        ``saturate``, sent at the bound it crossed (±inf included; NaN is still an error): what a
        real node's signal does, so that a diverging estimate is a result, not the run's end."""
        if not self.declared:
            raise CosimError(
                f"{self.name!r} has no messages in this run's DBC; declare it in the scenario's [[clients]]"
            )
        k = tick.tick if isinstance(tick, TickFrames) else tick
        frames = []
        for spec in self.messages:
            missing = [s for s in spec.signals if s not in values]
            if missing:
                raise CosimError(f"publish: no value for {', '.join(missing)} (message {spec.name})")
            payload = [values[s] for s in spec.signals]
            if saturate:
                payload = saturated(payload, spec.channels)
            if self.decoded is not None and self.secoc is None:  # a SecOC trailer is written after encoding
                frame, carried = self.codec.encode_decoded(spec.name, k, payload)
                self.decoded[id(frame)] = (frame, carried)
            else:
                frame = self.codec.encode(spec.name, k, payload)
            if self.secoc is not None:
                self.secoc.sign(frame, k)
            frames.append(frame)
        self._send(frames)

    def publish_encoded(self, frames: list[tuple[can.Message, Decoded]]) -> None:
        """Send its messages' frames for a tick, encoded elsewhere as ``publish`` encodes them (one
        per message, in order, with what each decodes to): a batch encodes its runs' frames on
        arrays (``Codec.encode_rows``). Not with SecOC, whose trailer ``publish`` writes."""
        if self.secoc is not None:
            raise CosimError("publish_encoded: frames signed under SecOC are published by publish")
        if self.decoded is not None:
            self.decoded.update((id(frame), (frame, decoded)) for frame, decoded in frames)
        self._send([frame for frame, _ in frames])

    def _send(self, frames: list[can.Message]) -> None:
        self._published += len(frames)
        if self.lockstep:  # they go with the heartbeat that closes the tick, in one datagram where the bus can
            self._outbox += frames
        else:
            send_all(self.bus, frames)

    def done(self, tick: TickFrames | int) -> None:
        """Close a tick: the heartbeat that tells the runner this node has answered it, after the
        frames published for it (together, in one datagram on a bus that batches)."""
        if self.lockstep and self._node is not None:  # lockstep only for a declared node
            k = tick.tick if isinstance(tick, TickFrames) else tick
            self._outbox.append(self._heartbeat_frame(OPERATIONAL, k, self._published, self.assembler.lost))
            send_all(self.bus, self._outbox)
            self.closing = self._outbox
        self._outbox = []
        self._published = 0

    def _heartbeat_frame(self, state: int, tick: int, frames: int = 0, lost: int = 0) -> can.Message:
        frame = self.codec.heartbeat(self._node or "", state, tick, frames, lost)
        if self.control is not None:
            self.control.sign(frame, tick)
        return frame

    def _heartbeat(self, state: int) -> None:
        """Send this node's boot-up or stopped heartbeat (at the last tick it saw), signed."""
        self.bus.send(self._heartbeat_frame(state, self.assembler.last_sync or 0))
