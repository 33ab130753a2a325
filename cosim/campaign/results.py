"""The results table of a campaign: one row per run and estimator, its columns and units, and its parts.

Each finished run leaves one part on disk, ``DIR/parts/run-<index>.json``, written whole or not at
all (a temporary file renamed into place): a campaign killed at any moment has lost at most the
runs in flight, and ``--resume`` redoes exactly the runs without a part. ``DIR/results.parquet`` is
assembled from the parts in run order, in batches (the coordinator never holds the whole table).

A row holds the run (index, replicate, seed, its axis and sample columns, status, error, wall
time, the log if kept), the estimator, and its metrics from ``cosim inspect`` flattened: the
estimation errors, the first fault's peak and recovery, and for an estimator that publishes an
alarm its detection and isolation (``docs/campaigns.md`` defines every column).
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # the metrics' modules load the codec and the estimators: not for reading a table
    import pyarrow as pa

    from cosim.analysis.metrics import DiagnosisMetrics, RunMetrics


def column(kind: str, unit: str, description: str) -> Any:
    """A column of the table: its type ("int", "float", "bool", "text"), its unit ("state": the
    unit of the state norm) and what it holds; None where a row has no value."""
    return field(default=None, metadata={"type": kind, "unit": unit, "description": description})


@dataclass
class Row:
    """A row of the table, its fixed columns in order (the campaign's axis and sample columns, which
    follow ``seed``, are the campaign file's)."""

    run: int | None = column("int", "", "run index in the campaign")
    replicate: int | None = column("int", "", "replicate (from the campaign's seeds)")
    seed: int | None = column("int", "", "the run's scenario seed (cosim run --seed)")
    status: str | None = column("text", "", "completed, interrupted or error")
    error: str | None = column("text", "", "why the run failed (empty if it did not)")
    wall_time_s: float | None = column("float", "s", "wall-clock time of the run and its metrics")
    log: str | None = column("text", "", "the run's log, relative to the campaign folder (empty if not kept)")
    estimator: str | None = column("text", "", "estimator name")
    kind: str | None = column("text", "", "estimator kind (a plugin's: its module path)")
    kind_name: str | None = column(
        "text", "", "the name a plugin's kind declares, where its kind is a module path (empty otherwise)"
    )
    estimator_failed: str | None = column(
        "text", "", "the estimator failed during the run: when and what it raised (empty if it did not)"
    )
    contested_ticks: int | None = column(
        "int", "", "ticks during which another program sent on the runner's ids (spoofing without authentication)"
    )
    fault_kind: str | None = column("text", "", "kinds of the run's faults, joined with +; none without faults")
    fault_onset_s: float | None = column("float", "s", "first fault onset")
    ticks: int | None = column("int", "", "ticks run")
    frames_lost: int | None = column("int", "", "frames lost on the bus")
    rms_pre_fault: float | None = column("float", "state", "RMS of |x − x̂| before the first fault")
    rms_post_fault: float | None = column("float", "state", "RMS of |x − x̂| from the first fault onset")
    final_error: float | None = column("float", "state", "|x − x̂| at the last tick")
    band: float | None = column("float", "state", "pre-fault band: 2 × the largest settled pre-fault error")
    bias_rejection_ratio: float | None = column("float", "", "post-fault RMS over the uniform-weight baseline's")
    peak_error: float | None = column("float", "state", "largest |x − x̂| after the first fault's onset")
    recovery_time_s: float | None = column(
        "float", "s", "from the first fault's onset until |x − x̂| stays in the band (null: never)"
    )
    diagnoses: bool | None = column("bool", "", "the estimator publishes an alarm")
    false_alarms: int | None = column("int", "", "alarm episodes starting with no fault active")
    false_alarm_rate_per_hour: float | None = column("float", "1/h", "false alarms per fault-free hour")
    fault_free_time_s: float | None = column("float", "s", "scored time with no fault active")
    missed_detections: int | None = column("int", "", "faults with no alarm in their segment")
    detected: bool | None = column("bool", "", "every fault of the run detected")
    detection_delay_s: float | None = column("float", "s", "first fault: onset to the first alarm")
    isolated: bool | None = column("bool", "", "every isolable fault isolated")
    isolation_delay_s: float | None = column("float", "s", "first fault: onset to its isolation")
    isolation_correct: bool | None = column("bool", "", "every isolable fault isolated to the right targets")
    isolation_expected: str | None = column(
        "text", "", "first isolable fault: the targets it is to be isolated to, joined with +"
    )
    isolation_result: str | None = column(
        "text", "", "first isolable fault: the targets the scheme isolated it to, joined with + (none: not isolated)"
    )

    @classmethod
    def of(cls, values: dict[str, Any]) -> Row:
        """The fixed columns of a row of the table (its other columns left out)."""
        return cls(**{name: values[name] for name in COLUMNS if name in values})

    def metric_columns(self) -> dict[str, Any]:
        """Its columns from the run's metrics (those from ``estimator`` on), as a part holds them."""
        return {name: _finite(getattr(self, name)) for name in COLUMNS if name not in RUN_COLUMNS}


#: The fixed columns: name → (type, unit, description). "state" stands for the unit of the state norm.
COLUMNS: dict[str, tuple[str, str, str]] = {
    f.name: (f.metadata["type"], f.metadata["unit"], f.metadata["description"]) for f in fields(Row)
}
#: The columns the worker fills for every run, before its metrics.
RUN_COLUMNS = ("run", "replicate", "seed", "status", "error", "wall_time_s", "log")
IDENTITY = ("run", "replicate", "seed")
#: Columns that vary between identical runs (wall-clock), left out when tables are compared.
NONDETERMINISTIC = ("wall_time_s",)


def part_path(folder: Path, index: int) -> Path:
    return folder / "parts" / f"run-{index:06d}.json"


def write_part(folder: Path, index: int, part: dict[str, Any]) -> None:
    """Write a run's part atomically (a temporary file renamed into place)."""
    path = part_path(folder, index)
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_suffix(f".{os.getpid()}.tmp")
    temporary.write_text(json.dumps(part, allow_nan=False, default=_jsonable))
    os.replace(temporary, path)


def done_runs(folder: Path) -> set[int]:
    """The runs that have a part."""
    return {int(p.stem.split("-")[1]) for p in (folder / "parts").glob("run-*.json")}


def _jsonable(value: Any) -> Any:
    raise TypeError(f"{type(value).__name__} is not JSON")


def _finite(value: Any) -> Any:
    return None if isinstance(value, float) and not math.isfinite(value) else value


def rows_of(metrics: RunMetrics) -> list[dict[str, Any]]:
    """The metric columns of a run's rows, one per estimator (and diagnosis scheme that is none)."""
    from cosim.analysis.metrics import EstimationMetrics, FaultRecovery

    faults = sorted(metrics.faults.items(), key=lambda item: (item[1].onset is None, item[1].onset or 0))
    first = faults[0][0] if faults else None
    names = [*metrics.estimators, *(n for n in metrics.diagnosis if n not in metrics.estimators)]
    run: dict[str, Any] = {
        "contested_ticks": metrics.contested_ticks,
        "fault_kind": "+".join(sorted({str(f.kind) for _, f in faults})) or "none",
        "fault_onset_s": metrics.fault_onset,
        "ticks": metrics.ticks,
        "frames_lost": metrics.frames.lost,
    }
    rows = []
    for name in names:
        e = metrics.estimators.get(name, EstimationMetrics())
        d = metrics.diagnosis.get(name)
        f = e.faults.get(first, FaultRecovery()) if first else FaultRecovery()
        row = Row(
            **run,
            estimator=name,
            kind=e.kind or (d.kind if d else None),
            kind_name=e.kind_name or (d.kind_name if d else None),
            estimator_failed=e.failed,
            rms_pre_fault=e.rms_pre_fault,
            rms_post_fault=e.rms_post_fault,
            final_error=e.final_error,
            band=e.band,
            bias_rejection_ratio=e.bias_rejection_ratio,
            peak_error=f.peak_error,
            recovery_time_s=f.recovery_time,
            diagnoses=d is not None,
        )
        if d is not None:
            _diagnosis_columns(row, d, first)
        rows.append(row.metric_columns())
    # The bus's own schemes, each scored as a diagnosis scheme of its own: the runner's intrusion
    # detector (its "any" check) and SecOC's receivers (their rejections)
    bus = metrics.bus
    for scheme, score in (
        (INTRUSION_DETECTOR, (bus.intrusion_detection or {}).get("any") if bus else None),
        (SECOC, bus.secoc_detection if bus else None),
    ):
        if score is not None:
            row = Row(**run, estimator=scheme, kind=scheme, diagnoses=True)
            _diagnosis_columns(row, score, first)
            rows.append(row.metric_columns())
    return rows


INTRUSION_DETECTOR = "intrusion-detector"
"""The ``estimator`` and ``kind`` of the intrusion detector's rows (``[bus] intrusion_detector``)."""
SECOC = "secoc"
"""The ``estimator`` and ``kind`` of SecOC's rows (``[bus] authentication = "secoc"``)."""


def _diagnosis_columns(row: Row, d: DiagnosisMetrics, first: str | None) -> None:
    """A diagnosis scheme's columns: its false alarms, and whether it detected and isolated every
    fault (the first one's delays)."""
    from cosim.analysis.metrics import FaultDiagnosis

    scored = d.faults
    isolable = [x for x in scored.values() if x.isolable]
    head = scored.get(first, FaultDiagnosis()) if first else FaultDiagnosis()
    row.false_alarms = d.false_alarms
    row.false_alarm_rate_per_hour = d.false_alarm_rate_per_hour
    row.fault_free_time_s = d.fault_free_time_s
    row.missed_detections = d.missed_detections
    row.detected = all(x.detected for x in scored.values()) if scored else None
    row.detection_delay_s = head.detection_delay
    row.isolated = all(x.isolation_delay is not None for x in isolable) if isolable else None
    row.isolation_delay_s = head.isolation_delay
    row.isolation_correct = all(bool(x.isolation_correct) for x in isolable) if isolable else None
    if isolable:  # the confusion matrix's cell of this run: the first isolable fault, expected and found
        target = isolable[0]
        row.isolation_expected = "+".join(sorted(target.expected or [])) or "none"
        row.isolation_result = "+".join(sorted(target.isolated or [])) or "none"


@dataclass(frozen=True)
class TableSchema:
    """The columns of one campaign's table: the fixed ones and its axis and sample columns, each
    with a type ("int", "float", "bool", "text") and a unit."""

    columns: tuple[tuple[str, str, str, str], ...]

    @classmethod
    def of(cls, varying: dict[str, list[Any]], state_unit: str) -> TableSchema:
        """The schema for axis and sample columns with these values (in order) and the state's unit."""
        fixed = [(n, t, state_unit if u == "state" else u, d) for n, (t, u, d) in COLUMNS.items()]
        head, tail = fixed[: len(IDENTITY)], fixed[len(IDENTITY) :]
        extra = []
        for name, values in varying.items():
            numeric = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values)
            extra.append((name, "float" if numeric else "text", "", "campaign axis or sample"))
        return cls(tuple(head + extra + tail))

    @property
    def names(self) -> list[str]:
        return [c[0] for c in self.columns]

    def arrow(self) -> pa.Schema:
        import pyarrow as pa

        types = {"int": pa.int64(), "float": pa.float64(), "bool": pa.bool_(), "text": pa.string()}
        return pa.schema([pa.field(n, types[t], metadata={"unit": u, "description": d}) for n, t, u, d in self.columns])

    def convert(self, row: dict[str, Any]) -> dict[str, Any]:
        out = {}
        for name, kind, _, _ in self.columns:
            value = row.get(name)
            if value is not None and kind == "float":
                value = float(value)
            elif value is not None and kind == "text" and not isinstance(value, str):
                value = json.dumps(value)
            out[name] = value
        return out


def assemble(
    folder: Path, indices: Iterable[int], schema: TableSchema, metadata: dict[str, str], batch: int = 2000
) -> Path:
    """Write ``DIR/results.parquet`` from the parts of ``indices`` (in that order), in batches."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    arrow = schema.arrow().with_metadata(metadata)
    target = folder / "results.parquet"
    temporary = folder / "results.parquet.part"
    with pq.ParquetWriter(temporary, arrow) as writer:
        pending: list[dict[str, Any]] = []
        for row in _rows(folder, indices):
            pending.append(schema.convert(row))
            if len(pending) >= batch:
                writer.write_table(pa.Table.from_pylist(pending, schema=arrow))
                pending.clear()
        if pending:
            writer.write_table(pa.Table.from_pylist(pending, schema=arrow))
    os.replace(temporary, target)
    return target


def _rows(folder: Path, indices: Iterable[int]) -> Iterator[dict[str, Any]]:
    for index in indices:
        yield from json.loads(part_path(folder, index).read_text())["rows"]
