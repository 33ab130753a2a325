"""The quiet ticks of K runs' wires on arrays (cosim.run.arbitration.quiet_ticks) against each run's
own ``Arbitration.tick``: the same frames sent in the same order, the same deliveries to the
nanosecond, the same state left, tick after tick, on classic CAN and CAN FD, at loads where some
ticks are quiet and others are not; and the frames' lengths on arrays (``frame_bits_rows``) and
their durations (``Wire.durations_rows``) against the scalar ones."""

from __future__ import annotations

import random

import can
import numpy as np
import pytest

from cosim import api
from cosim.bus.codec import CONTROLLER, OPERATIONAL
from cosim.bus.timing import frame_bits, frame_bits_rows
from cosim.bus.wire import Wire, WireFrame, dlc_of
from cosim.run.arbitration import Arbitration, Periodic, quiet_ticks
from cosim.run.loop import runner_frames
from cosim.run.plan import RunPlan
from cosim.scenario import apply


@pytest.mark.parametrize(("fd", "brs"), [(False, False), (True, False), (True, True)])
def test_frame_lengths_on_arrays_equal_the_scalar_ones_frame_by_frame(fd, brs):
    rng = random.Random(7)
    lengths = [0, 1, 2, 3, 5, 7, 8] if not fd else [0, 1, 8, 12, 16, 20, 24, 32, 48, 64]
    for n in lengths:
        columns, rows = 24, 16
        ids = [rng.randrange(1 << 29) if c % 3 == 0 else rng.randrange(1 << 11) for c in range(columns)]
        extended = [c % 3 == 0 for c in range(columns)]
        payloads = np.zeros((columns, rows, n), dtype=np.uint8)
        for c in range(columns):
            for r in range(rows):  # runs of equal bits (the most stuff bits) as well as random bytes
                payloads[c, r] = [rng.choice([0, 255]) if r % 2 else rng.randrange(256) for _ in range(n)]
        nominal, fast = frame_bits_rows(ids, extended, [dlc_of(n)] * columns, payloads, fd, brs)
        want = [[frame_bits(ids[c], extended[c], fd, brs, dlc_of(n), bytes(payloads[c, r])) for r in range(rows)]
                for c in range(columns)]  # fmt: skip
        assert nominal.tolist() == [[w[0] for w in row] for row in want]
        assert fast.tolist() == [[w[1] for w in row] for row in want]


def test_durations_on_arrays_equal_the_wires_own():
    rng = random.Random(3)
    for bitrate, data_bitrate in [(125_000, 125_000), (500_000, 2_000_000), (333_333, 1_000_000), (83_333, 83_333)]:
        wire = Wire(bitrate, data_bitrate)
        bits = [(rng.randrange(20, 700), rng.choice([0, rng.randrange(0, 700)])) for _ in range(200)]
        total, delivery = wire.durations_rows(np.array([b[0] for b in bits]), np.array([b[1] for b in bits]))
        for (nominal, fast), t, d in zip(bits, total.tolist(), delivery.tolist()):
            frame = WireFrame(1, False, fast > 0, fast > 0, b"", "x", 0, 0)
            frame.bits = (nominal, fast)
            assert (t, d) == wire.duration_ns(frame)


def plan_of(bitrate: int, fd: bool) -> RunPlan:
    settings = [("duration", 1.0), ("bus.bitrate", bitrate), ("bus.fd", fd)]
    return RunPlan.build(apply(api.load("masses-pid-can"), settings), 1)


def wires(plan: RunPlan, runs: int, traffic_period_ns: int | None) -> list[Arbitration]:
    """``runs`` wires of one design, each with background traffic from 0.2 s to 0.4 s if given."""
    s = plan.scenario
    out = []
    for r in range(runs):
        traffic = []
        if traffic_period_ns is not None and r % 2:
            rng = np.random.default_rng(r)
            traffic = [Periodic("chatty", 0x0C0, traffic_period_ns, 8, 200_000_000, 400_000_000, s.bus.fd, rng)]
        out.append(Arbitration(plan.codec, s.bus.bitrate, s.bus.data_bitrate, s.dt_ns, traffic))
    return out


