"""The co-simulation runner: owns simulated time and drives one run tick by tick.

Tick k at t_k = k τ:
  1. read the plant's true state x_k and sensors y_k (MuJoCo, after the previous mj_step);
  2. evaluate the commanded inputs u_k and apply the fault layer: measured readings and
     effective inputs;
  3. send SYNC(k) and the sensor and command frames of tick k on the bus;
  4. let every estimator node answer with its frames for tick k, and collect them;
  5. log every frame and the ground truth of tick k;
  6. hold the effective inputs for τ and advance the physics (mj_step).

Estimator nodes run in this process on a python-can ``virtual`` bus and see only frames.
Whatever ends the run, the MCAP log is finished and records how the run ended.
"""

from __future__ import annotations

import importlib.metadata
import json
import math
import platform
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from uuid import uuid4

import can
import numpy as np

import estimators
import faults as fm
from cosim import __version__
from cosim.codec import Codec
from cosim.errors import CosimError, ModelError, ScenarioError
from cosim.interrupts import DeferredInterrupts
from cosim.log import McapLog
from cosim.node import EstimatorNode, NodeDriver
from cosim.plant import Plant
from cosim.recorder import RunRecorder
from cosim.scenario import ActuatorEffectivenessSpec, LoadedScenario, Scenario, build_waveform
from estimators import Estimator, LinearModel, ParameterError
from mjcf import Channel


@dataclass(frozen=True)
class Progress:
    tick: int
    ticks: int
    sim_time: float
    wall_time: float
    frames: int

    @property
    def realtime_factor(self) -> float:
        return self.sim_time / self.wall_time if self.wall_time > 0 else float("inf")


@dataclass(frozen=True)
class RunResult:
    path: Path
    status: str
    ticks: int
    frames: int
    frames_lost: int
    wall_time: float
    sim_time: float
    error: str = ""

    @property
    def realtime_factor(self) -> float:
        return self.sim_time / self.wall_time if self.wall_time > 0 else float("inf")


def build_faults(s: Scenario) -> fm.FaultInjector:
    """The scenario's noise and faults as fault models on the transmitted sensors and actuators."""
    sensors, actuators = list(s.sensors), list(s.actuators)

    def sensor_model(spec, label: str) -> fm.SensorFault:
        names = spec.sensors if spec.sensors is not None else sensors
        channels = tuple(sensors.index(n) for n in names)
        common = dict(channels=channels, start=spec.start, end=spec.end, label=label)
        n = len(channels)
        widen = lambda values: tuple(values) * n if len(values) == 1 else tuple(values)  # noqa: E731
        match spec.kind:
            case "bias":
                return fm.Bias(**common, value=widen(spec.value), amplitude=build_waveform(spec.amplitude))
            case "drift":
                return fm.Drift(**common, rate=widen(spec.rate))
            case "gain":
                return fm.Gain(**common, gain=widen(tuple(build_waveform(g) for g in spec.gain)))
            case "gaussian_noise":
                return fm.GaussianNoise(**common, std=widen(spec.std))
            case "uniform_noise":
                return fm.UniformNoise(**common, bound=widen(spec.bound))
            case "stuck":
                return fm.StuckAt(**common, value=None if spec.value is None else widen(spec.value))
            case "dropout":
                return fm.Dropout(**common, probability=spec.probability)
            case "outliers":
                return fm.Outliers(**common, probability=spec.probability, magnitude=widen(spec.magnitude))
        raise AssertionError(spec.kind)

    noise_labels, fault_labels = s.fault_labels()
    noise = [sensor_model(spec, label) for spec, label in zip(s.noise, noise_labels)]
    sensor_faults, actuator_faults = [], []
    for spec, label in zip(s.faults, fault_labels):
        if isinstance(spec, ActuatorEffectivenessSpec):
            names = spec.actuators if spec.actuators is not None else actuators
            profiles = tuple(build_waveform(w) for w in spec.effectiveness)
            profiles = profiles * len(names) if len(profiles) == 1 else profiles
            actuator_faults.append(fm.ActuatorEffectiveness(
                channels=tuple(actuators.index(n) for n in names), start=spec.start, end=spec.end, label=label,
                effectiveness=profiles,
            ))
        else:
            sensor_faults.append(sensor_model(spec, label))
    return fm.FaultInjector(noise, sensor_faults, actuator_faults, s.seed)


def build_estimators(s: Scenario, model: LinearModel, source: str) -> dict[str, Estimator]:
    built = {}
    for i, spec in enumerate(s.estimators):
        try:
            built[spec.name] = estimators.create(spec.kind, model, spec.params)
        except ParameterError as error:
            raise ScenarioError(f"{source}: estimators[{i}] ({spec.name}): params.{error}") from None
    return built


