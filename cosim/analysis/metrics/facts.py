"""What a run log's metadata says about the run, as the metrics need it, read leniently."""

from __future__ import annotations

from typing import Any

from cosim.analysis.metrics.values import FaultSpan
from cosim.log.metadata import EstimatorRecord, LogMetadata, RunRecord


class RunFacts:
    """The run's description from its metadata records (``cosim.log.metadata``); what is missing
    or damaged becomes ``warnings`` and ``missing``."""

    def __init__(self, meta: dict[str, dict[str, str]]) -> None:
        records = LogMetadata.read(meta)
        self.warnings: list[str] = list(records.warnings)
        self.missing: list[str] = []
        result = records.result
        self.status = result.status if result else "incomplete"
        self.frames_total = result.frames_total if result else None
        self.frames_lost = result.frames_lost if result else None
        self.deadline_misses = result.deadline_misses if result else None
        self.lost_by_sender = (
            {name: c.lost + c.runner_frames_missed for name, c in result.senders.items()} if result else {}
        )
        self.late_by_sender = {name: c.late for name, c in result.senders.items()} if result else {}
        self.result_ticks = result.ticks if result else None
        self.failed = dict(result.failed) if result else {}
        self.contested_ticks = result.contested_ticks if result else 0
        self.known = records.run is not None
        self.record = run = records.run or RunRecord()
        if records.imported is not None:  # a bus log of another tool (cosim import): no run to score
            i = records.imported
            self.status = "imported"
            of = f"{i.format}, channel {i.channel}" if i.channel else i.format
            self.record = run = RunRecord(source=f"cosim import of {i.source} ({of}) by {i.dbc}")
            self.missing.append(
                f"a run: an imported bus log ({i.decoded} of {i.frames} frames decoded, {i.unknown} on ids the DBC "
                "does not describe); only channels, message counts and the time span are reported"
            )
        elif records.run is None:
            self.warnings.append(
                "no cosim.run metadata: not a cosim log, or written by another program; "
                "estimator errors, fault and diagnosis metrics and the bus load are unavailable"
            )
            self.missing.append(
                "cosim.run metadata (sample time, states, estimators, faults, bus): without it only "
                "channels, message counts and the time span are reported"
            )
        if result is None and records.imported is None:
            self.missing.append("cosim.result metadata (status, frame counts): the run did not finish writing its log")
        self.sample_time, self.dt_ns = run.sample_time, run.dt_ns
        self.states, self.sensors, self.actuators = run.states, run.sensors, run.actuators
        self.estimators: dict[str, EstimatorRecord] = run.estimators
        self.onset, self.onset_tick, self.seed = run.fault_onset, run.fault_onset_tick, run.seed
        self.bus: dict[str, Any] = run.bus
        self.faults = {f.label: FaultSpan(f.kind, list(f.targets or []), f.start, f.end) for f in run.faults}
        if any(f.targets is None for f in run.faults):
            self.missing.append("fault targets (cosim.run faults): isolation is not scored for the faults without them")
        self.baseline = next(
            (
                name
                for name, e in self.estimators.items()
                if e.kind == "pseudoinverse" and e.params.get("weights") is None
            ),
            None,
        )

    def seconds(self, k: int | None) -> float | None:
        """The time of tick ``k`` (None without a tick or a sample time)."""
        return None if k is None or self.sample_time is None else round(k * self.sample_time, 9)
