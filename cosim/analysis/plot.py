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
  weights and the logged fault (estimators are rebuilt from the log's metadata to evaluate it);
  the log axis spans six decades below the largest value;
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
  y_G(t)), with fault onsets and, if it happened, the controller's reconfiguration;
- ``path``: for a plant with planar positions ``x`` and ``y`` (the vessel), y against x, true and
  estimated, at equal scales.

Each figure is one function of a ``Canvas`` (the log's series, colours and the shared drawing
helpers) in the table ``FIGURES``; a figure that has nothing to show draws nothing. The series are
read by ``cosim.analysis.series``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from cosim.analysis import bus_layout
from cosim.analysis.series import RunSeries, bias_effect, cofd_directions, first_tick, load, true_gains, virtual_output
from cosim.errors import LogError
from cosim.extras import require
from estimators.base import DiagnosticKind

if TYPE_CHECKING:
    from matplotlib.artist import Artist
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

#: Figure formats and what matplotlib writes into them that would change from one run to the next.
FORMATS = {"png": {"Software": None}, "svg": {"Date": None}, "pdf": {"CreationDate": None}}
WIDTH = 9.0  # inches: a full-width figure
DECADES = 6  # a log axis shows this many decades below its largest value
STYLE: Any = {  # matplotlib rc parameters (typed as its literal keys)
    "svg.fonttype": "none",  # text stays text
    "pdf.fonttype": 42,
    "axes.titlesize": 10,
    "axes.labelsize": 9,
    "xtick.labelsize": 8,
    "ytick.labelsize": 8,
    "legend.fontsize": 7.5,
    "figure.titlesize": 11,
    "axes.formatter.useoffset": False,  # tick labels say their values (|Γ| near 1.0003 is not "+1")
}
TIME = "time t [s]"


