"""Nothing on the wire crashes, hangs or silently corrupts a run; every stop leaves a log any reader opens.

Each test here is one of the failures issue 17 found, tried again: a fuzzer throwing datagrams at
a running co-simulation, unicast and foreign traffic, a transmitter that never stops, a second run
on the same bus, channels that leave the host, forged control frames, losses in realtime, double
Ctrl-C, SIGKILL and recovery, damaged logs under replay, scenario values at the limits, the run
registry's privacy, and a chaos test killing and stopping participants at random ticks.
"""

from __future__ import annotations

import json
import os
import random
import resource
import signal
import socket
import stat
import subprocess
import sys
import threading
import time
from pathlib import Path

import can
import pytest
from mcap.reader import make_reader

from cosim import scenario
from cosim.analysis.metrics import compute_metrics
from cosim.bus import registry
from cosim.bus.codec import BOOTUP, NMT_STOP, OPERATIONAL, STOPPED
from cosim.bus.transport import allocate, open_bus
from cosim.errors import CosimError, ScenarioError
from cosim.log.reader import LogReader
from cosim.log.recover import recover
from cosim.run import Replay, Run, run
from tests.conftest import ROOT
from tests.frame_digests import log_digest
from tests.snippets import short_scenario

pytestmark = pytest.mark.slow  # every test here runs node processes


@pytest.fixture(autouse=True)
def private_registry(tmp_path, monkeypatch):
    monkeypatch.setenv("COSIM_RUNTIME_DIR", str(tmp_path / "registry"))


def loaded(tmp_path, duration: float, name: str = "masses-bias", **settings):
    text = short_scenario(scenario.load(name).text, duration)
    path = tmp_path / f"{name}-{duration:g}.toml"
    path.write_text(text)
    base = scenario.load(path)
    return scenario.apply(base, settings) if settings else base


def sender(config):
    """A raw socket sending to the run's group and port, as any program on the host could."""
    family = socket.AF_INET6 if ":" in config.channel else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_DGRAM)
    if family == socket.AF_INET6:
        sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_MULTICAST_HOPS, (1).to_bytes(4, "little"))
    else:
        sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, (0).to_bytes(4, "little"))
    return sock


def fuzz_datagrams(count: int, seed: int = 5) -> list[tuple[str, bytes]]:
    """Random bytes, truncated and oversized python-can packets, frames with unknown ids and
    malformed control frames, each labelled with what the runner must count it as."""
    from can.interfaces.udp_multicast.utils import pack_message

    rng = random.Random(seed)
    good = pack_message(can.Message(arbitration_id=0x100, data=bytes(8), is_extended_id=False))
    made = []
    for i in range(count):
        kind = i % 5
        if kind == 0:
            made.append(("datagram", rng.randbytes(rng.randrange(0, 200))))
        elif kind == 1:
            made.append(("datagram", good[: rng.randrange(1, len(good) - 1)]))
        elif kind == 2:
            made.append(("datagram", good + rng.randbytes(5000)))  # longer than a receive buffer: truncated
        elif kind == 3:  # a frame on an id outside the run's database
            extended = rng.random() < 0.3
            frame = can.Message(
                arbitration_id=0x1FFFFFF if extended else rng.choice([0x7F0, 0x5FF]),
                data=rng.randbytes(rng.randrange(9)),
                is_extended_id=extended,
            )
            made.append(("frame", pack_message(frame)))
        else:  # a malformed SYNC or NMT (the runner's own ids, wrong lengths)
            frame = can.Message(
                arbitration_id=rng.choice([0x000, 0x080]),
                data=rng.randbytes(rng.choice([1, 3, 7])),
                is_extended_id=False,
            )
            made.append(("frame", pack_message(frame)))
    return made


