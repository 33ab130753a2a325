"""A CAN log from another tool, with its DBC, as an MCAP log: what ``cosim import`` writes.

The log is read frame by frame (``cosim.bus.canlogs``: candump, BLF, ASC, TRC, MF4, python-can's
CSV and SQLite; ``cosim.bus.bag_frames``: a ROS 2 bag's ``can_msgs/msg/Frame`` and
``ros2_socketcan_msgs/msg/FdFrame`` topics) and each frame decoded through cantools by the DBC
(``cosim.bus.foreign``: by its id and its own extended flag). The MCAP log holds

- ``/can/frames``: every data frame in the log's order, as a run logs its frames, with the
  channel the log recorded it on (``cosim.log.topics.ImportedFrame``; a bag's: the frame's ROS
  topic): ``tick`` and ``seq`` are the frame's position in the log (an imported log has no
  ticks), ``t`` the seconds since its first frame, ``sender`` and ``message`` from the DBC
  (``unknown`` and null for ids it does not describe), ``stamp`` a bag's header stamp;
- ``/can/<Message>``: each DBC message's decoded signals, one topic per message that occurs, its
  JSON Schema naming each signal's unit (``"<comment> [<unit>]"``, as a run's do) and its value
  table; a multiplexed message's signals are required only where they are in every frame. A
  signal with a value table is its number, as every signal (plots, exports and a value outside
  the table stay exact); its schema's description names the values (``0: Off, 1: On``; the first
  ``CHOICES_SHOWN``), the attached DBC has them all;
- the DBC as the ``cosim.dbc`` attachment, ``cosim.import`` metadata (``ImportRecord``) and
  ``cosim.versions``.

Every message's log time is the frame's own time, exactly as the log has it (``cosim.bus.canlogs``;
a bag's: the time rosbag2 recorded it, to the ns), in ns since the Unix epoch where the format
records the date: Foxglove shows when the bus was recorded. A log of local times (ASC, TRC, BLF) is
logged as if they were UTC with its zone ``unknown``, or converted to UTC from the ``timezone``
given; ``ImportRecord.time_zone`` says which. A J1939 message (``cosim.bus.foreign``) also keeps the
``source_address`` of each frame. Error and remote frames carry no signals and are left out
(counted, the remote ones by id). A log of several channels (buses) is decoded whole by the one
DBC, with a warning, unless one ``channel`` is asked for (a bag's topic): its frames alone are
imported. The file is written beside the output and renamed into place once complete: an import
that fails or is interrupted leaves nothing under the name.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
from cantools.database.can import Message

from cosim.bus.bag_frames import bag_format, is_bag, read_bag
from cosim.bus.canlogs import LogReading, channel_name, log_format, read_frames
from cosim.bus.foreign import FrameDecoder, is_j1939, read_dbc, source_address
from cosim.bus.log_clock import UTC, time_zone
from cosim.errors import CosimError
from cosim.files import temporary_beside
from cosim.log.metadata import DBC_ATTACHMENT, IMPORT, VERSIONS, ImportRecord, versions
from cosim.log.topics import FRAMES, CanFrame, integer, message_topic, prop, text, topic
from cosim.log.writer import McapLog, number

#: Choices shown in a signal's description, at most (a DTC table may have hundreds).
CHOICES_SHOWN = 16
#: The field of a J1939 message's record that keeps the address of the ECU that sent its frame.
SOURCE_ADDRESS = "source_address"
#: Ids named in a warning that counts frames by id, at most.
IDS_NAMED = 5


@topic(FRAMES, "cosim.ImportedFrame", "A frame of a CAN log another tool recorded (cosim import)")
class ImportedFrame(CanFrame):
    """``/can/frames`` of an imported log: a run's ``CanFrame`` and the channel the log recorded the
    frame on (``channel_name``). A run's frames keep their own record: a run has one bus."""

    channel: str | None = prop(
        text(
            "the channel the log recorded the frame on, as the log names it (a ROS 2 bag: its topic; null: it records "
            "none)",
            nullable=True,
        ),
        default=None,
    )
    stamp: int | None = prop(
        integer(
            "a ROS 2 bag's frame: its header stamp, ns since the Unix epoch (null: the log has none)", nullable=True
        ),
        default=None,
    )

    @staticmethod
    def payload(
        tick: int,
        t: float,
        seq: int,
        frame: can.Message,
        sender: str,
        message: str | None,
        channel: str | None = None,
        stamp: int | None = None,
    ) -> dict[str, Any]:
        return {**CanFrame.payload(tick, t, seq, frame, sender, message), "channel": channel, "stamp": stamp}


