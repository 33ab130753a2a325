"""Running a campaign: its runs on an engine, their parts on disk, the results table at the end.

``run_campaign`` writes into one folder: ``campaign.toml`` (the file as given, with the command
line's seeds and settings, its scenario file named relative to the folder), ``versions.json``,
``parts/`` (one file per finished run), ``logs/`` (the logs kept) and ``results.parquet``. With
``resume`` it finishes the campaign a killed coordinator left (SIGKILL included): the folder's
campaign must be the same (that copy itself, or the file with the same options), and only runs
without a part run again.
"""

from __future__ import annotations

import functools
import json
import math
import os
import shlex
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cosim.campaign.engine import Engine, open_engine
from cosim.campaign.results import TableSchema, assemble, done_runs, write_part
from cosim.campaign.spec import Campaign, RunSpec
from cosim.campaign.worker import execute_batch_in
from cosim.errors import CosimError
from cosim.extras import require_all
from cosim.log.metadata import versions

KEEP_LOGS = ("all", "failed", "none")
MAX_BATCH = 32
"""The most runs a batch holds when its size is chosen: past it a run costs hardly less (bench/campaign.py)."""


@dataclass(frozen=True)
class CampaignProgress:
    done: int
    failed: int
    total: int
    skipped: int
    """Runs finished before this session (``resume``)."""
    elapsed: float
    mean_run_s: float

    @property
    def eta_s(self) -> float | None:
        ran = self.done - self.skipped
        if ran <= 0:
            return None
        return (self.total - self.done) * self.elapsed / ran


@dataclass(frozen=True)
class CampaignResult:
    path: Path
    runs: int
    failed: int
    resumed: int
    wall_time: float
    engine: str
    workers: int
    startup_time: float = 0.0
    """Wall time to start (or join) the engine."""
    loop_time: float = 0.0
    """Wall time from the first run submitted to the last result."""
    run_time: float = 0.0
    """The runs' own wall times (measured by the workers), summed."""
    batched: int = 0
    """Runs of this session that ran in a batch (the others ran alone: ``cosim.campaign.batch.refusal``)."""
    alone: dict[str, int] = field(default_factory=dict)
    """Why the others ran alone, with how many runs each reason sent alone."""


def engine_extras(engine: str) -> dict[str, list[str]]:
    """What the campaign engine needs of the extras: the table's writer, and Dask for ``dask``."""
    return {"campaign": ["pyarrow", *(["distributed"] if engine == "dask" else [])]}


def require_extras(engine: str) -> None:
    """MissingExtra now, before any run, if the table's writer (or the engine) is not installed."""
    require_all("cosim campaign", engine_extras(engine))


def run_campaign(
    campaign: Campaign,
    out: str | Path,
    *,
    engine: str | Engine = "dask",
    workers: int | None = None,
    address: str | None = None,
    resume: bool = False,
    keep_logs: str = "failed",
    on_progress: Callable[[CampaignProgress], None] | None = None,
    on_start: Callable[[str, int], None] | None = None,
    batch: int | None = None,
) -> CampaignResult:
    """Run every run of ``campaign`` (those without a part, with ``resume``) and write the table.
    Runs of one configuration that differ in their seed step together in batches of ``batch``
    (None: chosen, ``batches``; 1: one at a time); the table is the same whatever the batches.
    ``engine``: its name (an engine is opened for this campaign and closed after it), or an open
    ``Engine`` that several campaigns share."""
    check_batch(batch)
    _check_keep_logs(keep_logs)
    require_extras(engine if isinstance(engine, str) else "inline")
    pending = _Pending(campaign, out, resume, on_progress)
    with _opened(engine, workers, address) as pool:
        if on_start is not None:
            on_start(pool.description, pool.workers)
        (result,) = _run(pool, [pending], keep_logs, batch)
    return result


