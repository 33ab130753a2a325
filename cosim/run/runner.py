"""The co-simulation runner: one run of a scenario into an MCAP log.

The plant runs here; every estimator runs as a node in a process of its own (``cosim node``) and
talks to the runner only through CAN frames on the run's bus; with the ``virtual`` interface the
nodes run in this process, through the same classes. A ``Run`` is a plan (``cosim.run.plan``:
what the scenario designs before tick 0), a session (``cosim.run.session``: the bus, the
participants, the accounting, the log) and the tick loop over the plant (``cosim.run.loop``).
Whatever ends the run, the nodes are stopped and the MCAP log is finished with how the run ended.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any
from uuid import uuid4

from cosim import progress
from cosim.blas import one_thread
from cosim.bus.codec import Codec
from cosim.bus.registry import Registration
from cosim.bus.transport import allocate
from cosim.errors import CodecError, ScenarioError
from cosim.log.metadata import DBC_ATTACHMENT, RUN, SCENARIO, VERSIONS, versions
from cosim.log.writer import LogSink, RecordSink
from cosim.run.loop import Execution, PlantSource, execute, start_participants
from cosim.run.outcome import Progress, RunResult
from cosim.run.plan import RunPlan
from cosim.run.session import Session
from cosim.scenario import LoadedScenario


class Run(Execution):
    """One co-simulation run of a loaded scenario into an MCAP file.

    ``overrides`` (``seed``, ``interface``, ``channel``, ``port``, ``mode``, ``speed``) replace the
    scenario's values, validated like the file's. Building a Run designs everything (``plan``);
    ``execute`` runs it. With ``out`` None the run writes no file: everything goes to the sink
    ``execute`` is given (a ``RecordSink``: the live scorer), as a campaign run whose log is not kept.
    """

    def __init__(
        self, loaded: LoadedScenario, out: str | Path | None, seed: int | None = None, **overrides: Any
    ) -> None:
        self.plan = RunPlan.build(loaded, seed, **overrides)
        with progress.step(f"loading the plant {self.plan.scenario.plant.model} again, for the first tick's frames"):
            first = PlantSource(self.plan)
        try:  # the first tick's frames, before any process starts: a value outside its bus range is the scenario's
            first.frames(0)
        except CodecError as error:
            raise ScenarioError(f"{loaded.source}: {error}") from None
        finally:
            first.close()
        self.loaded, self.out = loaded, None if out is None else Path(out)
        self.run_id = uuid4().hex[:12]
        self.source: PlantSource | None = None

    @property
    def plant_said(self) -> str:
        """What an FMU plant logged and printed (in the log's /plant/fmu), in a few words; "" if nothing."""
        said = self.source.said if self.source is not None else None
        return f"{self.plan.scenario.plant_info.name} {said}" if said else ""

    @property
    def estimators(self) -> dict[str, Any]:
        return self.plan.estimators

    @property
    def warnings(self) -> tuple[str, ...]:
        return self.plan.warnings

    @property
    def codec(self) -> Codec:
        return self.plan.codec

    @property
    def participants(self) -> list:
        return self.session.participants if self.session is not None else []

    def execute(
        self,
        on_progress: Callable[[Progress], None] | None = None,
        progress_every: float = 0.2,
        on_start: Callable[[Run], None] | None = None,
        sink: LogSink | RecordSink | None = None,
    ) -> RunResult:
        """Run every tick; the log is complete and valid whatever ends the run. ``sink`` (the live
        view, ``cosim.log.live``; the live scorer) gets every channel and message the log gets."""
        plan, s = self.plan, self.plan.scenario
        self.bus = bus = allocate(
            s.bus.interface, s.bus.channel, s.bus.port, s.bus.fd, s.bus.allow_network, s.bus.mirror
        )
        registration = Registration(
            self.run_id,
            {
                "scenario": s.name,
                "source": self.loaded.source,
                "seed": s.seed,
                "sample_time": s.sample_time,
                "bus": bus.to_dict(),
                "dbc": plan.codec.dbc,
                "log": "" if self.out is None else str(self.out.resolve()),
                "nodes": {name: plan.node_spec(name, bus).to_json() for name in plan.external_nodes},
                "control_keys": plan.client_keys(),
            },
        )
        with one_thread(), plan.session(self.out, bus, registration, sink) as session:  # cosim.blas
            self.session = session
            self._write_metadata(session)
            session.begin_log(f"{s.name} seed={s.seed} ticks={s.ticks} mode={s.timing.mode}", plan.warnings)

            if plan.plant_messages:
                session.recorder.fmu_messages(0, *session.time(0), list(plan.plant_messages))
            with progress.step(f"loading the plant {s.plant.model} for the run"):
                self.source = PlantSource(plan, session.interrupts.check)
            self.source.said.add(list(plan.plant_messages))

            def start() -> None:
                start_participants(plan, session)
                if on_start is not None:
                    on_start(self)

            return execute(self.source, session, start, plan.senders, on_progress, progress_every)

    def _write_metadata(self, session: Session) -> None:
        plan, log = self.plan, session.log
        log.metadata(RUN, plan.run_record(start_time_ns=time.time_ns()).to_metadata())
        log.metadata(SCENARIO, plan.scenario_record().to_metadata())
        log.metadata(VERSIONS, versions())
        info = plan.scenario.plant_info
        if info.model_file:
            log.attach(info.model_file, "application/xml", info.model_path.read_bytes())
        log.attach(DBC_ATTACHMENT, "text/plain", plan.codec.dbc.encode())


def run(
    loaded: LoadedScenario,
    out: str | Path,
    seed: int | None = None,
    on_progress: Callable[[Progress], None] | None = None,
    **overrides: Any,
) -> RunResult:
    """Run a loaded scenario and write its log to ``out``."""
    return Run(loaded, out, seed, **overrides).execute(on_progress)
