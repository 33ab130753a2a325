"""cosim plot draws the paper-style figures of a log."""

from __future__ import annotations

from pathlib import Path

import pytest

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
    from cosim.analysis.plot import plot
    from cosim.analysis.series import load as load_series
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


@pytest.mark.slow
def test_figures_come_as_png_svg_or_pdf_with_units_named_legends_and_nothing_cut(tmp_path: Path, capsys):
    import matplotlib.image
    import numpy as np

    from cosim.scenario import LoadedScenario

    log = tmp_path / "run.mcap"
    scenario = load("masses-bias").scenario.model_copy(update={"duration": 6.0})
    Run(LoadedScenario(scenario, "masses-bias (6 s)", ""), log, interface="virtual").execute()
    for fmt in ("svg", "pdf"):
        assert main(["plot", str(log), "--out", str(tmp_path / fmt), "--format", fmt]) == 0
    written = {Path(line).name for line in capsys.readouterr().out.split()}
    names = ("estimates", "state_errors", "error", "faults", "bias_effect")
    assert written == {f"{n}.{fmt}" for n in names for fmt in ("svg", "pdf")}
    assert all((tmp_path / "pdf" / f"{n}.pdf").read_bytes().startswith(b"%PDF") for n in names)
    svg = (tmp_path / "svg" / "estimates.svg").read_text()  # text stays text: readable, searchable
    for label in (
        "x1 [m]",
        "v2 [m/s]",
        "time t [s]",
        "uniform (pseudoinverse): x̂",
        "kalman: x̂",  # an estimator named after its kind is not named twice
        "true state x",
    ):
        assert label in svg, label
    assert "kalman (kalman)" not in svg
    assert "|x − x̂| (mixes m, m/s)" in (tmp_path / "svg" / "error.svg").read_text()
    assert "faults.fault.x1_minus_x2" in (tmp_path / "svg" / "faults.svg").read_text()
    assert "CreationDate" not in (tmp_path / "pdf" / "error.pdf").read_bytes().decode("latin-1")  # reproducible

    widths = {}
    for dpi in (100, 200):
        assert main(["plot", str(log), "--out", str(tmp_path / f"png{dpi}"), "--dpi", str(dpi)]) == 0
        pixels = matplotlib.image.imread(tmp_path / f"png{dpi}" / "estimates.png")
        widths[dpi] = pixels.shape[1]
        edge = np.concatenate(
            [
                pixels[:3].reshape(-1, 4),
                pixels[-3:].reshape(-1, 4),
                pixels[:, :3].reshape(-1, 4),
                pixels[:, -3:].reshape(-1, 4),
            ]
        )
        assert np.all(edge[:, :3] > 0.99)  # a white margin all round: nothing drawn is cut at the edge
    assert abs(widths[200] / widths[100] - 2) < 0.02


def test_a_closed_loop_without_reconfiguration_does_not_promise_one(tmp_path: Path):
    from cosim.analysis.plot import plot
    from cosim.scenario import LoadedScenario

    log = tmp_path / "vessel.mcap"
    scenario = load("vessel-nominal").scenario.model_copy(update={"duration": 3.0})
    Run(LoadedScenario(scenario, "vessel-nominal (3 s)", ""), log, interface="virtual").execute()
    written = {p.name: p for p in plot(log, tmp_path / "figs", fmt="svg")}
    trajectory = written["trajectory.svg"].read_text()
    assert "reconfigur" not in trajectory and "fault" not in trajectory  # it has neither
    for label in ("x [m]", "psi [rad]", "y_dot [m/s]", "r [rad/s]"):
        assert label in trajectory, label
    path = written["path.svg"].read_text()  # the planar plant's path: y against x
    for label in ("x [m]", "y [m]", "true path", "y against x"):
        assert label in path, label


def test_log_axes_span_six_decades_and_linear_axes_carry_no_offset():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from cosim.analysis.plot import STYLE, log_floor

    with plt.rc_context(STYLE):
        fig, (log, linear) = plt.subplots(2)
        values = np.array([2.0, 1e-3, 1e-16, 0.0])  # a rejected fault's effect falls to rounding
        log.semilogy(range(4), values)
        log_floor(log, [values])
        assert log.get_ylim() == (2e-6, 4.0)
        linear.plot([0, 1], [1.00031, 1.00032])  # |Γ| near 1: matplotlib would write "+1" and 0.00031
        fig.canvas.draw()
        assert linear.yaxis.get_major_formatter().get_offset() == ""
        assert any(label.get_text().startswith("1.000") for label in linear.get_yticklabels())
        plt.close(fig)