def test_ten_thousand_foreign_datagrams_change_no_estimate_and_every_one_is_counted(tmp_path):
    # 6000 ticks: the fuzzing (1-3 s) must end while the run still ticks, however fast the tick is
    datagrams = fuzz_datagrams(10_000)
    clean = run(loaded(tmp_path, 60.0), tmp_path / "clean.mcap")
    peak_after_clean = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # kB: the runner is this process
    target = Run(loaded(tmp_path, 60.0), tmp_path / "fuzzed.mcap")
    done = threading.Event()

    def fuzz() -> None:
        sock = sender(target.bus)
        for _, data in datagrams:
            sock.sendto(data, (target.bus.channel, target.bus.port))
            time.sleep(0.0001)
        done.set()

    started: list[threading.Thread] = []
    finished_at: list[int] = []

    def progress(p) -> None:
        if not started and p.tick >= 10:
            started.append(threading.Thread(target=fuzz))
            started[0].start()
        if done.is_set() and not finished_at:
            finished_at.append(p.tick)

    result = target.execute(progress, progress_every=0.0)
    started[0].join()
    assert finished_at, "the run ended before the fuzzing did: what came after it was not counted"
    assert result.status == "completed" and result.frames_lost == 0
    assert log_digest(result.path) == log_digest(clean.path)  # the estimators' frames are the clean run's
    bus = compute_metrics(result.path)["bus"]
    # every one is counted: as a datagram that is no frame, or as a frame the run did not send (a few random
    # byte strings happen to unpack as a map of a frame's fields)
    assert bus["foreign"]["datagrams"] + bus["foreign"]["frames"] == len(datagrams)
    # the same run fuzzed needs at most 10 MB more than it did clean
    growth = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - peak_after_clean
    print(f"the runner's peak memory under the fuzz: +{growth / 1024:.1f} MB over the clean run's")
    assert growth < 10 * 1024, growth
    assert bus["foreign"]["frames"] >= sum(kind == "frame" for kind, _ in datagrams)


def test_unicast_and_other_groups_on_the_port_never_reach_the_run():
    config = allocate("udp_multicast")
    other = allocate("udp_multicast", port=config.port)  # another group, the same port
    with open_bus(config) as bus, open_bus(other) as neighbour:
        unicast = socket.socket(socket.AF_INET6 if ":" in config.channel else socket.AF_INET, socket.SOCK_DGRAM)
        unicast.sendto(b"hello", ("::1" if ":" in config.channel else "127.0.0.1", config.port))
        neighbour.send(can.Message(arbitration_id=0x100, data=bytes(2), is_extended_id=False))
        assert bus.recv(0.3) is None and bus.foreign == 0


@pytest.mark.parametrize("pause", [0.0005, 0.0])
def test_a_run_ends_while_another_program_transmits_without_pause(tmp_path, pause):
    """2000 frames/s of another program's: the run completes; a flood as fast as a process can send:
    the run still ends, in bounded time, with its log and result."""
    target = Run(loaded(tmp_path, 2.0), tmp_path / "chatty.mcap")
    stop = threading.Event()

    def chatter() -> None:
        with can.Bus(**target.bus.kwargs()) as bus:
            while not stop.is_set():
                bus.send(can.Message(arbitration_id=0x7F0, data=bytes(8), is_extended_id=False))
                if pause:
                    time.sleep(pause)

    threads = [threading.Thread(target=chatter)]
    started = time.perf_counter()
    try:
        result = target.execute(on_start=lambda r: threads[0].start())
    except CosimError:
        result = target.result
    finally:
        stop.set()
        threads[0].join()
    elapsed = time.perf_counter() - started
    assert result is not None and elapsed < 90
    metrics = compute_metrics(result.path)
    assert metrics["status"] == result.status and metrics["bus"]["foreign"]["frames"] > 0
    if pause:
        assert result.status == "completed"
    elif result.status != "completed":  # a participant delayed past its timeout: the flood is named, not it
        assert "another program flooded the bus" in result.error and "0x7F0" in result.error, result.error


FLOODER = """
import socket, sys, time
channel, port, rate, seconds = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), float(sys.argv[4])
datagram = bytes.fromhex(sys.argv[5])
family = socket.AF_INET6 if ":" in channel else socket.AF_INET
sock = socket.socket(family, socket.SOCK_DGRAM)
if family == socket.AF_INET6:
    sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_MULTICAST_HOPS, (1).to_bytes(4, "little"))
else:
    sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, (0).to_bytes(4, "little"))
sent, start, batch = 0, time.perf_counter(), rate // 100
while (now := time.perf_counter()) - start < seconds:
    for _ in range(batch):
        sock.sendto(datagram, (channel, port))
    sent += batch
    time.sleep(max(0.0, start + sent / rate - time.perf_counter()))
print(sent, time.perf_counter() - start)
"""


