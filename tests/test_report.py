"""cosim report: one self-contained HTML page, rendered in a real headless browser.

The browser tests need Debian's Chromium (``apt-get install -y chromium``) and the Python package
``playwright`` (in the ``test`` extra), which drives it; they fail, never skip, when either is missing.
The page of every built-in scenario is measured at a laptop's and a phone's width: nothing wider
than the screen, names as the log writes them, units on the numbers that have one.
"""

from __future__ import annotations

import base64
import re
from dataclasses import dataclass, field
from pathlib import Path

import matplotlib.image
import numpy as np
import pytest
from markupsafe import escape

from cosim import scenario
from cosim.analysis import report as report_module
from cosim.analysis.metrics import BusMetrics, EstimationMetrics, IdTraffic, RunMetrics, compute_metrics
from cosim.analysis.plot import plot
from cosim.analysis.report import report
from cosim.cli import main
from cosim.run import run
from cosim.scenario import LoadedScenario
from tests.other_logs import write_other_log

CHROMIUM = Path("/usr/bin/chromium")
#: Flags that keep Chromium off the (closed) network and out of first-run work.
FLAGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
SCREENS = {
    "laptop": {"viewport": {"width": 1280, "height": 800}},
    "phone": {
        "viewport": {"width": 390, "height": 844},
        "device_scale_factor": 3,
        "is_mobile": True,
        "has_touch": True,
    },
}


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    """tac2024-s1-constant for 1 s: two estimators and four figures (error, weights, |h_Γ|, φ̂)."""
    loaded = scenario.load("tac2024-s1-constant")
    short = LoadedScenario(loaded.scenario.with_overrides(duration=1.0), "tac2024-s1-constant (1 s)", loaded.text)
    result = run(short, tmp_path_factory.mktemp("report") / "run.mcap", interface="virtual")
    assert result.status == "completed"
    return result.path


@pytest.fixture(scope="module")
def page(log, tmp_path_factory):
    out = tmp_path_factory.mktemp("html") / "report.html"
    assert main(["report", str(log), "--out", str(out)]) == 0
    return out


@pytest.mark.slow
def test_the_page_is_self_contained_with_every_figure_inlined(log, page, tmp_path):
    text = page.read_text(encoding="utf-8")
    assert '<meta name="viewport" content="width=device-width, initial-scale=1">' in text
    assert not re.search(r"""(src|href)\s*=\s*["'](?!data:|#)|url\(|@import""", text)  # nothing to fetch
    images = re.findall(r'<img src="data:image/png;base64,([A-Za-z0-9+/=]+)"', text)
    drawn = {path.stem for path in plot(log, tmp_path)}
    assert len(images) == len(drawn) and {"estimates", "state_errors", "error", "faults", "weights"} <= drawn
    assert all(base64.b64decode(data).startswith(b"\x89PNG\r\n\x1a\n") for data in images)
    for name in ("tac2024-s1-constant", "adaptive", "uniform", "RMS before fault", "/can/EST_adaptive_0"):
        assert name in text
    assert all(str(escape(report_module.CAPTIONS[stem])) in text for stem in drawn)  # each says what it shows


def test_every_metric_of_the_value_gets_a_cell(log, tmp_path, monkeypatch):
    """The tables follow the metrics, whatever fields they gain: scalars, records, nested records."""

    @dataclass
    class Estimation(EstimationMetrics):
        brand_new_metric: float = 0.123456
        per_fault: dict = field(default_factory=lambda: {"f1": {"delay": 2.5}})

    @dataclass
    class Metrics(RunMetrics):
        novel: dict = field(default_factory=lambda: {"x": {"delay_s": 1.5, "per_hour": 2}})
        novel_scalar_s: float = 0.25

    values = Metrics(
        status="completed",
        estimators={"a": Estimation(kind="k")},
        bus=BusMetrics(load=0.25, by_id={"0x080": IdTraffic(frames=7)}),
        warnings=["careful"],
    )
    monkeypatch.setattr(report_module, "metrics", lambda path: values)
    monkeypatch.setattr(report_module, "_figures", lambda path: ([], "", None))
    text = report(log, tmp_path / "r.html").read_text()
    assert "0.1235" in text and "careful" in text and ">25.00 %<" in text  # the load, in percent
    assert ">7<" in text  # frames of 0x080
    assert ">brand_new_metric<" in text and "a · per_fault" in text and ">f1<" in text and ">2.5<" in text
    assert ">novel<" in text and ">delay_s<" in text and ">1.5 s<" in text  # unknown metrics, names as they are
    assert ">novel_scalar_s<" in text and ">0.25 s<" in text


