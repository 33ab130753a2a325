"""An estimator the package never saw, written in a file beside the user's scenario, goes wherever a
built-in goes: in-process, as a node process, in replay, in a campaign on two Dask workers, and on
the leaderboard beside ``kalman``."""

from __future__ import annotations

import io
import json
import os
import re
import time
from contextlib import redirect_stdout

import pytest

from cosim import api
from cosim.campaign.coordinator import run_campaign
from cosim.campaign.leaderboard import leaderboard
from cosim.campaign.spec import load_campaign
from cosim.cli import main
from cosim.errors import CosimError
from tests.conftest import ROOT
from tests.snippets import short_scenario

#: The user's observer: the plugin template's (a Luenberger observer with residuals, an alarm and
#: isolation flags), in a file next to the user's scenario.
OBSERVER = (ROOT / "examples" / "plugin" / "my_observer.py").read_text()

#: The default scenario, shortened, with the user's observer beside its estimators.
SCENARIO = (
    short_scenario((ROOT / "scenarios" / "masses-bias.toml").read_text(), 1.5)
    + """
[[estimators]]
name = "mine"
kind = "observers.py:ResidualObserver"
params = { poles = [0.5, 0.55, 0.6, 0.65] }
"""
)

CAMPAIGN = """
name = "mine"
scenario = "mine.toml"
seed = 3
seeds = 2
bus = "processes"
[set]
"faults[0].start" = 0.5
"bus.fd" = true
"""


@pytest.fixture()
def folder(tmp_path):
    (tmp_path / "observers.py").write_text(OBSERVER)
    (tmp_path / "mine.toml").write_text(SCENARIO)
    (tmp_path / "campaign.toml").write_text(CAMPAIGN)
    return tmp_path


def test_a_scenario_file_names_its_estimator_file_relative_to_itself(folder):
    loaded = api.load_scenario(folder / "mine.toml")
    assert [e.name for e in loaded.scenario.estimators] == ["uniform", "kalman", "mine"]
    assert loaded.scenario.estimators[-1].kind == f"{folder / 'observers.py'}:ResidualObserver"


@pytest.mark.slow
def test_my_estimator_runs_replays_and_ranks_beside_the_built_ins(folder, monkeypatch, capsys):
    monkeypatch.chdir(folder)
    log = folder / "mine.mcap"
    result = api.run(api.load_scenario(folder / "mine.toml"), log)  # node processes
    assert result.status == "completed", result.error
    mine = api.metrics(log)["estimators"]["mine"]
    assert mine["final_error"] < 0.05  # converged from x̂ = 0

    kind = f"{folder / 'observers.py'}:ResidualObserver"
    assert main(["replay", str(log), "-e", "mine", "-q"]) == 0  # its frames again, bit for bit
    assert main(["replay", str(log), "-e", "faster", "--kind", kind, "--param", "poles=[0.7, 0.72, 0.74, 0.76]"]) == 0
    capsys.readouterr()
    assert api.metrics(folder / "mine-replay-mine.mcap")["estimators"]["mine"]["rms_pre_fault"] == mine["rms_pre_fault"]
    replayed = api.metrics(folder / "mine-replay-faster.mcap")["estimators"]["faster"]
    assert replayed["kind"] == kind and replayed["final_error"] < 0.05
    assert replayed["kind_name"] == mine["kind_name"] == "residual-observer"  # the name its class declares
    assert main(["inspect", str(log)]) == 0
    shown = capsys.readouterr().out  # the text names the kind as the class does; --json has its path
    assert "residual-observer" in shown and "observers.py" not in shown

    campaign = run_campaign(load_campaign(folder / "campaign.toml"), folder / "out", engine="dask", workers=2)
    assert campaign.runs == 2 and campaign.failed == 0
    board = leaderboard(campaign.path)
    (group,) = board["groups"]
    assert {s["estimator"] for s in group["ranking"]} == {"uniform", "kalman", "mine"}
    out = io.StringIO()
    with redirect_stdout(out):
        assert main(["leaderboard", str(campaign.path), "--json"]) == 0
    ranked = json.loads(out.getvalue())["groups"][0]["ranking"]
    assert next(s for s in ranked if s["estimator"] == "mine")["kind"] == kind
    assert next(s for s in ranked if s["estimator"] == "mine")["kind_name"] == "residual-observer"
    with redirect_stdout(out := io.StringIO()):
        assert main(["leaderboard", str(campaign.path)]) == 0
    assert "mine (residual-observer)" in out.getvalue() and "observers.py" not in out.getvalue()


BREAKS = '''
"""An estimator with a bug that shows at its 51st step."""

from dataclasses import dataclass

import numpy as np

from cosim.api import Estimate, Estimator


@dataclass(frozen=True)
class Params:
    at: int = 50
    how: str = "raise"


class Breaks(Estimator):
    """After ``at`` ticks, raises, or returns an estimate of the wrong shape, or not an estimate."""

    kind = "breaks"
    Params = Params
    k = 0

    def _step(self, dy, du):
        self.k += 1
        if self.k > self.params.at:
            if self.params.how == "shape":
                return Estimate(np.zeros(1))
            if self.params.how == "type":
                return np.zeros(self.model.n)
            raise ZeroDivisionError("my bug")
        return Estimate(np.zeros(self.model.n))
'''


