"""cosim replay: a log's bus traffic fed again to an estimator process, and played onto a live bus.

The runs are short, time-compressed versions of the built-in scenarios (their faults moved into
the shortened window), one per estimator kind, run in-process (virtual bus); every replay is a
real ``cosim node`` process on a udp_multicast bus. The three-tank run includes the LPV design of
IJC 2018 Theorem 1 (about 100 s on a fresh design cache, shared with the other tests of a session).
"""

from __future__ import annotations

import json
import subprocess
import sys
import time

import numpy as np
import pytest

import estimators.reconciliation
from cosim import scenario
from cosim.analysis.summary import summarize
from cosim.bus.transport import allocate, open_bus
from cosim.cli import main
from cosim.errors import CosimError
from cosim.log.reader import LogReader
from cosim.log.recorder import FRAMES
from cosim.run import run
from cosim.run.replay import TRUTH, Replay, parse_params, settings_as_params
from cosim.scenario import LoadedScenario, Scenario
from tests.frame_digests import unsigned
from tests.snippets import masses_pid

#: (built-in scenario, duration [s], factor dividing every fault's start and end)
SHORT = {
    "masses-faults-fd": (2.0, 10.0),  # drift, gain, stuck, dropout (from 1 s), outliers, actuator loss
    "tac2024-s1-timevarying": (1.0, 1.0),
    "cdc2016-ex2": (2.0, 85.0),  # the fault at 1 s, with noisy outputs
    "uio-fault-detection": (3.5, 10.0),  # sensor fault on y2 in [1, 2) s, actuator fault from 3 s
    "three-tank-reconciliation": (50.0, 10.0),  # bias from 20 s, gain faults from 40 s
    "vessel-fault-T2-T5": (8.0, 10.0),  # closed loop, cluster family: T2 and T5 fade from 2 s
}
#: One estimator of every kind: (scenario, estimator name, kind).
KINDS = [
    ("masses-faults-fd", "uniform", "pseudoinverse"),
    ("masses-faults-fd", "kalman", "kalman"),
    ("tac2024-s1-timevarying", "adaptive", "adaptive"),
    ("tac2024-s1-timevarying", "injection_filtered", "injection"),
    ("cdc2016-ex2", "L2_k1", "adaptive-ct"),
    ("uio-fault-detection", "uio", "uio"),
    ("three-tank-reconciliation", "lpv", "lpv-uio-sr"),
    ("three-tank-reconciliation", "lft", "lft-uio-sr"),
    ("three-tank-reconciliation", "raw", "no-reconciliation"),
    ("vessel-fault-T2-T5", "fdi", "cofd"),
]


def compressed(name: str) -> LoadedScenario:
    duration, factor = SHORT[name]
    loaded = scenario.load(name)
    data = loaded.scenario.model_dump()
    data["duration"] = duration
    for fault in data["faults"]:
        fault["start"] /= factor
        fault["end"] /= factor
    return LoadedScenario(Scenario.model_validate(data), f"{name} (compressed to {duration:g} s)", loaded.text)


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """The log of each compressed scenario, run once on first use."""
    folder = tmp_path_factory.mktemp("originals")
    made = {}

    def log(name: str):
        if name not in made:
            result = run(compressed(name), folder / f"{name}.mcap", interface="virtual")
            assert result.status == "completed" and result.frames_lost == 0
            made[name] = result.path
        return made[name]

    return log


def frames(path, keep) -> list[tuple]:
    with LogReader(path) as reader:
        return [
            (m["tick"], m["id"], m["dlc"], unsigned(m["id"], m["data"]))
            for _, _, m in reader.messages([FRAMES])
            if keep(m)
        ]


def topics(path, names) -> dict[str, list]:
    found: dict[str, list] = {name: [] for name in names}
    with LogReader(path) as reader:
        for topic, log_time, message in reader.messages(list(names)):
            found[topic].append((log_time, message))
    return found


