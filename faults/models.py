"""Fault models applied between the plant's true signals and the bus.

Sensor faults act on a vector of readings y (one entry per transmitted sensor) and return the
faulty readings; a fault may also stop some sensors' frames from being sent (``drops``).
Actuator faults scale the commanded inputs. Every model is active on the window
start <= t < end, acts on a subset of channels (indices into y or u), and draws its randomness
from its own generator, keyed by the model's label, so that adding, removing or reordering other
faults never changes its random sequence.

Sources: additive bias φ (TAC 2024, eq. (1)); bias of constant direction and time-varying
amplitude φ_k = g_k φ̄ (TAC 2024, eq. (35)); sensor loss of effectiveness y_i ← γ_i y_i (IJC 2018,
eq. (2)–(4)); actuator loss of effectiveness u_eff = Δ u (Cristofaro & Johansen, eq. (1)); additive
actuator fault u_eff = u + f_a (course notes on the UIO, eq. (11)).
"""

from __future__ import annotations

import bisect
import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from typing import Any, ClassVar

import numpy as np

from cosim.kinds import Kinds
from faults.waveforms import Constant, Waveform


def per_channel(what: str, default: Any = ()) -> Any:
    """A parameter with one value per channel (a scalar stands for all), kept as an array in
    ``_vectors``; ``what`` names it in messages."""
    return field(default=default, metadata={"per_channel": what})


def profiles(what: str) -> Any:
    """A parameter with one waveform per channel; ``what`` names it in messages."""
    return field(default=(), metadata={"profiles": what})


def probability(what: str) -> Any:
    """A parameter in [0, 1]; ``what`` names it in messages."""
    return field(default=0.0, metadata={"probability": what})


def per_channel_parameters(model: type[Fault]) -> tuple[str, ...]:
    """The parameters of a fault model that hold one value per channel."""
    return tuple(f.name for f in fields(model) if {"per_channel", "profiles"} & f.metadata.keys())


@dataclass
class Fault(ABC):
    """A fault acting on some channels of a signal vector during [start, end).

    A model is a dataclass whose fields after these are its parameters, with a ``kind``; a
    parameter declared with ``per_channel`` or ``profiles`` is checked to have one value per
    channel, one declared with ``probability`` to lie in [0, 1]."""

    channels: tuple[int, ...]
    start: float = 0.0
    end: float = math.inf
    label: str = ""
    _rng: np.random.Generator = field(default=None, init=False, repr=False, compare=False)  # type: ignore[assignment]
    _vectors: dict[str, np.ndarray] = field(default_factory=dict, init=False, repr=False, compare=False)

    kind: ClassVar[str]

    def __post_init__(self) -> None:
        for parameter in fields(self):
            value, what = getattr(self, parameter.name), parameter.metadata
            if "per_channel" in what and value is not None:
                self._vectors[parameter.name] = _vector(value, self.channels, what["per_channel"])
            if "profiles" in what and len(value) != len(self.channels):
                raise ValueError(
                    f"{what['profiles']}: expected {len(self.channels)} profiles (one per channel), got {len(value)}"
                )
            if "probability" in what and not 0.0 <= value <= 1.0:
                raise ValueError(f"{what['probability']} must be in [0, 1]")

    def reset(self, rng: np.random.Generator) -> None:
        """Prepare for a new run with this fault's own random generator."""
        self._rng = rng

    def active(self, t: float) -> bool:
        return self.start <= t < self.end


