"""Metrics of a run log against its ground truth: estimation, detection and isolation, the bus.

``measure(path)`` reads the log once, in file order, and returns a ``RunMetrics``;
``compute_metrics(path)`` its JSON form (``cosim inspect --json`` prints it); ``LiveMeasurement``
scores a run while it writes its log, to the same ``RunMetrics``. Every metric is
defined in docs/metrics.md; in short, with e_k = |x_k − x̂_k| (Euclidean norm over the whole state)
and τ the sample time:

- estimation, per estimator (``estimation``): RMS of e_k before and from the first fault onset;
  the pre-fault band b = 2 max e_k over the second half of the ticks before the first onset; per
  fault, over its segment (from its onset to the next onset of any fault, or the end of the log),
  the peak of e_k and the recovery time (from the onset to the tick after the last one with
  e_k > b; null if e_k is still out of the band at the segment's end); the bias rejection ratio
  (post-fault RMS over that of the uniform-weight baseline: a ``pseudoinverse`` estimator without
  ``weights``).
- diagnosis, per estimator that publishes ``alarm`` (and optionally isolation flags)
  (``diagnosis``): per fault, detection delay (first alarm tick in its segment), isolation delay
  and decision; false alarms (alarm episodes starting with no fault active), their rate per
  fault-free hour, and missed detections.
- bus (``bus``): frames and bits per id, load against the configured bit rates (exact bit
  stuffing, ``cosim.bus.timing``), overall and per second, lost frames and deadline misses; on an
  arbitrated bus (``/cosim/wire``) per-id latency (min, median, max), late and replaced frames.

The parts: ``values`` (the typed value and its JSON form), ``facts`` (what the metadata says),
``scorer`` (the log's messages in file order, ticks assembled from their parts, fault segments),
``compute`` (reading a log, assembling its metrics).
"""

from cosim.analysis.metrics.compute import LiveMeasurement, compute_metrics, measure
from cosim.analysis.metrics.estimation import BAND_FACTOR
from cosim.analysis.metrics.values import (
    BusMetrics,
    DiagnosisMetrics,
    EstimationMetrics,
    FaultDiagnosis,
    FaultRecovery,
    FaultSpan,
    ForeignTraffic,
    FrameCounts,
    IdLatency,
    IdTraffic,
    LoadOverTime,
    RunMetrics,
)

__all__ = [
    "BAND_FACTOR",
    "BusMetrics",
    "DiagnosisMetrics",
    "EstimationMetrics",
    "FaultDiagnosis",
    "FaultRecovery",
    "FaultSpan",
    "ForeignTraffic",
    "FrameCounts",
    "IdLatency",
    "IdTraffic",
    "LiveMeasurement",
    "LoadOverTime",
    "RunMetrics",
    "compute_metrics",
    "measure",
]
