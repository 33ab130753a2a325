"""Scalar time profiles: input signals and the time-varying amplitudes of faults.

A waveform is a callable ``w(t) -> float``. Fault profiles are evaluated at the time since the
fault's onset, input signals at the simulated time. Examples from the papers:
``Sine(amplitude=0.1, frequency=100 / (2 * pi), offset=1)`` is γ_k = 1 + 0.1 sin(100 τ k) = 1 + 0.1 sin(100 t)
of TAC 2024 Sec. VII-A, and ``Exponential(initial=1, rate=0.03)`` is δ1 = e^(−0.03 t) of
Cristofaro & Johansen Sec. 4.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field


class Waveform(ABC):
    """Base class of scalar time profiles."""

    @abstractmethod
    def __call__(self, t: float) -> float:
        """The profile's value at time t [s]."""


@dataclass(frozen=True)
class Constant(Waveform):
    """w(t) = value."""

    value: float

    def __call__(self, t: float) -> float:
        return self.value


@dataclass(frozen=True)
class Periodic(Waveform):
    """w(t) = offset + amplitude · p(t), p a profile of period 1 / ``frequency`` (Hz) in [−1, 1]."""

    amplitude: float
    frequency: float
    offset: float = field(default=0.0, kw_only=True)

    def __call__(self, t: float) -> float:
        return self.offset + self.amplitude * self.profile(t)

    @abstractmethod
    def profile(self, t: float) -> float:
        """p(t)."""


@dataclass(frozen=True)
class Sine(Periodic):
    """p(t) = sin(2π · frequency · t + phase), phase in rad."""

    phase: float = 0.0

    def profile(self, t: float) -> float:
        return math.sin(2.0 * math.pi * self.frequency * t + self.phase)


@dataclass(frozen=True)
class Square(Periodic):
    """p(t) = ±1: +1 for the first ``duty`` fraction of each period."""

    duty: float = 0.5

    def profile(self, t: float) -> float:
        return 1.0 if (t * self.frequency) % 1.0 < self.duty else -1.0


@dataclass(frozen=True)
class Ramp(Waveform):
    """w(t) = offset + slope · t."""

    slope: float
    offset: float = 0.0

    def __call__(self, t: float) -> float:
        return self.offset + self.slope * t


@dataclass(frozen=True)
class Exponential(Waveform):
    """w(t) = final + (initial − final) · exp(−rate · t)."""

    rate: float
    initial: float = 1.0
    final: float = 0.0

    def __call__(self, t: float) -> float:
        try:
            decay = math.exp(-self.rate * t)
        except OverflowError:  # a growing exponential left the floats: the caller rejects non-finite values
            decay = math.inf
        return self.final + (self.initial - self.final) * decay


@dataclass(frozen=True)
class Sum(Waveform):
    """w(t) = Σ terms_i(t)."""

    terms: tuple[Waveform, ...]

    def __call__(self, t: float) -> float:
        return math.fsum(term(t) for term in self.terms)