def test_a_flood_of_100_000_frames_per_second_is_survived_and_every_loss_is_the_kernels(tmp_path):
    """Another process sends 100 000 frames/s on a foreign id for 2 s into a lockstep run: it
    completes, or stops naming the flood. The runner's socket accounts for every datagram sent to
    it: what the kernel dropped is the flood's frames it did not count, the participants' frames
    it lost and its own echoes that did not come back, exactly."""
    from can.interfaces.udp_multicast.utils import pack_message

    target = Run(loaded(tmp_path, 8.0), tmp_path / "flooded.mcap")
    datagram = pack_message(can.Message(arbitration_id=0x7F0, data=bytes(8), is_extended_id=False)).hex()
    flooder: list[subprocess.Popen] = []

    def flood(p) -> None:
        if not flooder and p.tick >= 50:
            bus = target.bus
            args = [sys.executable, "-c", FLOODER, bus.channel, str(bus.port), "100000", "2.0", datagram]
            flooder.append(subprocess.Popen(args, stdout=subprocess.PIPE, text=True))
        elif flooder and p.tick >= 700 and flooder[0].poll() is None:
            # the kernel reports its drops with the next datagram read: the run must outlast the flood
            # (a quick machine finishes the 800 ticks within its 2 s) for every drop to be counted
            flooder[0].wait(timeout=30)

    try:
        result = target.execute(flood, progress_every=0.0)
    except CosimError:
        result = target.result
    assert flooder, "the run ended before the flood began"
    sent, seconds = flooder[0].communicate(timeout=30)[0].split()
    assert result is not None
    print(
        f"flood: {int(sent)} frames in {float(seconds):.2f} s; {result.status}; kernel dropped {result.kernel_dropped}"
    )
    if result.status != "completed":
        assert "another program flooded the bus" in result.error and "0x7F0" in result.error, result.error
        return
    traffic = target.session.traffic
    with LogReader(result.path) as reader:
        own = sum(1 for _, _, m in reader.messages(["/can/frames"]) if m["sender"] in ("runner", "plant", "controller"))
    flood_received = traffic.foreign_frames
    lost_at_runner = sum(traffic.lost.values())
    assert int(sent) - flood_received + lost_at_runner + (own - traffic.echoes) == result.kernel_dropped
    assert result.frames_lost == lost_at_runner + sum(traffic.missed_by.values())


def test_a_second_run_on_the_same_group_and_port_is_refused_before_tick_0(tmp_path):
    first = Run(loaded(tmp_path, 20.0), tmp_path / "first.mcap")
    errors = []

    def second(r) -> None:
        if errors:
            return
        try:
            Run(loaded(tmp_path, 1.0), tmp_path / "second.mcap", channel=r.bus.channel, port=r.bus.port).execute()
            errors.append(None)
        except CosimError as error:
            errors.append(str(error))
        raise KeyboardInterrupt  # enough: stop the first run

    with pytest.raises(KeyboardInterrupt):
        first.execute(on_progress=lambda p: second(first) if p.tick > 5 else None, progress_every=0.0)
    assert errors and errors[0] is not None and "is in use by the running co-simulation" in errors[0]
    assert not (tmp_path / "second.mcap").exists()  # refused before its log was even opened


@pytest.mark.parametrize("channel", ["ff02::1:c05", "ff0e::c05:1"])
def test_a_channel_that_leaves_the_host_needs_allow_network(tmp_path, channel):
    with pytest.raises(CosimError, match="go out on the network.*--allow-network"):
        Run(loaded(tmp_path, 1.0), tmp_path / "x.mcap", channel=channel).execute()
    assert allocate("udp_multicast", channel, allow_network=True).hop_limit == 1


