"""Frames nobody in the run sent: a plain python-can program joins a running co-simulation, sends
100 frames with a sensor's id, and cosim inspect counts 100 foreign frames for that id; with
authentication on, the estimators' inputs are unaffected."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import can
import pytest

from cosim.bus import registry
from cosim.bus.transport import BusConfig
from cosim.log.reader import LogReader

pytestmark = pytest.mark.slow

SENSOR_X2 = 0x101  # SENSOR_x2 of masses-bias


def intrude(out, scenario: str, *settings: str, length: int = 5, fd: bool = False, env=None, status: int = 0) -> dict:
    """Run ``scenario`` with node processes while a plain python-can program joins its bus after the
    first SYNC and sends 100 frames on SENSOR_x2's id; the run's ``cosim inspect --json`` (the run's
    exit status must be ``status``)."""
    command = [sys.executable, "-m", "cosim.cli", "run", scenario, "--out", str(out), "-q", *settings]
    runner = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        deadline = time.monotonic() + 60
        info = None
        while time.monotonic() < deadline and info is None:
            running = registry.active()
            info = next((entry for entry in running if entry.get("scenario") == scenario), None)
            time.sleep(0.1)
        assert info is not None, "the run did not register"
        kwargs = BusConfig.from_dict(info["bus"]).kwargs()
        with can.Bus(**kwargs) as intruder:  # what a new user would type
            # past tick 0 (a SYNC has gone by): before it, a frame on the runner's ids refuses the run
            while (frame := intruder.recv(30)) is not None and frame.arbitration_id != 0x080:
                pass
            for i in range(100):
                data = bytes([0xA5, i] + [0] * (length - 2))
                intruder.send(can.Message(arbitration_id=SENSOR_X2, is_extended_id=False, data=data, is_fd=fd))
                time.sleep(0.01)
        assert runner.wait(120) == status, runner.stderr.read()
    finally:
        if runner.poll() is None:
            runner.kill()
    inspect = subprocess.run(
        [sys.executable, "-m", "cosim.cli", "inspect", str(out), "--json"], capture_output=True, text=True, check=True
    )
    return json.loads(inspect.stdout)


def test_a_python_can_intruder_is_seen_frame_by_frame_and_contests_its_ticks(tmp_path):
    """Without authentication the intruder's frames may have been taken by the estimators: every tick
    it sent in is contested, and the run says so in its status line and its exit status (3)."""
    out = tmp_path / "intruded.mcap"
    summary = intrude(out, "masses-bias", "--mode", "realtime", "--set", "duration=8", status=3)
    assert summary["bus"]["foreign_frames"] == {"0x101": 100}
    assert 50 <= summary["contested_ticks"] <= 100, summary["contested_ticks"]
    inspect = subprocess.run([sys.executable, "-m", "cosim.cli", "inspect", str(out)], capture_output=True, text=True)
    assert f"status completed, {summary['contested_ticks']} contested ticks" in inspect.stdout


def test_with_authentication_an_intruder_changes_no_estimate(tmp_path):
    """SecOC on (CAN FD, a fixed run secret so that two runs sign alike): 100 forged SENSOR_x2 frames
    of the right length are foreign, rejected by every receiver, and the estimate frames are the
    clean run's bit for bit."""
    env = {**os.environ, "COSIM_RUN_SECRET": "5e" * 32}
    settings = ("--set", "faults=[]", "--set", "bus.authentication=secoc", "--set", "duration=30")
    intruded, clean = tmp_path / "intruded.mcap", tmp_path / "clean.mcap"
    summary = intrude(intruded, "masses-spoofing", *settings, length=16, fd=True, env=env)
    assert summary["bus"]["foreign_frames"] == {"0x101": 100} and summary["contested_ticks"] == 0
    assert (
        subprocess.run(
            [sys.executable, "-m", "cosim.cli", "run", "masses-spoofing", "--out", str(clean), "-q", *settings], env=env
        ).returncode
        == 0
    )

    def estimates(path):
        with LogReader(path) as reader:
            return [
                (m["tick"], m["id"], m["data"])
                for _, _, m in reader.messages(["/can/frames"])
                if m["message"].startswith("EST_")
            ]

    assert estimates(intruded) == estimates(clean) and len(estimates(clean)) > 0
