"""A data set's frames in the forms existing CAN intrusion detection code reads: the HCRL car-hacking
CSV and ROAD's candump logs with their capture metadata.

- **HCRL** (the car-hacking data set of the Hacking and Countermeasure Research Lab, Song et al.
  2020): one CSV per capture, no header, a frame per line: ``Timestamp,CAN ID,DLC,DATA[0],...,
  DATA[DLC-1],Flag``, the timestamp in seconds (six decimals), the id as four hex digits, the data
  bytes as two hex digits each (as many as the frame has: lines are ragged, as in HCRL's files),
  the flag ``T`` for an injected frame and ``R`` for a genuine one.
- **ROAD** (Verma et al., PLOS ONE 2024): one log per capture in ``candump -L``'s text as ROAD's
  logs hold it, ``(timestamp) can0 ID#DATA`` and nothing after (python-can's writer adds a
  direction flag, `` R``, that ROAD's logs do not have; ``can.LogReader`` and can-utils read both),
  in ``ambient/`` or ``attacks/`` beside that folder's ``capture_metadata.json``
  (``cosim.campaign.dataset_road`` says what goes where and why ROAD's rule labels it right).

Timestamps are simulated time from the run's start (tick 0 at 0 s), the same in every form.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

from cosim.campaign.dataset_road import METADATA

CHANNEL = "can0"


def write_hcrl(path: Path, frames: dict[str, list[Any]]) -> None:
    """The frames as an HCRL car-hacking CSV (ragged lines, no header)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        for timestamp, frame_id, data, label in zip(frames["timestamp"], frames["id"], frames["data"], frames["label"]):
            writer.writerow(
                [f"{timestamp:.6f}", f"{frame_id:04x}", len(data), *(f"{b:02x}" for b in data), "T" if label else "R"]
            )


def candump_line(timestamp: float, frame_id: int, extended: bool, fd: bool, brs: bool, data: bytes) -> str:
    """One frame as a line of ``candump -L`` (can-utils' log format), without a direction flag."""
    ident = f"{frame_id:08X}" if extended else f"{frame_id:03X}"
    body = f"#{int(brs):X}{data.hex().upper()}" if fd else data.hex().upper()  # CAN FD: ##<flags>, BRS is bit 0
    return f"({timestamp:.6f}) {CHANNEL} {ident}#{body}\n"


def write_road_log(path: Path, frames: dict[str, list[Any]]) -> None:
    """The frames as a ROAD capture's log."""
    path.parent.mkdir(parents=True, exist_ok=True)
    columns = ("timestamp", "id", "extended", "fd", "brs", "data")
    with path.open("w", newline="\n") as handle:
        handle.writelines(candump_line(*frame) for frame in zip(*(frames[c] for c in columns)))


def write_road_metadata(folder: Path, captures: dict[str, dict[str, Any]]) -> None:
    """A ROAD folder's ``capture_metadata.json``: each capture's metadata by its name."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / METADATA).write_text(json.dumps(captures, indent=2, sort_keys=True) + "\n")
