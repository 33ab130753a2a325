"""A plant given as an FMU (FMI 2.0 or 3.0, co-simulation or model exchange), run through FMPy.

``FmuPlant`` has the interface of the other plants (``cosim.plant.physics.Plant``): ``reset``,
``state``, ``sensors``, ``step`` (inputs held over the sample time), ``linearize``. Which variables
are which signals is ``cosim.plant.fmu_model``'s business (docs/fmi.md).

It advances the FMU exactly as FMPy's ``simulate_fmu`` does with ``output_interval`` = the sample
time and the same inputs, so that a run's plant trajectory is the reference importer's:

- co-simulation: one ``doStep`` from t_k = k τ to t_{k+1} = (k+1) τ, the inputs set at t_k;
- model exchange: FMPy's CVode solver (BDF, relative tolerance from ``[plant.fmu] tolerance``, the
  default experiment's or 1e-5, maximum step duration / 50, as ``simulate_fmu`` with that stop
  time) integrates from output point to output point without restarting; time events, state
  events (event indicators: BouncingBall's bounce) and step events are handled in event mode and
  restart it, as does an input that changes at t_k (FMPy's input event: a step in its input table).

The design model of the estimators is the FMU linearized about its start point (its start values
with the scenario's parameters and initial state, the inputs at their start values), or about the
equilibrium reached from it where it is none (``cosim.plant.fmu_linear``): with the
model-exchange interface, by the FMU's directional derivatives where it provides them (FMI 2
``providesDirectionalDerivative``, FMI 3 ``providesDirectionalDerivatives``) and central finite
differences otherwise, then discretized by the exact zero-order hold like the other plants; or the
``[plant.state_space]`` model the scenario gives (required for an FMU without model exchange).
"""

from __future__ import annotations

import mmap
import shutil
import weakref
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from cosim.errors import ModelError
from cosim.plant.fmu_calls import CallWatch, FmuMessage
from cosim.plant.fmu_instance import (
    Access,
    do_step,
    initialize,
    instantiate,
    release,
    set_continuous_states,
    start_values,
    update_discrete_states,
)
from cosim.plant.fmu_linear import linearize
from cosim.plant.fmu_model import FmuModel, fmpy
from cosim.plant.fmu_plant_base import FmuPlantBase
from estimators.model import LinearModel

#: The relative tolerance of FMPy's model-exchange solver when neither the scenario nor the FMU's
#: default experiment gives one (``fmpy.simulation.simulateME``).
FMPY_TOLERANCE = 1e-5


class _HeldInputs:
    """The inputs FMPy's CVode solver re-applies while it integrates: ours, held (zero-order hold)."""

    def __init__(self, plant: FmuPlant) -> None:
        self.plant = plant

    def apply(self, time: float, **_: Any) -> None:
        if self.plant._inputs.elements:
            self.plant._inputs.set(self.plant.fmu, self.plant._u)