@dataclass
class ImportResult:
    """What an import wrote: the MCAP file, its record, the decoded topics, frames per id the DBC
    does not describe and per channel of the log (None: not recorded), and warnings."""

    path: Path
    record: ImportRecord
    topics: dict[str, int] = field(default_factory=dict)
    unknown_ids: Counter[str] = field(default_factory=Counter)
    channels: Counter[str | None] = field(default_factory=Counter)
    warnings: list[str] = field(default_factory=list)


def signals_schema(message: Message) -> dict[str, Any]:
    """The JSON Schema of a message's decoded signals: a number each, described by its comment (or
    name), unit and value table; required where every frame of the message carries it."""
    properties = {}
    for signal in message.signals:
        comment = signal.comment if isinstance(signal.comment, str) and signal.comment else signal.name
        if signal.choices:
            shown = list(signal.choices.items())[:CHOICES_SHOWN]
            more = ", ..." if len(signal.choices) > CHOICES_SHOWN else ""
            comment += f" ({', '.join(f'{value}: {name}' for value, name in shown)}{more})"
        properties[signal.name] = number(" ".join(comment.split()), signal.unit or "")
    if is_j1939(message):
        properties[SOURCE_ADDRESS] = {
            "type": "integer",
            "description": "J1939 source address: the ECU that sent the frame (its id's low byte)",
        }
    kind = "extended" if message.is_extended_frame else "standard"
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": message.name,
        "description": f"{message.name}: decoded signals of {kind} id 0x{message.frame_id:X}",
        "type": "object",
        "properties": properties,
        "required": [s.name for s in message.signals if not s.multiplexer_ids]
        + ([SOURCE_ADDRESS] if is_j1939(message) else []),
    }


def import_log(
    source: str | Path, dbc: str | Path, out: str | Path, channel: str | None = None, timezone: str | None = None
) -> ImportResult:
    """Write the MCAP log ``out`` of the CAN log or ROS 2 bag ``source`` decoded by the DBC file
    ``dbc``: of its frames on ``channel`` only (as the log names it, ``channel_name``; a bag's
    topic), or of all of them; a log of local times recorded in the zone ``timezone`` (an IANA name
    or UTC) logged in UTC."""
    source, dbc, out = Path(source), Path(dbc), Path(out)
    fmt = _format(source)
    if timezone is not None and is_bag(source):
        raise CosimError("--timezone: a ROS 2 bag's times are ns since the Unix epoch (UTC) already")
    zone = time_zone(timezone) if timezone is not None else None
    decoder = FrameDecoder(read_dbc(dbc))
    _check_names(dbc, decoder)
    if out.suffix != ".mcap":
        raise CosimError(f"--out {out}: an MCAP file (.mcap)")
    if out.resolve() == source.resolve():
        raise CosimError(f"--out {out}: the output would overwrite the bag; choose another --out")
    part = temporary_beside(out, ".mcap")
    try:
        with McapLog(part) as log:
            importer = _Importer(log, decoder)
            reading = LogReading()
            for frame, time_ns, recorded_on, stamp in _recorded(source, fmt, reading, zone, channel):
                importer.on_channel[recorded_on] += 1
                if channel is None or recorded_on == channel:
                    importer.add(source, frame, time_ns, recorded_on, stamp)
            result = importer.finish(source, fmt, dbc, channel, reading)
        if channel is not None and channel not in result.channels:
            found = result.channels
            where = (
                "its format records no channel" if list(found) == [None] else f"its {_kind(fmt)}: {_channels(found)}"
            )
            raise CosimError(f"{_option(fmt)} {channel}: {source} has no frame on it; {where}")
        if result.record.frames == 0:
            raise CosimError(f"{source}: the log holds no CAN data frames")
        part.replace(out)
    finally:
        part.unlink(missing_ok=True)
    result.path = out
    return result


