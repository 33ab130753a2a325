"""Exports of run logs for the tools engineers already use.

Three kinds of output, each streamed through the log in bounded memory (a one-hour run is never loaded whole):

- **Tidy tables** (``csv``, ``parquet``): one row per tick k, columns ``tick``, ``t [s]``
  (simulated time t_k), then the truth topics and the decoded data messages of the bus, one column
  per field, named ``<name>.<field> [unit]`` as ``cosim.analysis.names`` names them, the same on
  classic CAN and CAN FD: ``state.x1 [m]`` (``/truth/state``), ``inputs.effective.force [N]``,
  ``faults.measured.x2 [m]``, ``SENSOR_x1.x1 [m]``, ``kalman.xhat_v1 [m/s]`` (from
  ``/can/EST_kalman_1`` or ``/can/EST_kalman``). Units come from the log's JSON Schemas.
  A cell is empty (null) when the tick has no such value: a frame not sent (dropout), a reading
  not measured. Lists (the active faults, the dropped sensors) are comma-joined text. Decoded
  frames go to the row of the tick they carry (their ``tick`` signal), which is the tick they were
  logged at in lockstep; control messages (NMT, SYNC, heartbeats) are in the frame exports only.
  An imported log (``cosim import``) has a row per decoded frame instead: ``time [ns]``, ``t [s]``,
  its ``message`` (one without signals too), then every message's signals.
- **Frame logs** (``blf``, ``mf4``, ``candump``, ``asc``, ``trc``): every frame of ``/can/frames`` in bus order,
  stamped at the run's wall-clock start plus simulated time (the frames of one tick share t_k),
  so tools show the date the run happened. The start is the log's ``cosim.run`` ``start_time_ns``
  to the millisecond (BLF's header holds milliseconds; the three formats then agree to the
  nanosecond); ``start_ns`` overrides it, 0 gives times from the Unix epoch (t = 0 s at tick 0), and
  a log that records no start is stamped from the epoch, with a warning. BLF is written with
  python-can's ``BLFWriter`` (channel 1), candump with its ``CanutilsLogWriter`` (the text of
  ``candump -L``: ``(t) can0 1A0#0011 R``, ``##<flags>`` for CAN FD, which can-utils' log2asc,
  ``can.LogReader``, cantools and SavvyCAN read), ASC (Vector's text log, channel 1, CANoe and
  CANalyzer) with its ``ASCWriter`` and TRC (PEAK's trace, version 2.1, PCAN-View and PCAN-Explorer;
  classic CAN only: python-can does not write CAN FD to it) with its ``TRCWriter``. MF4 is an
  ASAM MDF 4.10 bus log written in bulk with asammdf's public API: one ``CAN_DataFrame`` channel
  group in the standard bus-logging layout (``ID``, ``IDE``, ``DLC``, ``DataLength``,
  ``DataBytes``, ``EDL``, ``BRS``, ...) with a CAN bus acquisition source and the DBC attached, so
  asammdf's ``extract_bus_logging`` and CANalyzer decode it; its header's start time is the start,
  its timestamps simulated time.
- **A ROS 2 bag** (``rosbag2``, ``cosim.analysis.rosbag_export``): a rosbag2 folder (MCAP storage,
  CDR) of the frames as ros2_socketcan's messages and every other topic as a ROS message, stamped
  as the frame logs.

A file goes to a temporary file beside it (``cosim.files``) renamed into place at the end: a
failed export leaves no half-written file under the final name."""

from __future__ import annotations

import csv
import json
import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from hashlib import md5
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cosim.analysis import names
from cosim.bus.log_clock import times_caveat
from cosim.errors import CosimError, LogError
from cosim.extras import require
from cosim.files import temporary_beside
from cosim.log.metadata import DBC_ATTACHMENT, RUN, LogMetadata
from cosim.log.reader import LogReader
from cosim.log.recorder import FAULTS, FRAMES, INPUTS, SENSORS, STATE, carried_tick

if TYPE_CHECKING:
    import can
    import numpy as np