class SensorFault(Fault):
    """A fault on sensor readings: y ← f(y, t)."""

    def apply(self, y: np.ndarray, t: float) -> np.ndarray:
        """The readings after this fault at time t (a new array; y is not modified)."""
        if not self.active(t):
            return y
        out = y.copy()
        index = list(self.channels)
        out[index] = self._affect(y[index], t - self.start)
        return out

    @classmethod
    def apply_batch(cls, models: Sequence[SensorFault], y: np.ndarray, t: float) -> np.ndarray:
        """``apply`` for K runs at once: the K instances of one fault of a batch (one configuration,
        each with its own random stream), y of shape (K, p); row r is, bit for bit, what
        ``models[r].apply(y[r], t)`` returns. By default each instance applies itself; a model
        whose effect is the same arithmetic in every run does it on the array
        (``_affect_batch``)."""
        first = models[0]
        if not first.active(t):
            return y
        affect = getattr(first, "_affect_batch", None)
        if affect is None or type(first).active is not Fault.active:
            return np.stack([m.apply(row, t) for m, row in zip(models, y)])
        out = y.copy()
        index = list(first.channels)
        out[:, index] = affect(models, y[:, index], t - first.start)
        return out

    @abstractmethod
    def _affect(self, y: np.ndarray, elapsed: float) -> np.ndarray:
        """The faulty values of this fault's channels, ``elapsed`` seconds after onset."""

    def drops(self, t: float) -> list[int]:
        """Channels whose frame is not sent at time t (called once per tick, after ``apply``)."""
        return []


def _vector(values: float | tuple[float, ...], channels: tuple[int, ...], what: str) -> np.ndarray:
    """One value per channel; a scalar applies to every channel."""
    array = np.asarray(values, dtype=float)
    if array.ndim == 0:
        array = np.full(len(channels), float(array))
    if array.shape != (len(channels),):
        raise ValueError(f"{what}: expected {len(channels)} values (one per channel), got {array.size}")
    return array.copy()


@dataclass
class Bias(SensorFault):
    """Additive bias φ(t) = g(t − start) · value: constant (g ≡ 1) or of constant direction and
    time-varying amplitude, φ_k = g_k φ̄ (TAC 2024, eq. (35))."""

    value: tuple[float, ...] = per_channel("bias value")
    amplitude: Waveform = Constant(1.0)
    kind = "bias"

    def _affect(self, y: np.ndarray, elapsed: float) -> np.ndarray:
        return y + self.amplitude(elapsed) * self._vectors["value"]

    def _affect_batch(self, models: Sequence[Bias], y: np.ndarray, elapsed: float) -> np.ndarray:
        return y + self.amplitude(elapsed) * self._vectors["value"]


@dataclass
class Drift(SensorFault):
    """Additive ramp (drift) φ(t) = rate · (t − start)."""

    rate: tuple[float, ...] = per_channel("drift rate")
    kind = "drift"

    def _affect(self, y: np.ndarray, elapsed: float) -> np.ndarray:
        return y + self._vectors["rate"] * elapsed


@dataclass
class Gain(SensorFault):
    """Loss of effectiveness y_i ← γ_i(t − start) · y_i (IJC 2018, eq. (2)–(4))."""

    gain: tuple[Waveform, ...] = profiles("gain")
    kind = "gain"

    def _affect(self, y: np.ndarray, elapsed: float) -> np.ndarray:
        return y * np.array([g(elapsed) for g in self.gain])


@dataclass
class GaussianNoise(SensorFault):
    """Additive white Gaussian noise with standard deviation ``std`` per channel."""

    std: tuple[float, ...] = per_channel("noise std")
    kind = "gaussian_noise"

    def _affect(self, y: np.ndarray, elapsed: float) -> np.ndarray:
        return y + self._vectors["std"] * self._rng.standard_normal(len(self.channels))

    def _affect_batch(self, models: Sequence[GaussianNoise], y: np.ndarray, elapsed: float) -> np.ndarray:
        return y + self._vectors["std"] * np.stack([m._rng.standard_normal(len(m.channels)) for m in models])


@dataclass
class UniformNoise(SensorFault):
    """Additive noise uniform on [−bound, bound] per channel."""

    bound: tuple[float, ...] = per_channel("noise bound")
    kind = "uniform_noise"

    def _affect(self, y: np.ndarray, elapsed: float) -> np.ndarray:
        return y + self._vectors["bound"] * self._rng.uniform(-1.0, 1.0, len(self.channels))

    def _affect_batch(self, models: Sequence[UniformNoise], y: np.ndarray, elapsed: float) -> np.ndarray:
        return y + self._vectors["bound"] * np.stack([m._rng.uniform(-1.0, 1.0, len(m.channels)) for m in models])


