"""One self-contained HTML page of a run log: what ran, how well each estimator did, the figures of ``cosim plot``.

``cosim report FILE.mcap --out report.html`` writes a page that needs nothing else to be read: the
figures are inlined as base64 PNG, the style sheet is inline, and the page loads no script, font or
image from anywhere. It reads on a laptop and on a phone: tables fit the screen (on a phone each
row becomes a card of labelled values), figures shrink to its width, long names wrap.

The page, in the order a reader needs it (``templates/report.html.j2``, jinja2):

1. the run: scenario, description, when it ran, status, duration, seed, plant, bus, settings;
2. the faults (kind, targets, window, onset and clearance);
3. the estimators: parameters, then the error of each, |x − x̂| over the whole state (its unit,
   or the units it mixes) and per state in its own unit, then each fault's peak and recovery;
4. diagnosis (detection and isolation per fault, false alarms);
5. the figures, each with a caption saying what it shows;
6. the bus (load in %, bit rates, frames per id) and the log (topics as they are, message counts,
   folded away), then any metric this page does not know yet, so that a metric added to
   ``cosim.analysis.metrics`` shows up here.

Every number that has a unit carries it; names (topics, estimators, metric keys) are shown as
they are written.
"""

from __future__ import annotations

import base64
import json
import math
import tempfile
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from cosim import __version__
from cosim.errors import CosimError
from cosim.extras import MissingExtra
from cosim.log.metadata import LogMetadata, RunRecord, ScenarioRecord
from cosim.log.reader import LogReader

#: What each figure of ``cosim plot`` shows (the file names are plot.py's).
CAPTIONS = {
    "estimates": "Every state of the plant (black) against each estimator's estimate x̂, in the state's unit; "
    "the shaded spans are the faults' windows, from their onsets (dotted).",
    "state_errors": "The estimation error x̂ − x of every estimator, one panel per state, each in its own unit.",
    "error": "The estimation error |x − x̂| over the whole state (the norm the metrics score), linear (top) and "
    "logarithmic (bottom); where the states' units differ the norm mixes them.",
    "faults": "What the faults injected, from the log's truth: the deviation added to each sensor reading, the "
    "frames that were not sent, and each actuator's effectiveness δ, with every fault's onset marked.",
    "weights": "The pseudoinverse weights per sensor: the selector s and optimizer z (TAC 2024) or the weights Γ "
    "(CDC 2016); a weight going to 0 discards its sensor.",
    "bias_effect": "|h_Γ|: the part of each observer's output injection due to the true fault (logarithmic); it "
    "vanishes when the weights reject the fault.",
    "gamma_norm": "|Γ|: the norm of the weights of the continuous-time observers (CDC 2016).",
    "bias_estimate": "The bias estimates φ̂ against the true fault φ added to each sensor.",
    "residual": "The residual r = y − C x̂ per output and its norm (logarithmic), with every fault's window shaded.",
    "gain_estimate": "The estimated sensor effectiveness γ̂ of the reconciliation schemes against the true gain.",
    "virtual_output": "The reconciled virtual output ẑ of every scheme against the true z = H_z y, and |ẑ − z|.",
    "cofd_residuals": "Each COFD observer's residual components over their thresholds (logarithmic; above 1 the "
    "component exceeds its threshold), named by the input whose fault drives them, with fault onsets, "
    "isolations and the controller's reconfiguration.",
    "trajectory": "The true state of the closed loop against time, with fault onsets and the controller's "
    "reconfiguration, if it happened.",
}

#: Metric keys this page lays out in its own sections; the rest go to "Other metrics".
_SHOWN = {
    "file",
    "scenario",
    "source",
    "seed",
    "status",
    "sample_time",
    "ticks",
    "duration_s",
    "time_span_s",
    "channels",
    "frames",
    "fault_onset",
    "faults",
    "estimators",
    "baseline",
    "diagnosis",
    "bus",
    "warnings",
    "missing",
}


def metrics(path: str | Path) -> dict[str, Any]:
    """The log's metrics (``cosim.analysis.metrics.compute_metrics``)."""
    from cosim.analysis.metrics import compute_metrics

    return compute_metrics(path)


# -- cells and tables -----------------------------------------------------------------------------