def run_campaigns(
    members: Sequence[tuple[Campaign, str | Path, bool]],
    engine: Engine,
    *,
    keep_logs: str = "failed",
    batch: int | None = None,
    on_begin: Callable[[int], None] | None = None,
    on_progress: Callable[[int, CampaignProgress], None] | None = None,
    on_done: Callable[[int, CampaignResult], None] | None = None,
) -> list[CampaignResult]:
    """Several campaigns (each with its folder, and whether to resume it) on one open engine, each
    written as ``run_campaign`` writes it. Their batches go to the engine as one stream, campaign
    after campaign, so that one campaign's last batches run beside the next one's first: no worker
    waits for a campaign's slowest batch before the next campaign starts (``cosim benchmark``).
    ``on_begin(i)``: campaign i's first batch is about to be submitted; ``on_progress(i, ...)``
    after each of its runs; ``on_done(i, result)`` once its table is written."""
    check_batch(batch)
    _check_keep_logs(keep_logs)
    folders = [Path(folder).resolve() for _, folder, _ in members]
    if len(set(folders)) != len(folders):
        raise CosimError("run_campaigns: give each campaign a folder of its own")
    pendings = [
        _Pending(campaign, folder, resume, None if on_progress is None else functools.partial(on_progress, i))
        for i, (campaign, folder, resume) in enumerate(members)
    ]
    return _run(engine, pendings, keep_logs, batch, on_begin, on_done)


def _check_keep_logs(keep_logs: str) -> None:
    if keep_logs not in KEEP_LOGS:
        raise CosimError(f"--keep-logs {keep_logs}: choose one of {', '.join(KEEP_LOGS)}")


class _Pending:
    """A campaign being run: its folder (prepared), its runs, those still to run in batches, its tally."""

    def __init__(
        self, campaign: Campaign, out: str | Path, resume: bool, on_progress: Callable[[CampaignProgress], None] | None
    ) -> None:
        self.created = time.perf_counter()
        self.campaign, self.folder = campaign, Path(out).resolve()
        _prepare(self.folder, campaign, resume)
        self.runs = campaign.runs()
        self.done = done_runs(self.folder)
        self.tally = _Tally(
            len(self.runs), len(self.done), sum(_failed(self.folder, i) for i in self.done), on_progress
        )
        self.todo: list[list[RunSpec]] = []
        self.waiting = 0  # batches submitted whose outcomes have not come back
        self.begun = self.created

    @functools.cached_property
    def ticks(self) -> int:
        """The ticks of its runs still to run: a rough measure of its work."""
        base = self.campaign.base.scenario
        total = 0
        for run in self.runs:
            if run.index not in self.done:
                settings = dict(run.settings)
                total += round(settings.get("duration", base.duration) / settings.get("sample_time", base.sample_time))
        return total

    def begin(self, batch: int | None, workers: int) -> None:
        """Its batches, about to be submitted; its clock (progress, ETA) starts now."""
        self.begun = self.tally.start = time.perf_counter()
        self.todo = batches([run for run in self.runs if run.index not in self.done], batch, workers)
        self.waiting = len(self.todo)

    def result(self, pool: Engine) -> CampaignResult:
        """Its table, written now that every run has its part."""
        campaign, runs, tally = self.campaign, self.runs, self.tally
        metadata = {
            "cosim.campaign": campaign.text,
            "cosim.campaign.name": campaign.spec.name,
            "cosim.versions": json.dumps(versions()),
        }
        path = assemble(self.folder, [run.index for run in runs], _schema(campaign, runs), metadata)
        now = time.perf_counter()
        return CampaignResult(
            path,
            len(runs),
            tally.failed,
            len(self.done),
            now - self.created,
            pool.description,
            pool.workers,
            self.begun - self.created,
            now - self.begun,
            tally.run_time,
            tally.batched,
            dict(sorted(tally.alone.items(), key=lambda item: -item[1])),
        )