def estimates(path, name: str) -> list[tuple]:
    """The decoded values of an estimator's messages, tick by tick (its messages in id order)."""
    with LogReader(path) as reader:
        messages = json.loads(reader.metadata()["cosim.run"]["estimators"])[name]["messages"]
    found = topics(path, [f"/can/{m}" for m in messages])
    return list(zip(*(found[f"/can/{m}"] for m in messages)))


def runner_frames(m) -> bool:
    """What replay sends for the original run: the runner's and, closed loop, the controller's frames
    of every tick (not the controller's boot-up and stopped heartbeats: replay has no such node)."""
    lifecycle = m["message"] == "HEARTBEAT_controller" and not m["data"].startswith("05")
    return m["sender"] in ("runner", "plant", "controller") and m["message"] != "NMT" and not lifecycle


@pytest.mark.slow
@pytest.mark.parametrize("name, estimator, kind", KINDS, ids=[k for _, _, k in KINDS])
def test_replaying_an_estimator_of_the_run_reproduces_its_frames_bit_for_bit(logs, tmp_path, name, estimator, kind):
    original = logs(name)
    replay = Replay(original, tmp_path / "replay.mcap", estimator)
    assert replay.kind == kind
    result = replay.execute()
    assert result.status == "completed" and result.frames_lost == 0, result.error
    mine = frames(original, lambda m: m["sender"] == estimator)
    assert len(mine) > result.ticks  # its estimate frames and heartbeats of every tick
    assert frames(result.path, lambda m: m["sender"] == estimator) == mine
    assert frames(result.path, runner_frames) == frames(original, runner_frames)
    assert topics(result.path, TRUTH) == topics(original, TRUTH)
    messages = [
        f"/can/{m}"
        for m in json.loads(LogReader(original).metadata()["cosim.run"]["estimators"])[estimator]["messages"]
    ]
    assert topics(result.path, messages) == topics(original, messages)
    with LogReader(result.path) as reader:
        meta = reader.metadata()
    assert json.loads(meta["cosim.run"]["estimators"]).keys() == {estimator}
    assert meta["cosim.replay"]["log"] == str(original) and meta["cosim.replay"]["estimator"] == estimator
    assert json.loads(meta["cosim.replay"]["new"]) is False


CLOSED_LOOP = masses_pid("masses-pid-short", duration=2.0, seed=0, fault_start=1.0)


def test_in_a_closed_loop_the_controller_frames_are_replayed_and_the_estimator_matches(tmp_path):
    """The estimator reads the controller node's commands (upstream, lag 0): the replay sends them as
    logged, after each tick's sensor frames, with the controller's heartbeat."""
    path = tmp_path / "pid.toml"
    path.write_text(CLOSED_LOOP)
    original = run(scenario.load(path), tmp_path / "pid.mcap", interface="virtual").path
    result = Replay(original, tmp_path / "replay.mcap", "kf").execute()
    assert result.status == "completed" and result.frames_lost == 0, result.error
    assert frames(result.path, lambda m: m["sender"] == "kf") == frames(original, lambda m: m["sender"] == "kf")
    bootup = lambda m: m["message"] == "HEARTBEAT_controller" and m["data"][:2] == "00"  # noqa: E731
    controller = frames(original, lambda m: m["sender"] == "controller" and not bootup(m))
    commands = [f for f in controller if f[1] == 0x180]
    heartbeats = [f for f in controller if f[1] >= 0x700]
    assert len(commands) == len(heartbeats) == result.ticks  # COMMAND_force and the heartbeat closing each tick
    assert frames(result.path, lambda m: m["sender"] == "controller") == controller
    with pytest.raises(CosimError, match="closed-loop"):
        Replay(original, tmp_path / "new.mcap", "kf2", kind="kalman")


def test_frames_a_dropout_kept_off_the_bus_are_not_replayed(logs, tmp_path):
    """masses-faults-fd drops 20 % of the range_x2 frames from 1 s (compressed): the replay sends the
    same, fewer, frames, and the estimator sees the same gaps (its frames match, test above)."""
    original = logs("masses-faults-fd")
    result = Replay(original, tmp_path / "replay.mcap", "kalman").execute()
    with LogReader(original) as reader:
        dropped = sum(len(m["dropped"]) for _, _, m in reader.messages(["/truth/faults"]))
    sent = [f for f in frames(result.path, runner_frames) if f[1] >= 0x100 and f[1] < 0x180]
    assert dropped > 0
    assert len(sent) == result.ticks * 4 - dropped  # four sensors per tick, minus the dropped frames