#: Format → file suffix of its output.
FORMATS = {
    "csv": ".csv",
    "parquet": ".parquet",
    "blf": ".blf",
    "mf4": ".mf4",
    "candump": ".log",
    "asc": ".asc",
    "trc": ".trc",
    "rosbag2": "",  # a folder named as the log
}
TABLE_FORMATS = ("csv", "parquet")
#: The formats stamped from the run's start (``--start-time``).
FRAME_FORMATS = ("blf", "mf4", "candump", "asc", "trc", "rosbag2")
TRUTH_TOPICS = (STATE, SENSORS, INPUTS, FAULTS)
#: Decoded topics that are bus control, not signals.
CONTROL_MESSAGES = re.compile(r"^/can/(NMT|SYNC|HEARTBEAT_.*)$")
CANDUMP_INTERFACE = "can0"
#: Rows kept open for frames that arrive after their tick (realtime mode); later ones are left out.
ROW_WINDOW = 256
PARQUET_BATCH_ROWS = 8192
MF4_BATCH_FRAMES = 16384
MF4_FRAGMENT_BYTES = 1 << 20  # asammdf's data blocks: what it holds in memory while saving

#: The column of an imported log's table that names each row's message.
MESSAGE_COLUMN = "message"
_UNIT = re.compile(r"\[([^\[\]]*)\]\s*$")  # cosim.log.writer.number writes "<description> [<unit>]"


@dataclass
class ExportResult:
    """What an export wrote: the file, its format, how many rows (tables) or frames, warnings."""

    path: Path
    format: str
    count: int
    warnings: list[str] = field(default_factory=list)
    start_ns: int | None = None
    """Frame logs: the wall-clock time (ns since the epoch, UTC) their frames are stamped from."""
    what: str = "frames"
    """What ``count`` counts, as the command says it: frames, rows (ticks), rows (decoded frames)."""
    start_of: str = "tick 0"
    """What is stamped at ``start_ns``: tick 0 of a run, the first frame of an imported log."""


@dataclass(frozen=True)
class Column:
    """One column of the tidy table: the topic and field path it comes from, its type and unit."""

    name: str
    topic: str
    path: tuple[str, ...]
    kind: str  # "int", "float", "bool" or "text"
    unit: str = ""
    description: str = ""


def default_output(log: str | Path, fmt: str) -> Path:
    """FILE.mcap → FILE.<suffix of the format> next to it."""
    return Path(log).with_suffix(FORMATS[fmt])


def export(
    log: str | Path, fmt: str, out: str | Path | None = None, dbc: str | Path | None = None, start_ns: int | None = None
) -> ExportResult:
    """Export the log ``log`` as ``fmt`` (one of FORMATS) to ``out`` (default: next to the log).

    ``dbc`` (mf4 only) replaces the DBC attached to the log, for logs that lack one. ``start_ns``
    (frame logs only): the wall-clock time of tick 0 in ns since the Unix epoch (default: the run's
    start, to the millisecond; 0: the epoch)."""
    if fmt not in FORMATS:
        raise CosimError(f"unknown export format {fmt!r}: choose one of {', '.join(FORMATS)}")
    if dbc is not None and fmt != "mf4":
        raise CosimError(f"--dbc is used by the mf4 export only (it is attached to the file), not by {fmt}")
    if start_ns is not None and fmt not in FRAME_FORMATS:
        raise CosimError(
            f"--start-time stamps the frame logs ({', '.join(FRAME_FORMATS)}); a {fmt} table is in simulated time "
            "(its 't [s]' column)"
        )
    out = Path(out) if out is not None else default_output(log, fmt)
    if out.resolve() == Path(log).resolve():
        raise CosimError(f"{out}: the output would overwrite the log; choose another --out")
    with LogReader(log) as reader:
        if fmt == "rosbag2":
            return _export_bag(reader, out, start_ns)
        part = temporary_beside(out, FORMATS[fmt])  # asammdf insists on its suffix
        imported = LogMetadata.read(reader.metadata()).imported
        caveat = times_caveat(imported.time_zone) if imported is not None else None
        warnings = [caveat] if caveat is not None else []
        start, what = None, "frames"
        try:
            if fmt in TABLE_FORMATS:
                count = _export_table(reader, fmt, part, warnings)
                what = "rows (ticks)" if imported is None else "rows (decoded frames)"
            else:
                start = start_ns if start_ns is not None else run_start_ns(reader, warnings)
                count = _export_frames(reader, fmt, part, dbc, start, out.name)
            part.replace(out)
        finally:
            part.unlink(missing_ok=True)
        start_of = "tick 0" if imported is None else "the first frame"
        return ExportResult(out, fmt, count, reader.warnings + warnings, start, what, start_of)


