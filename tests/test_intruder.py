"""Frames nobody in the run sent: a plain python-can program joins a running co-simulation, sends
100 frames with a sensor's id, and cosim inspect counts 100 foreign frames for that id."""

from __future__ import annotations

import json
import subprocess
import sys
import time

import can
import pytest

from cosim.bus import registry
from cosim.bus.transport import BusConfig

pytestmark = pytest.mark.slow

SENSOR_X2 = 0x101  # SENSOR_x2 of masses-bias


def test_a_python_can_intruder_is_seen_frame_by_frame(tmp_path):
    out = tmp_path / "intruded.mcap"
    runner = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "cosim.cli",
            "run",
            "--out",
            str(out),
            "-q",
            "--mode",
            "realtime",
            "--set",
            "duration=8",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 60
        info = None
        while time.monotonic() < deadline and info is None:
            running = registry.active()
            info = next((entry for entry in running if entry.get("scenario") == "masses-bias"), None)
            time.sleep(0.1)
        assert info is not None, "the run did not register"
        kwargs = BusConfig.from_dict(info["bus"]).kwargs()
        with can.Bus(**kwargs) as intruder:  # what a new user would type
            # past tick 0 (a SYNC has gone by): before it, a frame on the runner's ids refuses the run
            while (frame := intruder.recv(30)) is not None and frame.arbitration_id != 0x080:
                pass
            for i in range(100):
                intruder.send(
                    can.Message(arbitration_id=SENSOR_X2, is_extended_id=False, data=bytes([0xA5, i, 0, 0, 0]))
                )
                time.sleep(0.01)
        assert runner.wait(60) == 0, runner.stderr.read()
    finally:
        if runner.poll() is None:
            runner.kill()
    inspect = subprocess.run(
        [sys.executable, "-m", "cosim.cli", "inspect", str(out), "--json"], capture_output=True, text=True, check=True
    )
    bus = json.loads(inspect.stdout)["bus"]
    assert bus["foreign_frames"] == {"0x101": 100}
