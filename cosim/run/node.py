"""Nodes: an estimator or the controller on the bus, seeing only CAN frames.

An estimator node is a ``Client`` whose answer to tick k is its estimator's estimate x̂_k: it
decodes the sensor readings and commanded inputs of tick k, calls ``estimator.step`` and publishes
the ``EST_<name>`` frames, then the heartbeat that closes the tick. The controller node answers
tick k with the commands u_k (``COMMAND_<actuator>`` frames, which the runner applies to the plant)
and its ``CONTROL_STATUS``. ``cosim node`` runs one in a process of its own (``serve``); with the
``virtual`` interface the runner drives nodes in its own process through the same classes.

Everything a node needs comes in a ``NodeSpec``: its kind and parameters, the linear model it is
designed on (from the runner's linearization of the plant), the run's DBC and bus, and the nodes
it listens to (``upstream``, see ``cosim.bus.client.TickAssembler``).
"""

from __future__ import annotations

import json
import os
import sys
import traceback
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import can
import numpy as np

import estimators
from cosim.blas import one_thread
from cosim.bus.client import Client, TickFrames
from cosim.bus.codec import COMMAND, CONTROLLER, Codec, estimated_state
from cosim.bus.control_frames import ControlAuth
from cosim.bus.secoc import SecOC
from cosim.bus.transport import BusConfig, drain, open_bus
from cosim.errors import CosimError
from estimators import Estimator, LinearModel, ParameterError
from estimators import controller as controllers


@dataclass(frozen=True)
class NodeSpec:
    """What a node needs, as one JSON document. The node named ``controller`` is the controller."""

    name: str
    kind: str
    params: dict[str, Any]
    model: LinearModel
    dbc: str
    bus: BusConfig
    sample_time: float
    upstream: dict[str, int] = field(default_factory=dict)
    """Nodes whose frames this one needs, with the lag in ticks (``cosim.bus.client.TickAssembler``)."""
    diagnosis: str = ""
    """The controller's diagnosis node (upstream with lag 1), whose report it reads."""
    keys: dict[str, str] = field(default_factory=dict, repr=False)
    """SecOC (``cosim.bus.secoc``): AES keys (hex) by sender, its own and those of the senders it
    hears; secret: the spec file is private to the run and deleted once the node has read it."""
    control_keys: dict[str, str] = field(default_factory=dict, repr=False)
    """Control frames (``cosim.bus.control_frames``): keys (hex) by sender, its own (to sign its
    heartbeats), the runner's and those of its upstream nodes (to verify); as secret as ``keys``."""

    def secoc(self, codec: Codec) -> SecOC | None:
        """The node's SecOC on a secured bus (None otherwise); a CosimError if its keys are missing."""
        secoc = SecOC.from_codec(codec, {sender: bytes.fromhex(key) for sender, key in self.keys.items()})
        if secoc is not None and self.name not in self.keys:
            raise CosimError(f"node {self.name}: the bus is authenticated (SecOC) and its spec holds no key of it")
        return secoc

    def control(self, codec: Codec) -> ControlAuth | None:
        """The node's control-frame keys (None: the DBC's control frames carry no MAC); a CosimError
        if its spec holds none of its own."""
        if not codec.control_macs:
            return None
        if self.name not in self.control_keys:
            raise CosimError(f"node {self.name}: its spec holds no control key of its own (control frames are signed)")
        return ControlAuth.from_hex(codec, self.control_keys)

    def to_json(self) -> str:
        return json.dumps(
            {
                "name": self.name,
                "kind": self.kind,
                "params": self.params,
                "model": self.model.to_dict(),
                "dbc": self.dbc,
                "bus": self.bus.to_dict(),
                "sample_time": self.sample_time,
                "upstream": self.upstream,
                "diagnosis": self.diagnosis,
                **({"keys": self.keys} if self.keys else {}),
                **({"control_keys": self.control_keys} if self.control_keys else {}),
            }
        )

    @classmethod
    def from_json(cls, text: str) -> NodeSpec:
        data = json.loads(text)
        model = LinearModel.from_dict(data["model"])
        return cls(
            data["name"],
            data["kind"],
            data["params"],
            model,
            data["dbc"],
            BusConfig.from_dict(data["bus"]),
            data["sample_time"],
            data.get("upstream", {}),
            data.get("diagnosis", ""),
            data.get("keys", {}),
            data.get("control_keys", {}),
        )


T = TypeVar("T")


def _create(create: Callable[..., T], spec: NodeSpec, what: str) -> T:
    """The node's estimator or controller, built by ``create`` from its spec (on one BLAS thread, as
    the runner builds it: ``cosim.blas.one_thread``); CosimError naming it."""
    try:
        with one_thread():
            return create(spec.kind, spec.model, spec.params, spec.sample_time)
    except ParameterError as error:
        raise CosimError(f"{what}: params.{error}") from None


def node_client(spec: NodeSpec, codec: Codec, bus: can.BusABC, name: str) -> Client:
    """The client named ``name`` a node of ``spec`` puts on ``bus``: its sample time, the nodes it
    listens to, its keys (a batch drives a run's nodes through the same: ``cosim.campaign.batch_wire``)."""
    return Client(
        name,
        codec,
        bus,
        sample_time=spec.sample_time,
        upstream=spec.upstream,
        secoc=spec.secoc(codec),
        control=spec.control(codec),
    )