@dataclass
class Cell:
    text: str
    num: bool = False


@dataclass
class Table:
    """A table of the page: its columns and its rows of cells (the first cell names the row)."""

    title: str
    columns: list[str]
    rows: list[list[Cell]]
    note: str = ""
    id: str = ""
    folded: bool = False
    """shown folded away (a <details> the reader opens)"""


@dataclass
class Page:
    title: str
    lead: str
    description: str
    facts: list[tuple[str, str]]
    notes: list[str]
    sections: dict[str, list[Table]] = field(default_factory=dict)
    figures: list[dict[str, str]] = field(default_factory=list)
    footer: str = ""


def number(value: Any, unit: str = "", digits: int = 4) -> Cell:
    """A number with its unit: ``0.9185 m``; – for none."""
    if value is None or isinstance(value, bool) or not isinstance(value, (int, float)):
        return Cell(_format(value), isinstance(value, (int, float)) and not isinstance(value, bool))
    if isinstance(value, float) and not math.isfinite(value):
        return Cell("–", True)
    text = f"{value:.{digits}g}" if isinstance(value, float) else str(value)
    return Cell(f"{text} {unit}".rstrip() if unit else text, True)


def percent(value: Any) -> Cell:
    return Cell("–", True) if value is None else Cell(f"{100 * value:.2f} %", True)


def text(value: Any) -> Cell:
    return Cell(_format(value))


def _format(value: Any) -> str:
    if value is None:
        return "–"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return "–" if math.isnan(value) else f"{value:.4g}"
    if isinstance(value, list):
        return ", ".join(_format(v) for v in value) or "none"
    if isinstance(value, dict):
        return ", ".join(f"{k}: {_format(v)}" for k, v in value.items()) or "none"
    return str(value)


def _unit_of_key(key: str) -> str:
    """The unit a metric's key says it has (``..._s``, ``..._per_hour``), for metrics this page does not know."""
    if key.endswith("_s") or key in ("sample_time", "fault_onset"):
        return "s"
    if key.endswith("_per_hour"):
        return "1/h"
    return ""


def _bitrate(value: Any) -> Cell:
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        return Cell("–", True)
    return Cell(f"{value / 1e6:g} Mbit/s" if value >= 1e6 else f"{value / 1e3:g} kbit/s", True)


# -- the page -------------------------------------------------------------------------------------


def report(path: str | Path, out: str | Path) -> Path:
    """Write the HTML report of one log to ``out``; returns ``out``."""
    path, out = Path(path), Path(out)
    with LogReader(path) as reader:
        meta = LogMetadata.read(reader.metadata())
    values = metrics(path)
    notes = [*values.get("warnings", []), *(f"missing: {m}" for m in values.get("missing", []))]
    figures, figure_note, series = _figures(path)
    if figure_note:
        notes.append(figure_note)
    run = meta.run
    resolved = (meta.scenario or ScenarioRecord()).resolved_json()
    scenario = (run.scenario if run else None) or path.stem
    page = Page(
        title=f"{scenario}: run report",
        lead=f"{path.name} · status {values.get('status', 'unknown')}",
        description=str(resolved.get("description", "")),
        facts=_facts(meta, values),
        notes=notes,
        figures=figures,
        footer=f"cosim {__version__} · cosim report {path.name}",
    )
    norm = _norm_unit(series)
    page.sections["faults"] = _faults(values, run)
    page.sections["estimators"] = _estimators(values, run, resolved, series, norm)
    page.sections["diagnosis"] = _diagnosis(values)
    page.sections["bus"] = _bus(values)
    page.sections["log"] = _log(values)
    page.sections["other"] = _other(values)
    html = _template().render(page=page, no_run=run is None)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(html, encoding="utf-8")
    return out


def _template():
    import jinja2

    environment = jinja2.Environment(
        loader=jinja2.PackageLoader("cosim.analysis", "templates"),
        autoescape=True,
        trim_blocks=True,
        lstrip_blocks=True,
        undefined=jinja2.StrictUndefined,
    )
    return environment.get_template("report.html.j2")


