"""The registry of kinds: a kind resolves from the built-in table (imported on first lookup), from
a module path, or from an installed distribution's entry point; it knows where it came from; and a
part that breaks its group's contract is refused in one line saying what is wrong."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import estimators
import faults
import mjcf
from cosim import kinds, scenario
from cosim.errors import ScenarioError
from cosim.kinds import KindError, Kinds
from estimators import Estimator, ParameterError
from estimators.controller import CONTROLLERS, Controller
from tests.linear_masses import masses_model
from tests.snippets import MASSES

ROOT = Path(__file__).resolve().parent.parent

#: A plugin's module: a working estimator, fault and plant, and parts that break the contract.
PLUGIN = '''
"""Parts a user writes: what the registry finds by module path or entry point."""

from dataclasses import dataclass, replace

import numpy as np

import mjcf
from estimators import Estimate, Estimator
from estimators.controller import Controller
from faults.models import Fault, SensorFault


@dataclass(frozen=True)
class NoParams:
    pass


class MeasuredState(Estimator):
    """x̂ = C⁺ y: the least-squares state of the readings, no dynamics."""

    kind = "measured-state"
    Params = NoParams

    def __init__(self, model, params, sample_time=None):
        super().__init__(model, params, sample_time)
        self.inverse = np.linalg.pinv(model.C)

    def _step(self, dy, du):
        return Estimate(self.inverse @ np.nan_to_num(dy))


class NoStep(Estimator):
    kind = "no-step"
    Params = NoParams


class PlainParams(MeasuredState):
    kind = "plain-params"

    class Params:
        pass


class Nameless(MeasuredState):
    kind = None


class NoCommand(Controller):
    kind = "no-command"
    Params = NoParams


@dataclass
class Offset(SensorFault):
    """y <- y + value on every channel."""

    value: float = 0.0
    kind = "offset"

    def _affect(self, y, elapsed):
        return y + self.value


class NotADataclass(SensorFault):
    kind = "not-a-dataclass"

    def _affect(self, y, elapsed):
        return y


@dataclass
class Neither(Fault):
    kind = "neither"


MY_MASSES = replace(mjcf.get("masses"), name="my-masses", model_file=str(mjcf.get("masses").model_path))
NO_FILE = replace(MY_MASSES, name="no-file", model_file="/nonexistent/plant.xml")
'''


@pytest.fixture()
def plugin(tmp_path, monkeypatch):
    """The plugin module ``cosim_plugin_example`` on sys.path (and on the PYTHONPATH of children)."""
    (tmp_path / "cosim_plugin_example.py").write_text(PLUGIN)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")]))
    yield "cosim_plugin_example"
    sys.modules.pop("cosim_plugin_example", None)


@pytest.fixture()
def installed(tmp_path, plugin, monkeypatch):
    """A distribution ``cosim-plugin-example 0.1`` declaring entry points, installed as a
    dist-info folder on sys.path, as pip would leave it."""
    info = tmp_path / "cosim_plugin_example-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: cosim-plugin-example\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(
        "[cosim.estimators]\n"
        "measured-state = cosim_plugin_example:MeasuredState\n"
        "renamed = cosim_plugin_example:MeasuredState\n"
        "broken = cosim_plugin_example_missing:Anything\n"
        "[cosim.plants]\nmy-masses = cosim_plugin_example:MY_MASSES\n"
    )
    kinds.rescan()
    yield plugin
    kinds.rescan()


def fresh(what: str = "estimator", base: type = Estimator, builtin: dict | None = None, **options) -> Kinds:
    """A registry of its own, so that what a test resolves stays out of the product's."""
    return Kinds(what, f"cosim.{what}s", builtin or {}, base, **options)


