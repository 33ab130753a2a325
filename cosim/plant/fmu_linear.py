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
    fmu = instantiate(model, plant._unzipped, "model-exchange")
    try:
        initialize(model, fmu, "model-exchange", plant._start, plant.tolerance, plant.duration)
        version, nx = model.version, len(model.continuous_states)
        states, inputs = Access(model.continuous_states, version), Access(model.actuators + model.disturbances, version)
        derivatives, named, sensors = Access(model.derivatives, version), Access(model.states, version), plant._sensors
        if x is not None:
            set_continuous_states(fmu, np.asarray(x, dtype=float))
        u0 = inputs.get(fmu)
        if u is not None:
            u0[: len(model.actuators)] = u
            inputs.set(fmu, u0)
        x0 = states.get(fmu)
        unknowns = [derivatives, named, sensors]

        def outputs() -> np.ndarray:
            return np.concatenate([a.get(fmu) for a in unknowns])

        y_op, s_op = sensors.get(fmu), named.get(fmu)
        knowns = model.continuous_states + model.actuators + model.disturbances
        if model.directional and all(_scalar_float(e) for e in (*knowns, *model.derivatives, *model.states)):
            jacobian = _directional_jacobian(fmu, version, unknowns, knowns)
        else:

            def at(dx: np.ndarray, du: np.ndarray) -> np.ndarray:
                set_continuous_states(fmu, x0 + dx)
                inputs.set(fmu, u0 + du)
                return outputs()

            steps = FD_STEP * np.where(np.concatenate([x0, u0]) != 0, np.abs(np.concatenate([x0, u0])), 1.0)
            discrete = [not _scalar_float(e) for e in knowns]
            jacobian = np.zeros((len(outputs()), len(knowns)))
            for j, h in enumerate(steps):
                if discrete[j]:
                    continue  # an integer or Boolean input has no derivative
                e = np.zeros(len(knowns))
                e[j] = h
                jacobian[:, j] = (at(e[:nx], e[nx:]) - at(-e[:nx], -e[nx:])) / (2.0 * h)
    finally:
        fmu.terminate()
        fmu.freeInstance()
    ns = len(model.states)
    F, S, Y = jacobian[:nx], jacobian[nx : nx + ns], jacobian[nx + ns :]
    F_x, F_u, S_x, Y_x, Y_u = F[:, :nx], F[:, nx:], S[:, :nx], Y[:, :nx], Y[:, nx:]
    if renamed:
        if ns != nx or np.linalg.matrix_rank(S_x) < nx or np.abs(S[:, nx:]).max(initial=0.0) > 1e-9:
            raise ModelError(
                f"{model.path.name}: the states named in [plant.fmu] states ({', '.join(plant.state_names)}) do not "
                f"determine its {nx} continuous states one to one (independent of the inputs)"
            )
        T_inv = np.linalg.inv(S_x)
        A, BE, C = S_x @ F_x @ T_inv, S_x @ F_u, Y_x @ T_inv
    else:
        A, BE, C = F_x, F_u, Y_x
    if dt is not None:
        A, BE = zoh_discretize(A, BE, dt)
    m = len(model.actuators)
    return LinearModel(
        A,
        BE[:, :m],
        C,
        Y_u[:, :m],
        dt,
        plant.state_names,
        plant.actuator_names,
        plant.sensor_names,
        x_op=s_op,
        u_op=u0[:m],
        y_op=y_op,
        E=BE[:, m:],
        disturbances=plant.disturbance_names,
    )


def _scalar_float(element: Element) -> bool:
    return not element.variable.shape and element.variable.type in FLOATS


def _directional_jacobian(fmu: Any, version: int, unknowns: list[Any], knowns: tuple[Element, ...]) -> np.ndarray:
    """∂(unknowns)/∂(knowns) column by column from the FMU's directional derivatives (scalars)."""
    vrs = [e.variable.valueReference for a in unknowns for e in a.elements]
    columns = []
    for known in knowns:
        if version == 2:
            column = fmu.getDirectionalDerivative(vrs, [known.variable.valueReference], [1.0])
        else:
            column = fmu.getDirectionalDerivative(vrs, [known.variable.valueReference], [1.0], len(vrs))
        columns.append(np.asarray(column, dtype=float))
    return np.array(columns).T if columns else np.zeros((len(vrs), 0))
