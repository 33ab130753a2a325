"""An FMU linearized about a point through its model-exchange interface.

At the point (x, u) of a fresh model-exchange instance initialized like the plant, the Jacobians

    F_x = ∂ẋ/∂x, F_u = ∂ẋ/∂[u d],  Y_x = ∂y/∂x, Y_u = ∂y/∂u,  S_x = ∂s/∂x

of the derivatives ẋ, the selected sensors y and the named states s with respect to the
continuous states x and the inputs (actuators u, disturbance inputs d) come from the FMU's
directional derivatives where it provides them for scalar variables, else from central
differences with relative steps 2⁻²⁰ (1 for a zero value). When the scenario names other
variables than the continuous states as the states (``[plant.fmu] states``), s = T x with
T = S_x square and invertible, and the model is taken in s:

    A = T F_x T⁻¹, [B E] = T F_u, C = Y_x T⁻¹, D = Y_u,

then discretized at the sample time by the exact zero-order hold (``zoh_discretize``).
"""

from __future__ import annotations

import ctypes
from typing import Any

import numpy as np

from cosim.errors import ModelError
from cosim.plant.fmu import FD_STEP, Access, FmuPlant, initialize, instantiate, set_continuous_states
from cosim.plant.fmu_model import FLOATS, Element
from estimators.design import zoh_discretize
from estimators.model import LinearModel


def linearize(plant: FmuPlant, x: np.ndarray | None, u: np.ndarray | None, dt: float | None) -> LinearModel:
    """The FMU's linear model at its start point (or at states ``x``, actuator inputs ``u``)."""
    model = plant.model
    if not model.has_model_exchange:
        raise ModelError(
            f"{model.path.name} has no model-exchange interface to linearize: give the estimators' design model "
            "as [plant.state_space]"
        )
    renamed = model.states != model.continuous_states
    if x is not None and renamed:
        raise ModelError(f"{model.path.name}: linearize at given states only where they are the continuous states")
    jacobian, v_op, s_op, y_op = _jacobian(plant, x, u)
    nx, ns = len(model.continuous_states), len(model.states)
    F, S, Y = jacobian[:nx], jacobian[nx : nx + ns], jacobian[nx + ns :]
    F_x, F_v, S_x, Y_x, Y_v = F[:, :nx], F[:, nx:], S[:, :nx], Y[:, :nx], Y[:, nx:]
    if renamed:
        if ns != nx or np.linalg.matrix_rank(S_x) < nx or np.abs(S[:, nx:]).max(initial=0.0) > 1e-9:
            raise ModelError(
                f"{model.path.name}: the states named in [plant.fmu] states ({', '.join(plant.state_names)}) do not "
                f"determine its {nx} continuous states one to one (independent of the inputs)"
            )
        T_inv = np.linalg.inv(S_x)
        A, BE, C = S_x @ F_x @ T_inv, S_x @ F_v, Y_x @ T_inv
    else:
        A, BE, C = F_x, F_v, Y_x
    if dt is not None:
        A, BE = zoh_discretize(A, BE, dt)
    m = len(model.actuators)
    return LinearModel(
        A,
        BE[:, :m],
        C,
        Y_v[:, :m],
        dt,
        plant.state_names,
        plant.actuator_names,
        plant.sensor_names,
        x_op=s_op,
        u_op=v_op[:m],
        y_op=y_op,
        E=BE[:, m:],
        disturbances=plant.disturbance_names,
    )


def _jacobian(
    plant: FmuPlant, x: np.ndarray | None, u: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """∂[ẋ; s; y]/∂[x; v] at the point, and there the inputs v, the named states s and the sensors y,
    from a fresh model-exchange instance."""
    model = plant.model
    fmu = instantiate(model, plant._unzipped, "model-exchange")
    try:
        initialize(model, fmu, "model-exchange", plant._start, plant.tolerance, plant.duration)
        version, nx = model.version, len(model.continuous_states)
        states, inputs = Access(model.continuous_states, version), Access(model.actuators + model.disturbances, version)
        derivatives, named, sensors = Access(model.derivatives, version), Access(model.states, version), plant._sensors
        if x is not None:
            set_continuous_states(fmu, np.asarray(x, dtype=float))
        v0 = inputs.get(fmu)
        if u is not None:
            v0[: len(model.actuators)] = u
            inputs.set(fmu, v0)
        x0, s_op, y_op = states.get(fmu), named.get(fmu), sensors.get(fmu)
        knowns = model.continuous_states + model.actuators + model.disturbances
        if model.directional and all(_scalar_float(e) for e in (*knowns, *model.derivatives, *model.states)):
            return _directional_jacobian(fmu, version, [derivatives, named, sensors], knowns), v0, s_op, y_op

        def at(dx: np.ndarray, dv: np.ndarray) -> np.ndarray:  # ẋ by the call that computes it
            set_continuous_states(fmu, x0 + dx)
            inputs.set(fmu, v0 + dv)
            return np.concatenate([state_derivatives(fmu, version, nx), named.get(fmu), sensors.get(fmu)])

        point = np.concatenate([x0, v0])
        steps = FD_STEP * np.where(point != 0, np.abs(point), 1.0)
        jacobian = np.zeros((nx + len(s_op) + len(y_op), len(knowns)))
        for j, (h, known) in enumerate(zip(steps, knowns)):
            if known.discrete:
                continue  # an integer or Boolean input has no derivative
            e = np.zeros(len(knowns))
            e[j] = h
            jacobian[:, j] = (at(e[:nx], e[nx:]) - at(-e[:nx], -e[nx:])) / (2.0 * h)
        return jacobian, v0, s_op, y_op
    finally:
        fmu.terminate()
        fmu.freeInstance()


def state_derivatives(fmu: Any, version: int, nx: int) -> np.ndarray:
    """ẋ of a model-exchange instance at its current states, inputs and time."""
    dx = np.zeros(nx)
    pointer = dx.ctypes.data_as(ctypes.POINTER(ctypes.c_double))
    (fmu.getDerivatives if version == 2 else fmu.getContinuousStateDerivatives)(pointer, nx)
    return dx


def _scalar_float(element: Element) -> bool:
    return not element.variable.shape and element.variable.type in FLOATS


def _directional_jacobian(fmu: Any, version: int, unknowns: list[Any], knowns: tuple[Element, ...]) -> np.ndarray:
    """∂(unknowns)/∂(knowns) column by column from the FMU's directional derivatives (scalars).
    An unknown that is itself a known (an output that is a continuous state) has the unit row:
    FMUs need not answer for it (the Reference FMUs answer 0)."""
    rows = [e for a in unknowns for e in a.elements]
    known_at = {id(k.variable): j for j, k in enumerate(knowns)}
    asked = [i for i, e in enumerate(rows) if id(e.variable) not in known_at]
    vrs = [rows[i].variable.valueReference for i in asked]
    jacobian = np.zeros((len(rows), len(knowns)))
    for i, e in enumerate(rows):
        if id(e.variable) in known_at:
            jacobian[i, known_at[id(e.variable)]] = 1.0
    for j, known in enumerate(knowns):
        if not vrs:
            break
        reference = [known.variable.valueReference]
        if version == 2:
            column = fmu.getDirectionalDerivative(vrs, reference, [1.0])
        else:
            column = fmu.getDirectionalDerivative(vrs, reference, [1.0], len(vrs))
        jacobian[asked, j] = column
    return jacobian
