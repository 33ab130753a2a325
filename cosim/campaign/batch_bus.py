"""The in-process ideal bus of a batch where it does more than carry each run's frames into their
tick: bus faults and attacks on the sensors' frames, SecOC, the key-less intrusion detector.

A run's bus does here what it does alone (``cosim.run.session.Session.send`` and the nodes'
``cosim.bus.client.Client.feed``), through the same objects wherever a frame is not simply the
runner's, and on arrays where it is:

- a run whose bus faults act in a tick (one of them is active) has its frames of the tick built
  (``runner_frames``, as its ``PlantSource`` builds them) and put through its own ``BusFaultStage``
  (its models seeded as alone): the intruders' frames, the lost ones, SYNC re-announced. Every
  intruder's frame goes through the run's own ``SecOC.verify`` (the runner's verdict, which is every
  node's: the same keys, frames and order), each genuine one is accepted as signed
  (``SecOC.accept``: the sender signed it); what the nodes take goes through the run's own
  ``TickAssembler`` (a second copy of a reading makes it NaN, a frame after the tick completed is
  not taken), whose tick is the readings the estimators get. An intruder that records what it will
  replay hears, before such a tick, the frames it would have heard since its stage last acted
  (``_catch_up``: the same stage fed the recorded messages' frames of those ticks, which no fault
  touched), so its record is the one it has alone;
- in every other run and tick the readings are what the runner sent;
- the intrusion detector of the K runs (``DetectorRuns``) checks the genuine frames of a tick on
  arrays and each intruder's frame by itself, by the rule ``IntrusionDetector`` applies to each;
- a tick with an intruder's frame on the runner's ids is contested unless the bus authenticates
  (``contests``), as ``Traffic.injected`` has it.

What a batch does not emulate on the ideal bus it refuses (``refusal``): bus faults other than
``SUPPORTED`` or acting on other frames than the sensors', bus faults in a closed loop, SecOC or
the detector in a closed loop, other traffic. An arbitrated wire is ``cosim.campaign.batch_wire``'s
(every bus fault, open and closed loops, the detector, background traffic; it refuses SecOC).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

import faults as fm
from cosim.analysis.metrics.scorer import BusVerdicts
from cosim.bus.client import TickAssembler, TickFrames
from cosim.bus.codec import COMMAND, SENSOR, Decoded, MessageSpec
from cosim.bus.secoc import SecOC
from cosim.campaign.batch_wire import refusal as wire_refusal
from cosim.errors import CodecError, CosimError
from cosim.log.topics import SecurityRejection
from cosim.run.busfaults import BusFaultStage, Frame
from cosim.run.detector import DetectorRuns
from cosim.run.loop import runner_frames
from cosim.run.plan import RunPlan
from cosim.run.traffic import contests, own_ids
from cosim.scenario.faults import build_bus_faults

SUPPORTED = ("spoofing", "replay", "frame_loss", "suspension", "masquerade")
"""The bus faults a batch emulates, each exactly (``tests/test_batch_bus.py``): on an ideal bus, on
the sensors' frames."""


def refusal(plan: RunPlan) -> str | None:
    """Why a batch cannot give the bus of ``plan``'s runs (None: it can, or it only carries frames);
    an arbitrated wire's are ``cosim.campaign.batch_wire``'s."""
    s = plan.scenario
    if s.bus.timing == "arbitrated":
        return wire_refusal(plan)
    models = build_bus_faults(s)
    other = sorted({model.kind for model in models} - set(SUPPORTED))
    sensors = {plan.codec.sensor(name).name for name in s.sensors}
    reasons = [
        (bool(other), f"its bus faults {', '.join(other)} act on frames in ways a batch does not emulate"),
        (any(set(m.targets()) - sensors for m in models), "its bus faults act on frames other than the sensors'"),
        (bool(models) and plan.controller is not None, "its bus faults act in a closed loop"),
        (plan.authenticated and plan.controller is not None, "its frames are authenticated (SecOC) in a closed loop"),
        (s.bus.intrusion_detector and plan.controller is not None, "its intrusion detector reads a closed loop"),
        (bool(s.bus.traffic), "other traffic shares its bus"),
    ]
    return next((why for refuse, why in reasons if refuse), None)


