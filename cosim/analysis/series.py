"""A run log read back as per-tick series: the truth, the faults, each estimator's decoded frames,
and what the figures derive from them (the fault's effect h_Γ, true gains, the virtual output).

``cosim plot`` draws these (``cosim.analysis.plot``); the report, the documentation's figures and
the reproduction tests read them too.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

import estimators
from cosim import design_cache, progress
from cosim.analysis import names
from cosim.bus.codec import estimate_signal
from cosim.errors import LogError
from cosim.log.metadata import EstimatorRecord, LogMetadata, ScenarioRecord
from cosim.log.reader import LogReader
from cosim.log.recorder import FAULTS, SENSORS, STATE, carried_tick, message_topic
from estimators import LinearModel
from estimators.base import DiagnosticKind


@dataclass
class EstimatorSeries:
    kind: str
    params: dict
    model: dict | None
    record: EstimatorRecord
    values: dict[int, dict[str, float]] = field(default_factory=lambda: defaultdict(dict))

    def signals(self, kind: DiagnosticKind) -> dict[str, str]:
        """Its diagnostic signals of one kind, each with its target."""
        return self.record.signals_of(kind)

    @property
    def shown_kind(self) -> str:
        """Its kind as people read it: a built-in's name, or the name a plugin's class declares
        (not its module path); the class's name where the plugin cannot be imported here."""
        if ":" not in self.kind:
            return self.kind
        try:
            return str(estimators.ESTIMATORS[self.kind].kind)
        except Exception:  # noqa: BLE001 (a plugin's import may raise anything: its class name will do)
            return self.kind.rsplit(":", 1)[-1]


