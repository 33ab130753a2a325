"""What an FMU plant does when the FMU misbehaves, or its description is unusual (issue 38).

The FMU is cosim's misbehaving test FMU (tests/misbehaving_fmu.py builds it with gcc): a
first-order plant with inputs of every FMI 2.0 type whose parameter ``mode`` makes it loop forever,
segfault, fail, print, or answer wrong directional derivatives from t >= ``trigger`` on.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

from cosim import scenario
from cosim.errors import ModelError, ScenarioError
from cosim.log.metadata import RESULT, ResultRecord
from cosim.log.reader import LogReader
from cosim.log.topics import FmuMessage, TruthInputs, TruthSensors
from cosim.plant import fmu_model
from cosim.plant.fmu import FmuPlant
from cosim.plant.fmu_process import IsolatedFmuPlant
from cosim.run import run
from cosim.scenario.spec import FmuSpec
from tests import misbehaving_fmu
from tests.fmu_scenario import scenario_text

fmpy = pytest.importorskip("fmpy", reason="the 'fmi' extra (FMPy) is not installed")
pytestmark = pytest.mark.skipif(misbehaving_fmu.compiler() is None, reason="no C compiler to build the test FMU")

KALMAN = """
[[estimators]]
name = "kf"
kind = "kalman"
params = { measurement_std = 1e-3, process_std = 1e-2 }
"""


@pytest.fixture(scope="module")
def fmu(tmp_path_factory) -> Path:
    return misbehaving_fmu.build(tmp_path_factory.mktemp("misbehaving"))


def write(folder: Path, fmu: Path, *, interface: str = "co-simulation", fmu_table: str = "", extra: str = "") -> Path:
    path = folder / "misbehaving.toml"
    path.write_text(
        scenario_text(fmu, interface, duration=0.2, dt=0.01, extra=extra, fmu_table=fmu_table, name="misbehaving")
    )
    return path


def messages(log: Path) -> list[FmuMessage]:
    with LogReader(log) as reader:
        return [FmuMessage.read(m) for _, _, m in reader.messages([FmuMessage.TOPIC])]


def result_of(log: Path) -> ResultRecord:
    with LogReader(log) as reader:
        return ResultRecord.from_metadata(reader.metadata()[RESULT], [])


def cli(*args: str, **kwargs) -> subprocess.CompletedProcess:
    # utf-8, not the locale's encoding: an FMU run in this process (FMPy's reference runs) may set C's locale
    return subprocess.run(
        [sys.executable, "-m", "cosim.cli", *args], capture_output=True, encoding="utf-8", timeout=300, **kwargs
    )


@pytest.mark.parametrize("interface", ["co-simulation", "model-exchange"])
def test_undriven_inputs_of_every_type_hold_their_start_values(fmu, interface, tmp_path):
    loaded = scenario.load(write(tmp_path, fmu, interface=interface))
    assert run(loaded, tmp_path / "run.mcap", interface="virtual").status == "completed"
    with LogReader(tmp_path / "run.mcap") as reader:
        inputs = [TruthInputs.read(m).effective for _, _, m in reader.messages([TruthInputs.TOPIC])]
        sensors = [TruthSensors.read(m).values for _, _, m in reader.messages([TruthSensors.TOPIC])]
    assert all(u == {"u": 0.5, "gear": 2.0, "count": 7.0, "on": 1.0} for u in inputs), inputs[0]
    seen = {"u_seen": 0.5, "gear_seen": 2.0, "count_seen": 7.0, "on_seen": 1.0}
    assert all({name: y[name] for name in seen} == seen for y in sensors)


def test_an_enumeration_input_is_only_ever_one_of_its_items(fmu, tmp_path):
    fault = '[[faults]]\nkind = "actuator_offset"\nactuators = ["gear"]\nvalue = [5.0]\nstart = 0.1\n'
    loaded = scenario.load(write(tmp_path, fmu, extra=fault))
    with pytest.raises(ModelError, match=r"input gear \(enumeration Gear\) would be set to 7, which is none of its"):
        run(loaded, tmp_path / "run.mcap", interface="virtual")
    assert result_of(tmp_path / "run.mcap").ticks == 10  # the log ends at the tick before


@pytest.mark.parametrize(
    ("interface", "mode", "line"),
    [
        (
            "co-simulation",
            3,
            "Misbehaving.fmu: fmi2DoStep returned Error at t = 0.1 s; its last message: [Error] "
            "logStatusError: the plant broke at t = 0.1 in fmi2DoStep",
        ),
        ("model-exchange", 3, "Misbehaving.fmu: fmi2GetDerivatives returned Error at t = 0.1"),
        (
            "co-simulation",
            4,
            "Misbehaving.fmu: fmi2DoStep returned Fatal at t = 0.1 s; its last message: [Fatal] "
            "logStatusFatal: out of memory (on purpose)",
        ),
        ("model-exchange", 6, "Misbehaving.fmu: the model-exchange solver (CVode) failed at t = 0.1 s: CVode's error"),
    ],
)
def test_an_error_of_the_fmu_or_its_solver_is_one_line_and_the_log_keeps_it(fmu, interface, mode, line, tmp_path):
    path = write(tmp_path, fmu, interface=interface, fmu_table=f"parameters = {{ mode = {mode}, trigger = 0.1 }}")
    with pytest.raises(ModelError) as error:
        run(scenario.load(path), tmp_path / "run.mcap", interface="virtual")
    assert str(error.value).startswith(line) and "\n" not in str(error.value), str(error.value)
    result = result_of(tmp_path / "run.mcap")
    # co-simulation fails in tick 10's step; model exchange's solver looks beyond t = 0.1 in tick 9's
    assert result.status == "error" and result.error == str(error.value)
    assert result.ticks == (10 if interface == "co-simulation" else 9)
    logged = [m for m in messages(tmp_path / "run.mcap") if m.source == "logger"]
    assert mode == 6 or logged[-1].status in ("Error", "Fatal")


def start_run(path, log) -> subprocess.Popen:
    """``cosim run`` of a scenario file into ``log``, as a user starts it (to be signalled)."""
    return subprocess.Popen(
        [sys.executable, "-m", "cosim.cli", "run", str(path), "--interface", "virtual", "--out", str(log), "-q"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        encoding="utf-8",
    )


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_an_fmu_that_never_returns_is_stopped_by_ctrl_c_and_sigterm(fmu, signum, tmp_path):
    path = write(tmp_path, fmu, fmu_table="parameters = { mode = 1, trigger = 0.05 }")
    log = tmp_path / "run.mcap"
    process = start_run(path, log)
    deadline = time.monotonic() + 120
    while not (log.exists() and log.stat().st_size > 0) and time.monotonic() < deadline:  # the run has started
        time.sleep(0.1)
    time.sleep(1.5)  # and hangs in tick 5
    assert process.poll() is None
    sent = time.monotonic()
    process.send_signal(signum)
    _, err = process.communicate(timeout=30)
    assert time.monotonic() - sent < 2.0
    assert process.returncode == 128 + signum
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Misbehaving.fmu was in fmi2DoStep at t = 0.05 s" in lines[0], err
    result = result_of(log)
    assert result.status == "interrupted" and result.ticks == 5 and "fmi2DoStep" in result.error


def children(pid: int) -> list[int]:
    try:
        return [int(c) for c in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except OSError:
        return []


def running(pid: int) -> bool:
    """Whether process ``pid`` exists and is not a zombie."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_while_the_plan_is_made_is_one_line_and_ends_the_fmus_process(fmu, signum, tmp_path):
    """Before the run's session (its handlers) exists: the plan's linearization hangs in the FMU."""
    path = write(tmp_path, fmu, interface="model-exchange", fmu_table="parameters = { mode = 1, trigger = 0.0 }")
    path.write_text(path.read_text() + KALMAN)
    log = tmp_path / "run.mcap"
    process = start_run(path, log)
    deadline = time.monotonic() + 120
    while not (hosts := children(process.pid)) and time.monotonic() < deadline:  # the FMU's host process
        time.sleep(0.05)
    time.sleep(2.0)  # which hangs in the plan's first call of fmi2GetDerivatives
    assert process.poll() is None and hosts
    sent = time.monotonic()
    process.send_signal(signum)
    _, err = process.communicate(timeout=30)
    assert time.monotonic() - sent < 2.0
    assert process.returncode == 128 + signum
    assert err.strip().splitlines() == [err.strip()] and err.startswith(
        "interrupted while preparing the run: Misbehaving.fmu was in "
    ), err
    assert err.strip().endswith("its process was killed; no log was written") and not log.exists()
    assert not any(running(host) for host in hosts)


