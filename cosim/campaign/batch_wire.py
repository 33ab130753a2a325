"""The arbitrated in-process bus of a batch (``[bus] timing = "arbitrated"``): each run's own wire,
bus faults, nodes' protocol and intrusion detector, fed tick by tick with exactly the frames the run
puts on its bus alone.

Alone, an arbitrated in-process run (``cosim.run.session.Session._send_arbitrated``) sends, at each
tick k, the runner's frames through its ``BusFaultStage`` onto its ``Arbitration``, whose wire also
carries the nodes' answers to tick k − 1 (as its ``Traffic`` heard them, in canonical order) and the
periodic traffic (``[[bus.traffic]]``, babbling nodes); the frames the wire lets through in their
tick go on the in-process channel with SYNC(k) announcing them, the late ones after, and each node
takes what it needs (``Client.feed``: its ``TickAssembler``, SYNC's and upstream heartbeats' MACs).
What the wire delivers is logged at its delivery time: the intrusion detector checks it there, and
the scores read the estimators' frames from there.

A batch keeps, per run, those very objects (``cosim.campaign.run_wire.RunWire``, built as
``RunPlan.session`` builds them) and drives them as the session does: the runner's frames
(``runner_frames``) through the stage, ``Arbitration.tick``, the control frames signed
(``sign_control``), the frames on an in-process channel of the run's own. Each node is its
``Client`` on that channel (``node_client``, its keys and upstream from its ``NodeSpec``): it takes
its tick as alone (which readings, which commands, late frames and second copies, what its heartbeat
counts as missed), then publishes what the batch computed for it on arrays (``Client.publish``,
``done``: its frames, saturated or not, and its heartbeat), which the run's ``Traffic`` hears,
counts and hands to the wire at the next tick. The wire's deliveries go to the run's
``IntrusionDetector`` and, for the estimators' frames, to its ``Scorer`` (``Scorer.estimate``,
``verdict``, ``state``, ``faults``), in the order its log would hold them: a frame the wire replaced
never reaches the scores, as alone; or the tick is scored whole (``RunWire._whole``, ``TickBatch``).

Not built, as a batched run builds no log: the frames' and passages' records, the bus load, the
foreign frames' records. A run whose nodes would not complete a tick, or whose runner would reject
a node's frame, leaves the batch (and runs alone).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import can
import numpy as np

from cosim.analysis.metrics.scorer import BusVerdicts, TickBatch
from cosim.bus.client import TickFrames
from cosim.bus.codec import CONTROLLER, Codec, Decoded, MessageSpec, ranges
from cosim.campaign.run_wire import Frame, RunWire
from cosim.campaign.steady_wire import SteadyWires
from cosim.errors import CodecError, CosimError
from cosim.log.metadata import SenderCounts
from cosim.log.recorder import IDS_CHECKS
from cosim.run.arbitration import quiet_ticks
from cosim.run.busfaults import Applied
from cosim.run.loop import runner_frames
from cosim.run.plan import RunPlan


def refusal(plan: RunPlan) -> str | None:
    """Why a batch cannot give the arbitrated bus of ``plan``'s runs (None: it can)."""
    if plan.authenticated:
        return "its frames are authenticated (SecOC) on an arbitrated wire"
    return None


def _encoded_runs(
    codec: Codec, k: int, rows: np.ndarray, names: list[str], values: np.ndarray, sent: np.ndarray | None = None
) -> dict[int, list[tuple[can.Message, Decoded]]]:
    """The frames of messages ``names`` for tick k of the runs ``rows`` (by run), encoded on arrays
    (``Codec.encode_rows``): ``values`` (R, every message's signals in turn), ``sent`` (R,
    messages) which each run sends (None: all). A run with a value its frame cannot carry (NaN, out
    of range) is left out, and all of them where a message is not packed on arrays: their own path
    encodes them and names what it refuses."""
    found = codec.encode_rows(names, k, values, sent)
    if found is None:
        return {}
    return {r: frames for r, frames in zip(rows.tolist(), found) if frames is not None}


def _undelayed(applied: Applied | None) -> bool:
    """Whether the bus faults of a tick delayed no frame (its wire may be quiet)."""
    return applied is None or not applied.delays_ns


