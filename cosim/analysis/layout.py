"""Foxglove layouts for a run: what to plot, found from the run's record and its CAN database.

``cosim layout LOG|SCENARIO --out FILE.json`` writes a layout in the format Foxglove exports and
imports (Layouts → Import from file): ``configById`` (the panels), ``layout`` (their arrangement),
``userNodes`` (user scripts), ``globalVariables``, ``playbackConfig``. One tab per subject:

- **estimates**: per state, the truth (``/truth/state.<state>``) against every estimator's
  estimate (``/can/EST_<estimator>[_n].xhat_<state>``, whichever frame carries it);
- **errors**: per state, x̂ − x of every estimator, computed by a user script from the truth and the
  estimates of the same tick (its output topic is ``ERRORS_TOPIC``, fields ``<estimator>.<state>``);
- **faults**: what the fault layer added to each sensor (``/truth/faults.fault.<sensor>``), the
  reading sent against the true one for each faulted sensor, the actuator effectiveness δ and the
  commanded against the effective input of each faulted actuator;
- **diagnosis** (estimators that publish diagnostics): alarms and isolation flags as state
  transitions, residuals with their thresholds, bias estimates φ̂ and gain estimates γ̂ against
  the true fault, the controller's status;
- **trajectory** (plants with planar positions ``x`` and ``y``): y against x, and the heading.

Series are labelled with the stable names of ``cosim.analysis.names`` (``kalman.xhat_x1``) and
plotted against the message's log time (simulated time, or the run's wall clock in the live view).
Every message path is a topic and field of the run's log (``paths`` lists them; the tests resolve
each one against real logs of every built-in scenario), but the errors', which the script writes.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cosim.analysis import names
from cosim.bus.codec import Codec, estimate_signal
from cosim.errors import LogError
from cosim.log.metadata import LogMetadata, RunRecord, logged_dbc
from cosim.log.reader import LogReader
from cosim.log.recorder import FAULTS, INPUTS, SENSORS, STATE, message_topic
from estimators.base import DiagnosticKind

#: The user script's output: x̂ − x per estimator and state (``<topic>.<estimator>.<state>``).
ERRORS_TOPIC = "/studio_script/cosim_errors"
#: Series colours (matplotlib's tab10, the figures' colours); the truth is black.
COLORS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22")
TRUTH = "#222222"


@dataclass
class RunSignals:
    """What a layout needs to know about a run: its names, units, and which topic carries which signal."""

    scenario: str
    states: list[str]
    sensors: list[str]
    actuators: list[str]
    units: dict[str, str]
    """unit per state, sensor and actuator name"""
    run: RunRecord
    topics: dict[str, dict[str, str]] = field(default_factory=dict)
    """node (estimator, client, ``controller``) → signal → the decoded topic carrying it"""
    known: dict[str, str] = field(default_factory=dict)
    """topic → the stable name prefix of its fields (``cosim.analysis.names``)"""

    @classmethod
    def of(cls, run: RunRecord, codec: Codec, units: dict[str, str]) -> RunSignals:
        known = names.node_prefixes(codec)
        topics: dict[str, dict[str, str]] = {}
        for spec in codec.specs.values():
            topic = message_topic(spec.name)
            if topic in known:
                for signal in spec.signals:
                    topics.setdefault(spec.sender, {})[signal] = topic
        return cls(
            run.scenario or "run",
            run.states,
            run.sensors,
            run.actuators,
            units,
            run,
            topics,
            {**known, **names.TRUTH_PREFIX},
        )

    def path(self, node: str, signal: str) -> str | None:
        """The message path of a node's signal, or None if its frames do not carry it."""
        topic = self.topics.get(node, {}).get(signal)
        return None if topic is None else f"{topic}.{signal}"

    def label(self, node: str, signal: str) -> str:
        topic = self.topics.get(node, {}).get(signal)
        return names.signal_name(topic, signal, self.known) if topic else f"{node}.{signal}"

    def unit(self, name: str) -> str:
        return self.units.get(name, "")


