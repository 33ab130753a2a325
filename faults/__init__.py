"""Fault models and their injection between the plant and the bus.

``FaultInjector`` composes measurement noise and faults on the sensor readings, and loss of
effectiveness and additive offsets on the actuators, all seeded from the scenario's seed.
"""

from __future__ import annotations

import zlib
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from faults.models import (
    FAULT_MODELS,
    ActuatorEffectiveness,
    ActuatorFault,
    ActuatorOffset,
    BabblingNode,
    Bias,
    BusFault,
    BusOff,
    Drift,
    Dropout,
    Fault,
    FrameCorruption,
    FrameDelay,
    FrameFate,
    FrameLoss,
    Gain,
    GaussianNoise,
    Outliers,
    Replay,
    SensorFault,
    Spoofing,
    StuckAt,
    UniformNoise,
    per_channel_parameters,
)
from faults.waveforms import Constant, Exponential, Ramp, Sine, Square, Sum, Waveform

# Random streams are keyed by (group, label) so that each model draws from its own generator.
_NOISE, _FAULT, _ACTUATOR = 0, 1, 2


@dataclass(frozen=True)
class SensorOutcome:
    """What the fault layer did to one tick's sensor readings.

    ``measured`` is what the sensors read and ``sent`` which of their frames go on the bus;
    ``noise`` is the part added by measurement noise and ``fault`` the deviation the faults added
    on top of it (measured = true + noise + fault). ``active`` names the faults active.
    """

    measured: np.ndarray
    sent: np.ndarray
    noise: np.ndarray
    fault: np.ndarray
    active: tuple[str, ...]


class FaultInjector:
    """Applies measurement noise, then sensor faults in order, and actuator faults.

    Noise models are part of the healthy sensor; they do not count as faults (a fault's onset is
    what the metrics measure from).
    """

    def __init__(
        self,
        noise: list[SensorFault],
        sensor_faults: list[SensorFault],
        actuator_faults: list[ActuatorFault],
        seed: int,
    ) -> None:
        self.noise = list(noise)
        self.sensor_faults = list(sensor_faults)
        self.actuator_faults = list(actuator_faults)
        for group, models in ((_NOISE, self.noise), (_FAULT, self.sensor_faults), (_ACTUATOR, self.actuator_faults)):
            for index, model in enumerate(models):
                model.label = model.label or f"{model.kind}{index}"
            labels = [model.label for model in models]
            if len(set(labels)) != len(labels):
                raise ValueError(f"fault labels must be unique, got {labels}")
            for model in models:
                key = (group, zlib.crc32(model.label.encode()))
                model.reset(np.random.default_rng(np.random.SeedSequence(seed, spawn_key=key)))

    @property
    def faults(self) -> list[Fault]:
        return [*self.sensor_faults, *self.actuator_faults]

    @property
    def first_onset(self) -> float | None:
        """The earliest start time of any fault (noise excluded), or None without faults."""
        return min((f.start for f in self.faults), default=None)

    def sensors(self, y_true: np.ndarray, t: float) -> SensorOutcome:
        noisy = y_true
        for model in self.noise:
            noisy = model.apply(noisy, t)
        measured = noisy
        sent = np.ones(len(y_true), dtype=bool)
        for model in self.sensor_faults:
            measured = model.apply(measured, t)
            sent[model.drops(t)] = False
        active = tuple(f.label for f in self.faults if f.active(t))
        return SensorOutcome(measured, sent, noisy - y_true, measured - noisy, active)

    @staticmethod
    def sensors_batch(
        injectors: Sequence[FaultInjector], y_true: np.ndarray, t: float
    ) -> tuple[np.ndarray, np.ndarray, list[tuple[str, ...]]]:
        """``sensors`` for the K injectors of a batch (one configuration, each its own random
        streams), y_true of shape (K, p): the measured readings (K, p), which are sent (K, p) and
        each run's active faults, row for row what each injector's ``sensors`` gives."""
        first = injectors[0]
        noisy = y_true
        for i, model in enumerate(first.noise):
            noisy = type(model).apply_batch([injector.noise[i] for injector in injectors], noisy, t)
        measured = noisy
        sent = np.ones(y_true.shape, dtype=bool)
        for i, model in enumerate(first.sensor_faults):
            models = [injector.sensor_faults[i] for injector in injectors]
            measured = type(model).apply_batch(models, measured, t)
            if type(model).drops is not SensorFault.drops:
                for r, each in enumerate(models):
                    sent[r, each.drops(t)] = False
        if all(type(f).active is Fault.active for f in first.faults):  # the same window in every run
            active = [tuple(f.label for f in first.faults if f.active(t))] * len(injectors)
        else:
            active = [tuple(f.label for f in injector.faults if f.active(t)) for injector in injectors]
        return measured, sent, active

    def actuators(self, u: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        """The effective inputs δ ∘ u + f_a and the effectiveness factors δ (δ the product of every
        actuator fault's factors, f_a the sum of their offsets: the order of the faults does not matter)."""
        u_eff, delta = FaultInjector.actuators_batch([self], u[None, :], t)
        return u_eff[0], delta[0]

    @staticmethod
    def actuators_batch(injectors: Sequence[FaultInjector], u: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        """``actuators`` for the K injectors of a batch (each its own faults), u of shape (K, m):
        the effective inputs and the factors (K, m), elementwise as each run's alone."""
        m = u.shape[1]
        delta, offset = np.ones(u.shape), np.zeros(u.shape)
        for r, injector in enumerate(injectors):
            for model in injector.actuator_faults:
                delta[r] = delta[r] * model.factors(t, m)
                offset[r] = offset[r] + model.offsets(t, m)
        return delta * u + offset, delta


__all__ = [
    "FAULT_MODELS",
    "ActuatorEffectiveness",
    "ActuatorFault",
    "ActuatorOffset",
    "BabblingNode",
    "Bias",
    "BusFault",
    "BusOff",
    "Constant",
    "Drift",
    "Dropout",
    "Exponential",
    "FaultInjector",
    "FrameCorruption",
    "FrameDelay",
    "FrameFate",
    "FrameLoss",
    "Gain",
    "GaussianNoise",
    "Outliers",
    "Ramp",
    "Replay",
    "SensorFault",
    "SensorOutcome",
    "Sine",
    "Spoofing",
    "Square",
    "StuckAt",
    "Sum",
    "UniformNoise",
    "Waveform",
    "per_channel_parameters",
]
