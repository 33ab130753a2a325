"""End to end: the default scenario's log, its frames, its truth, determinism and interruptions."""

from __future__ import annotations

import hashlib
import io
import json
import os
import re
import signal
import subprocess
import sys
import time
import types
from collections import Counter, defaultdict
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from cosim import scenario
from cosim.bus.codec import load_dbc
from cosim.cli import main
from cosim.errors import CodecError
from cosim.log.reader import LogReader
from cosim.run import Run, run
from tests.snippets import short_scenario

PER_TICK = {
    "SYNC": 1,
    "SENSOR_x1": 1,
    "SENSOR_x2": 1,
    "SENSOR_x1_minus_x2": 1,
    "COMMAND_force": 1,
    "EST_uniform_0": 1,
    "EST_uniform_1": 1,
    "EST_kalman_0": 1,
    "EST_kalman_1": 1,
    "HEARTBEAT_uniform": 1,
    "HEARTBEAT_kalman": 1,
}
TOTAL = 3000 * 11 + 2 + 1  # ticks, the two boot-up heartbeats, the final NMT stop


def frames_by_tick(path):
    ticks = defaultdict(list)
    with LogReader(path) as reader:
        for _, _, msg in reader.messages(["/can/frames"]):
            ticks[msg["tick"]].append(msg)
    return ticks


def inspect_json(path) -> dict:
    out = io.StringIO()
    with redirect_stdout(out):
        assert main(["inspect", str(path), "--json"]) == 0
    return json.loads(out.getvalue())


def write_short(tmp_path, text, duration, name="short.toml"):
    path = tmp_path / name
    path.write_text(short_scenario(text, duration))
    return scenario.load(path)


def test_every_tick_has_its_sync_sensor_and_estimator_frames(default_run):
    assert default_run.status == "completed" and default_run.ticks == 3000 and default_run.frames_lost == 0
    ticks = frames_by_tick(default_run.path)
    assert sorted(ticks) == list(range(3001))
    boot, first = ticks[0][:2], ticks[0][2:]
    assert [f["message"] for f in boot] == ["HEARTBEAT_uniform", "HEARTBEAT_kalman"]  # joined before tick 0
    assert [f["message"] for f in ticks[3000]] == ["NMT"]  # stop, after the last tick
    ticks[0] = first
    del ticks[3000]
    seq = 2
    order = list(PER_TICK)
    for k, frames in ticks.items():
        assert [f["message"] for f in frames] == order, k  # runner frames as sent, then by arbitration id
        for f in frames:
            assert f["seq"] == seq and f["t"] == pytest.approx(k * 0.01)
            seq += 1
    assert {f["sender"] for f in first} == {"runner", "plant", "controller", "uniform", "kalman"}


def test_frames_decode_with_the_dbc_from_cosim_dbc(default_run, tmp_path):
    dbc_path = tmp_path / "bus.dbc"
    assert main(["dbc", "--out", str(dbc_path)]) == 0
    db = load_dbc(dbc_path.read_text())
    decoded_topics = defaultdict(list)
    frames = []
    with LogReader(default_run.path) as reader:
        for topic, _, msg in reader.messages():
            if topic == "/can/frames":
                frames.append(msg)
            elif topic.startswith("/can/"):
                decoded_topics[topic.removeprefix("/can/")].append(msg)
    position = Counter()
    for frame in frames:
        message = db.get_message_by_frame_id(frame["id"])
        assert message.name == frame["message"] and message.senders == [frame["sender"]]
        values = db.decode_message(frame["id"], bytes.fromhex(frame["data"]))
        values.pop("mac", None)  # a control frame's MAC is in the DBC and not among the logged values
        logged = decoded_topics[message.name][position[message.name]]
        position[message.name] += 1
        assert values == pytest.approx(logged)


