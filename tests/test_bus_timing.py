"""Arbitrated timing: the wire's schedule against a computation by hand, and a run on it."""

from __future__ import annotations

import random

import pytest

from cosim import scenario
from cosim.bus.timing import frame_bits
from cosim.bus.wire import Transmission, Wire, WireFrame, dlc_of
from cosim.errors import ScenarioError
from cosim.log.reader import LogReader
from cosim.run import run
from tests.frame_digests import unsigned
from tests.snippets import masses

BIT_NS = 8000  # 125 kbit/s


def hand_bits(can_id: int, data: bytes) -> int:
    """A classic 11-bit data frame written out bit by bit, as on the wire: SOF, id, RTR, IDE, r0,
    DLC, data, CRC-15 (long division, bit at a time), stuffed after every five equal bits, then
    CRC delimiter, ACK slot and delimiter, EOF (7) and the intermission (3)."""
    bits = [0] + [(can_id >> i) & 1 for i in range(10, -1, -1)] + [0, 0, 0]
    bits += [(len(data) >> i) & 1 for i in range(3, -1, -1)]
    bits += [(byte >> i) & 1 for byte in data for i in range(7, -1, -1)]
    crc = 0
    for bit in bits:
        top = (crc >> 14) & 1
        crc = (crc << 1) & 0x7FFF
        if bit ^ top:
            crc ^= 0x4599
    bits += [(crc >> i) & 1 for i in range(14, -1, -1)]
    stuffed, run_bit, run_length = 0, None, 0
    for bit in bits:
        if bit == run_bit:
            run_length += 1
        else:
            run_bit, run_length = bit, 1
        if run_length == 5:
            stuffed += 1
            run_bit, run_length = 1 - bit, 1  # the stuff bit starts the next run
    return len(bits) + stuffed + 13


def test_the_all_zero_frame_by_hand():
    # id 0x000, no data: SOF, 11 id bits, RTR, IDE, r0, DLC (4) are 19 dominant bits and the CRC of
    # zeros is zero: 34 zeros, a stuff bit after every five (6), then 13 tail bits.
    assert hand_bits(0x000, b"") == 34 + 6 + 13 == frame_bits(0, False, False, False, 0, b"")[0]


def test_frame_lengths_match_the_bit_by_bit_computation():
    rng = random.Random(15)
    for _ in range(300):
        can_id, data = rng.randrange(0x800), bytes(rng.randrange(256) for _ in range(rng.randrange(9)))
        assert frame_bits(can_id, False, False, False, len(data), data)[0] == hand_bits(can_id, data)


def _frame(can_id, data, queued_ns, sender="a"):
    return WireFrame(can_id, False, False, False, data, sender, queued_ns, queued_ns + 10_000_000)


def test_the_dlc_table_is_python_cans_len2dlc():
    """Every payload length, those past CAN FD's 64 bytes included (a foreign frame may carry them)."""
    from can.util import len2dlc

    assert [dlc_of(n) for n in range(200)] == [len2dlc(n) for n in range(200)]


def test_latencies_match_a_hand_computation():
    """Four frames at 125 kbit/s: three queued at 0, one of higher priority while the first is on the wire."""
    a, b, c = _frame(0x123, bytes(range(8)), 0), _frame(0x050, b"\x0f\xf0", 0), _frame(0x7FF, b"", 0)
    d = _frame(0x010, b"\xaa", 100_000)
    wire = Wire(125_000)
    for frame in (a, b, c, d):
        wire.offer(frame)
    passed = wire.run(10**9)
    # By hand: b wins at 0 (lowest id); d is queued during b and wins when b ends; then a, then c.
    order = [b, d, a, c]
    assert [p.frame for p in passed] == order
    t = 0
    for p, frame in zip(passed, order):
        start = max(t, frame.queued_ns)
        length = hand_bits(frame.frame_id, frame.data)
        assert (p.start_ns, p.delivered_ns, p.end_ns) == (start, start + (length - 3) * BIT_NS, start + length * BIT_NS)
        assert p.latency_ns == start + (length - 3) * BIT_NS - frame.queued_ns
        t = p.end_ns
    # b: 2 bytes 0x0F 0xF0 have two stuff bits of their own
    assert passed[0].delivered_ns == (hand_bits(0x050, b"\x0f\xf0") - 3) * BIT_NS


def test_a_newer_frame_of_an_id_replaces_the_waiting_one():
    wire = Wire(125_000)
    hog = _frame(0x001, bytes(8), 0, "hog")
    old, new = _frame(0x100, b"\x01", 0), _frame(0x100, b"\x02", 50_000)
    for frame in (hog, old, new):
        wire.offer(frame)
    passed = wire.run(10**9)
    assert [(p.frame, p.dropped is not None) for p in passed] == [(hog, False), (old, True), (new, False)]
    assert passed[1].start_ns == 50_000  # replaced when the newer one was queued


