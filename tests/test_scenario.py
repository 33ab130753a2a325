"""Scenario files: the built-in ones load; bad ones give one clear error naming the field."""

from __future__ import annotations

import subprocess
import sys

import pytest

from cosim import scenario
from cosim.errors import ScenarioError
from tests.snippets import MASSES

BASE = MASSES


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
        (
            '[[faults]]\nkind = "bias"\nvalu = [1, 2, 3]\n',
            r"faults\[0\]: unknown key 'valu' \(did you mean 'value'\?\)",
        ),
        ('[[faults]]\nkind = "bias"\nvalue = [1, 2]\n', r"faults\[0\]\.value: has 2 values for 3 channels"),
        ('[[faults]]\nkind = "biass"\nvalue = 1\n', r"faults\[0\]: unknown fault 'biass' \(did you mean 'bias'\?\)"),
        (
            '[[faults]]\nkind = "bias"\nvalue = 1\nsensors = ["x3"]\n',
            r"faults\[0\]\.sensors: masses has no transmitted sensor 'x3'",
        ),
        (
            '[[faults]]\nkind = "bias"\nvalue = 1\nstart = 3\nend = 2\n',
            r"faults\[0\]: end \(2\.0\) must be after start \(3\.0\)",
        ),
        (
            '[[faults]]\nkind = "dropout"\nprobability = 1.5\n',
            r"faults\[0\]\.probability: Input should be less than or equal to 1",
        ),
        (
            '[[faults]]\nkind = "gain"\ngain = [1, {kind = "ramp"}, 0.5]\n',
            r"faults\[0\]\.gain\[1\]\.slope: required but missing",
        ),
        (
            '[[faults]]\nkind = "bias"\nvalue = 1\namplitude = {kind = "sin", amplitude = 1}\n',
            r"faults\[0\]\.amplitude: unknown kind 'sin'",
        ),
        ('[[noise]]\nkind = "gaussian_noise"\nstd = -1\n', r"noise\[0\]\.std: must be non-negative"),
        (
            '[[noise]]\nkind = "bias"\nvalue = 1\n',
            r"noise\[0\]: unknown kind 'bias'; expected one of 'gaussian_noise', 'uniform_noise'",
        ),
        (
            '[[inputs]]\nactuator = "forse"\nsignal = 1\n',
            r"inputs\[0\]\.actuator: masses has no actuator 'forse' \(did you mean 'force'\?\)",
        ),
        ('[[estimators]]\nname = "a b"\nkind = "kalman"\n', r"estimators\[0\]\.name: String should match pattern"),
        (
            '[[estimators]]\nname = "k"\nkind = "kalmn"\n',
            r"estimators\[0\]\.kind: unknown estimator 'kalmn' \(did you mean 'kalman'\?\)",
        ),
        ('[bus]\nfd = "yes"\n', r"bus\.fd: Input should be a valid boolean"),
        ("[bus.sensors.x9]\nmaximum = 3\n", r"bus\.sensors: masses has no transmitted sensor 'x9'"),
        ('[bus]\ninterface = "pcan"\n', r"bus\.interface: Input should be 'udp_multicast', 'socketcan' or 'virtual'"),
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
        (
            BASE.replace('model = "masses"', 'model = "tanks"'),
            r"plant\.model: unknown plant 'tanks'; known plants: masses",
        ),
        (BASE.replace('name = "t"\n', ""), r"name: required but missing"),
        (BASE + "colour = 1\n", r"plant: unknown key 'colour'"),
        (BASE.replace("sample_time = 0.01", "sample_time = 2.0"), r"sample_time: 2\.0 s is longer than the duration"),
        (
            'name = "x"\n[plant\n',
            r"invalid TOML: Expected '\]' at the end of a table declaration \(at line 2, column 7\)",
        ),
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
    with pytest.raises(
        ScenarioError, match=r"no scenario 'nope': not a file and not a built-in scenario \(built-in: .*masses-bias"
    ):
        scenario.load("nope")


