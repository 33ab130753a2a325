"""A plugin for cosim: an observer that detects and isolates a faulty sensor, and a fault model.

``ResidualObserver`` is a Luenberger observer x̂⁺ = A x̂ + B u + L (y − C x̂ − D u) whose residual
r = y − C x̂ − D u it publishes per sensor, with an alarm while |r| exceeds ``threshold`` and, for
each sensor, a flag while that sensor's residual is the largest under alarm (isolation). Its
diagnostics are declared once (``diagnostic_channels``): the runner gives them DBC signals, the
log decoded fields, and the metrics score the alarm (detection delay, false alarms) and the flags
(isolation) like the built-in schemes'.

``Quantized`` is a sensor fault: the reading comes in steps of ``step``.

Installed (``pip install examples/plugin``), both are kinds by name through the entry points in
``pyproject.toml``; uninstalled, a scenario names them by file (``my_observer.py:ResidualObserver``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cosim.api import Diagnostic, DiagnosticKind, Estimate, Estimator, ParameterError, SensorFault

RESIDUAL = Diagnostic("r_{}", "", "residual of {}", 10.0, 1e-5, DiagnosticKind.RESIDUAL)
ALARM = Diagnostic("alarm", "", "1 while |r| > threshold", 1.0, 1.0, DiagnosticKind.ALARM)
ISOLATED = Diagnostic("faulty_{}", "", "1 while {} is isolated as faulty", 1.0, 1.0, DiagnosticKind.ISOLATION)


@dataclass(frozen=True)
class Params:
    """The observer's parameters, as a scenario's ``params = {...}`` gives them (converted to
    these types; an unknown or ill-typed one is a one-line error naming it)."""

    poles: tuple[float, ...] = (0.8, 0.82, 0.84, 0.86)
    """Where spec(A − L C) is placed (one per state, inside the unit circle)."""
    threshold: float = 0.02
    """|r| above which the alarm is raised (in the sensors' units)."""


class ResidualObserver(Estimator):
    """A Luenberger observer with residual-based detection and isolation of a faulty sensor."""

    kind = "residual-observer"
    Params = Params

    def __init__(self, model, params, sample_time=None):
        super().__init__(model, params, sample_time)
        if len(params.poles) != model.n or not all(abs(p) < 1 for p in params.poles):
            raise ParameterError("poles", f"give {model.n} poles inside the unit circle")
        from scipy.signal import place_poles

        rows = []  # the first independent rows of C: place_poles wants a full-rank output matrix
        for i in range(model.p):
            if np.linalg.matrix_rank(model.C[rows + [i]]) > len(rows):
                rows.append(i)
        self.L = np.zeros((model.n, model.p))
        self.L[:, rows] = place_poles(model.A.T, model.C[rows].T, params.poles).gain_matrix.T
        self.x = np.zeros(model.n)

    @classmethod
    def diagnostic_channels(cls, states, outputs):
        return [*RESIDUAL.over(outputs), ALARM, *ISOLATED.over(outputs)]

    def _step(self, dy, du):
        m = self.model
        y = np.where(np.isnan(dy), m.C @ self.x + m.D @ du, dy)  # a missing reading: the prediction
        r = y - m.C @ self.x - m.D @ du
        estimate = self.x.copy()
        self.x = m.A @ self.x + m.B @ du + self.L @ r
        alarm = float(np.linalg.norm(r) > self.params.threshold)
        largest = int(np.argmax(np.abs(r)))
        flags = [alarm * (i == largest) for i in range(m.p)]
        diagnostics = {**RESIDUAL.values(m.outputs, r), ALARM.name: alarm, **ISOLATED.values(m.outputs, flags)}
        return Estimate(estimate, diagnostics)


@dataclass
class Quantized(SensorFault):
    """y ← step · round(y / step) on its sensors: a reading that comes in steps."""

    step: float = 0.1
    kind = "quantized"

    def _affect(self, y, elapsed):
        return self.step * np.round(y / self.step)