@dataclass
class StuckAt(SensorFault):
    """The reading freezes: at ``value`` if given, else at the reading at onset."""

    value: tuple[float, ...] | None = per_channel("stuck value", None)
    kind = "stuck"

    def reset(self, rng: np.random.Generator) -> None:
        super().reset(rng)
        self._held = self._vectors.get("value")

    def _affect(self, y: np.ndarray, elapsed: float) -> np.ndarray:
        if self._held is None:
            self._held = y.copy()
        return self._held.copy()


@dataclass
class Dropout(SensorFault):
    """Intermittent loss: each tick, each channel's frame is not sent with ``probability``."""

    probability: float = probability("dropout probability")
    kind = "dropout"

    def _affect(self, y: np.ndarray, elapsed: float) -> np.ndarray:
        return y

    def drops(self, t: float) -> list[int]:
        if not self.active(t):
            return []
        lost = self._rng.random(len(self.channels)) < self.probability
        return [channel for channel, gone in zip(self.channels, lost) if gone]


@dataclass
class Outliers(SensorFault):
    """Spikes: each tick, with ``probability`` per channel, add ±magnitude (random sign)."""

    probability: float = probability("outlier probability")
    magnitude: tuple[float, ...] = per_channel("outlier magnitude")
    kind = "outliers"

    def _affect(self, y: np.ndarray, elapsed: float) -> np.ndarray:
        hit = self._rng.random(len(self.channels)) < self.probability
        sign = np.where(self._rng.random(len(self.channels)) < 0.5, -1.0, 1.0)
        return y + hit * sign * self._vectors["magnitude"]


class ActuatorFault(Fault):
    """A fault on the inputs: u_eff = δ(t) ∘ u + f_a(t), composed over all actuator faults as the
    product of their factors δ and the sum of their offsets f_a."""

    def factors(self, t: float, n: int) -> np.ndarray:
        """The multiplicative factor on each of the n inputs at time t (1 where unaffected)."""
        return np.ones(n)

    def offsets(self, t: float, n: int) -> np.ndarray:
        """The additive offset on each of the n inputs at time t (0 where unaffected)."""
        return np.zeros(n)


@dataclass
class ActuatorEffectiveness(ActuatorFault):
    """Actuator loss of effectiveness u_eff,i = δ_i(t − start) · u_i (Cristofaro & Johansen, eq. (1))."""

    effectiveness: tuple[Waveform, ...] = profiles("effectiveness")
    kind = "actuator_effectiveness"

    def factors(self, t: float, n: int) -> np.ndarray:
        delta = np.ones(n)
        if self.active(t):
            delta[list(self.channels)] = [d(t - self.start) for d in self.effectiveness]
        return delta


@dataclass
class ActuatorOffset(ActuatorFault):
    """Additive actuator fault u_eff,i = u_i + g(t − start) · value_i: the f_a of ẋ = A x + B u + B f_a
    (course notes on the UIO, eq. (11)); constant (g ≡ 1) or of constant direction and varying
    amplitude, like ``Bias`` on the sensors."""

    value: tuple[float, ...] = per_channel("actuator offset value")
    amplitude: Waveform = Constant(1.0)
    kind = "actuator_offset"

    def offsets(self, t: float, n: int) -> np.ndarray:
        offset = np.zeros(n)
        if self.active(t):
            offset[list(self.channels)] = self.amplitude(t - self.start) * self._vectors["value"]
        return offset


#: The attack kinds of ``faults.attacks`` (imported when first named): kind -> class name.
ATTACKS = {"suspension": "Suspension", "masquerade": "Masquerade", "fuzzing": "Fuzzing"}

# -- bus faults -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class FrameFate:
    """What a bus fault does to one frame: ``lost``, ``delay`` (s) before it is queued, ``errors``:
    transmission attempts destroyed (each an error frame; CAN retransmits unless ``single_shot``)."""

    lost: bool = False
    delay: float = 0.0
    errors: int = 0
    single_shot: bool = False


