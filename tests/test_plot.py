"""cosim plot draws the paper-style figures of a log."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cosim.cli import main
from cosim.run import Run
from cosim.scenario import load


@pytest.fixture(scope="module")
def adaptive_log(tmp_path_factory) -> Path:
    """tac2024-s2-p4 for 1 s: three estimators, weights, bias estimates, |h_Γ|."""
    from cosim.scenario import LoadedScenario

    log = tmp_path_factory.mktemp("adaptive") / "run.mcap"
    scenario = load("tac2024-s2-p4").scenario.model_copy(update={"duration": 1.0})
    Run(LoadedScenario(scenario, "tac2024-s2-p4 (1 s)", ""), log, interface="virtual").execute()
    return log


def test_plot_writes_the_figures_of_an_adaptive_run(adaptive_log: Path, tmp_path: Path, capsys):
    log = adaptive_log
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
        "uniform (pseudoinverse)",
        "kalman",  # an estimator named after its kind is not named twice
        "true state x",
    ):
        assert label in svg, label
    assert "kalman (kalman)" not in svg
    assert "|x − x̂| (mixes m, m/s)" in (tmp_path / "svg" / "error.svg").read_text()
    faults = (tmp_path / "svg" / "faults.svg").read_text()  # each sensor with the faults on it, as named
    assert "x1_minus_x2: bias" in faults and "faults.fault" not in faults
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

    from cosim.analysis.canvas import Style, log_floor

    with plt.rc_context(Style.of().rc):
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


@pytest.mark.parametrize("style", ["screen", "paper"])
def test_seven_series_on_top_of_each_other_all_stay_in_sight_and_the_legend_off_the_data(tmp_path, style):
    """Seven schemes that agree draw the same curve: each keeps its colour, dashes and marker in
    sight (markers staggered, dash gaps showing the curves under them), and the legend sits under
    the panel, not on it. (Drawn the old way, in colour alone, only the last curve showed.)"""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from cosim.analysis.canvas import PALETTE, Canvas, Style
    from cosim.analysis.series import RunSeries

    look = Style.of(style)
    with plt.rc_context(look.rc):
        canvas = Canvas(RunSeries("s", "", 1.0, [], [], {}, {}, {}), tmp_path, "png", 150, look)
        looks = [canvas.look(i, 1500) for i in range(7)]
        assert len({(k["color"], str(k["ls"]), k["marker"]) for k in looks}) == 7
        assert len({k["color"] for k in looks}) == len({str(k["ls"]) for k in looks}) == 7
        assert len({k["marker"] for k in looks}) == 7
        fig, axes = canvas.figure(1)
        ax = axes[0, 0]
        t = np.linspace(0.0, 100.0, 1500)
        for i in range(7):
            canvas.curve(ax, t, np.sin(t / 10), i, f"scheme {i}")
        canvas.legend(fig, [ax])
        fig.canvas.draw()
        pixels = np.asarray(fig.canvas.buffer_rgba())[..., :3].astype(float)
        box = ax.get_window_extent()
        height = pixels.shape[0]
        inside = pixels[int(height - box.y1) : int(height - box.y0), int(box.x0) : int(box.x1)]
        for colour in PALETTE:
            rgb = np.array(matplotlib.colors.to_rgb(colour)) * 255
            seen = int((np.abs(inside - rgb).max(axis=-1) < 40).sum())
            assert seen > 20, (colour, seen)
        (legend,) = fig.legends
        assert not legend.get_window_extent().overlaps(box)
        assert legend.get_window_extent().x1 <= fig.bbox.x1 and legend.get_window_extent().x0 >= 0  # not cut
        plt.close(fig)


def test_paper_figures_are_a_column_wide_with_fonts_embedded_and_the_estimators_asked_for(
    adaptive_log: Path, tmp_path: Path, capsys
):
    import re

    args = ["plot", str(adaptive_log), "--style", "paper", "--no-title", "--estimators", "uniform,adaptive"]
    assert main([*args, "--format", "pdf", "--out", str(tmp_path / "pdf")]) == 0
    pdf = (tmp_path / "pdf" / "error.pdf").read_bytes()
    (width,) = {float(w) for w in re.findall(rb"/MediaBox \[ *0 0 ([0-9.]+) [0-9.]+ *\]", pdf)}
    assert width == 3.5 * 72  # IEEE's column, exactly: drawn to it, not cropped
    assert b"/FontFile2" in pdf and b"/Type3" not in pdf  # TrueType (Type 42) embedded, no Type 3
    assert main([*args, "--format", "svg", "--width", "double", "--out", str(tmp_path / "svg")]) == 0
    svg = (tmp_path / "svg" / "error.svg").read_text()
    assert re.search(r'<svg [^>]*width="515\.52pt"', svg)  # 7.16 in
    assert "tac2024-s2-p4" not in svg and "estimation error norm" not in svg  # --no-title
    texts = re.findall(r">([^<>]+)</text>", svg)
    names = [text for text in texts if text in ("uniform", "adaptive", "residual_injection")]
    assert names[:2] == ["uniform", "adaptive"] and "residual_injection" not in names  # as asked, in that order
    assert "(pseudoinverse)" not in svg  # a paper's legend names a scheme as the scenario does
    assert main([*args[:-1], "uniform,kalman", "--out", str(tmp_path / "none")]) == 1
    assert "no estimator 'kalman' in the log (its estimators: residual_injection, adaptive, uniform)" in (
        capsys.readouterr().err
    )


def test_a_curve_is_broken_where_its_values_are_missing_not_drawn_across():
    """An estimator whose frames stopped arriving (an overloaded bus) has no values there: a
    straight line across the gap would show estimates nobody made."""
    import numpy as np

    from cosim.analysis.canvas import gapped

    t = np.array([0.0, 0.1, 0.2, 0.3, 2.0, 2.1])
    x, y = gapped(t, t * 10, t, 0.3)
    assert np.isnan(x[4]) and np.isnan(y[4]) and len(x) == 7
    assert np.array_equal(x[[0, 1, 2, 3, 5, 6]], t)
    whole = t[:4]
    assert gapped(whole, whole, whole, 0.3)[0] is whole  # no gap: the values as they are


def test_a_start_up_transient_far_off_the_scale_does_not_flatten_the_rest_and_is_said():
    """φ̂ of TAC 2024 starts at ±10⁴ against a fault of 1: the axis shows the truth and the bulk of
    the estimate, and says what it leaves out."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from cosim.analysis.plot import in_view

    fig, (clipped, whole) = plt.subplots(2)
    estimate = np.r_[1.0e4, -9.0e3, np.full(998, 1.0)]
    in_view(clipped, [estimate], np.ones(1000))
    assert clipped.get_ylim() == (-0.15, 1.15) and clipped.get_title(loc="right") == (
        "2 values off the axis, from -9e+03 to 1e+04"
    )
    in_view(whole, [np.r_[15.0, np.linspace(0.0, 2.0, 999)]], np.ones(1000))  # nothing far off: as drawn
    assert whole.get_title(loc="right") == "" and whole.get_ylim() == (0.0, 1.0)  # (limits left to matplotlib)
    plt.close(fig)