def _facts(meta: LogMetadata, values: dict[str, Any]) -> list[tuple[str, str]]:
    """The run at a glance: what, when, how long, on which bus."""
    run = meta.run
    if run is None:
        return []
    bus, timing = run.bus, run.timing
    sample_time, ticks = run.sample_time or math.nan, run.ticks or 0
    facts = [("scenario", f"{run.scenario} ({run.source})")]
    if run.start_time_ns:
        when = datetime.fromtimestamp(run.start_time_ns / 1e9, UTC)
        facts.append(("started", when.strftime("%Y-%m-%d %H:%M:%S UTC")))
    facts += [
        ("status", str(values.get("status", "unknown"))),
        ("duration", f"{ticks * sample_time:g} s: {ticks} ticks of τ = {sample_time:g} s"),
        ("seed", str(run.seed)),
        ("plant", str(run.plant)),
        ("states", ", ".join(run.states)),
        ("sensors", ", ".join(run.sensors)),
        ("actuators", ", ".join(run.actuators) or "none"),
    ]
    if run.disturbances:
        facts.append(("unknown inputs", ", ".join(run.disturbances)))
    rate = _bitrate(bus.get("bitrate")).text
    data = f", data phase {_bitrate(bus.get('data_bitrate')).text}" if bus.get("fd") else ""
    facts.append(
        (
            "bus",
            f"{'CAN FD' if bus.get('fd') else 'classic CAN'} at {rate}{data}, "
            f"{meta.bus.get('interface', bus.get('interface', '?'))}",
        )
    )
    facts.append(
        (
            "timing",
            timing.get("mode", "?") + (f" at {timing.get('speed'):g}×" if timing.get("mode") == "realtime" else ""),
        )
    )
    frames = values.get("frames") or {}
    facts.append(("frames", f"{frames.get('total', '–')} on the bus, {frames.get('lost', '–')} lost"))
    settings = json.loads((meta.scenario or ScenarioRecord()).settings or "[]")
    if settings:
        facts.append(("settings", ", ".join(f"{key} = {json.dumps(value)}" for key, value in settings)))
    replay = meta.replay
    if replay:
        what = "a new estimator" if replay.new else "an estimator of the run"
        facts.append(
            (
                "replay",
                f"of {replay.log}: {replay.estimator} ({replay.kind}), {what}"
                + (f", with {_compact(replay.params)}" if replay.params else ""),
            )
        )
    return facts


def _norm_unit(series: Any) -> str:
    """The unit of the error norm: the states' common unit, or "" when they differ."""
    if series is None:
        return ""
    units = {series.units.get(s, "") for s in series.states}
    return units.pop() if len(units) == 1 else ""


def _norm_note(series: Any) -> str:
    if series is None:
        return ""
    units = list(dict.fromkeys(series.units.get(s, "") or "1" for s in series.states))
    if len(units) <= 1:
        return ""
    return (
        f"|x − x̂| is the Euclidean norm over {', '.join(f'{s} [{series.units.get(s) or 1}]' for s in series.states)}: "
        f"it mixes {' and '.join(units)}, so its values carry no single unit; the table below gives each state's "
        "error in its own unit."
    )


def _faults(values: dict[str, Any], run: RunRecord | None) -> list[Table]:
    faults = values.get("faults") or {}
    if not faults:
        return []
    rows = [
        [
            text(label),
            text(f.get("kind")),
            text(f.get("targets")),
            number(f.get("start"), "s"),
            Cell("end of run") if f.get("end") is None else number(f.get("end"), "s"),
            number(f.get("onset"), "s"),
            Cell("not cleared" if f.get("onset") is not None else "–")
            if f.get("cleared") is None
            else number(f.get("cleared"), "s"),
        ]
        for label, f in faults.items()
    ]
    return [
        Table(
            "",
            ["fault", "kind", "acts on", "starts", "ends", "first active", "cleared"],
            rows,
            "Onset and clearance are read from the truth (/truth/faults): the first tick a fault is active, and the "
            "first after it that it is not.",
            id="faults",
        )
    ]


