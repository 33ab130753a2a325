"""A process that ran one plant runs the next exactly as a fresh one would (docs/process-state.md).

Campaign workers, the test suite and notebooks run many scenarios in one Python process. Here a
campaign-style sequence of other runs (state-space plants, many estimators, a run interrupted by
Ctrl-C, one ended by an error, one over udp_multicast with node processes) comes first; then every
built-in plant's scenario, shortened, runs in orders that put each plant after each other one and
the vessel after itself. Each run's participant frames must be bit-identical to the same run in a
fresh process (``python -m tests.test_process_state NAME DURATION``, which computes every design
itself where the runs here read the design cache), and after each run the process state the audit
lists must be what it was before.
"""

from __future__ import annotations

import json
import os
import random
import re
import signal
import subprocess
import sys
import threading
import warnings
from pathlib import Path
from typing import Any

import can.interfaces.virtual
import mujoco
import numpy as np
import pytest

import mjcf
from cosim import scenario
from cosim.bus import registry
from cosim.plant.physics import Plant
from cosim.run import Run, run
from tests.conftest import ROOT
from tests.frame_digests import log_digest

#: The built-in plants' scenarios, shortened: the vessel past its fault's onset (20 s), the
#: three-tank past its bias (200 s); everything else as the files say.
PLANT_RUNS = {
    "vessel": ("vessel-fault-T1", 25.0),
    "masses": ("masses-bias", 2.0),
    "three-tank": ("three-tank-reconciliation", 220.0),
}
#: Every ordered pair of plants appears in one of these, and the vessel after itself.
ORDERS = {
    "vessel-masses-tank-vessel": ("vessel", "masses", "three-tank", "vessel"),
    "masses-vessel-vessel-tank-masses": ("masses", "vessel", "vessel", "three-tank", "masses"),
}
CALLBACKS = ("passive", "control", "act_dyn", "act_gain", "act_bias", "sensor", "time", "contactfilter")


def shortened(name: str, duration: float) -> scenario.LoadedScenario:
    """A built-in scenario with another duration (everything else as the file says)."""
    loaded = scenario.load(name)
    text = re.sub(r"(?m)^duration\s*=.*$", f"duration = {duration!r}", loaded.text, count=1)
    return scenario.LoadedScenario(scenario.parse(text, loaded.source), loaded.source, text)


def run_digest(name: str, duration: float, out: Path, **overrides: Any) -> tuple[str, int]:
    result = run(shortened(name, duration), out, 0, **overrides)
    assert result.status == "completed", (name, result.status, result.error)
    return log_digest(out)


def fresh_digest(name: str, duration: float) -> tuple[str, int]:
    """The digest of the run in a new Python process without the design cache (every design
    computed there; the runs in this process take theirs from the session's cache)."""
    child = subprocess.run(
        [sys.executable, "-m", "tests.test_process_state", name, repr(duration)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=600,
        env={**os.environ, "COSIM_CACHE_DIR": "off"},
    )
    assert child.returncode == 0, child.stderr
    digest, count = json.loads(child.stdout)
    return digest, count


def _children() -> set[int]:
    pids: set[int] = set()
    for task in Path("/proc/self/task").iterdir():
        pids |= {int(pid) for pid in (task / "children").read_text().split()}
    return pids


def process_state() -> dict[str, Any]:
    """What the audit (docs/process-state.md) lists, as far as a test can see it."""
    fds = {}
    for fd in os.listdir("/proc/self/fd"):
        try:
            fds[fd] = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:  # the directory listing's own descriptor, closed by now
            pass
    return {
        "mujoco callbacks": {name: getattr(mujoco, f"get_mjcb_{name}")() for name in CALLBACKS},
        "numpy error state": np.geterr(),
        "numpy print options": np.get_printoptions(),
        "numpy global random state": np.random.get_state()[1].tobytes(),
        "python random state": random.getstate(),
        "signal handlers": {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)},
        "environment": {k: v for k, v in os.environ.items() if k != "PYTEST_CURRENT_TEST"},  # pytest's phase
        "warning filters": list(warnings.filters),
        "working directory": os.getcwd(),
        "open files and sockets": fds,
        "threads": sorted(t.name for t in threading.enumerate()),
        "child processes": _children(),
        "run registry (this process)": [e.name for e in registry.directory().glob("*.json") if _ours(e)],
        "virtual bus channels": sorted(can.interfaces.virtual.channels),
    }


