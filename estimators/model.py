"""Linear state-space models, the common currency between plants and estimators."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True, init=False)
class LinearModel:
    """x⁺ = A x + B u + E d + c, y = C x + D u about an operating point (discrete time, ``dt``
    seconds), or ẋ = A x + B u + E d + c, y = C x + D u when ``dt`` is None (continuous time).

    u are the known (commanded) inputs; d the unknown inputs (disturbances) that act on the
    plant but that no estimator measures: only their direction E is known, which unknown input
    observers decouple. The matrices act on deviations from the operating point
    (x_op, u_op, y_op): the plant's x ≈ x_op + δx, u = u_op + δu, y ≈ y_op + C δx + D δu.
    Shapes: A (n, n), B (n, m), C (p, n), D (p, m), E (n, len(disturbances)).

    c is the ``drift``: zero where the operating point is an equilibrium of the inputs u_op (the
    usual linearization); else the model is affine, and its deviations from the operating point do
    not stay put but follow the model's free response (``OperatingPoint``), which ``Estimator.step``
    tracks for every estimator. In discrete time c = ∫₀^dt exp(A s) ds f₀ for the continuous-time
    drift f₀ = ẋ at the operating point (the exact zero-order hold).

    x_op, u_op, y_op, E and drift may be given as None (the constructor's defaults): zeros of the
    right shape. The attributes are always arrays.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    dt: float | None
    states: tuple[str, ...]
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    x_op: np.ndarray
    u_op: np.ndarray
    y_op: np.ndarray
    E: np.ndarray
    disturbances: tuple[str, ...]
    drift: np.ndarray

    def __init__(
        self,
        A: np.ndarray,
        B: np.ndarray,
        C: np.ndarray,
        D: np.ndarray,
        dt: float | None,
        states: tuple[str, ...],
        inputs: tuple[str, ...],
        outputs: tuple[str, ...],
        x_op: np.ndarray | None = None,
        u_op: np.ndarray | None = None,
        y_op: np.ndarray | None = None,
        E: np.ndarray | None = None,
        disturbances: tuple[str, ...] = (),
        drift: np.ndarray | None = None,
    ) -> None:
        # The attributes a dataclass __init__ would set (frozen: through object.__setattr__), then
        # the normalization that dataclass's __post_init__ did.
        for name, value in (
            ("A", A),
            ("B", B),
            ("C", C),
            ("D", D),
            ("dt", dt),
            ("states", states),
            ("inputs", inputs),
            ("outputs", outputs),
            ("disturbances", tuple(disturbances)),
        ):
            object.__setattr__(self, name, value)
        n, m, p = len(self.states), len(self.inputs), len(self.outputs)
        object.__setattr__(self, "E", np.zeros((n, len(self.disturbances))) if E is None else E)
        for name, shape in (
            ("A", (n, n)),
            ("B", (n, m)),
            ("C", (p, n)),
            ("D", (p, m)),
            ("E", (n, len(self.disturbances))),
        ):
            # C order whatever the source: BLAS takes another path for a Fortran-ordered matrix and
            # rounds differently, and a node or a replay that reads the model from JSON must compute
            # bit for bit what the runner's in-memory model computes.
            array = np.ascontiguousarray(getattr(self, name), dtype=float)
            if array.shape != shape:
                raise ValueError(f"LinearModel.{name} has shape {array.shape}, expected {shape}")
            object.__setattr__(self, name, array)
        for name, op, size in (("x_op", x_op, n), ("u_op", u_op, m), ("y_op", y_op, p), ("drift", drift, n)):
            vector = np.zeros(size) if op is None else np.asarray(op, dtype=float)
            if vector.size != size:
                raise ValueError(f"LinearModel.{name} has {vector.size} values, expected {size}")
            object.__setattr__(self, name, vector.reshape(size))

    @property
    def affine(self) -> bool:
        """Whether the model has a drift (its operating point is no equilibrium)."""
        return bool(np.any(self.drift))

    @property
    def n(self) -> int:
        return len(self.states)

    @property
    def m(self) -> int:
        return len(self.inputs)

    @property
    def p(self) -> int:
        return len(self.outputs)

    def select_outputs(self, names: list[str] | tuple[str, ...]) -> LinearModel:
        """The same model with only the named outputs, in the given order."""
        rows = [self.outputs.index(name) for name in names]
        return LinearModel(
            self.A,
            self.B,
            self.C[rows],
            self.D[rows],
            self.dt,
            self.states,
            self.inputs,
            tuple(names),
            self.x_op,
            self.u_op,
            self.y_op[rows],
            self.E,
            self.disturbances,
            self.drift,
        )

    def to_dict(self) -> dict[str, Any]:
        """The model as plain JSON-able values (node specs, log metadata, the design cache); the drift
        only where there is one (the model of an equilibrium reads as it always did)."""
        drift = {"drift": self.drift.tolist()} if self.affine else {}
        return {
            "A": self.A.tolist(),
            "B": self.B.tolist(),
            "C": self.C.tolist(),
            "D": self.D.tolist(),
            "dt": self.dt,
            "states": list(self.states),
            "inputs": list(self.inputs),
            "outputs": list(self.outputs),
            "x_op": self.x_op.tolist(),
            "u_op": self.u_op.tolist(),
            "y_op": self.y_op.tolist(),
            "E": self.E.tolist(),
            "disturbances": list(self.disturbances),
            **drift,
        }

    @classmethod
    def from_dict(cls, m: dict[str, Any]) -> LinearModel:
        """The model ``to_dict`` wrote (E, the disturbances and the drift may be absent: none)."""
        disturbances = tuple(m.get("disturbances", ()))
        E = np.array(m["E"]).reshape(len(m["states"]), len(disturbances)) if "E" in m else None
        return cls(
            np.array(m["A"]),
            np.array(m["B"]),
            np.array(m["C"]),
            np.array(m["D"]),
            m["dt"],
            tuple(m["states"]),
            tuple(m["inputs"]),
            tuple(m["outputs"]),
            np.array(m["x_op"]),
            np.array(m["u_op"]),
            np.array(m["y_op"]),
            E,
            disturbances,
            np.array(m["drift"]) if "drift" in m else None,
        )


class OperatingPoint:
    """Where the operating point of an estimator's model lies at the current tick.

    For a model without drift it stays at (x_op, y_op), the very arrays of the model. For an affine
    model it moves along the model's own free response from x_op with the inputs held at u_op,
    x°_{k+1} − x_op = A_d (x°_k − x_op) + c_d, y°_k = y_op + C (x°_k − x_op): the plant's deviation
    from it, x_k − x°_k, then follows the linear part alone, δx⁺ = A_d δx + B_d δu + E_d d, so
    that an estimator written in deviation coordinates is right as it stands. A continuous-time
    model's point moves by its exact zero-order hold over ``sample_time``.
    """

    def __init__(self, model: LinearModel, sample_time: float | None) -> None:
        self.model = model
        self.x, self.y = model.x_op, model.y_op
        self._moved = np.zeros(model.n)
        self._free: tuple[np.ndarray, np.ndarray] | None = None
        if model.affine:
            if model.dt is not None:
                self._free = model.A, model.drift
            else:
                if sample_time is None:
                    raise ValueError(
                        "an affine continuous-time model needs the sample time to move its operating point"
                    )
                from estimators.design import zoh_discretize

                A_d, c_d = zoh_discretize(model.A, model.drift[:, None], sample_time)
                self._free = A_d, c_d[:, 0]

    def advance(self) -> None:
        """On to the next tick."""
        if self._free is None:
            return
        A_d, c_d = self._free
        self._moved = A_d @ self._moved + c_d
        self.x = self.model.x_op + self._moved
        self.y = self.model.y_op + self.model.C @ self._moved
