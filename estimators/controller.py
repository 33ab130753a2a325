"""The controller interface: a feedback law that closes the loop over the bus, no I/O.

A controller runs as the run's ``controller`` node: each tick it receives the sensor readings y_k
and, if it listens to a diagnosis node, that node's latest report (its diagnostics of tick k − 1:
a fault cannot be reported before the commands it is diagnosed from went out), and returns the
commanded inputs u_k, which the plant holds for one sample time. Like estimators, controllers are
built from the plant's linear model and a ``Params`` dataclass, and run the same in a node process,
in tests and in replay.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from cosim.kinds import KindError, Kinds
from estimators.base import Configurable, ParameterError
from estimators.diagnostics import Diagnostic, DiagnosticKind
from estimators.model import LinearModel


@dataclass(frozen=True)
class Command:
    """The commanded inputs u_k (absolute, shape (m,)) with named scalar diagnostics."""

    u: np.ndarray
    diagnostics: dict[str, float] = field(default_factory=dict)


class Controller(Configurable, ABC):
    """Base class of controllers for a plant with a LinearModel.

    ``reports`` names the diagnostics of the diagnosis node that ``step`` reads (for example a
    fault mask); the runner delivers them from the node named in the scenario's
    ``controller.diagnosis``. ``continuous`` kinds are given the continuous-time model.
    """

    continuous: ClassVar[bool] = False
    reports: ClassVar[tuple[str, ...]] = ()

    def __init__(self, model: LinearModel, params: Any, sample_time: float | None = None) -> None:
        if sample_time is None or not sample_time > 0:
            raise ParameterError("sample_time", f"{self.kind} needs the sample time")
        if self.continuous != (model.dt is None):
            wanted = "continuous-time" if self.continuous else "discrete-time"
            raise ParameterError("model", f"{self.kind} needs the plant's {wanted} model")
        self.model = model
        self.params = params
        self.sample_time = float(sample_time)

    @classmethod
    def diagnostic_channels(cls, model_inputs: tuple[str, ...], outputs: tuple[str, ...]) -> list[Diagnostic]:
        """The diagnostics ``step`` returns each tick, for a plant with these inputs and outputs."""
        return []

    @abstractmethod
    def step(self, y: np.ndarray, t: float, report: Mapping[str, float]) -> Command:
        """u_k from y_k (shape (p,), absolute, NaN where a reading did not arrive), t_k and the
        diagnosis node's latest report (empty before its first one)."""

    @classmethod
    def batched(cls, instances: Sequence[Any]) -> Any:
        """Optional: these K instances (one design, each its own state) as one object whose
        ``step(y, t, reports)`` takes y (K, p), t_k and each run's report, and returns u (K, m) and
        each diagnostic as (K,), run for run bit for bit each instance's ``step``. None, the
        default: a batch steps each instance by itself."""
        return None


def _indices(names: tuple[str, ...], known: tuple[str, ...], parameter: str, what: str) -> list[int]:
    missing = [name for name in names if name not in known]
    if missing:
        raise ParameterError(
            parameter, f"{', '.join(missing)} is not a {what} of the plant (it has: {', '.join(known)})"
        )
    return [known.index(name) for name in names]


def _per_loop(value: tuple[float, ...], loops: int, parameter: str) -> np.ndarray:
    if len(value) not in (1, loops):
        raise ParameterError(parameter, f"give one value per loop ({loops}) or one for all, got {len(value)}")
    return np.broadcast_to(np.asarray(value, dtype=float), (loops,)).copy()


CONTROL_ERROR = Diagnostic("e_{}", "", "control error r - y of the loop on {}", 1e6, 1e-6, DiagnosticKind.CONTROL_ERROR)
"""The PID's diagnostics: the control error of each output (0 for an output without a loop)."""