def _export_bag(reader: LogReader, out: Path, start_ns: int | None) -> ExportResult:
    """The log as a ROS 2 bag folder (``cosim.analysis.rosbag_export``), stamped as the frame logs."""
    from cosim.analysis.rosbag_export import write_bag

    warnings: list[str] = []
    start = start_ns if start_ns is not None else run_start_ns(reader, warnings)
    count = sum(write_bag(reader, out, start, _log_base(reader)).values())
    start_of = "tick 0" if LogMetadata.read(reader.metadata()).imported is None else "the first frame"
    return ExportResult(out, "rosbag2", count, reader.warnings + warnings, start, "messages", start_of)


def _log_base(reader: LogReader) -> int:
    """What a log time is counted from: an imported log's are its frames' own (since the epoch,
    from its start to the millisecond), a run's simulated time (from 0)."""
    return run_start_ns(reader, []) if LogMetadata.read(reader.metadata()).imported is not None else 0


def run_start_ns(reader: LogReader, warnings: list[str]) -> int:
    """The wall-clock start a frame log is stamped from: the run's (``cosim.run`` ``start_time_ns``)
    to the millisecond, or 0 (the epoch), with a warning, for a log that does not record it."""
    meta = LogMetadata.read(reader.metadata())
    if meta.imported is not None:  # its first frame's time, to the millisecond
        first = meta.imported.start_time_ns or 0
        return first - first % 1_000_000
    run = meta.run
    if run is None or run.start_time_ns is None:
        warnings.append(
            "the log does not record when the run started (written by an older cosim or another program): "
            "frames are stamped from the Unix epoch; give the date with --start-time"
        )
        return 0
    return run.start_time_ns - run.start_time_ns % 1_000_000


def parse_start_time(text: str) -> int:
    """``--start-time``: an ISO 8601 date and time (``2025-06-01T12:00:00+02:00``; UTC without a
    zone) or seconds since the Unix epoch (``0``: the epoch itself) → ns since the epoch."""
    try:
        seconds = float(text)
    except ValueError:
        try:
            when = datetime.fromisoformat(text)
        except ValueError:
            raise CosimError(
                f"--start-time {text!r}: give an ISO 8601 date and time (2025-06-01T12:00:00Z, UTC without a zone) "
                "or seconds since the Unix epoch (0: the epoch)"
            ) from None
        if when.tzinfo is None:
            when = when.replace(tzinfo=UTC)
        delta = when - datetime(1970, 1, 1, tzinfo=UTC)
        return (delta.days * 86_400 + delta.seconds) * 1_000_000_000 + delta.microseconds * 1000
    if not (0 <= seconds < 2**33):
        raise CosimError(f"--start-time {text}: seconds since the Unix epoch must be >= 0 (and before the year 2242)")
    return round(seconds * 1e9)


# -- tidy tables ----------------------------------------------------------------------------------