def test_cli_reports_a_bad_scenario_in_one_message_without_traceback(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(BASE + '[[faults]]\nkind = "bias"\nvalue = [1, 2]\n')
    result = subprocess.run([sys.executable, "-m", "cosim.cli", "run", str(bad)], capture_output=True, text=True)
    assert result.returncode == 1
    assert "Traceback" not in result.stderr
    assert (
        result.stderr.strip()
        == f"error: {bad}: faults[0].value: has 2 values for 3 channels; give one per channel (or one for all)"
    )


def test_estimator_parameter_errors_name_the_estimator(tmp_path):
    from cosim.run import Run

    bad = tmp_path / "bad.toml"
    bad.write_text(BASE + '[[estimators]]\nname = "u"\nkind = "pseudoinverse"\nparams = { poles = [0.5] }\n')
    with pytest.raises(ScenarioError, match=r"estimators\[0\] \(u\): params\.poles: need 4 poles"):
        Run(scenario.load(bad), tmp_path / "x.mcap")


def test_sample_time_that_is_not_a_multiple_of_the_timestep(tmp_path):
    from cosim.run import Run

    bad = tmp_path / "bad.toml"
    bad.write_text(
        BASE.replace("sample_time = 0.01", "sample_time = 0.0105").replace("duration = 1.0", "duration = 1.05")
    )
    with pytest.raises(
        ScenarioError, match=r"sample_time = 0\.0105 s is not a whole multiple of the timestep 0\.001 s"
    ):
        Run(scenario.load(bad), tmp_path / "x.mcap")


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        ('[[faults]]\nkind = "bias"\nvalue = nan\n', r"faults\[0\]\.value: Input should be a finite number"),
        ('[[faults]]\nkind = "gain"\ngain = inf\n', r"faults\[0\]\.gain: Input should be a finite number"),
        ('[[faults]]\nkind = "bias"\nvalue = 1\nend = nan\n', r"faults\[0\]: end \(nan\) must be after start"),
        (
            '[[faults]]\nkind = "bias"\nvalue = 1\n[[faults]]\nkind = "drift"\nrate = 1\nname = "bias0"\n',
            r"two noise models or faults are labelled 'bias0'",
        ),
        (
            '[[estimators]]\nname = "u"\nkind = "pseudoinverse"\nparams = { weights = "abc" }\n',
            r"estimators\[0\]\.params\.weights: expected a list of numbers, got 'abc'",
        ),
        (
            '[[estimators]]\nname = "k"\nkind = "kalman"\nparams = { measurement_std = "a" }\n',
            r"params\.measurement_std: expected a number or a list of numbers",
        ),
        (
            '[[estimators]]\nname = "u"\nkind = "pseudoinverse"\nparams = { poles = ["a", 1, 2, 3] }\n',
            r"params\.poles\[0\]: expected a number, got 'a'",
        ),
        ("[bus.sensors.x1]\nminimum = 3\nmaximum = 2\n", r"bus\.sensors\.x1: minimum must be below maximum"),
        ("[bus.states.v1]\nresolution = 1e-15\n", r"needs \d+ bits .* \[bus\.states\.v1\], or use CAN FD"),
    ],
)
def test_non_finite_values_labels_params_and_bus_are_checked_on_load(extra, message):
    with pytest.raises(ScenarioError, match=message):
        scenario.parse(
            BASE + extra + ('[[estimators]]\nname = "e"\nkind = "kalman"\n' if "states" in extra else ""), "bad.toml"
        )


def test_an_open_ended_fault_may_say_end_inf():
    s = scenario.parse(BASE + '[[faults]]\nkind = "bias"\nvalue = 1\nend = inf\n')
    assert s.faults[0].end == float("inf")


def test_duration_must_be_a_whole_number_of_ticks_and_infinity_is_refused():
    with pytest.raises(
        ScenarioError, match=r"duration: 0\.015 s is not a whole number of sample times \(0\.01 s\); use 0\.01 or 0\.02"
    ):
        scenario.parse(BASE.replace("duration = 1.0", "duration = 0.015"))
    with pytest.raises(ScenarioError, match=r"duration: Input should be a finite number"):
        scenario.parse(BASE.replace("duration = 1.0", "duration = inf"))


def test_scenario_names_are_safe_in_file_names():
    with pytest.raises(ScenarioError, match=r"name: String should match pattern"):
        scenario.parse(BASE.replace('name = "t"', 'name = "../x"'))


def test_a_negative_seed_override_is_refused():
    with pytest.raises(ScenarioError, match=r"seed: Input should be greater than or equal to 0"):
        scenario.parse(BASE).with_seed(-1)
    assert scenario.parse(BASE).with_seed(7).seed == 7


def test_fault_onset_is_the_first_tick_at_or_after_start_even_when_kτ_rounds_below():
    """0.33 / 0.03 = 10.999… in floating point: the fault must still start at tick 11 (t = 0.33 s)."""
    from cosim.run.plan import first_tick_at
    from cosim.scenario import build_faults

    s = scenario.parse(
        BASE.replace("sample_time = 0.01", "sample_time = 0.03").replace("duration = 1.0", "duration = 0.6")
        + '[[faults]]\nkind = "bias"\nvalue = 1\nstart = 0.33\n'
    )
    assert 11 * 0.03 < 0.33  # the trap
    assert first_tick_at(s, 0.33) == 11
    injector = build_faults(s)
    assert not injector.sensor_faults[0].active(s.time(10)) and injector.sensor_faults[0].active(s.time(11))


def test_settings_applied_in_turn_all_hold():
    once = scenario.apply(scenario.load("masses-bias"), [("duration", 1.0)])
    twice = scenario.apply(once, [("faults[0].value", 0.5)])
    assert twice.scenario.duration == 1.0 and list(twice.scenario.faults[0].value) == [0.5]
    assert twice.settings == (("duration", 1.0), ("faults[0].value", 0.5))
