"""Linear state-space models, the common currency between plants and estimators."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True, init=False)
class LinearModel:
    """x⁺ = A x + B u + E d, y = C x + D u about an operating point (discrete time, ``dt``
    seconds), or ẋ = A x + B u + E d, y = C x + D u when ``dt`` is None (continuous time).

    u are the known (commanded) inputs; d the unknown inputs (disturbances) that act on the
    plant but that no estimator measures: only their direction E is known, which unknown input
    observers decouple. The matrices act on deviations from the operating point
    (x_op, u_op, y_op): the plant's x ≈ x_op + δx, u = u_op + δu, y ≈ y_op + C δx + D δu.
    Shapes: A (n, n), B (n, m), C (p, n), D (p, m), E (n, len(disturbances)).

    x_op, u_op, y_op and E may be given as None (the constructor's defaults): zeros of the right
    shape. The attributes are always arrays.
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
        for name, op, size in (("x_op", x_op, n), ("u_op", u_op, m), ("y_op", y_op, p)):
            object.__setattr__(self, name, np.zeros(size) if op is None else np.asarray(op, dtype=float).reshape(size))

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
        )

    def to_dict(self) -> dict[str, Any]:
        """The model as plain JSON-able values (node specs, log metadata, the design cache)."""
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
        }

    @classmethod
    def from_dict(cls, m: dict[str, Any]) -> LinearModel:
        """The model ``to_dict`` wrote (E and the disturbances may be absent: none)."""
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
        )
