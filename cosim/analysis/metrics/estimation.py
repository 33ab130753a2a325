"""The estimation error of one estimator, tick by tick: RMS before and after the first fault, the
pre-fault band, and per fault its peak and recovery (docs/metrics.md, "Estimation").

With e_k = |x_k − x̂_k| and k_f the first fault onset: RMS = sqrt(mean e_k²) over the scored ticks
before k_f and from it; the band b = 2 max{e_k : ⌊k_f/2⌋ ≤ k < k_f}; in a fault's segment the peak
max e_k and the recovery time (k* − k_f) τ, k* one past the last tick with e_k > b, None if e_k is
still out of the band at the segment's end.
"""

from __future__ import annotations

import math

from cosim.analysis.metrics.segments import Segment
from cosim.analysis.metrics.values import EstimationMetrics, FaultRecovery, Saturation

#: The pre-fault band is this many times the largest settled pre-fault error.
BAND_FACTOR = 2.0


class EstimationScore:
    """One estimator's error, fed tick by tick in order."""

    def __init__(self, onset_tick: int | None, sample_time: float | None) -> None:
        self.onset_tick, self.sample_time = onset_tick, sample_time
        self.sums = {"pre": [0.0, 0], "post": [0.0, 0]}
        self.final: tuple[int, float | None] = (-1, None)
        self.settled_max: float | None = None
        self.scored = 0
        self.seg_peak: tuple[float, int] | None = None
        self.seg_last_out: int | None = None
        self.seg_last: tuple[int, float] | None = None
        self.faults: dict[str, FaultRecovery] = {}
        self.saturated: dict[str, list[int]] = {}  # signal -> [ticks, first tick]

    @property
    def band(self) -> float | None:
        return None if self.settled_max is None else BAND_FACTOR * self.settled_max

    def add(self, k: int, error: float, segment: Segment | None) -> None:
        onset = self.onset_tick
        window = "post" if onset is not None and k >= onset else "pre"
        self.sums[window][0] += error * error
        self.sums[window][1] += 1
        self.scored += 1
        if k > self.final[0]:
            self.final = (k, error)
        if onset is not None and onset // 2 <= k < onset:
            self.settled_max = error if self.settled_max is None else max(self.settled_max, error)
        if segment is not None:
            if self.seg_peak is None or error > self.seg_peak[0]:
                self.seg_peak = (error, k)
            band = self.band
            if band is not None and error > band:
                self.seg_last_out = k
            self.seg_last = (k, error)

    def saturation(self, k: int, signal: str) -> None:
        """Tick k's estimate signal sits at its bus range's bound: the node saturated it."""
        self.saturated.setdefault(signal, [0, k])[0] += 1

    def close(self, segment: Segment) -> None:
        dt, band = self.sample_time, self.band
        assert dt is not None, "segments start at scored ticks, and ticks are scored only with a sample time"
        recovery = None
        if band is not None and self.seg_last is not None and self.seg_last[1] <= band:
            recovery = 0.0 if self.seg_last_out is None else segment.since(self.seg_last_out + 1, dt)
        for label in segment.labels:
            self.faults[label] = FaultRecovery(
                peak_error=None if self.seg_peak is None else self.seg_peak[0],
                peak_at=None if self.seg_peak is None else segment.since(self.seg_peak[1], dt),
                recovery_time=recovery,
                recovered=recovery is not None,
            )
        self.seg_peak = self.seg_last_out = self.seg_last = None

    def rms(self, window: str) -> float | None:
        total, n = self.sums[window]
        return math.sqrt(total / n) if n else None

    def metrics(self, kind: str, baseline: EstimationScore | None) -> EstimationMetrics:
        """The scores; ``baseline``: the uniform-weight estimator's, for the bias rejection ratio."""
        post, base = self.rms("post"), baseline.rms("post") if baseline else None
        return EstimationMetrics(
            kind=kind,
            rms_pre_fault=self.rms("pre"),
            rms_post_fault=post,
            final_error=self.final[1],
            ticks_scored=self.scored,
            band=self.band,
            bias_rejection_ratio=post / base if post is not None and base else None,
            saturated={
                signal: Saturation(n, None if self.sample_time is None else round(first * self.sample_time, 9))
                for signal, (n, first) in sorted(self.saturated.items())
            },
            faults=self.faults,
        )