def test_forged_control_frames_are_rejected_and_change_nothing(tmp_path):
    """Boot-ups in the nodes' names before they join, then an NMT stop (to all, and to one node), an
    NMT reset, a SYNC ahead of the run and heartbeats in a node's name (closing the current tick
    with 255 frames, stopped, closing a tick far ahead): none carries the run's MAC. The run
    completes with the clean run's frames, nothing lost, no tick contested, and each forged frame
    is logged as rejected."""
    clean = run(loaded(tmp_path, 3.0), tmp_path / "clean.mcap")
    target = Run(loaded(tmp_path, 3.0), tmp_path / "forged.mcap")
    forged: list[can.Message] = []

    def send(frames: list[can.Message]) -> None:
        with can.Bus(**target.bus.kwargs()) as bus:
            for frame in frames:
                bus.send(frame)
                forged.append(frame)

    def join(r) -> None:
        send([r.codec.heartbeat(node, BOOTUP) for node in ("uniform", "kalman")])

    def forge(p) -> None:
        if p.tick > 20 and len(forged) == 2:
            c = target.codec
            send(
                [
                    c.nmt(NMT_STOP),
                    c.nmt(NMT_STOP, c.node_ids["kalman"]),
                    c.nmt(0x81),  # CANopen's reset node
                    c.sync(p.tick + 5, 3),
                    c.heartbeat("kalman", OPERATIONAL, p.tick, frames=255),
                    c.heartbeat("uniform", STOPPED, p.tick),
                    c.heartbeat("uniform", OPERATIONAL, p.tick + 10**4, frames=2),
                ]
            )

    result = target.execute(forge, progress_every=0.0, on_start=join)
    assert len(forged) == 9
    assert result.status == "completed" and result.frames_lost == 0 and result.contested_ticks == 0
    assert log_digest(result.path) == log_digest(clean.path)
    rejected = compute_metrics(result.path)["bus"]["secoc_rejected"]
    assert sum(reasons.get("bad_mac", 0) for reasons in rejected.values()) == 9, rejected


def test_realtime_losses_are_counted_per_sender(tmp_path):
    """At 50× real time the nodes cannot keep up: whatever estimate is missing from the log is lost or late."""
    result = Run(loaded(tmp_path, 10.0), tmp_path / "fast.mcap", mode="realtime", speed=50).execute()
    metrics = compute_metrics(result.path)
    bus = metrics["bus"]
    for name, estimator in metrics["estimators"].items():
        missing_ticks = result.ticks - estimator["ticks_scored"]
        if missing_ticks > 0:  # two frames per tick (EST_<name>_0 and _1): each missing tick is frames lost or late
            assert bus["lost_by_sender"][name] + bus["late_by_sender"][name] >= missing_ticks, (name, bus)
    assert bus["lost"] == result.frames_lost == sum(bus["lost_by_sender"].values())


def _cosim(*args, **kwargs) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "cosim.cli", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kwargs
    )


def test_a_double_ctrl_c_still_writes_the_result(tmp_path):
    for attempt in range(3):
        out = tmp_path / f"double-{attempt}.mcap"
        process = _cosim("run", "--out", str(out), "-q", "--set", "duration=600")  # still ticking when stopped
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and (not out.exists() or out.stat().st_size < 30_000):  # ticking
            time.sleep(0.05)
        time.sleep(0.3 * attempt)
        process.send_signal(signal.SIGINT)
        time.sleep(0.05 * attempt)
        process.send_signal(signal.SIGINT)
        process.wait(60)
        metrics = compute_metrics(out)
        assert metrics["status"] == "interrupted" and "cosim.result" not in " ".join(metrics["missing"])


def test_sigkill_then_recover_gives_a_log_every_reader_opens(tmp_path):
    out = tmp_path / "killed.mcap"
    process = _cosim("run", "--out", str(out), "-q", start_new_session=True)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and (not out.exists() or out.stat().st_size < 200_000):  # ticks on disk
        time.sleep(0.1)
    os.kill(process.pid, signal.SIGKILL)
    process.wait()
    with pytest.raises(Exception), open(out, "rb") as stream:  # noqa: B017 (the official reader refuses it)
        list(make_reader(stream).iter_messages())
    assert compute_metrics(out)["ticks"] > 0  # cosim inspect reads it as far as it goes
    recovered = recover(out, tmp_path / "fixed.mcap")
    assert recovered.messages > 1000 and "without its summary" in recovered.damage
    with open(recovered.path, "rb") as stream:
        reader = make_reader(stream)
        assert (
            sum(1 for _ in reader.iter_messages())
            == recovered.messages
            == reader.get_summary().statistics.message_count
        )
    time.sleep(2.0)  # the nodes notice their runner is gone
    assert (
        subprocess.run(
            ["pgrep", "-f", f"cosim.cli node.*{process.pid}|cosim-nodes-{process.pid}"], capture_output=True
        ).returncode
        == 1
    )
    # the next run removes the killed run's node folder and registry entry
    run(loaded(tmp_path, 0.5), tmp_path / "next.mcap", interface="virtual")
    import tempfile

    assert not list(Path(tempfile.gettempdir()).glob(f"cosim-nodes-{process.pid}-*")) and registry.active() == []