def _estimators(
    values: dict[str, Any], run: RunRecord | None, resolved: dict[str, Any], series: Any, norm: str
) -> list[Table]:
    found = values.get("estimators") or {}
    tables: list[Table] = []
    given = {e.get("name"): e.get("params", {}) for e in resolved.get("estimators", [])}
    if run is not None and run.estimators:
        tables.append(
            Table(
                "Parameters",
                ["estimator", "kind", "parameters given"],
                [
                    [text(name), text(e.kind), Cell(_compact(given.get(name, {})) or "defaults")]
                    for name, e in run.estimators.items()
                ],
                id="estimator-list",
            )
        )
    if not found:
        return tables
    unit = f" [{norm}]" if norm else ""
    baseline = values.get("baseline")
    rows = []
    for name, e in found.items():
        rows.append(
            [
                text(name),
                text(e.get("kind")),
                number(e.get("rms_pre_fault"), norm),
                number(e.get("rms_post_fault"), norm),
                number(e.get("final_error"), norm),
                number(e.get("band"), norm),
                number(e.get("bias_rejection_ratio"), "× baseline" if baseline else ""),
                number(e.get("ticks_scored")),
            ]
        )
    onset = values.get("fault_onset")
    when = (
        f"the first fault's onset ({onset:g} s)" if isinstance(onset, (int, float)) else "the first fault (none here)"
    )
    tables.append(
        Table(
            "Estimation error |x − x̂|",
            [
                "estimator",
                "kind",
                f"RMS before fault{unit}",
                f"RMS after fault{unit}",
                f"final{unit}",
                f"band{unit}",
                "bias rejection",
                "ticks scored",
            ],
            rows,
            " ".join(
                part
                for part in (
                    f"RMS over the ticks before and from {when}; band: twice the largest error in the second half "
                    "of the fault-free window; bias rejection: RMS after fault over that of the uniform-weight baseline"
                    + (f" ({baseline})" if baseline else " (none in this run)")
                    + " (docs/metrics.md).",
                    _norm_note(series),
                )
                if part
            ),
            id="estimation",
        )
    )
    states = _per_state(series, onset)
    if states:
        tables.append(
            Table(
                "Error per state, x̂ − x",
                ["estimator", "state", "RMS before fault", "RMS after fault", "final", "largest |x̂ − x|"],
                states,
                "Each state's error in its own unit (from the logged truth and estimates).",
                id="per-state",
            )
        )
    known = {"kind", "rms_pre_fault", "rms_post_fault", "final_error", "band", "bias_rejection_ratio", "ticks_scored"}
    more = {name: {k: v for k, v in e.items() if k not in known and k != "faults"} for name, e in found.items()}
    if any(more.values()):  # metrics of an estimator this page has no column for, as they are
        tables += _generic("More estimator metrics", {name: extra for name, extra in more.items() if extra})
    per_fault = [
        [
            text(f"{name} · {label}"),
            number(f.get("peak_error"), norm),
            number(f.get("peak_at"), "s"),
            (number(f.get("recovery_time"), "s") if f.get("recovered") else Cell("not recovered")),
        ]
        for name, e in found.items()
        for label, f in (e.get("faults") or {}).items()
    ]
    if per_fault:
        tables.append(
            Table(
                "Per fault: peak error and recovery",
                ["estimator · fault", f"peak |x − x̂|{unit}", "peak after onset", "recovery time"],
                per_fault,
                "Within each fault's segment (from its onset to the next onset): the largest error, when it came, and "
                "how long until the error stayed inside the band.",
                id="per-fault",
            )
        )
    return tables


def _per_state(series: Any, onset: Any) -> list[list[Cell]]:
    """Per estimator and state: RMS of x̂_i − x_i before and after the first fault, the final and largest."""
    if series is None:
        return []
    rows = []
    for name in series.estimators:
        t, x_hat, x = series.estimate(name)
        if not t.size:
            continue
        error = x_hat - x
        before = t < onset if isinstance(onset, (int, float)) else np.ones(t.size, dtype=bool)
        for i, state in enumerate(series.states):
            unit = series.units.get(state, "")
            e = error[:, i]
            rows.append(
                [
                    text(name),
                    text(state),
                    number(float(np.sqrt(np.mean(e[before] ** 2))) if before.any() else None, unit),
                    number(float(np.sqrt(np.mean(e[~before] ** 2))) if (~before).any() else None, unit),
                    number(float(e[-1]), unit),
                    number(float(np.max(np.abs(e))), unit),
                ]
            )
    return rows


