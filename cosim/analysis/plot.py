"""Paper-style figures of a run log: estimates against the truth, errors, faults, and what each estimator publishes.

``cosim plot FILE.mcap [--out DIR] [--format png|svg|pdf] [--dpi N] [--style screen|paper]
[--width single|double|INCHES] [--no-title] [--estimators A,B]`` writes one file per figure
(matplotlib, no display needed; vector formats keep their text as text, PDFs embed their fonts).
Every axis says its quantity and unit (from the log's JSON Schemas); legends sit outside the data
and name estimators, sensors and faults as the scenario does; each series has a look of its own
(colour-blind-safe colour, dashes, marker), an estimator the same in every figure
(``cosim.analysis.canvas``). A screen's figures are saved with their whole bounding box, a paper's
exactly a column wide; nothing is clipped. A curve is broken where its values are missing, and an
axis that leaves a far start-up transient out says so.

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

Each figure is one function of a ``Canvas`` (the log's series, the style, the looks and the shared
drawing helpers: ``cosim.analysis.canvas``) in the table ``FIGURES``; a figure that has nothing to
show draws nothing. The series are read by ``cosim.analysis.series``.
"""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from cosim.analysis import bus_figures, bus_layout
from cosim.analysis.canvas import FORMATS, GAP, PALETTE, TIME, Canvas, Style, gapped, log_floor, log_scale
from cosim.analysis.series import RunSeries, bias_effect, cofd_directions, load, true_gains, virtual_output
from cosim.errors import LogError
from cosim.extras import require
from estimators.base import DiagnosticKind

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure


def one_panel(
    c: Canvas, named: dict[str, tuple[np.ndarray, np.ndarray]], ylabel: str, what: str, name: str, log: bool
) -> None:
    """One panel of one curve per estimator against time."""
    fig, axes = c.figure(1, height=3.0)
    ax = axes[0, 0]
    for est, (t, v) in named.items():
        c.estimator(ax, est, t, v)
    if log:  # a log axis, or where the curves are zero for a while (before the fault) a symmetric one
        ylabel += log_scale(ax, [v for _, v in named.values()])
    ax.set_xlabel(TIME)
    c.faults_shaded(ax)
    c.onsets_named(ax)
    c.finish(ax, ylabel)
    c.legend(fig, [ax])
    c.save(fig, name, what)


def estimates(c: Canvas) -> None:
    """The true state against every estimate, and the error per state."""
    s = c.series
    estimated = {name: v for name in s.estimators for v in [s.estimate(name)] if v[0].size}
    t_true, x = c.truth
    if not t_true.size or not estimated:
        return
    fig, cells = c.state_grid(s.states)
    for i, (ax, state) in enumerate(zip(cells, s.states)):
        c.reference(ax, t_true, x[:, i], "true state x")
        for name, (t, xhat, _) in estimated.items():
            c.estimator(ax, name, t, xhat[:, i])
        in_view(ax, [xhat[:, i] for _, xhat, _ in estimated.values()], x[:, i])
        c.faults_shaded(ax)
        c.finish(ax, f"{state}{s.unit(state)}")
    c.onsets_named(cells[0])
    c.legend(fig, cells)
    c.save(fig, "estimates", "true state and every estimate x̂")

    fig, cells = c.state_grid(s.states)
    for i, (ax, state) in enumerate(zip(cells, s.states)):
        for name, (t, xhat, xt) in estimated.items():
            c.estimator(ax, name, t, xhat[:, i] - xt[:, i])
        in_view(ax, [xhat[:, i] - xt[:, i] for _, xhat, xt in estimated.values()], np.zeros(1))
        ax.axhline(0, color="k", lw=0.6)
        c.faults_shaded(ax)
        c.finish(ax, f"x̂ − x of {state}{s.unit(state)}")
    c.onsets_named(cells[0])
    c.legend(fig, cells)
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
            c.estimator(linear, name, t, err)
            c.estimator(log, name, t, err, log=True)
            errors.append(err)
    log_floor(log, errors)
    labels = (f"|x − x̂|{s.norm_unit()}", "|x − x̂| (log scale)")
    c.finish_pair(fig, (linear, log), labels, "error", "estimation error norm |x − x̂| over the whole state")


