"""Foxglove layouts of an imported bus log (``cosim import``), a plot per DBC message, and the
messages its figures draw.

An imported log has no run (no truth, no estimators): what there is to see is each decoded
message's signals over time. ``messages`` reads which there are from the log's topics and JSON
Schemas (a topic per message that occurs, a number per signal with its unit in its description);
``build`` lays them out for Foxglove (``cosim layout``), a tab per sending node of the DBC with at
most ``PANELS_PER_TAB`` plots, each message's signals in one plot against the frames' recorded
time (their log time); ``cosim.analysis.bus_figures`` draws them with matplotlib (``cosim plot``).
A J1939 message's ``source_address`` is not a signal: it is left out of the plots.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cosim.analysis.layout import COLORS, _Builder, _plot, _series, _tree
from cosim.errors import LogError
from cosim.log.can_import import SOURCE_ADDRESS
from cosim.log.metadata import LogMetadata
from cosim.log.reader import LogReader
from cosim.log.topics import FRAMES

PANELS_PER_TAB = 6
_UNIT = re.compile(r"\[([^\[\]]*)\]\s*$")  # cosim.log.writer.number writes "<description> [<unit>]"


@dataclass
class Message:
    """A decoded message of the log: its topic, its sender (from the frames) and its signals' units."""

    topic: str
    name: str
    sender: str = "unknown"
    units: dict[str, str] = field(default_factory=dict)


def is_imported(path: str | Path) -> bool:
    """Whether a log was written by ``cosim import`` (it has ``cosim.import`` metadata)."""
    with LogReader(path) as reader:
        return LogMetadata.read(reader.metadata()).imported is not None


def messages(reader: LogReader) -> list[Message]:
    """The decoded messages of an imported log, in topic order, with their senders and units."""
    found = []
    for topic, schema in reader.schemas().items():
        if not topic.startswith("/can/") or topic == FRAMES:
            continue
        units = {}
        for name, signal in schema.get("properties", {}).items():
            if name == SOURCE_ADDRESS:
                continue
            match = _UNIT.search(signal.get("description", "")) if isinstance(signal, dict) else None
            units[name] = match.group(1) if match else ""
        found.append(Message(topic, topic.removeprefix("/can/"), units=units))
    senders: dict[str, str] = {}
    wanted = {m.name for m in found}
    for _, _, frame in reader.messages([FRAMES]):  # a frame of each message names its sender
        if frame.get("message") in wanted and frame["message"] not in senders:
            senders[frame["message"]] = str(frame.get("sender") or "unknown")
            if len(senders) == len(wanted):
                break
    for message in found:
        message.sender = senders.get(message.name, "unknown")
    return found


def build(found: list[Message]) -> dict[str, Any]:
    """The Foxglove layout of an imported log's messages (those without signals have nothing to plot)."""
    b = _Builder()
    by_sender: dict[str, list[Message]] = {}
    for message in (m for m in found if m.units):
        by_sender.setdefault(message.sender, []).append(message)
    for sender, group in sorted(by_sender.items()):
        for first in range(0, len(group), PANELS_PER_TAB):
            part = group[first : first + PANELS_PER_TAB]
            title = sender if len(group) <= PANELS_PER_TAB else f"{sender} {first // PANELS_PER_TAB + 1}"
            b.tab(title, [(f"Plot!{m.name}", _message_plot(m)) for m in part])
    if not b.tabs:
        raise LogError(
            "the log has no decoded signals to lay out (its DBC described none of its frames, or only messages "
            "without signals)"
        )
    tab_config = {"activeTabIdx": 0, "tabs": [{"title": title, "layout": _tree(ids)} for title, ids in b.tabs]}
    return {
        "configById": {"Tab!cosim": tab_config, **b.panels},
        "globalVariables": {},
        "userNodes": {},
        "playbackConfig": {"speed": 1},
        "layout": "Tab!cosim",
    }


def _message_plot(message: Message) -> dict[str, Any]:
    units = sorted({unit for unit in message.units.values() if unit})
    series = [
        _series(f"{message.topic}.{name}", f"{name}{f' [{unit}]' if unit else ''}", COLORS[i % len(COLORS)])
        for i, (name, unit) in enumerate(message.units.items())
    ]
    return _plot(message.name, series, units[0] if len(units) == 1 else "")


def layout_of_log(path: str | Path) -> tuple[str, dict[str, Any]]:
    """The name and the Foxglove layout of an imported log."""
    with LogReader(path) as reader:
        return Path(path).stem, build(messages(reader))