def test_inspect_reports_counts_and_errors(default_run, default_loaded):
    report = inspect_json(default_run.path)
    assert report["scenario"] == "masses-bias" and report["seed"] == 0 and report["status"] == "completed"
    assert report["ticks"] == 3000 and report["duration_s"] == 30.0
    assert report["frames"] == {"total": TOTAL, "lost": 0}
    assert report["channels"]["/can/frames"] == TOTAL
    for topic in (
        "/truth/state",
        "/truth/sensors",
        "/truth/inputs",
        "/truth/faults",
        "/can/SYNC",
        "/can/EST_uniform_1",
    ):
        assert report["channels"][topic] == 3000
    assert report["fault_onset"] == 5.0
    uniform, kalman = report["estimators"]["uniform"], report["estimators"]["kalman"]
    # The uniform-weight observer settles to the steady error of eq. (19) under the constant bias.
    r = Run(default_loaded, "/dev/null")
    obs = r.estimators["uniform"]
    phi = np.array([1.0, -1.5, 0.5])
    steady = np.linalg.norm(np.linalg.solve(np.eye(4) - obs.model.A + obs.L @ obs.H, obs.L @ obs.Pi @ phi))
    assert uniform["final_error"] == pytest.approx(steady, rel=0.02)  # 1 mm noise on a 0.9 m error
    assert steady < uniform["rms_post_fault"] < 1.1 * steady  # the steady error plus the onset transient
    for e in (uniform, kalman):
        assert e["rms_pre_fault"] < e["rms_post_fault"]
    assert kalman["rms_pre_fault"] < 0.02 and kalman["final_error"] > 0.5  # biased too, as expected


def test_log_is_valid_for_the_official_reader(default_run, default_loaded):
    with open(default_run.path, "rb") as stream:
        reader = make_reader(stream, validate_crcs=True)
        summary = reader.get_summary()
        assert summary.statistics.message_count == sum(summary.statistics.channel_message_counts.values())
        assert summary.chunk_indexes and all(ci.compression == "zstd" for ci in summary.chunk_indexes)
        assert all(ci.message_index_offsets for ci in summary.chunk_indexes)  # message indexes present
        for schema in summary.schemas.values():
            assert schema.encoding == "jsonschema" and json.loads(schema.data)["type"] == "object"
        assert {c.message_encoding for c in summary.channels.values()} == {"json"}
        count = sum(1 for _ in reader.iter_messages())
        assert count == summary.statistics.message_count
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
        attachments = {a.name: a.data for a in reader.iter_attachments()}
    assert set(meta) == {"cosim.run", "cosim.scenario", "cosim.versions", "cosim.bus", "cosim.result"}
    assert meta["cosim.run"]["seed"] == "0" and meta["cosim.scenario"]["toml"] == default_loaded.text
    assert meta["cosim.result"]["status"] == "completed"
    assert attachments["masses.xml"] == Path(default_loaded.scenario.plant_info.model_path).read_bytes()
    assert attachments["cosim.dbc"].decode() == Run(default_loaded, "/dev/null").codec.dbc


def test_truth_faults_and_sent_readings_agree(default_run):
    faults, sensors = [], {}
    with LogReader(default_run.path) as reader:
        for topic, _, msg in reader.messages(["/truth/faults", "/truth/sensors", "/can/SENSOR_x1_minus_x2"]):
            if topic == "/truth/faults":
                faults.append(msg)
            elif topic == "/truth/sensors":
                sensors[msg["tick"]] = msg
            else:
                sensors[("sent", msg["tick"])] = msg  # the tick counter: k mod 65536, and k < 3000
    for f in faults:
        k, true = f["tick"], sensors[f["tick"]]
        bias = [1.0, -1.5, 0.5] if f["t"] >= 5.0 else [0.0, 0.0, 0.0]
        assert list(f["fault"].values()) == pytest.approx(bias, abs=1e-12)
        assert f["active"] == (["bias"] if f["t"] >= 5.0 else [])
        for name in ("x1", "x2", "x1_minus_x2"):
            assert f["measured"][name] == pytest.approx(true[name] + f["noise"][name] + f["fault"][name], abs=1e-12)
        sent = sensors[("sent", k)]["x1_minus_x2"]
        assert abs(sent - f["measured"]["x1_minus_x2"]) <= 0.5e-6 + 1e-12
    noise = np.array([f["noise"]["x1"] for f in faults])
    assert noise.std() == pytest.approx(1e-3, rel=0.05)


def log_content(path) -> tuple[list, dict, dict]:
    """Everything a log holds: its messages (topic, log time, sequence, data), its metadata records
    and its attachments."""
    with open(path, "rb") as stream:
        reader = make_reader(stream)
        messages = [(c.topic, m.log_time, m.sequence, m.data) for _, c, m in reader.iter_messages()]
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        attachments = {a.name: a.data for a in reader.iter_attachments()}
    return messages, metadata, attachments


