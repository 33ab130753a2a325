"""One run of a campaign, as a worker runs it: scenario with its settings, run, metrics, rows.

``execute_run`` is what the engine ships to its workers. It never raises for a run that fails: a
run that cannot be built or that stops with an error is a row with its status and error, and the
campaign goes on.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cosim.blas import one_thread
from cosim.campaign.results import rows_of
from cosim.campaign.spec import RunSpec
from cosim.errors import CosimError

if TYPE_CHECKING:
    from cosim.scenario import LoadedScenario


def preload() -> None:
    """Import what a run needs, once per worker, before the first run (so that runs cost runs)."""
    import scipy.signal  # noqa: F401 (observer designs import it when first used: about 2 s)

    import cosim.analysis.metrics  # noqa: F401
    import cosim.api  # noqa: F401
    import cosim.campaign.batch  # noqa: F401
    import cosim.run.runner  # noqa: F401


def ignore_interrupts() -> None:
    """Leave Ctrl-C to the coordinator: a terminal sends SIGINT to every process of its foreground
    group, local workers included, and each would print its own traceback while the coordinator
    stops them anyway."""
    import signal
    import threading

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)


def execute_batch_in(item: tuple[str, list[RunSpec]], keep_logs: str) -> list[dict[str, Any]]:
    """``execute_batch`` of a (folder, runs) item: the engine's task when several campaigns share it."""
    folder, specs = item
    return execute_batch(specs, folder, keep_logs)


def execute_batch(specs: list[RunSpec], folder: str, keep_logs: str) -> list[dict[str, Any]]:
    """Run ``specs``, runs of one scenario that differ in their seed or in what acts on each run's
    plant (``coordinator.batches``), together (``cosim.campaign.batch.run_together``); returns each
    run's part, in order, as ``execute_run`` would return it alone, with ``batched`` saying whether
    it ran in a batch and ``alone`` why not. Runs whose log is kept (``keep_logs`` all), runs that leave the batch and a
    configuration the batch cannot express run alone, through ``execute_run``."""
    start = time.perf_counter()
    batched: dict[int, _Attempt] = {}
    why = {spec.index: "a batch of one (--batch 1, or the only run of its configuration)" for spec in specs}
    if keep_logs == "all":
        why = dict.fromkeys(why, "its log is kept (--keep-logs all)")
    elif not specs[0].in_process:
        why = dict.fromkeys(why, "its nodes run in processes (bus = processes)")
    elif len(specs) > 1:
        with one_thread():  # as a run alone computes (cosim.blas)
            batched, why = _batch_attempts(specs)
    each = (time.perf_counter() - start) / len(specs)
    parts = []
    for spec in specs:
        attempt = batched.get(spec.index)
        if attempt is None:
            parts.append({**execute_run(spec, folder, keep_logs), "batched": False, "alone": why[spec.index]})
        else:
            parts.append({**_part(spec, folder, attempt, each, None), "batched": True})
    return parts


def _batch_attempts(specs: list[RunSpec]) -> tuple[dict[int, _Attempt], dict[int, str]]:
    """The runs of ``specs`` that completed in a batch, by index, and why each other one did not."""
    from cosim.campaign.batch import run_together
    from cosim.campaign.results import rows_of

    found, why = {}, {}
    members, described = [], []
    for spec in specs:
        try:
            loaded, known, state_unit = _loaded(spec)
        except CosimError as error:  # alone, it fails with the same error
            why[spec.index] = f"its settings do not apply ({error})"
            continue
        members.append((loaded, spec.seed))
        described.append((spec, known, state_unit))
    try:
        done = run_together(members)
    except Exception as error:  # noqa: BLE001 (a bug of the batch's: the runs alone say what they say)
        return {}, {spec.index: f"the batch failed ({type(error).__name__}: {error})" for spec in specs}
    for (spec, known, state_unit), run in zip(described, done):
        if run.metrics is None:
            why[spec.index] = run.refused or f"it left the batch at {run.left}"
            continue
        attempt = _Attempt(logged=False, status="completed", known=known, state_unit=state_unit)
        attempt.rows = rows_of(run.metrics)
        found[spec.index] = attempt
    return found, why