def test_the_page_shows_no_table_of_nothing_and_says_when_an_estimator_failed(log, tmp_path, monkeypatch):
    """An estimator that never saturated and did not fail has no "more metrics" to show: no table
    with no rows, none whose cells all say –; one that failed says so with its errors."""
    values = RunMetrics(
        status="completed",
        estimators={
            "calm": EstimationMetrics(kind="k", rms_post_fault=0.5, saturated={}, failed=None),
            "broke": EstimationMetrics(kind="k", rms_post_fault=0.7, failed="tick 51: ValueError: boom"),
        },
    )
    monkeypatch.setattr(report_module, "metrics", lambda path: values)
    monkeypatch.setattr(report_module, "_figures", lambda path: ([], "", None))
    text = report(log, tmp_path / "r.html").read_text(encoding="utf-8")
    assert "More estimator metrics" not in text and "saturated" not in text
    assert "broke failed: tick 51: ValueError: boom; its errors cover the ticks before." in text
    for table in re.findall(r"<table>.*?</table>", text, re.S):
        values_shown = re.findall(r"<td[^>]*>(.*?)</td>", table, re.S)
        assert values_shown and any(v != "–" for v in values_shown), table[:300]


def test_a_log_of_another_program_gives_a_page_that_says_what_is_missing(tmp_path):
    foreign = write_other_log(tmp_path / "foreign.mcap", [("/other", 0, b"{}")])
    text = report(foreign, tmp_path / "foreign.html").read_text()
    assert "no <code>cosim.run</code> metadata" in text and "no figures" in text and "/other" in text


def test_a_missing_log_is_one_error_line(tmp_path, capsys):
    assert main(["report", str(tmp_path / "none.mcap")]) == 1
    assert "none.mcap: no such file" in capsys.readouterr().err


def _playwright():
    if not CHROMIUM.exists():
        pytest.fail(f"{CHROMIUM} is missing: install Debian's Chromium with 'apt-get install -y chromium'")
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.fail("the Python package playwright is missing: pip install '.[test]'")
    return sync_playwright


MEASURE = """async () => {
    const images = [...document.images];
    await Promise.all(images.map(image => image.decode()));
    const width = window.innerWidth;
    const wide = [...document.querySelectorAll("main *")]
        .filter(e => e.getClientRects().length && e.getBoundingClientRect().right > width + 0.5)
        .map(e => e.tagName + " " + (e.textContent || "").slice(0, 40));
    const cells = [...document.querySelectorAll("table")].map(table => {
        const heads = [...table.querySelectorAll("thead th")].map(th => th.textContent);
        return [...table.querySelectorAll("tbody tr")].map(tr =>
            [...tr.children].map((cell, i) => [heads[i] || "", cell.textContent]));
    });
    return {
        images: images.map(image => ({natural: image.naturalWidth, shown: image.getBoundingClientRect().width})),
        scrollWidth: document.documentElement.scrollWidth, width,
        fontSize: parseFloat(getComputedStyle(document.body).fontSize),
        tables: document.querySelectorAll("table").length, wide, cells,
        text: document.body.textContent,
    };
}"""

#: Columns whose numbers are times (s after the start or the onset).
SECONDS = {
    "starts",
    "ends",
    "first active",
    "cleared",
    "peak after onset",
    "recovery time",
    "detection delay",
    "isolation delay",
}