class FmuPlant(FmuPlantBase):
    """One FMU instance advanced ``sample_time`` seconds per tick, with the ``Plant`` interface.

    ``duration`` is the run's stop time (the model-exchange solver's maximum step is duration/50,
    as FMPy's); ``design`` an optional ``[plant.state_space]`` design model (a ``StateSpaceSpec``).
    """

    def __init__(
        self,
        model: FmuModel,
        sample_time: float,
        duration: float,
        sensors: Sequence[str] | None = None,
        *,
        design: Any = None,
        tolerance: float | None = None,
        slot: mmap.mmap | None = None,
        on_message: Callable[[FmuMessage], None] | None = None,
    ) -> None:
        super().__init__(model, sample_time, duration, sensors, design)
        self.watch = CallWatch(model.path.name, model.version, slot)
        self.watch.on_message = on_message
        self.equilibria: dict[tuple[str, bytes, bytes], np.ndarray | str] = {}
        """Where the search for an equilibrium ended from each start point searched from (or what
        stopped it)."""
        experiment = model.description.defaultExperiment
        self.tolerance = tolerance
        if tolerance is None and experiment is not None and experiment.tolerance is not None:
            self.tolerance = float(experiment.tolerance)
        by_name = {e.name: e for e in model.sensors}
        version = model.version
        self._states = Access(model.states, version)
        self._sensors = Access([by_name[n] for n in self.sensor_names], version)
        self._reading = Access(self._states.elements + self._sensors.elements, version)
        self._inputs = Access(model.actuators + model.disturbances, version)
        self._unzipped = fmpy().extract(str(model.path))
        self._finalizer = weakref.finalize(self, shutil.rmtree, self._unzipped, True)
        self.fmu: Any = None
        self.reset()

    def reset(self, initial: dict[str, float] | None = None) -> None:
        """A fresh instance at the start point: the FMU's start values with the scenario's
        parameters, the named states' start values overridden by ``initial``, initialized at t = 0."""
        self.close()
        self._start = start_values(self.model, initial)
        self._k = 0
        self.watch.time = 0.0
        self.fmu = instantiate(self.model, self._unzipped, self.model.interface, self.watch)
        self._event_time = initialize(
            self.model, self.fmu, self.model.interface, self._start, self.tolerance, self.duration
        )
        self._u = self._inputs.get(self.fmu)
        self._solver: Any = None
        if self.model.interface == "model-exchange":
            self._solver = self._cvode()

    def close(self) -> None:
        """Free the FMU instance (a later ``reset`` makes a new one); after a Fatal status no call
        is allowed, after an error only freeing it."""
        if self.fmu is not None:
            fmu, self.fmu, self._solver = self.fmu, None, None
            release(fmu, self.watch)

    def take_messages(self) -> list[FmuMessage]:
        """What the FMU logged or printed since the last take."""
        return self.watch.take()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # noqa: BLE001 (interpreter shutdown: FMPy's modules may be gone)
            pass

    def state(self) -> np.ndarray:
        return self._states.get(self.fmu)

    def set_state(self, x: np.ndarray) -> None:
        """Set the continuous states (model exchange, states not renamed); FMI co-simulation has no
        way to set them."""
        if self._solver is None or self.model.states != self.model.continuous_states:
            raise ModelError(f"{self.info.name}: only a model-exchange FMU's continuous states can be set")
        set_continuous_states(self.fmu, x)
        self._solver.reset(self.time)

    def sensors(self) -> np.ndarray:
        return self._sensors.get(self.fmu)

    def reading(self) -> np.ndarray:
        """The states, then the sensors, in one read (one FMI call per variable type)."""
        return self._reading.get(self.fmu)

    def step(self, ctrl: np.ndarray, disturbance: np.ndarray | None = None) -> None:
        """Hold the inputs (actuators ``ctrl``, disturbance inputs ``disturbance``, default 0) from
        t_k to t_{k+1} and advance the FMU."""
        d = np.zeros(len(self.disturbance_names)) if disturbance is None else np.asarray(disturbance, dtype=float)
        u = np.concatenate([np.asarray(ctrl, dtype=float), d])
        t, t_next = self._k * self.sample_time, (self._k + 1) * self.sample_time
        self.watch.time = t
        if self._solver is None:
            self._u = u
            self._inputs.set(self.fmu, u)
            do_step(self.model, self.fmu, t, t_next - t)
        else:
            if not np.array_equal(u, self._u):  # an input event: FMPy's step in its input table
                self._u = u
                self._event(t, inputs=True)
            self._integrate(t, t_next)
        self._k += 1

    def _cvode(self) -> Any:
        from fmpy.sundials import CVodeSolver

        md, fmu = self.model.description, self.fmu
        return CVodeSolver(
            nx=md.numberOfContinuousStates,
            nz=md.numberOfEventIndicators,
            get_x=fmu.getContinuousStates,
            set_x=fmu.setContinuousStates,
            get_dx=fmu.getContinuousStateDerivatives if self.model.version == 3 else fmu.getDerivatives,
            get_z=fmu.getEventIndicators,
            get_nominals=fmu.getNominalsOfContinuousStates,
            set_time=fmu.setTime,
            input=_HeldInputs(self),
            startTime=0.0,
            maxStep=self.duration / 50.0,
            relativeTolerance=FMPY_TOLERANCE if self.tolerance is None else self.tolerance,
        )

    def _integrate(self, t: float, t_end: float) -> None:
        """Model exchange from t to the output point t_end, through the events on the way (the
        loop of ``fmpy.simulation.simulateME``)."""
        from fmpy.simulation import isclose

        needs_step_event = self.model.description.modelExchange.needsCompletedIntegratorStep
        while not (t > t_end or isclose(t, t_end)):
            target, event = t_end, self._event_time
            if event is not None and target > event and not isclose(target, event):
                target = event
            time_event = event is not None and isclose(target, event)
            try:
                state_event, _, t = self._solver.step(t, target)
            except RuntimeError as error:  # CVode's failure (FMPy's message holds CVode's own)
                raise self.watch.solver_failed(str(error)) from None
            self.watch.check()  # a call that failed inside the solver's callbacks
            self.watch.time = t
            self.fmu.setTime(t)
            step_event = False
            if needs_step_event:
                step_event, terminate = self.fmu.completedIntegratorStep()
                self._check_terminate(terminate, t)
            if time_event or state_event or step_event:
                self._event(t)

    def _event(self, t: float, inputs: bool = False) -> None:
        """Event mode at t (new inputs set there), the discrete states updated, the solver restarted."""
        self.fmu.enterEventMode()
        if inputs:
            self._inputs.set(self.fmu, self._u)
        terminate, self._event_time = update_discrete_states(self.model, self.fmu)
        self._check_terminate(terminate, t)
        self.fmu.enterContinuousTimeMode()
        self._solver.reset(t)

    def _check_terminate(self, terminate: bool, t: float) -> None:
        if terminate:
            raise ModelError(f"{self.info.name}: the FMU ended the simulation at t = {t:g} s")

    def linearize(
        self, x: np.ndarray | None = None, u: np.ndarray | None = None, *, continuous: bool = False, method: str = "zoh"
    ) -> LinearModel:
        """The design model: ``[plant.state_space]`` if the scenario gives one, else the FMU
        linearized at its start point (or at states ``x`` and actuator inputs ``u``), in discrete
        time at the sample time (exact zero-order hold) or in continuous time."""
        if self.design is not None:
            return self.design.linearize(continuous=continuous)
        if method != "zoh":
            raise ValueError(f"an FMU plant is linearized by the zero-order hold only, not {method!r}")
        return linearize(self, x, u, None if continuous else self.sample_time)
