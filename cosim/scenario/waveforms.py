"""Waveform tables: a signal of time as a table with a ``kind`` (a number stands for a constant)."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BeforeValidator, Discriminator, Field

import faults as fm
from cosim.scenario.tables import NonNegative, Positive, Strict


def _as_waveform(value: Any) -> Any:
    """A number stands for a constant waveform."""
    return (
        {"kind": "constant", "value": value}
        if isinstance(value, (int, float)) and not isinstance(value, bool)
        else value
    )


class ConstantSpec(Strict):
    kind: Literal["constant"]
    value: float


class SineSpec(Strict):
    kind: Literal["sine"]
    amplitude: float
    frequency: NonNegative
    phase: float = 0.0
    offset: float = 0.0


class SquareSpec(Strict):
    kind: Literal["square"]
    amplitude: float
    frequency: Positive
    duty: Annotated[float, Field(gt=0, lt=1)] = 0.5
    offset: float = 0.0


class RampSpec(Strict):
    kind: Literal["ramp"]
    slope: float
    offset: float = 0.0


class ExponentialSpec(Strict):
    kind: Literal["exponential"]
    rate: float
    initial: float = 1.0
    final: float = 0.0


class SumSpec(Strict):
    kind: Literal["sum"]
    terms: list[WaveformSpec] = Field(min_length=1)


WaveformSpec = Annotated[
    ConstantSpec | SineSpec | SquareSpec | RampSpec | ExponentialSpec | SumSpec,
    Discriminator("kind"),
    BeforeValidator(_as_waveform),
]
SumSpec.model_rebuild()


def build_waveform(spec: Any) -> fm.Waveform:
    if isinstance(spec, SumSpec):
        return fm.Sum(tuple(build_waveform(term) for term in spec.terms))
    cls = {
        "constant": fm.Constant,
        "sine": fm.Sine,
        "square": fm.Square,
        "ramp": fm.Ramp,
        "exponential": fm.Exponential,
    }[spec.kind]
    return cls(**spec.model_dump(exclude={"kind"}))