def check_page(tab, page: Path, screen: str, metrics: dict) -> list[str]:
    """Load the page in ``tab``; returns what is wrong with it at this screen's width."""
    problems: list[str] = []
    requests: list[str] = []
    tab.on(
        "console", lambda m: problems.append(f"console {m.type}: {m.text}") if m.type in ("error", "warning") else None
    )
    tab.on("pageerror", lambda e: problems.append(f"page error: {e}"))
    tab.on("request", lambda r: requests.append(r.url))
    tab.goto(page.as_uri(), wait_until="load")
    layout = tab.evaluate(MEASURE)
    width = SCREENS[screen]["viewport"]["width"]
    if [url for url in requests if not url.startswith("data:")] != [page.as_uri()]:
        problems.append(f"fetched more than the page: {requests}")
    if layout["width"] != width or layout["scrollWidth"] > width:
        problems.append(f"the page is {layout['scrollWidth']} px wide on a {width} px screen")
    if layout["wide"]:
        problems.append(f"elements past the right edge: {layout['wide'][:5]}")
    if not layout["images"] or not all(0 < i["shown"] <= width and i["natural"] > 0 for i in layout["images"]):
        problems.append(f"figures missing or wider than the screen: {layout['images']}")
    if layout["fontSize"] < 14:
        problems.append(f"font size {layout['fontSize']} px")
    for table in layout["cells"]:
        for row in table:
            for head, cell in row:
                if head in SECONDS and re.fullmatch(r"-?[\d.e+-]+", cell):
                    problems.append(f"{head} {cell!r}: a time without its unit")
                if head in ("bus load", "bus load, worst-case bit stuffing") and not cell.endswith("%"):
                    problems.append(f"{head} {cell!r}: not a percentage")
    for topic in metrics["channels"]:
        if topic not in layout["text"]:
            problems.append(f"topic {topic} is not shown as it is")
    if re.search(r"/can/\S+ \S+ \d", layout["text"]) or "EST " in layout["text"]:
        problems.append("a name with its underscores turned into spaces")
    return problems


def _browser(p):
    return p.chromium.launch(executable_path=str(CHROMIUM), args=FLAGS, headless=True)


@pytest.mark.slow
@pytest.mark.parametrize("screen", SCREENS)
def test_the_page_renders_in_a_real_browser_on_a_laptop_and_a_phone(page, log, tmp_path, screen):
    sync_playwright = _playwright()
    with sync_playwright() as p:
        browser = _browser(p)
        try:
            tab = browser.new_context(**SCREENS[screen]).new_page()
            problems = check_page(tab, page, screen, compute_metrics(log))
            layout = tab.evaluate(MEASURE)
            shot = tmp_path / f"{screen}.png"
            tab.screenshot(path=str(shot), full_page=True)
        finally:
            browser.close()
    assert problems == []
    assert layout["tables"] >= 5
    width = SCREENS[screen]["viewport"]["width"]
    pixels = matplotlib.image.imread(shot)
    assert pixels.shape[1] == width * SCREENS[screen].get("device_scale_factor", 1)
    assert pixels.shape[0] > 3 * pixels.shape[1] and np.std(pixels) > 0.05  # a long page with content, not blank


@pytest.fixture(scope="module")
def every_page(tmp_path_factory) -> dict[str, tuple[Path, dict]]:
    """The report of a short run of every built-in scenario, with its metrics (of the ten
    vessel-fault scenarios, which differ only in the thrusters that fail, the first stands for all)."""
    folder = tmp_path_factory.mktemp("pages")
    pages = {}
    vessel_faults = [n for n in scenario.builtin_names() if n.startswith("vessel-fault-")]
    for name in [n for n in scenario.builtin_names() if n not in vessel_faults[1:]]:
        loaded = scenario.load(name)
        duration = 3.0 if name == "three-tank-reconciliation" else 1.0
        short = LoadedScenario(
            loaded.scenario.with_overrides(duration=duration), f"{name} ({duration:g} s)", loaded.text
        )
        result = run(short, folder / f"{name}.mcap", interface="virtual")
        assert result.status == "completed", name
        pages[name] = (report(result.path, folder / f"{name}.html"), compute_metrics(result.path))
    return pages


@pytest.mark.slow
def test_the_page_of_every_builtin_scenario_fits_a_laptop_and_a_phone(every_page):
    sync_playwright = _playwright()
    found = {}
    with sync_playwright() as p:
        browser = _browser(p)
        try:
            for screen in SCREENS:
                context = browser.new_context(**SCREENS[screen])
                for name, (page, metrics) in every_page.items():
                    tab = context.new_page()
                    problems = check_page(tab, page, screen, metrics)
                    if problems:
                        found[f"{name} on a {screen}"] = problems
                    tab.close()
                context.close()
        finally:
            browser.close()
    assert found == {}
