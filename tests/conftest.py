"""Shared fixtures: the default scenario and the built-in scenarios, each run once per session."""

from __future__ import annotations

import locale
import os
from pathlib import Path

import pytest

from cosim import scenario
from cosim.run import run

ROOT = Path(__file__).resolve().parent.parent

#: The files that read the built-in scenarios' node-process runs (``builtin_run``, minutes each):
#: on one worker, so that each run is made once.
BUILTIN_RUN_READERS = ("test_fmu_export.py", "test_frame_digests.py", "test_reproductions.py")


#: Tests that measure the wall clock or the kernel's socket buffers (paced runs, floods, bursts, the
#: benchmarks): marked ``serial``, which CI runs after the others, alone on the machine.
SERIAL = (
    "test_bench.py",
    "test_udp_bursts.py",
    "test_cosim.py::test_realtime_mode_paces_ticks_and_counts_deadline_misses",
    "test_cosim.py::test_monitor_writes_a_line_per_message_into_a_pipe_until_the_run_stops",
    "test_hostile_datagrams.py::test_the_datagrams_the_kernel_drops_in_a_flood_are_counted",
    "test_hostile_datagrams.py::test_a_flood_is_named_as_the_cause_of_a_failure_and_a_trickle_is_not",
    "test_reliability.py::test_a_flood_of_100_000_frames_per_second_is_survived_and_every_loss_is_the_kernels",
    "test_reliability.py::test_realtime_losses_are_counted_per_sender",
    "test_reliability.py::test_a_run_ends_while_another_program_transmits_without_pause",
    "test_run.py::test_a_realtime_run_that_cannot_keep_up_says_so",
    "test_run.py::test_a_wait_before_tick_0_does_not_count_in_the_real_time_factor",
    # a signal meant for the FMU's hanging call, sent 2 s after its host starts; an intruder that
    # must send while a 30 s lockstep run lasts: on a loaded machine both come too early or too late
    "test_fmu_failures.py::test_a_signal_while_the_plan_is_made_is_one_line_and_ends_the_fmus_process",
    "test_intruder.py::test_with_authentication_an_intruder_changes_no_estimate",
)


def pytest_collection_modifyitems(items):
    """CI runs the suite in two parts (README): ``-n 2 --dist loadgroup -m "not serial"`` with
    pytest-xdist, where a file's tests run on one worker (its module fixtures are made once) and the
    files of ``BUILTIN_RUN_READERS`` on one; then ``-m serial``, one test at a time."""
    for item in items:
        name = item.path.name
        item.add_marker(pytest.mark.xdist_group("builtin_runs" if name in BUILTIN_RUN_READERS else name))
        test = f"{name}::{item.originalname}"
        if name in SERIAL or test in SERIAL:
            item.add_marker(pytest.mark.serial)


@pytest.fixture(scope="session", autouse=True)
def design_cache_dir(tmp_path_factory):
    """A fresh design cache per test session: no test depends on an earlier run's designs."""
    folder = tmp_path_factory.mktemp("designs")
    previous = os.environ.get("COSIM_CACHE_DIR")
    os.environ["COSIM_CACHE_DIR"] = str(folder)
    yield folder
    if previous is None:
        os.environ.pop("COSIM_CACHE_DIR", None)
    else:
        os.environ["COSIM_CACHE_DIR"] = previous


@pytest.fixture(autouse=True)
def locale_kept():
    """Tests that load an FMU with FMPy in this process (its reference runs) must not leave the
    locale an FMU's runtime set (Dymola's sets C: Python's default text encoding becomes ASCII)."""
    kept = locale.setlocale(locale.LC_ALL)
    yield
    if locale.setlocale(locale.LC_ALL) != kept:
        locale.setlocale(locale.LC_ALL, kept)


@pytest.fixture(scope="session")
def default_loaded():
    return scenario.load()


@pytest.fixture(scope="session")
def default_run(tmp_path_factory, default_loaded):
    """The default scenario, run once; its log is shared by the end-to-end tests."""
    out = tmp_path_factory.mktemp("run") / "default.mcap"
    result = run(default_loaded, out)
    return result


@pytest.fixture(scope="session")
def builtin_run(tmp_path_factory):
    """A built-in scenario at seed 0 on its own bus (node processes over udp_multicast unless it says
    otherwise), run once per session: the frame digests and the reproductions of the papers read the
    same log."""
    runs = {}

    def get(name: str):
        if name not in runs:
            out = tmp_path_factory.mktemp("builtin") / f"{name}.mcap"
            runs[name] = run(scenario.load(name), out, 0)
        return runs[name]

    return get
