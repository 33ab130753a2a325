"""Paper-style figures of a run log: estimates against the truth, errors, faults, and what each estimator publishes.

``cosim plot FILE.mcap [--out DIR] [--format png|svg|pdf] [--dpi N]`` writes one file per figure
(matplotlib, no display needed; vector formats keep their text as text). Every axis says its
quantity and unit (from the log's JSON Schemas), every legend names its curves after the
estimators and signals (``cosim.analysis.names``), and figures are saved with their whole
bounding box, so nothing is clipped. Colours are the estimators', the same in every figure.

- ``estimates``: every state against each estimator's estimate x̂ (TAC 2024 Figs. 3–5 show the
  errors; these are what the errors are made of);
- ``error``: |x − x̂| of every estimator against time (linear and logarithmic), the top panels
  of TAC 2024 Figs. 3–5 and CDC 2016 Figs. 1, 6; the norm mixes the states' units when they
  differ, which ``state_errors`` does not;
- ``state_errors``: x̂_i − x_i per state, in its unit, per estimator;
- ``faults``: what the faults injected: the deviation added to each sensor, the frames dropped,
  the effectiveness δ of each actuator, with every fault's window shaded;
- ``weights``: the selector state s and optimizer state z (TAC 2024), or the weights Γ
  (CDC 2016), per estimator that has them (Figs. 3–5 bottom; CDC Figs. 3, 8);
- ``bias_effect``: |h_Γ|, the part of each observer's output injection due to the true fault
  (h_Γ = Z_Γ φ in CDC 2016 Figs. 4, 9; R(s)⁻¹Γ(φ)s of TAC 2024 eq. (20)), from the logged
  weights and the logged fault;
- ``gamma_norm``: |Γ| (CDC 2016 Figs. 5, 10), when a run has continuous-time observers;
- ``bias_estimate``: φ̂ against the true fault, for estimators that estimate it (TAC eq. (7));
- ``residual``: the residual r = y − C x̂ per output (linear) and |r| (logarithmic), for
  estimators that publish ``r_<sensor>`` diagnostics (the unknown input observer, course notes
  eq. (10)), with every fault's window shaded and its onset marked;
- ``gain_estimate``: the estimated sensor effectiveness γ̂ of the reconciliation schemes
  (IJC 2018 eq. (53), Figs. 6–7) against the true gain of the scenario's gain faults;
- ``virtual_output``: the reconciled virtual output ẑ = H_z ŷ of every scheme against the
  true z = H_z y (IJC 2018 eq. (6), Fig. 9), and |ẑ − z|;
- ``cofd_residuals``: each COFD observer's residual components |r^(h)_i| over their thresholds
  (Cristofaro & Johansen, Figs. 2–4), each named by the thruster (input column) whose fault
  drives it, with fault onsets and the diagnosis node's isolations;
- ``trajectory``: in a closed-loop run, the true state against time (Figs. 5–6: x_G(t),
  y_G(t)), with fault onsets and, if it happened, the controller's reconfiguration.

Estimators are rebuilt from the log's metadata (kind, parameters, design model) to evaluate h_Γ.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import estimators
from cosim.analysis import names
from cosim.bus.codec import estimate_signal
from cosim.errors import LogError
from cosim.extras import require
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
    units: dict[str, str] = field(default_factory=dict)
    """The unit of every state, sensor and actuator (from the log's JSON Schemas; "" where none)."""
    actuators: list[str] = field(default_factory=list)
    effectiveness: dict[int, np.ndarray] = field(default_factory=dict)
    """The actuator effectiveness δ per tick (1: healthy)."""
    dropped: dict[int, list[str]] = field(default_factory=dict)
    """The sensors whose frame was not sent, per tick (only ticks with some)."""

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
        effectiveness: dict[int, np.ndarray] = {}
        dropped: dict[int, list[str]] = {}
        units = names.units(reader.schemas())
        actuators = run.actuators
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
                delta = msg.get("effectiveness") or {}
                effectiveness[msg["tick"]] = np.array([delta.get(a, 1.0) for a in actuators], dtype=float)
                if msg.get("dropped"):
                    dropped[msg["tick"]] = list(msg["dropped"])
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
        units=units,
        actuators=list(actuators),
        effectiveness=effectiveness,
        dropped=dropped,
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


#: Figure formats and what matplotlib writes into them that would change from one run to the next.
FORMATS = {"png": {"Software": None}, "svg": {"Date": None}, "pdf": {"CreationDate": None}}
WIDTH = 9.0  # inches: a full-width figure
STYLE: Any = {  # matplotlib rc parameters (typed as its literal keys)
    "svg.fonttype": "none",  # text stays text
    "pdf.fonttype": 42,
    "axes.titlesize": 10,
    "axes.labelsize": 9,
    "xtick.labelsize": 8,
    "ytick.labelsize": 8,
    "legend.fontsize": 7.5,
    "figure.titlesize": 11,
}


def plot(path: str | Path, out: str | Path, fmt: str = "png", dpi: int = 150) -> list[Path]:
    """Write the figures of one log into ``out`` as ``fmt`` (png, svg, pdf); returns the files written."""
    if fmt not in FORMATS:
        raise LogError(f"unknown figure format {fmt!r}: choose png, svg or pdf")
    require("matplotlib", "cosim plot")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with plt.rc_context(STYLE):
        series = load(path)
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        written: list[Path] = []
        title = series.scenario
        color = {name: f"C{i % 10}" for i, name in enumerate(series.estimators)}
        end = max(series.truth, default=0) * series.sample_time

        def figure(rows: int, columns: int = 1, height: float = 2.2, **kw):
            return plt.subplots(
                rows, columns, figsize=(WIDTH, max(2.8, height * rows + 0.6)), squeeze=False, layout="constrained", **kw
            )

        def save(fig, name: str, heading: str) -> None:
            fig.suptitle(f"{title}: {heading}")
            target = out / f"{name}.{fmt}"
            fig.savefig(target, dpi=dpi, bbox_inches="tight", pad_inches=0.08, metadata=FORMATS[fmt])
            plt.close(fig)
            written.append(target)

        def faults_shaded(ax, label: bool = False) -> None:
            """Every fault's window shaded, its onset dotted."""
            for f in series.faults:
                stop = end if f.get("end") is None else f["end"]
                ax.axvspan(f["start"], stop, color="0.5", alpha=0.06, lw=0)
                ax.axvline(
                    f["start"], color="0.35", ls=":", lw=1, label=f"fault onset ({f['label']})" if label else None
                )

        def finish(ax, ylabel: str, legend: bool = True, **legend_kw) -> None:
            ax.set_ylabel(ylabel)
            ax.grid(alpha=0.3)
            if legend and ax.get_legend_handles_labels()[0]:
                ax.legend(**{"loc": "best", "framealpha": 0.85, **legend_kw})

        def state_grid(names: list[str]):
            columns = 2 if len(names) > 3 else 1
            rows = -(-len(names) // columns)
            fig, axes = figure(rows, columns, height=2.0, sharex=True)
            cells = list(axes.T.ravel())
            for ax in cells[len(names) :]:
                ax.set_visible(False)
            for ax in axes[-1]:
                ax.set_xlabel("time t [s]")
            if len(names) % columns:  # the column with one fewer panel gets its time axis labelled too
                cells[len(names) - 1].set_xlabel("time t [s]")
                cells[len(names) - 1].tick_params(labelbottom=True)
            return fig, cells

        def label(name: str) -> str:
            return f"{name} ({series.estimators[name].kind})"

        def figure_legend(fig, cells) -> None:
            """One legend for the whole figure, under its panels: each curve name once."""
            found: dict[str, object] = {}
            for ax in cells:
                for handle, text in zip(*ax.get_legend_handles_labels()):
                    found.setdefault(text, handle)
            if found:
                fig.legend(list(found.values()), list(found), loc="outside lower center", ncol=min(4, len(found)))

        # -- the state against every estimate ---------------------------------------------------------
        ks = np.array(sorted(series.truth), dtype=int)
        x = np.array([series.truth[k] for k in ks]).reshape(len(ks), len(series.states))
        estimated = {name: series.estimate(name) for name in series.estimators}
        estimated = {name: v for name, v in estimated.items() if v[0].size}
        if ks.size and estimated:
            fig, cells = state_grid(series.states)
            for i, (ax, state) in enumerate(zip(cells, series.states)):
                ax.plot(ks * series.sample_time, x[:, i], color="k", lw=1.8, label="true state x")
                for name, (t, xhat, _) in estimated.items():
                    ax.plot(t, xhat[:, i], color=color[name], lw=1, label=f"{label(name)}: x̂")
                faults_shaded(ax, label=True)
                finish(ax, f"{state}{series.unit(state)}", legend=False)
            figure_legend(fig, cells)
            save(fig, "estimates", "true state and every estimate x̂")

            fig, cells = state_grid(series.states)
            for i, (ax, state) in enumerate(zip(cells, series.states)):
                for name, (t, xhat, xt) in estimated.items():
                    ax.plot(t, xhat[:, i] - xt[:, i], color=color[name], lw=1, label=label(name))
                ax.axhline(0, color="k", lw=0.6)
                faults_shaded(ax, label=True)
                finish(ax, f"x̂ − x of {state}{series.unit(state)}", legend=False)
            figure_legend(fig, cells)
            save(fig, "state_errors", "estimation error per state, x̂ − x")

        # -- the norm of the error ----------------------------------------------------------------------
        fig, axes = figure(2, height=2.6, sharex=True)
        linear, log = axes[0, 0], axes[1, 0]
        for name in series.estimators:
            t, err = series.error(name)
            if t.size:
                linear.plot(t, err, color=color[name], label=label(name), lw=1)
                log.semilogy(t, np.maximum(err, 1e-16), color=color[name], label=label(name), lw=1)
        for ax in (linear, log):
            faults_shaded(ax, label=ax is linear)
        finish(linear, f"|x − x̂|{series.norm_unit()}")
        finish(log, "|x − x̂| (log scale)", legend=False)
        log.set_xlabel("time t [s]")
        save(fig, "error", "estimation error norm |x − x̂| over the whole state")

        # -- the injected faults ------------------------------------------------------------------------
        fault_panels = _fault_panels(series)
        if fault_panels:
            ratios = [0.25 + 0.2 * len(curves) if events_only else 1.0 for _, curves, events_only in fault_panels]
            fig, axes = figure(
                len(fault_panels), height=2.1 * sum(ratios) / len(ratios), sharex=True, height_ratios=ratios
            )
            for ax, (ylabel, curves, events_only) in zip(axes[:, 0], fault_panels):
                if events_only:  # one row of marks per sensor, at the ticks its frame was not sent
                    for row, (times, _) in enumerate(curves.values()):
                        ax.plot(times, np.full(len(times), row), "|", ms=8, mew=0.8, color=f"C{row}")
                    ax.set_yticks(range(len(curves)), list(curves))
                    ax.set_ylim(-0.7, len(curves) - 0.3)
                    faults_shaded(ax)
                    finish(ax, ylabel, legend=False)
                    continue
                for curve_label, (times, v) in curves.items():
                    ax.plot(times, v, lw=1, label=curve_label)
                faults_shaded(ax)
                finish(ax, ylabel, ncol=min(3, len(curves)))
            top = axes[0, 0]
            for f in series.faults:
                top.annotate(
                    f" {f['label']} ({f['kind']})",
                    (f["start"], 1),
                    xycoords=("data", "axes fraction"),
                    rotation=90,
                    va="top",
                    ha="right",
                    fontsize=6.5,
                    color="0.3",
                )
            axes[-1, 0].set_xlabel("time t [s]")
            save(fig, "faults", "what the faults injected (/truth/faults), each from its onset")

        reconciliators = {name for name in series.estimators if virtual_output(series, name) is not None}
        weighted = [
            (name, kind, data)
            for name in series.estimators
            for kind in (DiagnosticKind.SELECTOR, DiagnosticKind.OPTIMIZER, DiagnosticKind.WEIGHT)
            for data in [series.diagnostic(name, kind)]
            if data is not None
        ]
        if weighted:
            fig, axes = figure(len(weighted), height=2.2, sharex=True)
            labels = {
                DiagnosticKind.SELECTOR: "selector s",
                DiagnosticKind.OPTIMIZER: "optimizer z",
                DiagnosticKind.WEIGHT: "weights Γ",
            }
            for ax, (name, kind, (t, w)) in zip(axes[:, 0], weighted):
                for i, sensor in enumerate(series.sensors):
                    ax.plot(t, w[:, i], label=f"sensor {sensor}", lw=1)
                finish(ax, f"{name}: {labels[kind]} [1]", loc="center right")
            axes[-1, 0].set_xlabel("time t [s]")
            save(fig, "weights", "pseudoinverse weights per sensor")

        def one_panel(
            named: dict[str, tuple[np.ndarray, np.ndarray]], ylabel: str, what: str, name: str, log: bool
        ) -> None:
            """One panel of one curve per estimator against time."""
            fig, axes = figure(1, height=3.0)
            ax = axes[0, 0]
            for est, (t, v) in named.items():
                (ax.semilogy if log else ax.plot)(
                    t, np.maximum(v, 1e-16) if log else v, color=color[est], label=label(est), lw=1
                )
            ax.set_xlabel("time t [s]")
            faults_shaded(ax)
            finish(ax, ylabel)
            save(fig, name, what)

        effects = {name: e for name in series.estimators for e in [bias_effect(series, name)] if e is not None}
        if effects:
            units = set(series.units.get(s, "") for s in series.sensors)
            unit = f" [{units.pop()}]" if len(units) == 1 and "" not in units else ""
            one_panel(
                effects,
                f"|h_Γ|{unit} (log scale)",
                "the fault's effect on the output injection, |h_Γ|",
                "bias_effect",
                log=True,
            )
        weights = series.diagnostics(DiagnosticKind.WEIGHT)
        norms = {name: (t, np.linalg.norm(w, axis=1)) for name, (t, w) in weights.items()}
        if norms:
            one_panel(norms, "|Γ| [1]", "norm of the pseudoinverse weights Γ", "gamma_norm", log=False)

        bias = series.diagnostics(DiagnosticKind.BIAS_ESTIMATE)
        if bias:
            fig, axes = figure(len(series.sensors), height=2.0, sharex=True)
            fk = np.array(sorted(series.fault))
            for i, (ax, sensor) in enumerate(zip(axes[:, 0], series.sensors)):
                for name, (t, v) in bias.items():
                    ax.plot(t, v[:, i], color=color[name], label=f"{name} φ̂", lw=1)
                ax.plot(fk * series.sample_time, [series.fault[k][i] for k in fk], "k--", lw=1, label="true fault φ")
                finish(ax, f"φ on {sensor}{series.unit(sensor)}", legend=i == 0)
            axes[-1, 0].set_xlabel("time t [s]")
            save(fig, "bias_estimate", "bias estimates φ̂ against the true sensor fault")

        residuals = series.diagnostics(DiagnosticKind.RESIDUAL)
        if residuals:
            fig, axes = figure(2 * len(residuals), height=2.2, sharex=True)
            for i, (name, (t, r)) in enumerate(residuals.items()):
                linear, log = axes[2 * i, 0], axes[2 * i + 1, 0]
                for j, sensor in enumerate(series.sensors):
                    linear.plot(t, r[:, j], label=f"r on {sensor}{series.unit(sensor)}", lw=1)
                log.semilogy(t, np.maximum(np.linalg.norm(r, axis=1), 1e-16), "k", lw=1, label="|r|")
                for ax in (linear, log):
                    faults_shaded(ax, label=ax is log)
                finish(linear, f"{name}: r = y − C x̂", ncol=min(3, len(series.sensors)))
                finish(log, f"{name}: |r|{series.norm_unit_of(series.sensors)} (log)")
            axes[-1, 0].set_xlabel("time t [s]")
            save(fig, "residual", "residual r = y − C x̂ per output and its norm; faults shaded")

        gains = series.diagnostics(DiagnosticKind.GAIN_ESTIMATE, reconciliators)
        if gains:
            fig, axes = figure(len(series.sensors), height=1.9, sharex=True)
            t_all = np.array(sorted(series.sensor_truth)) * series.sample_time
            truth = true_gains(series, t_all)
            for i, (ax, sensor) in enumerate(zip(axes[:, 0], series.sensors)):
                for name, (t, g) in sorted(gains.items()):
                    ax.plot(t, g[:, i], color=color[name], label=f"{name} γ̂", lw=1)
                ax.plot(t_all, truth[:, i], "k--", lw=1, label="true γ")
                finish(ax, f"γ of {sensor} [1]", legend=i == 0, ncol=3)
            axes[-1, 0].set_xlabel("time t [s]")
            save(fig, "gain_estimate", "sensor effectiveness γ̂ against the true gain")

        outputs = {name: v for name in sorted(reconciliators) for v in [virtual_output(series, name)] if v is not None}
        if outputs:
            fig, axes = figure(2, height=2.8, sharex=True)
            values, errors = axes[0, 0], axes[1, 0]
            t, _, z = next(iter(outputs.values()))
            values.plot(t, z, "k", lw=1.6, label="true z = H_z y")
            for name, (t, zhat, z) in outputs.items():
                values.plot(t, zhat, color=color[name], lw=1, label=f"{name} ẑ")
                errors.semilogy(t, np.maximum(np.abs(zhat - z), 1e-12), color=color[name], lw=1, label=name)
            for ax in (values, errors):
                faults_shaded(ax)
            finish(values, "virtual output z", ncol=2)
            finish(errors, "|ẑ − z| (log scale)", ncol=2)
            errors.set_xlabel("time t [s]")
            save(fig, "virtual_output", "reconciled virtual output ẑ against the true z")

        reconfigured_at = None
        if series.reconfigured and (k := first_tick(series.control, series.reconfigured[0])) is not None:
            reconfigured_at = k * series.sample_time

        def events(ax, isolations: Sequence[tuple[float, str]] = (), label: bool = False) -> None:
            """Fault onsets (dotted), isolations (red, named) and the reconfiguration (green, dashed)."""
            for f in series.faults:
                ax.axvline(
                    f["start"], color="0.4", ls=":", lw=1, label=f"fault onset ({f['label']})" if label else None
                )
            for t, what in isolations:
                ax.axvline(t, color="C3", ls="--", lw=1, label=f"isolated {what} at {t:g} s" if label else None)
            if reconfigured_at is not None:
                ax.axvline(
                    reconfigured_at,
                    color="C2",
                    ls="--",
                    lw=1.2,
                    label=f"reconfigured at {reconfigured_at:g} s" if label else None,
                )

        # Diagnosis nodes whose residual components have thresholds (COFD): one panel per observer.
        diagnosers = {name: e for name, e in series.estimators.items() if e.signals(DiagnosticKind.THRESHOLD)}
        for name, e in diagnosers.items():
            bounded = {residual: threshold for threshold, residual in e.signals(DiagnosticKind.THRESHOLD).items()}
            dk = np.array(sorted(k for k, v in e.values.items() if all(t in v for t in bounded.values())), dtype=int)
            if dk.size == 0:
                continue
            first = e.values[dk[0]]
            observers: dict[str, list[str]] = {}  # observer → its residual components in use (threshold > 0)
            for residual, observer in e.signals(DiagnosticKind.RESIDUAL).items():
                if residual in bounded and first.get(bounded[residual], 0.0) > 0:
                    observers.setdefault(observer, []).append(residual)
            if not observers:
                continue
            directions = cofd_directions(series, name)
            t = dk * series.sample_time
            flags = e.signals(DiagnosticKind.ISOLATION)
            raised = [
                "+".join(target for flag, target in flags.items() if e.values[k].get(flag, 0.0) > 0.5) for k in dk
            ]
            isolations = [(t[i], what) for i, what in enumerate(raised) if what and (i == 0 or what != raised[i - 1])]
            fig, axes = figure(len(observers), height=2.2, sharex=True)
            for number, (ax, (observer, components)) in enumerate(zip(axes[:, 0], observers.items())):
                for residual in components:
                    ratio = np.array([abs(e.values[dk_][residual]) / e.values[dk_][bounded[residual]] for dk_ in dk])
                    ax.semilogy(t, np.maximum(ratio, 1e-4), lw=1, label=directions.get(residual, residual))
                ax.axhline(1.0, color="k", lw=0.8, label="threshold" if number == 0 else None)
                events(ax, isolations, label=number == 0)
                finish(ax, f"{observer}: |r_i| / threshold", loc="upper left", ncol=2)
            axes[-1, 0].set_xlabel("time t [s]")
            save(
                fig,
                "cofd_residuals" if len(diagnosers) == 1 else f"cofd_residuals_{name}",
                f"{name}, COFD residual components over their thresholds",
            )

        if series.control:
            fig, cells = state_grid(series.states)
            for i, (ax, state) in enumerate(zip(cells, series.states)):
                ax.plot(ks * series.sample_time, x[:, i], "k", lw=1, label="true state")
                events(ax, label=True)
                finish(ax, f"{state}{series.unit(state)}", legend=False)
            figure_legend(fig, cells)
            marks = [
                *(["fault onsets dotted"] if series.faults else []),
                *(["reconfiguration dashed"] if reconfigured_at is not None else []),
            ]
            save(fig, "trajectory", "true state of the closed loop" + (f" ({', '.join(marks)})" if marks else ""))
        return written


def _fault_panels(series: RunSeries) -> list[tuple[str, dict[str, tuple[np.ndarray, np.ndarray]], bool]]:
    """The panels of the faults figure: (y label, curves, drawn as steps)."""
    panels: list[tuple[str, dict[str, tuple[np.ndarray, np.ndarray]], bool]] = []
    fk = np.array(sorted(series.fault), dtype=int)
    t = fk * series.sample_time
    if fk.size:
        values = np.array([series.fault[k] for k in fk])
        hit = [i for i in range(len(series.sensors)) if np.any(values[:, i] != 0)]
        by_unit: dict[str, list[int]] = {}
        for i in hit:
            by_unit.setdefault(series.units.get(series.sensors[i], ""), []).append(i)
        for unit, columns in by_unit.items():
            curves = {f"faults.fault.{series.sensors[i]}": (t, values[:, i]) for i in columns}
            panels.append((f"added to sensor{f' [{unit}]' if unit else ''}", curves, False))
    if series.dropped:
        curves = {}
        for sensor in series.sensors:
            dropped = np.array([sensor in series.dropped.get(k, ()) for k in fk])
            if dropped.any():
                curves[sensor] = (t[dropped], np.zeros(int(dropped.sum())))
        if curves:
            panels.append(("frames not sent", curves, True))
    ek = np.array(sorted(series.effectiveness), dtype=int)
    if ek.size and series.actuators:
        delta = np.array([series.effectiveness[k] for k in ek])
        changed = [j for j, _ in enumerate(series.actuators) if np.any(delta[:, j] != 1.0)]
        if changed:
            curves = {f"δ of {series.actuators[j]}": (ek * series.sample_time, delta[:, j]) for j in changed}
            panels.append(("actuator effectiveness δ [1]", curves, False))
    return panels


def cofd_directions(series: RunSeries, name: str) -> dict[str, str]:
    """What drives each COFD residual component r<h>_<i>: the i-th input column of observer h's
    multi-index (its thruster input, or cluster), as a legend label; {} if it cannot be told."""
    e = series.estimators[name]
    try:
        params = estimators.ESTIMATORS[e.kind].check_params(e.params)
        family = params.family
        if family is None:
            from estimators.cofd import SHIP_CLUSTER_FAMILY, SHIP_FAMILY

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
                what = f"input {series.actuators[j]}"
            else:
                what = f"column {j + 1}"
            found[f"r{h}_{i}"] = f"r{h}_{i}: along {what}"
    return found


def first_tick(values: dict[int, dict[str, float]], name: str) -> int | None:
    """The first tick at which the signal ``name`` is set (> 0.5), or None."""
    return next((k for k in sorted(values) if values[k].get(name, 0.0) > 0.5), None)