def execute_run(spec: RunSpec, folder: str, keep_logs: str) -> dict[str, Any]:
    """Run ``spec``; returns its part: ``rows`` (one per estimator, or one describing the failure)
    and ``state_unit``. A run whose log is not to be kept (``keep_logs`` none, or failed and the
    run completes) writes none: it is scored as it goes. With ``failed``, a run that does not
    complete is run again with its log in ``folder/logs`` (a run is deterministic from its seed:
    the same run), and that run's rows and log are the run's; with ``all`` every run writes its log."""
    start = time.perf_counter()
    log = Path(folder) / "logs" / f"run-{spec.index:06d}.mcap"
    attempt = _attempt(spec, log if keep_logs == "all" else None)
    if not attempt.logged and (attempt.unscored or (keep_logs == "failed" and attempt.status != "completed")):
        attempt = _attempt(spec, log)  # the same run again, with its log
    kept = (
        attempt.logged
        and log.exists()
        and (keep_logs == "all" or (keep_logs == "failed" and attempt.status != "completed"))
    )
    if log.exists() and not kept:
        log.unlink()
    return _part(spec, folder, attempt, time.perf_counter() - start, log if kept else None)


def _part(spec: RunSpec, folder: str, attempt: _Attempt, wall_time: float, log: Path | None) -> dict[str, Any]:
    """A run's part: its rows (one per estimator, or one describing the failure), its state unit."""
    common = {
        "run": spec.index,
        "replicate": spec.replicate,
        "seed": spec.seed,
        **dict(spec.columns),
        "status": attempt.status,
        "error": attempt.error,
        "wall_time_s": wall_time,
        "log": str(log.relative_to(folder)) if log is not None else "",
    }
    rows = attempt.rows or [attempt.known]
    return {"rows": [{**common, **row} for row in rows], "state_unit": attempt.state_unit}


@dataclass
class _Attempt:
    """One run of a spec: how it ended and its metric rows."""

    logged: bool
    status: str = "error"
    error: str = ""
    rows: list[dict[str, Any]] = field(default_factory=list)
    known: dict[str, Any] = field(default_factory=dict)
    """What a row says of a run that has no metrics (its faults, from the scenario)."""
    state_unit: str = ""
    unscored: bool = False
    """Run without a log, and its scoring failed on the way (a bug): to be run again with its log."""


def _attempt(spec: RunSpec, log: Path | None) -> _Attempt:
    """Run ``spec`` into ``log`` (None: no log, scored as it goes); never raises for a run that fails."""
    from cosim import api
    from cosim.analysis.metrics import measure

    attempt = _Attempt(logged=log is not None)
    try:
        loaded, attempt.known, attempt.state_unit = _loaded(spec)
        result = api.run(loaded, log, seed=spec.seed, in_process=spec.in_process, measure=True)
        attempt.status, attempt.error = result.status, result.error
        metrics = result.metrics
        if log is None and metrics is None:
            attempt.unscored = True
            return attempt
        if metrics is None or result.status != "completed":
            assert log is not None
            metrics = measure(log)  # a run that did not complete is read back, damage and all
        attempt.rows = rows_of(metrics)
    except CosimError as failure:
        attempt.error = str(failure)
    except Exception as failure:  # a bug, reported in its row: the campaign goes on
        attempt.error = f"{type(failure).__name__}: {failure}"
    return attempt


def _loaded(spec: RunSpec) -> tuple[LoadedScenario, dict[str, Any], str]:
    """The run's scenario with its settings, what its row says without metrics, its state unit."""
    from cosim.scenario import LoadedScenario, apply, parse

    base = LoadedScenario(parse(spec.scenario_text, spec.scenario_source), spec.scenario_source, spec.scenario_text)
    loaded = apply(base, spec.settings)
    kinds = sorted({fault.kind for fault in loaded.scenario.faults})
    known = {
        "fault_kind": "+".join(kinds) or "none",
        "fault_onset_s": min((f.start for f in loaded.scenario.faults), default=None),
    }
    units = {c.unit for c in loaded.scenario.plant_info.states}
    return loaded, known, units.pop() if len(units) == 1 else "mixed units"