@pytest.mark.slow
def test_the_lpv_design_is_taken_from_the_log_not_solved_again(logs, tmp_path, monkeypatch):
    original = logs("three-tank-reconciliation")

    def refuse(*args, **kwargs):
        raise AssertionError("the replay solved the LMI design again")

    monkeypatch.setattr(estimators.reconciliation, "lpv_uio_design", refuse)
    replay = Replay(original, tmp_path / "replay.mcap", "lpv")
    assert {"G", "Y"} <= replay.node_spec("lpv", allocate("virtual")).params.keys()


def test_changed_parameters_change_the_estimates_and_are_recorded(logs, tmp_path):
    original = logs("masses-faults-fd")
    index = [e.name for e in scenario.load("masses-faults-fd").scenario.estimators].index("kalman")
    result = Replay(
        original, tmp_path / "kf.mcap", "kalman", settings=[(f"estimators[{index}].params.measurement_std", 0.05)]
    ).execute()
    assert result.status == "completed"
    before, after = estimates(original, "kalman"), estimates(result.path, "kalman")
    assert len(after) == len(before) == result.ticks and after != before
    with LogReader(result.path) as reader:
        meta = reader.metadata()
    assert json.loads(meta["cosim.replay"]["params"]) == {"measurement_std": 0.05}
    assert json.loads(meta["cosim.run"]["estimators"])["kalman"]["params"]["measurement_std"] == 0.05


@pytest.mark.slow
def test_a_new_estimator_is_designed_on_the_logged_model_and_scored(logs, tmp_path):
    original = logs("uio-fault-detection")
    result = Replay(
        original, tmp_path / "new.mcap", "kf2", kind="kalman", params={"measurement_std": 0.01, "process_std": 0.01}
    ).execute()
    assert result.status == "completed" and result.frames_lost == 0
    # The same kind and parameters as the run's kalman, under another name (other ids): the same values.
    replayed, logged = estimates(result.path, "kf2"), estimates(original, "kalman")
    assert len(replayed) == result.ticks and replayed == logged
    report = summarize(result.path)
    assert report["estimators"]["kf2"]["kind"] == "kalman"
    assert report["estimators"]["kf2"]["rms_pre_fault"] == pytest.approx(
        summarize(original)["estimators"]["kalman"]["rms_pre_fault"]
    )


@pytest.mark.slow
def test_the_cli_replays_and_refuses_bad_requests_with_one_message(logs, tmp_path, capsys):
    original = str(logs("masses-faults-fd"))
    out = tmp_path / "cli.mcap"
    assert main(["replay", original, "--estimator", "uniform", "--out", str(out), "-q"]) == 0
    assert frames(out, lambda m: m["sender"] == "uniform") == frames(original, lambda m: m["sender"] == "uniform")
    capsys.readouterr()
    cases = {
        ("--estimator", "nope"): "--estimator nope: the run has no estimator of that name (it has: uniform, kalman)",
        (
            "--estimator",
            "kalman",
            "--kind",
            "kalman",
        ): "--estimator kalman: the run already has an estimator of that name",
        ("--estimator", "k", "--kind", "kalmann"): "--kind kalmann: unknown estimator kind",
        ("--estimator", "kalman", "--param", "measurement_std=abc"): "--param measurement_std: expected a number",
        ("--estimator", "kalman", "--param", "noise"): "--param 'noise': expected KEY=VALUE",
        ("--estimator", "kalman", "--speed", "2"): "--speed: only with --live",
        ("--estimator", "kalman", "--set", "faults[0].value=2.0"): "to change faults, simulate again",
        ("--live", "--set", "duration=1"): "--set: not with --live",
        ("--live", "--estimator", "kalman"): "--estimator: not with --live",
        ("--estimator", "kalman", "--out", original): "that is the log being replayed",
    }
    for args, message in cases.items():
        out = [] if "--live" in args or "--out" in args else ["--out", str(tmp_path / "bad.mcap")]
        assert main(["replay", original, *args, *out]) == 1
        err = capsys.readouterr().err
        assert message in " ".join(err.split()), (args, err)
        assert "Traceback" not in err


