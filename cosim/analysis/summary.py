"""``cosim inspect``: a log's summary and metrics (``cosim.analysis.metrics``), as JSON or as text tables."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rich.console import Console
from rich.markup import escape
from rich.table import Table

from cosim.analysis.metrics import BusMetrics, DiagnosisMetrics, RunMetrics, compute_metrics
from cosim.kinds import is_file_reference


def summarize(path: str | Path) -> dict[str, Any]:
    """The summary and metrics of a log in their JSON form (keys in the README and docs/metrics.md)."""
    return compute_metrics(path)


def _number(value: float | None, fmt: str = ".3e") -> str:
    return "-" if value is None else format(value, fmt)


def _table(title: str, columns: list[str]) -> Table:
    table = Table(title=escape(title), box=None, header_style="bold", title_justify="left")
    for i, column in enumerate(columns):  # escaped: "[s]" is a unit here, not rich's strike-through
        table.add_column(escape(column), justify="left" if i < 2 else "right")
    return table


def _kind(kind: str | None) -> str:
    """A kind as a table shows it: a class in a file by the file's name, not its whole path."""
    if kind is not None and is_file_reference(kind):
        file, _, name = kind.rpartition(":")
        return f"{Path(file).name}:{name}"
    return str(kind)


def render(report: RunMetrics | dict[str, Any], console: Console) -> None:
    """Print a log's metrics (``measure``'s value, or its JSON form) as text: the run, its channels,
    then each metrics table that has rows."""
    metrics = report if isinstance(report, RunMetrics) else RunMetrics.from_json(report)
    _run(metrics, console)
    _faults(metrics, console)
    _estimation(metrics, console)
    for name, diagnosis in metrics.diagnosis.items():
        _diagnosis(name, diagnosis, console)
    if metrics.bus:
        _bus(metrics.bus, console)


def _run(m: RunMetrics, console: Console) -> None:
    console.print(f"[bold]{escape(m.file)}[/bold]")
    for warning in m.warnings:
        console.print(f"[yellow]warning:[/yellow] {escape(warning)}")
    for missing in m.missing:
        console.print(f"[yellow]missing:[/yellow] {escape(missing)}")
    onset = m.fault_onset
    first = "-" if onset is None else f"{onset:g} s"
    if onset is not None and m.duration_s is not None and onset >= m.duration_s:
        first += " (after the run's end: no fault happened)"
    if m.status == "imported":  # cosim import: a bus log, no run
        console.print(f"{escape(str(m.source))}: frames {m.frames.total} over {m.time_span_s} s")
        _channels(m, console)
        return
    status = m.status + (f", {m.contested_ticks} contested ticks" if m.contested_ticks else "")
    console.print(
        f"scenario {m.scenario} ({m.source}), seed {m.seed}, status {status}\n"
        f"{m.ticks} ticks, {m.duration_s} s simulated; frames {m.frames.total} "
        f"({m.frames.lost} lost); first fault at {first}"
    )
    for name, e in m.estimators.items():
        if e.failed:
            console.print(f"[yellow]estimator {escape(name)} {escape(e.failed)}[/yellow]")
    _channels(m, console)


def _channels(m: RunMetrics, console: Console) -> None:
    channels = _table("channels", ["topic", "messages"])
    for topic, count in m.channels.items():
        channels.add_row(escape(topic), str(count))
    console.print(channels)


def _faults(m: RunMetrics, console: Console) -> None:
    if not m.faults:
        return
    table = _table(
        "faults (onset and clearance from /truth/faults)", ["fault", "kind", "targets", "onset [s]", "cleared [s]"]
    )
    for label, f in m.faults.items():
        targets = ", ".join(f.targets) or "-"
        table.add_row(escape(label), str(f.kind), targets, _number(f.onset, "g"), _number(f.cleared, "g"))
    console.print(table)