@pytest.mark.slow
def test_same_seed_gives_the_same_log_but_for_the_start_time(tmp_path, default_loaded, monkeypatch):
    """A run's one wall-clock value is its start (cosim.run start_time_ns): two runs of the same seed
    with the same run secret (COSIM_RUN_SECRET; else the control frames' MACs differ) log the same
    messages, metadata and attachments but for it, and with the clock pinned, the same bytes."""
    monkeypatch.setenv("COSIM_RUN_SECRET", "a5" * 32)
    loaded = write_short(tmp_path, default_loaded.text, 6.0)
    started = time.time_ns()
    d = run(loaded, tmp_path / "d.mcap", seed=1, interface="virtual", channel="determinism")
    monkeypatch.setattr("cosim.run.runner.time", types.SimpleNamespace(time_ns=lambda: 1_750_000_000_123_456_789))
    a, b, c = (
        run(loaded, tmp_path / f"{n}.mcap", seed=s, interface="virtual", channel="determinism")
        for n, s in (("a", 1), ("b", 1), ("c", 2))
    )
    digest = lambda r: hashlib.sha256(r.path.read_bytes()).hexdigest()  # noqa: E731
    assert digest(a) == digest(b)
    assert digest(a) != digest(c)
    (ma, meta_a, files_a), (md, meta_d, files_d) = log_content(a.path), log_content(d.path)
    assert json.loads(meta_a["cosim.run"].pop("start_time_ns")) == 1_750_000_000_123_456_789
    assert started <= json.loads(meta_d["cosim.run"].pop("start_time_ns")) <= time.time_ns()
    assert ma == md and meta_a == meta_d and files_a == files_d
    fa, fc = frames_by_tick(a.path), frames_by_tick(c.path)
    assert [f["data"] for f in fa[100] if f["message"] == "SENSOR_x1"] != [
        f["data"] for f in fc[100] if f["message"] == "SENSOR_x1"
    ]


def test_an_interrupted_run_leaves_a_valid_log_up_to_that_tick(tmp_path, default_loaded):
    r = Run(default_loaded, tmp_path / "cut.mcap", interface="virtual")

    def stop(progress):
        if progress.tick >= 700:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        r.execute(stop, progress_every=0.0)
    report = inspect_json(tmp_path / "cut.mcap")
    assert report["status"] == "interrupted" and report["ticks"] == 700 and report["duration_s"] == 7.0
    assert report["channels"]["/truth/state"] == 700 and report["frames"]["total"] == 700 * 11 + 3
    assert report["estimators"]["uniform"]["rms_post_fault"] > 0.5


@pytest.mark.slow
def test_an_error_mid_run_is_recorded_and_the_log_stays_valid(tmp_path, default_loaded):
    path = tmp_path / "narrow.toml"
    path.write_text(short_scenario(default_loaded.text, 10.0) + "\n[bus.sensors.x1]\nmaximum = 0.9\n")
    # x1 stays below 0.35 m; the +1 m bias from t = 5 s pushes the reading past 0.9 m at once
    with pytest.raises(
        CodecError, match=r"SENSOR_x1\.x1 at tick 500 = 0\.9\d+ m is outside its declared range \[-8, 0\.9\] m"
    ):
        run(scenario.load(path), tmp_path / "err.mcap")
    report = inspect_json(tmp_path / "err.mcap")
    assert report["status"] == "error" and report["ticks"] == 500
    with LogReader(tmp_path / "err.mcap") as reader:
        assert "outside its declared range" in reader.metadata()["cosim.result"]["error"]


