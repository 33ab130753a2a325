"""Bus nodes: they see only CAN frames, decode them with the run's DBC, and answer per tick.

A node gathers the frames of tick k (``TickAssembler``), calls its algorithm and sends its own
frames tagged with k. ``EstimatorNode`` wraps an estimator: sensor readings and commanded inputs
of tick k in, its estimate x̂_k out. ``NodeDriver`` binds a node to a python-can bus; it runs the
same in the runner's process (virtual bus) and in a node process of its own.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import can
import numpy as np

from cosim.codec import COMMAND, SENSOR, SYNC, Codec
from estimators import Estimator


@dataclass
class TickFrames:
    """The decoded inputs of one tick: sensor readings and commands that arrived, by channel name.

    ``expected`` is the number of data frames SYNC announced and ``received`` how many arrived.
    """

    tick: int
    expected: int
    sensors: dict[str, float] = field(default_factory=dict)
    commands: dict[str, float] = field(default_factory=dict)
    received: int = 0

    @property
    def complete(self) -> bool:
        return self.received >= self.expected


class TickAssembler:
    """Groups incoming frames by tick: SYNC(k) opens tick k and announces its data frames.

    ``push`` returns the tick once all its announced frames arrived. If SYNC(k+1) arrives while
    tick k is still incomplete, tick k is returned incomplete and the missing frames are counted
    in ``lost`` (in lockstep this cannot happen without frame loss on the transport).
    """

    def __init__(self, codec: Codec) -> None:
        self.codec = codec
        self.pending: TickFrames | None = None
        self.lost = 0

    def push(self, frame: can.Message) -> list[TickFrames]:
        decoded = self.codec.decode(frame)
        if decoded is None:
            return []
        done: list[TickFrames] = []
        role = decoded.spec.role
        if role == SYNC:
            if self.pending is not None:
                self.lost += self.pending.expected - self.pending.received
                done.append(self.pending)
            self.pending = TickFrames(decoded.tick, int(decoded.values["frames"]))
            if self.pending.complete:
                done.append(self.pending)
                self.pending = None
            return done
        pending = self.pending
        if role not in (SENSOR, COMMAND) or pending is None:
            return done
        if decoded.tick != pending.tick % self.codec.tick_modulus:
            self.lost += 1  # a late frame of an earlier tick
            return done
        target = pending.sensors if role == SENSOR else pending.commands
        for channel, signal in zip(decoded.spec.channels, decoded.spec.signals):
            target[channel.name] = decoded.values[signal]
        pending.received += 1
        if pending.complete:
            done.append(pending)
            self.pending = None
        return done


class EstimatorNode:
    """An estimator on the bus: y_k and u_k from tick k's frames in, frames of x̂_k out.

    Missing sensor readings reach the estimator as NaN. A command that did not arrive is held at
    its last value (zero before the first).
    """

    def __init__(
        self, name: str, estimator: Estimator, codec: Codec, sensors: tuple[str, ...], actuators: tuple[str, ...]
    ) -> None:
        self.name = name
        self.estimator = estimator
        self.codec = codec
        self.sensors = sensors
        self.actuators = actuators
        self.messages = codec.messages(sender=name)
        states = estimator.model.states
        self._state_index = [[states.index(c.name) for c in spec.channels] for spec in self.messages]
        self._u = np.zeros(len(actuators))

    def on_tick(self, tick: TickFrames) -> list[can.Message]:
        y = np.array([tick.sensors.get(name, np.nan) for name in self.sensors])
        for i, name in enumerate(self.actuators):
            if name in tick.commands:
                self._u[i] = tick.commands[name]
        estimate = self.estimator.step(y, self._u.copy())
        return [
            self.codec.encode(spec.name, tick.tick, estimate.x[index])
            for spec, index in zip(self.messages, self._state_index)
        ]


class NodeDriver:
    """Connects a node to a bus: feeds received frames to the assembler and sends the answers."""

    def __init__(self, node: EstimatorNode, bus: can.BusABC) -> None:
        self.node = node
        self.bus = bus
        self.assembler = TickAssembler(node.codec)
        self.ticks = 0

    def service(self, timeout: float = 0.0) -> int:
        """Handle every frame waiting on the bus (waiting up to ``timeout`` for the first);
        returns the number of ticks answered."""
        answered = 0
        frame = self.bus.recv(timeout)
        while frame is not None:
            for tick in self.assembler.push(frame):
                for reply in self.node.on_tick(tick):
                    self.bus.send(reply)
                answered += 1
            frame = self.bus.recv(0.0)
        self.ticks += answered
        return answered
