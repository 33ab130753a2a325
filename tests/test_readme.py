"""The README's Python examples run as printed and print what the README says they print."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def python_examples() -> list[str]:
    return re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), flags=re.S)


def test_the_python_api_example_prints_a_completed_run_and_its_error(tmp_path):
    """The example's fault must happen within its run: it printed ``completed None`` when the
    run ended at the fault's start."""
    (example,) = [text for text in python_examples() if "from cosim.api import" in text]
    said = re.search(r"It prints `([^`]*)`", (ROOT / "README.md").read_text())
    assert said, "the README says what the API example prints"
    done = subprocess.run([sys.executable, "-c", example], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    status, error = done.stdout.split()
    assert status == "completed" and float(error) > 0
    assert done.stdout.strip().startswith(said.group(1).rstrip("…"))
    assert (tmp_path / "runs" / "short.mcap").exists()


def test_a_fault_after_the_runs_end_is_warned_about():
    from cosim import api
    from cosim.scenario.load import timing_warnings

    late = api.load_scenario("masses-bias", {"duration": 5.0}).scenario  # the bias starts at 5 s
    assert timing_warnings(late) == [
        "faults[0] (bias) starts at 5 s, after the run's last tick (t = 4.99 s): it never happens; "
        "start it earlier or lengthen the run (duration = 5)"
    ]
    assert timing_warnings(api.load_scenario("masses-bias", {"duration": 5.01}).scenario) == []