@pytest.fixture(scope="module")
def cdc_log(tmp_path_factory) -> Path:
    """cdc2016-ex1 for 6 s, its bias from 3 s: |h_Γ| is 0 before the fault."""
    from cosim import scenario

    log = tmp_path_factory.mktemp("cdc") / "run.mcap"
    loaded = scenario.apply(load("cdc2016-ex1"), [("duration", 6.0), ("faults[0].start", 3.0)])
    Run(loaded, log, interface="virtual").execute()
    return log


@pytest.mark.slow
def test_paper_figures_have_one_line_titles_the_shading_in_the_legend_zeros_on_the_axis_and_h_gamma_set(
    cdc_log: Path, tmp_path: Path
):
    """At 3.5 in: each title on one line (the scenario's name dropped, then smaller type, where it
    would wrap); the faults' shaded windows named in the legend; |h_Γ|, 0 before the fault, on a
    symmetric log axis that draws the zeros (a log axis left them out); h_Γ with Γ as a subscript."""
    import re

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from cosim.analysis.plot import plot

    written = plot(cdc_log, tmp_path / "svg", fmt="svg", style="paper")
    svgs = {path.stem: path.read_text() for path in written}
    assert {"error", "bias_effect", "faults"} <= set(svgs)
    for name, svg in svgs.items():
        texts = re.findall(r"<text [^>]*>([^<]*)</text>", svg)
        shaded = "fault_active" in svg or "fault active" in texts
        assert shaded == (name != "weights"), name  # every figure that shades the faults names the shading
    assert "estimation error norm |x − x̂| over the whole state" in re.findall(r">([^<]*)</text>", svgs["error"])
    texts = [t.strip() for t in re.findall(r">([^<>]+)</(?:text|tspan)>", svgs["bias_effect"])]
    assert texts and not any("h_" in text for text in texts)  # mathtext: Γ a subscript, no underscore shown
    assert "Γ" in texts and "h" in texts  # h and its subscript Γ, each a text of its own
    figures = plot(cdc_log, tmp_path / "png", fmt="png", style="paper")
    assert all(path.exists() for path in figures)

    from cosim.analysis.canvas import SMALLEST_TITLE, Canvas, Style, log_scale
    from cosim.analysis.series import RunSeries

    look = Style.of("paper")
    with plt.rc_context(look.rc):
        canvas = Canvas(
            RunSeries("a-scenario-with-a-long-name", "", 1.0, [], [], {}, {}, {}), tmp_path, "png", 300, look
        )
        for heading in ("estimation error norm |x − x̂| over the whole state", "a heading " * 12):
            fig, _ = canvas.figure(1)
            canvas.titled(fig, f"a-scenario-with-a-long-name: {heading}", heading)
            title = fig.get_suptitle()
            size = fig._suptitle.get_fontsize()  # type: ignore[attr-defined]
            box = fig._suptitle.get_window_extent(fig.canvas.get_renderer())  # type: ignore[attr-defined]
            if heading.startswith("estimation"):  # fits without the scenario's name, at full size or a little less
                assert title == heading and size >= SMALLEST_TITLE and box.width <= fig.bbox.width
            else:  # too long at any size: wrapped, at the smallest size
                assert size == SMALLEST_TITLE
            plt.close(fig)
        fig, axes = canvas.figure(1)
        ax = axes[0, 0]
        zero_then_decaying = np.concatenate([np.zeros(50), 2.0 * np.exp(-np.arange(50.0) / 5)])
        ax.plot(np.arange(100.0), zero_then_decaying)
        assert log_scale(ax, [zero_then_decaying]) == " (log scale, linear below 1e-4)"  # 2 e^{-49/5} = 1.1e-4
        assert ax.get_yscale() == "symlog" and ax.get_ylim()[0] == 0.0  # the zeros are drawn, at 0
        ax2 = fig.add_subplot(2, 1, 2)
        assert log_scale(ax2, [zero_then_decaying[50:]]) == " (log scale)" and ax2.get_yscale() == "log"
        plt.close(fig)