def _ours(entry: Path) -> bool:
    try:
        return json.loads(entry.read_text()).get("pid") == os.getpid()
    except (OSError, ValueError):
        return False


def assert_state_is(before: dict[str, Any], after_what: str) -> None:
    after = process_state()
    changed = {key: (before[key], after[key]) for key in before if before[key] != after[key]}
    assert not changed, f"after {after_what}, process state changed: {changed}"


@pytest.fixture(scope="module")
def campaign(tmp_path_factory) -> dict[str, Any]:
    """A campaign-style sequence of other runs in this process, each leaving the process state as
    it found it; returns that state."""
    folder = tmp_path_factory.mktemp("campaign")
    Plant(mjcf.get("vessel"), 0.1)  # imports done, nothing run
    state = process_state()

    runs: list[tuple[str, float, str, BaseException | None, str]] = [
        ("uio-fault-detection", 15.0, "virtual", None, "completed"),
        ("cdc2016-ex1", 8.0, "virtual", None, "completed"),  # six estimators
        ("vessel-reconfiguration", 30.0, "virtual", KeyboardInterrupt(), "interrupted"),  # Ctrl-C at tick 100
        ("three-tank-reconciliation", 300.0, "virtual", RuntimeError("a failing run"), "error"),  # at tick 100
        ("masses-bias", 1.0, "udp_multicast", None, "completed"),  # node processes and sockets
    ]
    for i, (name, duration, interface, stop, status) in enumerate(runs):

        def on_progress(progress, stop=stop) -> None:
            if stop is not None and progress.tick == 100:
                raise stop

        job = Run(shortened(name, duration), folder / f"{i}-{name}.mcap", 0, interface=interface)
        try:
            job.execute(on_progress, progress_every=0.0)
        except (KeyboardInterrupt, RuntimeError) as error:
            assert error is stop, error
        assert job.result is not None and job.result.status == status, (name, job.result)
        assert_state_is(state, f"the campaign's run of {name} ({status})")
    return state


@pytest.fixture(scope="module")
def fresh() -> dict[str, tuple[str, int]]:
    return {plant: fresh_digest(*PLANT_RUNS[plant]) for plant in PLANT_RUNS}


def test_plants_leave_no_process_state_behind():
    """Loading, resetting, stepping and linearizing every built-in plant changes nothing."""
    state = process_state()
    for name in mjcf.PLANTS:
        plant = Plant(mjcf.get(name), 1.0)
        plant.reset(keyframe=plant.info.design_keyframe or None)
        plant.linearize()
        plant.step(plant.data.ctrl[plant.actuator_index].copy())
        assert_state_is(state, f"the {name} plant's calls")


def test_a_run_that_cannot_start_leaves_nothing_behind(monkeypatch, tmp_path):
    """The session undoes what it had entered when a later part fails (here: no run registry):
    the signal handlers, the log file, the bus."""
    monkeypatch.setenv("COSIM_RUNTIME_DIR", str(tmp_path / "not-a-directory"))
    (tmp_path / "not-a-directory").write_text("")
    state = process_state()
    with pytest.raises(OSError):
        run(shortened("masses-bias", 0.1), tmp_path / "run.mcap", 0, interface="virtual")
    assert_state_is(state, "a run whose session could not start")


@pytest.mark.slow
@pytest.mark.parametrize("order", sorted(ORDERS))
def test_each_plant_runs_as_in_a_fresh_process_in_any_order(order, campaign, fresh, tmp_path):
    for i, plant in enumerate(ORDERS[order]):
        name, duration = PLANT_RUNS[plant]
        digest = run_digest(name, duration, tmp_path / f"{i}-{name}.mcap", interface="virtual")
        assert digest == fresh[plant], f"{order}: run {i} ({name}) differs from its run in a fresh process"
        assert_state_is(campaign, f"{order}: run {i} ({name})")


if __name__ == "__main__":  # the fresh process of fresh_digest: one run, its digest as JSON
    import tempfile

    with tempfile.TemporaryDirectory() as scratch:
        print(json.dumps(run_digest(sys.argv[1], float(sys.argv[2]), Path(scratch) / "run.mcap", interface="virtual")))