@dataclass
class RunSeries:
    """Everything the figures need from one log, per tick."""

    scenario: str
    description: str
    sample_time: float
    states: list[str]
    sensors: list[str]
    truth: dict[int, np.ndarray]
    fault: dict[int, np.ndarray]
    estimators: dict[str, EstimatorSeries]
    faults: list[dict] = field(default_factory=list)
    """Each fault's ``label``, ``kind``, ``start`` and ``end`` (s; None: until the end of the run)."""
    sensor_truth: dict[int, np.ndarray] = field(default_factory=dict)
    """The fault-free readings of the transmitted sensors, per tick."""
    toml: str = ""
    """The scenario file as given (empty for logs without it)."""
    resolved: str = ""
    """The scenario as run, with its settings, as JSON (empty for logs without it)."""
    control: dict[int, dict[str, float]] = field(default_factory=dict)
    """The controller node's status signals per tick (closed-loop runs)."""
    reconfigured: list[str] = field(default_factory=list)
    """The controller's status signals that say it has reconfigured."""
    units: dict[str, str] = field(default_factory=dict)
    """The unit of every state, sensor and actuator (from the log's JSON Schemas; "" where none)."""
    actuators: list[str] = field(default_factory=list)
    effectiveness: dict[int, np.ndarray] = field(default_factory=dict)
    """The actuator effectiveness δ per tick (1: healthy)."""
    dropped: dict[int, list[str]] = field(default_factory=dict)
    """The sensors whose frame was not sent, per tick (only ticks with some)."""
    warnings: list[str] = field(default_factory=list)
    """What the log reader found wrong (damage, a cut: the series end there)."""

    def only(self, names: Sequence[str]) -> RunSeries:
        """The series with these estimators alone, in this order; a LogError names one it lacks."""
        missing = [name for name in names if name not in self.estimators]
        if missing:
            raise LogError(
                f"no estimator {', '.join(map(repr, missing))} in the log (its estimators: "
                f"{', '.join(self.estimators) or 'none'})"
            )
        return replace(self, estimators={name: self.estimators[name] for name in dict.fromkeys(names)})

    def unit(self, name: str) -> str:
        """`` [unit]`` of a state, sensor or actuator, or "" if it has none."""
        unit = self.units.get(name, "")
        return f" [{unit}]" if unit else ""

    def norm_unit(self) -> str:
        """The unit of |x − x̂|: the states' common unit, or what it mixes."""
        return self.norm_unit_of(self.states)

    def norm_unit_of(self, names: list[str]) -> str:
        """`` [unit]`` of a norm over ``names``: their common unit, or `` (mixes m, m/s)``."""
        units = list(dict.fromkeys(self.units.get(s, "") for s in names))
        if len(units) == 1:
            return f" [{units[0]}]" if units[0] else ""
        return f" (mixes {', '.join(u or '1' for u in units)})"

    def ticks(self, name: str) -> np.ndarray:
        have = self.estimators[name].values
        return np.array(
            sorted(k for k in have if k in self.truth and all(estimate_signal(s) in have[k] for s in self.states)),
            dtype=int,
        )

    def estimate(self, name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(t, x̂, x) of one estimator at the ticks with a complete estimate and truth."""
        ks = self.ticks(name)
        values = self.estimators[name].values
        x_hat = np.array([[values[k][estimate_signal(s)] for s in self.states] for k in ks]).reshape(
            len(ks), len(self.states)
        )
        x = np.array([self.truth[k] for k in ks]).reshape(len(ks), len(self.states))
        return ks * self.sample_time, x_hat, x

    def error(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """(t, |x − x̂|) of one estimator."""
        t, x_hat, x = self.estimate(name)
        return t, np.linalg.norm(x - x_hat, axis=1)

    def diagnostic(self, name: str, kind: DiagnosticKind) -> tuple[np.ndarray, np.ndarray] | None:
        """One estimator's diagnostics of ``kind`` that have a sensor as target, one column per
        transmitted sensor (None unless it publishes one for every sensor)."""
        e = self.estimators[name]
        by_target = {target: signal for signal, target in e.record.signals_of(kind).items()}
        if not all(o in by_target for o in self.sensors):
            return None
        values = e.values
        keys = [by_target[o] for o in self.sensors]
        ks = np.array(sorted(k for k in values if all(key in values[k] for key in keys)), dtype=int)
        if ks.size == 0:
            return None
        return ks * self.sample_time, np.array([[values[k][key] for key in keys] for k in ks])

    def diagnostics(self, kind: DiagnosticKind, names: Iterable[str] | None = None) -> dict:
        """``diagnostic(name, kind)`` of every estimator (or of ``names``) that publishes it."""
        found = {name: self.diagnostic(name, kind) for name in (self.estimators if names is None else names)}
        return {name: v for name, v in found.items() if v is not None}


def load(path: str | Path) -> RunSeries:
    """Read a run log into per-tick series (truth, faults, each estimator's decoded frames)."""
    with LogReader(path) as reader:
        meta = LogMetadata.read(reader.metadata())
        run = meta.run
        if run is None or run.sample_time is None or run.dt_ns is None:
            raise LogError(f"{path}: no cosim.run metadata; cosim plot needs a log written by cosim run")
        given = meta.scenario or ScenarioRecord()
        series = RunSeries(
            run.scenario or Path(path).stem,
            given.resolved_json().get("description", ""),
            run.sample_time,
            run.states,
            run.sensors,
            {},
            {},
            {name: EstimatorSeries(e.kind, e.params, e.model, e) for name, e in run.estimators.items()},
            [f.to_json() for f in run.faults],
            toml=given.toml,
            resolved=given.resolved,
            reconfigured=run.controller.signals_of(DiagnosticKind.RECONFIGURATION) if run.controller else [],
            units=names.units(reader.schemas()),
            actuators=list(run.actuators),
        )
        owner = run.estimate_topics()
        status = [message_topic(m) for m in run.controller.status_messages] if run.controller else []
        control: dict[int, dict[str, float]] = defaultdict(dict)
        for topic, log_time, msg in reader.messages([STATE, FAULTS, SENSORS, *owner, *status]):
            if topic == STATE:
                series.truth[msg["tick"]] = np.array([msg[s] for s in series.states])
            elif topic == SENSORS:
                series.sensor_truth[msg["tick"]] = np.array([msg[s] for s in series.sensors])
            elif topic == FAULTS:
                _take_faults(series, msg)
            else:  # an estimator's frame, or the controller's status: by the tick it belongs to
                values = control if topic in status else series.estimators[owner[topic]].values
                values[carried_tick(log_time // run.dt_ns, msg["tick"])].update(
                    {k: v for k, v in msg.items() if k != "tick"}
                )
        series.warnings = list(reader.warnings)
    series.control = dict(control)
    return series


def _take_faults(series: RunSeries, msg: dict) -> None:
    """One tick of /truth/faults: the deviation per sensor, actuator effectiveness, frames dropped."""
    k = msg["tick"]
    series.fault[k] = np.array([msg["fault"].get(s) or 0.0 for s in series.sensors])
    delta = msg.get("effectiveness") or {}
    series.effectiveness[k] = np.array([delta.get(a, 1.0) for a in series.actuators], dtype=float)
    if msg.get("dropped"):
        series.dropped[k] = list(msg["dropped"])


def true_gains(series: RunSeries, t: np.ndarray) -> np.ndarray:
    """The effectiveness γ_i(t) of each transmitted sensor (shape (len(t), p)): the product of the
    scenario's active gain faults on it, 1 where none is."""
    gains = np.ones((len(t), len(series.sensors)))
    from cosim.scenario import GainSpec, Scenario, build_waveform

    try:
        faults = Scenario.from_resolved(series.resolved).faults if series.resolved else []
    except ValueError:
        return gains  # a scenario this version cannot read: no known gain faults
    for spec in faults:
        if not isinstance(spec, GainSpec):
            continue
        names = spec.sensors if spec.sensors is not None else series.sensors
        active = (t >= spec.start) & (t < spec.end)
        for j, name in enumerate(names):
            waveform = build_waveform(spec.gain[j if len(spec.gain) > 1 else 0])
            column = series.sensors.index(name)
            gains[active, column] *= [waveform(tk - spec.start) for tk in t[active]]
    return gains


def virtual_output(series: RunSeries, name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(t, ẑ, z): a reconciliation scheme's virtual output and the true z = H_z y, or None."""
    e = series.estimators[name]
    zhat = next(iter(e.signals(DiagnosticKind.VIRTUAL_OUTPUT)), None)
    if zhat is None:
        return None
    ks = np.array(sorted(k for k, v in e.values.items() if zhat in v and k in series.sensor_truth), dtype=int)
    if ks.size == 0:
        return None
    hz = np.asarray(estimators.ESTIMATORS[e.kind].check_params(e.params).Hz, dtype=float)
    z = np.array([hz @ series.sensor_truth[k] for k in ks])
    return ks * series.sample_time, np.array([e.values[k][zhat] for k in ks]), z


def bias_effect(series: RunSeries, name: str) -> tuple[np.ndarray, np.ndarray] | None:
    """|h_Γ| over time for one estimator, or None if the notion does not apply to it."""
    e = series.estimators[name]
    if e.model is None:
        return None
    with progress.step(f"estimator {name} ({e.shown_kind}), for its |h_Γ|"):
        estimator = design_cache.create(e.kind, LinearModel.from_dict(e.model), e.params, series.sample_time)
    ks = [k for k in sorted(e.values) if k in series.fault]
    out = []
    for k in ks:
        effect = estimator.bias_effect(e.values[k], series.fault[k])
        if effect is None:
            return None
        out.append(np.linalg.norm(effect))
    return np.array(ks) * series.sample_time, np.array(out)


def cofd_directions(series: RunSeries, name: str) -> dict[str, str]:
    """What drives each COFD residual component r<h>_<i>: the i-th input column of observer h's
    multi-index (its thruster input, or cluster), as a legend label (``r1_2 along T1y``); {} if it
    cannot be told."""
    e = series.estimators[name]
    try:
        params = estimators.ESTIMATORS[e.kind].check_params(e.params)
        family = params.family
        if family is None:
            from estimators.cofd_design import SHIP_CLUSTER_FAMILY, SHIP_FAMILY

            family = SHIP_CLUSTER_FAMILY if getattr(params, "zeta", None) else SHIP_FAMILY
    except Exception:  # another kind, or parameters this version reads differently: plain names
        return {}
    cluster = bool(getattr(params, "zeta", None))
    found = {}
    for h, columns in enumerate(family, 1):
        for i, column in enumerate(columns, 1):
            j = int(column) - 1
            if cluster:
                what = f"cluster {j + 1}"
            elif 0 <= j < len(series.actuators):
                what = series.actuators[j]
            else:
                what = f"column {j + 1}"
            found[f"r{h}_{i}"] = f"r{h}_{i} along {what}"
    return found


def first_tick(values: dict[int, dict[str, float]], name: str) -> int | None:
    """The first tick at which the signal ``name`` is set (> 0.5), or None."""
    return next((k for k in sorted(values) if values[k].get(name, 0.0) > 0.5), None)