@pytest.mark.parametrize("in_process", [True, False], ids=["in-process", "node process"])
def test_an_estimator_whose_step_raises_leaves_the_run_which_goes_on(tmp_path, in_process, capsys):
    (tmp_path / "breaks.py").write_text(BREAKS)
    text = short_scenario((ROOT / "scenarios" / "masses-bias.toml").read_text(), 1.0)
    (tmp_path / "s.toml").write_text(text + '[[estimators]]\nname = "bad"\nkind = "breaks.py:Breaks"\n')
    out = tmp_path / "run.mcap"
    result = api.run(api.load_scenario(tmp_path / "s.toml"), out, in_process=in_process)
    assert result.status == "completed" and result.ticks == 100
    why = result.failed["bad"]
    assert why.startswith("failed at tick 50: ZeroDivisionError: my bug") and "breaks.py" in why and "\n" not in why
    metrics = api.metrics(out)
    assert metrics["estimators"]["bad"]["failed"] == why and metrics["estimators"]["kalman"]["failed"] is None
    assert metrics["estimators"]["kalman"]["ticks_scored"] == 100 and metrics["estimators"]["bad"]["ticks_scored"] == 50
    from cosim.log.reader import LogReader

    with LogReader(out) as reader:
        events = [m for _, _, m in reader.messages(["/cosim/events"]) if m["event"] == "node failed"]
    assert len(events) == 1 and 'raise ZeroDivisionError("my bug")' in events[0]["detail"]  # the whole traceback
    from cosim.analysis.metrics import measure
    from cosim.campaign.results import rows_of

    rows = {row["estimator"]: row for row in rows_of(measure(out))}
    assert rows["bad"]["estimator_failed"] == why and rows["kalman"]["estimator_failed"] is None
    assert main(["inspect", str(out)]) == 0
    assert "estimator bad failed at tick 50" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("how", "said"),
    [
        ("shape", "ValueError: breaks: _step returned an estimate of shape (1,), not (4,): one value per state"),
        ("type", "TypeError: breaks: _step returned ndarray, not an Estimate(x, diagnostics)"),
    ],
)
def test_an_estimate_of_the_wrong_shape_or_type_fails_its_estimator_in_one_line(tmp_path, how, said):
    (tmp_path / "breaks.py").write_text(BREAKS)
    text = short_scenario((ROOT / "scenarios" / "masses-bias.toml").read_text(), 1.0)
    bad = f'[[estimators]]\nname = "bad"\nkind = "breaks.py:Breaks"\nparams = {{ how = "{how}" }}\n'
    (tmp_path / "s.toml").write_text(text + bad)
    result = api.run(api.load_scenario(tmp_path / "s.toml"), tmp_path / "run.mcap", in_process=True)
    assert result.status == "completed" and result.ticks == 100
    why = result.failed["bad"]
    assert why.startswith(f"failed at tick 50: {said}") and "\n" not in why, why


MY_FAULTS = '''
"""A fault of mine: an actuator wired the wrong way round."""

from dataclasses import dataclass

import numpy as np

from cosim.api import ActuatorFault


@dataclass
class Reversed(ActuatorFault):
    """u_eff = -u on its actuators."""

    kind = "reversed"

    def factors(self, t, n):
        delta = np.ones(n)
        if self.active(t):
            delta[list(self.channels)] = -1.0
        return delta
'''


def test_fault_kinds_of_my_own_act_like_the_built_ins(tmp_path):
    (tmp_path / "my_faults.py").write_text(MY_FAULTS)
    (tmp_path / "my_observer.py").write_text(OBSERVER)  # the template's quantized sensor
    text = short_scenario((ROOT / "scenarios" / "masses-bias.toml").read_text(), 1.0)
    text = re.sub(r"\[\[faults\]\]\n(.+\n)+\n", "", text)  # without its bias
    assert "[[faults]]" not in text and "[[estimators]]" in text
    text += (
        '[[faults]]\nkind = "my_observer.py:Quantized"\nsensors = ["x1"]\nstart = 0.5\nparams = { step = 0.05 }\n'
        '[[faults]]\nkind = "my_faults.py:Reversed"\nactuators = ["force"]\nstart = 0.8\n'
    )
    (tmp_path / "s.toml").write_text(text)
    loaded = api.load_scenario(tmp_path / "s.toml")
    assert loaded.scenario.faults[0].kind == f"{tmp_path / 'my_observer.py'}:Quantized"  # made absolute
    out = tmp_path / "run.mcap"
    assert api.run(loaded, out, in_process=True).status == "completed"
    from cosim.log.reader import LogReader

    with LogReader(out) as reader:
        faults = {m["tick"]: m for _, _, m in reader.messages(["/truth/faults"])}
    assert faults[10]["fault"]["x1"] == 0.0 and faults[10]["effectiveness"]["force"] == 1.0
    steps = [faults[k]["measured"]["x1"] / 0.05 for k in range(50, 100)]  # quantized from its onset
    assert all(abs(s - round(s)) < 1e-9 for s in steps) and faults[60]["fault"]["x1"] != 0.0
    assert faults[90]["effectiveness"]["force"] == -1.0 and faults[70]["effectiveness"]["force"] == 1.0
    metrics = api.metrics(out)
    assert {f["kind"] for f in metrics["faults"].values()} == {"quantized", "reversed"}
    with pytest.raises(CosimError, match=r"params: size is not a parameter of fault .*Quantized.* \(it has: step\)"):
        api.load_scenario(tmp_path / "s.toml", {"faults[0].params": {"size": 1.0}})
    with pytest.raises(CosimError, match=r"faults\[1\]: actuators: fault .* acts on sensors"):
        api.load_scenario(
            tmp_path / "s.toml",
            {"faults[1]": {"kind": f"{tmp_path / 'my_observer.py'}:Quantized", "actuators": ["force"]}},
        )


