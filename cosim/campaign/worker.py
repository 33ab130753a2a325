"""One run of a campaign, as a worker runs it: scenario with its settings, run, metrics, rows.

``execute_run`` is what the engine ships to its workers. It never raises for a run that fails: a
run that cannot be built or that stops with an error is a row with its status and error, and the
campaign goes on.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from cosim.campaign.results import rows_of
from cosim.campaign.spec import RunSpec
from cosim.errors import CosimError


def preload() -> None:
    """Import what a run needs, once per worker, before the first run (so that runs cost runs)."""
    import scipy.signal  # noqa: F401 (observer designs import it when first used: about 2 s)

    import cosim.analysis.metrics  # noqa: F401
    import cosim.api  # noqa: F401
    import cosim.run.runner  # noqa: F401


def ignore_interrupts() -> None:
    """Leave Ctrl-C to the coordinator: a terminal sends SIGINT to every process of its foreground
    group, local workers included, and each would print its own traceback while the coordinator
    stops them anyway."""
    import signal
    import threading

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)


def execute_run(spec: RunSpec, folder: str, keep_logs: str) -> dict[str, Any]:
    """Run ``spec`` with its log in ``folder/logs``; returns its part: ``rows`` (one per estimator,
    or one describing the failure) and ``state_unit``."""
    from cosim import api
    from cosim.analysis.metrics import measure
    from cosim.scenario import LoadedScenario, apply, parse

    start = time.perf_counter()
    log = Path(folder) / "logs" / f"run-{spec.index:06d}.mcap"
    status, error, rows, state_unit = "error", "", [], ""
    known: dict[str, Any] = {}
    try:
        base = LoadedScenario(parse(spec.scenario_text, spec.scenario_source), spec.scenario_source, spec.scenario_text)
        loaded = apply(base, spec.settings)
        kinds = sorted({spec.kind for spec in loaded.scenario.faults})
        known = {
            "fault_kind": "+".join(kinds) or "none",
            "fault_onset_s": min((f.start for f in loaded.scenario.faults), default=None),
        }
        units = {c.unit for c in loaded.scenario.plant_info.states}
        state_unit = units.pop() if len(units) == 1 else "mixed units"
        result = api.run(loaded, log, seed=spec.seed, in_process=spec.in_process, measure=True)
        status, error = result.status, result.error
        # scored while the run wrote its log; a run that did not complete is read back, damage and all
        rows = rows_of(result.metrics if status == "completed" and result.metrics is not None else measure(log))
    except CosimError as failure:
        error = str(failure)
    except Exception as failure:  # a bug, reported in its row: the campaign goes on
        error = f"{type(failure).__name__}: {failure}"
    kept = log.exists() and (keep_logs == "all" or (keep_logs == "failed" and status != "completed"))
    if log.exists() and not kept:
        log.unlink()
    common = {
        "run": spec.index,
        "replicate": spec.replicate,
        "seed": spec.seed,
        **dict(spec.columns),
        "status": status,
        "error": error,
        "wall_time_s": time.perf_counter() - start,
        "log": str(log.relative_to(folder)) if kept else "",
    }
    return {"rows": [{**common, **row} for row in rows] or [{**common, **known}], "state_unit": state_unit}