def _diagnosis(values: dict[str, Any]) -> list[Table]:
    tables = []
    for name, d in (values.get("diagnosis") or {}).items():
        tables.append(
            Table(
                f"Diagnosis by {name} ({d.get('kind')})",
                ["measure", "value"],
                [
                    [text("false alarms"), number(d.get("false_alarms"))],
                    [text("false-alarm rate"), number(d.get("false_alarm_rate_per_hour"), "per hour")],
                    [text("fault-free time"), number(d.get("fault_free_time_s"), "s")],
                    [text("missed detections"), number(d.get("missed_detections"))],
                    [text("time with the alarm raised"), number(d.get("alarm_time_s"), "s")],
                    [
                        text("isolation flags"),
                        text({k: ", ".join(v) for k, v in (d.get("isolation_flags") or {}).items()} or None),
                    ],
                ],
                id=f"diagnosis-{name}",
            )
        )
        faults = d.get("faults") or {}
        if faults:
            tables.append(
                Table(
                    f"{name}: detection and isolation per fault",
                    ["fault", "detected", "detection delay", "isolated as", "isolation delay", "isolation correct"],
                    [
                        [
                            text(label),
                            text(f.get("detected")),
                            number(f.get("detection_delay"), "s"),
                            text(f.get("isolated")),
                            number(f.get("isolation_delay"), "s"),
                            text(f.get("isolation_correct")),
                        ]
                        for label, f in faults.items()
                    ],
                    "Delays from the fault's onset (docs/metrics.md).",
                    id=f"diagnosis-{name}-faults",
                )
            )
    return tables


def _bus(values: dict[str, Any]) -> list[Table]:
    bus = values.get("bus")
    if not bus:
        return []
    known = {
        "fd": ("CAN FD", text),
        "bitrate": ("bit rate", _bitrate),
        "data_bitrate": ("data phase bit rate", _bitrate),
        "frames": ("frames", number),
        "load": ("bus load", percent),
        "load_worst_case": ("bus load, worst-case bit stuffing", percent),
        "peak_tick_load": ("load of the busiest tick", percent),
        "lost": ("frames lost", number),
        "deadline_misses": ("deadline misses", number),
    }
    rows = [[text(label), render(bus.get(key))] for key, (label, render) in known.items() if key in bus]
    for key, value in bus.items():
        if key not in known and key != "by_id" and not isinstance(value, dict):
            rows.append(
                [text(key), number(value, _unit_of_key(key)) if isinstance(value, (int, float)) else text(value)]
            )
    for key, value in bus.items():
        if key not in known and isinstance(value, dict) and key not in ("by_id", "foreign_frames", "latency"):
            rows.append([text(key), text(value)])
    tables = [
        Table(
            "",
            ["measure", "value"],
            rows,
            "Load: the fraction of simulated time the bus is busy, with exact bit stuffing (docs/metrics.md).",
            id="bus",
        )
    ]
    by_id = bus.get("by_id") or {}
    if by_id:
        tables.append(
            Table(
                "Frames per identifier",
                ["id", "message", "frames", "bits on the bus"],
                [
                    [text(i), text(e.get("message")), number(e.get("frames")), number(e.get("bits"), "bit")]
                    for i, e in by_id.items()
                ],
                id="by-id",
                folded=True,
            )
        )
    foreign = bus.get("foreign_frames") or {}
    if foreign:  # never folded: frames on the run's ids that their owner did not send are news
        tables.append(
            Table(
                "Frames nobody in the run sent",
                ["id", "message", "foreign frames"],
                [[text(i), text(by_id.get(i, {}).get("message")), number(n)] for i, n in foreign.items()],
                "Frames on an id whose owner did not send them (an intruder, a program that joined the bus): "
                "counted and logged on /cosim/foreign, never used by the runner.",
                id="foreign",
            )
        )
    latency = bus.get("latency") or {}
    if latency:
        tables.append(
            Table(
                "Latency on the arbitrated bus",
                ["id", "message", "frames", "min", "median", "max", "late", "replaced"],
                [
                    [
                        text(i),
                        text(by_id.get(i, {}).get("message")),
                        number(e.get("frames")),
                        *(
                            number(e.get(key) * 1e3 if e.get(key) is not None else None, "ms")
                            for key in ("min", "median", "max")
                        ),
                        number(e.get("late")),
                        number(e.get("dropped")),
                    ]
                    for i, e in latency.items()
                ],
                "From queueing to the frame's last bit (docs/bus.md); late: delivered after its deadline; replaced: "
                "overwritten by its sender's next frame of the id before it won arbitration.",
                id="latency",
                folded=True,
            )
        )
    return tables


