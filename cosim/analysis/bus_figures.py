"""Figures of an imported bus log (``cosim plot`` of a log ``cosim import`` wrote): each decoded
message's signals against time, on pages of a bounded size.

- A panel per unit; the signals without one that only take the values 0 and 1 (flags, the bits of
  a status byte) share panels, any other signal without a unit has a panel of its own.
- At most ``CURVES_PER_PANEL`` curves in a panel and ``PANELS_PER_FIGURE`` panels in a figure: a
  message of many signals gets several figures (``Status-1.png``, ``Status-2.png``, "page 1 of 2"),
  each of a size a screen shows.
- A J1939 message sent by several ECUs has a curve per source address (``EngineSpeed, SA 0x03``):
  their values are not one series.
- A message without signals gets no figure; a warning names those left out.
- The time axis counts seconds from the log's first frame and names its date in the zone the log
  records (``cosim.bus.log_clock.date_text``: UTC, a named zone, or "local time, zone unknown").

Signals are drawn as the steps a bus holds a value in. A curve of more than SAMPLES_PER_PIXEL
samples a pixel of the figure's width is drawn from the first, lowest, highest and last sample of
each stretch of about a pixel (``envelope``): what shows is the same at the figure's
resolution, and the drawing's work stays bounded however long the log.
Work that takes seconds says what it is doing (``cosim.progress``): reading the log, then each
message's figure.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from cosim import progress
from cosim.analysis.bus_layout import Message, messages
from cosim.bus.log_clock import UTC, date_text
from cosim.log.can_import import SOURCE_ADDRESS
from cosim.log.metadata import LogMetadata
from cosim.log.reader import LogReader

if TYPE_CHECKING:
    from matplotlib.axes import Axes

    from cosim.analysis.canvas import Style

CURVES_PER_PANEL = 8
PANELS_PER_FIGURE = 6
#: Samples a curve keeps per pixel of the figure's width, at most (``envelope``).
SAMPLES_PER_PIXEL = 4
_FLAGS = "\0flags"  # the panel key of the unitless 0/1 signals


@dataclass
class _Track:
    """The samples of one message from one sender: times (s since the first frame) and values."""

    times: list[float] = field(default_factory=list)
    values: dict[str, list[float]] = field(default_factory=dict)


def plot(
    path: str | Path,
    out: Path,
    fmt: str,
    dpi: int,
    style: Style,
    title: bool,
    metadata: dict[str, Any],
    warnings: list[str] | None = None,
) -> list[Path]:
    """The figures of an imported log's messages written into ``out`` as ``fmt``, as wide as
    ``style`` says (a paper's exactly so), titled or not; the files written. ``warnings`` gets the
    messages left out and what the log's times are where their zone is not known."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with LogReader(path) as reader:
        record = LogMetadata.read(reader.metadata()).imported
        start = (record.start_time_ns or 0) if record is not None else 0
        zone = record.time_zone if record is not None else UTC
        found = messages(reader)
        with progress.step(f"reading the {len(found)} decoded messages of {Path(path).name}"):
            tracks = _tracks(reader, found, start)
    bare = [m for m in found if not m.units]
    if bare and warnings is not None:
        named = ", ".join(f"{m.name} ({sum(len(t.times) for t in tracks[m.topic].values())} frames)" for m in bare)
        some = (
            "1 message carries no signals and has"
            if len(bare) == 1
            else f"{len(bare)} messages carry no signals and have"
        )
        warnings.append(f"{some} no figure: {named}")
    drawn = [m for m in found if m.units]
    when = date_text(start, zone)
    axis = "time since the log's first frame [s]" + (f", {when}" if when else " (the log records no date)")
    written: list[Path] = []
    with plt.rc_context(style.rc):
        for i, message in enumerate(drawn, 1):
            with progress.step(f"figure of {message.name}, {i} of {len(drawn)}"):
                pages = _pages(message, tracks[message.topic])
                for page, panels in enumerate(pages, 1):
                    heading = f"{Path(path).stem}: {message.name} (sent by {message.sender})"
                    heading += f", page {page} of {len(pages)}" if len(pages) > 1 else ""
                    fig = _figure(plt, style, panels, tracks[message.topic], axis, heading if title else None, dpi)
                    name = _file_name(message.name) + (f"-{page}" if len(pages) > 1 else "")
                    target = out / f"{name}.{fmt}"
                    tight: dict[str, Any] = (
                        {"bbox_inches": "tight", "pad_inches": 0.08} if style.name == "screen" else {}
                    )
                    fig.savefig(target, dpi=dpi, metadata=metadata, **tight)
                    plt.close(fig)
                    written.append(target)
    return written


def _tracks(reader: LogReader, found: list[Message], start: int) -> dict[str, dict[int | None, _Track]]:
    """Every message's samples, per source address (None: not a J1939 message), in one pass."""
    tracks: dict[str, dict[int | None, _Track]] = {m.topic: {} for m in found}
    signals = {m.topic: list(m.units) for m in found}
    for topic, log_time, decoded in reader.messages(list(tracks)):
        sender = decoded.get(SOURCE_ADDRESS)
        track = tracks[topic].get(sender)
        if track is None:
            track = tracks[topic][sender] = _Track(values={name: [] for name in signals[topic]})
        track.times.append((log_time - start) / 1e9)
        for name, column in track.values.items():
            value = decoded.get(name)
            column.append(float(value) if isinstance(value, (int, float)) else np.nan)
    return tracks


def _pages(message: Message, tracks: dict[int | None, _Track]) -> list[list[tuple[str, list[str]]]]:
    """The message's panels (y label, signals), in pages of at most PANELS_PER_FIGURE."""
    groups: dict[str, list[str]] = {}
    for name, unit in message.units.items():
        flag = all(np.isin(t.values[name], (0.0, 1.0)).all() for t in tracks.values()) if not unit else False
        groups.setdefault(unit or (_FLAGS if flag else f"\0{name}"), []).append(name)
    per_panel = max(1, CURVES_PER_PANEL // max(1, len(tracks)))  # each signal has a curve per sender
    panels = []
    for key, names in groups.items():
        label = "value (0 or 1)" if key == _FLAGS else names[0] if key.startswith("\0") else f"[{key}]"
        panels += [(label, names[i : i + per_panel]) for i in range(0, len(names), per_panel)]
    return [panels[i : i + PANELS_PER_FIGURE] for i in range(0, len(panels), PANELS_PER_FIGURE)]


def _figure(
    plt: Any,
    style: Style,
    panels: list[tuple[str, list[str]]],
    tracks: dict[int | None, _Track],
    axis: str,
    heading: str | None,
    dpi: int,
) -> Any:
    """One page: its panels, each signal's curve per sender, named above its panel."""
    height = max(2.8, 2.0 * len(panels) + 0.6) * style.scale
    columns = round(style.width * dpi)
    fig, axes = plt.subplots(
        len(panels), 1, figsize=(style.width, height), squeeze=False, sharex=True, layout="constrained"
    )
    for ax, (label, names) in zip(axes[:, 0], panels):
        for name in names:
            for sender, track in sorted(tracks.items(), key=lambda item: -1 if item[0] is None else item[0]):
                named = name if sender is None or len(tracks) == 1 else f"{name}, SA 0x{sender:02X}"
                alone = len(track.times) == 1  # a single frame draws no step: a mark
                t, v = envelope(track.times, track.values[name], columns)
                ax.plot(
                    track.times,
                    track.values[name],
                    lw=1,
                    label=named,
                    drawstyle="steps-post",
                    marker="o" if alone else None,
                )
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        _legend_above(ax)
    axes[-1, 0].set_xlabel(axis)
    if heading is not None:
        fig.suptitle(heading, wrap=True)
    return fig


def envelope(times: list[float], values: list[float], pixels: int) -> tuple[np.ndarray, np.ndarray]:
    """A curve as drawn ``pixels`` wide: all of it where it has at most SAMPLES_PER_PIXEL samples a
    pixel, else the first, lowest, highest and last sample of each stretch of about a pixel (in
    their order; a missing value stays missing where a stretch has nothing else)."""
    t, v = np.asarray(times, dtype=float), np.asarray(values, dtype=float)
    if len(t) <= SAMPLES_PER_PIXEL * max(pixels, 1):
        return t, v
    size = -(-len(t) // pixels)
    starts = np.arange(0, len(t), size)
    low = np.where(np.isnan(v), np.inf, v)
    high = np.where(np.isnan(v), -np.inf, v)
    keep = [starts, np.minimum(starts + size, len(t)) - 1]
    for picked in (low, high):
        padded = np.pad(picked, (0, len(starts) * size - len(t)), constant_values=picked[-1])
        best = padded.reshape(len(starts), size)
        keep.append(starts + (best.argmin(axis=1) if picked is low else best.argmax(axis=1)))
    index = np.unique(np.minimum(np.concatenate(keep), len(t) - 1))
    return t[index], v[index]


def _legend_above(ax: Axes) -> None:
    """The panel's curves named above it, off the data (a legend placed by 'best' costs seconds)."""
    count = len(ax.get_lines())
    ax.legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), ncol=min(4, count), frameon=False, fontsize="small")


def _file_name(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "-", name).strip("-") or "message"