def test_replay_of_a_cut_log_says_where_it_ends(tmp_path):
    original = run(loaded(tmp_path, 3.0), tmp_path / "original.mcap", interface="virtual").path
    data = original.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    started = time.perf_counter()
    with pytest.raises(CosimError, match=r"the log ends at tick \d+"):
        Replay(cut, tmp_path / "replay.mcap", "kalman", interface="virtual").execute()
    assert time.perf_counter() - started < 10.0  # not a node timeout
    assert compute_metrics(tmp_path / "replay.mcap")["status"] == "error"  # and its log says so


@pytest.mark.parametrize(
    "settings, message",
    [
        ({"duration": 1e308}, "at most 1e+09"),
        ({"sample_time": 5e-324}, "below 1e-06 s"),
        ({"plant.initial_state.x1": 40.0}, "SENSOR_x1.x1 at tick 0 = 40"),
        ({"faults[0].value": 50.0, "faults[0].start": 0.0}, "outside its declared range"),
    ],
)
def test_scenario_values_at_the_limits_are_errors_before_any_process_starts(tmp_path, settings, message):
    with pytest.raises(ScenarioError, match=message.replace("(", r"\(").replace("+", r"\+")):
        Run(scenario.apply(scenario.load("masses-bias"), settings), tmp_path / "x.mcap")


def test_a_deeply_nested_waveform_is_one_line_not_a_traceback():
    nested: object = 1.0
    for _ in range(200):
        nested = {"kind": "sum", "terms": [nested]}
    with pytest.raises(ScenarioError, match="nested more than 32"):
        scenario.apply(scenario.load("masses-bias"), {"inputs[0].signal": nested})


@pytest.mark.parametrize("value", ["[" * 3000 + "]" * 3000, "{b = " * 3000 + "1" + "}" * 3000])
def test_a_toml_nested_thousands_deep_is_one_line_not_a_recursion_error(tmp_path, value):
    """tomllib's parser recurses: 3000 nested arrays or inline tables were ~3000 lines of traceback."""
    (tmp_path / "deep.toml").write_text(f"a = {value}\n")
    with pytest.raises(ScenarioError, match=r"deep.toml: invalid TOML: arrays or inline tables nested thousands deep"):
        scenario.load(tmp_path / "deep.toml")
    with pytest.raises(ScenarioError, match="is not a TOML value"):
        scenario.parse_value(value)
    done = subprocess.run(
        [sys.executable, "-m", "cosim.cli", "run", str(tmp_path / "deep.toml")], capture_output=True, text=True
    )
    assert done.returncode == 1 and done.stderr.strip().endswith("nested thousands deep (a scenario needs a few)")
    assert "Traceback" not in done.stderr


def test_a_module_next_to_the_scenario_is_found(tmp_path):
    """``kind = "module:Class"``: on the import path first, else ``module.py`` next to the scenario."""
    text = (ROOT / "scenarios" / "masses-bias.toml").read_text()
    (tmp_path / "myobs.py").write_text(
        "from estimators.kalman import KalmanFilter\n\nclass Mine(KalmanFilter):\n    pass\n"
    )
    (tmp_path / "s.toml").write_text(text.replace('kind = "kalman"', 'kind = "myobs:Mine"'))
    loaded = scenario.load(tmp_path / "s.toml").scenario
    assert loaded.estimators[1].kind == f"{tmp_path / 'myobs.py'}:Mine"
    assert loaded.codec().specs  # its kind resolved: the scenario validated whole
    (tmp_path / "json.py").write_text("raise RuntimeError('the import path comes first')\n")
    (tmp_path / "s.toml").write_text(text.replace('kind = "kalman"', 'kind = "json:JSONDecoder"'))
    with pytest.raises(ScenarioError, match="estimators\\[1\\].kind: estimator 'json:JSONDecoder'"):
        scenario.load(tmp_path / "s.toml")  # the standard library's json, not the file beside


def test_the_run_registry_is_private_to_its_user(tmp_path):
    result = []
    Run(loaded(tmp_path, 0.3), tmp_path / "r.mcap").execute(
        on_start=lambda r: result.append([(p, stat.S_IMODE(p.stat().st_mode)) for p in registry.directory().iterdir()])
    )
    folder_mode = stat.S_IMODE(registry.directory().stat().st_mode)
    assert folder_mode == 0o700 and all(mode == 0o600 for _, mode in result[0])
    planted = registry.directory() / "planted.json"
    planted.write_text(json.dumps({"id": "x", "pid": os.getpid()}))
    os.chown(planted, 12345, 12345)  # as if another user had written it
    assert all(info["id"] != "x" for info in registry.active())


