"""The physical effect of each fault or attack in a data set of ``cosim dataset``, from its truth.

    .venv/bin/python bench/dataset_effects.py DATASET [--state x2] [--json]

Common random numbers make it a difference: every run of a replicate has the same noise and
weather, so a run's effect is its true state minus the state of the replicate's run without any
fault or attack, over the fault's window (the data set's events): per kind, the RMS and the
largest |Δ state| (mean over the replicates), the ticks whose reading was missing or doubled (NaN in
the signals), and the frames the attack sent and kept off the bus.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np


def effects(dataset: Path, state: str) -> dict[str, dict[str, float]]:
    import pyarrow.parquet as pq

    card = json.loads((dataset / "card.json").read_text())
    runs = defaultdict(dict)  # (campaign, replicate) -> run -> split
    for r in card["runs"]:
        runs[(r["campaign"], r["replicate"])][r["run"]] = r["split"]
    found: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    for (campaign, _), members in runs.items():
        tables = {}
        for run, split in members.items():
            stem = f"run-{run:06d}.parquet"
            truth = pq.read_table(dataset / "truth" / campaign / split / stem).to_pydict()
            signals = pq.read_table(dataset / "signals" / campaign / split / stem).to_pydict()
            events = pq.read_table(dataset / "events" / split / f"{campaign}-{stem}").to_pylist()
            tables[run] = (truth, signals, events)
        clean = next((t for t in tables.values() if not t[2]), None)
        if clean is None or f"state.{state}" not in clean[0]:
            continue  # no run of the replicate without a fault, or another plant
        reference = np.asarray(clean[0][f"state.{state}"])
        readings = [name for name in clean[1] if name.startswith("reading.")]
        for truth, signals, events in tables.values():
            for event in events:
                window = slice(event["onset_tick"], event["end_tick"])
                delta = np.asarray(truth[f"state.{state}"])[window] - reference[window]
                missing = np.isnan(np.column_stack([signals[name] for name in readings])[window]).any(axis=1)
                entry = found[f"{campaign}: {event['kind']}"]
                entry["rms"].append(float(np.sqrt(np.mean(delta**2))))
                entry["max"].append(float(np.abs(delta).max()))
                entry["missing"].append(float(missing.sum()))
                entry["injected"].append(float(event["frames_injected"]))
                entry["lost"].append(float(event["frames_lost"]))
    return {kind: {k: float(np.mean(v)) for k, v in values.items()} for kind, values in sorted(found.items())}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--state", default="x2")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    found = effects(args.dataset, args.state)
    if args.json:
        print(json.dumps(found, indent=2))
        return 0
    print(f"{'kind':44s} RMS |Δ{args.state}|  max |Δ{args.state}|  ticks without a reading  frames sent / kept off")
    for kind, e in found.items():
        print(
            f"{kind:44s} {e['rms']:10.4f} {e['max']:12.4f} {e['missing']:14.0f} {e['injected']:14.0f} / {e['lost']:.0f}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
