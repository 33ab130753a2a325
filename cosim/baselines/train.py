"""Fit the baselines on data sets of ``cosim dataset``: ``python -m cosim.baselines.train DATASET ... --out DIR``.

Per plant (a campaign's sensors; campaigns with the same sensors are pooled): the readings of the
train split's ticks before any fault or attack of their run began fit the models, and the same
ticks of the validation split (the train split's where it has none) set each statistic's limit at
its ``--quantile``. ``--leave-out SENSOR`` keeps a reading out of the models (a level that
integrates, such as a ship's position, which no model fitted on one stretch of time holds on
another). Writes ``DIR/pca.json`` and ``DIR/one_class.json`` and says what it fitted.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from cosim.baselines import one_class, pca


def normal_runs(dataset: Path, campaign: str, split: str, sensors: list[str]) -> list[np.ndarray]:
    """Each run's readings (ticks × sensors) before any fault or attack began in it, in tick order."""
    import pyarrow.parquet as pq

    folder = dataset / "signals" / campaign / split
    runs = []
    for path in sorted(folder.glob("*.parquet")):
        signals = pq.read_table(path).to_pydict()
        labels = pq.read_table(dataset / "labels" / split / f"{campaign}-{path.name}").to_pydict()
        if signals["tick"] != labels["tick"]:
            raise SystemExit(f"{path}: its ticks are not its labels' (a damaged data set?)")
        before = np.cumsum(labels["label"]) == 0
        readings = np.column_stack([np.asarray(signals[f"reading.{s}"], dtype=float) for s in sensors])[before]
        if len(readings) > 2:
            runs.append(readings[~np.isnan(readings).any(axis=1)])
    return runs


def train(
    datasets: list[Path], quantile: float = 0.999, variance: float = 0.95, leave_out: tuple[str, ...] = ()
) -> dict[str, dict[str, Any]]:
    """The models of both baselines, per plant, as their files hold them; ``leave_out``: sensors the
    models do not use (a level that integrates, as a ship's position, holds on no stretch of time
    but the one it was fitted on)."""
    pooled: dict[tuple[str, ...], dict[str, list[np.ndarray]]] = defaultdict(lambda: defaultdict(list))
    plants: dict[tuple[str, ...], str] = {}
    for dataset in datasets:
        card = json.loads((dataset / "card.json").read_text())
        for campaign in card["campaigns"]:
            sensors = tuple(campaign["sensors"])
            plants[sensors] = campaign["plant"]
            for split in ("train", "validation"):
                pooled[sensors][split] += normal_runs(dataset, campaign["name"], split, list(sensors))
    files: dict[str, dict[str, Any]] = {
        "pca": {"kind": "pca", "models": []},
        "one_class": {"kind": "one_class", "models": []},
    }
    for sensors, splits in pooled.items():
        if not splits["train"]:
            continue
        use = [i for i, name in enumerate(sensors) if name not in leave_out]
        fit_on = [run[:, use] for run in splits["train"]]
        limit_on = [run[:, use] for run in splits["validation"] or splits["train"]]
        common = {
            "plant": plants[sensors],
            "sensors": list(sensors),
            "use": [sensors[i] for i in use],
            "quantile": quantile,
        }
        model = pca.fit(np.vstack(fit_on), variance)
        stats = pca.statistics(model, np.vstack(limit_on))
        model["limits"] = {name: float(np.quantile(values, quantile)) for name, values in stats.items()}
        files["pca"]["models"].append({**common, "ticks": int(sum(len(r) for r in fit_on)), **model})
        model = one_class.fit(fit_on)
        d2 = np.concatenate([one_class.scores(model, one_class.features(model, run))[1:] for run in limit_on])
        model["limits"] = {one_class.SCORE.name: float(np.quantile(d2, quantile))}
        files["one_class"]["models"].append({**common, "ticks": int(sum(len(r) for r in fit_on)), **model})
    return files


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m cosim.baselines.train", description=__doc__.splitlines()[0])
    parser.add_argument("datasets", nargs="+", type=Path, metavar="DATASET", help="folders of cosim dataset")
    parser.add_argument("--out", required=True, type=Path, metavar="DIR", help="where pca.json and one_class.json go")
    parser.add_argument("--quantile", type=float, default=0.999, help="limits: this quantile of the normal ticks")
    parser.add_argument("--variance", type=float, default=0.95, help="PCA: the share of variance its components keep")
    parser.add_argument(
        "--leave-out", action="append", default=[], metavar="SENSOR", help="a sensor the models do not use (repeat)"
    )
    args = parser.parse_args(argv)
    files = train(args.datasets, args.quantile, args.variance, tuple(args.leave_out))
    args.out.mkdir(parents=True, exist_ok=True)
    for name, document in files.items():
        (args.out / f"{name}.json").write_text(json.dumps(document, indent=1) + "\n")
        for m in document["models"]:
            limits = ", ".join(f"{k} {v:.4g}" for k, v in m["limits"].items())
            extra = f", {len(m['eigenvalues'])} components ({m['explained']:.1%})" if "eigenvalues" in m else ""
            left = [s for s in m["sensors"] if s not in m["use"]]
            out = f" (left out: {', '.join(left)})" if left else ""
            print(f"{name}: {m['plant']} ({', '.join(m['use'])}){out}: {m['ticks']} ticks{extra}; limits {limits}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
