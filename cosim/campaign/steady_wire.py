"""Steady ticks of a batch's arbitrated buses, on arrays (``cosim.campaign.batch_wire``).

A run's tick k is steady when nothing but the co-simulation's protocol is on its wire: no bus fault
can act (none of its windows meets the tick, no error counter is up; an intruder that records the
bus hears the tick's frames, ``_observed``), no background frame is due, the wire is quiet
(``cosim.run.arbitration.quiet_ticks``) with the nodes' answers to tick k − 1 on it, every frame's
values are within their ranges and every data frame's tick counter is the one after its id's last.
Then what the run's objects would do with the tick is known, and none of it depends on anything
but arrays the batch holds:

- the wire sends the answers to tick k − 1 from when they were queued, then SYNC(k) and the
  runner's frames by id, each from the end of the one before (``quiet_schedule``, with each frame's
  stuff bits from its payload, a control frame's MAC at 0, as the wire times it); what is left of it
  is when it falls idle, how many frames it was offered and when the receivers had their inputs;
- the runner hears each node's answer once, on time, nothing lost (``Traffic.answered``), each
  node takes its tick whole (``RunWire.intake``), the intrusion detector raises nothing and notes
  each id's last frame (``IntrusionDetector.frame``), and the tick is scored whole (``TickBatch``),
  or, where the scorer still holds an earlier tick, given to it in its parts (``score``).

So a steady run's objects (``RunWire``: its wire, traffic, clients, channels, detector) are left as
they were, and the batch keeps on arrays what the ticks change: the wire's idle time, offers and
inputs time, the answers of the last tick (their bytes, the values they were encoded from and
those they carry), the detector's last frame per id. A run enters after a tick its objects took whole, with their
state what this module reads (``_enters``); where a tick is not steady, its objects are brought to
what they would be after tick k − 1 (``materialize``: the counts, times and frames the steady ticks
would have left, the last answers published again on its channel) and they take the tick, as they
would have. Nothing is guessed: a run whose objects are not in a state this module can read stays
with its objects; one whose frames cannot be built from the arrays leaves the batch (and runs alone).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from cosim.bus.client import TickFrames
from cosim.bus.codec import OPERATIONAL, Decoded, MessageSpec, ranges
from cosim.bus.dbc import heartbeat_message
from cosim.bus.inprocess import InProcessBus
from cosim.campaign.run_wire import RunWire, score_estimate
from cosim.errors import CodecError
from cosim.log.recorder import IDS_CHECKS
from cosim.run.arbitration import bits_of_payloads, quiet_schedule
from cosim.run.busfaults import BusFaultStage
from cosim.run.detector import out_of_range
from faults.models import BusFault

Head = tuple[int, bool, bool, bool, int]  # a frame's id, extended, FD, BRS flags and length


class SteadyWires:
    """The steady ticks of the arbitrated buses of K runs of one design (``WireBatch``)."""

    def __init__(
        self, runs: Sequence[RunWire], runner: Sequence[MessageSpec], ticks: int, stages: Sequence[Sequence[str]]
    ) -> None:
        """``runner``: its data messages, in the order of its frames; ``stages``: the nodes in the
        order the batch steps them, in stages: each node of a stage takes its tick, then each answers
        (``cosim.campaign.batch._Batch._tick_wire``: the controller, then the estimators)."""
        first = runs[0]
        self.runs, self.codec, self.dt_ns, self.ticks = list(runs), first.codec, first.dt_ns, ticks
        self.runner, self.stages = list(runner), [list(stage) for stage in stages]
        self.runner_ranges = ranges(self.runner)
        n = len(runs)
        self.on = np.zeros(n, dtype=bool)  # steady: its objects stand still, its wire is these arrays
        self.tick = -1  # the tick under way
        self.entered = np.zeros(n, dtype=np.int64)  # the tick at which it went steady
        self.idle, self.offers, self.inputs = (np.zeros(n, dtype=np.int64) for _ in range(3))
        self.until = np.zeros(n, dtype=np.int64)  # the first tick a bus fault or background frame may meet
        self.leaving = np.zeros(n, dtype=bool)  # an answer out of its range: its next tick is its objects'
        self.observers: dict[int, list[BusFault]] = {}  # run -> its bus faults that record the bus (if any)
        self.plain = np.full(n, -1, dtype=np.int64)  # the tick its objects are taking whole so far (−1: none)
        self.nodes = [name for stage in self.stages for name in stage]  # in the order they answer
        self.messages: dict[str, list[MessageSpec]] = {}
        self.ranges: dict[str, tuple[np.ndarray, np.ndarray]] = {}  # node -> its messages' signals' ranges
        self.values: dict[str, np.ndarray] = {}  # node -> the values its last answers were encoded from
        self.payloads: dict[str, np.ndarray] = {}  # node -> its last answers' bytes (K, messages, 8)
        self.carried: dict[str, np.ndarray] = {}  # node -> the values they carry
        self.delivered = np.zeros((n, 0), dtype=np.int64)  # when the answers to the last tick arrived (ns)
        self.lost = np.zeros((n, 0), dtype=np.int64)  # each node's count of missed runner frames
        self.columns: list[tuple[int, int]] = []  # the answers on the wire by id: (node, message; −1 its heartbeat)
        self.ids: list[int] = []  # the data ids the detector follows, the answers' then the runner's
        self.last_ns = self.last_counter = np.zeros((n, 0), dtype=np.int64)
        self.known = np.zeros((n, 0), dtype=bool)

    # -- a tick --------------------------------------------------------------------------------

    def send(self, k: int, values: np.ndarray, sent: np.ndarray, alive: np.ndarray, truth: tuple | None) -> np.ndarray:
        """Tick k of the runs alive that are steady (or may enter), the runner's frames of
        ``self.runner`` carrying ``values`` (K, their signals) where ``sent`` (K, messages): their
        wires on arrays; the others are their objects' (a steady run whose tick is not steady
        brought back to them first, with ``truth``, tick k − 1's (states, their names, each run's
        active faults)). The runs steady in tick k, (K,) bool."""
        self.on &= alive
        self.tick = k
        entering = self._entering(k, alive)
        rows = np.flatnonzero(self.on | entering)
        steady = np.zeros(len(self.runs), dtype=bool)
        if len(rows):
            stays = self._tick(k, rows, values[rows], sent[rows])
            steady[rows[stays]] = True
        for r in np.flatnonzero(self.on & ~steady).tolist():
            self.materialize(r, k, None if truth is None else (truth[0], truth[1], truth[2][r]))
        for r in np.flatnonzero(entering & steady).tolist():
            self.entered[r] = k
            self.runs[r].held = None  # its tick k − 1 is scored from the arrays (``score``, ``TickBatch``)
        self.on = steady
        return steady

    def _tick(self, k: int, rows: np.ndarray, values: np.ndarray, sent: np.ndarray) -> np.ndarray:
        """Which of ``rows`` have a steady tick k (the runner's ``values`` and which are ``sent``,
        by row); their arrays moved on to its end."""
        codec, modulus = self.codec, self.codec.tick_modulus
        found = codec.rows_payloads([spec.name for spec in self.runner], k, values, sent)
        if found is None:
            return np.zeros(len(rows), dtype=bool)
        payloads, carried, fits = found
        stays = fits & (self.until[rows] > k) & ~self.leaving[rows]
        low, high = self.runner_ranges
        signals = np.repeat(sent, [len(spec.signals) for spec in self.runner], axis=1)
        stays &= (~signals | ((low <= carried) & (carried <= high))).all(axis=1)
        staying = np.flatnonzero(stays)
        if len(staying) and (sent[staying] == sent[staying[0]]).all():  # the runner sends alike: one layout
            groups = [staying]
        else:
            patterns: dict[bytes, list[int]] = {}
            for i in staying.tolist():
                patterns.setdefault(sent[i].tobytes(), []).append(i)
            groups = [np.array(members) for members in patterns.values()]
        for group in groups:
            stays[group] = self._schedule(k, rows[group], payloads[group], sent[group[0]], modulus)
        for i, r in enumerate(rows.tolist() if self.observers else []):
            if r in self.observers and stays[i]:
                self._observed(k, self.observers[r], carried[i], sent[i])
        return stays

    def _observed(self, k: int, observers: list[BusFault], carried: np.ndarray, sent: np.ndarray) -> None:
        """The runner's frames of tick k (their values ``carried``, where ``sent``) to the bus faults
        that record what goes out (``BusFault.observe``, a replaying intruder's), as
        ``BusFaultStage.apply`` gives each genuine frame that goes out: frame by frame, each to all."""
        t, values, at = k * self.dt_ns / 1e9, carried.tolist(), 0
        for spec, on in zip(self.runner, sent.tolist()):
            if on:
                heard = tuple(values[at : at + len(spec.signals)])
                for model in observers:
                    model.observe(spec.name, heard, t)
            at += len(spec.signals)

    def _schedule(self, k: int, rows: np.ndarray, payloads: np.ndarray, sent: np.ndarray, modulus: int) -> np.ndarray:
        """Tick k's wire of ``rows``, whose runner sends the messages ``sent`` with these bytes: which
        are quiet, with every data frame the next of its id (those move on)."""
        codec, t_ns = self.codec, k * self.dt_ns
        on = [j for j, s in enumerate(sent.tolist()) if s]
        try:
            sync = codec.sync(k, len(on))
        except CodecError:  # more frames than a SYNC announces: the objects say so
            return np.zeros(len(rows), dtype=bool)
        heads: list[Head] = []
        columns: list[np.ndarray] = []
        for node, j in self.columns:  # the answers to tick k − 1, by id
            name = self.nodes[node]
            if j < 0:
                count, lost = len(self.messages[name]), self.lost[rows, node].tolist()
                beats = {n: bytes(codec.heartbeat(name, OPERATIONAL, k - 1, count, n).data) for n in set(lost)}
                heads.append(codec.head(heartbeat_message(name)))
                columns.append(np.frombuffer(b"".join(beats[n] for n in lost), dtype=np.uint8).reshape(len(rows), -1))
            else:
                heads.append(codec.head(self.messages[name][j].name))
                columns.append(self.payloads[name][rows, j, : heads[-1][4]])
        answers = len(heads)
        heads.append(codec.head("SYNC"))
        columns.append(np.frombuffer(bytes(sync.data) * len(rows), dtype=np.uint8).reshape(len(rows), -1))
        for j in on:
            heads.append(codec.head(self.runner[j].name))
            columns.append(payloads[:, j, : heads[-1][4]])
        order = answers + np.argsort([head[0] for head in heads[answers:]], kind="stable")
        wire = self.runs[rows[0]].arbitration.wire
        ok, delivered, ends = quiet_schedule(
            wire,
            t_ns,
            self.dt_ns,
            bits_of_payloads(codec, heads, columns),
            self.idle[rows],
            self.inputs[rows],
            answers,
            order,
        )
        # the detector's data ids, with each frame's delivery and counter
        at = {heads[c][0]: c for c in range(answers)} | {heads[j][0]: i for i, j in enumerate(order.tolist(), answers)}
        followed = [(self.ids.index(frame_id), at[frame_id]) for frame_id in self.ids if frame_id in at]
        ids, places = [c for c, _ in followed], [p for _, p in followed]
        counters = np.array([(k - 1 if p < answers else k) % modulus for p in places])
        before = self.last_counter[rows][:, ids]
        ok &= (~self.known[rows][:, ids] | ((counters - before) % modulus == 1)).all(axis=1)
        moved = rows[ok]
        self.idle[moved], self.inputs[moved] = ends[ok], delivered[ok, -1]
        self.delivered[moved] = delivered[ok][:, :answers]
        self.offers[moved] += len(heads)
        self.last_ns[np.ix_(moved, ids)] = delivered[ok][:, places]
        self.last_counter[np.ix_(moved, ids)] = counters
        self.known[np.ix_(moved, ids)] = True
        return ok

    def tick_of(self, k: int, sent: np.ndarray) -> list[TickFrames | None]:
        """What each steady run's node takes of tick k (its count of the runner's frames): the tick
        whole (``RunWire.intake``); None for the others."""
        out: list[TickFrames | None] = [None] * len(self.runs)
        shared: dict[int, TickFrames] = {}
        for r in np.flatnonzero(self.on).tolist():
            count = int(sent[r].sum())
            out[r] = shared.get(count) or shared.setdefault(count, TickFrames(k, count))
        return out

    def answer(self, name: str, k: int, rows: np.ndarray, names: list[str], values: np.ndarray) -> np.ndarray:
        """Node ``name``'s answers to tick k in the steady ``rows``, its messages ``names`` carrying
        ``values`` (saturated where it saturates): kept for the wire's next tick. Which rows' frames
        could not be built (a value its frame cannot carry: alone, its client names it)."""
        found = self.codec.rows_payloads(names, k, values)
        if found is None:
            return np.ones(len(rows), dtype=bool)
        payloads, carried, fits = found
        low, high = self.ranges[name]
        self.leaving[rows] |= ~((low <= carried) & (carried <= high)).all(axis=1)  # the detector's range check
        self.values[name][rows], self.payloads[name][rows], self.carried[name][rows] = values, payloads, carried
        return ~fits

    def score(
        self, k: int, rows: np.ndarray, truth: tuple[np.ndarray, Sequence[str], Sequence[tuple[str, ...]]]
    ) -> list[int]:
        """Tick k − 1 of the steady ``rows`` to their scorers where they hold another tick (a tick
        whose estimates a flood starved, until it is ``WINDOW`` ticks old) or expect none: in the
        parts its log would hold, in its order (``RunWire.send``: the truth, then each frame the
        wire delivered, an estimator's to the scores, then the detector's verdict, which is clear),
        from the arrays. The rows whose scorer took the tick so, the others are scored whole
        (``RunWire._whole``'s test of the scorer, the rest of it holding in a steady tick)."""
        x, states, active = truth
        scorers, parts = [self.runs[r].scorer for r in rows.tolist()], []
        for r, scorer in zip(rows.tolist(), scorers):
            if scorer.pending or scorer.next_tick != k - 1 or scorer.expected_parts <= 0:
                parts.append(r)
        if not parts:
            return parts
        modulus, verdict = self.codec.tick_modulus, {check: 0 for check in IDS_CHECKS}
        scored = [(c, self.messages[self.nodes[i]][j]) for c, (i, j) in enumerate(self.columns) if j >= 0]
        for r in parts:
            run = self.runs[r]
            run.scorer.state(k - 1, dict(zip(states, x[r].tolist())))
            run.scorer.faults(k - 1, list(active[r]))
            for c, spec in scored:
                name = self.nodes[self.columns[c][0]]
                at = self._signals[name][spec.name]
                row = self.carried[name][r, at : at + len(spec.signals)].tolist()
                decoded = Decoded(spec, (k - 1) % modulus, dict(zip(spec.signals, row)))
                score_estimate(run.scorer, int(self.delivered[r, c]) // self.dt_ns, decoded)
            if run.detector is not None:
                run.scorer.verdict(k - 1, False, verdict)
        return parts

    def begun(self, r: int, k: int, whole: bool) -> None:
        """Run r's objects began tick k: tick k − 1's answers carried whole (``RunWire._carried_whole``), or not."""
        self.plain[r] = k if whole else -1

    def missed(self, r: int) -> None:
        """Run r's objects took a part of their tick otherwise than whole: a node took its frames one
        by one, or its client encoded its answer (a run enters after a tick taken whole, all of it)."""
        self.plain[r] = -1

    # -- entering -------------------------------------------------------------------------------

    def _entering(self, k: int, alive: np.ndarray) -> np.ndarray:
        """The runs whose objects took tick k − 1 whole, all of it, and are in a state steady ticks
        go on from: their arrays set from it."""
        out = np.zeros(len(self.runs), dtype=bool)
        for r in np.flatnonzero(alive & ~self.on & (self.plain == k - 1)).tolist():
            if self._enters(r, k):
                out[r] = True
        return out

    def _enters(self, r: int, k: int) -> bool:
        """Whether run r's objects, after tick k − 1, are what steady ticks from k go on from, and
        if so its arrays set from them: the wire's state, the answers to tick k − 1 on the runner's
        channel, the detector's last frame per id, when a bus fault or background frame may come."""
        run = self.runs[r]
        if not self.columns:
            self._layout(run)
        if not self._between_ticks(run, k) or not all(self._answered(run, name, k) for name in self.nodes):
            return False
        closings = [frame for name in self.nodes for frame in run.nodes[name].closing]
        if [id(frame) for frame in _channel(run.bus).waiting()] != [id(frame) for frame in closings]:
            return False
        until = _quiet_until(run, k, self.ticks)
        if until <= k:
            return False
        self.until[r] = until
        models = run.stage.models if run.stage is not None else []
        self.observers.pop(r, None)
        if recording := [model for model in models if type(model).observe is not BusFault.observe]:
            self.observers[r] = recording
        arbitration, detector = run.arbitration, run.detector
        self.idle[r], self.offers[r], self.inputs[r] = (
            arbitration.wire.idle_ns,
            arbitration.wire._seq,
            arbitration._inputs_ns,
        )
        leaving = False
        for i, name in enumerate(self.nodes):
            client = run.nodes[name]
            self.lost[r, i] = client.assembler.lost
            for j, frame in enumerate(client.closing[:-1]):
                decoded = run._decode(frame)
                if decoded is None:
                    return False
                self.payloads[name][r, j, : len(frame.data)] = np.frombuffer(bytes(frame.data), dtype=np.uint8)
                at = self._signals[name][decoded.spec.name]
                self.carried[name][r, at : at + len(decoded.spec.signals)] = [
                    decoded.values[s] for s in decoded.spec.signals
                ]
                leaving |= out_of_range(decoded.spec, decoded.values)  # the detector's range check, in tick k
        self.leaving[r] = leaving
        last = detector._last if detector is not None else {}
        for c, frame_id in enumerate(self.ids):
            found = last.get(frame_id)
            self.known[r, c] = found is not None
            self.last_ns[r, c], self.last_counter[r, c] = found if found is not None else (0, 0)
        return True

    def _between_ticks(self, run: RunWire, k: int) -> bool:
        """Whether the run's wire, traffic and detector are between ticks k − 1 and k as a tick taken
        whole leaves them: nothing on the wire or pending, the truth of k − 1 held, the detector due
        to give tick k − 1, on in-process channels. (Its scorer takes tick k − 1 as it stands:
        ``score``.)"""
        arbitration, traffic, detector = run.arbitration, run.traffic, run.detector
        return not (
            run.answering != self.nodes
            or run.marker != k - 1
            or run.held is None
            or run.held[0] != k - 1
            or run.rejected
            or arbitration.wire.queue
            or arbitration._answers
            or arbitration._runner
            or arbitration._on_channel
            or traffic.pending
            or traffic._distrusted
            or traffic._counts
            or traffic._echoes
            or traffic.secoc is not None
            or (detector is not None and (detector.given != k - 1 or detector._alarms))
            or not isinstance(run.bus, InProcessBus)
        )

    def _answered(self, run: RunWire, name: str, k: int) -> bool:
        """Whether node ``name`` took tick k − 1 whole and answered it, each of its messages once and
        its heartbeat, which the runner has not heard yet, with its count of missed frames as the
        runner last heard it (so that hearing this one adds none)."""
        client, traffic = run.nodes[name], run.traffic
        heartbeat = self.codec.specs[heartbeat_message(name)].frame_id
        return not (
            client.stopped
            or client.secoc is not None
            or not isinstance(client.bus, InProcessBus)
            or not client.assembler.between(k - 1)
            or any(lag != 0 for lag in client.assembler.upstream.values())
            or client._outbox
            or client._published
            or name in traffic.left
            or traffic.closed.get(name) == k - 1
            or traffic._lost_carried.get(name, 0) != client.assembler.lost % 256
            or [frame.arbitration_id for frame in client.closing]
            != [*(spec.frame_id for spec in self.messages[name]), heartbeat]
        )

    def _layout(self, run: RunWire) -> None:
        """The nodes' messages, the answers on the wire by id, the detector's ids."""
        codec, n, nodes = self.codec, len(self.runs), self.nodes
        self.messages = {name: run.nodes[name].messages for name in nodes}
        self.ranges = {name: ranges(specs) for name, specs in self.messages.items()}
        self._signals = {  # node -> where each of its messages' signals start among its values
            name: dict(zip([spec.name for spec in specs], np.cumsum([0, *(len(s.signals) for s in specs)]).tolist()))
            for name, specs in self.messages.items()
        }
        self.values = {name: np.zeros((n, sum(len(s.signals) for s in self.messages[name]))) for name in nodes}
        self.payloads = {name: np.zeros((n, len(self.messages[name]), 8), dtype=np.uint8) for name in nodes}
        self.carried = {name: np.zeros_like(values) for name, values in self.values.items()}
        self.lost = np.zeros((n, len(nodes)), dtype=np.int64)
        columns = [
            (spec.frame_id, i, j)
            for i, name in enumerate(nodes)
            for j, spec in [*enumerate(self.messages[name]), (-1, codec.specs[heartbeat_message(name)])]
        ]
        self.columns = [(i, j) for _, i, j in sorted(columns)]
        self.delivered = np.zeros((n, len(columns)), dtype=np.int64)
        self.ids = [spec.frame_id for name in nodes for spec in self.messages[name]] + [s.frame_id for s in self.runner]
        self.last_ns, self.last_counter = (np.zeros((n, len(self.ids)), dtype=np.int64) for _ in range(2))
        self.known = np.zeros((n, len(self.ids)), dtype=bool)

    # -- leaving --------------------------------------------------------------------------------

    def materialize(
        self, r: int, k: int, truth: tuple[np.ndarray, Sequence[str], tuple[str, ...]] | None = None
    ) -> None:
        """Run r's objects as its steady ticks up to k − 1 would have left them: the wire's idle
        time, offers and inputs time; the runner's counts of the answers it heard (those of the
        ticks from the one before it went steady to k − 2) and the answers to tick k − 1 on its
        channel, each node's published again as it sent them (its frames re-encoded from the
        values they were encoded from, its heartbeat signed); the nodes at tick k − 1; the
        detector's last frame per id and its verdicts given; the truth of tick k − 1 held."""
        self.on[r] = False
        run, codec = self.runs[r], self.codec
        arbitration, traffic = run.arbitration, run.traffic
        arbitration.wire.idle_ns, arbitration.wire._seq = int(self.idle[r]), int(self.offers[r])
        arbitration._inputs_ns = int(self.inputs[r])
        heard = k - int(self.entered[r])  # the answers to ticks entered − 1 ... k − 2
        for name in self.nodes:
            count = len(self.messages[name])
            traffic.closed[name] = k - 2
            traffic.data[name] += count * heard
            traffic.received[name] += (count + 1) * heard
        traffic.current = k - 1
        traffic.commands.clear()
        if run.stage is not None:
            for spec in self.runner:
                run.stage.tec.setdefault(spec.sender, 0)
        detector = run.detector
        if detector is not None:
            for c in np.flatnonzero(self.known[r]).tolist():
                detector._last[self.ids[c]] = (int(self.last_ns[r, c]), int(self.last_counter[r, c]))
            detector.given = k - 1
        _channel(run.bus).discard()
        run.answering = []
        for stage in self.stages:  # each node takes its tick whole (what came before it is dropped), then answers
            for name in stage:
                run.nodes[name].assembler.last_sync = k - 1
                _channel(run.nodes[name].bus).discard()
            for name in stage:
                names = [spec.name for spec in self.messages[name]]
                found = codec.encode_rows(names, k - 1, self.values[name][r : r + 1])
                assert found is not None and found[0] is not None  # they were built from these values
                run.publish_encoded(name, TickFrames(k - 1, 0), found[0])
        run.marker = run.clean = k - 1
        if truth is not None:
            run.held = (k - 1, truth[0], r, truth[1], truth[2])


def _channel(bus: object) -> InProcessBus:
    assert isinstance(bus, InProcessBus)  # a run enters on in-process channels only (``_enters``)
    return bus


def _quiet_until(run: RunWire, k: int, ticks: int) -> int:
    """The first tick from k on that run's bus faults or background traffic may meet (``ticks``:
    none), as ``BusFaultStage.apply`` and ``Arbitration.tick`` decide it: a bus fault's window meets
    the tick (its forgeries' test; its being active is within it), a background frame is due; k
    itself where its stage holds anything (an error count, a node bus-off, a frame held). A fault
    that records the bus (``BusFault.observe``) hears a steady tick's frames (``_observed``)."""
    at = np.arange(k, ticks, dtype=np.int64) * run.dt_ns
    busy = np.zeros(len(at), dtype=bool)
    stage: BusFaultStage | None = run.stage
    if stage is not None:
        if stage.off_until or stage._held or any(stage.tec.values()):
            return k
        t, dt = at / 1e9, run.dt_ns / 1e9
        for model in stage.models:
            busy |= (model.start < t + dt) & (t < model.end)
    for source in run.arbitration.traffic:
        first = -(-(np.maximum(source.start_ns, at) - source.start_ns) // source.period_ns)
        busy |= source.start_ns + first * source.period_ns < np.minimum(at + run.dt_ns, source.end_ns)
    return k + int(np.argmax(busy)) if busy.any() else ticks