VICTIMS = ("node-kill", "node-stop", "runner-kill", "client-kill")


def test_chaos_every_stopped_participant_is_named_and_every_log_recovers(tmp_path):
    """Kill or stop a random participant (a node, the runner, a client) at a random moment, 8 times:
    every log opens with cosim inspect and, recovered, with the official reader; the culprit is named;
    no process and no node folder is left."""
    rng = random.Random(17)
    examples = Path(__file__).resolve().parent.parent / "examples"
    # long enough that the kill, at most a second after the run starts ticking, lands before it ends
    quick = ["--set", "duration=60", "--set", "timing.node_timeout=2", "--set", "timing.join_timeout=10"]
    tally: dict[str, int] = {}
    for trial in range(16):  # 8 stops (each kind twice) keep the suite within CI's half hour
        if sum(tally.values()) >= 8:
            break
        victim = VICTIMS[sum(tally.values()) % len(VICTIMS)]  # each kind in turn; the moment is random
        out = tmp_path / f"chaos-{trial}.mcap"
        if victim == "client-kill":
            process = _cosim(
                "run",
                str(examples / "least-squares-client.toml"),
                "--out",
                str(out),
                "-q",
                *quick,
                start_new_session=True,
            )
            deadline = time.monotonic() + 30
            while not registry.active() and time.monotonic() < deadline:
                time.sleep(0.05)
            client = subprocess.Popen(
                [sys.executable, str(examples / "least_squares_client.py")],
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
            time.sleep(rng.uniform(1.0, 3.0))
            client.kill()
            client.wait()
            _, stderr = process.communicate(timeout=60)
            if process.returncode == 0:  # the run was over before the client was
                continue
            assert "client lsq" in stderr, stderr
        else:
            process = _cosim("run", "--out", str(out), "-q", *quick, start_new_session=True)
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline and (not out.exists() or out.stat().st_size < 30_000):  # ticking
                time.sleep(0.05)
            time.sleep(rng.uniform(0.0, 1.0))
            if victim == "runner-kill":
                os.kill(process.pid, signal.SIGKILL)
                process.wait()
            else:
                nodes = subprocess.run(
                    ["pgrep", "-f", f"cosim-nodes-{process.pid}-"], capture_output=True, text=True
                ).stdout.split()
                if not nodes:  # the run was over already
                    process.wait(60)
                    continue
                os.kill(int(rng.choice(nodes)), signal.SIGKILL if victim == "node-kill" else signal.SIGSTOP)
                _, stderr = process.communicate(timeout=90)
                if process.returncode == 0:  # it stopped a node that had finished its last tick
                    continue
                assert "node " in stderr and ("exited with status" in stderr or "did not answer tick" in stderr), stderr
        tally[victim] = tally.get(victim, 0) + 1
        assert compute_metrics(out)["channels"]  # cosim inspect opens it
        fixed = recover(out, tmp_path / f"chaos-{trial}-fixed.mcap")
        with open(fixed.path, "rb") as stream:
            assert sum(1 for _ in make_reader(stream).iter_messages()) == fixed.messages > 0
        if victim == "runner-kill":
            time.sleep(1.5)  # its nodes notice their runner is gone
        assert subprocess.run(["pgrep", "-f", f"cosim-nodes-{process.pid}-"], capture_output=True).returncode == 1
    assert tally == dict.fromkeys(VICTIMS, 2), tally
    print(f"chaos: {tally} in {trial + 1} trials")


def test_a_scenario_file_alone_cannot_open_the_bus_to_the_network(tmp_path):
    path = tmp_path / "wide.toml"
    text = (Path(scenario.__file__).parent.parent.parent / "scenarios" / "masses-bias.toml").read_text()
    path.write_text(text.replace("[bus]\n", '[bus]\nallow_network = true\nchannel = "ff0e::c05:1"\n'))
    with pytest.raises(CosimError, match=r"bus.allow_network: a scenario file cannot widen the bus .*--allow-network"):
        scenario.load(path)
    with pytest.raises(CosimError, match=r"bus.allow_network"):
        scenario.apply(scenario.load(), [("bus.allow_network", True)])
    # whoever runs it may: the command line's override
    s = scenario.load().scenario.with_overrides(allow_network=True, channel="ff0e::c05:1")
    assert s.bus.allow_network