class WireBatch:
    """The arbitrated buses of K runs of one design (``cosim.campaign.batch._Batch``), tick by tick:
    ``send`` the runner's frames, ``inputs`` what a node takes of its tick, ``answer`` its frames,
    ``truth`` the tick's truth for the scores, ``finish`` the end."""

    def __init__(
        self,
        plans: Sequence[RunPlan],
        scores: TickBatch,
        sensor_specs: Sequence[MessageSpec],
        command_specs: Sequence[MessageSpec],
        leave: Callable[[int, int, str], None],
    ) -> None:
        plan = plans[0]
        self.codec, self.scenario, self.plan = plan.codec, plan.scenario, plan
        self.sensor_specs, self.command_specs, self.leave = list(sensor_specs), list(command_specs), leave
        self.closed = plan.controller is not None
        self.scores = scores
        self.runs = [RunWire(each, scorer) for each, scorer in zip(plans, scores.scorers)]
        self.runner = [*self.sensor_specs, *([] if self.closed else self.command_specs)]  # its data messages
        stages = [[CONTROLLER]] if self.closed else []
        self.steady = SteadyWires(self.runs, self.runner, self.scenario.ticks, [*stages, list(plan.estimators)])
        self._ticks: list[TickFrames | None] = [None] * len(plans)  # each steady run's node's tick (``inputs``)
        # the last tick's truth: (tick, states (K, states), each run's active faults, the estimators'
        # values, the states' names)
        self._truth: tuple[int, np.ndarray, Sequence[tuple[str, ...]], Sequence[np.ndarray], Sequence[str]] | None = (
            None
        )
        # each node's messages, its signals' columns and ranges (``_layout``), by node and signals
        self._layouts: dict[
            tuple[str, tuple[str, ...]], tuple[list[str], list[int], np.ndarray, np.ndarray] | None
        ] = {}

    def active(self, t: float) -> list[tuple[str, ...]]:
        """Each run's bus faults active at t, by label (what its ``/truth/faults`` adds): none in a
        steady tick."""
        on = self.steady.on.tolist()
        return [
            tuple(run.stage.active(t)) if run.stage is not None and not on[r] else () for r, run in enumerate(self.runs)
        ]

    def send(self, k: int, measured: np.ndarray, sent: np.ndarray, commands: np.ndarray, alive: np.ndarray) -> None:
        """Tick k's frames of each run alive: its ``measured`` readings that are ``sent``, and in an
        open loop its ``commands`` (the input signals, as given). A run whose frames its bus cannot
        carry (a forged value outside its range) leaves the batch."""
        codec, sensors, actuators = self.codec, self.sensor_specs, [] if self.closed else self.command_specs
        values, on = measured, sent
        if not self.closed:
            values = np.concatenate([measured, commands], axis=1)
            on = np.concatenate([sent, np.ones((len(sent), len(self.command_specs)), dtype=bool)], axis=1)
        held = None if self._truth is None else (self._truth[1], self._truth[4], self._truth[2])
        steady = self.steady.send(k, values, on, alive, held)
        self._ticks = self.steady.tick_of(k, on)  # what each steady run's node takes of the tick
        prepared: list[tuple[list[Frame], Applied | None] | None] = [None] * len(self.runs)
        rows = np.flatnonzero(alive & ~steady)
        built = self._runner_frames(k, values, on, rows) if len(rows) else {}
        for r in rows.tolist():
            try:
                given = [] if self.closed else commands[r].tolist()
                frames = built.get(r) or runner_frames(
                    codec, k, sensors, measured[r].tolist(), sent[r].tolist(), actuators, given
                )
                prepared[r] = self.runs[r].prepare(k, frames)
            except (CodecError, CosimError) as error:
                self._leave(r, k, str(error), alive)
        plain = [item[0] if item is not None and _undelayed(item[1]) else None for item in prepared]
        senders = [item[1].intruders if item is not None and item[1] is not None else {} for item in prepared]
        quiet = quiet_ticks([run.arbitration for run in self.runs], k, plain, senders)
        whole: list[tuple[int, dict[str, int]]] = []
        for r, item in enumerate(prepared):
            if item is None:
                continue
            run = self.runs[r]
            try:
                verdict = run.send(k, *item, quiet[r])
            except (CodecError, CosimError) as error:
                self._leave(r, k, str(error), alive)
                continue
            self.steady.begun(r, k, run.carried_whole and not run.rejected)
            if run.rejected:
                self._leave(r, k, run.rejected, alive)
            elif verdict is not None:
                whole.append((r, verdict))
            else:
                self.scores.forget(r)  # its scorer took the tick's parts
        scored = steady & alive  # a copy: ``steady`` is the runs' steady mask
        if scored.any():
            assert self._truth is not None
            for r in self.steady.score(k, np.flatnonzero(scored), (self._truth[1], self._truth[4], self._truth[2])):
                scored[r] = False
                self.scores.forget(r)  # its scorer took the tick's parts
        if whole or scored.any():
            self._scored_whole(k - 1, whole, np.flatnonzero(scored))

    def _scored_whole(self, k: int, verdicts: list[tuple[int, dict[str, int]]], steady: np.ndarray) -> None:
        """Tick k of the runs scored whole (``RunWire._whole``) and of the ``steady`` ones (whose
        detector raised nothing), from the batch's arrays: their truth, their estimators' values as
        their frames carried them, the detector's ``verdicts`` on the tick (each check's count, by
        run), as ``Scorer.verdict`` takes them."""
        assert self._truth is not None and self._truth[0] == k
        _, x, active, values, _ = self._truth
        rows = np.union1d(np.array([r for r, _ in verdicts], dtype=np.int64), steady)
        bus = None
        if self.runs[int(rows[0])].detector is not None:
            ids = np.zeros((len(self.runs), 1 + len(IDS_CHECKS)))
            for r, checks in verdicts:
                counts = [checks[check] for check in IDS_CHECKS]
                ids[r] = [float(any(counts)), *(float(count > 0) for count in counts)]
            bus = BusVerdicts(ids, [()] * len(self.runs))
        self.scores.tick(k, rows, x, active, values, bus)

    def _runner_frames(self, k: int, values: np.ndarray, on: np.ndarray, rows: np.ndarray) -> dict[int, list[Frame]]:
        """``runner_frames`` of the runs ``rows`` whose values their frames carry (``values``, (K,
        the runner's messages' signals), ``on`` which it sends), their data frames encoded on arrays
        (``Codec.encode_rows``), by run; the others are left out (``runner_frames`` refuses them,
        naming the value)."""
        codec = self.codec
        out: dict[int, list[Frame]] = {}
        # Their SYNC is one per count, shared: the wire announces a SYNC of its own, which is the one
        # signed and sent (``quiet_ticks``, ``Arbitration.tick``, the bus faults' ``apply``)
        syncs: dict[int, Frame] = {}
        for r, data in _encoded_runs(
            codec, k, rows, [spec.name for spec in self.runner], values[rows], on[rows]
        ).items():
            sync = syncs.get(len(data))
            if sync is None:
                try:
                    message = codec.sync(k, len(data))
                except CodecError:  # more frames than a SYNC announces: ``runner_frames`` says so, for that run
                    continue
                sync = syncs[len(data)] = (message, codec.decode(message))
            out[r] = [sync, *data]
        return out

    def inputs(
        self, k: int, name: str, alive: np.ndarray, carried: tuple[np.ndarray, np.ndarray]
    ) -> tuple[list[TickFrames | None], np.ndarray, np.ndarray]:
        """Node ``name``'s tick k in each run alive (None in the others), with its readings (K,
        sensors; NaN: missing) and the commands it took (K, actuators; NaN: none came). ``carried``:
        the readings and commands its frames carry in a run where nothing but the runner and the
        nodes before it touched them (the runner's sensor values that are sent; its input signals,
        or the commands of its upstream controller node; NaN where no frame is due), which it takes
        as they are in a run where its tick is that (``RunWire.intake``). A run whose node would not
        complete tick k (alone, the runner would wait for it in vain) leaves."""
        s = self.scenario
        steady = self.steady.on & alive
        ticks = list(self._ticks)
        readings = np.where(steady[:, None], carried[0], np.nan)
        commands = np.where(steady[:, None], carried[1], np.nan)
        for r in np.flatnonzero(alive & ~steady).tolist():
            run = self.runs[r]
            whole = run.intake(name, k)
            if whole is not None:
                ticks[r] = whole
                readings[r], commands[r] = carried[0][r], carried[1][r]
                continue
            self.steady.missed(r)
            done = run.take(name)
            if [tick.tick for tick in done] != [k]:
                why = f"its node {name} would not complete tick {k} (frames announced by SYNC missing)"
                self._leave(r, k, why, alive)
                continue
            tick = ticks[r] = done[0]
            readings[r] = [tick.sensors.get(sensor, np.nan) for sensor in s.sensors]
            commands[r] = [tick.commands.get(actuator, np.nan) for actuator in s.actuators]
        return ticks, readings, commands

    def answer(
        self,
        name: str,
        ticks: Sequence[TickFrames | None],
        signals: Sequence[str],
        values: np.ndarray,
        alive: np.ndarray,
        saturate: bool,
    ) -> None:
        """Node ``name``'s frames of the ticks it completed, ``values`` (K, signals) by ``signals``
        as it computed them (before saturation and quantization: its client does both, or the
        batch on arrays, each run's frames as its client encodes them: ``_encoded``)."""
        rows = np.flatnonzero(alive & ~self.steady.on)
        self._steady_answers(name, signals, values, alive, saturate)
        encoded = self._encoded(name, ticks, signals, values, rows, saturate) if len(rows) else {}
        for r in rows.tolist():
            tick = ticks[r]
            assert tick is not None  # a run whose node completed no tick has left
            try:
                if r in encoded:
                    self.runs[r].publish_encoded(name, tick, encoded[r])
                else:
                    self.steady.missed(r)
                    self.runs[r].publish(name, tick, dict(zip(signals, values[r].tolist())), saturate)
            except (CodecError, CosimError) as error:
                self._leave(r, tick.tick, str(error), alive)

    def _steady_answers(
        self, name: str, signals: Sequence[str], values: np.ndarray, alive: np.ndarray, saturate: bool
    ) -> None:
        """``answer`` in the steady runs: their frames' bytes and values on arrays (``SteadyWires``).
        A run with a value its frame cannot carry leaves (alone, its client names it)."""
        rows = np.flatnonzero(alive & self.steady.on)
        if not len(rows):
            return
        k = self.steady.tick
        names, v = self._saturated(name, signals, values, rows, saturate)
        for r in rows[self.steady.answer(name, k, rows, names, v)].tolist():
            self._leave(r, k, f"its node {name} sends a value its frame cannot carry", alive)

    def _encoded(
        self,
        name: str,
        ticks: Sequence[TickFrames | None],
        signals: Sequence[str],
        values: np.ndarray,
        rows: np.ndarray,
        saturate: bool,
    ) -> dict[int, list[tuple[can.Message, Decoded]]]:
        """Node ``name``'s frames of tick k in the runs ``rows``, encoded on arrays (``Codec.encode_rows``),
        by run: its messages in order, each value saturated (``saturated``'s bound where it crossed
        one) and in range. A run with a value its frame cannot carry (NaN, or out of range unsaturated),
        or a node whose messages are not packed on arrays, is left out: its client encodes (and refuses) it."""
        k = next(tick.tick for r in rows.tolist() if (tick := ticks[r]) is not None)
        if any(getattr(ticks[r], "tick", None) != k for r in rows.tolist()):
            return {}
        layout = self._layouts.get((name, tuple(signals)))
        if layout is None:
            layout = self._layouts[(name, tuple(signals))] = self._layout(name, signals)
        if not layout:
            return {}  # its client names what is missing, run by run
        return _encoded_runs(self.codec, k, rows, *self._saturated(name, signals, values, rows, saturate))

    def _saturated(
        self, name: str, signals: Sequence[str], values: np.ndarray, rows: np.ndarray, saturate: bool
    ) -> tuple[list[str], np.ndarray]:
        """Node ``name``'s messages and the values of their signals in ``rows``, each saturated
        (``saturated``'s bound where it crossed one) where it saturates (its layout is known)."""
        layout = self._layouts[(name, tuple(signals))]
        assert layout is not None  # a node whose frames its client encodes never goes steady
        names, columns, low, high = layout
        v = values[rows][:, columns]
        if saturate:
            v = np.where(np.isnan(v), v, np.minimum(np.maximum(v, low), high))
        return names, v

    def _layout(self, name: str, signals: Sequence[str]) -> tuple[list[str], list[int], np.ndarray, np.ndarray] | None:
        """Node ``name``'s messages, the columns of their signals among ``signals`` and those
        signals' ranges (None: a signal of its messages is not among them)."""
        messages = self.runs[0].nodes[name].messages
        if any(signal not in signals for spec in messages for signal in spec.signals):
            return None
        return (
            [spec.name for spec in messages],
            [signals.index(signal) for spec in messages for signal in spec.signals],
            *ranges(messages),
        )

    def truth(
        self,
        k: int,
        x: np.ndarray,
        states: Sequence[str],
        active: Sequence[tuple[str, ...]],
        rows: Any,
        values: Sequence[np.ndarray],
    ) -> None:
        """Tick k's truth of the runs ``rows``: their states (K, states) and active faults, with
        their estimators' values (each (K, signals), as their frames carry them), for the scores."""
        x = x.copy()
        self._truth = (k, x, active, values, states)
        on = self.steady.on
        for r in rows:
            if not on[r]:  # a steady run's truth is the batch's
                self.runs[r].truth(k, x, r, states, active[r])

    def finish(self, r: int, ticks: int) -> tuple[int, dict[str, SenderCounts]]:
        """Run r's end after ``ticks`` ticks: its contested ticks and what each node sent and missed."""
        if self.steady.on[r]:
            assert self._truth is not None
            self.steady.materialize(r, ticks, (self._truth[1], self._truth[4], self._truth[2][r]))
        return self.runs[r].finish(ticks, self.plan.senders)

    def close(self) -> None:
        """Every run's channel closed."""
        for run in self.runs:
            run.close()

    def _leave(self, r: int, k: int, why: str, alive: np.ndarray) -> None:
        self.leave(r, k, why)
        alive[r] = False