def acts(plan: RunPlan) -> bool:
    """Whether the bus of ``plan``'s runs does more than carry their frames into their tick."""
    s = plan.scenario
    return bool(build_bus_faults(s)) or plan.authenticated or s.bus.intrusion_detector


class BusBatch:
    """The bus of K runs of one design (``cosim.campaign.batch._Batch``), tick by tick: ``runner``
    takes the runner's frames of a tick and gives the readings the nodes take, ``estimates`` the
    nodes' frames, ``verdicts`` what the detector and SecOC said of the tick."""

    def __init__(
        self,
        plans: Sequence[RunPlan],
        sensor_specs: Sequence[MessageSpec],
        command_specs: Sequence[MessageSpec],
        estimates: Sequence[Sequence[MessageSpec]],
        leave: Callable[[int, int, str], None],
    ) -> None:
        plan = plans[0]
        s = plan.scenario
        self.codec, self.dt_ns, self.sensors = plan.codec, s.dt_ns, s.sensors
        self.sensor_specs, self.command_specs, self.leave = list(sensor_specs), list(command_specs), leave
        runs = len(plans)
        self.models = [build_bus_faults(each.scenario) for each in plans]
        self.stages = [_stage(each, models) if models else None for each, models in zip(plans, self.models)]
        # the messages each run's intruders record (those whose bus faults ``observe`` frames)
        self.recorded = [
            {name for m in models if type(m).observe is not fm.BusFault.observe for name in m.targets()}
            for models in self.models
        ]
        self.secoc: list[SecOC] | None = None
        if plan.authenticated:
            self.secoc = [secoc for each in plans if (secoc := each.secoc()) is not None]
        self.assemblers = [TickAssembler(self.codec, s.sample_time) for _ in plans]
        self.own = own_ids(self.codec, plan.own_senders)
        width = max((len(models) for models in self.models), default=0)
        self.starts = np.full((runs, width), math.inf)
        self.ends = np.full((runs, width), -math.inf)
        for r, models in enumerate(self.models):
            self.starts[r, : len(models)] = [m.start for m in models]
            self.ends[r, : len(models)] = [m.end for m in models]
        self._mask = np.zeros((runs, width), dtype=bool)
        self.labels: list[tuple[str, ...]] = [() for _ in plans]
        self.fed = np.full(runs, -1)  # the last tick each run's stage was given
        # each tick's (measured, sent), for _catch_up: kept only where an intruder records what it hears
        self.history: list[tuple[np.ndarray, np.ndarray]] | None = [] if any(self.recorded) else None
        self.last_sent = np.full((runs, len(self.sensor_specs)), -1)  # the last tick of each genuine reading
        self.contested = np.zeros(runs, dtype=int)
        self.missed = np.zeros(runs, dtype=int)  # the runner's frames each node found missing
        self.rejections: list[list[SecurityRejection]] = [[] for _ in plans]
        self._forged: list[tuple[int, list[Frame]]] = []
        self.sensor_ids = [spec.frame_id for spec in self.sensor_specs]
        self.command_ids = [spec.frame_id for spec in self.command_specs]
        self.estimate_messages = [list(messages) for messages in estimates]
        self.detector = None
        if s.bus.intrusion_detector:
            ids = self.sensor_ids + self.command_ids + [m.frame_id for ms in self.estimate_messages for m in ms]
            self.detector = DetectorRuns(self.codec, self.dt_ns, runs, ids)

    def active(self, t: float) -> list[tuple[str, ...]]:
        """Each run's bus faults active at t, by label (what its ``/truth/faults`` adds)."""
        mask = (self.starts <= t) & (t < self.ends)
        for r in np.flatnonzero((mask != self._mask).any(axis=1)).tolist():
            self.labels[r] = tuple(m.label for m, on in zip(self.models[r], mask[r]) if on)
        self._mask = mask
        return self.labels

    def runner(
        self,
        k: int,
        measured: np.ndarray,
        sent: np.ndarray,
        carried: np.ndarray,
        commands: np.ndarray,
        carried_commands: np.ndarray,
        ranges: tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]],
        alive: np.ndarray,
    ) -> np.ndarray:
        """Tick k's readings as the nodes take them (K, sensors; NaN: missing or distrusted), from
        the runner's: ``measured`` and which are ``sent``, ``carried`` as their frames carry them,
        the open loop's ``commands`` (as given and as carried); ``ranges`` the sensors' and the
        commands' signal ranges. A run whose bus raises (a forged value outside its range) or
        whose nodes would not complete the tick leaves the batch."""
        readings = np.where(sent, carried, np.nan)
        arrived = sent.copy()
        if self.history is not None:
            self.history.append((measured.copy(), sent.copy()))
        self.rejections = [[] for _ in self.rejections]
        self._forged = []
        acting = alive & (self._mask.any(axis=1) if self._mask.size else np.zeros_like(alive))
        for r in np.flatnonzero(acting).tolist():
            try:
                tick, arrived[r] = self._run_tick(r, k, measured[r], sent[r], commands[r])
            except (CodecError, CosimError) as error:
                self.leave(r, k, str(error))
                alive[r] = False
                continue
            readings[r] = [tick.sensors.get(name, math.nan) for name in self.sensors]
        self.last_sent = np.where(arrived, k, self.last_sent)
        if self.detector is not None:
            t_ns, counter = k * self.dt_ns, k % self.codec.tick_modulus
            (slo, shi), (clo, chi) = ranges
            in_range = np.concatenate(
                [(slo <= carried) & (carried <= shi), (clo <= carried_commands) & (carried_commands <= chi)], axis=1
            )
            came = np.concatenate([arrived, np.ones(carried_commands.shape, dtype=bool)], axis=1)
            self.detector.frames(t_ns, counter, self.sensor_ids + self.command_ids, came, in_range)
            for r, forged in self._forged:
                for _, decoded in forged:
                    assert decoded is not None  # SUPPORTED forges the run's messages only
                    self.detector.frame(r, t_ns, decoded.spec.frame_id, decoded)
        return readings

    def estimates(self, k: int, values: Sequence[np.ndarray], bounds: Sequence[tuple[np.ndarray, np.ndarray]]) -> None:
        """Each estimator's frames of tick k, its signals' values as they carry them (K, signals)
        with their ranges: the detector checks them."""
        if self.detector is None:
            return
        columns = []
        for messages, v, (lo, hi) in zip(self.estimate_messages, values, bounds):
            inside = (lo <= v) & (v <= hi)
            at = 0
            for message in messages:  # a frame is out of range where one of its signals is
                columns.append(inside[:, at : at + len(message.signals)].all(axis=1))
                at += len(message.signals)
        if not columns:
            return
        in_range = np.stack(columns, axis=1)
        ids = [message.frame_id for messages in self.estimate_messages for message in messages]
        self.detector.frames(k * self.dt_ns, k % self.codec.tick_modulus, ids, np.ones_like(in_range), in_range)

    def verdicts(self) -> BusVerdicts:
        """What the detector and SecOC said of the tick just given."""
        return BusVerdicts(self.detector.verdicts() if self.detector is not None else None, self.rejections)

    def _run_tick(
        self, r: int, k: int, measured: np.ndarray, sent: np.ndarray, commands: np.ndarray
    ) -> tuple[TickFrames, np.ndarray]:
        """Run r's frames of tick k through its stage, SecOC and nodes: the tick the nodes take,
        and which genuine readings arrived."""
        stage = self.stages[r]
        assert stage is not None
        self._catch_up(r, k, stage)
        frames = runner_frames(
            self.codec, k, self.sensor_specs, measured.tolist(), sent.tolist(), self.command_specs, commands.tolist()
        )
        secoc = self.secoc[r] if self.secoc is not None else None
        if secoc is not None:  # the frames an intruder records are recorded as signed (the others' MACs: unused)
            for frame, decoded in frames:
                if decoded is not None and decoded.spec.name in self.recorded[r]:
                    secoc.sign(frame, k)
        applied = stage.apply(k, frames)
        self.fed[r] = k
        forged = [item for item in applied.frames if id(item) in applied.intruders]
        if forged:
            self._forged.append((r, forged))
        self.contested[r] += contests([frame for frame, _ in forged], self.own, secoc is not None)
        taken = self._verified(r, k, applied.frames[1:], applied.intruders, secoc)
        arrived = np.zeros(len(self.sensor_specs), dtype=bool)
        for item in applied.frames[1:]:
            if id(item) not in applied.intruders and item[0].arbitration_id in self.sensor_ids:
                arrived[self.sensor_ids.index(item[0].arbitration_id)] = True
        sync = applied.frames[0][1]
        assert sync is not None
        return self._assemble(r, k, sync, taken), arrived

    def _verified(
        self, r: int, k: int, frames: list[Frame], intruders: dict[int, str], secoc: SecOC | None
    ) -> list[Decoded]:
        """The frames of run r's tick k that its nodes take, in order: under SecOC the genuine ones
        (accepted as signed) and the intruders' that pass ``verify``; the others' rejections kept."""
        if secoc is None:
            return [decoded for _, decoded in frames if decoded is not None]
        for col, frame_id in enumerate(self.sensor_ids):  # what it accepted in the ticks between
            if self.last_sent[r, col] >= 0:
                secoc.accept(frame_id, int(self.last_sent[r, col]))
        taken = []
        for item in frames:
            frame, decoded = item
            if id(item) not in intruders:
                if frame.arbitration_id in secoc.trailers:
                    secoc.accept(frame.arbitration_id, k)
            elif (rejection := secoc.verify(frame, k)) is not None:
                name = decoded.spec.name if decoded is not None else None
                self.rejections[r].append(
                    SecurityRejection(
                        tick=k,
                        t=k * self.dt_ns / 1e9,
                        id=rejection.frame_id,
                        message=name,
                        sender=rejection.sender,
                        reason=rejection.reason,
                        freshness=rejection.freshness,
                        data=bytes(frame.data).hex(),
                    )
                )
                continue
            if decoded is not None:
                taken.append(decoded)
        return taken

    def _assemble(self, r: int, k: int, sync: Decoded, taken: list[Decoded]) -> TickFrames:
        """Run r's tick k as its nodes assemble it (each node alike: the same frames)."""
        assembler = self.assemblers[r]
        lost = assembler.lost
        done = assembler.push(sync)
        for decoded in taken:
            if decoded.spec.role in (SENSOR, COMMAND):
                done += assembler.push(decoded)
        self.missed[r] += assembler.lost - lost
        found = [tick for tick in done if tick.tick == k]
        if not found:  # alone, its nodes would wait for frames that never come
            raise CosimError(f"its nodes would not complete tick {k} (frames announced by SYNC missing)")
        return found[0]

    def _catch_up(self, r: int, k: int, stage: BusFaultStage) -> None:
        """Feed run r's stage the frames its recording intruders heard since it last acted: the
        recorded messages' frames of those ticks (no fault was active in them, so hearing is all
        the stage did then). Only the frames a record can still hold are needed: from (lag + 1) s
        before the last one sent (``faults.models.Replay`` forgets older ones), with a tick to spare."""
        recorded = self.recorded[r]
        if not recorded or self.fed[r] >= k - 1:
            return
        assert self.history is not None  # kept since a run's intruder records
        columns = [i for i, spec in enumerate(self.sensor_specs) if spec.name in recorded]
        lag = max((getattr(m, "lag", 0.0) for m in self.models[r]), default=0.0)
        last = int(self.last_sent[r, columns].max()) if columns else -1
        first = max(int(self.fed[r]) + 1, last - math.ceil((lag + 1.0) * 1e9 / self.dt_ns) - 2, 0)
        specs = [self.sensor_specs[i] for i in columns]
        secoc = self.secoc[r] if self.secoc is not None else None
        for j in range(first, k):
            measured, sent = self.history[j]
            frames = runner_frames(
                self.codec, j, specs, measured[r, columns].tolist(), sent[r, columns].tolist(), [], []
            )
            if secoc is not None:
                for frame, _ in frames[1:]:
                    secoc.sign(frame, j)
            stage.apply(j, frames)


def _stage(plan: RunPlan, models: list[fm.BusFault]) -> BusFaultStage:
    """Run ``plan``'s bus fault stage, as its session builds it (``RunPlan.session``)."""
    s = plan.scenario
    return BusFaultStage(plan.codec, models, s.seed, s.dt_ns, s.bus.bitrate, False, authenticated=plan.authenticated)
