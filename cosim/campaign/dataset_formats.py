"""A data set's frames in the forms existing CAN intrusion detection code reads: the HCRL car-hacking
CSV and ROAD's candump logs with their capture metadata.

- **HCRL** (the car-hacking data set of the Hacking and Countermeasure Research Lab, Song et al.
  2020): one CSV per capture, no header, a frame per line: ``Timestamp,CAN ID,DLC,DATA[0],...,
  DATA[DLC-1],Flag``, the timestamp in seconds (six decimals), the id as four hex digits, the data
  bytes as two hex digits each (as many as the frame has: lines are ragged, as in HCRL's files),
  the flag ``T`` for an injected frame and ``R`` for a genuine one.
- **ROAD** (Verma et al., PLOS ONE 2024): one candump log per capture (``candump -L``'s text,
  ``(timestamp) can0 ID#DATA``, written by python-can's ``CanutilsLogWriter``, which ``can.LogReader``
  and can-utils read) and its metadata as ROAD's ``capture_metadata.json`` gives it per capture:
  ``description``, ``elapsed_sec``, ``injection_id``, ``injection_interval`` (s, from the capture's
  start) and ``injection_data_str``; ours adds every fault and attack of the run (``events``), since a
  run may hold more than one. ROAD labels frames by that interval and id; the exact label of every
  frame is in the Parquet and HCRL forms.

Timestamps are simulated time from the run's start (tick 0 at 0 s), the same in every form.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

from cosim.campaign.dataset_run import RunTables

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


def write_road(folder: Path, stem: str, tables: RunTables) -> None:
    """The frames as a ROAD capture: ``<stem>.log`` (candump -L) and ``<stem>.json`` (its metadata)."""
    import can
    from can.io.canutils import CanutilsLogWriter

    folder.mkdir(parents=True, exist_ok=True)
    frames = tables.frames
    writer = CanutilsLogWriter(folder / f"{stem}.log", channel=CHANNEL)
    try:
        for timestamp, frame_id, extended, fd, brs, data in zip(
            frames["timestamp"], frames["id"], frames["extended"], frames["fd"], frames["brs"], frames["data"]
        ):
            writer.on_message_received(
                can.Message(
                    timestamp=timestamp,
                    arbitration_id=frame_id,
                    is_extended_id=extended,
                    is_fd=fd,
                    bitrate_switch=brs,
                    data=data,
                )
            )
    finally:
        writer.stop()
    metadata = {stem: road_metadata(tables)}
    (folder / f"{stem}.json").write_text(json.dumps(metadata, indent=2, sort_keys=True) + "\n")


def road_metadata(tables: RunTables) -> dict[str, Any]:
    """A capture's metadata in ROAD's fields (its first attack's injection), and every event of the run."""
    events = tables.events
    rows = [dict(zip(events, values)) for values in zip(*events.values())] if events else []
    injected: dict[str, set[int]] = {}
    for frame_id, fault in zip(tables.frames["id"], tables.frames["fault"]):
        if fault:
            injected.setdefault(fault, set()).add(frame_id)
    first = next((row for row in rows if row["category"] == "attack"), None)
    ids = sorted(injected.get(first["fault"], ())) if first else []
    described = "; ".join(f"{r['kind']} ({r['fault']}) on {', '.join(r['targets']) or 'the bus'}" for r in rows)
    return {
        "description": described or "ambient: no fault, no attack",
        "elapsed_sec": tables.duration,
        "injection_id": (f"0x{ids[0]:X}" if len(ids) == 1 else [f"0x{i:X}" for i in ids]) if ids else None,
        "injection_interval": [first["start"], first["end"]] if first else None,
        "injection_data_str": None,
        "events": rows,
    }