@pytest.mark.slow
def test_a_crash_of_the_fmu_ends_the_run_in_one_line_with_a_valid_log(fmu, tmp_path):
    path = write(tmp_path, fmu, fmu_table="parameters = { mode = 2, trigger = 0.05 }")
    log = tmp_path / "run.mcap"
    done = cli("run", str(path), "--interface", "virtual", "--out", str(log), "-q")
    assert done.returncode == 1 and "Traceback" not in done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "Misbehaving.fmu crashed (SIGSEGV) in fmi2DoStep at t = 0.05 s" in lines[0], done.stderr
    result = result_of(log)
    assert result.status == "error" and result.ticks == 5 and "SIGSEGV" in result.error


@pytest.mark.slow
def test_what_the_fmu_prints_goes_to_the_log_and_json_stays_json(fmu, tmp_path):
    path = write(tmp_path, fmu, fmu_table="parameters = { mode = 5, trigger = 0.0 }")
    log = tmp_path / "run.mcap"
    done = cli("run", str(path), "--interface", "virtual", "--out", str(log), "--json")
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["status"] == "completed", done.stdout
    assert "Misbehaving.fmu logged 20 messages (20 Warning) and printed 20 lines" in done.stderr
    said = messages(log)
    printed = [m for m in said if m.source == "stdout"]
    assert [m.message for m in printed[:2]] == ["fmi2DoStep at t = 0", "fmi2DoStep at t = 0.01"]
    assert {(m.status, m.category, m.message) for m in said if m.source == "logger"} == {
        ("Warning", "logStatusWarning", "a chatty step")
    }
    quiet = cli("run", str(path), "--interface", "virtual", "--out", str(tmp_path / "quiet.mcap"), "-q")
    assert quiet.returncode == 0 and quiet.stderr == "", quiet.stderr
    assert quiet.stdout.strip() == str(tmp_path / "quiet.mcap")


