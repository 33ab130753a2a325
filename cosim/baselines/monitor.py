"""What both baselines share: a fitted model per plant in a JSON file, its statistics' limits, and an
alarm that rises after ``persistence`` ticks over a limit and falls after as many under.

A model file holds ``{"kind": ..., "models": [{"sensors": [...], "mean": [...], "std": [...],
"limits": {...}, ...}, ...]}``; a monitor takes the model whose sensors are its plant's outputs. It
reads the file once, where the run is planned, and carries the model in its design parameters
(``fitted``), so a node process needs no access to the file and the log records the model used.
"""

from __future__ import annotations

import json
from abc import abstractmethod
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from cosim.api import Diagnostic, DiagnosticKind, Estimate, Estimator, LinearModel, ParameterError

ALARM = Diagnostic(
    "alarm", "", "1 while a statistic is over its limit (after the persistence)", 1.0, 1.0, DiagnosticKind.ALARM
)


@dataclass(frozen=True)
class MonitorParams:
    model: str = ""
    """The model file of ``python -m cosim.baselines.train`` (``pca.json``, ``one_class.json``)."""
    fitted: str = ""
    """The model itself, as JSON (set by the run from ``model``: what a node is built with)."""
    persistence: int = 3
    """Ticks over (under) a limit in a row before the alarm rises (falls)."""


def model_for(text: str, sensors: tuple[str, ...], kind: str) -> dict[str, Any] | None:
    """The model of a file's text fitted on a plant with these sensors (None if it has none)."""
    document = json.loads(text)
    if document.get("kind") != kind:
        raise ParameterError("model", f"it holds {document.get('kind')!r} models, not {kind!r} ones")
    return next((m for m in document.get("models", []) if tuple(m["sensors"]) == tuple(sensors)), None)


class Monitor(Estimator):
    """A detector on the readings: ``statistics(y)`` → named statistics, each with its limit."""

    estimates = False
    Params = MonitorParams
    kind_of_file: ClassVar[str]
    STATISTICS: ClassVar[tuple[Diagnostic, ...]]

    def __init__(self, model: LinearModel, params: MonitorParams, sample_time: float | None = None) -> None:
        super().__init__(model, params, sample_time)
        if params.persistence < 1:
            raise ParameterError("persistence", "give at least 1 tick")
        text = params.fitted
        if not text:
            if not params.model:
                raise ParameterError(
                    "model", f"give the model file of python -m cosim.baselines.train ({self.kind_of_file}.json)"
                )
            try:
                text = Path(params.model).read_text()
            except OSError as error:
                raise ParameterError("model", f"{params.model}: cannot read it ({error.strerror})") from None
        self._text = text
        self.fitted = model_for(text, model.outputs, self.kind_of_file)
        self._over = self._under = 0
        self._alarm = 0.0
        if self.fitted is not None:
            used = self.fitted.get("use", self.fitted["sensors"])
            self.use = [model.outputs.index(name) for name in used]
            self.mean = np.asarray(self.fitted["mean"], dtype=float)
            self.std = np.asarray(self.fitted["std"], dtype=float)
            self.limits = {name: float(v) for name, v in self.fitted["limits"].items()}
            self.setup(self.fitted)

    def setup(self, fitted: dict[str, Any]) -> None:
        """Take the fitted model's own parts."""

    def design_params(self) -> dict[str, Any]:
        return {"fitted": json.dumps({"kind": self.kind_of_file, "models": [self.fitted] if self.fitted else []})}

    @classmethod
    def diagnostic_channels(cls, states: tuple[str, ...], outputs: tuple[str, ...]) -> list[Diagnostic]:
        return [*cls.STATISTICS, ALARM]

    @abstractmethod
    def statistics(self, y: np.ndarray) -> dict[str, float]:
        """The monitored statistics of the readings y (absolute, the model's ``use``d ones; NaN where missing)."""

    def _step(self, dy: np.ndarray, du: np.ndarray) -> Estimate:
        if self.fitted is None:
            source = self.params.model or "its model"
            raise LookupError(
                f"{self.kind}: {source} has no model of a plant with the sensors {', '.join(self.model.outputs)}; "
                "train one on a data set of this plant (python -m cosim.baselines.train)"
            )
        values = self.statistics((dy + self.operating_point.y)[self.use])
        over = any(not values[name] <= limit for name, limit in self.limits.items())  # NaN is over
        self._over, self._under = (self._over + 1, 0) if over else (0, self._under + 1)
        if self._over >= self.params.persistence:
            self._alarm = 1.0
        elif self._under >= self.params.persistence:
            self._alarm = 0.0
        shown = {
            d.name: min(values[d.name], d.bound) if np.isfinite(values[d.name]) else d.bound for d in self.STATISTICS
        }
        return Estimate(np.zeros(self.model.n), {**shown, ALARM.name: self._alarm})