@pytest.mark.slow
def test_the_plugin_template_installs_and_its_kinds_are_names(tmp_path):
    """examples/plugin is a pip-installable package: installed, its entry points make
    'residual-observer' and 'quantized' kinds by name, and its own test passes."""
    import os
    import shutil
    import subprocess
    import sys

    source = tmp_path / "plugin"
    shutil.copytree(ROOT / "examples" / "plugin", source)  # the build leaves its folders beside the sources
    target = tmp_path / "site"
    pip = [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--target"]  # setuptools fetched to build
    subprocess.run([*pip, str(target), str(source)], check=True, capture_output=True)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(target), os.environ.get("PYTHONPATH", "")])}
    kinds = subprocess.run(
        [sys.executable, "-m", "cosim.cli", "kinds", "--json"], env=env, capture_output=True, text=True, check=True
    )
    listing = json.loads(kinds.stdout)
    mine = next(e for e in listing["cosim.estimators"] if e["name"] == "residual-observer")
    assert mine["source"] == "entry point" and mine["distribution"] == "cosim-my-observer 0.1.0"
    assert any(e["name"] == "quantized" for e in listing["cosim.faults"])
    scenario = (
        (source / "my-observer.toml").read_text().replace('"my_observer.py:ResidualObserver"', '"residual-observer"')
    )
    (tmp_path / "by-name.toml").write_text(
        scenario + '\n[[faults]]\nkind = "quantized"\nsensors = ["x2"]\nparams = { step = 0.001 }\n'
    )
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "cosim.cli",
            "run",
            str(tmp_path / "by-name.toml"),
            "-q",
            "--out",
            str(tmp_path / "r.mcap"),
        ],
        env=env,
        capture_output=True,
        text=True,
    )
    assert run.returncode == 0, run.stderr
    test = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(source / "test_my_observer.py")],
        env=env,
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    assert test.returncode == 0, test.stdout + test.stderr


#: An observer whose dependency only the coordinator's process has: the campaign loads it, the
#: workers cannot import it.
COORDINATOR_ONLY = '''
"""A plugin that imports on the coordinator and fails to import on the workers."""

import os

if str(os.getpid()) != os.environ.get("COSIM_TEST_COORDINATOR"):
    raise ModuleNotFoundError("No module named 'secret_sauce'", name="secret_sauce")

from estimators.kalman import KalmanFilter


class Mine(KalmanFilter):
    kind = "mine"
'''


@pytest.mark.slow
def test_a_worker_that_cannot_import_a_plugin_fails_its_runs_in_one_line(tmp_path, monkeypatch):
    monkeypatch.setenv("COSIM_TEST_COORDINATOR", str(os.getpid()))
    (tmp_path / "coordinator_only.py").write_text(COORDINATOR_ONLY)
    scenario_text = short_scenario((ROOT / "scenarios" / "masses-bias.toml").read_text(), 0.5)
    (tmp_path / "mine.toml").write_text(
        scenario_text + '[[estimators]]\nname = "mine"\nkind = "coordinator_only.py:Mine"\n'
    )
    (tmp_path / "campaign.toml").write_text('name = "lacking"\nscenario = "mine.toml"\nseeds = 2\n')
    started = time.monotonic()
    campaign = run_campaign(load_campaign(tmp_path / "campaign.toml"), tmp_path / "out", engine="dask", workers=1)
    assert time.monotonic() - started < 120  # no hang
    assert campaign.runs == 2 and campaign.failed == 2
    import pyarrow.parquet as pq

    errors = set(pq.read_table(campaign.path).column("error").to_pylist())
    (error,) = errors
    assert "coordinator_only.py:Mine" in error and "No module named 'secret_sauce'" in error and "\n" not in error