def _estimation(m: RunMetrics, console: Console) -> None:
    if not m.estimators:
        return
    unit = f" [{m.error_unit}]" if m.error_unit and not m.error_unit.startswith("mixes") else ""
    mixed = f" ({m.error_unit})" if m.error_unit and m.error_unit.startswith("mixes") else ""
    table = _table(
        f"estimation error |x - x̂|{unit}{mixed}",
        ["estimator", "kind", "RMS before fault", "RMS after fault", "final", "band", "bias rejection"],
    )
    per_fault = _table(
        f"per fault: peak error{unit}, its time and the recovery time after onset [s]",
        ["estimator", "fault", "peak", "peak at", "recovery"],
    )
    for name, e in m.estimators.items():
        table.add_row(
            escape(name),
            escape(_kind(e.kind)),
            _number(e.rms_pre_fault),
            _number(e.rms_post_fault),
            _number(e.final_error),
            _number(e.band),
            _number(e.bias_rejection_ratio, ".3f"),
        )
        for label, f in e.faults.items():
            recovery = _number(f.recovery_time, "g") if f.recovered else "not recovered"
            per_fault.add_row(escape(name), escape(label), _number(f.peak_error), _number(f.peak_at, "g"), recovery)
    console.print(table)
    if per_fault.row_count:
        console.print(per_fault)


def _diagnosis(name: str, d: DiagnosisMetrics, console: Console) -> None:
    console.print(
        f"[bold]diagnosis {escape(name)}[/bold] ({escape(_kind(d.kind))}): {d.false_alarms} false alarms "
        f"({_number(d.false_alarm_rate_per_hour, '.3g')} per hour over {d.fault_free_time_s:g} s fault-free), "
        f"{d.missed_detections} missed detections"
    )
    table = _table("", ["fault", "detected", "delay [s]", "isolated", "delay [s]", "correct"])
    for label, f in d.faults.items():
        table.add_row(
            escape(label),
            "yes" if f.detected else "no",
            _number(f.detection_delay, "g"),
            "-" if f.isolated is None else ", ".join(f.isolated),
            _number(f.isolation_delay, "g"),
            "-" if f.isolation_correct is None else ("yes" if f.isolation_correct else "no"),
        )
    if table.row_count:
        console.print(table)


def _bus(bus: BusMetrics, console: Console) -> None:
    rate = (
        "-"
        if bus.bitrate is None
        else f"{bus.bitrate:g} bit/s" + (f", data {bus.data_bitrate:g} bit/s" if bus.fd and bus.data_bitrate else "")
    )
    console.print(
        f"[bold]bus[/bold] ({'CAN FD' if bus.fd else 'classic CAN'}, {rate}): load {_number(bus.load, '.2%')} "
        f"(worst-case stuffing {_number(bus.load_worst_case, '.2%')}, busiest tick "
        f"{_number(bus.peak_tick_load, '.2%')}), {bus.lost} frames lost, {bus.deadline_misses} deadline misses"
    )
    ids = _table("", ["id", "message", "frames", "bits"])
    for frame_id, entry in bus.by_id.items():
        ids.add_row(frame_id, escape(str(entry.message)), str(entry.frames), str(entry.bits))
    console.print(ids)
    for name in sorted(name for name, n in {**bus.lost_by_sender, **bus.late_by_sender}.items() if n):
        console.print(
            f"[yellow]{escape(name)}: {bus.lost_by_sender.get(name, 0)} frames lost, "
            f"{bus.late_by_sender.get(name, 0)} late[/yellow]"
        )
    foreign = bus.foreign
    if foreign.datagrams or foreign.frames:
        reasons = "; ".join(f"{count} {escape(reason)}" for reason, count in foreign.by_reason.items())
        console.print(
            f"[yellow]foreign: {foreign.datagrams} datagrams and {foreign.frames} frames that do not "
            f"belong to the run arrived (counted, never used): {reasons}[/yellow]"
        )