def table_columns(
    schemas: dict[str, dict[str, Any]], dbc: str | bytes | None = None, imported: bool = False
) -> list[Column]:
    """The tidy table's columns, from the JSON Schemas of the log's topics and its DBC (which names
    a node's packed messages after the node, ``cosim.analysis.names``): ``tick``, ``t [s]``, the
    truth topics, then the decoded data messages in channel order. An ``imported`` log (``cosim
    import``) has no ticks: ``time [ns]`` (the frame's, since the Unix epoch), ``t [s]`` (since the
    log's first frame), then every decoded message."""
    if imported:
        columns = [
            Column("time [ns]", "", (), "int", "ns", "the frame's timestamp, ns since the Unix epoch"),
            Column("t [s]", "", (), "float", "s", "time since the log's first frame"),
            Column(MESSAGE_COLUMN, "", (), "text", "", "the DBC message the frame decoded as"),
        ]
    else:
        columns = [
            Column("tick", "", (), "int", "", "tick counter k"),
            Column("t [s]", "", (), "float", "s", "simulated time t_k"),
        ]
    known = {} if imported else names.prefixes(dbc)
    decoded = [
        t for t in schemas if t.startswith("/can/") and t != FRAMES and (imported or not CONTROL_MESSAGES.match(t))
    ]
    for topic in [t for t in TRUTH_TOPICS if t in schemas] + decoded:
        properties = {k: v for k, v in schemas[topic].get("properties", {}).items() if k not in ("tick", "t")}
        columns += _flatten(topic, names.prefix(topic, known), (), properties)
    seen: dict[str, Column] = {}
    for column in columns:
        if column.name in seen:
            raise LogError(
                f"columns {_source(seen[column.name])} and {_source(column)} would both be named {column.name!r}"
            )
        seen[column.name] = column
    return columns


def _flatten(topic: str, prefix: str, path: tuple[str, ...], properties: dict[str, Any]) -> list[Column]:
    columns = []
    for key, schema in properties.items():
        here = (*path, key)
        types = schema.get("type", "")
        types = [types] if isinstance(types, str) else list(types)
        if "object" in types:
            columns += _flatten(topic, prefix, here, schema.get("properties", {}))
            continue
        kind = (
            "int" if "integer" in types else "float" if "number" in types else "bool" if "boolean" in types else "text"
        )
        description = schema.get("description", "")
        match = _UNIT.search(description)
        unit = match.group(1) if match else ""
        name = ".".join((prefix, *here)) + (f" [{unit}]" if unit else "")
        columns.append(Column(name, topic, here, kind, unit, description))
    return columns


def table_rows(reader: LogReader, columns: list[Column], warnings: list[str]) -> Iterator[list[Any]]:
    """Rows of the tidy table in tick order, one per tick, each a list aligned with ``columns``.

    Holds at most ROW_WINDOW open rows: memory does not grow with the length of the log."""
    run = LogMetadata.read(reader.metadata()).run
    if run is None or run.dt_ns is None:
        raise LogError(
            f"{reader.path}: no cosim.run metadata, so not a log of 'cosim run'; tidy tables need its ticks "
            f"and truth (export its frames with --to blf, mf4 or candump)"
        )
    dt_ns = run.dt_ns
    fields: dict[str, list[tuple[int, tuple[str, ...], str]]] = {}
    for i, column in enumerate(columns):
        if column.topic:
            fields.setdefault(column.topic, []).append((i, column.path, column.kind))
    open_rows: dict[int, list[Any]] = {}
    newest = -1
    late = 0
    for topic, log_time, message in reader.messages(list(fields)):
        logged_tick = log_time // dt_ns
        counter = message.get("tick")
        if topic.startswith("/can/") and isinstance(counter, int):
            k = carried_tick(logged_tick, counter)
        else:
            k = counter if isinstance(counter, int) else logged_tick
        if k > newest:
            newest = k
            for old in sorted(t for t in open_rows if t <= newest - ROW_WINDOW):
                yield open_rows.pop(old)
        elif k <= newest - ROW_WINDOW:
            late += 1
            continue
        row = open_rows.get(k)
        if row is None:
            row = open_rows[k] = [None] * len(columns)
            row[0], row[1] = k, k * dt_ns / 1e9
        for i, path, kind in fields[topic]:
            row[i] = _cell(message, path, kind)
    for k in sorted(open_rows):
        yield open_rows[k]
    if late:
        warnings.append(
            f"{late} messages came more than {ROW_WINDOW} ticks after their tick and were left out of the table"
        )


