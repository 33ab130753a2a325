"""The co-simulation as separate processes over udp_multicast: determinism, isolation, failures,
realtime accounting, external tools and user-written clients."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path

import can
import numpy as np
import pytest

from cosim import scenario
from cosim.bus import registry
from cosim.bus.codec import load_dbc
from cosim.bus.transport import allocate
from cosim.errors import CosimError
from cosim.log.reader import LogReader
from cosim.run import Run, run
from tests.conftest import ROOT
from tests.frame_digests import unsigned
from tests.monitor_process import start_monitor, stop_monitor
from tests.snippets import short_scenario

pytestmark = pytest.mark.slow  # every test here runs node processes or long scenarios


@pytest.fixture(autouse=True)
def private_registry(tmp_path, monkeypatch):
    """Each test's runs register in a directory of their own (inherited by subprocesses)."""
    monkeypatch.setenv("COSIM_RUNTIME_DIR", str(tmp_path / "registry"))


def messages(path, exclude=("/cosim/events",)) -> list:
    """A log's records, control frames without their MACs (each run signs with its own key)."""
    with LogReader(path) as reader:
        return [
            (topic, t, {**msg, "data": unsigned(msg["id"], msg["data"])} if topic == "/can/frames" else msg)
            for topic, t, msg in reader.messages()
            if topic not in exclude
        ]


def short(tmp_path, duration=3.0, extra="", name="short.toml", base=None):
    text = base if base is not None else scenario.load().text
    path = tmp_path / name
    path.write_text(short_scenario(text, duration) + extra)
    return scenario.load(path)


def cli(*args, **kwargs) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "cosim.cli", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
        **kwargs,
    )


def wait_for(condition, timeout=60.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.05)
    raise AssertionError("timed out waiting")


def test_the_default_run_is_separate_processes_over_a_host_only_multicast_bus(default_run):
    with LogReader(default_run.path) as reader:
        bus = reader.metadata()["cosim.bus"]
        result = reader.metadata()["cosim.result"]
    assert bus["interface"] == "udp_multicast"
    assert (
        bus["channel"].startswith("ff11:")
        and bus["hop_limit"] == "1"
        or bus["channel"].startswith("239.255.")
        and bus["hop_limit"] == "0"
    )
    assert json.loads(result["senders"]) == {
        "uniform": {"frames": 3001 * 1 + 3000 * 2, "lost": 0, "runner_frames_missed": 0, "late": 0},
        "kalman": {"frames": 3001 * 1 + 3000 * 2, "lost": 0, "runner_frames_missed": 0, "late": 0},
    }
    assert registry.active() == []  # the run's registry entry is gone


def test_the_log_matches_the_in_process_bus_frame_for_frame(default_run, default_loaded, tmp_path):
    virtual = run(default_loaded, tmp_path / "virtual.mcap", interface="virtual")
    assert messages(default_run.path) == messages(virtual.path)


def test_lockstep_is_deterministic_whatever_the_machine_load(tmp_path):
    loaded = short(tmp_path, 5.0)
    quiet = run(loaded, tmp_path / "quiet.mcap")
    burners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(3)]
    try:
        loaded_run = run(loaded, tmp_path / "loaded.mcap")
    finally:
        for burner in burners:
            burner.kill()
    assert quiet.frames_lost == loaded_run.frames_lost == 0
    assert messages(quiet.path) == messages(loaded_run.path)


def test_concurrent_runs_never_hear_each_other(tmp_path):
    loaded = short(tmp_path, 4.0)
    procs = [
        cli("run", "-q", str(loaded.source), "--seed", str(seed), "--out", str(tmp_path / f"together{seed}.mcap"))
        for seed in (1, 2)
    ]
    for proc in procs:
        _, err = proc.communicate(timeout=120)
        assert proc.returncode == 0, err
    for seed in (1, 2):
        alone = run(loaded, tmp_path / f"alone{seed}.mcap", seed=seed)
        assert messages(tmp_path / f"together{seed}.mcap") == messages(alone.path)


def _tx_packets() -> dict[str, int]:
    counts = {}
    for device in Path("/sys/class/net").iterdir():
        if device.name != "lo" and (device / "statistics/tx_packets").exists():
            counts[device.name] = int((device / "statistics/tx_packets").read_text())
    return counts


