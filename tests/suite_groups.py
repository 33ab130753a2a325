"""How the suite is split for CI: the groups of tests that share a worker under pytest-xdist, and the
tests that run alone after the others (``serial``). ``tests/conftest.py`` marks every test with them
at collection; ``tests/test_suite_groups.py`` checks that pytest-xdist honours the groups."""

from __future__ import annotations

import pytest

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
    "test_intruder.py::test_a_python_can_intruder_is_seen_frame_by_frame_and_contests_its_ticks",
    # python-can's own timing test of send_periodic (100 ± 20 frames in 2 s), which python-can skips on CI
    "test_python_can_interfaces.py::test_cycle_time",
)


def mark(items: list[pytest.Item]) -> None:
    """CI runs the suite in two parts (README): ``-n 2 --dist loadgroup -m "not serial"`` with
    pytest-xdist, where a file's tests run on one worker (its module fixtures are made once) and the
    files of ``BUILTIN_RUN_READERS`` on one; then ``-m serial``, one test at a time
    (tests/test_suite_groups.py checks that the groups hold)."""
    for item in items:
        name = item.path.name
        item.add_marker(pytest.mark.xdist_group("builtin_runs" if name in BUILTIN_RUN_READERS else name))
        test = f"{name}::{item.originalname}"
        if name in SERIAL or test in SERIAL:
            item.add_marker(pytest.mark.serial)