def imported_rows(reader: LogReader, columns: list[Column], start_ns: int) -> Iterator[list[Any]]:
    """Rows of an imported log's table (``cosim import``), one per decoded frame in the log's
    order, a message without signals included: its time, its message, then its message's
    signals (the other messages' cells empty)."""
    fields: dict[str, list[tuple[int, tuple[str, ...], str]]] = {
        topic: [] for topic in reader.schemas() if topic.startswith("/can/") and topic != FRAMES
    }
    for i, column in enumerate(columns):
        if column.topic:
            fields[column.topic].append((i, column.path, column.kind))
    for topic, log_time, message in reader.messages(list(fields)):
        row: list[Any] = [None] * len(columns)
        row[0], row[1], row[2] = log_time, (log_time - start_ns) / 1e9, topic.removeprefix("/can/")
        for i, path, kind in fields[topic]:
            row[i] = _cell(message, path, kind)
        yield row


def _cell(message: dict[str, Any], path: tuple[str, ...], kind: str) -> Any:
    value: Any = message
    for key in path:
        if not isinstance(value, dict):
            return None
        value = value.get(key)
    if isinstance(value, list):
        return ",".join(str(item) for item in value)
    if kind == "float" and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value


def _export_table(reader: LogReader, fmt: str, path: Path, warnings: list[str]) -> int:
    imported = LogMetadata.read(reader.metadata()).imported
    columns = table_columns(reader.schemas(), reader.attachments().get(DBC_ATTACHMENT), imported is not None)
    if fmt == "parquet":
        require("pyarrow", "cosim export --to parquet")
    if imported is not None:
        rows = imported_rows(reader, columns, imported.start_time_ns or 0)
    else:
        rows = table_rows(reader, columns, warnings)
    return _write_csv(path, columns, rows) if fmt == "csv" else _write_parquet(path, columns, rows, reader)


def _write_csv(path: Path, columns: list[Column], rows: Iterator[list[Any]]) -> int:
    count = 0
    with open(path, "w", newline="") as stream:
        writer = csv.writer(stream)
        writer.writerow([c.name for c in columns])
        for row in rows:  # floats are written as repr(): the shortest text that reads back exactly
            writer.writerow(row)
            count += 1
    return count


def _write_parquet(path: Path, columns: list[Column], rows: Iterator[list[Any]], reader: LogReader) -> int:
    import pyarrow as pa
    import pyarrow.parquet as pq

    types = {"int": pa.int64(), "float": pa.float64(), "bool": pa.bool_(), "text": pa.string()}
    schema = pa.schema(
        [
            pa.field(
                c.name, types[c.kind], metadata={"unit": c.unit, "description": c.description, "source": _source(c)}
            )
            for c in columns
        ],
        metadata={RUN: json.dumps(reader.metadata().get(RUN, {})), "cosim.source_log": reader.path.name},
    )
    count = 0
    with pq.ParquetWriter(path, schema, compression="zstd") as writer:
        batch: list[list[Any]] = []

        def flush() -> None:
            arrays = [pa.array([row[i] for row in batch], type=schema.field(i).type) for i in range(len(columns))]
            writer.write_batch(pa.RecordBatch.from_arrays(arrays, schema=schema))
            batch.clear()

        for row in rows:
            batch.append(row)
            count += 1
            if len(batch) == PARQUET_BATCH_ROWS:
                flush()
        if batch:
            flush()
    return count


def _source(column: Column) -> str:
    """Where a column comes from, as a message path (``/truth/state.x1``), as Foxglove writes it."""
    return ".".join((column.topic, *column.path)) if column.topic else column.name


# -- frame logs -----------------------------------------------------------------------------------


def frames(reader: LogReader, base_ns: int = 0) -> Iterator[tuple[int, dict[str, Any]]]:
    """(log_time_ns − ``base_ns``, frame record) of every frame of ``/can/frames``, in bus order."""
    for _, log_time, frame in reader.messages([FRAMES]):
        yield log_time - base_ns, frame