def _random_frame(rng, latest_ns):
    """Of a few ids (so that senders' frames of one id replace each other), queued up to ``latest_ns``."""
    data = bytes(rng.randrange(256) for _ in range(rng.randrange(9)))
    return _frame(rng.randrange(0x20), data, rng.randrange(0, latest_ns, 1000), rng.choice("ab"))


def _state(wire):
    return wire.idle_ns, wire._seq, [id(frame) for frame in wire.queue]


def test_committing_a_forks_plan_is_running_the_wire_to_an_earlier_stop():
    """``commit``: a fork's passages to a later stop, cut at any stop, are what the wire's own run
    gives and leave it as that run does (contention, replaced frames, idle gaps, frames still
    queued past the stop), over random queues."""
    rng = random.Random(45)
    for _ in range(300):
        wire = Wire(125_000)
        for _ in range(rng.randrange(6)):  # frames left from before, some of them queued later
            wire.offer(_random_frame(rng, 2_000_000))
        wire.idle_ns = rng.randrange(0, 500_000, 1000)
        later = [_random_frame(rng, 3_000_000) for _ in range(rng.randrange(1, 10))]
        deadline = rng.randrange(1_000_000, 5_000_000, 1000)
        trial = wire.fork()
        for frame in later:
            trial.offer(frame)
        planned = trial.run(deadline)
        starts = [p.start_ns for p in planned]  # a stop at a passage's start: is that one in or out?
        stop = rng.choice(starts) if starts and rng.random() < 0.5 else rng.randrange(0, deadline + 1, 1000)
        alone = wire.fork()
        for frame in later:
            alone.offer(frame)
        expected = alone.run(stop)
        for frame in later:
            wire.offer(frame)
        assert wire.commit(planned, stop) == expected
        assert _state(wire) == _state(alone)
        assert wire.run(2**62) == alone.run(2**62)  # and it goes on alike


class _ReferenceWire(Wire):
    """The wire as first written (each idle moment: every frame queued by then scanned, replaced,
    the lowest chosen), the yardstick of ``Wire.run``'s heap."""

    def run(self, stop_ns: int) -> list[Transmission]:
        """Simulate the wire: the transmissions that start before ``stop_ns`` (in order), and the
        frames replaced before they could go, are taken off the queue and returned."""
        out: list[Transmission] = []
        t = self.idle_ns
        while self.queue:
            eligible = [f for f in self.queue if f.queued_ns <= t]
            if not eligible:
                t = max(t, min(f.queued_ns for f in self.queue))
                if t >= stop_ns:
                    break
                continue
            if t >= stop_ns:
                break
            dropped = self._replace(eligible)
            if dropped:
                out += dropped
                eligible = [f for f in self.queue if f.queued_ns <= t]
            winner = min(eligible, key=lambda f: (f.frame_id, f.queued_ns, f.seq))
            self.queue.remove(winner)
            total, delivery = self.duration_ns(winner)
            out.append(Transmission(winner, t, t + delivery, t + total))
            t += total
            self.idle_ns = t
        return out

    def _replace(self, eligible: list[WireFrame]) -> list[Transmission]:
        """A sender's newer frame of an id replaces its older one still waiting."""
        if len({(frame.sender, frame.frame_id) for frame in eligible}) == len(eligible):
            return []  # the usual case: one frame per sender and id
        newest: dict[tuple[str, int], WireFrame] = {}
        for frame in sorted(eligible, key=lambda f: (f.queued_ns, f.seq)):
            newest[(frame.sender, frame.frame_id)] = frame
        dropped = []
        for frame in eligible:
            newer = newest[(frame.sender, frame.frame_id)]
            if newer is not frame:
                self.queue.remove(frame)
                at = newer.queued_ns
                dropped.append(Transmission(frame, at, at, at, "replaced by a newer frame of its id"))
        return dropped


def _copied(wire, cls=Wire):
    twin = cls(wire.bitrate, wire.data_bitrate)
    twin.idle_ns, twin.queue, twin._seq = wire.idle_ns, list(wire.queue), wire._seq
    return twin


def test_the_wire_runs_as_its_first_plain_form():
    """Over random queues of contending, replaced and later frames, run in pieces to random stops:
    the same passages, drops and times, and the same queue left, as the plain scan."""
    rng = random.Random(11898)
    for _ in range(400):
        wire = Wire(rng.choice((125_000, 500_000)))
        for _ in range(rng.randrange(25)):
            wire.offer(_random_frame(rng, 4_000_000))
        wire.idle_ns = rng.randrange(0, 1_000_000, 1000)
        reference = _copied(wire, _ReferenceWire)
        for stop in sorted(rng.randrange(0, 6_000_000, 1000) for _ in range(3)) + [2**62]:
            assert wire.run(stop) == reference.run(stop)
            assert _state(wire) == _state(reference)
            for _ in range(rng.randrange(3)):  # more frames between the pieces
                frame = _random_frame(rng, 6_000_000)
                wire.offer(frame)
                reference.offer(frame)