def faults(c: Canvas) -> None:
    """What the faults injected: sensor deviations, frames not sent, actuator effectiveness."""
    panels = _fault_panels(c.series)
    if not panels:
        return
    ratios = [0.35 + 0.2 * len(curves) if events_only else 1.0 for _, curves, events_only in panels]
    fig, axes = c.figure(len(panels), height=2.1 * sum(ratios) / len(ratios), sharex=True, height_ratios=ratios)
    drawn = 0  # curves so far: each its own look, across the panels (they share one legend)
    for ax, (ylabel, curves, events_only) in zip(axes[:, 0], panels):
        if events_only:  # one row of marks per sensor, at the ticks its frame was not sent
            for row, (times, _) in enumerate(curves.values()):
                ax.plot(times, np.full(len(times), row), "|", ms=8 * c.style.scale, mew=0.8, color=PALETTE[row % 7])
            ax.set_yticks(range(len(curves)), list(curves))
            ax.set_ylim(-0.7, len(curves) - 0.3)
            ax.set_title(ylabel, loc="left")  # beside the sensors' names a y label would not fit
            ylabel = ""
        for curve_label, (times, v) in () if events_only else curves.items():
            c.curve(ax, times, v, drawn, curve_label)
            drawn += 1
        c.faults_shaded(ax)
        c.finish(ax, ylabel)
    c.onsets_named(axes[0, 0])
    c.finish_column(fig, axes, "faults", "what the faults injected (/truth/faults), each from its onset")


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
            c.curve(ax, t, w[:, i], i, f"sensor {sensor}")
        ax.set_title(name, loc="left")
        c.finish(ax, f"{labels[kind]} [1]")
    c.finish_column(fig, axes, "weights", "pseudoinverse weights per sensor")


def effect_of_the_bias(c: Canvas) -> None:
    """|h_Γ|, the fault's part of each observer's output injection."""
    s = c.series
    effects = {name: e for name in s.estimators for e in [bias_effect(s, name)] if e is not None}
    if effects:
        units = set(s.units.get(sensor, "") for sensor in s.sensors)
        unit = f" [{units.pop()}]" if len(units) == 1 and "" not in units else ""
        what = r"the fault's effect on the output injection, $|h_\Gamma|$"  # mathtext: Γ as a subscript
        one_panel(c, effects, rf"$|h_\Gamma|${unit}", what, "bias_effect", log=True)


def gamma_norm(c: Canvas) -> None:
    """|Γ| of the continuous-time observers (CDC 2016 Figs. 5, 10)."""
    norms = {
        name: (t, np.linalg.norm(w, axis=1)) for name, (t, w) in c.series.diagnostics(DiagnosticKind.WEIGHT).items()
    }
    if norms:
        one_panel(c, norms, "|Γ| [1]", "norm of the pseudoinverse weights Γ", "gamma_norm", log=False)


def bias_estimate(c: Canvas) -> None:
    """φ̂ against the true fault (TAC 2024 eq. (7))."""
    s = c.series
    bias = s.diagnostics(DiagnosticKind.BIAS_ESTIMATE)
    if not bias:
        return
    fk = np.array(sorted(s.fault))
    true = np.array([s.fault[k] for k in fk], dtype=float).reshape(len(fk), len(s.sensors))
    fig, axes = sensor_panels(
        c, bias, (fk * s.sample_time, true, "true fault φ"), lambda sensor: f"φ̂ on {sensor}{s.unit(sensor)}", 2.0, True
    )
    c.finish_column(fig, axes, "bias_estimate", "bias estimates φ̂ against the true sensor fault")


def sensor_panels(
    c: Canvas,
    estimates: dict[str, tuple[np.ndarray, np.ndarray]],
    reference: tuple[np.ndarray, np.ndarray, str],
    ylabel: Callable[[str], str],
    height: float,
    keep_in_view: bool = False,
) -> tuple[Figure, np.ndarray]:
    """A panel per sensor: ``reference`` (its times, its values a column per sensor, its name) and
    each estimator's column of ``estimates``; ``keep_in_view``: the bulk kept in view (``in_view``)."""
    s = c.series
    times, values, label = reference
    fig, axes = c.figure(len(s.sensors), height=height, sharex=True)
    for i, (ax, sensor) in enumerate(zip(axes[:, 0], s.sensors)):
        c.reference(ax, times, values[:, i], label)
        for name, (t, v) in estimates.items():
            c.estimator(ax, name, t, v[:, i])
        if keep_in_view:
            in_view(ax, [v[:, i] for _, v in estimates.values()], values[:, i])
        c.finish(ax, ylabel(sensor))
    return fig, axes


#: How many times the span of what matters the values must span before ``in_view`` leaves some out.
FAR = 20