def _export_frames(reader: LogReader, fmt: str, path: Path, dbc: str | Path | None, start_ns: int, title: str) -> int:
    if FRAMES not in reader.schemas():
        raise LogError(
            f"{reader.path}: the log has no {FRAMES} topic, so no CAN frames to export; "
            f"tables of its messages come with --to csv or parquet"
        )
    base = _log_base(reader)
    if fmt == "mf4":
        require("asammdf", "cosim export --to mf4")
        return _write_mf4(path, frames(reader, base), _dbc_text(reader, dbc), start_ns)
    return _write_frame_log(fmt, path, frames(reader, base), start_ns, title)


def _dbc_text(reader: LogReader, dbc: str | Path | None) -> bytes:
    if dbc is not None:
        try:
            return Path(dbc).read_bytes()
        except OSError as error:
            raise CosimError(
                f"--dbc {dbc}: cannot be read ({error.strerror}); write one with 'cosim dbc SCENARIO --out FILE.dbc'"
            ) from None
    attached = reader.attachments().get(DBC_ATTACHMENT)
    if attached is None:
        raise LogError(
            f"{reader.path}: no DBC attached ({DBC_ATTACHMENT}), and the MF4 bus log carries one; pass "
            f"--dbc FILE.dbc (write it with 'cosim dbc SCENARIO --out FILE.dbc' for the run's scenario)"
        )
    return attached


def can_message(time_ns: int, frame: dict[str, Any]) -> can.Message:
    """The python-can message of a ``/can/frames`` record, stamped ``time_ns`` (ns since the epoch)."""
    import can

    return can.Message(
        timestamp=time_ns / 1e9,
        arbitration_id=frame["id"],
        is_extended_id=frame["extended"],
        is_fd=frame["fd"],
        bitrate_switch=frame["brs"],
        data=bytes.fromhex(frame["data"]),
    )


def _python_can_writer(fmt: str, path: Path, start_ns: int, title: str) -> Any:
    """python-can's writer of a frame-log format (BLF and ASC on channel 1, candump on ``can0``),
    its header dated at the run's start and naming the file ``title``, so that an export is the
    same bytes whenever and wherever it is made."""
    import can

    if fmt == "blf":
        blf = can.BLFWriter(path, channel=1)
        # The header's start time is in milliseconds and objects are stamped in ns after it: start
        # there (a whole millisecond) rather than at the first frame's time truncated.
        blf.start_timestamp = start_ns / 1e9
        return blf
    if fmt == "asc":
        asc = can.ASCWriter(path, channel=1)
        # Its header's date is the export's; its trigger block's (local time, as CANoe writes it)
        # the first frame's: the header gets the run's date in the same form.
        started = datetime.fromtimestamp(start_ns / 1e9)
        date = started.strftime(f"%a %b %d %H:%M:%S.{started.microsecond // 1000:03d} %Y")
        text: Any = asc.file  # opened in text mode
        text.seek(0)
        text.truncate()
        text.write(f"date {date}\nbase hex  timestamps absolute\ninternal events logged\n")
        return asc
    if fmt == "trc":
        trc = can.TRCWriter(path, channel=1)
        trc.filepath = title  # the header names the file: the final name, not the path written to
        return trc
    return can.CanutilsLogWriter(path, channel=CANDUMP_INTERFACE)


def _write_frame_log(
    fmt: str, path: Path, source: Iterator[tuple[int, dict[str, Any]]], start_ns: int, title: str
) -> int:
    count = 0
    with _python_can_writer(fmt, path, start_ns, title) as writer:
        for log_time, frame in source:
            if fmt == "trc" and frame["fd"]:  # python-can's TRC writer would leave it out with a log line
                raise CosimError(
                    "--to trc: the log has CAN FD frames, which python-can's TRC writer does not write; "
                    "export them with --to asc, blf, candump or mf4"
                )
            writer.on_message_received(can_message(start_ns + log_time, frame))
            count += 1
    return count