def test_the_linearization_reads_the_outputs_as_a_step_completes(fmu):
    """y = gain·x is computed only in fmi2CompletedIntegratorStep (as OpenModelica's FMUs do): read
    right after fmi2SetContinuousStates it is stale, and C came out 0."""
    spec = FmuSpec.model_validate({"interface": "model-exchange", "parameters": {"k": 3.0}})
    plant = FmuPlant(fmu_model.read(fmu, spec), 0.01, 1.0)
    model = plant.linearize(continuous=True)
    y = plant.sensor_names.index("y")
    assert not plant.model.directional
    assert np.allclose(model.A, [[-3.0]], rtol=1e-9) and np.allclose(model.C[y], [2e5], rtol=1e-9)
    assert plant.warnings == []


def test_directional_derivatives_that_disagree_with_differences_are_named(tmp_path):
    fmu = misbehaving_fmu.build(tmp_path, directional=True)
    right = FmuPlant(fmu_model.read(fmu, FmuSpec.model_validate({"interface": "model-exchange"})), 0.01, 1.0)
    assert right.model.directional and np.allclose(right.linearize(continuous=True).A, [[-1.0]])
    assert right.warnings == []
    spec = FmuSpec.model_validate({"interface": "model-exchange", "parameters": {"mode": 7}})
    wrong = IsolatedFmuPlant(fmu_model.read(fmu, spec), 0.01, 1.0)
    model = wrong.linearize(continuous=True)
    assert np.allclose(model.A, [[-2.0]])  # the FMU's (wrong) derivatives are used, and said to disagree
    assert [w.split(", worst")[0] for w in wrong.warnings] == [
        f"Misbehaving.fmu: its directional derivatives and central differences disagree on {n} entries of {m} "
        "(tolerance 0.0001 relative + 1e-06 of the matrix's largest entry)"
        for n, m in ((1, "A"), (1, "B"), (1, "C"), (1, "D"))
    ]
    assert "A[x, x] -2 vs -1" in wrong.warnings[0]
    wrong.close()


def cs_only(fmu: Path, folder: Path) -> Path:
    """The FMU without its model-exchange interface."""
    target = folder / "CoSimulationOnly.fmu"
    with zipfile.ZipFile(fmu) as old, zipfile.ZipFile(target, "w") as new:
        for item in old.infolist():
            data = old.read(item)
            if item.filename == "modelDescription.xml":
                data = data.replace(b'<ModelExchange modelIdentifier="misbehaving" />', b"")
            new.writestr(item, data)
    return target


