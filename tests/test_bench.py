"""The benchmark scripts keep working (tiny workloads; the figures themselves are in the README)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from tests.conftest import ROOT

#: Each starts a benchmark script (seconds each): the quick subset leaves them to CI.
pytestmark = pytest.mark.slow


def bench(script: str, *args: str) -> dict:
    result = subprocess.run(
        [sys.executable, str(ROOT / "bench" / script), "--json", *args],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=ROOT,
    )
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout)


def all_positive(figures: dict, keys: str) -> None:
    """Every figure named in ``keys`` (separated by spaces) is there and above 0."""
    for key in keys.split():
        assert figures[key] > 0, key


def test_codec_log_benchmark_reports_ratios_against_its_baselines():
    figures = bench("codec_log.py", "--frames", "500", "--repeat", "1")
    all_positive(
        figures,
        "codec_frames_per_s codec_baseline_frames_per_s codec_ratio logger_frames_per_s "
        "logger_baseline_frames_per_s logger_ratio run_wall_s run_realtime_factor",
    )


def test_cosim_throughput_benchmark_reports_its_figures():
    figures = bench("cosim_throughput.py", "--frames", "3000", "--repeat", "1")
    assert figures["raw_lost_frames"] == 0 and figures["lost_frames"] == 0
    all_positive(
        figures,
        "raw_frames_per_s pipeline_frames_per_s ratio realtime_factor node_startup_s "
        "inprocess_realtime_factor inprocess_run_realtime_factor floor_ticks_per_s floor_tick_us floor_ratio "
        "arithmetic_tick_us arithmetic_realtime_factor inprocess_over_arithmetic",
    )
    assert abs(figures["arithmetic_realtime_factor"] * figures["arithmetic_tick_us"] * 1e-6 - 0.01) < 1e-12  # τ
    assert figures["inprocess_over_arithmetic"] > 1  # the run does what the floor does, and more
    assert abs(figures["ratio"] - figures["pipeline_frames_per_s"] / figures["raw_frames_per_s"]) < 1e-9
    assert abs(figures["floor_ratio"] - figures["pipeline_ticks_per_s"] / figures["floor_ticks_per_s"]) < 1e-9
    assert set(figures["node_startup"]) == {"uniform", "kalman"} and figures["inprocess_lost_frames"] == 0


def test_tick_budget_reports_the_runner_and_each_node_per_phase():
    figures = bench("tick_budget.py", "--duration", "1", "--repeat", "1", "--udp-frames", "1000")
    budget = figures["us_per_tick"]
    assert set(budget) == {"runner", "node uniform", "node kalman"}
    assert {"mcap write", "mj_step", "encode", "decode", "bus send", "loop"} <= set(budget["runner"])
    assert {"step", "encode", "decode"} <= set(budget["node kalman"])
    total = sum(sum(phases.values()) for phases in budget.values())
    assert abs(total - figures["loop_us_per_tick"]) < 1e-6 * total  # the phases add up to the tick loop
    assert figures["udp_send_us_per_frame"] > 0 and figures["udp_recv_us_per_frame"] > 0


def test_estimator_step_benchmark_times_every_kind_against_kalman():
    figures = bench("estimator_step.py", "--steps", "300", "--repeat", "1")
    assert {
        "kalman",
        "kalman_as_plugin",
        "kalman_as_plugin_over_kalman",
        "residual_observer",
        "pseudoinverse",
        "injection",
        "adaptive",
        "adaptive-ct",
        "lft-uio-sr_eq53",
        "lft-uio-sr_model",
        "numpy_kalman",
        "kalman_over_numpy_kalman",
        "adaptive-ct_over_kalman",
    } <= set(figures)
    assert all(v > 0 for v in figures.values())
    assert abs(figures["kalman_over_numpy_kalman"] - figures["kalman"] / figures["numpy_kalman"]) < 0.01
    # each kind's batched step per run (32 instances), and its ratio to the single step
    assert figures["kalman_batched_32"] > 0 and figures["adaptive-ct_batched_over_single"] > 0


def test_lmi_design_benchmark_reports_its_figures():
    figures = bench("lmi_design.py", "--skip-lpv")
    assert figures["lft_design_s"] > 0 and figures["lti_design_s"] > 0
    assert figures["lft_diagonal_sigma"] <= figures["lft_sigma"] * (1 + 1e-6) and figures["lft_rho"] < 1


def test_log_io_benchmark_reports_write_inspect_and_export_ratios():
    figures = bench("log_io.py", "--seconds", "0.5", "--repeat", "1")
    all_positive(
        figures,
        "write_ratio inspect_ratio export_ratio write_frames_per_s bare_write_frames_per_s "
        "inspect_frames_per_s bare_read_frames_per_s export_mf4_frames_per_s",
    )
    assert abs(figures["write_ratio"] - figures["write_frames_per_s"] / figures["bare_write_frames_per_s"]) < 1e-9
    assert figures["export_ratio"] == min(
        figures[f"export_{f}_ratio"] for f in ("csv", "parquet", "blf", "mf4", "candump", "asc", "trc", "rosbag2")
    )


@pytest.mark.slow
def test_campaign_benchmark_reports_runs_per_hour_speedup_and_overhead():
    figures = bench("campaign.py", "--runs", "4", "--duration", "0.5", "--memory-runs", "20", "--logged", "1")
    assert figures["workers"] >= 1 and figures["runs_per_hour"] > 0 and figures["speedup"] > 0
    assert figures["overhead_per_run_s"] >= 0 and figures["identical"] is True, figures
    assert figures["batched_runs"] == figures["runs"] == 4 and figures["batch"] >= 2  # the default scenario batches
    assert figures["batch_speedup"] == pytest.approx(
        figures["runs_per_hour"] / figures["runs_per_hour_unbatched"], rel=0.01
    )
    assert figures["logged_run_s"] > 0 and figures["campaign_run_cost_s"] > 0
    cost = figures["campaign_run_cost_s"] / figures["logged_run_s"]
    assert figures["cost_over_logged_run"] == pytest.approx(cost, rel=0.01)


def test_vessel_fdi_figures_isolate_every_fault_on_the_linear_model():
    figures = bench("vessel_fdi.py")
    assert figures["zeta"] == pytest.approx([2.485, 5.524, 1.013], abs=1e-3)
    assert all(run["correct"] for run in figures["closed_loop"].values()), figures["closed_loop"]
    assert figures["largest_epsilon"]["T5"] < figures["largest_epsilon"]["T4"] < figures["largest_epsilon"]["T1"]


def test_plant_step_benchmark_times_both_damping_mechanisms_and_the_masses_after_the_vessel():
    figures = bench(
        "plant_step.py", "--ticks", "50", "--repeat", "1", "--masses-duration", "0.5", "--vessel-duration", "1"
    )
    all_positive(
        figures,
        "vessel_step_us vessel_step_global_us vessel_step_bare_us vessel_step_held_us "
        "vessel_step_ratio masses_fresh_s masses_fresh_first_s masses_after_vessel_s "
        "masses_after_vessel_ratio masses_old_global_s masses_old_global_ratio "
        "masses_each_us masses_batched_us masses_batched_ratio three_tank_each_us three_tank_batched_us "
        "three_tank_batched_ratio batch_runs",
    )
    assert figures["vessel_max_abs_diff"] == 0.0  # the scoped callback is the old physics, bit for bit
    assert figures["vessel_held_max_abs_diff"] > 1e-9  # a force held over the tick is not
    assert figures["vessel_ticks"] == 50 and figures["vessel_substeps"] == 10 and figures["masses_ticks"] == 50
