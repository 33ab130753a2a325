"""Score the baselines on a split of a data set, offline: ``python -m cosim.baselines.evaluate DATASET --models DIR``.

Per run of the split (``--split``, default test), each monitor's alarm is computed tick by tick as
its node would (the statistics of ``cosim.baselines.pca`` and ``cosim.baselines.one_class``, the limits and the
persistence of its model), then per fault or attack (the data set's ``events``): detected if the
alarm is up on a tick of its window, with the delay from its onset tick; and per run, the alarm
episodes that start with nothing active (false alarms). Prints a line per monitor and class.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from cosim.baselines import one_class, pca


def alarms(over: np.ndarray, persistence: int = 3) -> np.ndarray:
    """The alarm of ``cosim.baselines.monitor``: up after ``persistence`` ticks over, down after as many under."""
    out, up, run_over, run_under = np.zeros(len(over), dtype=bool), False, 0, 0
    for k, o in enumerate(over):
        run_over, run_under = (run_over + 1, 0) if o else (0, run_under + 1)
        up = True if run_over >= persistence else False if run_under >= persistence else up
        out[k] = up
    return out


def over_limits(kind: str, model: dict, y: np.ndarray) -> np.ndarray:
    if kind == "pca":
        stats = pca.statistics(model, y)
        return np.any([~(stats[name] <= limit) for name, limit in model["limits"].items()], axis=0)
    d2 = one_class.scores(model, one_class.features(model, y))
    return ~(d2 <= model["limits"]["d2"])


def evaluate(dataset: Path, models: Path, split: str) -> dict[tuple[str, str], dict[str, list[float]]]:
    import pyarrow.parquet as pq

    card = json.loads((dataset / "card.json").read_text())
    found: dict[tuple[str, str], dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    for kind in ("pca", "one_class"):
        fitted = json.loads((models / f"{kind}.json").read_text())["models"]
        for campaign in card["campaigns"]:
            model = next((m for m in fitted if m["sensors"] == campaign["sensors"]), None)
            if model is None:
                continue
            for path in sorted((dataset / "signals" / campaign["name"] / split).glob("*.parquet")):
                signals = pq.read_table(path).to_pydict()
                stem = f"{campaign['name']}-{path.name}"
                labels = pq.read_table(dataset / "labels" / split / stem).to_pydict()
                events = pq.read_table(dataset / "events" / split / stem).to_pylist()
                y = np.column_stack([np.asarray(signals[f"reading.{s}"], dtype=float) for s in model["use"]])
                alarm = alarms(over_limits(kind, model, y))
                dt = signals["t"][1] - signals["t"][0]
                for event in events:
                    window = alarm[event["onset_tick"] : event["end_tick"]]
                    hit = np.flatnonzero(window)
                    found[(kind, f"{campaign['name']}: {event['kind']}")]["detected"].append(float(hit.size > 0))
                    if hit.size:
                        found[(kind, f"{campaign['name']}: {event['kind']}")]["delay"].append(hit[0] * dt)
                quiet = np.asarray(labels["label"]) == 0
                starts = alarm & ~np.concatenate([[False], alarm[:-1]]) & quiet
                found[(kind, f"{campaign['name']}: normal")]["false_alarms"].append(float(starts.sum()))
                found[(kind, f"{campaign['name']}: normal")]["hours"].append(quiet.sum() * dt / 3600)
    return found


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m cosim.baselines.evaluate", description=__doc__.splitlines()[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--models", required=True, type=Path, metavar="DIR")
    parser.add_argument("--split", default="test", choices=("train", "validation", "test"))
    args = parser.parse_args(argv)
    for (kind, what), values in sorted(evaluate(args.dataset, args.models, args.split).items()):
        if what.endswith(": normal"):
            rate = sum(values["false_alarms"]) / max(sum(values["hours"]), 1e-12)
            print(
                f"{kind:9s} {what:50s} false alarms {sum(values['false_alarms']):.0f} in "
                f"{sum(values['hours']) * 3600:.0f} s ({rate:.0f} per hour)"
            )
        else:
            delay = f", delay median {np.median(values['delay']):.2f} s" if values["delay"] else ""
            print(f"{kind:9s} {what:50s} detected {sum(values['detected']):.0f} of {len(values['detected'])}{delay}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
