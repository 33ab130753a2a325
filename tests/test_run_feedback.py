"""What ``cosim run`` tells: slow work before the first tick is shown (on a terminal, as plain lines
otherwise, never with -q nor in the way of --json), and a run in which an estimator failed exits
with its own status."""

from __future__ import annotations

import io
import json
import time

import pytest
from rich.console import Console

from cosim import progress
from cosim.cli import common, main
from tests.conftest import ROOT
from tests.snippets import short_scenario

#: An estimator whose design takes ``design_s`` seconds and whose step raises from tick ``fails_at`` on.
SLOW = """
import time
from dataclasses import dataclass

import numpy as np

from cosim.api import Estimate, Estimator


@dataclass(frozen=True)
class Params:
    design_s: float = 0.0
    fails_at: int = 1_000_000


class Slow(Estimator):
    kind = "slow"
    Params = Params
    k = 0

    def __init__(self, model, params, sample_time=None):
        super().__init__(model, params, sample_time)
        time.sleep(params.design_s)  # an LMI solved, say

    def _step(self, dy, du):
        self.k += 1
        if self.k > self.params.fails_at:
            raise ZeroDivisionError("my bug")
        return Estimate(np.zeros(self.model.n))
"""


def scenario(folder, design_s: float, fails_at: int = 1_000_000) -> str:
    (folder / "slow.py").write_text(SLOW)
    text = short_scenario((ROOT / "scenarios" / "masses-bias.toml").read_text(), 1.0)
    params = f"params = {{ design_s = {design_s}, fails_at = {fails_at} }}"
    (folder / "s.toml").write_text(text + f'[[estimators]]\nname = "mine"\nkind = "slow.py:Slow"\n{params}\n')
    return str(folder / "s.toml")


def test_a_slow_design_is_shown_as_a_line_off_a_terminal_and_a_failed_estimator_sets_the_status(tmp_path, capsys):
    path = scenario(tmp_path, design_s=2.6, fails_at=50)
    status = main(["run", path, "--interface", "virtual", "--out", str(tmp_path / "run.mcap"), "--json"])
    out, err = capsys.readouterr()
    assert status == common.ESTIMATOR_FAILED == 4
    summary = json.loads(out)  # --json: standard output holds the summary alone
    assert summary["status"] == "completed" and summary["ticks"] == 100
    assert summary["failed"]["mine"].startswith("failed at tick 50: ZeroDivisionError: my bug")
    lines = [line for line in err.splitlines() if "estimator mine" in line and "designing" in line]
    assert len(lines) == 1, err  # said once, as a plain line: the time since the start, the step
    step = "estimator mine (slow), 3 of 3: designing (not in the design cache)"  # the kind its class declares
    assert lines[0].endswith(f" s  {step}"), lines
    assert "\x1b[" not in err  # no terminal codes off a terminal
    assert "estimator mine failed at tick 50" in err


def test_nothing_is_shown_with_q(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(common, "SILENT_FOR", 0.2)  # the thresholds, shortened: the design lasts 0.5 s
    monkeypatch.setattr(common, "STEP_LASTED", 0.3)
    path = scenario(tmp_path, design_s=0.5)
    assert main(["run", path, "--interface", "virtual", "--out", str(tmp_path / "q.mcap"), "-q"]) == 0
    out, err = capsys.readouterr()
    assert out.strip() == str(tmp_path / "q.mcap")
    assert "designing" not in err and "estimator mine" not in err, err  # -q: warnings and errors only


def test_on_a_terminal_a_spinner_shows_the_step_and_goes(monkeypatch):
    monkeypatch.setattr(common, "SILENT_FOR", 0.1)
    screen = io.StringIO()
    talk = Console(file=screen, force_terminal=True, width=100)
    with common.preparing(talk) as shown:
        with progress.step("estimator lpv (lpv-uio-sr), 1 of 7"), progress.step("designing"):
            time.sleep(0.5)
        assert shown is not None and shown.live is not None and shown.live.is_started
        shown.stop()  # the first tick's progress bar takes over
        assert not shown.live.is_started
    text = screen.getvalue()
    assert "estimator lpv (lpv-uio-sr), 1 of 7: designing" in text
    assert "\x1b[" in text  # drawn in place, not as lines


def test_steps_nest_and_say_nothing_without_a_listener():
    heard: list[tuple[str, ...]] = []
    with progress.step("unheard"):
        pass
    with progress.listening(heard.append):
        with progress.step("a"):
            with progress.step("b"):
                pass
    assert heard == [("a",), ("a", "b"), ("a",), ()]


@pytest.mark.parametrize("quiet", [True, False])
def test_quick_work_shows_nothing(quiet, monkeypatch):
    screen = io.StringIO()
    talk = Console(file=screen, quiet=quiet, force_terminal=False)
    with common.preparing(talk) as shown:
        with progress.step("linearizing"):
            time.sleep(0.05)
    assert (shown is None) == quiet and screen.getvalue() == ""
