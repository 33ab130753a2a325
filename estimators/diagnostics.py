"""What an estimator or controller publishes beside its estimate or command each tick: named
scalar diagnostics, each declared once (a ``Diagnostic``, or a pattern of one per output, state or
thruster) with its unit, its bus range and what it is (``DiagnosticKind``), by which the plots and
metrics find the signals they need."""

from __future__ import annotations

import functools
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, replace
from enum import StrEnum
from typing import Any

import numpy as np


class DiagnosticKind(StrEnum):
    """What a diagnostic is: plots and metrics find the signals they need by kind, never by name."""

    BIAS_ESTIMATE = "bias_estimate"
    """φ̂ of an output (TAC 2024 eq. (7c)); target: the output."""
    SELECTOR = "selector"
    """the selector state s (TAC 2024 eq. (17)); target: the output."""
    OPTIMIZER = "optimizer"
    """the optimizer state z (TAC 2024 eq. (16)); target: the output."""
    WEIGHT = "weight"
    """a pseudoinverse weight Γ (CDC 2016 eq. (7)); target: the output."""
    INJECTION = "injection"
    """the output injection's component; target: the state."""
    LOGIC = "logic"
    """a switching variable (the selector logic h)."""
    RESIDUAL = "residual"
    """a residual component; target: the output (UIO) or the observer whose residual it is (COFD)."""
    RESIDUAL_NORM = "residual_norm"
    THRESHOLD = "threshold"
    """the threshold of a residual component; target: that residual's signal."""
    ALARM = "alarm"
    """1 while a fault is detected."""
    ISOLATION = "isolation"
    """1 once the fault is isolated to the target (a thruster, a sensor, ...)."""
    FAULT_MASK = "fault_mask"
    """the isolated targets as bits."""
    CONSTRAINT = "constraint"
    """1 while a structural constraint holds."""
    GAIN_ESTIMATE = "gain_estimate"
    """an estimated sensor effectiveness γ̂ (IJC 2018 eq. (53)); target: the sensor."""
    BIAS = "bias"
    """an estimated sensor bias b̂."""
    VIRTUAL_OUTPUT = "virtual_output"
    """the reconciled virtual output ẑ (IJC 2018 eq. (6))."""
    EXCITATION = "excitation"
    FIT = "fit"
    CONTROL_ERROR = "control_error"
    """a controller's tracking error; target: the output."""
    EFFORT = "effort"
    """a commanded generalized force."""
    RECONFIGURATION = "reconfiguration"
    """1 once a controller reconfigured."""
    OTHER = "other"


@dataclass(frozen=True)
class Diagnostic:
    """A scalar an estimator publishes beside x̂ each tick (for example a pseudoinverse weight).

    ``bound`` and ``resolution`` size its classic-CAN signal: values in [−bound, bound] in steps
    of ``resolution`` (CAN FD carries float64). ``kind`` says what it is and ``target`` what it
    refers to (an output, a state, a thruster, another signal), for the tools that read it back.

    Diagnostics of one per key (an output, a state, a thruster, an (observer, component) pair) are
    declared once, as a pattern whose ``name``, ``description`` and ``target`` are format strings
    of the key (of its items, for a tuple), e.g. ``Diagnostic("phihat_{}", "", "φ̂ ({})", ...)``:
    ``over(keys)`` declares them (their target, unless given, the key), ``values(keys, numbers)``
    is what a step publishes, and ``read(diagnostics, keys)`` reads them back.
    """

    name: str
    unit: str
    description: str
    bound: float
    resolution: float
    kind: DiagnosticKind = DiagnosticKind.OTHER
    target: str = ""

    def named(self, key: Any) -> str:
        """The name of the pattern's diagnostic for ``key``."""
        return self.name.format(*_items(key))

    def over(self, keys: Iterable[Any]) -> list[Diagnostic]:
        """The pattern's diagnostics, one per key."""
        return [
            replace(
                self,
                name=self.named(key),
                description=self.description.format(*_items(key)),
                target=self.target.format(*_items(key)) if self.target else str(key),
            )
            for key in keys
        ]

    def values(self, keys: Iterable[Any], numbers: Iterable[Any]) -> dict[str, float]:
        """The pattern's diagnostics for these keys, with these values, as a step publishes them
        (the names are formatted once per pattern and keys: this runs every tick)."""
        floats = numbers.tolist() if isinstance(numbers, np.ndarray) else [float(n) for n in numbers]
        return dict(zip(_names(self.name, tuple(keys)), floats))

    def read(self, diagnostics: Mapping[str, float], keys: Iterable[Any]) -> np.ndarray:
        """The values of the pattern's diagnostics for these keys, out of a step's diagnostics."""
        return np.array([diagnostics[self.named(key)] for key in keys])


@functools.lru_cache(maxsize=1024)
def _names(pattern: str, keys: tuple[Any, ...]) -> tuple[str, ...]:
    return tuple(pattern.format(*_items(key)) for key in keys)


def _items(key: Any) -> tuple[Any, ...]:
    return key if isinstance(key, tuple) else (key,)