def _log(values: dict[str, Any]) -> list[Table]:
    channels = values.get("channels") or {}
    if not channels:
        return []
    return [
        Table(
            f"Topics of the log ({len(channels)}) and their messages",
            ["topic", "messages"],
            [[text(topic), number(count)] for topic, count in channels.items()],
            f"Simulated time covered: {_format(values.get('time_span_s'))} s.",
            id="topics",
            folded=True,
        )
    ]


def _other(values: dict[str, Any]) -> list[Table]:
    """Every metric this page has no section for, as it is: scalars in one table, mappings each in one."""
    rest = {k: v for k, v in values.items() if k not in _SHOWN}
    tables = []
    scalars = [
        [text(k), number(v, _unit_of_key(k)) if isinstance(v, (int, float)) and not isinstance(v, bool) else text(v)]
        for k, v in rest.items()
        if not isinstance(v, dict)
    ]
    if scalars:
        tables.append(Table("Other metrics", ["key", "value"], scalars, id="other"))
    for key, value in rest.items():
        if isinstance(value, dict):
            tables += _generic(key, value)
    return tables


def _generic(title: str, value: dict[str, Any]) -> list[Table]:
    """A mapping of records as a table (a row per record), of scalars as key-value rows; nested
    mappings as tables of their own."""
    tables = []
    if value and all(isinstance(v, dict) for v in value.values()):
        columns: list[str] = []
        for record in value.values():
            columns += [k for k, v in record.items() if not isinstance(v, dict) and k not in columns]
        rows = [
            [text(name)]
            + [
                number(record.get(c), _unit_of_key(c))
                if isinstance(record.get(c), (int, float)) and not isinstance(record.get(c), bool)
                else text(record.get(c))
                for c in columns
            ]
            for name, record in value.items()
        ]
        tables.append(Table(title, ["name", *columns], rows, id=f"other-{title}"))
        for name, record in value.items():
            for key, inner in record.items():
                if isinstance(inner, dict):
                    tables += _generic(f"{title} · {name} · {key}", inner)
        return tables
    rows = [
        [text(k), number(v, _unit_of_key(k)) if isinstance(v, (int, float)) and not isinstance(v, bool) else text(v)]
        for k, v in value.items()
        if not isinstance(v, dict)
    ]
    tables.append(Table(title, ["key", "value"], rows, id=f"other-{title}"))
    for key, inner in value.items():
        if isinstance(inner, dict):
            tables += _generic(f"{title} · {key}", inner)
    return tables


def _figures(path: Path) -> tuple[list[dict[str, str]], str, Any]:
    """The figures of ``cosim plot``, inlined, and the series they were drawn from; or a note saying
    why there are none."""
    from cosim.analysis.plot import load, plot

    try:
        series = load(path)
    except CosimError:
        series = None
    with tempfile.TemporaryDirectory(prefix="cosim-report-") as folder:
        try:
            written = plot(path, folder, fmt="png", dpi=120)
        except MissingExtra as error:
            return [], f"no figures: {error}", series
        except CosimError as error:
            return [], f"no figures: {error}", series
        except Exception as error:  # a figure that cannot be drawn must not cost the rest of the report
            return [], f"no figures: {type(error).__name__}: {error}", series
        figures = []
        for png in written:
            kind = "cofd_residuals" if png.stem.startswith("cofd_residuals") else png.stem
            caption = CAPTIONS.get(kind, "")
            figures.append(
                {
                    "id": f"fig-{png.stem}",
                    "name": png.name,
                    "data": base64.b64encode(png.read_bytes()).decode("ascii"),
                    "caption": caption,
                }
            )
    return figures, "", series


def _compact(params: dict[str, Any], limit: int = 240) -> str:
    text = ", ".join(f"{k} = {json.dumps(v)}" for k, v in params.items())
    return text if len(text) <= limit else text[: limit - 1] + "…"
