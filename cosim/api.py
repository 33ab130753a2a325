"""The Python API: what the command line does, as three functions.

    from cosim.api import load_scenario, run, metrics

    loaded = load_scenario("masses-bias", {"duration": 5.0, "faults[0].value": [0.5, 0, 0]})
    result = run(loaded, "runs/short.mcap", seed=3, in_process=True)
    print(result.status, metrics(result.path)["estimators"]["kalman"]["rms_post_fault"])

``load_scenario`` takes a built-in name or a TOML path and settings as ``cosim run --set`` takes
them (a mapping of path → value, or ``"KEY=VALUE"`` strings), validated like a file. ``run`` runs
it into an MCAP log, with its estimators in node processes on a host-local multicast bus (as
``cosim run``), or, with ``in_process``, on the in-process bus (the codec and its quantization
still in the loop: the same frames, bit for bit). ``metrics`` is ``cosim inspect --json``'s object.
Errors are ``cosim.errors.CosimError`` with one message naming what to fix.

It also holds the contract a user's parts are written against (``docs/extending.md``): an
estimator subclasses ``Estimator`` (a ``Params`` dataclass, the constructor ``(model, params,
sample_time)`` on the plant's ``LinearModel``, ``_step(dy, du) -> Estimate`` in deviation
coordinates, ``Diagnostic`` channels of a ``DiagnosticKind``); a controller ``Controller``; a fault
model ``SensorFault`` or ``ActuatorFault``; a plant is a ``PlantInfo``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

from cosim.run.outcome import Progress, RunResult
from cosim.scenario import LoadedScenario, apply, load, parse_setting
from estimators import Estimate, Estimator, LinearModel, ParameterError
from estimators.controller import Command, Controller
from estimators.diagnostics import Diagnostic, DiagnosticKind
from faults.models import ActuatorFault, BusFault, FrameFate, SensorFault
from mjcf import Parameter, PlantInfo

__all__ = [
    "ActuatorFault",
    "BusFault",
    "Command",
    "Controller",
    "Diagnostic",
    "DiagnosticKind",
    "Estimate",
    "Estimator",
    "FrameFate",
    "LinearModel",
    "LoadedScenario",
    "Parameter",
    "ParameterError",
    "PlantInfo",
    "Progress",
    "RunResult",
    "SensorFault",
    "load_scenario",
    "metrics",
    "run",
]


def load_scenario(
    name_or_path: str | Path | None = None, settings: Mapping[str, Any] | Iterable[str] | None = None
) -> LoadedScenario:
    """A built-in scenario by name, or a TOML file (default: the default scenario), with ``settings``."""
    loaded = load(name_or_path)
    if settings is None:
        return loaded
    items = list(settings.items()) if isinstance(settings, Mapping) else [parse_setting(text) for text in settings]
    return apply(loaded, items)


def run(
    scenario: LoadedScenario | str | Path | None,
    out: str | Path | None,
    *,
    seed: int | None = None,
    in_process: bool = False,
    on_progress: Callable[[Progress], None] | None = None,
    measure: bool = False,
    **options: Any,
) -> RunResult:
    """Run a scenario (a loaded one, or a name or path) into the MCAP log ``out``; returns how it
    ended. ``options`` are ``cosim run``'s: ``interface``, ``channel``, ``port``, ``mode``, ``speed``.
    With ``measure``, the result's ``metrics`` are the log's (``metrics(out)`` as a ``RunMetrics``),
    scored while the run wrote it rather than by reading it again. With ``out`` None the run writes
    no log at all and is scored as it goes (``measure`` is implied): its metrics are, field for
    field, those of the same run with its log (but ``file``, empty)."""
    from dataclasses import replace

    from cosim.analysis.metrics import LiveMeasurement
    from cosim.run.runner import Run

    loaded = scenario if isinstance(scenario, LoadedScenario) else load(scenario)
    if in_process:
        options["interface"] = "virtual"
    live = LiveMeasurement() if measure or out is None else None
    result = Run(loaded, out, seed, **options).execute(on_progress, sink=live)
    return replace(result, metrics=live.result(result.path)) if live is not None else result


def metrics(log: str | Path) -> dict[str, Any]:
    """The metrics of a log (``cosim inspect --json``; keys in docs/metrics.md)."""
    from cosim.analysis.metrics import compute_metrics

    return compute_metrics(log)