def test_a_built_in_kind_resolves_from_its_table_and_says_so():
    assert estimators.ESTIMATORS["kalman"].__name__ == "KalmanFilter"
    assert str(estimators.ESTIMATORS.origin("kalman")) == "built-in (estimators.kalman:KalmanFilter)"
    assert CONTROLLERS.origin("thrust-allocation").target == "estimators.allocation:ThrustAllocationController"
    assert faults.FAULT_MODELS["bias"] is faults.Bias and faults.FAULT_MODELS.origin("bias").source == "built-in"
    assert mjcf.PLANTS["vessel"].name == "vessel" and mjcf.PLANTS.origin("vessel").target == "mjcf.vessel:INFO"
    assert {"kalman", "cofd", "lft-uio-sr"} <= set(estimators.ESTIMATORS) and "kalman" in estimators.ESTIMATORS


def test_a_kind_is_imported_on_first_lookup_and_the_entry_points_only_for_a_name_not_built_in():
    """A node that runs a Kalman filter imports no other estimator's module (nor SciPy's optimizer
    or signal processing) and never reads the installed distributions' metadata."""
    code = textwrap.dedent(
        """
        import json, sys
        import estimators, faults, mjcf
        from cosim import kinds
        from estimators.controller import CONTROLLERS
        watched = ["estimators.kalman", "estimators.uio", "estimators.cofd", "estimators.allocation",
                   "estimators.reconciliation", "estimators.adaptive", "mjcf.vessel", "scipy.optimize",
                   "scipy.signal"]
        before = [m for m in watched if m in sys.modules]
        assert "kalman" in estimators.ESTIMATORS and "vessel" in mjcf.PLANTS
        estimators.ESTIMATORS["kalman"], CONTROLLERS["pid"], faults.FAULT_MODELS["bias"], mjcf.PLANTS["masses"]
        assert str(estimators.ESTIMATORS.origin("uio")) == "built-in (estimators.uio:UnknownInputObserver)"
        after = [m for m in watched if m in sys.modules]
        read = kinds._entry_points.cache_info().currsize
        "nothing-like-it" in estimators.ESTIMATORS, "nor-this" in estimators.ESTIMATORS
        print(json.dumps([before, after, read, kinds._entry_points.cache_info().misses]))
        """
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT)
    before, after, read, scans = json.loads(out.stdout)
    assert before == [] and after == ["estimators.kalman"]
    assert read == 0 and scans == 1  # built-in lookups read no metadata; unknown names read it once


def test_a_module_path_resolves_to_the_class_it_names(plugin):
    cls = estimators.ESTIMATORS[f"{plugin}:MeasuredState"]
    assert cls.kind == "measured-state" and str(estimators.ESTIMATORS.origin(f"{plugin}:MeasuredState")) == (
        "module path"
    )
    model = masses_model(("x1", "x2", "x1_minus_x2"))
    estimate = estimators.create(f"{plugin}:MeasuredState", model).step(model.C @ [1.0, 2.0, 0.0, 0.0], np.zeros(1))
    np.testing.assert_allclose(estimate.x[:2], [1.0, 2.0], atol=1e-12)
    assert faults.FAULT_MODELS[f"{plugin}:Offset"].kind == "offset"
    assert mjcf.get(f"{plugin}:MY_MASSES").name == "my-masses"


def test_a_scenario_names_a_plugin_s_estimator_by_module_path(plugin):
    text = MASSES + f'[[estimators]]\nname = "mine"\nkind = "{plugin}:MeasuredState"\n'
    loaded = scenario.parse(text, "plugin.toml")
    assert loaded.estimators[0].kind == f"{plugin}:MeasuredState"
    with pytest.raises(ScenarioError, match=rf"estimators\[0\]\.kind: estimator '{plugin}:NoStep' \(module path\): "):
        scenario.parse(text.replace("MeasuredState", "NoStep"), "plugin.toml")


def test_an_installed_entry_point_resolves_and_names_its_distribution(installed):
    registry = fresh()
    assert registry["measured-state"].__name__ == "MeasuredState"
    assert str(registry.origin("measured-state")) == (
        "entry point of cosim-plugin-example 0.1 (cosim_plugin_example:MeasuredState)"
    )
    assert {"measured-state", "renamed", "broken"} <= set(registry)
    assert fresh("plant", mjcf.PlantInfo, instance=True, key="name")["my-masses"].name == "my-masses"