class Canvas:
    """One log's figures in the making: its series, a colour per estimator, the files written."""

    def __init__(self, series: RunSeries, out: Path, fmt: str, dpi: int) -> None:
        import matplotlib.pyplot as plt

        self.plt, self.series, self.out, self.fmt, self.dpi = plt, series, out, fmt, dpi
        self.color = {name: f"C{i % 10}" for i, name in enumerate(series.estimators)}
        self.end = max(series.truth, default=0) * series.sample_time
        self.written: list[Path] = []

    @cached_property
    def truth(self) -> tuple[np.ndarray, np.ndarray]:
        """(t, x): the true state at every tick."""
        s = self.series
        ks = np.array(sorted(s.truth), dtype=int)
        return ks * s.sample_time, np.array([s.truth[k] for k in ks]).reshape(len(ks), len(s.states))

    @cached_property
    def reconfigured_at(self) -> float | None:
        """When the controller reconfigured (s), or None."""
        s = self.series
        if s.reconfigured and (k := first_tick(s.control, s.reconfigured[0])) is not None:
            return k * s.sample_time
        return None

    def label(self, name: str) -> str:
        """An estimator in a legend: its name, and its kind where that says more."""
        kind = self.series.estimators[name].kind
        return name if kind == name else f"{name} ({kind})"

    def figure(self, rows: int, columns: int = 1, height: float = 2.2, **kw: Any) -> tuple[Figure, np.ndarray]:
        return self.plt.subplots(
            rows, columns, figsize=(WIDTH, max(2.8, height * rows + 0.6)), squeeze=False, layout="constrained", **kw
        )

    def save(self, fig: Figure, name: str, heading: str) -> None:
        fig.suptitle(f"{self.series.scenario}: {heading}")
        target = self.out / f"{name}.{self.fmt}"
        fig.savefig(target, dpi=self.dpi, bbox_inches="tight", pad_inches=0.08, metadata=FORMATS[self.fmt])
        self.plt.close(fig)
        self.written.append(target)

    def faults_shaded(self, ax: Axes, label: bool = False) -> None:
        """Every fault's window shaded, its onset dotted."""
        for f in self.series.faults:
            stop = self.end if f.get("end") is None else f["end"]
            ax.axvspan(f["start"], stop, color="0.5", alpha=0.06, lw=0)
            ax.axvline(f["start"], color="0.35", ls=":", lw=1, label=f"fault onset ({f['label']})" if label else None)

    def events(self, ax: Axes, isolations: Sequence[tuple[float, str]] = (), label: bool = False) -> None:
        """Fault onsets (dotted), isolations (red, named) and the reconfiguration (green, dashed)."""
        for f in self.series.faults:
            ax.axvline(f["start"], color="0.4", ls=":", lw=1, label=f"fault onset ({f['label']})" if label else None)
        for t, what in isolations:
            ax.axvline(t, color="C3", ls="--", lw=1, label=f"isolated {what} at {t:g} s" if label else None)
        if (at := self.reconfigured_at) is not None:
            ax.axvline(at, color="C2", ls="--", lw=1.2, label=f"reconfigured at {at:g} s" if label else None)

    @staticmethod
    def finish(ax: Axes, ylabel: str, legend: bool = True, **legend_kw: Any) -> None:
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
        if legend and ax.get_legend_handles_labels()[0]:
            ax.legend(**{"loc": "best", "framealpha": 0.85, **legend_kw})

    def state_grid(self, names: list[str]) -> tuple[Figure, list[Axes]]:
        """A panel per state, in two columns when there are more than three."""
        columns = 2 if len(names) > 3 else 1
        rows = -(-len(names) // columns)
        fig, axes = self.figure(rows, columns, height=2.0, sharex=True)
        cells = list(axes.T.ravel())
        for ax in cells[len(names) :]:
            ax.set_visible(False)
        for ax in axes[-1]:
            ax.set_xlabel(TIME)
        if len(names) % columns:  # the column with one fewer panel gets its time axis labelled too
            cells[len(names) - 1].set_xlabel(TIME)
            cells[len(names) - 1].tick_params(labelbottom=True)
        return fig, cells

    @staticmethod
    def figure_legend(fig: Figure, cells: Sequence[Axes]) -> None:
        """One legend for the whole figure, under its panels: each curve name once."""
        found: dict[str, Artist] = {}
        for ax in cells:
            for handle, text in zip(*ax.get_legend_handles_labels()):
                found.setdefault(text, handle)
        if found:
            fig.legend(list(found.values()), list(found), loc="outside lower center", ncol=min(4, len(found)))

    def one_panel(
        self, named: dict[str, tuple[np.ndarray, np.ndarray]], ylabel: str, what: str, name: str, log: bool
    ) -> None:
        """One panel of one curve per estimator against time."""
        fig, axes = self.figure(1, height=3.0)
        ax = axes[0, 0]
        log = log and any(np.size(v) and np.max(v) > 0 for _, v in named.values())  # all zeros: linear
        ylabel += " (log scale)" if log else ""
        for est, (t, v) in named.items():
            (ax.semilogy if log else ax.plot)(t, v, color=self.color[est], label=self.label(est), lw=1)
        if log:
            log_floor(ax, [v for _, v in named.values()])
        ax.set_xlabel(TIME)
        self.faults_shaded(ax)
        self.finish(ax, ylabel)
        self.save(fig, name, what)


def log_floor(ax: Axes, curves: Sequence[np.ndarray]) -> None:
    """A log axis that spans ``DECADES`` below the largest value (not down to a curve's zeros)."""
    top = max((float(np.max(v)) for v in curves if np.size(v)), default=0.0)
    if top > 0:
        ax.set_ylim(top * 10.0**-DECADES, top * 2.0)
    else:  # nothing above zero (a fault rejected exactly): an axis of its own, not matplotlib's complaint
        ax.set_ylim(10.0**-DECADES, 1.0)


def estimates(c: Canvas) -> None:
    """The true state against every estimate, and the error per state."""
    s = c.series
    estimated = {name: v for name in s.estimators for v in [s.estimate(name)] if v[0].size}
    t_true, x = c.truth
    if not t_true.size or not estimated:
        return
    fig, cells = c.state_grid(s.states)
    for i, (ax, state) in enumerate(zip(cells, s.states)):
        ax.plot(t_true, x[:, i], color="k", lw=1.8, label="true state x")
        for name, (t, xhat, _) in estimated.items():
            ax.plot(t, xhat[:, i], color=c.color[name], lw=1, label=f"{c.label(name)}: x̂")
        c.faults_shaded(ax, label=True)
        c.finish(ax, f"{state}{s.unit(state)}", legend=False)
    c.figure_legend(fig, cells)
    c.save(fig, "estimates", "true state and every estimate x̂")

    fig, cells = c.state_grid(s.states)
    for i, (ax, state) in enumerate(zip(cells, s.states)):
        for name, (t, xhat, xt) in estimated.items():
            ax.plot(t, xhat[:, i] - xt[:, i], color=c.color[name], lw=1, label=c.label(name))
        ax.axhline(0, color="k", lw=0.6)
        c.faults_shaded(ax, label=True)
        c.finish(ax, f"x̂ − x of {state}{s.unit(state)}", legend=False)
    c.figure_legend(fig, cells)
    c.save(fig, "state_errors", "estimation error per state, x̂ − x")


def error(c: Canvas) -> None:
    """|x − x̂| of every estimator, linear and logarithmic."""
    s = c.series
    fig, axes = c.figure(2, height=2.6, sharex=True)
    linear, log = axes[0, 0], axes[1, 0]
    errors = []
    for name in s.estimators:
        t, err = s.error(name)
        if t.size:
            linear.plot(t, err, color=c.color[name], label=c.label(name), lw=1)
            log.semilogy(t, err, color=c.color[name], label=c.label(name), lw=1)
            errors.append(err)
    log_floor(log, errors)
    for ax in (linear, log):
        c.faults_shaded(ax, label=ax is linear)
    c.finish(linear, f"|x − x̂|{s.norm_unit()}")
    c.finish(log, "|x − x̂| (log scale)", legend=False)
    log.set_xlabel(TIME)
    c.save(fig, "error", "estimation error norm |x − x̂| over the whole state")


def faults(c: Canvas) -> None:
    """What the faults injected: sensor deviations, frames not sent, actuator effectiveness."""
    panels = _fault_panels(c.series)
    if not panels:
        return
    ratios = [0.25 + 0.2 * len(curves) if events_only else 1.0 for _, curves, events_only in panels]
    fig, axes = c.figure(len(panels), height=2.1 * sum(ratios) / len(ratios), sharex=True, height_ratios=ratios)
    for ax, (ylabel, curves, events_only) in zip(axes[:, 0], panels):
        if events_only:  # one row of marks per sensor, at the ticks its frame was not sent
            for row, (times, _) in enumerate(curves.values()):
                ax.plot(times, np.full(len(times), row), "|", ms=8, mew=0.8, color=f"C{row}")
            ax.set_yticks(range(len(curves)), list(curves))
            ax.set_ylim(-0.7, len(curves) - 0.3)
            c.faults_shaded(ax)
            c.finish(ax, ylabel, legend=False)
            continue
        for curve_label, (times, v) in curves.items():
            ax.plot(times, v, lw=1, label=curve_label)
        c.faults_shaded(ax)
        c.finish(ax, ylabel, ncol=min(3, len(curves)))
    for f in c.series.faults:
        axes[0, 0].annotate(
            f" {f['label']} ({f['kind']})",
            (f["start"], 1),
            xycoords=("data", "axes fraction"),
            rotation=90,
            va="top",
            ha="right",
            fontsize=6.5,
            color="0.3",
        )
    axes[-1, 0].set_xlabel(TIME)
    c.save(fig, "faults", "what the faults injected (/truth/faults), each from its onset")


def weights(c: Canvas) -> None:
    """The selector s and optimizer z (TAC 2024), or the weights Γ (CDC 2016), per estimator."""
    s = c.series
    labels = {
        DiagnosticKind.SELECTOR: "selector s",
        DiagnosticKind.OPTIMIZER: "optimizer z",
        DiagnosticKind.WEIGHT: "weights Γ",
    }
    weighted = [
        (name, kind, data) for name in s.estimators for kind in labels for data in [s.diagnostic(name, kind)] if data
    ]
    if not weighted:
        return
    fig, axes = c.figure(len(weighted), height=2.2, sharex=True)
    for ax, (name, kind, (t, w)) in zip(axes[:, 0], weighted):
        for i, sensor in enumerate(s.sensors):
            ax.plot(t, w[:, i], label=f"sensor {sensor}", lw=1)
        c.finish(ax, f"{name}: {labels[kind]} [1]", loc="center right")
    axes[-1, 0].set_xlabel(TIME)
    c.save(fig, "weights", "pseudoinverse weights per sensor")


def effect_of_the_bias(c: Canvas) -> None:
    """|h_Γ|, the fault's part of each observer's output injection."""
    s = c.series
    effects = {name: e for name in s.estimators for e in [bias_effect(s, name)] if e is not None}
    if effects:
        units = set(s.units.get(sensor, "") for sensor in s.sensors)
        unit = f" [{units.pop()}]" if len(units) == 1 and "" not in units else ""
        what = "the fault's effect on the output injection, |h_Γ|"
        c.one_panel(effects, f"|h_Γ|{unit}", what, "bias_effect", log=True)


def gamma_norm(c: Canvas) -> None:
    """|Γ| of the continuous-time observers (CDC 2016 Figs. 5, 10)."""
    norms = {
        name: (t, np.linalg.norm(w, axis=1)) for name, (t, w) in c.series.diagnostics(DiagnosticKind.WEIGHT).items()
    }
    if norms:
        c.one_panel(norms, "|Γ| [1]", "norm of the pseudoinverse weights Γ", "gamma_norm", log=False)


def bias_estimate(c: Canvas) -> None:
    """φ̂ against the true fault (TAC 2024 eq. (7))."""
    s = c.series
    bias = s.diagnostics(DiagnosticKind.BIAS_ESTIMATE)
    if not bias:
        return
    fig, axes = c.figure(len(s.sensors), height=2.0, sharex=True)
    fk = np.array(sorted(s.fault))
    for i, (ax, sensor) in enumerate(zip(axes[:, 0], s.sensors)):
        for name, (t, v) in bias.items():
            ax.plot(t, v[:, i], color=c.color[name], label=f"{name} φ̂", lw=1)
        ax.plot(fk * s.sample_time, [s.fault[k][i] for k in fk], "k--", lw=1, label="true fault φ")
        c.finish(ax, f"φ on {sensor}{s.unit(sensor)}", legend=i == 0)
    axes[-1, 0].set_xlabel(TIME)
    c.save(fig, "bias_estimate", "bias estimates φ̂ against the true sensor fault")


def residual(c: Canvas) -> None:
    """r = y − C x̂ per output and |r| (course notes eq. (10))."""
    s = c.series
    residuals = s.diagnostics(DiagnosticKind.RESIDUAL)
    if not residuals:
        return
    fig, axes = c.figure(2 * len(residuals), height=2.2, sharex=True)
    for i, (name, (t, r)) in enumerate(residuals.items()):
        linear, log = axes[2 * i, 0], axes[2 * i + 1, 0]
        for j, sensor in enumerate(s.sensors):
            linear.plot(t, r[:, j], label=f"r on {sensor}{s.unit(sensor)}", lw=1)
        norm = np.linalg.norm(r, axis=1)
        log.semilogy(t, norm, "k", lw=1, label="|r|")
        log_floor(log, [norm])
        for ax in (linear, log):
            c.faults_shaded(ax, label=ax is log)
        c.finish(linear, f"{name}: r = y − C x̂", ncol=min(3, len(s.sensors)))
        c.finish(log, f"{name}: |r|{s.norm_unit_of(s.sensors)} (log)")
    axes[-1, 0].set_xlabel(TIME)
    c.save(fig, "residual", "residual r = y − C x̂ per output and its norm; faults shaded")


def _reconciliators(s: RunSeries) -> list[str]:
    return sorted(name for name in s.estimators if virtual_output(s, name) is not None)


def gain_estimate(c: Canvas) -> None:
    """γ̂ of the reconciliation schemes against the true gain (IJC 2018 eq. (53), Figs. 6–7)."""
    s = c.series
    gains = s.diagnostics(DiagnosticKind.GAIN_ESTIMATE, _reconciliators(s))
    if not gains:
        return
    fig, axes = c.figure(len(s.sensors), height=1.9, sharex=True)
    t_all = np.array(sorted(s.sensor_truth)) * s.sample_time
    truth = true_gains(s, t_all)
    for i, (ax, sensor) in enumerate(zip(axes[:, 0], s.sensors)):
        for name, (t, g) in sorted(gains.items()):
            ax.plot(t, g[:, i], color=c.color[name], label=f"{name} γ̂", lw=1)
        ax.plot(t_all, truth[:, i], "k--", lw=1, label="true γ")
        c.finish(ax, f"γ of {sensor} [1]", legend=i == 0, ncol=3)
    axes[-1, 0].set_xlabel(TIME)
    c.save(fig, "gain_estimate", "sensor effectiveness γ̂ against the true gain")


def reconciled_output(c: Canvas) -> None:
    """ẑ = H_z ŷ of every scheme against the true z = H_z y (IJC 2018 eq. (6), Fig. 9)."""
    s = c.series
    outputs = {name: v for name in _reconciliators(s) for v in [virtual_output(s, name)] if v is not None}
    if not outputs:
        return
    fig, axes = c.figure(2, height=2.8, sharex=True)
    values, errors = axes[0, 0], axes[1, 0]
    t, _, z = next(iter(outputs.values()))
    values.plot(t, z, "k", lw=1.6, label="true z = H_z y")
    for name, (t, zhat, z) in outputs.items():
        values.plot(t, zhat, color=c.color[name], lw=1, label=f"{name} ẑ")
        errors.semilogy(t, np.maximum(np.abs(zhat - z), 1e-12), color=c.color[name], lw=1, label=name)
    for ax in (values, errors):
        c.faults_shaded(ax)
    c.finish(values, "virtual output z", ncol=2)
    c.finish(errors, "|ẑ − z| (log scale)", ncol=2)
    errors.set_xlabel(TIME)
    c.save(fig, "virtual_output", "reconciled virtual output ẑ against the true z")


def cofd_residuals(c: Canvas) -> None:
    """Each COFD observer's residual components over their thresholds (Cristofaro & Johansen, Figs. 2–4)."""
    diagnosers = [name for name, e in c.series.estimators.items() if e.signals(DiagnosticKind.THRESHOLD)]
    for name in diagnosers:
        _cofd_figure(c, name, "cofd_residuals" if len(diagnosers) == 1 else f"cofd_residuals_{name}")


def _cofd_figure(c: Canvas, name: str, file: str) -> None:
    s = c.series
    e = s.estimators[name]
    bounded = {residual: threshold for threshold, residual in e.signals(DiagnosticKind.THRESHOLD).items()}
    dk = np.array(sorted(k for k, v in e.values.items() if all(t in v for t in bounded.values())), dtype=int)
    if dk.size == 0:
        return
    first = e.values[dk[0]]
    observers: dict[str, list[str]] = {}  # observer → its residual components in use (threshold > 0)
    for residual, observer in e.signals(DiagnosticKind.RESIDUAL).items():
        if residual in bounded and first.get(bounded[residual], 0.0) > 0:
            observers.setdefault(observer, []).append(residual)
    if not observers:
        return
    directions = cofd_directions(s, name)
    t = dk * s.sample_time
    flags = e.signals(DiagnosticKind.ISOLATION)
    raised = ["+".join(target for flag, target in flags.items() if e.values[k].get(flag, 0.0) > 0.5) for k in dk]
    isolations = [(t[i], what) for i, what in enumerate(raised) if what and (i == 0 or what != raised[i - 1])]
    fig, axes = c.figure(len(observers), height=2.2, sharex=True)
    for number, (ax, (observer, components)) in enumerate(zip(axes[:, 0], observers.items())):
        for residual in components:
            ratio = np.array([abs(e.values[k][residual]) / e.values[k][bounded[residual]] for k in dk])
            ax.semilogy(t, np.maximum(ratio, 1e-4), lw=1, label=directions.get(residual, residual))
        ax.axhline(1.0, color="k", lw=0.8, label="threshold" if number == 0 else None)
        c.events(ax, isolations, label=number == 0)
        c.finish(ax, f"{observer}: |r_i| / threshold", loc="upper left", ncol=2)
    axes[-1, 0].set_xlabel(TIME)
    c.save(fig, file, f"{name}, COFD residual components over their thresholds")


def trajectory(c: Canvas) -> None:
    """The true state of a closed loop against time (Cristofaro & Johansen, Figs. 5–6)."""
    s = c.series
    if not s.control:
        return
    t, x = c.truth
    fig, cells = c.state_grid(s.states)
    for i, (ax, state) in enumerate(zip(cells, s.states)):
        ax.plot(t, x[:, i], "k", lw=1, label="true state")
        c.events(ax, label=True)
        c.finish(ax, f"{state}{s.unit(state)}", legend=False)
    c.figure_legend(fig, cells)
    marks = [
        *(["fault onsets dotted"] if s.faults else []),
        *(["reconfiguration dashed"] if c.reconfigured_at is not None else []),
    ]
    c.save(fig, "trajectory", "true state of the closed loop" + (f" ({', '.join(marks)})" if marks else ""))


def planar_path(c: Canvas) -> None:
    """y against x for a plant with planar positions: the true path and each estimate's."""
    s = c.series
    if not {"x", "y"} <= set(s.states):
        return
    ix, iy = s.states.index("x"), s.states.index("y")
    _, x = c.truth
    fig, axes = c.figure(1, height=5.0)
    ax = axes[0, 0]
    ax.plot(x[:, ix], x[:, iy], color="k", lw=1.8, label="true path")
    ax.plot(x[:1, ix], x[:1, iy], "ko", ms=4, label="start")
    for name in s.estimators:
        t, xhat, _ = s.estimate(name)
        if t.size:
            ax.plot(xhat[:, ix], xhat[:, iy], color=c.color[name], lw=1, label=f"{c.label(name)}: x̂")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel(f"x{s.unit('x')}")
    c.finish(ax, f"y{s.unit('y')}")
    c.save(fig, "path", "path in the plane, y against x")


#: Every figure, in the order they are drawn.
FIGURES: tuple[Callable[[Canvas], None], ...] = (
    estimates,
    error,
    faults,
    weights,
    effect_of_the_bias,
    gamma_norm,
    bias_estimate,
    residual,
    gain_estimate,
    reconciled_output,
    cofd_residuals,
    trajectory,
    planar_path,
)


def plot(
    path: str | Path, out: str | Path, fmt: str = "png", dpi: int = 150, warnings: list[str] | None = None
) -> list[Path]:
    """Write the figures of one log into ``out`` as ``fmt`` (png, svg, pdf); returns the files written.
    ``warnings``, if given, gets what the log reader found wrong (damage: the figures end there)."""
    if fmt not in FORMATS:
        raise LogError(f"unknown figure format {fmt!r}: choose png, svg or pdf")
    require("matplotlib", "cosim plot")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if bus_layout.is_imported(path):  # a bus log of another tool (cosim import): a figure per message
        Path(out).mkdir(parents=True, exist_ok=True)
        return bus_layout.plot(path, Path(out), fmt, dpi, STYLE, FORMATS[fmt])
    with plt.rc_context(STYLE):
        series = load(path)
        if warnings is not None:
            warnings.extend(series.warnings)
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        canvas = Canvas(series, out, fmt, dpi)
        for draw in FIGURES:
            draw(canvas)
        return canvas.written


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