def answers(plan: RunPlan, k: int, rng: random.Random) -> list:
    """The nodes' answers to tick k − 1 as the runner's traffic hands them on (by id): each node's
    frames (random values; now and then one missing, or a second copy) and its heartbeat."""
    codec, found = plan.codec, []
    for node in [*plan.estimators, CONTROLLER]:
        sent = 0
        for spec in codec.data_messages(node):
            copies = rng.choices([0, 1, 2], weights=[1, 40, 1])[0]
            for _ in range(copies):
                values = [rng.uniform(c.minimum, c.maximum) / rng.choice([1, 1e3]) for c in spec.channels]
                found.append(codec.encode_decoded(spec.name, k - 1, values))
                sent += 1
        heartbeat = codec.heartbeat(node, OPERATIONAL, k - 1, sent, rng.randrange(3))
        at = codec.control_macs[heartbeat.arbitration_id][1].mac[0]  # a MAC as signed: timed as if 0
        heartbeat.data[at:] = bytes(rng.randrange(256) for _ in range(len(heartbeat.data) - at))
        found.append((heartbeat, codec.decode(heartbeat)))
    return sorted(found, key=lambda item: item[0].arbitration_id)


def runner(plan: RunPlan, k: int, rng: random.Random) -> tuple[list, dict[int, str]]:
    """The runner's frames of tick k (SYNC first) and the intruders' among them (by ``id()``):
    now and then a reading not sent, an intruder's copy of a sensor's frame (of this tick, which
    receivers distrust with the genuine one, or replayed from an earlier tick, which they do not
    count), two copies from one intruder (the newer replaces the older on the wire), a frame on
    SYNC's id in its sender's name, or one on a control frame's id shorter than its MAC."""
    s, codec = plan.scenario, plan.codec
    specs = [codec.sensor(name) for name in s.sensors]
    measured = [rng.uniform(-1, 1) * rng.choice([1, 1e-3]) for _ in specs]
    sent = [rng.random() > 0.05 for _ in specs]
    sync, *data = runner_frames(codec, k, specs, measured, sent, [], [])
    intruders: dict[int, str] = {}
    for _ in range(rng.choices([0, 1, 2], weights=[6, 3, 1])[0]):
        spec = rng.choice(specs)
        forged = codec.encode_decoded(spec.name, k - rng.choice([0, 0, 3]), (rng.uniform(-1, 1),))
        intruders[id(forged)] = "intruder"
        data.append(forged)
    if rng.random() < 0.05:  # on SYNC's id in SYNC's sender's name: it replaces SYNC on the wire
        forged = (can.Message(arbitration_id=sync[0].arbitration_id, data=bytes(8), is_extended_id=False), None)
        intruders[id(forged)] = sync[1].spec.sender
        data.append(forged)
    if rng.random() < 0.1:  # a fuzzer's frame too short for the MAC of the control frame whose id it has
        at = rng.choice(sorted(codec.control_macs))
        forged = (can.Message(arbitration_id=at, data=bytes(rng.randrange(3)), is_extended_id=False), None)
        intruders[id(forged)] = "fuzzer"
        data.append(forged)
    rng.shuffle(data)  # as a bus fault may leave them: the wire sends them by id whatever their order
    return [sync, *data], intruders


def shown(frame) -> tuple[int, bytes]:
    return frame[0].arbitration_id, bytes(frame[0].data)


@pytest.mark.parametrize(
    ("bitrate", "fd", "traffic_ns"),
    [(500_000, False, 1_100_000), (250_000, False, None), (200_000, False, 3_000_000), (500_000, True, 700_000)],
)
def test_quiet_ticks_give_and_leave_what_each_runs_wire_gives_and_leaves(bitrate, fd, traffic_ns):
    plan = plan_of(bitrate, fd)
    runs = 6
    alone, together = wires(plan, runs, traffic_ns), wires(plan, runs, traffic_ns)
    rngs = [random.Random(100 + r) for r in range(runs)]
    quiet = loud = 0
    for k in range(60):
        frames_of, senders_of = [], []
        for r in range(runs):
            for frame in answers(plan, k, rngs[r]) if k else []:
                for arbitration in (alone[r], together[r]):
                    arbitration.answer(k, 0.0, 0, *frame)
            frames, senders = runner(plan, k, rngs[r])
            frames_of.append(frames)
            senders_of.append(senders)
        found = quiet_ticks(together, k, frames_of, senders_of)
        for r in range(runs):
            step = alone[r].tick(k, frames_of[r], senders=senders_of[r])
            delivered = [(p.delivered_ns, p.frame.payload) for p in step.passed if p.dropped is None]
            if found[r] is None:
                other = together[r].tick(k, frames_of[r], senders=senders_of[r])
                assert [(p.delivered_ns, shown(p.frame.payload)) for p in other.passed if p.dropped is None] == [
                    (at, shown(frame)) for at, frame in delivered
                ]
                loud += 1
                continue
            quiet += 1
            got = found[r]
            assert [shown(f) for f in got.send] == [shown(f) for f in step.send]
            assert all(a is b for a, b in zip(got.send[1:], step.send[1:]))  # the runner's own frames
            assert [(at, shown(f)) for at, f in got.delivered] == [(at, shown(f)) for at, f in delivered]
            assert not step.passed or all(p.dropped is None for p in step.passed)
        for a, b in zip(alone, together):
            assert (a.wire.idle_ns, a.wire._seq, a._inputs_ns, len(a.wire.queue)) == (
                b.wire.idle_ns,
                b.wire._seq,
                b._inputs_ns,
                len(b.wire.queue),
            )
    for a, b in zip(alone, together):
        assert [(p.delivered_ns, p.dropped, shown(p.frame.payload)) for p in a.finish()] == [
            (p.delivered_ns, p.dropped, shown(p.frame.payload)) for p in b.finish()
        ]
    assert quiet > 30 and loud > 10, (quiet, loud)  # both ways taken: the equalities say something


