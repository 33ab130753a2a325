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

Every message's log time is the frame's own timestamp, in ns since the Unix epoch where the
format records the date (a bag's: the time rosbag2 recorded it, exact to the ns): Foxglove shows
when the bus was recorded. Error and remote frames carry
no signals and are left out (counted). A log of several channels (buses) is decoded whole by the
one DBC, with a warning, unless one ``channel`` is asked for (a bag's topic): its frames alone are
imported. The file is written beside the output and renamed into place once complete: an import that fails or
is interrupted leaves nothing under the name.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import can
from cantools.database.can import Message

from cosim.bus.bag_frames import bag_format, is_bag, read_bag
from cosim.bus.canlogs import channel_name, log_format, read_frames
from cosim.bus.foreign import FrameDecoder, read_dbc
from cosim.errors import CosimError
from cosim.files import temporary_beside
from cosim.log.metadata import DBC_ATTACHMENT, IMPORT, VERSIONS, ImportRecord, versions
from cosim.log.topics import FRAMES, CanFrame, integer, message_topic, prop, text, topic
from cosim.log.writer import McapLog, number

#: Choices shown in a signal's description, at most (a DTC table may have hundreds).
CHOICES_SHOWN = 16


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


class Recorded(NamedTuple):
    """A frame as its log recorded it: on which channel (a bag's topic), when (ns since the epoch),
    and a bag's header stamp."""

    frame: can.Message
    channel: str | None
    time_ns: int
    stamp_ns: int | None = None


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
    kind = "extended" if message.is_extended_frame else "standard"
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": message.name,
        "description": f"{message.name}: decoded signals of {kind} id 0x{message.frame_id:X}",
        "type": "object",
        "properties": properties,
        "required": [s.name for s in message.signals if not s.multiplexer_ids],
    }


def import_log(source: str | Path, dbc: str | Path, out: str | Path, channel: str | None = None) -> ImportResult:
    """Write the MCAP log ``out`` of the CAN log or ROS 2 bag ``source`` decoded by the DBC file
    ``dbc``: of its frames on ``channel`` only (as the log names it, ``channel_name``; a bag's
    topic), or of all of them."""
    source, dbc, out = Path(source), Path(dbc), Path(out)
    fmt = _format(source)
    decoder = FrameDecoder(read_dbc(dbc))
    if any(message_topic(m.name) == FRAMES for m in decoder.database.messages):
        raise CosimError(f"{dbc}: a message named 'frames' would share the topic {FRAMES} with the frames")
    if out.suffix != ".mcap":
        raise CosimError(f"--out {out}: an MCAP file (.mcap)")
    if out.resolve() == source.resolve():
        raise CosimError(f"--out {out}: the output would overwrite the bag; choose another --out")
    part = temporary_beside(out, ".mcap")
    try:
        with McapLog(part) as log:
            result = _write(log, source, fmt, dbc, decoder, channel)
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


def _write(log: McapLog, source: Path, fmt: str, dbc: Path, decoder: FrameDecoder, wanted: str | None) -> ImportResult:
    frames_channel = log.channel(FRAMES, ImportedFrame.schema())
    channels: dict[str, int] = {}
    topics: Counter[str] = Counter()
    unknown: Counter[str] = Counter()
    on_channel: Counter[str | None] = Counter()
    warnings: list[str] = []
    count = decoded_count = undecodable = skipped = 0
    first = last = None
    for frame, recorded_on, time_ns, stamp in _frames_on(source, fmt, wanted, on_channel, warnings):
        if frame.is_error_frame or frame.is_remote_frame:
            skipped += 1
            continue
        if time_ns < 0:
            raise CosimError(f"{source}: frame {count} is stamped before the Unix epoch ({time_ns / 1e9:g} s)")
        first = time_ns if first is None else first
        last = time_ns
        message = decoder.message(frame)
        sender = (message.senders[0] if message.senders else "unknown") if message is not None else "unknown"
        name = message.name if message is not None else None
        payload = ImportedFrame.payload(count, (time_ns - first) / 1e9, count, frame, sender, name, recorded_on, stamp)
        log.write(frames_channel, time_ns, payload)
        count += 1
        if message is None:
            unknown[_hex_id(frame)] += 1
            continue
        decoded = decoder.decode(frame)
        if decoded is None:
            undecodable += 1
            continue
        topic = message_topic(message.name)
        channel = channels.get(topic)
        if channel is None:
            channel = channels[topic] = log.channel(topic, signals_schema(message))
        log.write(channel, time_ns, decoded[1])
        topics[topic] += 1
        decoded_count += 1
    counts = (count, decoded_count, sum(unknown.values()), undecodable, skipped)
    others = sum(n for c, n in on_channel.items() if c != wanted) if wanted is not None else 0
    record = ImportRecord(source.name, fmt, dbc.name, *counts, first, last, wanted or "", others)
    log.metadata(IMPORT, record.to_metadata())
    log.metadata(VERSIONS, versions())
    log.attach(DBC_ATTACHMENT, "text/plain", dbc.read_bytes(), first or 0)
    warnings += _warnings(record, unknown, on_channel)
    return ImportResult(Path(), record, dict(topics), unknown, on_channel, warnings)


def _frames_on(
    source: Path, fmt: str, wanted: str | None, on_channel: Counter[str | None], warnings: list[str]
) -> Iterator[Recorded]:
    """The log's frames on the ``wanted`` channel (None: all), each with its channel's name; the
    frames of every channel counted in ``on_channel``."""
    for recorded in _recorded(source, fmt, warnings, wanted):
        on_channel[recorded.channel] += 1
        if wanted is None or recorded.channel == wanted:
            yield recorded


def _recorded(source: Path, fmt: str, warnings: list[str], wanted: str | None) -> Iterator[Recorded]:
    """Every frame of a log or bag as recorded: a bag's times are its own integer ns, a log's
    seconds (python-can's) rounded to the ns."""
    if is_bag(source):
        for found in read_bag(source, warnings, wanted):
            yield Recorded(found.frame, found.topic, found.time_ns, found.stamp_ns)
        return
    for frame in read_frames(source, warnings):
        yield Recorded(frame, channel_name(frame, fmt), round(frame.timestamp * 1e9))


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


def _warnings(record: ImportRecord, unknown: Counter[str], on_channel: Counter[str | None]) -> list[str]:
    """What the DBC did not decode, said where the counts are shown, and the channels it decoded
    as one where the log has several and no ``--channel`` picked one."""
    warnings = []
    if not record.channel and len(on_channel) > 1:
        warnings.append(
            f"{record.source} holds frames of {len(on_channel)} {_kind(record.format)} ({_channels(on_channel)}), "
            f"all decoded by the one DBC; {_option(record.format, True)} imports one {_kind(record.format)[:-1]}'s"
        )
    if record.unknown:
        ids = ", ".join(f"{frame_id} ({n})" for frame_id, n in unknown.most_common(5))
        more = f" and {len(unknown) - 5} more" if len(unknown) > 5 else ""
        warnings.append(
            f"{record.unknown} frames on {len(unknown)} ids the DBC does not describe ({ids}{more}): in {FRAMES} only"
        )
    if record.undecodable:
        warnings.append(
            f"{record.undecodable} frames on the DBC's ids are not frames of their message (too short, or a "
            f"multiplexer value it does not list): in {FRAMES} only"
        )
    if record.skipped:
        warnings.append(f"{record.skipped} error or remote frames carry no signals and were left out")
    return warnings