@dataclass
class BusFault(Fault):
    """A fault of the bus rather than of a signal: it acts on frames of some ``messages`` (DBC
    names), on a node's transmissions, or adds frames of an intruder. Bus faults are decided frame
    by frame by the runner (``cosim.run.busfaults``), from their own random stream, through these
    methods alone: a plugin's bus fault is one more subclass.

    Each genuine frame the runner sends meets ``fate`` of every active fault it ``hits``; a frame
    lost there may be taken over by an intruder (``substitute``); intruders add frames of a
    message right after its genuine frame (``inject``) and raw frames anywhere in the tick
    (``forge``). A fault that adds frames is an ``intruder``: its frames are foreign frames."""

    messages: tuple[str, ...] = ()

    intruder: ClassVar[bool] = False
    """It sends frames of its own (logged on ``/cosim/foreign``, each naming its frame)."""
    attack: ClassVar[str] = ""
    """Its class in the taxonomy of CAN attacks (``faults.attacks``): fabrication, suspension,
    masquerade or replay; empty for a fault of the bus that no one causes on purpose."""

    def targets(self) -> list[str]:
        """What it acts on, by name, for the log."""
        return list(self.messages)

    def hits(self, message: str, sender: str) -> bool:
        """Whether a genuine frame of ``message`` sent by ``sender`` meets ``fate``."""
        return message in self.messages

    def fate(self, message: str, t: float) -> FrameFate:
        """What becomes of a frame of ``message`` queued at t (called only while active)."""
        return FrameFate()

    def substitute(self, message: str, values: tuple[float, ...], t: float) -> tuple[float, ...] | None:
        """The values an intruder sends in place of a genuine frame of ``message`` (with these
        ``values``) that did not go out at t, in its slot and with its counter; None: nothing."""
        return None

    def inject(self, t: float) -> list[tuple[str, tuple[float, ...]]]:
        """Frames an intruder sends at t: (message, signal values), encoded by the runner, right
        after the genuine frame of the message (at the end of the tick where there was none)."""
        return []

    def forge(self, t: float, dt: float) -> list[tuple[float, int, bytes]]:
        """Raw frames an intruder puts on the bus in the tick [t, t + dt): (when, id, payload),
        ``when`` in [t, t + dt)."""
        return []

    def observe(self, message: str, values: tuple[float, ...], t: float) -> None:
        """A genuine frame an intruder could record."""


@dataclass
class FrameLoss(BusFault):
    """Frames of ``messages`` lost: each independently with ``probability`` (``burst_length`` 1), or
    in bursts: a burst starts at a frame with ``probability`` and goes on for a geometric number of
    frames of mean ``burst_length`` (a two-state Gilbert model)."""

    probability: float = 0.0
    burst_length: float = 1.0
    kind = "frame_loss"

    def reset(self, rng: np.random.Generator) -> None:
        super().reset(rng)
        self._left: dict[str, int] = {}

    def fate(self, message: str, t: float) -> FrameFate:
        left = self._left.get(message, 0)
        if left > 0:
            self._left[message] = left - 1
            return FrameFate(lost=True)
        if self._rng.random() < self.probability:
            self._left[message] = int(self._rng.geometric(1.0 / self.burst_length)) - 1
            return FrameFate(lost=True)
        return FrameFate()


@dataclass
class FrameDelay(BusFault):
    """Frames of ``messages`` held back ``delay`` ± ``jitter`` seconds (uniform, never negative)
    before they are queued: a gateway's store-and-forward, a slow transmit task."""

    delay: float = 0.0
    jitter: float = 0.0
    kind = "frame_delay"

    def fate(self, message: str, t: float) -> FrameFate:
        return FrameFate(delay=max(0.0, self.delay + self.jitter * self._rng.uniform(-1.0, 1.0)))


@dataclass
class FrameCorruption(BusFault):
    """Bit errors on frames of ``messages``: each transmission attempt is destroyed with
    ``probability`` (receivers discard it, an error frame follows, the transmitter's error counter
    rises by 8); CAN retransmits it, unless ``retransmit`` is false (single-shot mode)."""

    probability: float = 0.0
    retransmit: bool = True
    kind = "frame_corruption"

    def fate(self, message: str, t: float) -> FrameFate:
        errors = 0
        while errors < 64 and self._rng.random() < self.probability:
            errors += 1
            if not self.retransmit:
                break
        return FrameFate(errors=errors, single_shot=not self.retransmit)