def signals_of_log(path: str | Path) -> RunSignals:
    """What a layout needs, from a log's ``cosim.run`` record, DBC and schemas."""
    with LogReader(path) as reader:
        run = LogMetadata.read(reader.metadata()).run
        if run is None:
            raise LogError(
                f"{path}: no cosim.run metadata: not a log of 'cosim run', so there is nothing to lay out (give the "
                "scenario's name instead)"
            )
        dbc = logged_dbc(reader)
        schemas = reader.schemas()
    return RunSignals.of(run, Codec.from_dbc(dbc), names.units(schemas))


# -- panels ----------------------------------------------------------------------------------------


def _series(path: str, label: str, color: str, width: float = 1.5) -> dict[str, Any]:
    return {
        "value": path,
        "enabled": True,
        "timestampMethod": "receiveTime",
        "label": label,
        "color": color,
        "showLine": True,
        "lineSize": width,
    }


def _against(
    panel: str, quantity: str, what: str, unit: str, truth: tuple[str, str], other: tuple[str, str]
) -> tuple[str, dict[str, Any]]:
    """A plot panel of one quantity: its true value (black, thick) against another (path, label each)."""
    title = f"{quantity}{f' [{unit}]' if unit else ''}: {what}"
    return f"Plot!{panel}", _plot(title, [_series(*truth, TRUTH, 2), _series(*other, COLORS[3])], unit)


def _plot(title: str, series: list[dict[str, Any]], unit: str = "", **extra: Any) -> dict[str, Any]:
    return {
        "foxglovePanelTitle": title,
        "paths": series,
        "showXAxisLabels": True,
        "showYAxisLabels": True,
        "showLegend": True,
        "legendDisplay": "floating",
        "showPlotValuesInLegend": True,
        "isSynced": True,
        "xAxisVal": "timestamp",
        "yAxisLabel": unit,
        "sidebarDimension": 240,
        **extra,
    }


def _transitions(title: str, series: list[tuple[str, str]]) -> dict[str, Any]:
    return {
        "foxglovePanelTitle": title,
        "paths": [{"value": path, "timestampMethod": "receiveTime", "label": label} for path, label in series],
        "isSynced": True,
        "showPoints": False,
    }


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "-", text).strip("-")


class _Builder:
    def __init__(self) -> None:
        self.panels: dict[str, dict[str, Any]] = {}
        self.tabs: list[tuple[str, list[str]]] = []

    def tab(self, title: str, panels: Iterable[tuple[str, dict[str, Any]]]) -> None:
        ids = []
        for kind_and_name, config in panels:
            key = f"{kind_and_name.split('!')[0]}!{_slug(title)}-{_slug(kind_and_name.split('!', 1)[1])}"
            self.panels[key] = config
            ids.append(key)
        if ids:
            self.tabs.append((title, ids))


def _tree(ids: list[str], direction: str = "column") -> Any:
    """A mosaic tree laying ``ids`` out in equal parts, alternating columns and rows."""
    if len(ids) == 1:
        return ids[0]
    half = (len(ids) + 1) // 2
    other = "row" if direction == "column" else "column"
    return {
        "direction": direction,
        "first": _tree(ids[:half], other),
        "second": _tree(ids[half:], other),
        "splitPercentage": round(100 * half / len(ids), 1),
    }