def in_view(ax: Axes, curves: Sequence[np.ndarray], reference: np.ndarray) -> None:
    """Limits that show zero, ``reference`` and the bulk of ``curves`` (0.5–99.5 % of their values) when
    a few values lie ``FAR`` times as far beyond (φ̂ of TAC 2024 starts at ±10⁴ against a fault of
    1, an estimate at −250 against states of ±3: either would flatten the rest); the panel says
    what is off the axis."""
    values = np.concatenate([np.ravel(v) for v in curves]) if curves else np.zeros(0)
    values = values[np.isfinite(values)]
    if not values.size:
        return
    low, high = np.percentile(values, [0.5, 99.5])
    low, high = min(low, *reference, 0.0), max(high, *reference, 0.0)  # zero: a scale for values that agree
    low, high = low - 0.15 * (high - low or 1.0), high + 0.15 * (high - low or 1.0)
    if values.max() - values.min() <= FAR * (high - low):
        return
    off = int(((values < low) | (values > high)).sum())
    ax.set_ylim(low, high)
    note = f"{off} values off the axis, from {values.min():.3g} to {values.max():.3g}"
    ax.set_title(note, loc="right", fontsize="x-small", color="0.3")  # above the panel, not on its data


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
            c.curve(linear, t, r[:, j], j, f"r on {sensor}{s.unit(sensor)}")
        norm = np.linalg.norm(r, axis=1)
        log.semilogy(*gapped(t, norm, t, GAP * s.sample_time), "k", lw=c.style.line, label="|r|")
        log_floor(log, [norm])
        for ax in (linear, log):
            c.faults_shaded(ax)
        c.finish(linear, f"{name}: r = y − C x̂")
        c.finish(log, f"{name}: |r|{s.norm_unit_of(s.sensors)} (log)")
    c.onsets_named(axes[0, 0])
    c.finish_column(fig, axes, "residual", "residual r = y − C x̂ per output and its norm; faults shaded")


def _reconciliators(s: RunSeries) -> list[str]:
    return [name for name in s.estimators if virtual_output(s, name) is not None]


def gain_estimate(c: Canvas) -> None:
    """γ̂ of the reconciliation schemes against the true gain (IJC 2018 eq. (53), Figs. 6–7)."""
    s = c.series
    gains = s.diagnostics(DiagnosticKind.GAIN_ESTIMATE, _reconciliators(s))
    if not gains:
        return
    t_all = np.array(sorted(s.sensor_truth)) * s.sample_time
    reference = (t_all, true_gains(s, t_all), "true γ")
    fig, axes = sensor_panels(c, gains, reference, lambda sensor: f"γ̂ of {sensor} [1]", 1.9)
    c.finish_column(fig, axes, "gain_estimate", "sensor effectiveness γ̂ against the true gain")


def reconciled_output(c: Canvas) -> None:
    """ẑ = H_z ŷ of every scheme against the true z = H_z y (IJC 2018 eq. (6), Fig. 9)."""
    s = c.series
    outputs = {name: v for name in _reconciliators(s) for v in [virtual_output(s, name)] if v is not None}
    if not outputs:
        return
    fig, axes = c.figure(2, height=2.8, sharex=True)
    values, errors = axes[0, 0], axes[1, 0]
    t, _, z = next(iter(outputs.values()))
    c.reference(values, t, z, "true z = H_z y")
    for name, (t, zhat, z) in outputs.items():
        c.estimator(values, name, t, zhat)
        c.estimator(errors, name, t, np.maximum(np.abs(zhat - z), 1e-12), log=True)
    log_floor(errors, [np.abs(zhat - z) for _, zhat, z in outputs.values()])
    labels = (f"virtual output ẑ{s.norm_unit_of(s.sensors)}", "|ẑ − z| (log scale)")
    c.finish_pair(fig, (values, errors), labels, "virtual_output", "reconciled virtual output ẑ against the true z")


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
    own = []
    for ax, (observer, components) in zip(axes[:, 0], observers.items()):
        labels = [directions.get(residual, residual) for residual in components]
        for j, (residual, label) in enumerate(zip(components, labels)):
            ratio = np.array([abs(e.values[k][residual]) / e.values[k][bounded[residual]] for k in dk])
            c.curve(ax, t, np.maximum(ratio, 1e-4), j, label, log=True)
        ax.axhline(1.0, color="k", lw=0.8 * c.style.line, label="threshold")
        c.events(ax, isolations)
        c.finish(ax, observer)
        c.legend_above(ax, labels)
        own += labels
    fig.supylabel("|r_i| / threshold")
    c.finish_column(fig, axes, file, f"{name}, COFD residual components over their thresholds", leave=own)


