"""cosim plot draws the paper-style figures of a log."""

from __future__ import annotations

from pathlib import Path

from cosim.cli import main
from cosim.run import Run
from cosim.scenario import load


def test_plot_writes_the_figures_of_an_adaptive_run(tmp_path: Path, capsys):
    log = tmp_path / "run.mcap"
    scenario = load("tac2024-s2-p4").scenario.model_copy(update={"duration": 1.0})
    from cosim.scenario import LoadedScenario

    Run(LoadedScenario(scenario, "tac2024-s2-p4 (1 s)", ""), log, interface="virtual").execute()
    assert main(["plot", str(log), "--out", str(tmp_path / "figs")]) == 0
    written = {Path(line).name for line in capsys.readouterr().out.split()}
    assert {"error.png", "weights.png", "bias_effect.png", "bias_estimate.png"} <= written
    for name in written:
        assert (tmp_path / "figs" / name).stat().st_size > 10_000


def test_plot_draws_the_residual_of_an_unknown_input_observer(tmp_path: Path):
    from cosim.analysis.plot import load as load_series
    from cosim.analysis.plot import plot
    from cosim.scenario import LoadedScenario

    log = tmp_path / "uio.mcap"
    scenario = load("uio-fault-detection").scenario.model_copy(update={"duration": 10.5})
    Run(LoadedScenario(scenario, "uio-fault-detection (10.5 s)", ""), log, interface="virtual").execute()
    series = load_series(log)
    assert [(f["label"], f["start"], f["end"]) for f in series.faults] == [
        ("sensor_y2", 10.0, 20.0),
        ("actuator_u1", 30.0, None),
    ]
    written = {path.name: path for path in plot(log, tmp_path / "figs")}
    assert "residual.png" in written and written["residual.png"].stat().st_size > 10_000