def build(signals: RunSignals) -> dict[str, Any]:
    """The Foxglove layout of a run (a dict in the format of Foxglove's layout files)."""
    run, b = signals.run, _Builder()
    estimators = list(run.estimators)
    color = {name: COLORS[i % len(COLORS)] for i, name in enumerate(estimators)}

    estimates, errors = [], []
    for state in signals.states:
        unit = signals.unit(state)
        suffix = f" [{unit}]" if unit else ""
        series = [_series(f"{STATE}.{state}", f"state.{state} (truth)", TRUTH, 2)]
        error_series = []
        for name in estimators:
            path = signals.path(name, estimate_signal(state))
            if path is not None:
                series.append(_series(path, signals.label(name, estimate_signal(state)), color[name]))
                error_series.append(_series(f"{ERRORS_TOPIC}.{name}.{state}", f"{name}.{state} error", color[name]))
        estimates.append((f"Plot!{state}", _plot(f"{state}{suffix}: truth and estimates", series, unit)))
        if error_series:
            errors.append(
                (f"Plot!{state}", _plot(f"{state}{suffix}: estimation error x̂ − x (user script)", error_series, unit))
            )
    b.tab("estimates", estimates)
    b.tab("errors", errors)
    b.tab("faults", _fault_panels(signals))
    b.tab("diagnosis", _diagnosis_panels(signals, color))
    if {"x", "y"} <= set(signals.states):
        b.tab("trajectory", _trajectory_panels(signals))

    tab_config = {"activeTabIdx": 0, "tabs": [{"title": title, "layout": _tree(ids)} for title, ids in b.tabs]}
    configs = {"Tab!cosim": tab_config, **b.panels}
    script = _errors_script(signals) if errors else None
    return {
        "configById": configs,
        "globalVariables": {},
        "userNodes": {}
        if script is None
        else {"cosim-errors": {"name": "cosim: estimation errors", "sourceCode": script}},
        "playbackConfig": {"speed": 1},
        "layout": "Tab!cosim",
    }


def _fault_panels(signals: RunSignals) -> list[tuple[str, dict[str, Any]]]:
    run = signals.run
    targets = {t for f in run.faults for t in (f.targets or [])}
    sensor_faults = [s for s in signals.sensors if s in targets] or signals.sensors
    actuator_faults = [a for a in signals.actuators if a in targets]
    panels = []
    if sensor_faults:
        panels.append(
            (
                "Plot!sensor-faults",
                _plot(
                    "deviation the faults add to each sensor (faults.fault)",
                    [
                        _series(
                            f"{FAULTS}.fault.{s}",
                            f"faults.fault.{s}" + (f" [{signals.unit(s)}]" if signals.unit(s) else ""),
                            COLORS[i % len(COLORS)],
                        )
                        for i, s in enumerate(sensor_faults)
                    ],
                ),
            )
        )
    for sensor in [s for s in signals.sensors if s in targets]:
        true = (f"{SENSORS}.{sensor}", f"sensors.{sensor} (true)")
        sent = (f"{FAULTS}.measured.{sensor}", f"faults.measured.{sensor} (sent)")
        what = "sent on the bus against the true reading"
        panels.append(_against(f"sensor-{sensor}", sensor, what, signals.unit(sensor), true, sent))
    if actuator_faults:
        panels.append(
            (
                "Plot!effectiveness",
                _plot(
                    "actuator effectiveness δ (1: healthy)",
                    [
                        _series(f"{FAULTS}.effectiveness.{a}", f"faults.effectiveness.{a}", COLORS[i % len(COLORS)])
                        for i, a in enumerate(actuator_faults)
                    ],
                ),
            )
        )
        for actuator in actuator_faults:
            commanded = (f"{INPUTS}.commanded.{actuator}", f"inputs.commanded.{actuator}")
            effective = (f"{INPUTS}.effective.{actuator}", f"inputs.effective.{actuator}")
            what = "commanded against effective input"
            panels.append(
                _against(f"actuator-{actuator}", actuator, what, signals.unit(actuator), commanded, effective)
            )
    return panels