def trajectory(c: Canvas) -> None:
    """The true state of a closed loop against time (Cristofaro & Johansen, Figs. 5–6)."""
    s = c.series
    if not s.control:
        return
    t, x = c.truth
    fig, cells = c.state_grid(s.states)
    for i, (ax, state) in enumerate(zip(cells, s.states)):
        ax.plot(t, x[:, i], "k", lw=c.style.line, label="true state")
        c.events(ax)
        c.finish(ax, f"{state}{s.unit(state)}")
    c.legend(fig, cells)
    marks = [
        *(["fault onsets dotted"] if s.faults else []),
        *(["reconfiguration dash-dotted"] if c.reconfigured_at is not None else []),
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
    c.reference(ax, x[:, ix], x[:, iy], "true path")
    ax.plot(x[:1, ix], x[:1, iy], "ko", ms=c.style.marker, label="start")
    for name in s.estimators:
        t, xhat, _ = s.estimate(name)
        if t.size:
            c.estimator(ax, name, xhat[:, ix], xhat[:, iy], along=t)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel(f"x{s.unit('x')}")
    c.finish(ax, f"y{s.unit('y')}")
    c.legend(fig, [ax])
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
    path: str | Path,
    out: str | Path,
    fmt: str = "png",
    dpi: int = 150,
    warnings: list[str] | None = None,
    *,
    style: str = "screen",
    width: str | float | None = None,
    title: bool = True,
    estimators: Sequence[str] | None = None,
) -> list[Path]:
    """Write the figures of one log into ``out`` as ``fmt`` (png, svg, pdf) in ``style`` (screen,
    paper) at ``width`` (single, double, inches; default the style's), with or without titles, of
    all its estimators or those named (in that order); returns the files written. ``warnings``, if
    given, gets what the log reader found wrong (damage: the figures end there)."""
    if fmt not in FORMATS:
        raise LogError(f"unknown figure format {fmt!r}: choose png, svg or pdf")
    require("matplotlib", "cosim plot")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    look = Style.of(style, width)
    if bus_layout.is_imported(path):  # a bus log of another tool (cosim import): a figure per message
        if estimators is not None:
            raise LogError(f"{path}: a bus log of another tool has no estimators to choose (--estimators)")
        return _written_whole(
            Path(out), lambda part: bus_figures.plot(path, part, fmt, dpi, look, title, FORMATS[fmt], warnings)
        )
    series = load(path)
    if warnings is not None:
        warnings.extend(series.warnings)
    if estimators is not None:
        series = series.only(estimators)

    def draw_all(part: Path) -> list[Path]:
        with plt.rc_context(look.rc):
            canvas = Canvas(series, part, fmt, dpi, look, title)
            for draw in FIGURES:
                draw(canvas)
            return canvas.written

    return _written_whole(Path(out), draw_all)


def _written_whole(out: Path, draw: Callable[[Path], list[Path]]) -> list[Path]:
    """The figures ``draw`` writes into a new folder beside ``out``, moved into ``out`` once every
    one is drawn: a plot that fails part way leaves ``out`` as it was."""
    out.parent.mkdir(parents=True, exist_ok=True)
    part = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        written = draw(part)
        out.mkdir(exist_ok=True)
        return [figure.replace(out / figure.name) for figure in written]
    finally:
        shutil.rmtree(part, ignore_errors=True)


def _fault_panels(series: RunSeries) -> list[tuple[str, dict[str, tuple[np.ndarray, np.ndarray]], bool]]:
    """The panels of the faults figure: (y label, curves named by sensor and fault, drawn as steps)."""
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
            curves = {_on(series, series.sensors[i]): (t, values[:, i]) for i in columns}
            panels.append((f"fault on sensor{f' [{unit}]' if unit else ''}", curves, False))
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
            te = ek * series.sample_time
            curves = {_on(series, series.actuators[j], "δ of "): (te, delta[:, j]) for j in changed}
            panels.append(("effectiveness δ [1]", curves, False))
    return panels


def _on(series: RunSeries, target: str, prefix: str = "") -> str:
    """A sensor's or actuator's curve in the faults figure: its name and the faults on it, as the
    scenario names them (``x1: bias, drift``)."""
    names = [f["label"] for f in series.faults if f.get("targets") is None or target in f["targets"]]
    return f"{prefix}{target}" + (f": {', '.join(names)}" if names else "")