def mf4_frame_dtype() -> np.dtype:
    """The record of ASAM MDF bus logging's CAN_DataFrame channel group, as asammdf reads it."""
    import numpy as np

    return np.dtype(
        [
            ("CAN_DataFrame.BusChannel", "<u1"),
            ("CAN_DataFrame.ID", "<u4"),
            ("CAN_DataFrame.IDE", "<u1"),
            ("CAN_DataFrame.DLC", "<u1"),
            ("CAN_DataFrame.DataLength", "<u1"),
            ("CAN_DataFrame.DataBytes", "(64,)u1"),
            ("CAN_DataFrame.Dir", "<u1"),
            ("CAN_DataFrame.EDL", "<u1"),
            ("CAN_DataFrame.BRS", "<u1"),
            ("CAN_DataFrame.ESI", "<u1"),
        ]
    )


def _write_mf4(path: Path, source: Iterator[tuple[int, dict[str, Any]]], dbc: bytes, start_ns: int) -> int:
    import numpy as np
    from asammdf import MDF, Signal, Source

    dtype = mf4_frame_dtype()
    mdf = MDF(version="4.10")
    mdf.configure(read_fragment_size=MF4_FRAGMENT_BYTES, write_fragment_size=MF4_FRAGMENT_BYTES)
    try:
        start = datetime.fromtimestamp(start_ns // 1_000_000_000, UTC).replace(
            microsecond=start_ns % 1_000_000_000 // 1000
        )
        mdf.start_time = start  # the frames' timestamps are simulated time after it
        bus = Source("CAN", "CAN", "cosim run: the CAN bus", Source.SOURCE_BUS, Source.BUS_TYPE_CAN)
        mdf.append(
            Signal(
                name="CAN_DataFrame",
                samples=np.zeros(0, dtype=dtype),
                timestamps=np.zeros(0, dtype="<f8"),
                # asammdf's Signal annotates the name as a Path, but hands it to MDF4.attach, whose
                # file_name is a str or a path; the name stays a str, as the readers look it up.
                attachment=(dbc, DBC_ATTACHMENT, md5(dbc).digest()),  # type: ignore[arg-type]
                source=bus,
            ),
            acq_name="CAN",
            acq_source=bus,
            comment="cosim run: every frame on the bus; timestamps are simulated time after the start time",
        )
        batch: list[tuple] = []  # (t_ns, id, extended, dlc, length, data hex, fd, brs): small, unlike the dicts
        count = 0

        def flush() -> None:
            t_ns, ids, extended, dlc, length, data, fd, brs = (np.array(column) for column in zip(*batch))
            records = np.zeros(len(batch), dtype=dtype)
            records["CAN_DataFrame.BusChannel"] = 1
            records["CAN_DataFrame.ID"] = ids.astype("u4") | (
                extended.astype("u4") << 31
            )  # bit 31 flags an extended id
            records["CAN_DataFrame.IDE"] = extended
            records["CAN_DataFrame.DLC"] = dlc
            records["CAN_DataFrame.DataLength"] = length
            padded = b"".join(bytes.fromhex(text).ljust(64, b"\0") for text in data)
            records["CAN_DataFrame.DataBytes"] = np.frombuffer(padded, dtype="u1").reshape(len(batch), 64)
            records["CAN_DataFrame.EDL"] = fd
            records["CAN_DataFrame.BRS"] = brs
            mdf.extend(0, [(t_ns.astype("<i8") / 1e9, None), (records, None)])
            batch.clear()

        for log_time, f in source:
            batch.append((log_time, f["id"], f["extended"], f["dlc"], f["length"], f["data"], f["fd"], f["brs"]))
            count += 1
            if len(batch) == MF4_BATCH_FRAMES:
                flush()
        if batch:
            flush()
        for entry in mdf.file_history:  # asammdf stamps its history with the wall clock: the run's start instead
            entry.abs_time = start_ns
        mdf.save(path, overwrite=True, compression=2, add_history_block=False)
    finally:
        mdf.close()
    return count