def _tiny(tmp_path, **bus):
    settings = 'interface = "virtual"\nbitrate = 125000\n' + "\n".join(f"{k} = {v}" for k, v in bus.items())
    path = tmp_path / "tiny.toml"
    path.write_text(masses("tiny", 0.2, forced=True, bus=settings, kalman=True))
    return scenario.load(str(path))


def test_a_run_on_an_arbitrated_bus_delivers_each_frame_at_its_last_bit(tmp_path):
    """The runner's frames of a tick leave an idle wire at t_k back to back: SYNC, sensors by id,
    the command; each is logged when its last bit is on the wire."""
    out = tmp_path / "arb.mcap"
    result = run(_tiny(tmp_path, timing='"arbitrated"'), out, 0)
    assert result.status == "completed"
    with LogReader(out) as reader:
        frames = [(t, m) for _, t, m in reader.messages(["/can/frames"])]
        wire = [m for _, _, m in reader.messages(["/cosim/wire"])]
    assert wire and all(not m["late"] and m["dropped"] is None for m in wire)
    for k in (3, 7, 12):
        t_k = k * 10_000_000
        runner = sorted(
            (t, m)
            for t, m in frames
            if t_k <= t < t_k + 10_000_000 and m["sender"] in ("runner", "plant", "controller")
        )
        assert [m["message"] for _, m in runner] == [
            "SYNC",
            "SENSOR_x1",
            "SENSOR_x2",
            "SENSOR_x1_minus_x2",
            "COMMAND_force",
        ]
        start = t_k
        for t, m in runner:  # the wire times a control frame's MAC as zeros: a run's key changes no timing
            length = hand_bits(m["id"], bytes.fromhex(unsigned(m["id"], m["data"])))
            assert t == start + (length - 3) * BIT_NS
            start += length * BIT_NS


def test_the_same_seed_gives_the_same_arbitrated_log(tmp_path, monkeypatch):
    """Two runs of a seed: the same frames at the same times, but for the control frames' MACs (each
    run draws its key); with a fixed run secret, bit for bit."""
    s = _tiny(tmp_path, timing='"arbitrated"')
    logs = []
    for name in ("a", "b", "c", "d"):
        if name == "c":
            monkeypatch.setenv("COSIM_RUN_SECRET", "5e" * 32)
        run(s, tmp_path / f"{name}.mcap", 0)
        with LogReader(tmp_path / f"{name}.mcap") as reader:
            logs.append([(t, m) for topic, t, m in reader.messages(["/can/frames", "/cosim/wire"])])
    masked = [[(t, {**m, "data": unsigned(m["id"], m["data"])} if "data" in m else m) for t, m in log] for log in logs]
    assert logs[0] != logs[1] and masked[0] == masked[1] == masked[2]
    assert logs[2] == logs[3]


@pytest.mark.parametrize(
    ("bus", "field"),
    [
        ({"timing": '"arbitrated"', "traffic": '[{ name = "c", id = 0x100, period = 0.001 }]'}, "bus.traffic[0].id"),
        ({"traffic": '[{ name = "c", id = 0x0C0, period = 0.001 }]'}, "bus.traffic:"),
    ],
)
def test_bad_bus_tables_name_their_field(tmp_path, bus, field):
    with pytest.raises(ScenarioError, match=field.replace("[", r"\[").replace("]", r"\]")):
        _tiny(tmp_path, **bus)


@pytest.mark.slow
def test_overload_degrades_the_estimators_against_the_ideal_bus(tmp_path):
    """masses-bus-overload against masses-bus-ideal: past 100 % offered load sensor frames are late
    or replaced and the estimators' answers (lowest priority) hardly reach the bus."""
    from cosim.analysis.metrics import compute_metrics

    metrics = {}
    for name in ("masses-bus-ideal", "masses-bus-overload"):
        out = tmp_path / f"{name}.mcap"
        assert run(scenario.load(name), out, 0).status == "completed"
        metrics[name] = compute_metrics(out)
    ideal, over = metrics["masses-bus-ideal"], metrics["masses-bus-overload"]
    assert ideal["bus"]["latency"] is None
    offered = over["bus"]["load_over_time"]["offered"]
    assert max(offered[:10]) < 1.0 < 1.5 < min(offered[10:])
    latency = over["bus"]["latency"]
    assert latency["0x102"]["dropped"] > 1000 and latency["0x101"]["late"] + latency["0x101"]["dropped"] > 1000
    for estimator in ("uniform", "kalman"):
        assert over["estimators"][estimator]["ticks_scored"] < 0.5 * ideal["estimators"][estimator]["ticks_scored"]
        assert over["estimators"][estimator]["final_error"] > 1.5 * ideal["estimators"][estimator]["final_error"]
