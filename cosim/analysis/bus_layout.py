"""Foxglove layouts and figures of an imported bus log (``cosim import``): a plot per DBC message.

An imported log has no run (no truth, no estimators): what there is to see is each decoded
message's signals over time. ``messages`` reads which there are from the log's topics and JSON
Schemas (a topic per message that occurs, a number per signal with its unit in its description);
``build`` lays them out for Foxglove (``cosim layout``), a tab per sending node of the DBC with at
most ``PANELS_PER_TAB`` plots, each message's signals in one plot against the frames' recorded
time (their log time); ``plot`` draws them with matplotlib (``cosim plot``), one figure per
message, a panel per unit.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from cosim.analysis.layout import COLORS, _Builder, _plot, _series, _tree
from cosim.errors import LogError
from cosim.extras import require
from cosim.log.metadata import LogMetadata
from cosim.log.reader import LogReader
from cosim.log.topics import FRAMES

if TYPE_CHECKING:
    from cosim.analysis.canvas import Style

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
    """The Foxglove layout of an imported log's messages."""
    b = _Builder()
    by_sender: dict[str, list[Message]] = {}
    for message in found:
        by_sender.setdefault(message.sender, []).append(message)
    for sender, group in sorted(by_sender.items()):
        for first in range(0, len(group), PANELS_PER_TAB):
            part = group[first : first + PANELS_PER_TAB]
            title = sender if len(group) <= PANELS_PER_TAB else f"{sender} {first // PANELS_PER_TAB + 1}"
            b.tab(title, [(f"Plot!{m.name}", _message_plot(m)) for m in part])
    if not b.tabs:
        raise LogError("the log has no decoded messages to lay out (its DBC described none of its frames)")
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


def plot(
    path: str | Path, out: Path, fmt: str, dpi: int, style: Style, title: bool, metadata: dict[str, Any]
) -> list[Path]:
    """One figure per decoded message of an imported log: its signals against the time since the
    log's first frame, a panel per unit (a signal without one alone in its panel), drawn as the
    steps a bus holds a value in; as wide as ``style`` says (a paper's exactly so), titled or not."""
    require("matplotlib", "cosim plot")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with LogReader(path) as reader:
        record = LogMetadata.read(reader.metadata()).imported
        start = (record.start_time_ns or 0) if record is not None else 0
        found = messages(reader)
        series: dict[str, tuple[list[float], dict[str, list[float]]]] = {
            m.topic: ([], {name: [] for name in m.units}) for m in found
        }
        for topic, log_time, decoded in reader.messages(list(series)):  # one pass over the log
            times, values = series[topic]
            times.append((log_time - start) / 1e9)
            for name, column in values.items():
                value = decoded.get(name)
                column.append(float(value) if isinstance(value, (int, float)) else np.nan)
    written = []
    with plt.rc_context(style.rc):
        for message in found:
            times, values = series[message.topic]
            panels: dict[str, list[str]] = {}
            for name, unit in message.units.items():
                panels.setdefault(unit or f"\0{name}", []).append(name)
            fig, axes = plt.subplots(
                len(panels),
                1,
                figsize=(style.width, max(2.8, 2.0 * len(panels) + 0.6) * style.scale),
                squeeze=False,
                layout="constrained",
            )
            for ax, (unit, names) in zip(axes[:, 0], panels.items()):
                for name in names:
                    ax.plot(times, values[name], lw=1, label=name, drawstyle="steps-post")
                ax.set_ylabel(names[0] if unit.startswith("\0") else f"[{unit}]")
                ax.legend(loc="best")
            axes[-1, 0].set_xlabel(f"time since the log's first frame, {_date(start)} [s]")
            if title:
                fig.suptitle(f"{Path(path).stem}: {message.name} (sent by {message.sender})", wrap=True)
            target = out / f"{_file_name(message.name)}.{fmt}"
            tight: dict[str, Any] = {"bbox_inches": "tight", "pad_inches": 0.08} if style.name == "screen" else {}
            fig.savefig(target, dpi=dpi, metadata=metadata, **tight)
            plt.close(fig)
            written.append(target)
    return written


def _date(time_ns: int) -> str:
    """A frame's time as a date (UTC, to the millisecond)."""
    when = datetime.fromtimestamp(time_ns / 1e9, UTC)
    return when.isoformat(sep=" ", timespec="milliseconds").replace("+00:00", " UTC")


def _file_name(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "-", name).strip("-") or "message"
