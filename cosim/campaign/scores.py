"""One estimator's scores in one group of a campaign's runs (``Entry``): its runs' values
collected, and their summary with 95 % intervals (bootstrap, Wilson, exact Poisson).

``cosim.campaign.leaderboard`` groups the rows into entries; ``cosim.campaign.ranking`` ranks them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cosim.campaign.results import Row
from cosim.campaign.verdicts import Z95, bootstrap_median


def percentile(values: list[float], q: float) -> float | None:
    return float(np.percentile(values, q)) if values else None


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
    kind_name: str = ""
    """The name a plugin's kind declares (``kind`` is then its module path)."""
    runs: int = 0
    failed: int = 0
    rms: list[float] = field(default_factory=list)
    rms_by_run: dict[Any, float] = field(default_factory=dict)
    """RMS after onset by run (by case and run in a benchmark): what paired comparisons pair."""
    diagnosis_by_run: dict[Any, tuple[float, ...]] = field(default_factory=dict)
    """Per run, its ``diagnosis_outcome`` (lower is better): what sign comparisons pair."""
    rejection: list[float] = field(default_factory=list)
    final: list[float] = field(default_factory=list)
    peak: list[float] = field(default_factory=list)
    recovery: list[float] = field(default_factory=list)
    diagnoses: bool = False
    with_fault: int = 0
    detected: int = 0
    missed: int = 0
    false_alarms: int = 0
    fault_free_h: float = 0.0
    detection_delays: list[float] = field(default_factory=list)
    isolation_delays: list[float] = field(default_factory=list)
    isolable: int = 0
    isolated_correctly: int = 0
    confusion: dict[str, dict[str, int]] = field(default_factory=dict)
    """Expected targets → isolated targets → runs (the first isolable fault of each run)."""

    def add(self, row: Row, case: Any = None) -> None:
        """A row of one of its runs (of ``case`` in a benchmark): a failed run (or a run this
        estimator failed in) is counted, a completed one scored."""
        self.kind_name = self.kind_name or row.kind_name or ""
        if row.status != "completed" or row.estimator_failed:
            self.failed += 1
            return
        self.runs += 1
        for found, value in ((self.rms, row.rms_post_fault), (self.rejection, row.bias_rejection_ratio)):
            append_finite(found, value)
        run = row.run if case is None else (case, row.run)
        if (rms := finite_number(row.rms_post_fault)) is not None and row.run is not None:
            self.rms_by_run[run] = rms
        append_finite(self.final, row.final_error)
        append_finite(self.peak, row.peak_error)
        append_finite(self.recovery, row.recovery_time_s)
        if not row.diagnoses:
            return
        self.diagnoses = True
        if row.run is not None:
            self.diagnosis_by_run[run] = diagnosis_outcome(row)
        has_fault = row.fault_kind not in (None, "none")
        self.with_fault += has_fault
        self.detected += bool(has_fault and row.detected)
        self.missed += int(row.missed_detections or 0)
        self.false_alarms += int(row.false_alarms or 0)
        self.fault_free_h += (finite_number(row.fault_free_time_s) or 0.0) / 3600
        append_finite(self.detection_delays, row.detection_delay_s)
        append_finite(self.isolation_delays, row.isolation_delay_s)
        if row.isolation_correct is not None:
            self.isolable += 1
            self.isolated_correctly += bool(row.isolation_correct)
        if row.isolation_expected:
            cell = self.confusion.setdefault(row.isolation_expected, {})
            cell[row.isolation_result or "none"] = cell.get(row.isolation_result or "none", 0) + 1

    def scores(self) -> dict[str, Any]:
        rms, rejection = self.rms, self.rejection
        out: dict[str, Any] = {
            "estimator": self.estimator,
            "kind": self.kind,
            "kind_name": self.kind_name or self.kind,
            "runs": self.runs,
            "failed": self.failed,
            "rms_post_fault_median": percentile(rms, 50),
            "rms_post_fault_p90": percentile(rms, 90),
            "rms_post_fault_median_ci95": bootstrap_median(rms),
            "final_error_median": percentile(self.final, 50),
            "final_error_median_ci95": bootstrap_median(self.final),
            "peak_error_median": percentile(self.peak, 50),
            "peak_error_median_ci95": bootstrap_median(self.peak),
            "recovery_time_median_s": percentile(self.recovery, 50),
            "recovery_time_p90_s": percentile(self.recovery, 90),
            "bias_rejection_median": percentile(rejection, 50),
        }
        detections, isolations = self.detection_delays, self.isolation_delays
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
            "confusion": {e: dict(sorted(found.items())) for e, found in sorted(self.confusion.items())} or None,
        }
        if not self.diagnoses:
            out |= {
                key: None
                for key in out
                if key not in ("estimator", "kind", "kind_name", "runs", "failed", "diagnoses")
                and not key.startswith(("rms_", "bias_", "final_", "peak_", "recovery_"))
            }
        return out


def finite_number(value: Any) -> float | None:
    return (
        float(value)
        if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
        else None
    )


def append_finite(values: list[float], value: Any) -> None:
    """Add a finite number; anything else is no value."""
    if (number := finite_number(value)) is not None:
        values.append(number)


def diagnosis_outcome(row: Row) -> tuple[float, ...]:
    """A run's diagnosis by one scheme, to compare with another's on the same run (lower is better,
    in this order): faults missed, a wrong or missing isolation, false alarms, the detection delay."""
    delay = finite_number(row.detection_delay_s)
    return (
        float(row.missed_detections or 0),
        float(row.isolation_correct is False),
        float(row.false_alarms or 0),
        math.inf if delay is None else delay,
    )