class _Node(ABC):
    """A participant answering each tick on a bus through its ``client``: ``answer`` publishes its
    frames for the tick and closes it with the heartbeat."""

    spec: NodeSpec
    codec: Codec
    client: Client
    ticks: int
    """Ticks answered so far."""

    @abstractmethod
    def answer(self, tick: TickFrames) -> None:
        """Publish this node's frames for a complete tick, then close it."""

    def _join(self, spec: NodeSpec, bus: can.BusABC, name: str) -> None:
        """Read the spec's database and put a client named ``name`` on ``bus``."""
        self.spec = spec
        self.codec = Codec.from_dbc(spec.dbc)
        self.client = node_client(spec, self.codec, bus, name)
        self.ticks = 0

    def _publish(self, tick: TickFrames, values: dict[str, float], saturate: bool = False) -> None:
        self.client.publish(tick, values, saturate=saturate)
        self.client.done(tick)
        self.ticks += 1

    def service(self, timeout: float = 0.0) -> int:
        """Handle every frame waiting on the bus (waiting up to ``timeout`` for the first);
        returns the number of ticks answered."""
        answered = 0
        for frame in drain(self.client.bus, timeout):
            for tick in self.client.feed(frame):
                self.answer(tick)
                answered += 1
        return answered


class EstimatorNode(_Node):
    """An estimator answering each tick on a bus: y_k and u_k in, x̂_k and its diagnostics out.

    Missing sensor readings reach the estimator as NaN. A command that did not arrive is held at
    its last value (zero before the first). An estimate or diagnostic outside its signal's declared
    range is sent at the bound (saturated), as a real node's signal is; the metrics count those ticks.
    """

    def __init__(self, spec: NodeSpec, bus: can.BusABC, estimator: Estimator | None = None) -> None:
        if estimator is None:
            estimator = _create(estimators.create, spec, f"estimator {spec.name}")
        self.estimator = estimator
        self._join(spec, bus, spec.name)
        model = estimator.model
        signals = [signal for message in self.client.messages for signal in message.signals]
        states = {signal: estimated_state(signal) for signal in signals}
        self._states = [(signal, model.states.index(state)) for signal, state in states.items() if state is not None]
        self._diagnostics = [signal for signal, state in states.items() if state is None]
        self._u = np.zeros(model.m)

    def answer(self, tick: TickFrames) -> None:
        model = self.estimator.model
        y = np.array([tick.sensors.get(name, np.nan) for name in model.outputs])
        for i, name in enumerate(model.inputs):
            if name in tick.commands:
                self._u[i] = tick.commands[name]
        try:  # the estimator's own code (a plugin's, maybe): what it raises ends this node, not the run
            estimate = self.estimator.step(y, self._u.copy())
            values = {signal: float(estimate.x[index]) for signal, index in self._states}
            values |= {signal: float(estimate.diagnostics[signal]) for signal in self._diagnostics}
        except Exception as error:  # noqa: BLE001
            raise EstimatorFailure(self.client.name or "", error) from error
        self._publish(tick, values, saturate=True)


class ControllerNode(_Node):
    """The controller on the bus: y_k and the diagnosis node's report in, u_k out.

    Missing sensor readings reach the controller as NaN. Commands go out in the ``COMMAND_``
    frames, diagnostics in ``CONTROL_STATUS``; a command outside its actuator's declared range is
    an error naming the signal (the controller must saturate what it asks for).
    """

    def __init__(self, spec: NodeSpec, bus: can.BusABC, controller: controllers.Controller | None = None) -> None:
        self.controller = controller if controller is not None else _create(controllers.create, spec, "controller")
        self._join(spec, bus, CONTROLLER)
        self._inputs = {
            channel.name: signal
            for message in self.client.messages
            for channel, signal in zip(message.channels, message.signals)
            if message.role == COMMAND
        }
        self._diagnostics = [
            signal for message in self.client.messages if message.role != COMMAND for signal in message.signals
        ]

    def answer(self, tick: TickFrames) -> None:
        model = self.controller.model
        y = np.array([tick.sensors.get(name, np.nan) for name in model.outputs])
        report = tick.upstream.get(self.spec.diagnosis, {}) if self.spec.diagnosis else {}
        t = tick.t if tick.t is not None else tick.tick * self.spec.sample_time
        command = self.controller.step(y, t, report)
        values = {self._inputs[name]: float(u) for name, u in zip(model.inputs, command.u)}
        values |= {signal: command.diagnostics[signal] for signal in self._diagnostics}
        self._publish(tick, values)


#: The exit status of a node process whose estimator raised (the runner goes on without it).
ESTIMATOR_FAILED = 4


class EstimatorFailure(Exception):
    """The estimator of a node raised (or returned what is not an estimate): its traceback."""

    def __init__(self, name: str, error: BaseException) -> None:
        self.traceback = "".join(traceback.format_exception(error))
        super().__init__(f"node {name}: its estimator raised {type(error).__name__}; its traceback:\n{self.traceback}")


def serve(spec: NodeSpec) -> int:
    """Run a node process until the runner stops it (NMT stop) or goes away; returns the exit status."""
    parent = os.getppid()
    bus = open_bus(spec.bus)
    node = ControllerNode(spec, bus) if spec.name == CONTROLLER else EstimatorNode(spec, bus)
    try:
        node.client.join()
        while not node.client.stopped:
            node.service(timeout=0.5)
            node.client.announce()
            if os.getppid() != parent:  # the runner died without stopping us
                return 3
        return 0
    except KeyboardInterrupt:
        return 0
    except EstimatorFailure as failure:
        sys.stderr.write(failure.traceback)
        return ESTIMATOR_FAILED
    finally:
        node.client.close()
        bus.shutdown()


def load_spec(path: str | Path) -> NodeSpec:
    try:
        text = Path(path).read_text()
        spec = NodeSpec.from_json(text)
        if spec.keys:  # it holds the run's keys: the runner wrote it for this node alone
            Path(path).unlink(missing_ok=True)
        return spec
    except (OSError, ValueError, KeyError) as error:
        raise CosimError(f"{path}: not a readable node spec ({error})") from None
