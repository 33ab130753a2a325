"""The estimator interface: one sample in, one estimate out, no I/O.

Estimators run the same in a bus node, in replay, in tests and in batch campaigns. They are built
from a LinearModel and parameters, and fed one tick at a time.
"""

from __future__ import annotations

import math
import types
import typing
from abc import ABC, abstractmethod
from collections.abc import Hashable, Sequence
from dataclasses import dataclass, field, fields
from typing import Any, ClassVar

import numpy as np

from estimators.diagnostics import Diagnostic, DiagnosticKind
from estimators.model import LinearModel, OperatingPoint


@dataclass(frozen=True)
class Estimate:
    """The estimate x̂_k of the plant state at the tick just received, with named scalar
    diagnostics (named as the estimator's ``diagnostic_channels`` declare)."""

    x: np.ndarray
    diagnostics: dict[str, float] = field(default_factory=dict)


class ParameterError(ValueError):
    """An estimator parameter is unknown, missing or has an impossible value."""

    def __init__(self, parameter: str, message: str) -> None:
        super().__init__(f"{parameter}: {message}")
        self.parameter = parameter


class Configurable(ABC):
    """Something built from a plain parameter dict (parsed TOML): a ``kind`` and a ``Params``
    dataclass whose fields are the parameters, each converted to its declared type."""

    kind: ClassVar[str]
    Params: ClassVar[type]

    @abstractmethod
    def __init__(self, model: LinearModel, params: Any, sample_time: float | None = None) -> None:
        """The constructor every kind has, which ``from_params`` calls: the model, the checked
        ``Params`` and the sample time."""

    @classmethod
    def check_params(cls, params: dict[str, Any] | None = None) -> Any:
        """The ``Params`` dataclass built from plain values (e.g. parsed TOML), each converted to its
        declared type; a ParameterError names the first unknown or ill-typed parameter."""
        params = dict(params or {})
        hints = typing.get_type_hints(cls.Params)
        known = [f.name for f in fields(cls.Params)]
        for name in params:
            if name not in known:
                raise ParameterError(name, f"unknown parameter of {cls.kind} (known: {', '.join(sorted(known))})")
        return cls.Params(**{name: coerce(value, hints[name], name) for name, value in params.items()})

    @classmethod
    def from_params(
        cls, model: LinearModel, params: dict[str, Any] | None = None, sample_time: float | None = None
    ) -> Any:
        """Build from a plain dict of parameters, with a ParameterError naming any bad one."""
        return cls(model, cls.check_params(params), sample_time)


class Estimator(Configurable, ABC):
    """Base class of state estimators for a LinearModel in discrete time.

    ``step(y, u)`` receives the measurements y_k (shape (p,), NaN where a sensor's frame did not
    arrive) and the commanded inputs u_k (shape (m,)) of tick k, and returns the estimate of x_k.
    Subclasses implement ``_step`` in deviation coordinates about the model's operating point
    (``operating_point``: fixed, or moving along the free response of a model with drift, which
    keeps the deviations linear: ``estimators.model.OperatingPoint``). Each subclass declares its
    parameters as a dataclass ``Params``.
    """

    continuous: ClassVar[bool] = False
    """True for estimators designed on the continuous-time model (dt None) that integrate their own
    ODE between samples; they are given the sample time separately."""

    estimates: ClassVar[bool] = True
    """False for a scheme that only diagnoses (a detector): its node publishes its diagnostics and no
    state estimate (``_step`` still returns an ``Estimate``, whose ``x`` is not sent), so it has no
    estimation error and ranks among the diagnosis schemes."""

    design_free: ClassVar[frozenset[str]] = frozenset()
    """Parameters that do not change what ``design_params()`` returns: estimators that differ only
    in them share one cached design."""

    design_extras: ClassVar[tuple[str, ...]] = ()
    """The optional extras of cosim its design needs (``lmi``: the LMI solvers), unless the
    parameters give what the design would compute (``needs_extras``)."""

    @classmethod
    def needs_extras(cls, params: dict[str, Any]) -> tuple[str, ...]:
        """The extras designing it with ``params`` needs."""
        return cls.design_extras

    def __init__(self, model: LinearModel, params: Any, sample_time: float | None = None) -> None:
        if self.continuous:
            if model.dt is not None:
                raise ParameterError(
                    "model", f"{self.kind} needs a continuous-time model (got a discrete one, dt = {model.dt})"
                )
            if sample_time is None or not sample_time > 0:
                raise ParameterError("sample_time", f"{self.kind} integrates between samples and needs the sample time")
            self.sample_time: float = float(sample_time)
        elif model.dt is None:
            raise ParameterError("model", f"{self.kind} needs a discrete-time model (got a continuous one)")
        else:
            self.sample_time = float(sample_time) if sample_time is not None else model.dt
        self.model = model
        self.params = params
        self.operating_point = OperatingPoint(model, self.sample_time)
        """The operating point at the current tick (x_op, y_op where the model has no drift)."""

    @classmethod
    def diagnostic_channels(cls, states: tuple[str, ...], outputs: tuple[str, ...]) -> list[Diagnostic]:
        """The diagnostics ``step`` returns each tick, for a model with these states and outputs."""
        return []

    def step(self, y: np.ndarray, u: np.ndarray) -> Estimate:
        y = np.asarray(y, dtype=float)
        u = np.asarray(u, dtype=float)
        if y.shape != (self.model.p,) or u.shape != (self.model.m,):
            raise ValueError(
                f"expected y of shape ({self.model.p},) and u of shape ({self.model.m},), got {y.shape} and {u.shape}"
            )
        point = self.operating_point
        estimate = self._step(y - point.y, u - self.model.u_op)
        if not isinstance(estimate, Estimate):
            raise TypeError(f"{self.kind}: _step returned {type(estimate).__name__}, not an Estimate(x, diagnostics)")
        if np.shape(estimate.x) != (self.model.n,):
            raise ValueError(
                f"{self.kind}: _step returned an estimate of shape {np.shape(estimate.x)}, not ({self.model.n},): "
                f"one value per state ({', '.join(self.model.states)})"
            )
        x = estimate.x + point.x
        point.advance()
        return Estimate(x, estimate.diagnostics)

    @classmethod
    def batched(cls, instances: Sequence[Any]) -> Any:
        """Optional: these K instances of the kind (one design, each with its own state, as a batch
        of runs has them) as one object whose ``step(y, u)`` takes y (K, p) and u (K, m) and returns
        an ``estimators.batched.BatchEstimate``, run for run bit for bit what each instance's
        ``step`` returns (``estimators.batched.check_batched`` tests that). None, the default: the
        batch steps each instance by itself (``StepEach``), which is always right."""
        return None

    def joint_batch_key(self) -> Hashable | None:
        """Optional: what instances of this kind must share for ``batched`` to step them together
        though their designs differ (the estimators of one scenario that differ in a gain or a
        learning rate: a batch of K runs then steps them as one batch of E × K instances, each on its
        own design). Equal keys (not None) of the same kind join; None, the default: ``batched``
        takes instances of one design only, and each estimator of a batch is stepped by itself."""
        return None

    def design_params(self) -> dict[str, Any]:
        """Parameters that, added to the given ones, rebuild this estimator without redoing its
        design (e.g. an LMI solution): the runner designs once and ships them to the node process."""
        return {}

    def node_params(self) -> dict[str, Any]:
        """Parameters a node process is built with, added to the given ones: ``design_params()``,
        and what spares the node a design it would redo to the same numbers (a pole placement, whose
        import of ``scipy.signal`` alone costs a node a second of start-up). Unlike the design's,
        these are not recorded in the log: they say nothing the given parameters do not."""
        return self.design_params()

    def isolation_targets(self) -> dict[str, list[str]]:
        """What each isolation diagnostic names as faulty, as sensor or actuator names (the fault
        targets of a scenario): by default its target, where that is an output or an input."""
        known = {*self.model.outputs, *self.model.inputs}
        return {
            d.name: [d.target]
            for d in self.diagnostic_channels(self.model.states, self.model.outputs)
            if d.kind == DiagnosticKind.ISOLATION and d.target in known
        }

    def bias_effect(self, diagnostics: dict[str, float], phi: np.ndarray) -> np.ndarray | None:
        """What an output bias φ leaves in the observer's injection at a tick with these diagnostics
        (h_Γ = Z_Γ φ in CDC 2016, R(s)⁻¹Γ(φ)s in TAC 2024); None where the notion does not apply."""
        return None

    @abstractmethod
    def _step(self, dy: np.ndarray, du: np.ndarray) -> Estimate:
        """One tick in deviation coordinates; returns the deviation estimate δx̂_k."""


