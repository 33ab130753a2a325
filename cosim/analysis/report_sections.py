"""The sections of ``cosim report``'s page drawn from the run's metrics (``RunMetrics``): faults,
estimators, diagnosis, the bus, the log, and every metric the page has no section for."""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from cosim.analysis.metrics import BusMetrics, EstimationMetrics, RunMetrics
from cosim.analysis.metrics.values import to_json
from cosim.analysis.report_tables import Cell, Table, bitrate, format_value, generic, number, percent, scalar_rows, text
from cosim.log.metadata import RunRecord

#: The fields of the metrics this page lays out in its own sections; the rest go to "Other metrics".
SHOWN = {
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
#: The fields of an estimator's metrics with a column of their own (``faults`` has its table).
ESTIMATION_COLUMNS = {
    "kind",
    "kind_name",
    "rms_pre_fault",
    "rms_post_fault",
    "final_error",
    "band",
    "bias_rejection_ratio",
    "ticks_scored",
    "faults",
    "failed",
}


def faults(values: RunMetrics) -> list[Table]:
    if not values.faults:
        return []
    rows = [
        [
            text(label),
            text(f.kind),
            text(f.targets),
            number(f.start, "s"),
            Cell("end of run") if f.end is None else number(f.end, "s"),
            number(f.onset, "s"),
            Cell("not cleared" if f.onset is not None else "–") if f.cleared is None else number(f.cleared, "s"),
        ]
        for label, f in values.faults.items()
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


def estimators(values: RunMetrics, run: RunRecord | None, given: dict[str, Any], series: Any, norm: str) -> list[Table]:
    """The estimators' parameters (``given``: as the scenario gives them), their errors over the
    whole state (``norm``: its unit) and per state (from the figures' ``series``), per fault."""
    tables = _parameters(run, given)
    if not values.estimators:
        return tables
    tables.append(_errors(values, norm, norm_note(series)))
    states = _per_state(series, values.fault_onset)
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
    more = {name: _more(e) for name, e in values.estimators.items()}
    if any(more.values()):  # metrics of an estimator this page has no column for, as they are
        tables += generic("More estimator metrics", {name: extra for name, extra in more.items() if extra})
    return tables + _per_fault(values.estimators, norm)


def _parameters(run: RunRecord | None, given: dict[str, Any]) -> list[Table]:
    if run is None or not run.estimators:
        return []
    rows = [
        [text(name), text(e.kind), Cell(compact(given.get(name, {})) or "defaults")]
        for name, e in run.estimators.items()
    ]
    return [Table("Parameters", ["estimator", "kind", "parameters given"], rows, id="estimator-list")]


def _errors(values: RunMetrics, norm: str, note: str) -> Table:
    unit = f" [{norm}]" if norm else ""
    baseline = values.baseline
    rows = [
        [
            text(name),
            text(e.kind_name or e.kind),
            number(e.rms_pre_fault, norm),
            number(e.rms_post_fault, norm),
            number(e.final_error, norm),
            number(e.band, norm),
            number(e.bias_rejection_ratio, "× baseline" if baseline else ""),
            number(e.ticks_scored),
        ]
        for name, e in values.estimators.items()
    ]
    onset = values.fault_onset
    when = (
        f"the first fault's onset ({onset:g} s)" if isinstance(onset, (int, float)) else "the first fault (none here)"
    )
    scores = (
        f"RMS over the ticks before and from {when}; band: twice the largest error in the second half "
        "of the fault-free window; bias rejection: RMS after fault over that of the uniform-weight baseline"
        + (f" ({baseline})" if baseline else " (none in this run)")
        + " (docs/metrics.md)."
    )
    failed = [
        f"{name} failed: {e.failed}; its errors cover the ticks before."
        for name, e in values.estimators.items()
        if e.failed
    ]
    return Table(
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
        " ".join(part for part in (*failed, scores, note) if part),
        id="estimation",
    )


def _more(e: EstimationMetrics) -> dict[str, Any]:
    """An estimator's metrics beyond the columns of the page, those with a value (a table of
    nothing says nothing)."""
    return {
        key: value
        for key, value in to_json(e).items()
        if key not in ESTIMATION_COLUMNS and value is not None and value != {} and value != []
    }


def _per_fault(found: dict[str, EstimationMetrics], norm: str) -> list[Table]:
    rows = [
        [
            text(f"{name} · {label}"),
            number(f.peak_error, norm),
            number(f.peak_at, "s"),
            (number(f.recovery_time, "s") if f.recovered else Cell("not recovered")),
        ]
        for name, e in found.items()
        for label, f in e.faults.items()
    ]
    if not rows:
        return []
    unit = f" [{norm}]" if norm else ""
    return [
        Table(
            "Per fault: peak error and recovery",
            ["estimator · fault", f"peak |x − x̂|{unit}", "peak after onset", "recovery time"],
            rows,
            "Within each fault's segment (from its onset to the next onset): the largest error, when it came, and "
            "how long until the error stayed inside the band.",
            id="per-fault",
        )
    ]


def norm_unit(series: Any) -> str:
    """The unit of the error norm: the states' common unit, or "" when they differ."""
    if series is None:
        return ""
    units = {series.units.get(s, "") for s in series.states}
    return units.pop() if len(units) == 1 else ""


def norm_note(series: Any) -> str:
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


def diagnosis(values: RunMetrics) -> list[Table]:
    tables = []
    for name, d in values.diagnosis.items():
        flags = {k: ", ".join(v) for k, v in d.isolation_flags.items()} or None
        measures = [
            [text("false alarms"), number(d.false_alarms)],
            [text("false-alarm rate"), number(d.false_alarm_rate_per_hour, "per hour")],
            [text("fault-free time"), number(d.fault_free_time_s, "s")],
            [text("missed detections"), number(d.missed_detections)],
            [text("time with the alarm raised"), number(d.alarm_time_s, "s")],
            [text("isolation flags"), text(flags)],
        ]
        tables.append(
            Table(
                f"Diagnosis by {name} ({d.kind_name or d.kind})", ["measure", "value"], measures, id=f"diagnosis-{name}"
            )
        )
        if d.faults:
            rows = [
                [
                    text(label),
                    text(f.detected),
                    number(f.detection_delay, "s"),
                    text(f.isolated),
                    number(f.isolation_delay, "s"),
                    text(f.isolation_correct),
                ]
                for label, f in d.faults.items()
            ]
            tables.append(
                Table(
                    f"{name}: detection and isolation per fault",
                    ["fault", "detected", "detection delay", "isolated as", "isolation delay", "isolation correct"],
                    rows,
                    "Delays from the fault's onset (docs/metrics.md).",
                    id=f"diagnosis-{name}-faults",
                )
            )
    return tables


#: The bus's measures with a row of their own: field → (label, how its value is shown).
BUS_ROWS = {
    "fd": ("CAN FD", text),
    "bitrate": ("bit rate", bitrate),
    "data_bitrate": ("data phase bit rate", bitrate),
    "frames": ("frames", number),
    "load": ("bus load", percent),
    "load_worst_case": ("bus load, worst-case bit stuffing", percent),
    "peak_tick_load": ("load of the busiest tick", percent),
    "lost": ("frames lost", number),
    "deadline_misses": ("deadline misses", number),
}
#: The bus's mappings with a table of their own.
BUS_TABLES = ("by_id", "foreign_frames", "latency")


def bus(values: RunMetrics) -> list[Table]:
    found = values.bus
    if not found:
        return []
    measures = to_json(found)
    rows = [[text(label), show(measures[key])] for key, (label, show) in BUS_ROWS.items()]
    rest = {key: value for key, value in measures.items() if key not in BUS_ROWS and key != "by_id"}
    rows += scalar_rows(rest)  # a table's mapping left out where the run has none, as "–"
    rows += [
        [text(key), text(value)] for key, value in rest.items() if isinstance(value, dict) and key not in BUS_TABLES
    ]
    note = "Load: the fraction of simulated time the bus is busy, with exact bit stuffing (docs/metrics.md)."
    return [Table("", ["measure", "value"], rows, note, id="bus"), *_bus_ids(found)]


def _bus_ids(found: BusMetrics) -> list[Table]:
    """The frames per id, those nobody in the run sent, and the latency on an arbitrated bus."""
    by_id, tables = found.by_id, []
    message = {i: e.message for i, e in by_id.items()}
    if by_id:
        rows = [[text(i), text(e.message), number(e.frames), number(e.bits, "bit")] for i, e in by_id.items()]
        tables.append(
            Table(
                "Frames per identifier", ["id", "message", "frames", "bits on the bus"], rows, id="by-id", folded=True
            )
        )
    if found.foreign_frames:  # never folded: frames on the run's ids that their owner did not send are news
        tables.append(
            Table(
                "Frames nobody in the run sent",
                ["id", "message", "foreign frames"],
                [[text(i), text(message.get(i)), number(n)] for i, n in found.foreign_frames.items()],
                "Frames on an id whose owner did not send them (an intruder, a program that joined the bus): "
                "counted and logged on /cosim/foreign, never used by the runner.",
                id="foreign",
            )
        )
    if found.latency:
        rows = [
            [
                text(i),
                text(message.get(i)),
                number(e.frames),
                *(number(v * 1e3 if v is not None else None, "ms") for v in (e.min, e.median, e.max)),
                number(e.late),
                number(e.dropped),
            ]
            for i, e in found.latency.items()
        ]
        tables.append(
            Table(
                "Latency on the arbitrated bus",
                ["id", "message", "frames", "min", "median", "max", "late", "replaced"],
                rows,
                "From queueing to the frame's last bit (docs/bus.md); late: delivered after its deadline; replaced: "
                "overwritten by its sender's next frame of the id before it won arbitration.",
                id="latency",
                folded=True,
            )
        )
    return tables


def log(values: RunMetrics) -> list[Table]:
    channels = values.channels
    if not channels:
        return []
    return [
        Table(
            f"Topics of the log ({len(channels)}) and their messages",
            ["topic", "messages"],
            [[text(topic), number(count)] for topic, count in channels.items()],
            f"Simulated time covered: {format_value(values.time_span_s)} s.",
            id="topics",
            folded=True,
        )
    ]


def other(values: RunMetrics) -> list[Table]:
    """Every metric this page has no section for, as it is: scalars in one table, mappings each in one."""
    rest = {k: v for k, v in to_json(values).items() if k not in SHOWN}
    tables = []
    scalars = scalar_rows(rest)
    if scalars:
        tables.append(Table("Other metrics", ["key", "value"], scalars, id="other"))
    for key, value in rest.items():
        if isinstance(value, dict):
            tables += generic(key, value)
    return tables


def compact(params: dict[str, Any], limit: int = 240) -> str:
    found = ", ".join(f"{k} = {json.dumps(v)}" for k, v in params.items())
    return found if len(found) <= limit else found[: limit - 1] + "…"
