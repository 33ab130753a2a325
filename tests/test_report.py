"""cosim report: one self-contained HTML page, rendered in a real headless browser.

The browser test needs Debian's Chromium (``apt-get install -y chromium``) and the Python package
``playwright`` (in the ``test`` extra), which drives it; it fails, never skips, when either is missing.
"""

from __future__ import annotations

import base64
import re
from pathlib import Path

import matplotlib.image
import numpy as np
import pytest
from mcap.writer import Writer

from cosim import scenario
from cosim.analysis import report as report_module
from cosim.analysis.plot import plot
from cosim.analysis.report import report
from cosim.cli import main
from cosim.run import run
from cosim.scenario import LoadedScenario

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
    "laptop": {"viewport": {"width": 1366, "height": 768}},
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
    assert len(images) == len(plot(log, tmp_path)) == 4
    assert all(base64.b64decode(data).startswith(b"\x89PNG\r\n\x1a\n") for data in images)
    for name in ("tac2024-s1-constant", "adaptive", "uniform", "rms pre fault"):
        assert name in text


def test_every_metric_of_the_dict_gets_a_cell(log, tmp_path, monkeypatch):
    """The tables follow the metrics dict, whatever its keys: scalars, records, nested records."""
    values = {
        "status": "completed",
        "estimators": {"a": {"kind": "k", "brand_new_metric": 0.123456, "per_fault": {"f1": {"delay": 2.5}}}},
        "bus": {"load": 0.25, "by_id": {"0x080": {"frames": 7}}},
        "warnings": ["careful"],
    }
    monkeypatch.setattr(report_module, "metrics", lambda path: values)
    monkeypatch.setattr(report_module, "_figures", lambda path: ([], ""))
    text = report(log, tmp_path / "r.html").read_text()
    assert "brand new metric" in text and "0.1235" in text
    assert "estimators · per_fault" in text and "a · f1" in text and ">2.5<" in text
    assert "bus · by_id" in text and ">7<" in text and "careful" in text


def test_a_log_of_another_program_gives_a_page_that_says_what_is_missing(tmp_path):
    foreign = tmp_path / "foreign.mcap"
    with open(foreign, "wb") as stream:
        writer = Writer(stream)
        writer.start()
        schema = writer.register_schema(name="x", encoding="jsonschema", data=b"{}")
        channel = writer.register_channel(topic="/other", message_encoding="json", schema_id=schema)
        writer.add_message(channel, log_time=0, data=b"{}", publish_time=0)
        writer.finish()
    text = report(foreign, tmp_path / "foreign.html").read_text()
    assert "no <code>cosim.run</code> metadata" in text and "no figures" in text


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


@pytest.mark.slow
@pytest.mark.parametrize("screen", SCREENS)
def test_the_page_renders_in_a_real_browser_on_a_laptop_and_a_phone(page, tmp_path, screen):
    sync_playwright = _playwright()
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=FLAGS, headless=True)
        try:
            context = browser.new_context(**SCREENS[screen])
            tab = context.new_page()
            problems, requests = [], []
            tab.on(
                "console",
                lambda m: problems.append(f"console {m.type}: {m.text}") if m.type in ("error", "warning") else None,
            )
            tab.on("pageerror", lambda e: problems.append(f"page error: {e}"))
            tab.on("requestfailed", lambda r: problems.append(f"request failed: {r.url[:80]}"))
            tab.on("request", lambda r: requests.append(r.url))
            tab.goto(page.as_uri(), wait_until="load")
            layout = tab.evaluate("""async () => {
                const images = [...document.images];
                await Promise.all(images.map(image => image.decode()));
                return {
                    images: images.map(image => ({
                        natural: image.naturalWidth, shown: image.getBoundingClientRect().width,
                    })),
                    scrollWidth: document.documentElement.scrollWidth, width: window.innerWidth,
                    fontSize: parseFloat(getComputedStyle(document.body).fontSize),
                    tables: document.querySelectorAll("table").length,
                };
            }""")
            shot = tmp_path / f"{screen}.png"
            tab.screenshot(path=str(shot), full_page=True)
        finally:
            browser.close()
    assert problems == []
    assert [url for url in requests if not url.startswith("data:")] == [page.as_uri()]  # the page, nothing else
    assert len(layout["images"]) == 4 and all(i["natural"] > 0 for i in layout["images"])  # decoded
    width = SCREENS[screen]["viewport"]["width"]
    assert layout["width"] == width and layout["scrollWidth"] <= width  # no sideways scrolling of the page
    assert all(0 < i["shown"] <= width for i in layout["images"])  # figures fit the screen
    assert layout["fontSize"] >= 14 and layout["tables"] >= 5
    pixels = matplotlib.image.imread(shot)
    assert pixels.shape[1] == width * SCREENS[screen].get("device_scale_factor", 1)
    assert pixels.shape[0] > 3 * pixels.shape[1] and np.std(pixels) > 0.05  # a long page with content, not blank