def initial_state(model: LinearModel, x0: tuple[float, ...] | None) -> np.ndarray:
    """The initial deviation estimate: the given absolute x̂_0 minus the operating point, or 0."""
    if x0 is None:
        return np.zeros(model.n)
    x = np.asarray(x0, dtype=float)
    if x.shape != (model.n,):
        raise ParameterError("x0", f"expected {model.n} values ({', '.join(model.states)}), got {x.size}")
    return x - model.x_op


def coerce(value: Any, hint: Any, name: str) -> Any:
    """Convert a plain value to a parameter type: float, int, bool, str, tuple[float, ...], and
    unions of these with each other or None. Numbers must be finite."""
    options = typing.get_args(hint) if typing.get_origin(hint) in (typing.Union, types.UnionType) else (hint,)
    if value is None and type(None) in options:
        return None
    sequence = isinstance(value, (list, tuple))
    numeric = isinstance(value, (int, float)) and not isinstance(value, bool)
    for option in options:
        if option is float and numeric:
            return _number(value, name)
        if option is int and numeric and isinstance(value, int):
            return value
        if (
            typing.get_origin(option) is tuple
            and sequence
            and value
            and all(isinstance(row, (list, tuple)) for row in value)
        ):
            inner = typing.get_args(option)[0]
            if typing.get_origin(inner) is tuple:  # a matrix: tuple[tuple[float, ...], ...]
                return tuple(
                    tuple(_number(item, f"{name}[{i}][{j}]") for j, item in enumerate(row))
                    for i, row in enumerate(value)
                )
        if option is bool and isinstance(value, bool):
            return value
        if option is str and isinstance(value, str):
            return value
        if typing.get_origin(option) is tuple and sequence and typing.get_args(option)[0] is str:
            if all(isinstance(item, str) for item in value):
                return tuple(value)
            continue
        if typing.get_origin(option) is tuple and sequence:
            return tuple(_number(item, f"{name}[{i}]") for i, item in enumerate(value))
    expected = " or ".join(_describe(option) for option in options if option is not type(None))
    raise ParameterError(name, f"expected {expected}, got {value!r}")


def _number(value: Any, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParameterError(name, f"expected a number, got {value!r}")
    if not math.isfinite(value):
        raise ParameterError(name, f"expected a finite number, got {value!r}")
    return float(value)


def _describe(option: Any) -> str:
    if typing.get_origin(option) is tuple:
        inner = typing.get_args(option)[0]
        if inner is str:
            return "a list of names"
        return "a matrix (a list of rows of numbers)" if typing.get_origin(inner) is tuple else "a list of numbers"
    return {float: "a number", int: "an integer", bool: "true or false", str: "a string"}.get(option, str(option))