def test_a_co_simulation_only_fmu_runs_and_a_model_is_asked_only_when_needed(fmu, tmp_path):
    only = cs_only(fmu, tmp_path)
    assert fmpy.read_model_description(str(only)).modelExchange is None
    result = run(scenario.load(write(tmp_path, only)), tmp_path / "run.mcap", interface="virtual")
    assert result.status == "completed"
    with pytest.raises(ScenarioError) as error:
        run(scenario.load(write(tmp_path, only, extra=KALMAN)), tmp_path / "kf.mcap", interface="virtual")
    assert str(error.value) == (
        f"{tmp_path / 'misbehaving.toml'}: estimators[0] (kf, kalman) needs a linear model of the plant: "
        "CoSimulationOnly.fmu has no model-exchange interface to linearize (it is co-simulation only): give the "
        "design model as [plant.state_space], or use a build of the FMU with model exchange"
    )


def test_an_fmu_without_a_float_variable_or_a_state_runs(tmp_path):
    fmu = misbehaving_fmu.build(tmp_path, discrete=True, name="Discrete")
    loaded = scenario.load(write(tmp_path, fmu, extra='inputs = [{ actuator = "count", signal = 3.0 }]'))
    assert run(loaded, tmp_path / "run.mcap", interface="virtual").status == "completed"
    with LogReader(tmp_path / "run.mcap") as reader:
        sensors = [TruthSensors.read(m).values for _, _, m in reader.messages([TruthSensors.TOPIC])]
    assert sensors[0] == {"count_seen": 7.0, "on_seen": 1.0} and sensors[-1] == {"count_seen": 3.0, "on_seen": 1.0}


def test_a_description_that_breaks_the_schema_is_refused_in_one_line_unless_told(fmu, tmp_path):
    broken = tmp_path / "Broken.fmu"
    with zipfile.ZipFile(fmu) as old, zipfile.ZipFile(broken, "w") as new:
        for item in old.infolist():
            data = old.read(item)
            if item.filename == "modelDescription.xml":
                data = data.replace(b"<DefaultExperiment", b'<DefaultExperiment order="1"', 1)
            new.writestr(item, data)
    path = write(tmp_path, broken)
    with pytest.raises(ScenarioError) as error:
        scenario.load(path)
    assert "\n" not in str(error.value)
    assert str(error.value).startswith(f"{path}: plant.model: Broken.fmu: its modelDescription.xml is not valid")
    assert "attribute 'order'" in str(error.value)
    assert str(error.value).endswith("to run it anyway: [plant.fmu] validate = false (or cosim run --no-validate)")
    done = cli("run", str(path), "--interface", "virtual", "--out", str(tmp_path / "run.mcap"), "-q", "--no-validate")
    assert done.returncode == 0, done.stderr


def test_bus_signals_take_the_fmus_ranges_nominals_and_units(fmu, tmp_path):
    info = fmu_model.read(fmu, FmuSpec()).info()
    x, y, gear = info.state("x"), info.sensor("y"), info.actuator("gear")
    assert (x.unit, x.minimum, x.maximum, x.resolution) == ("m", -10.0, 10.0, 1e-6)  # declared min and max
    assert (y.unit, y.minimum, y.maximum) == ("N", -1e8, 1e8)  # ±1000 nominals
    assert y.resolution == pytest.approx(1e-6 * 1e5)  # as many bits as the default range
    assert (gear.minimum, gear.maximum, gear.resolution) == (-2000.0, 2000.0, 1.0)  # ±1000 start values
    loaded = scenario.load(write(tmp_path, fmu, extra=KALMAN))  # y = 2e5 x: beyond ±1000 from tick 0
    assert run(loaded, tmp_path / "run.mcap", interface="virtual").status == "completed"
    assert "SG_ y : " in loaded.scenario.codec().dbc and '"N"' in loaded.scenario.codec().dbc


def test_set_takes_a_quoted_dotted_name(tmp_path):
    loaded = scenario.load(ROOT_FMUS / "vanderpol-bias.toml")
    assert scenario.parse_setting('plant.fmu.parameters."mass.m"=3') == ('plant.fmu.parameters."mass.m"', 3)
    with pytest.raises(ScenarioError, match="has no parameter 'mass.m'"):
        scenario.apply(loaded, [scenario.parse_setting('plant.fmu.parameters."mass.m"=3')])
    changed = scenario.apply(loaded, [scenario.parse_setting("plant.fmu.parameters.'mu'=2.5")])
    assert changed.scenario.plant.fmu.parameters == {"mu": 2.5}


ROOT_FMUS = Path(__file__).resolve().parent / "data" / "fmus"