@pytest.mark.skipif(not _tx_packets(), reason="no network interface besides loopback to watch")
def test_bus_traffic_never_leaves_the_host(tmp_path):
    before = _tx_packets()
    result = run(short(tmp_path, 3.0), tmp_path / "host.mcap")
    after = _tx_packets()
    assert result.frames > 3000
    for device, count in after.items():  # thousands of frames went over the bus; background is a few packets
        assert count - before.get(device, 0) < 100, device


@pytest.mark.parametrize("interface", ["cosim_udp", "udp_multicast"])
def test_a_python_can_logger_on_the_printed_bus_captures_the_run(tmp_path, interface):
    """can.logger with the run's interface (cosim_udp: it reads the participants' batches), or
    python-can's own udp_multicast on the mirror of a run started with --mirror: every frame the log
    has, once."""
    mirrored = interface == "udp_multicast"
    bus = allocate("udp_multicast", mirror=mirrored)
    capture = tmp_path / "capture.log"
    logger = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "can.logger",
            "-i",
            interface,
            "-c",
            bus.channel,
            "--bus-kwargs",
            f"port={bus.mirror if mirrored else bus.port}",
            "-f",
            str(capture),
        ],
        stdout=(console := open(tmp_path / "logger.out", "w")),  # a file: a full pipe would block the logger
        stderr=subprocess.STDOUT,
        text=True,
        # Ctrl-C stops can.logger, unless SIGINT is ignored: a shell starts background jobs that way,
        # and Python keeps an ignored SIGINT ignored in the children.
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    deadline = time.monotonic() + 60  # until the logger has joined the group (importing can takes a while)
    while time.monotonic() < deadline and "Connected to" not in (tmp_path / "logger.out").read_text():
        time.sleep(0.05)
    try:
        proc = cli(
            "run",
            str(short(tmp_path, 2.0).source),
            "--channel",
            bus.channel,
            "--port",
            str(bus.port),
            "--out",
            str(tmp_path / "logged.mcap"),
            *(["--mirror"] if mirrored else []),
        )
        _, err = proc.communicate(timeout=120)
        assert proc.returncode == 0, err
        assert f" on udp_multicast channel {bus.channel} port {bus.port}   join with: can.Bus(" in err
        time.sleep(0.5)
    finally:
        logger.send_signal(signal.SIGINT)
        try:
            logger.wait(timeout=30)
        finally:
            logger.kill()
            console.close()
    assert logger.returncode is not None, (tmp_path / "logger.out").read_text()
    captured = list(can.LogReader(str(capture)))
    dbc = subprocess.run(
        [sys.executable, "-m", "cosim.cli", "dbc", str(tmp_path / "short.toml")],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    db = load_dbc(dbc)
    with LogReader(tmp_path / "logged.mcap") as reader:
        logged = [msg for _, _, msg in reader.messages(["/can/frames"])]
    on_the_bus = Counter((f.arbitration_id, bytes(f.data).hex()) for f in captured)
    for key in on_the_bus:  # a node repeats its boot-up until tick 0; the log keeps the first
        if db.get_message_by_frame_id(key[0]).name.startswith("HEARTBEAT_") and int(key[1][:2], 16) == 0:
            on_the_bus[key] = 1
    assert on_the_bus == Counter((f["id"], f["data"]) for f in logged)
    for frame in captured:
        message = db.get_message_by_frame_id(frame.arbitration_id)
        decoded = db.decode_message(frame.arbitration_id, bytes(frame.data))
        assert set(decoded) == {s.name for s in message.signals}


def _kill_at(tick: int, action):
    done = []

    def on_progress(progress):
        if progress.tick >= tick and not done:
            done.append(True)
            action()

    return on_progress


def test_a_killed_estimator_is_reported_by_name_with_its_status_and_output(tmp_path):
    r = Run(short(tmp_path, 10.0), tmp_path / "killed.mcap")
    node = lambda: next(p for p in r.participants if p.name == "kalman")  # noqa: E731
    with pytest.raises(CosimError) as info:
        r.execute(_kill_at(300, lambda: node().process.kill()), progress_every=0.0)
    message = str(info.value)
    assert message.startswith("node kalman exited with status -9; its last output:")
    with LogReader(tmp_path / "killed.mcap") as reader:
        result = reader.metadata()["cosim.result"]
    assert result["status"] == "error" and "node kalman exited" in result["error"]
    assert 300 <= int(result["ticks"]) < 1000
    assert all(p.process.poll() is not None for p in r.participants)  # the other node was stopped too


def test_a_hung_estimator_is_reported_and_killed(tmp_path):
    loaded = short(tmp_path, 10.0, "\n[timing]\nnode_timeout = 1.0\n")
    r = Run(loaded, tmp_path / "hung.mcap")
    node = lambda: next(p for p in r.participants if p.name == "uniform")  # noqa: E731
    started = time.perf_counter()
    with pytest.raises(CosimError, match=r"node uniform did not answer tick \d+ within 1 s and was killed \(it hung"):
        r.execute(_kill_at(200, lambda: os.kill(node().process.pid, signal.SIGSTOP)), progress_every=0.0)
    assert time.perf_counter() - started < 30
    assert node().process.poll() is not None
    with LogReader(tmp_path / "hung.mcap") as reader:
        assert reader.metadata()["cosim.result"]["status"] == "error"


def test_ctrl_c_stops_every_process_and_leaves_a_valid_log(tmp_path):
    out = tmp_path / "ctrlc.mcap"
    proc = cli("run", "--out", str(out))
    wait_for(lambda: out.exists() and out.stat().st_size > 150_000)
    children = subprocess.run(["pgrep", "-P", str(proc.pid)], capture_output=True, text=True).stdout.split()
    assert len(children) == 2  # the two estimator nodes
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130 and "interrupted after" in err and "Traceback" not in err
    for pid in children:
        with pytest.raises(ProcessLookupError):
            os.kill(int(pid), 0)
    with LogReader(out) as reader:
        meta = reader.metadata()
        frames = [msg for _, _, msg in reader.messages(["/can/frames"])]
    assert meta["cosim.result"]["status"] == "interrupted"
    stop = [i for i, f in enumerate(frames) if f["message"] == "NMT"]
    assert len(stop) == 1  # after it, at most what a node was still sending for the interrupted tick
    assert {f["sender"] for f in frames[stop[0] + 1 :]} <= {"uniform", "kalman"}


def test_realtime_mode_paces_ticks_and_counts_deadline_misses(tmp_path):
    loaded = short(tmp_path, 3.0, '\n[timing]\nmode = "realtime"\nspeed = 1.0\n')
    r = Run(loaded, tmp_path / "realtime.mcap")
    node = lambda: next(p for p in r.participants if p.name == "kalman")  # noqa: E731
    actions = {100: signal.SIGSTOP, 150: signal.SIGCONT}

    def on_progress(progress):
        if progress.tick in actions:
            os.kill(node().process.pid, actions.pop(progress.tick))

    result = r.execute(on_progress, progress_every=0.0)
    assert result.status == "completed" and result.frames_lost == 0
    assert 2.95 < result.loop_time < 3.5  # the tick loop is paced to the wall clock (startup is not)
    with LogReader(result.path) as reader:
        misses = [msg for _, _, msg in reader.messages(["/cosim/deadline_misses"])]
        meta = reader.metadata()["cosim.result"]
    stopped = [m for m in misses if m["node"] == "kalman" and 100 <= m["tick"] <= 200]
    sporadic = [m for m in misses if m not in stopped]  # a loaded machine may miss the odd tick
    assert 40 <= len(stopped) <= 70, misses  # stopped for 50 ticks of 10 ms, plus its catching up
    assert len(sporadic) <= 30, sporadic  # 10 % of the ticks: far fewer than the stopped node's
    assert int(meta["deadline_misses"]) == len(misses) == result.deadline_misses == misses[-1]["count"]


def test_a_user_written_client_joins_in_lockstep(tmp_path):
    base = (ROOT / "examples" / "least-squares-client.toml").read_text()
    loaded = short(tmp_path, 3.0, base=base, name="client.toml")
    out = tmp_path / "client.mcap"
    runner = cli("run", "-q", str(loaded.source), "--out", str(out))
    wait_for(lambda: registry.active())
    client = subprocess.run(
        [sys.executable, str(ROOT / "examples" / "least_squares_client.py")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    _, err = runner.communicate(timeout=120)
    assert client.returncode == 0, client.stderr
    assert runner.returncode == 0, err
    sensors, fixes, heartbeats = {}, {}, Counter()
    with LogReader(out) as reader:
        for topic, _, msg in reader.messages():
            if topic.startswith("/can/SENSOR_"):
                sensors.setdefault(msg["tick"], {})[topic.removeprefix("/can/SENSOR_")] = next(
                    v for key, v in msg.items() if key != "tick"
                )
            elif topic == "/can/CLIENT_lsq":
                fixes[msg["tick"]] = msg
            elif topic == "/can/HEARTBEAT_lsq":
                heartbeats[msg["state"]] += 1
        result = reader.metadata()["cosim.result"]
    assert sorted(fixes) == list(range(300)) and heartbeats == {0: 1, 5: 300}
    assert result["frames_lost"] == "0"
    for k, y in sensors.items():
        assert fixes[k]["x1"] == pytest.approx((2 * y["x1"] + y["x2"] + y["x1_minus_x2"]) / 3, abs=1e-6)
        assert fixes[k]["x2"] == pytest.approx((y["x1"] + 2 * y["x2"] - y["x1_minus_x2"]) / 3, abs=1e-6)


def test_a_declared_client_that_never_joins_is_reported(tmp_path):
    base = (
        (ROOT / "examples" / "least-squares-client.toml")
        .read_text()
        .replace("join_timeout = 120.0", "join_timeout = 1.0")
    )
    with pytest.raises(
        CosimError,
        match=r"client lsq(, node uniform)? did not join the bus udp_multicast channel \S+ port \d+ within 1 s",
    ):
        run(short(tmp_path, 1.0, base=base, name="nojoin.toml"), tmp_path / "nojoin.mcap")


def test_an_external_estimator_started_by_hand(tmp_path, default_loaded):
    text = default_loaded.text.replace(
        'name = "kalman"\nkind = "kalman"', 'name = "kalman"\nkind = "kalman"\nexternal = true'
    )
    loaded = short(tmp_path, 3.0, "\n[timing]\njoin_timeout = 60.0\n", base=text, name="external.toml")
    out = tmp_path / "external.mcap"
    runner = cli("run", "-q", str(loaded.source), "--out", str(out))
    wait_for(lambda: registry.active())
    node = cli("node", "kalman")
    _, err = runner.communicate(timeout=120)
    node.communicate(timeout=30)
    assert runner.returncode == 0 and node.returncode == 0, err
    reference = run(short(tmp_path, 3.0), tmp_path / "reference.mcap", interface="virtual")
    kalman = lambda path: [m for m in messages(path) if m[0].startswith(("/can/EST_kalman", "/can/HEARTBEAT_kalman"))]  # noqa: E731
    assert kalman(out) == kalman(reference.path)


def test_monitor_writes_a_line_per_message_into_a_pipe_until_the_run_stops(tmp_path):
    loaded = short(tmp_path, 3.0, '\n[timing]\nmode = "realtime"\n')
    runner = cli("run", "-q", str(loaded.source), "--out", str(tmp_path / "monitored.mcap"))
    wait_for(lambda: registry.active())
    monitor = cli("monitor")
    first = monitor.stdout.readline()  # lines come as the messages do, not at the end
    assert runner.poll() is None and len(first.split()) >= 3  # message, sender, tick, signals
    # The rest through the same text stream: communicate() would read the pipe's descriptor and lose
    # what readline() had already buffered. The watchdog bounds a monitor that never ends.
    watchdog = threading.Timer(120, monitor.kill)
    watchdog.start()
    try:
        out, err = monitor.stdout.read(), monitor.stderr.read()
        monitor.wait(timeout=60)
    finally:
        watchdog.cancel()
    runner.communicate(timeout=60)
    assert monitor.returncode == 0, err
    lines = [first, *out.splitlines()]
    estimates = [line.split() for line in lines if line.startswith("EST_uniform_0 ")]
    assert len(estimates) > 20 and all(e[1] == "uniform" and e[3].startswith("xhat_x1=") for e in estimates)
    ticks = [int(e[2]) for e in estimates]
    assert ticks == sorted(ticks) and len(set(ticks)) == len(ticks)  # one line per message, in order
    assert any(line.startswith("HEARTBEAT_kalman kalman ") for line in lines)
    assert "\x1b[" not in out and "message" not in lines[0]  # no table, no terminal codes
    header, summary = err.strip().splitlines()  # what is monitored, and how much: on standard error
    assert header.startswith("masses-bias (run ") and summary.endswith("the run has stopped")
    assert summary.startswith(f"{len(lines)} frames")


def test_no_running_cosimulation_is_a_clear_error():
    result = subprocess.run([sys.executable, "-m", "cosim.cli", "monitor"], capture_output=True, text=True)
    assert result.returncode == 1 and result.stderr.startswith("error: no co-simulation is running on this machine")


@pytest.mark.skipif(
    not Path("/sys/class/net/vcan0").exists(), reason="no vcan0 interface (needs the vcan kernel module)"
)
def test_socketcan_on_vcan(tmp_path, default_loaded):
    result = run(short(tmp_path, 2.0), tmp_path / "vcan.mcap", interface="socketcan", channel="vcan0")
    virtual = run(short(tmp_path, 2.0), tmp_path / "v.mcap", interface="virtual")
    assert result.frames_lost == 0 and messages(result.path) == messages(virtual.path)
    assert np.isfinite(result.wall_time)


def test_frames_from_a_program_that_joined_on_its_own_are_logged(tmp_path):
    """Any python-can program on the bus is heard: its frames reach the log, at the tick they came."""
    r = Run(short(tmp_path, 2.0), tmp_path / "foreign.mcap")
    sent = []

    def on_progress(progress):
        if progress.tick >= 50 and not sent:
            with can.Bus(**r.bus.kwargs()) as stranger:
                stranger.send(can.Message(arbitration_id=0x7E0, data=b"\x01\x02\x03", is_extended_id=False))
            sent.append(progress.tick)

    result = r.execute(on_progress, progress_every=0.0)
    with LogReader(result.path) as reader:
        foreign = [msg for _, _, msg in reader.messages(["/can/frames"]) if msg["id"] == 0x7E0]
    (frame,) = foreign
    assert frame["sender"] == "unknown" and frame["message"] is None and frame["data"] == "010203"
    assert sent[0] <= frame["tick"] <= sent[0] + 2 and result.frames_lost == 0


def test_nodes_exit_when_the_runner_is_killed_outright(tmp_path):
    """SIGKILL leaves the runner no chance to stop its nodes: they notice and exit by themselves."""
    out = tmp_path / "killed-runner.mcap"
    proc = cli("run", "-q", "--out", str(out))
    wait_for(lambda: out.exists() and out.stat().st_size > 100_000)
    children = subprocess.run(["pgrep", "-P", str(proc.pid)], capture_output=True, text=True).stdout.split()
    assert len(children) == 2
    proc.kill()
    proc.communicate(timeout=30)

    def gone(pid: str) -> bool:
        try:
            os.kill(int(pid), 0)
        except ProcessLookupError:
            return True
        state = Path(f"/proc/{pid}/stat").read_text().split()[2] if Path(f"/proc/{pid}/stat").exists() else "X"
        return state == "Z"  # exited, waiting to be reaped by init

    wait_for(lambda: all(gone(pid) for pid in children), timeout=10)


def test_monitor_decodes_any_bus_with_a_dbc(tmp_path):
    """No co-simulation registered: a bus named by its channel and port, frames decoded by a DBC file."""
    from cosim.bus.transport import open_bus

    dbc = tmp_path / "bus.dbc"
    assert subprocess.run([sys.executable, "-m", "cosim.cli", "dbc", "--out", str(dbc)]).returncode == 0
    codec = scenario.load().scenario.codec()
    config = allocate("udp_multicast")
    monitor = start_monitor(dbc, config)
    time.sleep(1.0)  # its socket joins the group
    bus = open_bus(config)
    try:
        for tick in range(40):
            bus.send(codec.encode("SENSOR_x1", tick, [0.25]))
            bus.send(can.Message(arbitration_id=0x7AB, data=b"\x01", is_extended_id=False))  # not in the DBC
            time.sleep(0.05)
    finally:
        bus.shutdown()
    out, err = stop_monitor(monitor)
    lines = [line.split() for line in out.splitlines()]  # a line per decoded frame: time since the start (s),
    assert 20 <= len(lines) <= 40  # message, id, sender, signals (a monitor that joins late misses the first)
    assert all(line[1:] == ["SENSOR_x1", "100", "plant", f"tick={int(line[4][5:])}", "x1=0.25", "m"] for line in lines)
    assert [float(line[0]) for line in lines] == sorted(float(line[0]) for line in lines)
    assert err.strip().splitlines()[-1].startswith(f"{2 * len(lines)} frames ({len(lines)} unknown)")  # 0x7AB
    refused = subprocess.run(
        [sys.executable, "-m", "cosim.cli", "monitor", "--dbc", str(dbc)], capture_output=True, text=True
    )
    assert refused.returncode == 1 and "--channel" in refused.stderr
