"""The leaderboard of a campaign: estimators ranked per group of runs, with confidence intervals.

``leaderboard(results, by)`` reads a results table (``cosim campaign``'s ``results.parquet``) and,
per group (the values of the ``by`` columns; by default the fault kind) and estimator, scores:

- estimation: the median and 90th percentile of the RMS error after onset, with a 95 % bootstrap
  interval of the median (2000 resamples, seeded: the same table gives the same interval), and
  the median bias rejection ratio;
- detection (estimators that publish an alarm): the detection rate over the runs with a fault
  (95 % Wilson interval), missed detections, false alarms per fault-free hour pooled over the runs
  (95 % exact Poisson interval), the median and 90th percentile of the detection and isolation
  delays, and the isolation accuracy (Wilson interval);
- failed runs, which are counted, never scored.

Estimators are ranked by the median RMS error after onset, or, in a group without any (a
fault-free group), by false alarms per hour; diagnosis schemes then by detection rate. ``outliers``
lists the runs whose error lies beyond Q3 + 3 IQR of their estimator's group: where to look first.
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cosim.errors import CosimError
from cosim.extras import require

Z95 = 1.959963984540054
BOOTSTRAP = 2000


def read_table(path: str | Path) -> tuple[dict[str, list[Any]], dict[str, str], dict[str, str]]:
    """The columns of a results table, the unit of each column, and the table's metadata."""
    pq = require("pyarrow.parquet", "cosim leaderboard", "campaign")
    try:
        table = pq.read_table(path)
    except FileNotFoundError:
        raise CosimError(f"{path}: no such file (a campaign writes DIR/results.parquet)") from None
    except (OSError, ValueError) as error:
        raise CosimError(f"{path}: not a readable Parquet table ({error})") from None
    units = {f.name: (f.metadata or {}).get(b"unit", b"").decode() for f in table.schema}
    metadata = {k.decode(): v.decode() for k, v in (table.schema.metadata or {}).items()}
    return table.to_pydict(), units, metadata


def percentile(values: list[float], q: float) -> float | None:
    return float(np.percentile(values, q)) if values else None


def bootstrap_median(values: list[float], seed: int = 0) -> tuple[float, float] | None:
    """95 % percentile-bootstrap interval of the median (None under 5 values)."""
    if len(values) < 5:
        return None
    rng = np.random.default_rng(seed)
    data = np.asarray(values)
    medians = np.median(rng.choice(data, size=(BOOTSTRAP, data.size), replace=True), axis=1)
    return float(np.percentile(medians, 2.5)), float(np.percentile(medians, 97.5))


def wilson(successes: int, n: int) -> tuple[float, float] | None:
    """95 % Wilson score interval of a proportion."""
    if n == 0:
        return None
    p = successes / n
    centre = (p + Z95**2 / (2 * n)) / (1 + Z95**2 / n)
    half = Z95 * math.sqrt(p * (1 - p) / n + Z95**2 / (4 * n * n)) / (1 + Z95**2 / n)
    return max(0.0, centre - half), min(1.0, centre + half)


def poisson_rate(events: int, exposure: float) -> tuple[float, float] | None:
    """95 % exact (Garwood) interval of a Poisson rate over ``exposure``."""
    if exposure <= 0:
        return None
    from scipy.stats import chi2

    low = 0.0 if events == 0 else chi2.ppf(0.025, 2 * events) / 2
    high = chi2.ppf(0.975, 2 * events + 2) / 2
    return float(low / exposure), float(high / exposure)


@dataclass
class Entry:
    """One estimator's scores in one group."""

    estimator: str
    kind: str
    runs: int = 0
    failed: int = 0
    rms: list[float] | None = None
    rejection: list[float] | None = None
    final: list[float] | None = None
    diagnoses: bool = False
    with_fault: int = 0
    detected: int = 0
    missed: int = 0
    false_alarms: int = 0
    fault_free_h: float = 0.0
    detection_delays: list[float] | None = None
    isolation_delays: list[float] | None = None
    isolable: int = 0
    isolated_correctly: int = 0

    def scores(self) -> dict[str, Any]:
        rms, rejection = self.rms or [], self.rejection or []
        out: dict[str, Any] = {
            "estimator": self.estimator,
            "kind": self.kind,
            "runs": self.runs,
            "failed": self.failed,
            "rms_post_fault_median": percentile(rms, 50),
            "rms_post_fault_p90": percentile(rms, 90),
            "rms_post_fault_median_ci95": bootstrap_median(rms),
            "final_error_median": percentile(self.final or [], 50),
            "bias_rejection_median": percentile(rejection, 50),
        }
        detections, isolations = self.detection_delays or [], self.isolation_delays or []
        out["diagnoses"] = self.diagnoses
        out |= {
            "detection_rate": self.detected / self.with_fault if self.with_fault else None,
            "detection_rate_ci95": wilson(self.detected, self.with_fault),
            "missed_detections": self.missed,
            "false_alarms_per_hour": self.false_alarms / self.fault_free_h if self.fault_free_h else None,
            "false_alarms_per_hour_ci95": poisson_rate(self.false_alarms, self.fault_free_h),
            "detection_delay_median_s": percentile(detections, 50),
            "detection_delay_p90_s": percentile(detections, 90),
            "isolation_delay_median_s": percentile(isolations, 50),
            "isolation_delay_p90_s": percentile(isolations, 90),
            "isolation_accuracy": self.isolated_correctly / self.isolable if self.isolable else None,
            "isolation_accuracy_ci95": wilson(self.isolated_correctly, self.isolable),
        }
        if not self.diagnoses:
            out |= {
                key: None
                for key in out
                if key not in ("estimator", "kind", "runs", "failed", "diagnoses")
                and not key.startswith(("rms_", "bias_", "final_"))
            }
        return out


