"""``cosim inspect``: what any MCAP file holds (``cosim.log.info``: what ``mcap info`` says) and, for a
log of cosim, its metrics (``cosim.analysis.metrics``), as JSON or as text tables."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rich.console import Console
from rich.markup import escape
from rich.table import Table

from cosim.analysis.metrics import BusMetrics, DiagnosisMetrics, EstimationMetrics, RunMetrics, compute_metrics
from cosim.log.info import file_info
from cosim.log.reader import LogReader


def summarize(path: str | Path) -> dict[str, Any]:
    """The metrics of a log in their JSON form (keys in the README and docs/metrics.md), with the
    file's contents under ``mcap`` (``cosim.log.info.file_info``)."""
    report = compute_metrics(path)
    with LogReader(path) as reader:
        report["mcap"] = file_info(reader)
    return report


def _number(value: float | None, fmt: str = ".3e") -> str:
    return "-" if value is None else format(value, fmt)


def _table(title: str, columns: list[str]) -> Table:
    table = Table(title=escape(title), box=None, header_style="bold", title_justify="left")
    for i, column in enumerate(columns):  # escaped: "[s]" is a unit here, not rich's strike-through
        table.add_column(escape(column), justify="left" if i < 2 else "right")
    return table


def _kind(found: EstimationMetrics | DiagnosisMetrics) -> str:
    """A kind as a table shows it: by the name its class declares (a plugin's module path is in --json)."""
    return str(found.kind_name or found.kind)


def render(report: RunMetrics | dict[str, Any], console: Console) -> None:
    """Print a log's metrics (``measure``'s value, or its JSON form) as text: the file's contents
    where the report has them, then for a log of cosim the run and each metrics table that has rows."""
    metrics = report if isinstance(report, RunMetrics) else RunMetrics.from_json(report)
    info = None if isinstance(report, RunMetrics) else report.get("mcap")
    console.print(f"[bold]{escape(metrics.file)}[/bold]")
    for warning in metrics.warnings:
        console.print(f"[yellow]warning:[/yellow] {escape(warning)}")
    if info is not None:
        render_info(info, console)
        if metrics.scenario is None and metrics.status != "imported":  # not a log of cosim: no run to show
            return
    _run(metrics, console, channels=info is None)
    _faults(metrics, console)
    _estimation(metrics, console)
    for name, diagnosis in metrics.diagnosis.items():
        _diagnosis(name, diagnosis, console)
    if metrics.bus:
        _bus(metrics.bus, console)


def render_info(info: dict[str, Any], console: Console) -> None:
    """What ``mcap info`` prints of a file (``cosim.log.info.file_info``'s value): its writer, messages
    and time span, chunks, channels with their schema, encoding and count, attachments, metadata."""
    start, end = info["start_ns"], info["end_ns"]
    lines = [f"library:     {info['library']}", f"profile:     {info['profile']}", f"messages:    {info['messages']}"]
    if start is not None and end is not None:
        lines += [
            f"duration:    {_duration(end - start)}",
            f"start:       {start / 1e9:.9f}",
            f"end:         {end / 1e9:.9f}",
        ]
    if info["chunks"]:
        lines.append("compression:")
        total = sum(entry["chunks"] for entry in info["chunks"].values())
        for name, entry in info["chunks"].items():
            saved = 1 - entry["compressed"] / entry["uncompressed"] if entry["uncompressed"] else 0.0
            lines.append(
                f"    {name}: [{entry['chunks']}/{total} chunks] "
                f"[{_bytes(entry['uncompressed'])}/{_bytes(entry['compressed'])} ({saved:.2%})]"
            )
    console.print(escape("\n".join(lines)), highlight=False)
    seconds = (end - start) / 1e9 if start is not None and end is not None else 0.0
    channels = _table(f"channels: {len(info['channels'])}", ["id", "topic", "messages", "rate", "schema", "encoding"])
    for c in info["channels"]:
        schema = "<no schema>" if c["schema"] is None else f"{c['schema']} [{c['schema_encoding']}]"
        rate = f"{c['messages'] / seconds:.4g} Hz" if seconds > 0 and c["messages"] > 1 else "-"
        channels.add_row(
            str(c["id"]), escape(c["topic"]), str(c["messages"]), rate, escape(schema), escape(c["message_encoding"])
        )
    console.print(channels)
    attachments = _table(f"attachments: {len(info['attachments'])}", ["name", "media type", "size", "log time [s]"])
    for a in info["attachments"]:
        attachments.add_row(
            escape(a["name"]), escape(a["media_type"]), _bytes(a["bytes"]), f"{a['log_time_ns'] / 1e9:.9f}"
        )
    console.print(attachments)
    metadata = _table(f"metadata: {len(info['metadata'])}", ["name", "keys"])
    for m in info["metadata"]:
        metadata.add_row(escape(m["name"]), escape(", ".join(m["metadata"])))
    console.print(metadata)


def _duration(ns: int) -> str:
    """A duration as ``mcap info`` writes it: 9ns, 1.5ms, 12.25s, 2m3.5s."""
    for unit, size in (("ns", 1), ("µs", 1_000), ("ms", 1_000_000)):
        if abs(ns) < size * 1000:
            return f"{ns / size:g}{unit}"
    minutes, seconds = divmod(ns / 1e9, 60)
    return f"{int(minutes)}m{seconds:g}s" if minutes else f"{seconds:g}s"


def _bytes(n: int) -> str:
    """A size in B, KiB, MiB or GiB."""
    if n < 1024:
        return f"{n} B"
    size, unit = n / 1024, "KiB"
    for larger in ("MiB", "GiB"):
        if size < 1024:
            break
        size, unit = size / 1024, larger
    return f"{size:.2f} {unit}"


def _run(m: RunMetrics, console: Console, channels: bool = True) -> None:
    for missing in m.missing:
        console.print(f"[yellow]missing:[/yellow] {escape(missing)}")
    onset = m.fault_onset
    first = "-" if onset is None else f"{onset:g} s"
    if onset is not None and m.duration_s is not None and onset >= m.duration_s:
        first += " (after the run's end: no fault happened)"
    if m.status == "imported":  # cosim import: a bus log, no run
        console.print(f"{escape(str(m.source))}: frames {m.frames.total} over {m.time_span_s} s")
        if channels:
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
    if channels:
        _channels(m, console)


def _channels(m: RunMetrics, console: Console) -> None:
    table = _table("channels", ["topic", "messages"])
    for topic, count in m.channels.items():
        table.add_row(escape(topic), str(count))
    console.print(table)


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
            escape(_kind(e)),
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
        f"[bold]diagnosis {escape(name)}[/bold] ({escape(_kind(d))}): {d.false_alarms} false alarms "
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
