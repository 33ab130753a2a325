"""``cosim monitor --dbc`` on a bus, started as from a terminal and stopped as Ctrl-C stops it
(tests/test_cosim.py, tests/test_foreign_dbc.py)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

from cosim.bus.transport import BusConfig
from tests.conftest import ROOT


def start_monitor(dbc: Path, config: BusConfig) -> subprocess.Popen:
    """The monitor decoding the bus of ``config`` with ``dbc``: 200 columns wide, and taking SIGINT
    as a terminal's foreground job does (not ignoring it, as a background job would)."""
    return subprocess.Popen(
        [sys.executable, "-m", "cosim.cli", "monitor", "--dbc", str(dbc), "--channel", config.channel]
        + ["--port", str(config.port)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT), "COLUMNS": "200"},
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )


def stop_monitor(monitor: subprocess.Popen) -> tuple[str, str]:
    """Ctrl-C: what the monitor printed (stdout, stderr), once it has ended without an error."""
    monitor.send_signal(signal.SIGINT)
    out, err = monitor.communicate(timeout=30)
    assert monitor.returncode == 0, err
    return out, err