def _diagnosis_panels(signals: RunSignals, color: dict[str, str]) -> list[tuple[str, dict[str, Any]]]:
    """The diagnosis: a state-transitions panel of every flag (alarms, isolations, constraints, the
    controller's reconfiguration) first, then each estimator's residuals and estimates, then the
    controller's status."""
    panels: list[tuple[str, dict[str, Any]]] = []
    flags: list[tuple[str, str]] = []
    for name, e in signals.run.estimators.items():
        by_kind: dict[str, list[tuple[str, str]]] = {}
        for signal, d in e.diagnostics.items():
            if signals.path(name, signal) is not None:
                by_kind.setdefault(d.kind, []).append((signal, d.target))
        for kind in (DiagnosticKind.ALARM, DiagnosticKind.ISOLATION, DiagnosticKind.CONSTRAINT):
            flags += [(p, signals.label(name, s)) for s, _ in by_kind.get(kind, []) if (p := signals.path(name, s))]
        panels += _residual_panels(signals, name, by_kind) + _estimate_panels(signals, name, by_kind)
    controller_panels, controller_flags = _controller_panels(signals)
    panels += controller_panels
    flags += controller_flags
    if flags:
        panels.insert(
            0, ("StateTransitions!flags", _transitions("diagnosis flags (alarm, isolations, reconfiguration)", flags))
        )
    return panels


def _residual_panels(
    signals: RunSignals, name: str, by_kind: dict[str, list[tuple[str, str]]]
) -> list[tuple[str, dict[str, Any]]]:
    """An estimator's residuals with their thresholds: a panel per observer (COFD), or one (UIO)."""
    thresholds = {target: signal for signal, target in by_kind.get(DiagnosticKind.THRESHOLD, [])}
    groups: dict[str, list[tuple[str, str]]] = {}
    for signal, target in by_kind.get(DiagnosticKind.RESIDUAL, []):
        groups.setdefault(target if thresholds else "", []).append((signal, target))
    panels = []
    for group, members in groups.items():
        series = []
        for i, (signal, _) in enumerate(members):
            series.append(
                _series(signals.path(name, signal) or "", signals.label(name, signal), COLORS[i % len(COLORS)])
            )
            if signal in thresholds and (p := signals.path(name, thresholds[signal])):
                series.append(_series(p, signals.label(name, thresholds[signal]), COLORS[i % len(COLORS)], 0.8))
        what = f"{group} residual components and their thresholds" if group else "residual r = y − C x̂"
        panels.append((f"Plot!{name}-residual-{group}", _plot(f"{name}: {what}", series)))
    return panels


def _estimate_panels(
    signals: RunSignals, name: str, by_kind: dict[str, list[tuple[str, str]]]
) -> list[tuple[str, dict[str, Any]]]:
    """An estimator's bias estimates (against the true fault), gain estimates and virtual output."""
    panels = []
    for kind, what, truth in (
        (DiagnosticKind.BIAS_ESTIMATE, "bias estimates φ̂ against the true fault", f"{FAULTS}.fault"),
        (DiagnosticKind.GAIN_ESTIMATE, "sensor effectiveness estimates γ̂", None),
        (DiagnosticKind.VIRTUAL_OUTPUT, "reconciled virtual output ẑ", None),
    ):
        members = by_kind.get(kind, [])
        if not members:
            continue
        series = []
        for i, (signal, target) in enumerate(members):
            series.append(
                _series(signals.path(name, signal) or "", signals.label(name, signal), COLORS[i % len(COLORS)])
            )
            if truth is not None and target in signals.sensors:
                series.append(
                    _series(f"{truth}.{target}", f"faults.fault.{target} (true)", COLORS[i % len(COLORS)], 0.8)
                )
        panels.append((f"Plot!{name}-{kind}", _plot(f"{name}: {what}", series)))
    return panels


def _controller_panels(signals: RunSignals) -> tuple[list[tuple[str, dict[str, Any]]], list[tuple[str, str]]]:
    """The controller's status panel (its efforts), and its reconfiguration flags."""
    controller = signals.run.controller
    if controller is None:
        return [], []
    status = [
        (signal, d) for signal, d in controller.diagnostics.items() if signals.path("controller", signal) is not None
    ]
    flags = [
        (signals.path("controller", signal) or "", signals.label("controller", signal))
        for signal, d in status
        if d.kind == DiagnosticKind.RECONFIGURATION
    ]
    efforts = [(s, d) for s, d in status if d.kind != DiagnosticKind.RECONFIGURATION]
    if not efforts:
        return [], flags
    series = [
        _series(
            signals.path("controller", s) or "",
            signals.label("controller", s) + (f" [{d.unit}]" if d.unit else ""),
            COLORS[i % len(COLORS)],
        )
        for i, (s, d) in enumerate(efforts)
    ]
    return [("Plot!controller", _plot("controller status", series))], flags


