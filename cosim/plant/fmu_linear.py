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

The point is the start point (the FMU's start values, as the run sets them) where that is an
equilibrium of the held inputs. Where it is not (a spring stretched, a mass moving), the model is
taken at the equilibrium that ``cosim.plant.equilibrium.search`` reaches from it, in a
model-exchange instance of its own; where it reaches none, the model stays at the start point as
an affine model with its drift ẋ₀ (``LinearModel.drift``). ``plant.operating_point`` says which.
"""

from __future__ import annotations

import ctypes
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from cosim.errors import ModelError
from cosim.plant import equilibrium
from cosim.plant.fmu_calls import CallWatch, FmuCallError
from cosim.plant.fmu_instance import Access, initialize, instantiate, release, set_continuous_states
from cosim.plant.fmu_model import Element, FmuModel
from estimators.design import zoh_discretize
from estimators.model import LinearModel

#: Relative finite-difference step of the linearization (a power of two: exact perturbations).
FD_STEP = 2.0**-20


class FmuPlantParts(Protocol):
    """What the linearization reads of an FMU plant (``cosim.plant.fmu.FmuPlant``), and what it
    sets: ``warnings``, ``operating_point``, ``equilibria`` (the private parts too, for the
    linearization is the plant's own: ``FmuPlant.linearize``)."""

    model: FmuModel
    watch: CallWatch
    tolerance: float | None
    duration: float
    state_names: tuple[str, ...]
    actuator_names: tuple[str, ...]
    sensor_names: tuple[str, ...]
    disturbance_names: tuple[str, ...]
    warnings: list[str]
    operating_point: str
    equilibria: dict[tuple[str, bytes, bytes], np.ndarray | str]
    _sensors: Access
    _start: dict[str, Any]
    _unzipped: str


def linearize(plant: FmuPlantParts, x: np.ndarray | None, u: np.ndarray | None, dt: float | None) -> LinearModel:
    """The FMU's linear model at its start point (or at states ``x``, actuator inputs ``u``).

    Where the start point is no equilibrium of its inputs, the model is taken at the equilibrium
    reached from it (``cosim.plant.equilibrium.search``), else kept there as an affine model with
    its drift; at a given point, always the latter. ``plant.operating_point`` says which."""
    model = plant.model
    if not model.has_model_exchange:
        raise ModelError(
            f"{model.path.name} has no model-exchange interface to linearize (it is co-simulation only): give the "
            "design model as [plant.state_space], or use a build of the FMU with model exchange"
        )
    if x is not None and model.states != model.continuous_states:
        raise ModelError(f"{model.path.name}: linearize at given states only where they are the continuous states")
    point = _jacobian(plant, x, u)
    plant.operating_point = ""
    if point.at_rest(plant):
        return _model(plant, point, dt)
    found = _equilibrium(plant, point, u) if x is None else None
    if isinstance(found, _Linearization) and found.at_rest(plant):
        plant.operating_point = (
            f"{model.path.name}: its start values ({equilibrium.values(plant.state_names, point.s)}) are no "
            f"equilibrium (the derivatives there: {_derivatives(model, point)}): "
            f"linearized at the equilibrium {equilibrium.values(plant.state_names, found.s)} reached from them"
            + equilibrium.stability(found.state_matrix(plant))
        )
        return _model(plant, found, dt)
    at = equilibrium.values(plant.state_names, point.s)
    drift = equilibrium.values(equilibrium.rates_of(plant.state_names), point.drift(plant))
    if x is not None:
        plant.operating_point = (
            f"{model.path.name}: the point given ({at}) is no equilibrium: affine model with drift {drift} about it"
        )
    else:
        searched = (
            f"; the search from them ended at {_derivatives(model, found)}"
            if isinstance(found, _Linearization)
            else f"; {found}"
        )
        plant.operating_point = (
            f"{model.path.name}: no equilibrium near its start values ({at}){searched}: affine model with drift "
            f"{drift} about them"
        )
    return _model(plant, point, dt, affine=True)


def _derivatives(model: Any, point: _Linearization) -> str:
    return equilibrium.values(point.derivative_names(model), point.f)


@dataclass(frozen=True)
class _Linearization:
    """The FMU at a point: its continuous states x, inputs v, named states s, sensors y, the
    derivatives f = ẋ, and the Jacobian ∂[ẋ; s; y]/∂[x; v] there."""

    jacobian: np.ndarray
    x: np.ndarray
    v: np.ndarray
    s: np.ndarray
    y: np.ndarray
    f: np.ndarray

    def blocks(self) -> tuple[np.ndarray, np.ndarray]:
        """∂ẋ/∂x and ∂ẋ/∂v."""
        nx = len(self.x)
        return self.jacobian[:nx, :nx], self.jacobian[:nx, nx:]

    def at_rest(self, plant: FmuPlantParts) -> bool:
        F_x, F_v = self.blocks()
        return equilibrium.at_rest(self.f, F_x, F_v, self.x, self.v, nominals(plant.model))

    def transform(self, plant: FmuPlantParts) -> np.ndarray | None:
        """T = ∂s/∂x where the named states are not the continuous states (None where they are)."""
        model = plant.model
        if model.states == model.continuous_states:
            return None
        nx = len(self.x)
        return self.jacobian[nx : nx + len(model.states), :nx]

    def state_matrix(self, plant: FmuPlantParts) -> np.ndarray:
        """The continuous-time A in the model's states."""
        F_x = self.blocks()[0]
        T = self.transform(plant)
        return F_x if T is None else T @ F_x @ np.linalg.inv(T)

    def drift(self, plant: FmuPlantParts) -> np.ndarray:
        """The derivative in the model's states: ẋ, or ṡ = T ẋ."""
        T = self.transform(plant)
        return self.f if T is None else T @ self.f

    @staticmethod
    def derivative_names(model: Any) -> list[str]:
        return equilibrium.rates_of([e.name for e in model.continuous_states])


def nominals(model: Any) -> np.ndarray:
    """The continuous states' nominal values (1 where the FMU declares none)."""
    return np.array(
        [float(e.variable.nominal) if e.variable.nominal is not None else 1.0 for e in model.continuous_states]
    )


def _model(plant: FmuPlantParts, point: _Linearization, dt: float | None, affine: bool = False) -> LinearModel:
    """The linear model of the FMU at ``point``; ``affine``: with its drift."""
    model = plant.model
    nx, ns = len(model.continuous_states), len(model.states)
    jacobian = point.jacobian
    F, S, Y = jacobian[:nx], jacobian[nx : nx + ns], jacobian[nx + ns :]
    F_x, F_v, S_x, Y_x, Y_v = F[:, :nx], F[:, nx:], S[:, :nx], Y[:, :nx], Y[:, nx:]
    if model.states != model.continuous_states:
        if ns != nx or np.linalg.matrix_rank(S_x) < nx or np.abs(S[:, nx:]).max(initial=0.0) > 1e-9:
            raise ModelError(
                f"{model.path.name}: the states named in [plant.fmu] states ({', '.join(plant.state_names)}) do not "
                f"determine its {nx} continuous states one to one (independent of the inputs)"
            )
        T_inv = np.linalg.inv(S_x)
        A, BE, C = S_x @ F_x @ T_inv, S_x @ F_v, Y_x @ T_inv
    else:
        A, BE, C = F_x, F_v, Y_x
    drift = equilibrium.drift_model(A, point.drift(plant), dt) if affine else None
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
        x_op=point.s,
        u_op=point.v[:m],
        y_op=point.y,
        E=BE[:, m:],
        disturbances=plant.disturbance_names,
        drift=drift,
    )


def _jacobian(plant: FmuPlantParts, x: np.ndarray | None, u: np.ndarray | None) -> _Linearization:
    """The FMU at the point, from a fresh model-exchange instance: its start point, or the
    continuous states ``x``, actuator inputs ``u``. Where the FMU provides directional derivatives
    they are the Jacobian, checked against central differences (``plant.warnings`` says where they
    disagree)."""
    model = plant.model
    fmu = instantiate(model, plant._unzipped, "model-exchange", plant.watch)
    try:
        initialize(model, fmu, "model-exchange", plant._start, plant.tolerance, plant.duration)
        version = model.version
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
        directional = None  # at the point itself, before the differences move the instance's states
        if _directional(model, sensors):
            directional = _directional_jacobian(fmu, version, [derivatives, named, sensors], knowns)
        point = _Point(fmu, model, x0, v0, inputs, named, sensors)
        jacobian = point.differences(knowns)
        if directional is not None:
            found = disagreements(model.path.name, plant, directional, jacobian)
            plant.warnings += [w for w in found if w not in plant.warnings]
            jacobian = directional
        at = point.at(np.zeros(len(x0)), np.zeros(len(v0)))  # as a solver's step ends there
        nx, ns = len(x0), len(named.elements)
        if x is not None:  # the outputs of a point set by hand, as a step ends there
            s_op, y_op = at[nx : nx + ns], at[nx + ns :]
        return _Linearization(jacobian, x0, v0, s_op, y_op, at[:nx])
    finally:
        release(fmu, plant.watch)


def _directional(model: Any, sensors: Access) -> bool:
    """Whether the Jacobian comes from the FMU's directional derivatives (scalar variables only)."""
    knowns = model.continuous_states + model.actuators + model.disturbances
    continuous = [e for e in (*knowns, *model.derivatives, *model.states, *sensors.elements) if not e.discrete]
    return bool(model.directional) and not any(e.variable.shape for e in continuous)


def _equilibrium(plant: FmuPlantParts, start: _Linearization, u: np.ndarray | None) -> _Linearization | str:
    """The FMU at the point where the search from ``start`` ends (an equilibrium if it is at rest
    there), or what stopped the search: an error of the FMU (its own instance is freed, the plant's
    is untouched)."""
    key = (repr(plant._start), start.x.tobytes(), start.v.tobytes())
    if key not in plant.equilibria:  # the plan linearizes twice (in discrete and in continuous time)
        plant.equilibria[key] = _search(plant, start)
    reached = plant.equilibria[key]
    return reached if isinstance(reached, str) else _jacobian(plant, reached, u)


def _search(plant: FmuPlantParts, start: _Linearization) -> np.ndarray | str:
    """Where ``equilibrium.search`` from ``start`` ends, in an instance of its own."""
    model = plant.model
    watch = CallWatch(model.path.name, model.version, plant.watch.slot)
    fmu = instantiate(model, plant._unzipped, "model-exchange", watch)
    try:
        initialize(model, fmu, "model-exchange", plant._start, plant.tolerance, plant.duration)
        version = model.version
        inputs, none = Access(model.actuators + model.disturbances, version), Access((), version)
        derivatives, states = Access(model.derivatives, version), model.continuous_states
        directional = _directional(model, plant._sensors)
        nx, zero = len(start.x), np.zeros(len(start.v))

        def f(x: np.ndarray) -> np.ndarray:
            return _Point(fmu, model, x, start.v, inputs, none, none).at(np.zeros(nx), zero)

        def jacobian(x: np.ndarray) -> np.ndarray:
            point = _Point(fmu, model, x, start.v, inputs, none, none)
            if directional:
                point.at(np.zeros(nx), zero)
                return _directional_jacobian(fmu, version, [derivatives], states)
            return point.differences(states)

        F_x, F_v = start.blocks()
        scale = nominals(model)
        rates = equilibrium.rate_scales(F_x, F_v, equilibrium.scales(start.x, scale), equilibrium.scales(start.v))
        return equilibrium.search(f, jacobian, start.x, rates, scale)
    except FmuCallError as error:
        if watch.fatal:
            raise
        return f"the search from them stopped: {error}"
    finally:
        release(fmu, watch)


class _Point:
    """The FMU at the linearization point (x0, v0), evaluated at perturbations of it."""

    def __init__(
        self, fmu: Any, model: Any, x0: np.ndarray, v0: np.ndarray, inputs: Access, named: Access, sensors: Access
    ) -> None:
        self.fmu, self.model, self.x0, self.v0 = fmu, model, x0, v0
        self.inputs, self.named, self.sensors = inputs, named, sensors
        self.completes_steps = model.description.modelExchange.needsCompletedIntegratorStep

    def at(self, dx: np.ndarray, dv: np.ndarray) -> np.ndarray:
        """[ẋ; s; y] at (x0 + dx, v0 + dv). As a solver's step ends (FMPy's order): time, inputs and
        states set, the integrator step completed where the FMU needs it, then the outputs read, then
        the derivatives. OpenModelica's FMUs compute their outputs only in fmi2CompletedIntegratorStep
        (and at events): without it they stay the initialization's, and C comes out all zeros."""
        fmu = self.fmu
        fmu.setTime(0.0)
        self.inputs.set(fmu, self.v0 + dv)
        set_continuous_states(fmu, self.x0 + dx)
        if self.completes_steps:
            fmu.completedIntegratorStep()
        s, y = self.named.get(fmu), self.sensors.get(fmu)
        return np.concatenate([state_derivatives(fmu, self.model.version, len(self.x0)), s, y])

    def differences(self, knowns: tuple[Element, ...]) -> np.ndarray:
        """The Jacobian by central differences, steps 2⁻²⁰·|value| (2⁻²⁰ at 0); integer and Boolean
        inputs have no derivative (their columns are 0)."""
        nx = len(self.x0)
        point = np.concatenate([self.x0, self.v0])
        steps = FD_STEP * np.where(point != 0, np.abs(point), 1.0)
        columns = []
        for j, (h, known) in enumerate(zip(steps, knowns)):
            e = np.zeros(len(point))
            if not known.discrete:
                e[j] = h
                columns.append((self.at(e[:nx], e[nx:]) - self.at(-e[:nx], -e[nx:])) / (2.0 * h))
            else:
                columns.append(None)
        rows = nx + len(self.named.elements) + len(self.sensors.elements)
        return (
            np.column_stack([c if c is not None else np.zeros(rows) for c in columns])
            if columns
            else np.zeros((rows, 0))
        )


#: Directional derivatives and central differences disagree on an entry J_ij when
#: |DD − FD| > RTOL·max(|DD|, |FD|) + ATOL·(the largest |entry| of its matrix).
RTOL, ATOL = 1e-4, 1e-6


def disagreements(name: str, plant: FmuPlantParts, directional: np.ndarray, differences: np.ndarray) -> list[str]:
    """One warning per matrix (in the FMU's coordinates: A = ∂ẋ/∂x, B = ∂ẋ/∂u, E = ∂ẋ/∂d, C = ∂y/∂x,
    D = ∂y/∂u, and S = ∂s/∂x for named states) whose entries disagree beyond the tolerance, with
    its three worst entries."""
    model = plant.model
    nx, ns, m = len(model.continuous_states), len(model.states), len(model.actuators)
    xs = [e.name for e in model.continuous_states]
    rows = {
        "x": (0, nx, xs),
        "s": (nx, nx + ns, list(plant.state_names)),
        "y": (nx + ns, None, list(plant.sensor_names)),
    }
    cols = {
        "x": (0, nx, xs),
        "u": (nx, nx + m, list(plant.actuator_names)),
        "d": (nx + m, None, list(plant.disturbance_names)),
    }
    found = []
    for matrix, row, col in (
        ("A", "x", "x"),
        ("B", "x", "u"),
        ("E", "x", "d"),
        ("S", "s", "x"),
        ("C", "y", "x"),
        ("D", "y", "u"),
    ):
        if matrix == "S" and model.states == model.continuous_states:
            continue
        r0, r1, row_names = rows[row]
        c0, c1, col_names = cols[col]
        dd, fd = directional[r0:r1, c0:c1], differences[r0:r1, c0:c1]
        if dd.size == 0:
            continue
        gap = np.abs(dd - fd)
        bad = gap > RTOL * np.maximum(np.abs(dd), np.abs(fd)) + ATOL * np.abs(dd).max()
        if not bad.any():
            continue
        worst = sorted(zip(*np.nonzero(bad)), key=lambda ij: -gap[ij])[:3]
        entries = ", ".join(
            f"{matrix}[{row_names[i]}, {col_names[j]}] {dd[i, j]:.6g} vs {fd[i, j]:.6g}" for i, j in worst
        )
        found.append(
            f"{name}: its directional derivatives and central differences disagree on {int(bad.sum())} entries of "
            f"{matrix} (tolerance {RTOL:g} relative + {ATOL:g} of the matrix's largest entry), worst {entries}; the "
            "design model uses the directional derivatives"
        )
    return found


def state_derivatives(fmu: Any, version: int, nx: int) -> np.ndarray:
    """ẋ of a model-exchange instance at its current states, inputs and time."""
    dx = np.zeros(nx)
    pointer = dx.ctypes.data_as(ctypes.POINTER(ctypes.c_double))
    (fmu.getDerivatives if version == 2 else fmu.getContinuousStateDerivatives)(pointer, nx)
    return dx


def _directional_jacobian(fmu: Any, version: int, unknowns: list[Any], knowns: tuple[Element, ...]) -> np.ndarray:
    """∂(unknowns)/∂(knowns) column by column from the FMU's directional derivatives (scalars).
    An unknown that is itself a known (an output that is a continuous state) has the unit row:
    FMUs need not answer for it (the Reference FMUs answer 0). Integer and Boolean variables have
    no derivative (FMI asks for Float ones only): their rows and columns are 0."""
    rows = [e for a in unknowns for e in a.elements]
    known_at = {id(k.variable): j for j, k in enumerate(knowns)}
    asked = [i for i, e in enumerate(rows) if id(e.variable) not in known_at and not e.discrete]
    vrs = [rows[i].variable.valueReference for i in asked]
    jacobian = np.zeros((len(rows), len(knowns)))
    for i, e in enumerate(rows):
        if id(e.variable) in known_at:
            jacobian[i, known_at[id(e.variable)]] = 1.0
    for j, known in enumerate(knowns):
        if not vrs:
            break
        if known.discrete:
            continue
        reference = [known.variable.valueReference]
        if version == 2:
            column = fmu.getDirectionalDerivative(vrs, reference, [1.0])
        else:
            column = fmu.getDirectionalDerivative(vrs, reference, [1.0], len(vrs))
        jacobian[asked, j] = column
    return jacobian