def _run(
    pool: Engine,
    pendings: Sequence[_Pending],
    keep_logs: str,
    batch: int | None,
    on_begin: Callable[[int], None] | None = None,
    on_done: Callable[[int, CampaignResult], None] | None = None,
) -> list[CampaignResult]:
    """The pending campaigns' batches through ``pool`` as one stream (see ``run_campaigns``)."""
    found: dict[int, CampaignResult] = {}
    by_folder = {str(p.folder): i for i, p in enumerate(pendings)}

    def finish(i: int) -> None:
        found[i] = pendings[i].result(pool)
        if on_done is not None:
            on_done(i, found[i])

    def stream() -> Iterator[tuple[str, list[RunSpec]]]:
        for i, pending in enumerate(pendings):
            pending.begin(batch, _idle_workers(pendings, i, pool.workers))
            if on_begin is not None:
                on_begin(i)
            if not pending.todo:
                finish(i)
            for specs in pending.todo:
                yield str(pending.folder), specs

    for (folder, specs), outcomes in pool.results(execute_batch_in, stream(), keep_logs):
        pending = pendings[i := by_folder[folder]]
        _collect([(specs, outcomes)], pending.folder, pending.tally)
        pending.waiting -= 1
        if pending.waiting == 0:
            finish(i)
    return [found[i] for i in range(len(pendings))]


def _idle_workers(pendings: Sequence[_Pending], i: int, workers: int) -> int:
    """The workers campaign i must keep busy by itself. A campaign is cut into more batches than it
    needs only so that no worker waits while it runs; in a stream, the campaigns after it fill the
    other workers where they hold at least as many ticks (runs × ticks, a rough measure of work) as
    it does per other worker: then it runs in as few batches as it can (larger batches run faster)."""
    after = sum(pending.ticks for pending in pendings[i + 1 :])
    return 1 if after >= (workers - 1) * pendings[i].ticks else workers


def check_batch(batch: int | None) -> None:
    """CosimError for a batch size that is not a positive number of runs (None: chosen)."""
    if batch is not None and batch < 1:
        raise CosimError(f"--batch {batch}: give a positive number of runs per batch (1: one at a time)")


def _opened(engine: str | Engine, workers: int | None, address: str | None) -> AbstractContextManager[Engine]:
    """The engine to run on: a new one by name (closed after the campaign), or the one given (left open)."""
    return nullcontext(engine) if isinstance(engine, Engine) else open_engine(engine, workers, address)


def _collect(results: Iterable[tuple[Any, Any]], folder: Path, tally: _Tally) -> None:
    """Each batch's outcomes as the engine gives them back: every run's part written, the tally told
    (a batch whose worker process died: each of its runs failed, saying so)."""
    for specs, outcomes in results:
        if isinstance(outcomes, BaseException):  # the worker process died running them
            outcomes = [_died(spec, outcomes) for spec in specs]
        for spec, outcome in zip(specs, outcomes):
            tally.batched += bool(outcome.pop("batched", False))
            if (why := outcome.pop("alone", None)) is not None:
                tally.alone[why] = tally.alone.get(why, 0) + 1
            write_part(folder, spec.index, outcome)
            tally.add(outcome["rows"])


#: Settings that act on a run's own plant (its faults, noise, disturbances, inputs, initial state): runs
#: that differ only in these (and their seed) go to one batch, where ``batch.run_together`` steps together
#: those whose designs agree.
PER_RUN_SETTINGS = ("faults", "noise", "disturbances", "inputs", "plant.initial_state")


def batches(runs: list[RunSpec], size: int | None, workers: int) -> list[list[RunSpec]]:
    """``runs`` in batches: runs of one scenario whose settings differ at most in ``PER_RUN_SETTINGS``,
    in index order, at most ``size`` a batch. None chooses the size: every such group's runs in as
    few batches as ``MAX_BATCH`` allows, cut smaller where that leaves a worker idle."""
    groups: dict[tuple[Any, ...], list[RunSpec]] = {}
    for run in runs:
        shared = [(path, value) for path, value in run.settings if not path.startswith(PER_RUN_SETTINGS)]
        key = (run.scenario_text, run.scenario_source, repr(shared), run.in_process)  # settings hold lists, tables
        groups.setdefault(key, []).append(run)
    found = []
    for group in groups.values():
        if size is not None:
            count = math.ceil(len(group) / size)
        else:
            count = max(math.ceil(len(group) / MAX_BATCH), math.ceil(max(1, workers) / len(groups)))
        each = math.ceil(len(group) / min(count, len(group)))
        found += [group[i : i + each] for i in range(0, len(group), each)]
    return sorted(found, key=lambda batch: batch[0].index)