def signalled_run(out: Path, signum: int, *options: str) -> tuple[int, str]:
    """``cosim run`` in a terminal of its own, sent ``signum`` once its log holds about 100 kB:
    its exit status and what it printed on standard error."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "cosim.cli", "run", *options, "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and (not out.exists() or out.stat().st_size < 100_000):
        time.sleep(0.05)
    proc.send_signal(signum)
    _, stderr = proc.communicate(timeout=60)
    return proc.returncode, stderr


@pytest.mark.slow
def test_ctrl_c_in_the_terminal(tmp_path):
    out = tmp_path / "ctrlc.mcap"
    status, stderr = signalled_run(out, signal.SIGINT)
    assert status == 130, stderr
    assert "interrupted after" in stderr and "Traceback" not in stderr
    report = inspect_json(out)
    assert report["status"] == "interrupted" and 0 < report["ticks"] < 3000
    assert report["frames"]["total"] == report["channels"]["/can/frames"]


@pytest.mark.slow
def test_sigterm_finishes_the_log_and_exits_with_143(tmp_path):
    out = tmp_path / "term.mcap"
    status, stderr = signalled_run(out, signal.SIGTERM, "-q")
    assert status == 143, stderr
    assert inspect_json(out)["status"] == "interrupted"


def test_sigterm_before_the_session_stops_like_ctrl_c():
    """While the plan is made (no session, no deferred interrupts yet) SIGTERM raises, as Ctrl-C
    does, instead of ending the process without a word; outside, the handler is what it was."""
    from cosim.run.interrupts import Interrupted, terminate_like_ctrl_c

    before = signal.getsignal(signal.SIGTERM)
    with pytest.raises(Interrupted) as stopped, terminate_like_ctrl_c():
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5.0)  # the signal is handled before this ends
    assert stopped.value.signum == signal.SIGTERM and signal.getsignal(signal.SIGTERM) is before


def test_a_signal_while_the_run_is_on_its_way_out_only_hurries_it():
    """The first Ctrl-C raises at the next tick boundary. A second one arriving while that raise
    goes up through the runner's ``except`` and ``finally`` blocks, before their shield, or within
    ``GRACE`` of the first (pressed twice in a row) must not raise (it could cut the writing of the
    log or its result short): it only asks the run to hurry. A second one later, before any
    boundary, still raises at once, for a run that never reaches one."""
    from cosim.run.interrupts import GRACE, DeferredInterrupts, Interrupted

    with DeferredInterrupts() as interrupts:
        signal.raise_signal(signal.SIGINT)
        assert interrupts.requested == signal.SIGINT and not interrupts.hurry
        with pytest.raises(Interrupted):
            interrupts.check()
        time.sleep(GRACE)
        try:
            signal.raise_signal(signal.SIGINT)  # between the raise and the shield
            signal.raise_signal(signal.SIGTERM)
        except Interrupted:
            pytest.fail("a signal on the way out raised again")
        assert interrupts.hurry
    with DeferredInterrupts() as interrupts:
        try:
            signal.raise_signal(signal.SIGINT)
            signal.raise_signal(signal.SIGINT)  # pressed twice in a row
        except Interrupted:
            pytest.fail("a second signal within the grace raised")
        assert interrupts.hurry and not interrupts.stopping
    with DeferredInterrupts() as interrupts, pytest.raises(Interrupted) as stopped:
        signal.raise_signal(signal.SIGINT)
        time.sleep(GRACE)
        signal.raise_signal(signal.SIGINT)  # stuck between boundaries: raises at once
    assert stopped.value.signum == signal.SIGINT and interrupts.stopping


@pytest.mark.slow
def test_fault_tour_on_can_fd(tmp_path):
    """Every fault kind end to end on a CAN FD bus: dropped frames are absent (and not lost),
    stuck readings hold, the actuator loses effectiveness, FD frames carry exact float64 values."""
    loaded = scenario.load("masses-faults-fd")
    result = run(loaded, tmp_path / "tour.mcap", interface="virtual")
    assert result.status == "completed" and result.frames_lost == 0
    ticks = frames_by_tick(tmp_path / "tour.mcap")
    faults, inputs, sent = {}, {}, defaultdict(dict)
    with LogReader(tmp_path / "tour.mcap") as reader:
        for topic, _, msg in reader.messages(
            ["/truth/faults", "/truth/inputs", "/can/SENSOR_x2_minus_x1", "/can/SENSOR_x1_minus_x2"]
        ):
            if topic == "/truth/faults":
                faults[msg["tick"]] = msg
            elif topic == "/truth/inputs":
                inputs[msg["tick"]] = msg
            else:
                sent[topic.removeprefix("/can/SENSOR_")][msg["tick"]] = msg
    dropped = [k for k, f in faults.items() if f["dropped"]]
    assert dropped and all(faults[k]["dropped"] == ["x2_minus_x1"] and k >= 1000 for k in dropped)
    assert 0.15 < len(dropped) / 1000 < 0.25  # probability 0.2 over t in [10, 20)
    for k, frames in ticks.items():
        names = [f["message"] for f in frames]
        if "SYNC" not in names:
            continue  # the final NMT stop
        assert ("SENSOR_x2_minus_x1" in names) == (k not in dropped)
        sync = next(f for f in frames if f["message"] == "SYNC")
        assert int.from_bytes(bytes.fromhex(sync["data"])[4:5], "little") == 5 - (k in dropped)
        assert all(f["fd"] for f in frames if not f["message"].startswith(("SYNC", "HEARTBEAT", "NMT")))
    for k in dropped:
        assert k not in sent["x2_minus_x1"]
    for k in range(0, 2000, 7):  # FD: the sent value is the measured value, exactly
        if k not in dropped:
            assert sent["x2_minus_x1"][k]["x2_minus_x1"] == faults[k]["measured"]["x2_minus_x1"]
    stuck = {faults[k]["measured"]["x1_minus_x2"] for k in range(800, 1200)}
    assert len(stuck) == 1 and len({faults[k]["measured"]["x1_minus_x2"] for k in range(1200, 1210)}) == 10
    assert (
        faults[1399]["active"] and "force_loss" not in faults[1399]["active"] and "force_loss" in faults[1400]["active"]
    )
    for k in (1400, 1700, 1999):
        delta = np.exp(-0.1 * (k * 0.01 - 14.0))
        assert inputs[k]["effective"]["force"] == pytest.approx(delta * inputs[k]["commanded"]["force"], rel=1e-12)
    assert inputs[1399]["effective"] == inputs[1399]["commanded"]
    report = inspect_json(tmp_path / "tour.mcap")
    assert report["fault_onset"] == 2.0 and report["frames"]["lost"] == 0


def test_a_cut_log_gives_a_partial_result_with_a_warning(default_run, tmp_path):
    data = default_run.path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    report = inspect_json(cut)
    assert report["status"] == "incomplete" and 1000 < report["ticks"] < 2000
    assert any("no summary section" in w for w in report["warnings"])
    assert any("damaged or cut after t =" in w for w in report["warnings"])
    assert report["estimators"]["uniform"]["rms_post_fault"] > 0.5  # computed from what was readable


def test_a_corrupted_chunk_is_skipped_with_a_warning(default_run, tmp_path):
    data = bytearray(default_run.path.read_bytes())
    with open(default_run.path, "rb") as stream:  # a chunk a third of the way in, not its message index
        chunks = make_reader(stream).get_summary().chunk_indexes
    chunk = chunks[len(chunks) // 3]
    middle = chunk.chunk_start_offset + chunk.chunk_length // 2
    data[middle : middle + 32] = bytes(b ^ 0xFF for b in data[middle : middle + 32])
    flipped = tmp_path / "flipped.mcap"
    flipped.write_bytes(bytes(data))
    report = inspect_json(flipped)
    (warning,) = report["warnings"]
    assert re.match(
        r"a damaged chunk was skipped: bytes \d+-\d+, t = [\d.]+-[\d.]+ s \(the Chunk at byte \d+ (is damaged \(its "
        r"records do not match their CRC\)|does not decompress)",
        warning,
    )
    assert report["estimators"]["uniform"]["final_error"] == pytest.approx(
        inspect_json(default_run.path)["estimators"]["uniform"]["final_error"]
    )


@pytest.mark.slow
def test_a_non_finite_effective_input_stops_the_run_with_a_clear_error(tmp_path, default_loaded):
    text = short_scenario(default_loaded.text, 2.0) + (
        '\n[[faults]]\nname = "blowup"\nkind = "actuator_effectiveness"\nstart = 1.0\n'
        'effectiveness = { kind = "exponential", rate = -1e6 }\n'
    )
    path = tmp_path / "blowup.toml"
    path.write_text(text)
    from cosim.errors import CosimError

    with pytest.raises(CosimError, match=r"actuator force: the effective input at tick 101 is not finite"):
        run(scenario.load(path), tmp_path / "blowup.mcap")
    assert inspect_json(tmp_path / "blowup.mcap")["status"] == "error"


def test_a_wait_before_tick_0_does_not_count_in_the_real_time_factor(tmp_path, default_loaded):
    """A viewer's wait (cosim run --foxglove) happens before tick 0: the run's pace is its ticks'."""
    loaded = scenario.apply(default_loaded, [("duration", 0.5)])
    seen = []
    result = Run(loaded, tmp_path / "w.mcap", interface="virtual").execute(
        seen.append, progress_every=0.0, on_start=lambda run: time.sleep(1.0)
    )
    assert result.wall_time > 1.0 > result.loop_time
    assert result.realtime_factor == pytest.approx(result.sim_time / result.loop_time)
    assert seen and all(p.wall_time < 1.0 for p in seen)


def test_a_realtime_run_that_cannot_keep_up_says_so(tmp_path, default_loaded):
    loaded = scenario.apply(default_loaded, [("duration", 2.0)])
    result = Run(loaded, tmp_path / "fast.mcap", interface="virtual", mode="realtime", speed=2000.0).execute()
    assert result.status == "completed" and result.late_ticks > 100  # 5 µs per tick: out of reach
    (warning,) = [w for w in result.warnings if "fell behind" in w]
    assert warning.startswith(f"realtime at 2000x fell behind: {result.late_ticks} of 200 ticks started late")
    with LogReader(result.path) as reader:
        record = reader.metadata()["cosim.result"]
    assert int(record["late_ticks"]) == result.late_ticks
    paced = Run(loaded, tmp_path / "paced.mcap", interface="virtual", mode="realtime", speed=5.0).execute()
    assert paced.late_ticks == 0 and not [w for w in paced.warnings if "fell behind" in w]
