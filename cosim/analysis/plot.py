"""Paper-style figures of a run log: estimation-error norms, pseudoinverse weights, |h_Γ|, |Γ|, φ̂.

``cosim plot FILE.mcap [--out DIR]`` writes PNG files (matplotlib, no display needed):

- ``error.png``: |x − x̂| of every estimator against time (linear and logarithmic), the top panels
  of TAC 2024 Figs. 3–5 and CDC 2016 Figs. 1, 6;
- ``weights.png``: the selector state s and optimizer state z (TAC 2024), or the weights Γ
  (CDC 2016), per estimator that has them (Figs. 3–5 bottom; CDC Figs. 3, 8);
- ``bias_effect.png``: |h_Γ|, the part of each observer's output injection due to the true fault
  (h_Γ = Z_Γ φ in CDC 2016 Figs. 4, 9; R(s)⁻¹Γ(φ)s of TAC 2024 eq. (20)), from the logged
  weights and the logged fault;
- ``gamma_norm.png``: |Γ| (CDC 2016 Figs. 5, 10), when a run has continuous-time observers;
- ``bias_estimate.png``: φ̂ against the true fault, for estimators that estimate it (TAC eq. (7)).
- ``residual.png``: the residual r = y − C x̂ per output (linear) and |r| (logarithmic), for
  estimators that publish ``r_<sensor>`` diagnostics (the unknown input observer, course notes
  eq. (10)), with every fault's window shaded and its onset marked.
- ``gain_estimate.png``: the estimated sensor effectiveness γ̂ of the reconciliation schemes
  (IJC 2018 eq. (53), Figs. 6–7) against the true gain of the scenario's gain faults;
- ``virtual_output.png``: the reconciled virtual output ẑ = H_z ŷ of every scheme against the
  true z = H_z y (IJC 2018 eq. (6), Fig. 9), and |ẑ − z|.
- ``cofd_residuals.png``: each COFD observer's residual components |r^(h)_i| over their thresholds
  (Cristofaro & Johansen, Figs. 2–4), with fault onsets and the diagnosis node's isolations;
- ``trajectory.png``: in a closed-loop run, the true state against time (Figs. 5–6: x_G(t),
  y_G(t)), with fault onsets and the controller's reconfiguration.

Estimators are rebuilt from the log's metadata (kind, parameters, design model) to evaluate h_Γ.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import estimators
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

    def ticks(self, name: str) -> np.ndarray:
        have = self.estimators[name].values
        return np.array(
            sorted(k for k in have if k in self.truth and all(estimate_signal(s) in have[k] for s in self.states)),
            dtype=int,
        )

    def error(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        ks = self.ticks(name)
        values = self.estimators[name].values
        x_hat = np.array([[values[k][estimate_signal(s)] for s in self.states] for k in ks]).reshape(
            len(ks), len(self.states)
        )
        x = np.array([self.truth[k] for k in ks]).reshape(len(ks), len(self.states))
        return ks * self.sample_time, np.linalg.norm(x - x_hat, axis=1)

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


def load(path: str | Path) -> RunSeries:
    """Read a run log into per-tick series (truth, faults, each estimator's decoded frames)."""
    with LogReader(path) as reader:
        meta = LogMetadata.read(reader.metadata())
        run = meta.run
        if run is None or run.sample_time is None or run.dt_ns is None:
            raise LogError(f"{path}: no cosim.run metadata; cosim plot needs a log written by cosim run")
        states, sensors = run.states, run.sensors
        given = meta.scenario or ScenarioRecord()
        description = given.resolved_json().get("description", "")
        ests = {name: EstimatorSeries(e.kind, e.params, e.model, e) for name, e in run.estimators.items()}
        owner = run.estimate_topics()
        status = [message_topic(m) for m in run.controller.status_messages] if run.controller else []
        reconfigured = run.controller.signals_of(DiagnosticKind.RECONFIGURATION) if run.controller else []
        control: dict[int, dict[str, float]] = defaultdict(dict)
        dt_ns = run.dt_ns
        truth: dict[int, np.ndarray] = {}
        fault: dict[int, np.ndarray] = {}
        sensor_truth: dict[int, np.ndarray] = {}
        for topic, log_time, msg in reader.messages([STATE, FAULTS, SENSORS, *owner, *status]):
            if topic == STATE:
                truth[msg["tick"]] = np.array([msg[s] for s in states])
            elif topic == SENSORS:
                sensor_truth[msg["tick"]] = np.array([msg[s] for s in sensors])
            elif topic in status:
                control[carried_tick(log_time // dt_ns, msg["tick"])].update(
                    {k: v for k, v in msg.items() if k != "tick"}
                )
            elif topic == FAULTS:
                fault[msg["tick"]] = np.array([msg["fault"].get(s) or 0.0 for s in sensors])
            else:
                ests[owner[topic]].values[carried_tick(log_time // dt_ns, msg["tick"])].update(
                    {k: v for k, v in msg.items() if k != "tick"}
                )
    return RunSeries(
        run.scenario or Path(path).stem,
        description,
        run.sample_time,
        states,
        sensors,
        truth,
        fault,
        ests,
        [f.to_json() for f in run.faults],
        sensor_truth,
        toml=given.toml,
        resolved=given.resolved,
        control=dict(control),
        reconfigured=reconfigured,
    )


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
    estimator = estimators.create(e.kind, LinearModel.from_dict(e.model), e.params, series.sample_time)
    ks = [k for k in sorted(e.values) if k in series.fault]
    out = []
    for k in ks:
        effect = estimator.bias_effect(e.values[k], series.fault[k])
        if effect is None:
            return None
        out.append(np.linalg.norm(effect))
    return np.array(ks) * series.sample_time, np.array(out)


def plot(path: str | Path, out: str | Path) -> list[Path]:
    """Write the figures of one log into ``out``; returns the files written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    series = load(path)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    title = series.scenario

    def save(fig, name: str) -> None:
        fig.tight_layout()
        target = out / name
        fig.savefig(target, dpi=110)
        plt.close(fig)
        written.append(target)

    fig, (linear, log) = plt.subplots(2, 1, figsize=(9, 6.5), sharex=True)
    for name in series.estimators:
        t, err = series.error(name)
        if t.size:
            linear.plot(t, err, label=name, lw=1)
            log.semilogy(t, np.maximum(err, 1e-16), label=name, lw=1)
    linear.set_ylabel("|x − x̂|")
    log.set_ylabel("|x − x̂| (log)")
    log.set_xlabel("time [s]")
    linear.set_title(f"{title}: estimation error")
    linear.legend(fontsize=8)
    for ax in (linear, log):
        ax.grid(alpha=0.3)
    save(fig, "error.png")

    reconciliators = {name for name in series.estimators if virtual_output(series, name) is not None}
    weighted = [
        (name, kind, data)
        for name in series.estimators
        for kind in (DiagnosticKind.SELECTOR, DiagnosticKind.OPTIMIZER, DiagnosticKind.WEIGHT)
        for data in [series.diagnostic(name, kind)]
        if data is not None
    ]
    if weighted:
        fig, axes = plt.subplots(len(weighted), 1, figsize=(9, 2.4 * len(weighted)), sharex=True, squeeze=False)
        labels = {
            DiagnosticKind.SELECTOR: "selector s",
            DiagnosticKind.OPTIMIZER: "optimizer z",
            DiagnosticKind.WEIGHT: "weights Γ",
        }
        for ax, (name, kind, (t, w)) in zip(axes[:, 0], weighted):
            for i, sensor in enumerate(series.sensors):
                ax.plot(t, w[:, i], label=sensor, lw=1)
            ax.set_ylabel(f"{name}\n{labels[kind]}", fontsize=8)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7, loc="right")
        axes[0, 0].set_title(f"{title}: pseudoinverse weights")
        axes[-1, 0].set_xlabel("time [s]")
        save(fig, "weights.png")

    def curves(named: dict[str, tuple[np.ndarray, np.ndarray]], ylabel: str, what: str, name: str, log: bool) -> None:
        """One panel of one curve per estimator against time."""
        fig, ax = plt.subplots(figsize=(9, 3.3))
        for label, (t, v) in named.items():
            (ax.semilogy if log else ax.plot)(t, np.maximum(v, 1e-16) if log else v, label=label, lw=1)
        ax.set_ylabel(ylabel)
        ax.set_xlabel("time [s]")
        ax.set_title(f"{title}: {what}")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        save(fig, name)

    effects = {name: e for name in series.estimators for e in [bias_effect(series, name)] if e is not None}
    if effects:
        curves(effects, "|h_Γ|", "fault effect on the output injection", "bias_effect.png", log=True)
    norms = {
        name: (t, np.linalg.norm(w, axis=1))
        for name in series.estimators
        for v in [series.diagnostic(name, DiagnosticKind.WEIGHT)]
        if v is not None
        for t, w in [v]
    }
    if norms:
        curves(norms, "|Γ|", "norm of the weights", "gamma_norm.png", log=False)

    bias = {
        name: v
        for name in series.estimators
        for v in [series.diagnostic(name, DiagnosticKind.BIAS_ESTIMATE)]
        if v is not None
    }
    if bias:
        fig, axes = plt.subplots(
            len(series.sensors), 1, figsize=(9, 2.2 * len(series.sensors)), sharex=True, squeeze=False
        )
        ks = np.array(sorted(series.fault))
        for i, (ax, sensor) in enumerate(zip(axes[:, 0], series.sensors)):
            for name, (t, v) in bias.items():
                ax.plot(t, v[:, i], label=f"{name} φ̂", lw=1)
            ax.plot(ks * series.sample_time, [series.fault[k][i] for k in ks], "k--", lw=1, label="true fault")
            ax.set_ylabel(sensor, fontsize=8)
            ax.grid(alpha=0.3)
        axes[0, 0].legend(fontsize=7)
        axes[0, 0].set_title(f"{title}: bias estimate φ̂ against the true fault")
        axes[-1, 0].set_xlabel("time [s]")
        save(fig, "bias_estimate.png")

    residuals = {
        name: v
        for name in series.estimators
        for v in [series.diagnostic(name, DiagnosticKind.RESIDUAL)]
        if v is not None
    }
    if residuals:
        fig, axes = plt.subplots(
            2 * len(residuals), 1, figsize=(9, 2.6 * 2 * len(residuals)), sharex=True, squeeze=False
        )
        end = max(t[-1] for t, _ in residuals.values())
        for i, (name, (t, r)) in enumerate(residuals.items()):
            linear, log = axes[2 * i, 0], axes[2 * i + 1, 0]
            for j, sensor in enumerate(series.sensors):
                linear.plot(t, r[:, j], label=f"r_{sensor}", lw=1)
            log.semilogy(t, np.maximum(np.linalg.norm(r, axis=1), 1e-16), "k", lw=1, label="|r|")
            linear.set_ylabel(f"{name}\nr = y − C x̂", fontsize=8)
            log.set_ylabel(f"{name}\n|r| (log)", fontsize=8)
            for ax in (linear, log):
                for number, f in enumerate(series.faults):
                    color = f"C{(number + len(series.sensors)) % 10}"
                    ax.axvspan(f["start"], end if f.get("end") is None else f["end"], color=color, alpha=0.08, lw=0)
                    ax.axvline(f["start"], color=color, ls="--", lw=1, label=f"{f['label']} ({f['kind']}) onset")
                ax.grid(alpha=0.3)
                ax.legend(fontsize=7, loc="best")
        axes[0, 0].set_title(f"{title}: residual r = y − C x̂ (faults shaded from onset)")
        axes[-1, 0].set_xlabel("time [s]")
        save(fig, "residual.png")

    gains = {
        name: v
        for name in reconciliators
        for v in [series.diagnostic(name, DiagnosticKind.GAIN_ESTIMATE)]
        if v is not None
    }
    if gains:
        fig, axes = plt.subplots(
            len(series.sensors), 1, figsize=(9, 2.1 * len(series.sensors)), sharex=True, squeeze=False
        )
        t_all = np.array(sorted(series.sensor_truth)) * series.sample_time
        truth = true_gains(series, t_all)
        for i, (ax, sensor) in enumerate(zip(axes[:, 0], series.sensors)):
            for name, (t, g) in gains.items():
                ax.plot(t, g[:, i], label=f"{name} γ̂", lw=1)
            ax.plot(t_all, truth[:, i], "k--", lw=1, label="true γ")
            ax.set_ylabel(sensor, fontsize=8)
            ax.grid(alpha=0.3)
        axes[0, 0].legend(fontsize=7, ncol=3)
        axes[0, 0].set_title(f"{title}: sensor effectiveness γ̂ against the true gain")
        axes[-1, 0].set_xlabel("time [s]")
        save(fig, "gain_estimate.png")

    outputs = {name: v for name in sorted(reconciliators) for v in [virtual_output(series, name)] if v is not None}
    if outputs:
        fig, (values, errors) = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
        t, _, z = next(iter(outputs.values()))
        values.plot(t, z, "k", lw=1.6, label="true z = H_z y")
        for name, (t, zhat, z) in outputs.items():
            values.plot(t, zhat, lw=1, label=f"{name} ẑ")
            errors.semilogy(t, np.maximum(np.abs(zhat - z), 1e-12), lw=1, label=name)
        values.set_ylabel("virtual output")
        errors.set_ylabel("|ẑ − z| (log)")
        errors.set_xlabel("time [s]")
        values.set_title(f"{title}: reconciled virtual output")
        for ax in (values, errors):
            for f in series.faults:
                ax.axvline(f["start"], color="0.5", ls=":", lw=1)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7, ncol=2)
        save(fig, "virtual_output.png")

    def events(ax, isolations: Sequence[tuple[float, str]] = ()) -> None:
        """Fault onsets (dotted), isolations and the reconfiguration (dashed)."""
        for f in series.faults:
            ax.axvline(f["start"], color="0.4", ls=":", lw=1)
        for t, label in isolations:
            ax.axvline(t, color="C3", ls="--", lw=1)
            ax.annotate(label, (t, 1), xycoords=("data", "axes fraction"), fontsize=7, color="C3", va="top", ha="left")
        if series.reconfigured and (k := first_tick(series.control, series.reconfigured[0])) is not None:
            ax.axvline(k * series.sample_time, color="C2", ls="--", lw=1.2)

    # Diagnosis nodes whose residual components have thresholds (COFD): one panel per observer.
    diagnosers = {name: e for name, e in series.estimators.items() if e.signals(DiagnosticKind.THRESHOLD)}
    for name, e in diagnosers.items():
        bounded = {residual: threshold for threshold, residual in e.signals(DiagnosticKind.THRESHOLD).items()}
        ks = np.array(sorted(k for k, v in e.values.items() if all(t in v for t in bounded.values())), dtype=int)
        if ks.size == 0:
            continue
        first = e.values[ks[0]]
        observers: dict[str, list[str]] = {}  # observer → its residual components in use (threshold > 0)
        for residual, observer in e.signals(DiagnosticKind.RESIDUAL).items():
            if residual in bounded and first.get(bounded[residual], 0.0) > 0:
                observers.setdefault(observer, []).append(residual)
        if not observers:
            continue
        t = ks * series.sample_time
        flags = e.signals(DiagnosticKind.ISOLATION)
        raised = ["+".join(target for flag, target in flags.items() if e.values[k].get(flag, 0.0) > 0.5) for k in ks]
        isolations = [(t[i], label) for i, label in enumerate(raised) if label and (i == 0 or label != raised[i - 1])]
        fig, axes = plt.subplots(len(observers), 1, figsize=(9, 2.3 * len(observers)), sharex=True, squeeze=False)
        for ax, (observer, components) in zip(axes[:, 0], observers.items()):
            for residual in components:
                ratio = np.array([abs(e.values[k][residual]) / e.values[k][bounded[residual]] for k in ks])
                ax.semilogy(t, np.maximum(ratio, 1e-4), lw=1, label=residual)
            ax.axhline(1.0, color="k", lw=0.8)
            ax.set_ylabel(f"{observer}\n|r_i| / threshold", fontsize=8)
            events(ax, isolations)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7, loc="upper left", ncol=3)
        axes[0, 0].set_title(
            f"{title}: {name}, COFD residual components over their thresholds (faults dotted, isolations red)"
        )
        axes[-1, 0].set_xlabel("time [s]")
        save(fig, "cofd_residuals.png" if len(diagnosers) == 1 else f"cofd_residuals_{name}.png")

    if series.control:
        ks = np.array(sorted(series.truth), dtype=int)
        x = np.array([series.truth[k] for k in ks])
        columns = 2 if len(series.states) > 3 else 1
        rows = -(-len(series.states) // columns)
        fig, axes = plt.subplots(rows, columns, figsize=(9, 2.1 * rows), sharex=True, squeeze=False)
        for i, (ax, state) in enumerate(zip(axes.T.ravel(), series.states)):
            ax.plot(ks * series.sample_time, x[:, i], "k", lw=1)
            ax.set_ylabel(state, fontsize=8)
            events(ax)
            ax.grid(alpha=0.3)
        for ax in axes[-1]:
            ax.set_xlabel("time [s]")
        fig.suptitle(f"{title}: true state (faults dotted, reconfiguration green)", fontsize=10)
        save(fig, "trajectory.png")
    return written


def first_tick(values: dict[int, dict[str, float]], name: str) -> int | None:
    """The first tick at which the signal ``name`` is set (> 0.5), or None."""
    return next((k for k in sorted(values) if values[k].get(name, 0.0) > 0.5), None)
