"""Scenario files: the built-in ones load; bad ones give one clear error naming the field."""

from __future__ import annotations

import subprocess
import sys

import pytest

from cosim import scenario
from cosim.errors import ScenarioError

BASE = """
name = "t"
duration = 1.0
sample_time = 0.01
[plant]
model = "masses"
sensors = ["x1", "x2", "x1_minus_x2"]
"""


def test_builtin_scenarios_load():
    names = scenario.builtin_names()
    assert "masses-bias" in names
    for name in names:
        loaded = scenario.load(name)
        assert loaded.scenario.name == name and loaded.source == f"builtin:{name}" and loaded.scenario.description


def test_default_scenario_is_the_one_the_issue_describes():
    s = scenario.load().scenario
    assert s.name == "masses-bias" and s.sample_time == 0.01 and s.duration == 30.0
    assert s.sensors == ("x1", "x2", "x1_minus_x2")
    (bias,) = s.faults
    assert bias.kind == "bias" and bias.value == [1.0, -1.5, 0.5] and bias.start == 5.0
    assert [(e.name, e.kind) for e in s.estimators] == [("uniform", "pseudoinverse"), ("kalman", "kalman")]
    assert s.inputs[0].actuator == "force" and s.inputs[0].signal.kind == "sine"


def test_scalars_stand_for_vectors_and_numbers_for_waveforms():
    s = scenario.parse(BASE + '[[noise]]\nkind = "gaussian_noise"\nstd = 0.1\n[[faults]]\nkind = "gain"\ngain = 0.5\n')
    assert s.noise[0].std == [0.1] and s.faults[0].gain[0].kind == "constant"


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        ('[[faults]]\nkind = "bias"\nvalu = [1, 2, 3]\n', r"faults\[0\]: unknown key 'valu' \(did you mean 'value'\?\)"),
        ('[[faults]]\nkind = "bias"\nvalue = [1, 2]\n', r"faults\[0\]\.value: has 2 values for 3 channels"),
        ('[[faults]]\nkind = "biass"\nvalue = 1\n', r"faults\[0\]: unknown kind 'biass'; expected one of 'bias'"),
        ('[[faults]]\nkind = "bias"\nvalue = 1\nsensors = ["x3"]\n', r"faults\[0\]\.sensors: masses has no transmitted sensor 'x3'"),
        ('[[faults]]\nkind = "bias"\nvalue = 1\nstart = 3\nend = 2\n', r"faults\[0\]: end \(2\.0\) must be after start \(3\.0\)"),
        ('[[faults]]\nkind = "dropout"\nprobability = 1.5\n', r"faults\[0\]\.probability: Input should be less than or equal to 1"),
        ('[[faults]]\nkind = "gain"\ngain = [1, {kind = "ramp"}, 0.5]\n', r"faults\[0\]\.gain\[1\]\.slope: required but missing"),
        ('[[faults]]\nkind = "bias"\nvalue = 1\namplitude = {kind = "sin", amplitude = 1}\n', r"faults\[0\]\.amplitude: unknown kind 'sin'"),
        ('[[noise]]\nkind = "gaussian_noise"\nstd = -1\n', r"noise\[0\]\.std: must be non-negative"),
        ('[[noise]]\nkind = "bias"\nvalue = 1\n', r"noise\[0\]: unknown kind 'bias'; expected one of 'gaussian_noise', 'uniform_noise'"),
        ('[[inputs]]\nactuator = "forse"\nsignal = 1\n', r"inputs\[0\]\.actuator: masses has no actuator 'forse' \(did you mean 'force'\?\)"),
        ('[[estimators]]\nname = "a b"\nkind = "kalman"\n', r"estimators\[0\]\.name: String should match pattern"),
        ('[[estimators]]\nname = "k"\nkind = "kalmn"\n', r"estimators\[0\]\.kind: unknown estimator 'kalmn' \(did you mean 'kalman'\?\)"),
        ('[bus]\nfd = "yes"\n', r"bus\.fd: Input should be a valid boolean"),
        ('[bus.sensors.x9]\nmaximum = 3\n', r"bus\.sensors: masses has no transmitted sensor 'x9'"),
        ('[bus]\ninterface = "pcan"\n', r"bus\.interface: Input should be 'virtual'"),
    ],
)
def test_bad_scenarios_name_the_field(extra, message):
    with pytest.raises(ScenarioError, match=message) as info:
        scenario.parse(BASE + extra, "bad.toml")
    assert str(info.value).startswith("bad.toml: ")


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (BASE.replace("duration = 1.0", "duration = -1.0"), r"duration: Input should be greater than 0"),
        (BASE.replace("duration = 1.0", 'duration = "long"'), r"duration: Input should be a valid number"),
        (BASE.replace("duration = 1.0", 'duration = "30"'), r"duration: Input should be a valid number"),
        (BASE.replace('model = "masses"', 'model = "tanks"'), r"plant\.model: unknown plant 'tanks'; known plants: masses"),
        (BASE.replace('name = "t"\n', ""), r"name: required but missing"),
        (BASE + "colour = 1\n", r"plant: unknown key 'colour'"),
        (BASE.replace("sample_time = 0.01", "sample_time = 2.0"), r"sample_time: 2\.0 s is longer than the duration"),
        ('name = "x"\n[plant\n', r"invalid TOML: Expected '\]' at the end of a table declaration \(at line 2, column 7\)"),
    ],
)
def test_bad_top_level_fields(text, message):
    with pytest.raises(ScenarioError, match=message):
        scenario.parse(text, "bad.toml")


def test_all_problems_are_reported_together():
    text = BASE.replace("duration = 1.0", "duration = 0") + '[[faults]]\nkind = "bias"\n'
    with pytest.raises(ScenarioError) as info:
        scenario.parse(text, "bad.toml")
    message = str(info.value)
    assert message.startswith("bad.toml: 2 problems:")
    assert "duration: Input should be greater than 0" in message and "faults[0].value: required but missing" in message


def test_unknown_scenario_name_lists_the_builtin_ones():
    with pytest.raises(ScenarioError, match=r"no scenario 'nope': not a file and not a built-in scenario \(built-in: .*masses-bias"):
        scenario.load("nope")


def test_cli_reports_a_bad_scenario_in_one_message_without_traceback(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(BASE + '[[faults]]\nkind = "bias"\nvalue = [1, 2]\n')
    result = subprocess.run([sys.executable, "-m", "cosim.cli", "run", str(bad)], capture_output=True, text=True)
    assert result.returncode == 1
    assert "Traceback" not in result.stderr
    assert result.stderr.strip() == f"error: {bad}: faults[0].value: has 2 values for 3 channels; give one per channel (or one for all)"


def test_estimator_parameter_errors_name_the_estimator(tmp_path):
    from cosim.runner import Run

    bad = tmp_path / "bad.toml"
    bad.write_text(BASE + '[[estimators]]\nname = "u"\nkind = "pseudoinverse"\nparams = { poles = [0.5] }\n')
    with pytest.raises(ScenarioError, match=r"estimators\[0\] \(u\): params\.poles: need 4 poles"):
        Run(scenario.load(bad), tmp_path / "x.mcap")


def test_sample_time_that_is_not_a_multiple_of_the_timestep(tmp_path):
    from cosim.runner import Run

    bad = tmp_path / "bad.toml"
    bad.write_text(BASE.replace("sample_time = 0.01", "sample_time = 0.0105"))
    with pytest.raises(ScenarioError, match=r"sample_time = 0\.0105 s is not a whole multiple of the timestep 0\.001 s"):
        Run(scenario.load(bad), tmp_path / "x.mcap")