def _check_names(dbc: Path, decoder: FrameDecoder) -> None:
    """A DBC whose names would collide with the log's own: one line naming the message."""
    for message in decoder.database.messages:
        if message_topic(message.name) == FRAMES:
            raise CosimError(f"{dbc}: a message named 'frames' would share the topic {FRAMES} with the frames")
        if is_j1939(message) and any(s.name == SOURCE_ADDRESS for s in message.signals):
            raise CosimError(
                f"{dbc}: J1939 message {message.name} has a signal named {SOURCE_ADDRESS}, the field that keeps "
                "the source address of its frames; rename the signal"
            )


class _Importer:
    """The writing of one import: every data frame on ``/can/frames``, every decoded one on its
    message's topic, and counts of what was not decoded (frames per id) or left out."""

    def __init__(self, log: McapLog, decoder: FrameDecoder) -> None:
        self.log, self.decoder = log, decoder
        self.frames_channel = log.channel(FRAMES, ImportedFrame.schema())
        self.channels: dict[str, int] = {}
        self.topics: Counter[str] = Counter()
        self.unknown: Counter[str] = Counter()
        self.undecodable: Counter[str] = Counter()
        self.remote: Counter[str] = Counter()
        self.on_channel: Counter[str | None] = Counter()
        self.count = self.decoded = self.error_frames = 0
        self.first: int | None = None
        self.last: int | None = None

    def add(
        self, source: Path, frame: can.Message, time_ns: int, recorded_on: str | None, stamp: int | None = None
    ) -> None:
        """One frame of the log, recorded at ``time_ns`` on the channel ``recorded_on`` (a bag's
        frame: its topic, and ``stamp`` its header's)."""
        if frame.is_error_frame or frame.is_remote_frame:
            if frame.is_error_frame:
                self.error_frames += 1
            else:
                self.remote[_hex_id(frame)] += 1
            return
        if time_ns < 0:
            raise CosimError(f"{source}: frame {self.count} is stamped before the Unix epoch ({time_ns / 1e9:g} s)")
        self.first = time_ns if self.first is None else self.first
        self.last = time_ns
        message = self.decoder.message(frame)
        sender = (message.senders[0] if message.senders else "unknown") if message is not None else "unknown"
        name = message.name if message is not None else None
        t = (time_ns - self.first) / 1e9
        self.log.write(
            self.frames_channel,
            time_ns,
            ImportedFrame.payload(self.count, t, self.count, frame, sender, name, recorded_on, stamp),
        )
        self.count += 1
        decoded = self.decoder.decode(frame) if message is not None else None
        if decoded is None:
            (self.unknown if message is None else self.undecodable)[_hex_id(frame)] += 1
            return
        values = decoded[1]
        if is_j1939(decoded[0]):
            values = {**values, SOURCE_ADDRESS: source_address(frame.arbitration_id)}
        topic = message_topic(decoded[0].name)
        channel = self.channels.get(topic)
        if channel is None:
            channel = self.channels[topic] = self.log.channel(topic, signals_schema(decoded[0]))
        self.log.write(channel, time_ns, values)
        self.topics[topic] += 1
        self.decoded += 1

    def finish(self, source: Path, fmt: str, dbc: Path, wanted: str | None, reading: LogReading) -> ImportResult:
        """The import's metadata, DBC and versions written; what it found."""
        skipped = self.error_frames + sum(self.remote.values())
        counts = (self.count, self.decoded, sum(self.unknown.values()), sum(self.undecodable.values()), skipped)
        others = sum(n for c, n in self.on_channel.items() if c != wanted) if wanted is not None else 0
        record = ImportRecord(
            source.name, fmt, dbc.name, *counts, self.first, self.last, wanted or "", others, reading.time_zone
        )
        self.log.metadata(IMPORT, record.to_metadata())
        self.log.metadata(VERSIONS, versions())
        self.log.attach(DBC_ATTACHMENT, "text/plain", dbc.read_bytes(), self.first or 0)
        warnings = reading.warnings + self.warnings(record)
        return ImportResult(Path(), record, dict(self.topics), self.unknown, self.on_channel, warnings)

    def warnings(self, record: ImportRecord) -> list[str]:
        """What the DBC did not decode, each by its ids, said where the counts are shown, what was
        left out, and the channels decoded as one where the log has several and no ``--channel``
        picked one."""
        warnings = []
        if not record.channel and len(self.on_channel) > 1:
            kind = _kind(record.format)
            warnings.append(
                f"{record.source} holds frames of {len(self.on_channel)} {kind} ({_channels(self.on_channel)}), all "
                f"decoded by the one DBC; {_option(record.format, True)} imports the frames of one {kind[:-1]} alone"
            )
        if record.unknown:
            warnings.append(
                f"{record.unknown} frames on {len(self.unknown)} ids the DBC does not describe "
                f"({_ids(self.unknown)}): in {FRAMES} only"
            )
        if record.undecodable:
            warnings.append(
                f"{record.undecodable} frames on the DBC's ids are not frames of their message (too short, or a "
                f"multiplexer value it does not list: {_ids(self.undecodable)}): in {FRAMES} only"
            )
        if self.remote or self.error_frames:
            remote = f"{sum(self.remote.values())} remote frames ({_ids(self.remote)})" if self.remote else ""
            errors = f"{self.error_frames} error frames" if self.error_frames else ""
            warnings.append(f"left out {' and '.join(filter(None, (remote, errors)))}: they carry no signals")
        return warnings