def test_wires_of_other_bit_rates_in_one_call_are_each_timed_at_their_own():
    plan = plan_of(500_000, False)
    s, codec = plan.scenario, plan.codec
    specs = [codec.sensor(name) for name in s.sensors]
    rates = [500_000, 125_000, 500_000, 250_000]
    frames_of = [runner_frames(codec, 2, specs, [0.1, 0.2, 0.3], [True] * 3, [], []) for _ in rates]
    together = [Arbitration(codec, rate, rate, s.dt_ns) for rate in rates]
    found = quiet_ticks(together, 2, frames_of)
    for rate, frames, quiet in zip(rates, frames_of, found):
        step = Arbitration(codec, rate, rate, s.dt_ns).tick(2, frames)
        assert quiet is not None
        assert [at for at, _ in quiet.delivered] == [p.delivered_ns for p in step.passed]


def test_a_sources_due_says_whether_its_frames_would_come_and_draws_nothing():
    rng = random.Random(5)
    for _ in range(300):
        period = rng.choice([1, 7, 250_000, 1_100_000, 10_000_000, 30_000_000])
        start = rng.choice([0, 1, rng.randrange(50_000_000), 10_000_000])
        end = rng.choice([2**62, start + rng.randrange(1, 60_000_000)])
        begin = rng.choice([start - 1, start, start + rng.randrange(40_000_000), end - 1, end, end + 1])
        stop = begin + rng.choice([1, 20 * period, period, period + 1, 10_000_000 if period > 7 else 20])
        source = Periodic("s", 0x0C0, period, 8, start, end, False, np.random.default_rng(0))
        due = source.due(begin, stop)
        state = source.rng.bit_generator.state
        assert due == bool(source.frames(begin, stop)), (period, start, end, begin, stop)
        if not due:  # frames drew nothing either: due draws nothing in any case (it takes no generator)
            assert source.rng.bit_generator.state == state


def test_a_sources_frames_of_an_interval_are_the_frame_by_frame_draws_of_its_stream():
    """``Periodic.frames`` draws an interval's payloads at once: the same bytes, queue times and
    stream position as a draw of ``integers(0, 256, length, dtype=uint8)`` frame after frame (the
    payloads of every run with background traffic, alone or batched, and so its frame digests)."""
    rng = random.Random(11)
    for _ in range(400):
        period = rng.choice([1, 7, 250_000, 1_100_000, 10_000_000])
        start = rng.choice([0, 3, rng.randrange(50_000_000)])
        end = rng.choice([2**62, start + rng.randrange(1, 60_000_000)])
        begin = rng.choice([start - 1, start, start + rng.randrange(40_000_000), end - 1, end])
        stop = begin + rng.choice([1, period, period + 1, 40 * period, 10_000_000 if period > 7 else 30])
        length, fd = rng.choice([(n, n > 8) for n in (0, 1, 2, 3, 4, 5, 7, 8, 12, 16, 20, 24, 32, 48, 64)])
        seed = rng.randrange(2**32)
        source = Periodic("s", 0x0C0, period, length, start, end, fd, np.random.default_rng(seed))
        reference = np.random.default_rng(seed)
        expected, n = [], -(-(max(start, begin) - start) // period)
        while (t := start + n * period) < min(stop, end):
            expected.append((t / 1e9, reference.integers(0, 256, length, dtype=np.uint8).tobytes()))
            n += 1
        got = source.frames(begin, stop)
        assert [(m.timestamp, bytes(m.data)) for m in got] == expected, (period, start, begin, length)
        assert all(m.arbitration_id == 0x0C0 and m.is_fd == fd and not m.is_extended_id for m in got)
        assert source.rng.bit_generator.state == reference.bit_generator.state  # the stream goes on alike