def test_a_replay_honours_the_set_paths_of_its_estimator_and_refuses_the_rest():
    original = scenario.load("masses-faults-fd").scenario
    names = [e.name for e in original.estimators]
    i = names.index("kalman")
    assert settings_as_params([(f"estimators[{i}].params.measurement_std", 0.05)], original, "kalman", None) == {
        "measurement_std": 0.05
    }
    refused = {
        "faults[0].value": "only the replayed estimator's parameters can change (estimators[i].params.NAME); to "
        "change faults, simulate again with 'cosim run SCENARIO --set faults[0].value=...'",
        "duration": "to change duration, simulate again",
        "estimators": "to change estimators, simulate again",
        f"estimators[{1 - i}].params.x": f"the run's estimators[{1 - i}] is {names[1 - i]}, and the replay runs kalman",
        "estimators[7].params.x": "the run has 2 estimators",
        f"estimators[{i}].kind": "a new kind is --estimator NEWNAME --kind KIND",
        f"estimators[{i}].params.a.b": f"only estimators[{i}].params.NAME can change",
    }
    for key, message in refused.items():
        with pytest.raises(CosimError) as error:
            settings_as_params([(key, 1)], original, "kalman", None)
        assert message in str(error.value), key
    with pytest.raises(CosimError, match="the replay runs a new estimator"):
        settings_as_params([(f"estimators[{i}].params.x", 1)], original, "kf2", "kalman")


def test_parameters_are_toml_values():
    assert parse_params(["a=0.5", "b=[1, 2]", 'c="x"', "d=true", "e=word"]) == {
        "a": 0.5,
        "b": [1, 2],
        "c": "x",
        "d": True,
        "e": "word",
    }


@pytest.mark.slow
def test_live_playback_reaches_a_python_can_receiver_on_time(logs, tmp_path):
    """Every frame of the log, in order and unchanged, with the log's timing at 2x: a frame of
    simulated time t arrives t/2 s after the first one, within a few ms."""
    original = logs("masses-faults-fd")
    with LogReader(original) as reader:
        logged = [(t / 1e9, m) for _, t, m in reader.messages([FRAMES])]
    speed = 2.0
    bus = allocate("udp_multicast")
    received = []
    with open_bus(bus) as receiver:
        player = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "cosim.cli",
                "replay",
                str(original),
                "--live",
                "--speed",
                str(speed),
                "--channel",
                bus.channel,
                "--port",
                str(bus.port),
            ],
            stderr=subprocess.PIPE,
            text=True,
        )
        deadline = time.monotonic() + 30
        while len(received) < len(logged) and time.monotonic() < deadline:
            frame = receiver.recv(0.5)
            if frame is not None:
                received.append((frame.timestamp, frame))  # the kernel's receive time (SO_TIMESTAMPNS)
        assert player.wait(30) == 0, player.stderr.read()
    assert [(f.arbitration_id, f.data.hex(), f.is_fd) for _, f in received] == [
        (m["id"], m["data"], m["fd"]) for _, m in logged
    ]
    arrival = np.array([t for t, _ in received]) - received[0][0]
    due = (np.array([t for t, _ in logged]) - logged[0][0]) / speed
    late = arrival - due
    print(
        f"lateness: median {np.median(late) * 1e3:.2f} ms, 90 % {np.quantile(late, 0.9) * 1e3:.2f} ms, "
        f"max {late.max() * 1e3:.2f} ms, min {late.min() * 1e3:.2f} ms"
    )
    assert due[-1] == pytest.approx(1.0)  # 2 s of simulated time
    assert late.min() > -0.002  # never ahead of time
    assert np.median(late) < 0.005 and np.quantile(late, 0.9) < 0.02
    assert late.max() < 0.5  # a loaded machine may hold a frame back; the schedule is absolute, it never drifts