def _recorded(
    source: Path, fmt: str, reading: LogReading, zone: Any, wanted: str | None
) -> Iterator[tuple[can.Message, int, str | None, int | None]]:
    """Every frame of a log or bag as recorded: the frame, its time (ns), its channel (a bag's
    topic) and a bag's header stamp. A bag's times are its own, UTC."""
    if is_bag(source):
        reading.time_zone = UTC
        for found in read_bag(source, reading.warnings, wanted):
            yield found.frame, found.time_ns, found.topic, found.stamp_ns
        return
    for frame, time_ns in read_frames(source, reading, zone):
        yield frame, time_ns, channel_name(frame, fmt), None


def _format(source: Path) -> str:
    """The format of a CAN log or bag; one line naming what cosim reads for any other file."""
    if is_bag(source):
        return bag_format(source)
    try:
        return log_format(source)
    except CosimError as error:
        raise CosimError(f"{error}; and ROS 2 bags (a rosbag2 folder, or its .mcap or .db3)") from None


def _option(fmt: str, metavar: bool = False) -> str:
    """The option that picks one channel of a log of this format (a bag's channels are its
    topics), with its argument's name where ``metavar``."""
    option, name = ("--topic", "TOPIC") if fmt.startswith("rosbag2") else ("--channel", "CH")
    return f"{option} {name}" if metavar else option


def _kind(fmt: str) -> str:
    return "topics" if fmt.startswith("rosbag2") else "channels"


def _ids(counts: Counter[str]) -> str:
    """Frames per id, the busiest first, as a warning names them."""
    named = ", ".join(f"{frame_id} ({n})" for frame_id, n in counts.most_common(IDS_NAMED))
    return named + (f" and {len(counts) - IDS_NAMED} more ids" if len(counts) > IDS_NAMED else "")


def _channels(counts: Counter[str | None]) -> str:
    """The channels of a log with their frames, as a line says them."""
    ordered = sorted(counts.items(), key=_by_name)
    return ", ".join(f"{c if c is not None else '(none)'} ({n} frames)" for c, n in ordered)


def _by_name(item: tuple[str | None, int]) -> tuple[int, str]:
    """Channels in their order: numbers as numbers (2 before 10), names after."""
    name = item[0] or ""
    return (0, f"{int(name):020d}") if name.isdigit() else (1, name)


def _hex_id(frame: can.Message) -> str:
    return f"0x{frame.arbitration_id:08X}" if frame.is_extended_id else f"0x{frame.arbitration_id:03X}"