@dataclass
class BusOff(BusFault):
    """Every transmission of ``node`` is destroyed (a shorted transceiver, CANstress disturbing
    all its frames): its transmit error counter passes 255 after 32 attempts and it goes bus-off;
    with ``recover`` it rejoins after 128 × 11 recessive bits, and goes bus-off again while the
    fault lasts."""

    node: str = "plant"
    recover: bool = False
    kind = "bus_off"

    def targets(self) -> list[str]:
        return [self.node]

    def hits(self, message: str, sender: str) -> bool:
        return sender == self.node

    def fate(self, message: str, t: float) -> FrameFate:
        return FrameFate(errors=64)


@dataclass
class BabblingNode(BusFault):
    """A node flooding ``frame_id`` (a high priority one) every ``period`` seconds with ``length``
    random bytes: on an arbitrated bus, what loses arbitration to it starves."""

    frame_id: int = 0x001
    period: float = 0.0
    length: int = 8
    kind = "babbling_node"
    intruder = True
    attack = "fabrication"

    def targets(self) -> list[str]:
        return [f"0x{self.frame_id:03X}"]


@dataclass
class Spoofing(BusFault):
    """An intruder sends ``message`` with the signal ``value`` every tick, right after the genuine
    frame: a receiver that gets both trusts neither (without the genuine one, it takes the forgery)."""

    message: str = ""
    value: tuple[float, ...] = ()
    kind = "spoofing"
    intruder = True
    attack = "fabrication"

    def targets(self) -> list[str]:
        return [self.message]

    def inject(self, t: float) -> list[tuple[str, tuple[float, ...]]]:
        return [(self.message, tuple(self.value))]


@dataclass
class Replay(BusFault):
    """An intruder records ``message`` and, while active, resends what it recorded ``lag`` seconds
    earlier, right after the genuine frame. Unauthenticated frames protect nothing, so it writes
    the current tick counter into them; an authenticated frame it can only resend as it was."""

    message: str = ""
    lag: float = 1.0
    kind = "replay"
    intruder = True
    attack = "replay"

    def reset(self, rng: np.random.Generator) -> None:
        super().reset(rng)
        self._heard: list[tuple[float, tuple[float, ...]]] = []

    def targets(self) -> list[str]:
        return [self.message]

    def observe(self, message: str, values: tuple[float, ...], t: float) -> None:
        if message == self.message:
            self._heard.append((t, values))
            while self._heard and self._heard[0][0] < t - self.lag - 1.0:
                self._heard.pop(0)

    def inject(self, t: float) -> list[tuple[str, tuple[float, ...]]]:
        # what it heard last by t - lag (heard in time order: a binary search, not a scan of the record)
        last = bisect.bisect_right(self._heard, t - self.lag + 1e-12, key=lambda heard: heard[0])
        return [(self.message, self._heard[last - 1][1])] if last else []


#: The fault models by kind (``kinds``): built in, a module path, or a plugin's entry point.
FAULT_MODELS: Kinds[type[Fault]] = Kinds(
    "fault",
    "cosim.faults",
    {
        model.kind: model
        for model in (
            Bias,
            Drift,
            Gain,
            GaussianNoise,
            UniformNoise,
            StuckAt,
            Dropout,
            Outliers,
            ActuatorEffectiveness,
            ActuatorOffset,
            FrameLoss,
            FrameDelay,
            FrameCorruption,
            BusOff,
            BabblingNode,
            Spoofing,
            Replay,
        )
    }
    | {kind: f"faults.attacks:{name}" for kind, name in ATTACKS.items()},
    Fault,
    params=None,
    check=lambda model: (
        []
        if issubclass(model, (SensorFault, ActuatorFault, BusFault))
        else ["not a SensorFault, ActuatorFault or BusFault subclass"]
    ),
)