@pytest.mark.slow
def test_a_run_s_node_processes_resolve_the_plugin_s_kinds_too(installed, tmp_path):
    """End to end: the scenario names its plant by module path (an MJCF file of its own), one
    estimator by entry point and one by module path; the runner designs them and each node process
    (PYTHONPATH inherited) resolves its own again."""
    from cosim.analysis.metrics import compute_metrics
    from cosim.run import run

    text = MASSES.replace("duration = 1.0", "duration = 0.5").replace('"masses"', f'"{installed}:MY_MASSES"') + (
        '[[estimators]]\nname = "by_entry_point"\nkind = "measured-state"\n'
        f'[[estimators]]\nname = "by_path"\nkind = "{installed}:MeasuredState"\n'
    )
    loaded = scenario.LoadedScenario(scenario.parse(text, "plugin.toml"), "plugin.toml", text)
    result = run(loaded, tmp_path / "plugin.mcap")
    assert result.status == "completed" and result.frames_lost == 0
    errors = compute_metrics(result.path)["estimators"]
    assert errors["by_entry_point"]["final_error"] == errors["by_path"]["final_error"] < 1.0


@pytest.mark.parametrize(
    ("name", "message"),
    [
        ("NoStep", "estimator '{p}:NoStep' (module path): missing _step"),
        ("PlainParams", "estimator '{p}:PlainParams' (module path): Params is not a dataclass"),
        ("Nameless", "estimator '{p}:Nameless' (module path): declares no kind (a string)"),
        (
            "Offset",
            "estimator '{p}:Offset' (module path): <class '{p}.Offset'> is not a subclass of estimators.base.Estimator",
        ),
        ("Missing", "estimator '{p}:Missing': cannot import it (AttributeError: module '{p}' has no attribute"),
    ],
)
def test_an_estimator_that_breaks_the_contract_is_refused_in_one_line(plugin, name, message):
    with pytest.raises(KindError) as error:
        fresh()[f"{plugin}:{name}"]
    assert str(error.value).startswith(message.format(p=plugin)) and "\n" not in str(error.value)


def test_the_other_groups_contracts(plugin):
    cases = [
        (fresh("controller", Controller), "NoCommand", "missing step"),
        (fresh("fault", faults.Fault, params=None), "NotADataclass", "not a dataclass"),
        (faults.FAULT_MODELS, "Neither", "not a SensorFault, ActuatorFault or BusFault subclass"),
        (mjcf.PLANTS, "NO_FILE", "its model file /nonexistent/plant.xml does not exist"),
        (mjcf.PLANTS, "MeasuredState", "is not an instance of mjcf._plant.PlantInfo"),
    ]
    for registry, name, problem in cases:
        with pytest.raises(KindError) as error:
            registry[f"{plugin}:{name}"]
        assert str(error.value).endswith(problem) and "\n" not in str(error.value), str(error.value)


def test_a_kind_listed_under_another_name_is_refused(installed):
    table = fresh(builtin={"other": f"{installed}:MeasuredState"})
    with pytest.raises(KindError, match=r"^estimator 'other' \(built-in \(.*\)\): its kind is 'measured-state', not"):
        table["other"]
    with pytest.raises(KindError, match=r"^estimator 'renamed' \(entry point of cosim-plugin-example 0\.1 "):
        table["renamed"]
    with pytest.raises(KindError, match=r"^estimator 'broken': cannot import it \(ModuleNotFoundError: "):
        table["broken"]


def test_an_unknown_kind_gets_the_near_name_and_the_known_ones():
    with pytest.raises(ParameterError, match=r"kind: unknown estimator 'kalmn' \(did you mean 'kalman'\?\); known "):
        estimators.create("kalmn", masses_model())
    with pytest.raises(KeyError, match=r"unknown plant 'vesel' \(did you mean 'vessel'\?\); known plants: masses"):
        mjcf.get("vesel")
    assert "kalmn" not in estimators.ESTIMATORS and "nowhere:Nothing" not in estimators.ESTIMATORS