def _trajectory_panels(signals: RunSignals) -> list[tuple[str, dict[str, Any]]]:
    unit = signals.unit("x")
    panels = [
        (
            "Plot!xy",
            _plot(
                f"trajectory: y against x{f' [{unit}]' if unit else ''}",
                [_series(f"{STATE}.y", "state.y against state.x", TRUTH, 2)],
                signals.unit("y"),
                xAxisVal="custom",
                xAxisPath={"value": f"{STATE}.x", "enabled": True},
            ),
        )
    ]
    heading = next((s for s in ("psi", "heading", "yaw") if s in signals.states), None)
    if heading is not None:
        unit = signals.unit(heading)
        panels.append(
            (
                "Plot!heading",
                _plot(
                    f"heading {heading}{f' [{unit}]' if unit else ''}",
                    [_series(f"{STATE}.{heading}", f"state.{heading}", TRUTH, 2)],
                    unit,
                ),
            )
        )
    return panels


def _errors_script(signals: RunSignals) -> str:
    """A Foxglove user script: x̂ − x per estimator and state, matching estimates to the truth by tick."""
    table: dict[str, list[list[str]]] = {}
    for name in signals.run.estimators:
        for state in signals.states:
            topic = signals.topics.get(name, {}).get(estimate_signal(state))
            if topic is not None:
                table.setdefault(topic, []).append([estimate_signal(state), state, name])
    inputs = [STATE, *table]
    return f"""// cosim layout: the estimation error x̂ − x of every estimator, per state, matched to the truth by tick.
// Inputs: the truth and the estimators' frames; output: {{ tick, <estimator>: {{ <state>: error }} }}.
export const inputs = {json.dumps(inputs)};
export const output = "{ERRORS_TOPIC}";

type Fields = {{ [name: string]: number }};
type Event = {{ topic: string; message: unknown }};

// decoded topic -> [estimate signal, state, estimator]
const ESTIMATES: {{ [topic: string]: [string, string, string][] }} = {json.dumps(table)};
const MODULUS = 65536; // classic CAN carries k mod 2^16
const truth = new Map<number, Fields>();

export default function script(event: Event): {{ [name: string]: number | Fields }} | undefined {{
  const message = event.message as Fields;
  if (event.topic === "{STATE}") {{
    truth.set(message["tick"] % MODULUS, message);
    if (truth.size > 512) {{
      const oldest = truth.keys().next().value;
      if (oldest !== undefined) truth.delete(oldest);
    }}
    return undefined;
  }}
  const x = truth.get(message["tick"] % MODULUS);
  if (x === undefined) return undefined;
  const out: {{ [name: string]: number | Fields }} = {{ tick: x["tick"] }};
  for (const [signal, state, estimator] of ESTIMATES[event.topic] ?? []) {{
    const errors = (out[estimator] ?? {{}}) as Fields;
    errors[state] = message[signal] - x[state];
    out[estimator] = errors;
  }}
  return out;
}}
"""


def paths(layout: dict[str, Any]) -> list[str]:
    """Every message path a layout's panels read (series and custom x axes)."""
    found = []
    for config in layout["configById"].values():
        found += [p["value"] for p in config.get("paths", [])]
        if isinstance(config.get("xAxisPath"), dict):
            found.append(config["xAxisPath"]["value"])
    return found


def write(layout: dict[str, Any], out: str | Path) -> Path:
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(layout, indent=2, ensure_ascii=False) + "\n", encoding="utf-8")
    return out