class PidController(Controller):
    """Decentralized discrete PID loops, loop i driving input ``inputs[i]`` from output ``outputs[i]``:

        r_k = r + a sin(2π f t_k),   e_k = r_k − y_k,   I_k = I_{k−1} + τ e_k,
        u_k = u_op + k_p e_k + k_i I_k − k_d (y_k − y_{k−1}) / τ,

    derivative on the measurement (no kick when the set point r steps), saturation to
    [``lower``, ``upper``] with conditional integration as anti-windup (the integral is not
    advanced while the loop is saturated in the direction the error pushes). The set point r may
    swing around its value with amplitude a (``amplitude``) at f hertz (``frequency``). A missing
    reading holds the loop's last command. The inputs of the plant with no loop stay at u_op.
    """

    kind = "pid"

    @dataclass(frozen=True)
    class Params:
        outputs: tuple[str, ...] = ()
        inputs: tuple[str, ...] = ()
        setpoint: tuple[float, ...] = (0.0,)
        kp: tuple[float, ...] = (0.0,)
        ki: tuple[float, ...] = (0.0,)
        kd: tuple[float, ...] = (0.0,)
        lower: tuple[float, ...] = (-np.inf,)
        upper: tuple[float, ...] = (np.inf,)
        amplitude: tuple[float, ...] = (0.0,)
        frequency: tuple[float, ...] = (0.0,)

    def __init__(self, model: LinearModel, params: Params, sample_time: float | None = None) -> None:
        super().__init__(model, params, sample_time)
        if not params.outputs or len(params.outputs) != len(params.inputs):
            raise ParameterError(
                "outputs",
                "give the same number (at least one) of outputs and inputs: loop i drives inputs[i] from outputs[i]",
            )
        loops = len(params.outputs)
        self._y = _indices(params.outputs, model.outputs, "outputs", "sensor")
        self._u = _indices(params.inputs, model.inputs, "inputs", "input")
        self.setpoint, self.kp, self.ki, self.kd, self.lower, self.upper = (
            _per_loop(getattr(params, name), loops, name) for name in ("setpoint", "kp", "ki", "kd", "lower", "upper")
        )
        self.amplitude, self.frequency = (_per_loop(getattr(params, n), loops, n) for n in ("amplitude", "frequency"))
        if np.any(self.lower >= self.upper):
            raise ParameterError("lower", "every lower limit must be below its upper limit")
        self.integral = np.zeros(loops)
        self.previous: np.ndarray | None = None
        self.u = model.u_op.copy()

    @classmethod
    def diagnostic_channels(cls, model_inputs: tuple[str, ...], outputs: tuple[str, ...]) -> list[Diagnostic]:
        return CONTROL_ERROR.over(outputs)

    def reference(self, t: float) -> np.ndarray:
        """The set points r_k at t (the constant ones, as they are, when nothing swings)."""
        if not self.amplitude.any():
            return self.setpoint
        return self.setpoint + self.amplitude * np.sin(2 * np.pi * self.frequency * t)

    def step(self, y: np.ndarray, t: float, report: Mapping[str, float]) -> Command:
        y = np.asarray(y, dtype=float)[self._y]
        self.integral, self.previous, self.u[self._u], error = self.law(
            y, t, self.integral, self.previous, self.u[self._u]
        )
        diagnostics = CONTROL_ERROR.values(self.model.outputs, np.zeros(self.model.p))
        diagnostics |= CONTROL_ERROR.values(self.params.outputs, np.where(np.isfinite(error), error, 0.0))
        return Command(self.u.copy(), diagnostics)

    def law(
        self, y: np.ndarray, t: float, integral: np.ndarray, previous: np.ndarray | None, held: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """One step of the loops on their readings y (loops,), or of K runs' loops (K, loops), each
        element by the same operations: the integral, the last readings, the loops' commands (a
        missing reading holds ``held``) and the control errors after it."""
        error = self.reference(t) - y
        ok = np.isfinite(y)
        previous = y if previous is None else np.where(np.isfinite(previous), previous, y)
        derivative = np.where(ok, (y - previous) / self.sample_time, 0.0)
        u_op = self.model.u_op[self._u]
        advanced = integral + np.where(ok, self.sample_time * error, 0.0)
        unclipped = u_op + self.kp * error + self.ki * advanced - self.kd * derivative
        winding_up = ((unclipped > self.upper) & (error > 0)) | ((unclipped < self.lower) & (error < 0))
        integral = np.where(ok & ~winding_up, advanced, integral)
        command = np.clip(u_op + self.kp * error + self.ki * integral - self.kd * derivative, self.lower, self.upper)
        return integral, np.where(ok, y, previous), np.where(ok, command, held), error

    @classmethod
    def batched(cls, instances: Sequence[Any]) -> _PidRuns:
        return _PidRuns(instances)


class _PidRuns:
    """K ``PidController`` instances of one design (``Controller.batched``): their states as (K, ·)
    arrays, stepped by the same ``law`` at once (a reading never had is NaN: ``law`` takes the
    reading itself then, as it does for a first step)."""

    def __init__(self, instances: Sequence[PidController]) -> None:
        self.pid = instances[0]
        self.integral = np.stack([pid.integral for pid in instances])
        self.previous = np.stack(
            [pid.previous if pid.previous is not None else np.full(len(pid.integral), np.nan) for pid in instances]
        )
        self.u = np.stack([pid.u for pid in instances])
        model, outputs = self.pid.model, self.pid.params.outputs
        self.names = [CONTROL_ERROR.named(name) for name in model.outputs]
        self.loops = [CONTROL_ERROR.named(name) for name in outputs]

    def step(self, y: np.ndarray, t: float, reports: Sequence[Mapping[str, float]]) -> tuple[np.ndarray, dict]:
        pid = self.pid
        y = np.asarray(y, dtype=float)[:, pid._y]
        self.integral, self.previous, self.u[:, pid._u], error = pid.law(
            y, t, self.integral, self.previous, self.u[:, pid._u]
        )
        errors = np.where(np.isfinite(error), error, 0.0)
        diagnostics = {name: np.zeros(len(y)) for name in self.names}
        diagnostics |= {name: errors[:, i] for i, name in enumerate(self.loops)}
        return self.u.copy(), diagnostics


#: Controller kinds; each built-in kind's module is imported when the kind is first looked up.
CONTROLLERS: Kinds[type[Controller]] = Kinds(
    "controller",
    "cosim.controllers",
    {PidController.kind: PidController, "thrust-allocation": "estimators.allocation:ThrustAllocationController"},
    Controller,
)


def create(
    kind: str, model: LinearModel, params: dict[str, Any] | None = None, sample_time: float | None = None
) -> Controller:
    """The controller of the given kind; unknown kinds and bad parameters raise ParameterError."""
    try:
        cls = CONTROLLERS[kind]
    except KindError as error:
        raise ParameterError("kind", str(error)) from None
    return cls.from_params(model, params, sample_time)