def first_tick_at(s: Scenario, start: float) -> int:
    """The first tick k with t_k >= start: where a fault starting at ``start`` is first active."""
    k = max(0, math.ceil(start / s.sample_time) - 1)
    while s.time(k) < start:
        k += 1
    return k


def versions() -> dict[str, str]:
    found = {"python": platform.python_version(), "cosim": __version__}
    for package in ("mujoco", "numpy", "scipy", "python-can", "cantools", "mcap"):
        try:
            found[package] = importlib.metadata.version(package)
        except importlib.metadata.PackageNotFoundError:
            found[package] = "unknown"
    return found


class Run:
    """One co-simulation run of a loaded scenario into an MCAP file."""

    def __init__(self, loaded: LoadedScenario, out: str | Path, seed: int | None = None) -> None:
        scenario = loaded.scenario.with_seed(seed)
        self.loaded, self.scenario, self.out = loaded, scenario, Path(out)
        s = scenario
        info = s.plant_info
        try:
            self.plant = Plant(info, s.sample_time, s.sensors)
        except ModelError as error:
            raise ScenarioError(f"{loaded.source}: {error}") from None
        # Estimators are designed on the linearization at the plant's keyframe (its operating point).
        self.model = self.plant.linearize()
        self.plant.reset(s.plant.initial_state)
        self.estimators = build_estimators(s, self.model, loaded.source)
        self.faults = build_faults(s)
        onset = self.faults.first_onset
        self.onset_tick = None if onset is None else first_tick_at(s, onset)
        self.inputs = [
            next((build_waveform(i.signal) for i in s.inputs if i.actuator == name), fm.Constant(0.0))
            for name in s.actuators
        ]
        sensors, actuators, states = s.channels()
        self.codec = Codec(
            sensors, actuators, {name: states for name in self.estimators}, fd=s.bus.fd, bitrate=s.bus.bitrate,
            data_bitrate=s.bus.data_bitrate, cycle_time=s.sample_time,
        )
        self.units = {
            "states": {c.name: c.unit for c in states},
            "sensors": {c.name: c.unit for c in sensors},
            "actuators": {c.name: c.unit for c in actuators},
        }

    def _metadata(self, log: McapLog) -> None:
        s = self.scenario
        est = {
            name: {"kind": e.kind, "messages": [m.name for m in self.codec.messages(sender=name)], "states": list(self.model.states)}
            for name, e in self.estimators.items()
        }
        log.metadata("cosim.run", {
            "scenario": s.name, "source": self.loaded.source, "seed": str(s.seed), "sample_time": repr(s.sample_time),
            "duration": repr(s.duration), "ticks": str(s.ticks), "plant": s.plant.model,
            "states": json.dumps(list(self.plant.state_names)), "sensors": json.dumps(list(s.sensors)),
            "actuators": json.dumps(list(s.actuators)), "estimators": json.dumps(est),
            "fault_onset": json.dumps(self.faults.first_onset),
            "fault_onset_tick": json.dumps(self.onset_tick),
            "faults": json.dumps([{"label": f.label, "kind": f.kind, "start": f.start, "end": f.end if np.isfinite(f.end) else None} for f in self.faults.faults]),
            "bus": json.dumps({"interface": s.bus.interface, "fd": s.bus.fd, "bitrate": s.bus.bitrate, "data_bitrate": s.bus.data_bitrate}),
        })
        log.metadata("cosim.scenario", {"source": self.loaded.source, "toml": self.loaded.text, "resolved": s.model_dump_json()})
        log.metadata("cosim.versions", versions())
        log.attach(self.plant.info.model_file, "application/xml", self.plant.info.model_path.read_bytes())
        log.attach("cosim.dbc", "text/plain", self.codec.dbc.encode())

    def execute(self, on_progress: Callable[[Progress], None] | None = None, progress_every: float = 0.2) -> RunResult:
        """Run every tick; the log is complete and valid whatever ends the run."""
        s, plant, codec = self.scenario, self.plant, self.codec
        sensor_specs = [codec.specs[f"SENSOR_{n}"] for n in s.sensors]
        command_specs = [codec.specs[f"COMMAND_{n}"] for n in s.actuators]
        expected = {name: len(codec.messages(sender=name)) for name in self.estimators}
        dt_ns = round(s.sample_time * 1e9)
        channel = f"cosim-{uuid4().hex[:12]}"
        status, error, k, frames_lost = "completed", "", 0, 0
        start = time.perf_counter()
        last_report = start
        with DeferredInterrupts() as interrupts, McapLog(self.out) as log, can.Bus(interface="virtual", channel=channel) as bus:
            recorder = RunRecorder(
                log, codec, states=plant.state_names, sensors=s.sensors, actuators=s.actuators, units=self.units
            )
            self._metadata(log)
            buses = [can.Bus(interface="virtual", channel=channel) for _ in self.estimators]
            drivers = [
                NodeDriver(EstimatorNode(name, est, codec, s.sensors, s.actuators), node_bus)
                for (name, est), node_bus in zip(self.estimators.items(), buses)
            ]
            recorder.event(0, 0.0, 0, "start", f"{s.name} seed={s.seed} ticks={s.ticks}")
            try:
                for k in range(s.ticks):
                    interrupts.check()
                    t, t_ns = s.time(k), k * dt_ns
                    x, y_true = plant.state(), plant.sensors()
                    outcome = self.faults.sensors(y_true, t)
                    frames = [
                        codec.encode(spec.name, k, (value,))
                        for spec, value, sent in zip(sensor_specs, outcome.measured, outcome.sent) if sent
                    ]
                    commands = [codec.encode(spec.name, k, (w(t),)) for spec, w in zip(command_specs, self.inputs)]
                    # The actuators receive what the command frames carry (quantized in classic CAN).
                    u_cmd = np.array([codec.decode(frame).values[spec.signals[0]] for frame, spec in zip(commands, command_specs)])
                    u_eff, delta = self.faults.actuators(u_cmd, t)
                    if not np.all(np.isfinite(u_eff)):
                        bad = s.actuators[int(np.flatnonzero(~np.isfinite(u_eff))[0])]
                        raise CosimError(f"actuator {bad}: the effective input at tick {k} is not finite; check its input signal and actuator faults")
                    frames += commands
                    frames.insert(0, codec.sync(k, len(frames)))
                    for frame in frames:
                        bus.send(frame)
                        recorder.frame(k, t, t_ns, frame, codec.decode(frame))
                    for driver in drivers:
                        driver.service()
                    received = dict.fromkeys(expected, 0)
                    reply = bus.recv(0.0)
                    while reply is not None:
                        decoded = codec.decode(reply)
                        recorder.frame(k, t, t_ns, reply, decoded)
                        if decoded is not None and decoded.spec.sender in received and decoded.tick == k % codec.tick_modulus:
                            received[decoded.spec.sender] += 1
                        reply = bus.recv(0.0)
                    for name, count in received.items():
                        if count < expected[name]:
                            frames_lost += expected[name] - count
                            recorder.event(k, t, t_ns, "frames_lost", f"{name}: {expected[name] - count} of {expected[name]}", "warning", expected[name] - count)
                    recorder.truth(
                        k, t, t_ns, x=x, y_true=y_true, noise=outcome.noise, fault=outcome.fault,
                        measured=np.where(outcome.sent, outcome.measured, np.nan), active=outcome.active, u_cmd=u_cmd,
                        u_eff=u_eff, delta=delta,
                    )
                    plant.step(u_eff)
                    if on_progress is not None and (now := time.perf_counter()) - last_report >= progress_every:
                        last_report = now
                        on_progress(Progress(k + 1, s.ticks, s.time(k + 1), now - start, recorder.frames))
                k = s.ticks
            except KeyboardInterrupt:
                status = "interrupted"
                raise
            except CosimError as exc:
                status, error = "error", str(exc)
                raise
            except BaseException as exc:
                status, error = "error", f"{type(exc).__name__}: {exc}"
                raise
            finally:
                t_end_ns = k * dt_ns
                recorder.event(k, s.time(k), t_end_ns, "stop", status if not error else f"{status}: {error}", "info" if status == "completed" else "error")
                log.metadata("cosim.result", {
                    "status": status, "ticks": str(k), "frames_total": str(recorder.frames),
                    "frames_lost": str(frames_lost), "error": error,
                })
                for node_bus in buses:
                    node_bus.shutdown()
                self.result = RunResult(
                    self.out, status, k, recorder.frames, frames_lost, time.perf_counter() - start, s.time(k), error
                )
        if on_progress is not None:
            on_progress(Progress(k, s.ticks, s.time(k), time.perf_counter() - start, self.result.frames))
        return self.result


def run(loaded: LoadedScenario, out: str | Path, seed: int | None = None, on_progress: Callable[[Progress], None] | None = None) -> RunResult:
    """Run a loaded scenario and write its log to ``out``."""
    return Run(loaded, out, seed).execute(on_progress)
