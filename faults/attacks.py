"""Attacks on the bus that the literature's taxonomy names and the other bus faults do not: an ECU
suspended, an ECU masqueraded, the bus fuzzed.

With ``babbling_node`` (flooding), ``spoofing`` (targeted injection) and ``replay`` of
``faults.models`` they make the taxonomy of CAN attacks of Verma et al. (ROAD, PLOS ONE 2024) and
Cho & Shin (CIDS, USENIX Security 2016): fabrication (flooding, targeted injection, fuzzing),
suspension, masquerade and replay. Each is a ``BusFault`` like a plugin's, decided frame by frame by
the runner (``cosim.run.busfaults``) through the methods of that class alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from faults.models import BusFault, FrameFate


@dataclass
class Suspension(BusFault):
    """The ECU that sends ``messages`` is silenced (a suspension attack: an attacker that drives
    it bus-off, or its firmware stopped): none of their frames goes out while active."""

    kind = "suspension"
    attack = "suspension"

    def fate(self, message: str, t: float) -> FrameFate:
        return FrameFate(lost=True)


@dataclass
class Masquerade(BusFault):
    """The genuine sender of ``message`` is suspended and an intruder sends the message in its
    place, in its slot, at its period and with its counter: timing gives nothing away.

    What it sends: ``value`` (one per signal) when given; otherwise what the genuine ECU would
    have sent plus ``offset`` + ``rate`` (t − start) per signal: the stealthiest masquerade, a
    bias injected into a reading that stays plausible, as an attacker with a model of the plant
    (or a tap on the sensor) would send it."""

    message: str = ""
    value: tuple[float, ...] | None = None
    offset: tuple[float, ...] = ()
    rate: tuple[float, ...] = ()
    kind = "masquerade"
    intruder = True
    attack = "masquerade"

    def targets(self) -> list[str]:
        return [self.message]

    def hits(self, message: str, sender: str) -> bool:
        return message == self.message

    def fate(self, message: str, t: float) -> FrameFate:
        return FrameFate(lost=True)

    def substitute(self, message: str, values: tuple[float, ...], t: float) -> tuple[float, ...] | None:
        if message != self.message:
            return None
        if self.value is not None:
            return tuple(float(v) for v in _per_signal(self.value, len(values), "value"))
        offset = _per_signal(self.offset or (0.0,), len(values), "offset")
        rate = _per_signal(self.rate or (0.0,), len(values), "rate")
        return tuple((np.asarray(values, dtype=float) + offset + rate * (t - self.start)).tolist())


def _per_signal(given: tuple[float, ...] | float, signals: int, what: str) -> np.ndarray:
    """One value per signal of the message (a single value stands for all)."""
    array = np.atleast_1d(np.asarray(given, dtype=float))
    if array.size == 1:
        return np.full(signals, float(array[0]))
    if array.size != signals:
        raise ValueError(f"masquerade {what}: the message carries {signals} signal(s), got {array.size} values")
    return array


@dataclass
class Fuzzing(BusFault):
    """An intruder sends frames of random ids in [``low``, ``high``] with ``length`` random bytes
    every ``period`` seconds (the fuzzy attack of the HCRL car-hacking data set: random ids and
    payloads every 0.5 ms), or with the same ``payload`` in every frame (ROAD's fuzzing: random ids,
    every byte 0xFF). A frame that lands on a message of the run is decoded as one: on a reading's
    id a receiver takes it for a second copy (or a frame of another tick), on a control frame's id
    its MAC fails."""

    low: int = 0x000
    high: int = 0x7FF
    period: float = 0.0005
    length: int = 8
    payload: bytes | None = None
    kind = "fuzzing"
    intruder = True
    attack = "fabrication"

    def __post_init__(self) -> None:
        super().__post_init__()
        if not 0 <= self.low <= self.high <= 0x7FF:
            raise ValueError(f"fuzzing ids: need 0 <= low <= high <= 0x7FF, got [{self.low:#x}, {self.high:#x}]")
        if not self.period > 0:
            raise ValueError("fuzzing period must be positive")
        if not 0 <= self.length <= 8:
            raise ValueError("fuzzing length must be 0 to 8 bytes")
        if self.payload is not None and len(self.payload) > 8:
            raise ValueError("fuzzing payload must be 0 to 8 bytes")

    def targets(self) -> list[str]:
        return [f"0x{self.low:03X}-0x{self.high:03X}"]

    def forge(self, t: float, dt: float) -> list[tuple[float, int, bytes]]:
        """Its frames of the tick: at start + n · period for every n that falls in [t, t + dt)."""
        first = max(0, int(np.ceil((t - self.start) / self.period - 1e-9)))
        out = []
        n = first
        while (when := self.start + n * self.period) < min(t + dt, self.end) - 1e-12:
            frame_id = int(self._rng.integers(self.low, self.high + 1))
            payload = self.payload
            if payload is None:
                payload = self._rng.integers(0, 256, self.length, dtype=np.uint8).tobytes()
            out.append((when, frame_id, payload))
            n += 1
        return out