def _number(value: Any) -> float | None:
    return (
        float(value)
        if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
        else None
    )


def leaderboard(path: str | Path, by: list[str] | None = None) -> dict[str, Any]:
    """The ranking of a results table per group (``by`` columns, default the fault kind)."""
    columns, units, metadata = read_table(path)
    by = by or ["fault_kind"]
    for column in by:
        if column not in columns:
            raise CosimError(f"--by {column}: the table has no such column (it has: {', '.join(columns)})")
    n = len(columns["run"])
    groups: dict[tuple[Any, ...], dict[tuple[str, str], Entry]] = defaultdict(dict)
    rows = [{name: values[i] for name, values in columns.items()} for i in range(n)]
    for row in rows:
        if not row.get("estimator"):  # a run that failed before it had estimators
            continue
        key = tuple(row.get(c) for c in by)
        entry = groups[key].setdefault(
            (row["estimator"], row.get("kind") or ""), Entry(row["estimator"], row.get("kind") or "")
        )
        if row.get("status") != "completed":
            entry.failed += 1
            continue
        entry.runs += 1
        for attribute, column in (
            ("rms", "rms_post_fault"),
            ("rejection", "bias_rejection_ratio"),
            ("final", "final_error"),
        ):
            if (value := _number(row.get(column))) is not None:
                setattr(entry, attribute, (getattr(entry, attribute) or []) + [value])
        if row.get("diagnoses"):
            entry.diagnoses = True
            has_fault = row.get("fault_kind") not in (None, "none")
            entry.with_fault += has_fault
            entry.detected += bool(has_fault and row.get("detected"))
            entry.missed += int(row.get("missed_detections") or 0)
            entry.false_alarms += int(row.get("false_alarms") or 0)
            entry.fault_free_h += (_number(row.get("fault_free_time_s")) or 0.0) / 3600
            for attribute, column in (
                ("detection_delays", "detection_delay_s"),
                ("isolation_delays", "isolation_delay_s"),
            ):
                if (value := _number(row.get(column))) is not None:
                    setattr(entry, attribute, (getattr(entry, attribute) or []) + [value])
            if row.get("isolation_correct") is not None:
                entry.isolable += 1
                entry.isolated_correctly += bool(row["isolation_correct"])
    ranked = []
    for key in sorted(groups, key=lambda k: tuple(str(v) for v in k)):
        scores = [entry.scores() for entry in groups[key].values()]
        scores.sort(key=_rank_key)
        for place, score in enumerate(scores, start=1):
            score["rank"] = place
        ranked.append({"group": dict(zip(by, key)), "ranking": scores})
    return {
        "table": str(path),
        "campaign": metadata.get("cosim.campaign.name"),
        "by": by,
        "runs": len(set(columns["run"])),
        "failed_runs": len({r["run"] for r in rows if r.get("status") != "completed"}),
        "units": {"rms_post_fault": units.get("rms_post_fault", "")},
        "groups": ranked,
        "outliers": outliers(rows, by),
    }


def _rank_key(score: dict[str, Any]) -> tuple[float, float, float]:
    inf = math.inf
    rms = score.get("rms_post_fault_median")
    alarms = score.get("false_alarms_per_hour")
    detection = score.get("detection_rate")
    return (
        rms if rms is not None else inf,
        -(detection if detection is not None else -inf),
        alarms if alarms is not None else inf,
    )


def outliers(rows: list[dict[str, Any]], by: list[str], factor: float = 3.0) -> list[dict[str, Any]]:
    """Completed runs whose RMS error after onset lies beyond Q3 + factor·IQR of their group and estimator."""
    errors: dict[tuple[Any, ...], list[float]] = defaultdict(list)
    for row in rows:
        if row.get("status") == "completed" and (value := _number(row.get("rms_post_fault"))) is not None:
            errors[(*(row.get(c) for c in by), row["estimator"])].append(value)
    found = []
    for row in rows:
        key = (*(row.get(c) for c in by), row.get("estimator"))
        value = _number(row.get("rms_post_fault"))
        if row.get("status") != "completed" or value is None or len(errors[key]) < 4:
            continue
        q1, q3 = np.percentile(errors[key], [25, 75])
        if value > q3 + factor * (q3 - q1) and value > q3:
            found.append(
                {
                    "run": row["run"],
                    "seed": row["seed"],
                    "estimator": row["estimator"],
                    "rms_post_fault": value,
                    "threshold": float(q3 + factor * (q3 - q1)),
                    "error": "",
                    "log": row.get("log") or "",
                    **{c: row.get(c) for c in by},
                }
            )
    failed = [
        {
            "run": r["run"],
            "seed": r["seed"],
            "estimator": r.get("estimator") or "",
            "rms_post_fault": None,
            "threshold": None,
            "error": r.get("error") or "",
            "log": r.get("log") or "",
            **{c: r.get(c) for c in by},
        }
        for r in rows
        if r.get("status") != "completed"
    ]
    unique_failed = list({f["run"]: f for f in failed}.values())
    return sorted(found, key=lambda o: -o["rms_post_fault"]) + unique_failed