class _Tally:
    """The runs finished so far, told to ``on_progress`` after each."""

    def __init__(
        self, total: int, skipped: int, failed: int, on_progress: Callable[[CampaignProgress], None] | None
    ) -> None:
        self.start = time.perf_counter()
        self.total, self.skipped, self.finished, self.failed = total, skipped, skipped, failed
        self.run_time = 0.0
        self.batched = 0
        self.alone: dict[str, int] = {}
        self.on_progress = on_progress

    def add(self, rows: list[dict[str, Any]]) -> None:
        """A run's rows: failed if any row did not complete; its wall time is its longest row's."""
        self.finished += 1
        self.failed += any(row.get("status") != "completed" for row in rows)
        self.run_time += max((row.get("wall_time_s") or 0.0) for row in rows)
        if self.on_progress is not None:
            ran = self.finished - self.skipped
            elapsed = time.perf_counter() - self.start
            mean = self.run_time / ran if ran else 0.0
            self.on_progress(CampaignProgress(self.finished, self.failed, self.total, self.skipped, elapsed, mean))


def _died(spec: RunSpec, error: BaseException) -> dict[str, Any]:
    """The part of a run whose worker process died running it."""
    row = {
        "run": spec.index,
        "replicate": spec.replicate,
        "seed": spec.seed,
        **dict(spec.columns),
        "status": "error",
        "error": f"the worker running it died: {error}",
    }
    return {"rows": [row]}


def _schema(campaign: Campaign, runs: list[RunSpec]) -> TableSchema:
    """The table's columns: the axis and sample columns of these runs, the state's unit."""
    states = {c.unit for c in campaign.base.scenario.plant_info.states}
    varying: dict[str, list[Any]] = {}
    for run in runs:
        for name, value in run.columns:
            varying.setdefault(name, []).append(value)
    return TableSchema.of(varying, states.pop() if len(states) == 1 else "mixed units")


def resume_command(folder: Path) -> str:
    """The command that finishes the campaign in ``folder``, as a shell takes it: the folder's own
    copy of the campaign holds the command line's changes, and names its scenario file from there."""
    return f"cosim campaign {shlex.quote(str(folder / 'campaign.toml'))} --out {shlex.quote(str(folder))} --resume"


def _prepare(folder: Path, campaign: Campaign, resume: bool) -> None:
    stored = folder / "campaign.toml"
    kept = campaign.kept_text(folder)
    if stored.exists():
        if not resume:
            raise CosimError(
                f"--out {folder}: holds a campaign already; add --resume to finish it, or choose another folder"
            )
        if stored.read_text(encoding="utf-8") != kept:
            raise CosimError(
                f"--resume: {folder} holds another campaign (its campaign.toml differs from {campaign.source} "
                f"with the options given); finish it with: {resume_command(folder)}; or choose another --out"
            )
        for leftover in (folder / "parts").glob("*.tmp"):  # a part being written when the coordinator died
            leftover.unlink()
        return
    if folder.exists() and any(folder.iterdir()):
        raise CosimError(f"--out {folder}: the folder is not empty and holds no campaign; choose a new or empty folder")
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "versions.json").write_text(json.dumps(versions(), indent=2) + "\n")
    temporary = folder / "campaign.toml.tmp"
    temporary.write_text(kept, encoding="utf-8")
    os.replace(temporary, stored)  # last: a folder with campaign.toml is a campaign


def _failed(folder: Path, index: int) -> bool:
    part = json.loads((folder / "parts" / f"run-{index:06d}.json").read_text())
    return any(row.get("status") != "completed" for row in part["rows"])
