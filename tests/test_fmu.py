"""FMU plants (FMI 2.0 and 3.0 through FMPy) and the export of a scenario's plant as an FMU.

The FMUs are the Modelica Association's Reference FMUs for Linux x86-64 (tests/data/fmus,
BSD-2-Clause, LICENSE.txt there). The reference importer is FMPy's ``simulate_fmu``: a run's plant
trajectory (the /truth/state of its log) equals what it computes with the same step size and the
same inputs, bit for bit here, within 1e-12 by the test.
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from cosim import scenario
from cosim.errors import ScenarioError
from cosim.log.reader import LogReader
from cosim.log.topics import TruthFaults, TruthInputs, TruthState
from cosim.plant import build_plant, fmu_model
from cosim.plant.fmu import FmuPlant
from cosim.run import run
from cosim.scenario.spec import FmuSpec
from tests.conftest import ROOT
from tests.fmu_scenario import scenario_text

fmpy = pytest.importorskip("fmpy", reason="the 'fmi' extra (FMPy) is not installed")

FMUS = ROOT / "tests" / "data" / "fmus"
VANDERPOL_SCENARIO = FMUS / "vanderpol-bias.toml"
INTERFACES = ("co-simulation", "model-exchange")
TOLERANCE = 1e-12


def load_text(text: str, folder: Path) -> scenario.LoadedScenario:
    path = folder / "scenario.toml"
    path.write_text(text)
    return scenario.load(path)


def truth(log: Path) -> dict[str, np.ndarray]:
    """The log's states, effective inputs, disturbances and measured sensors per tick."""
    rows: dict[str, list[list[float]]] = {"x": [], "u": [], "d": [], "measured": []}
    with LogReader(log) as reader:
        for topic, _, message in reader.messages([TruthState.TOPIC, TruthInputs.TOPIC, TruthFaults.TOPIC]):
            if topic == TruthState.TOPIC:
                rows["x"].append(list(TruthState.read(message).values.values()))
            elif topic == TruthInputs.TOPIC:
                inputs = TruthInputs.read(message)
                rows["u"].append(list(inputs.effective.values()))
                rows["d"].append(list(inputs.disturbance.values()))
            else:
                measured = TruthFaults.read(message).measured.values()
                rows["measured"].append([np.nan if v is None else v for v in measured])
    return {key: np.array(value, dtype=float) for key, value in rows.items()}


def staircase(fields: list[tuple[str, tuple[int, ...]]], values: np.ndarray, dt: float) -> np.ndarray:
    """FMPy's input table for inputs (``fields``: name and shape, their values side by side in a
    row of ``values`` per tick) held from t_k to t_{k+1}: a step (a repeated time) where a value
    changes, which FMPy takes as an input event."""
    rows, previous = [], None
    for k, value in enumerate(values):
        if previous is not None and not np.array_equal(previous, value):
            rows.append((k * dt, previous))
        rows.append((k * dt, value))
        previous = value
    rows.append((len(values) * dt, previous))
    dtype = [("time", float)] + [(name, float, shape) if shape else (name, float) for name, shape in fields]
    table = np.zeros(len(rows), dtype=dtype)
    for i, (t, value) in enumerate(rows):
        table[i]["time"], start = t, 0
        for name, shape in fields:
            size = int(np.prod(shape)) if shape else 1
            table[i][name] = value[start : start + size] if shape else value[start]
            start += size
    return table


def reference(fmu: Path, interface: str, duration: float, dt: float, outputs: list[str], **kwargs) -> np.ndarray:
    result = fmpy.simulate_fmu(
        str(fmu),
        fmi_type="CoSimulation" if interface == "co-simulation" else "ModelExchange",
        stop_time=duration,
        output_interval=dt,
        output=outputs,
        record_events=False,
        **kwargs,
    )
    return np.column_stack([np.asarray(result[name], dtype=float).reshape(len(result), -1) for name in outputs])


STATE_SPACE_INPUTS = """
inputs = [
  { actuator = "u_1", signal = { kind = "sine", amplitude = 1.0, frequency = 0.5 } },
  { actuator = "u_2", signal = { kind = "square", amplitude = 0.5, frequency = 2.0 } },
  { actuator = "u_3", signal = 0.25 },
]
"""

STATE_SPACE_DISTURBANCES = """
disturbances = [
  { input = "u_1", signal = { kind = "sine", amplitude = 2.0, frequency = 1.0 } },
  { input = "u_3", signal = { kind = "ramp", slope = 0.5 } },
]
"""
STATE_SPACE_A = "A = [0, 1, 0, -2, -0.5, 0, 0, 0, -1]"

CASES = [
    *((f"fmi{v}/VanDerPol.fmu", "parameters = { mu = 1.5 }", "", ["x0", "x1"]) for v in (2, 3)),
    *((f"fmi{v}/Dahlquist.fmu", "parameters = { k = 2.0 }", "", ["x"]) for v in (2, 3)),
    *((f"fmi{v}/BouncingBall.fmu", "", "", ["h", "v"]) for v in (2, 3)),
    ("fmi3/StateSpace.fmu", f"parameters = {{ {STATE_SPACE_A} }}", STATE_SPACE_INPUTS, ["x"]),
    (
        "fmi3/StateSpace.fmu",
        f'parameters = {{ {STATE_SPACE_A} }}\ndisturbances = ["u"]',
        STATE_SPACE_DISTURBANCES,
        ["x"],
    ),
]


@pytest.mark.parametrize("interface", INTERFACES)
@pytest.mark.parametrize(
    ("name", "table", "inputs", "states"), CASES, ids=[*(c[0] for c in CASES[:-1]), "StateSpace-disturbances"]
)
def test_the_plant_trajectory_of_a_run_equals_fmpys(name, table, inputs, states, interface, tmp_path):
    fmu, duration, dt = FMUS / name, 2.0, 0.01
    loaded = load_text(scenario_text(fmu, interface, duration=duration, dt=dt, fmu_table=table, extra=inputs), tmp_path)
    result = run(loaded, tmp_path / "run.mcap", interface="virtual")
    assert result.status == "completed"
    logged = truth(tmp_path / "run.mcap")
    spec = loaded.scenario.plant.fmu
    assert spec is not None
    kwargs: dict = {"start_values": dict(spec.parameters)}
    if inputs:
        model = fmu_model.read(fmu, spec)
        u = (model.actuators or model.disturbances)[0].variable
        kwargs["input"] = staircase([(u.name, tuple(u.shape))], logged["u" if model.actuators else "d"], dt)
    expected = reference(fmu, interface, duration, dt, states, **kwargs)
    # /truth/state holds x_k for k = 0 … N-1, FMPy's result x(t_k) for k = 0 … N.
    assert logged["x"].shape == expected[:-1].shape
    assert np.abs(logged["x"] - expected[:-1]).max() <= TOLERANCE
    assert np.abs(logged["x"]).max() > 0.1  # it moved


def vanderpol(version: int, interface: str = "model-exchange", mu: float = 1.5, **changes) -> FmuPlant:
    spec = FmuSpec.model_validate({"interface": interface, "parameters": {"mu": mu}})
    model = fmu_model.read(FMUS / f"fmi{version}" / "VanDerPol.fmu", spec)
    return FmuPlant(dataclasses.replace(model, **changes), 0.01, 1.0)


@pytest.mark.parametrize("version", [2, 3])
def test_the_linearization_is_van_der_pols_jacobian_by_directional_derivatives_and_by_differences(version):
    """ẋ0 = x1, ẋ1 = μ (1 − x0²) x1 − x0 at the start point (2, 0): A = [[0, 1], [−1, −3μ]], and
    the drift ẋ = (0, −2) there (no equilibrium); by default the model is taken at the equilibrium
    (0, 0) reached from it, A = [[0, 1], [−1, μ]]."""
    mu = 1.5
    exact = np.array([[0.0, 1.0], [-1.0, -3.0 * mu]])
    plant = vanderpol(version, mu=mu)
    start = plant.state()
    assert plant.model.directional  # both Reference FMUs declare them (FMI 2 and FMI 3 spellings)
    by_derivatives = plant.linearize(start, continuous=True)
    by_differences = vanderpol(version, mu=mu, directional=False).linearize(start, continuous=True)
    assert np.array_equal(by_derivatives.A, exact)
    assert np.abs(by_differences.A - exact).max() < 1e-8
    assert np.array_equal(by_derivatives.C, np.eye(2)) and by_derivatives.x_op.tolist() == [2.0, 0.0]
    assert by_derivatives.drift.tolist() == [0.0, -2.0]
    discrete = plant.linearize(start)
    assert discrete.dt == 0.01 and np.allclose(discrete.A, np.eye(2) + 0.01 * exact, atol=1e-3)
    at_rest = plant.linearize(continuous=True)
    assert np.array_equal(at_rest.A, [[0.0, 1.0], [-1.0, mu]]) and not at_rest.affine
    assert np.abs(at_rest.x_op).max() < 1e-12


def test_a_linear_fmu_linearizes_to_its_own_matrices():
    A = np.array([[0.0, 1.0, 0.0], [-2.0, -0.5, 0.0], [0.0, 0.0, -1.0]])
    B = np.arange(9.0).reshape(3, 3) / 10
    C = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [1.0, 1.0, 1.0]])
    D = np.diag([0.5, 0.0, 0.0])
    parameters = {name: m.ravel().tolist() for name, m in (("A", A), ("B", B), ("C", C), ("D", D))}
    spec = FmuSpec.model_validate({"parameters": parameters})
    plant = FmuPlant(fmu_model.read(FMUS / "fmi3" / "StateSpace.fmu", spec), 0.1, 1.0)
    model = plant.linearize(continuous=True)
    assert plant.state_names == ("x_1", "x_2", "x_3") and plant.actuator_names == ("u_1", "u_2", "u_3")
    for found, exact in ((model.A, A), (model.B, B), (model.C, C), (model.D, D)):
        assert np.abs(found - exact).max() < 1e-9


def test_bus_signals_take_the_fmus_units_ranges_and_start_values():
    spec = FmuSpec.model_validate({"bound": 50.0})
    info = fmu_model.read(FMUS / "fmi3" / "BouncingBall.fmu", spec).info()
    h, v = info.sensor("h"), info.sensor("v")
    assert (h.unit, v.unit) == ("m", "m/s") and (h.minimum, h.maximum) == (-50.0, 50.0)
    assert info.name == "BouncingBall.fmu" and [c.name for c in info.states] == ["h", "v"]
    plant = FmuPlant(fmu_model.read(FMUS / "fmi3" / "BouncingBall.fmu", spec), 0.01, 1.0)
    assert plant.state().tolist() == [1.0, 0.0]  # the start values
    model = plant.linearize(continuous=True)
    assert np.array_equal(model.A, [[0.0, 1.0], [0.0, 0.0]])


def test_the_fmus_units_reach_the_dbc_the_schemas_the_figures_and_the_exports(tmp_path):
    """BouncingBall's units come from its type definitions (``declaredType="Position"``: m)."""
    from cosim.analysis.export import export
    from cosim.analysis.plot import plot

    kalman = '[[estimators]]\nname = "kf"\nkind = "kalman"\nparams = { measurement_std = 1e-3, process_std = 1e-2 }\n'
    text = scenario_text(
        FMUS / "fmi3" / "BouncingBall.fmu", "model-exchange", duration=0.2, dt=0.01, fmu_table='isolation = "none"'
    )
    loaded = load_text(text + kalman, tmp_path)
    log = tmp_path / "ball.mcap"
    assert run(loaded, log, interface="virtual").status == "completed"
    dbc = loaded.scenario.codec().dbc
    assert "SG_ h : " in dbc and '"m" ' in dbc and '"m/s" ' in dbc
    with LogReader(log) as reader:
        schemas = reader.schemas()
    unit = {  # the unit at the end of each field's description: "<description> [<unit>]"
        (topic, name): field["description"].rpartition("[")[2].rstrip("]")
        for topic, schema in schemas.items()
        for name, field in schema["properties"].items()
        if "[" in field.get("description", "")
    }
    assert unit[("/truth/state", "h")] == unit[("/can/SENSOR_h", "h")] == "m"
    assert unit[("/truth/sensors", "v")] == unit[("/can/SENSOR_v", "v")] == "m/s"
    assert {unit[(t, n)] for t, n in unit if n.startswith("xhat_")} == {"m", "m/s"}  # the estimates' frames
    columns = export(log, "csv", tmp_path / "ball.csv").path.read_text().splitlines()[0].split(",")
    assert {"state.h [m]", "state.v [m/s]", "SENSOR_h.h [m]", "kf.xhat_v [m/s]"} <= set(columns)
    figure = next(p for p in plot(log, tmp_path / "plots", "svg") if p.name == "estimates.svg").read_text()
    assert ">h [m]</text>" in figure and ">v [m/s]</text>" in figure  # the y labels (SVG keeps text as text)


def test_outputs_named_as_states_change_the_model_coordinates(tmp_path):
    """States s = (x1, x0) swap the continuous states: A_s = P A P⁻¹, at the equilibrium (0, 0)
    reached from the start values (2, 0), where A = [[0, 1], [−1, μ]]."""
    spec = FmuSpec.model_validate({"states": ["x1", "x0"], "parameters": {"mu": 1.0}})
    plant = FmuPlant(fmu_model.read(FMUS / "fmi3" / "VanDerPol.fmu", spec), 0.01, 1.0)
    model = plant.linearize(continuous=True)
    assert plant.state_names == ("x1", "x0") and plant.state().tolist() == [0.0, 2.0]
    assert np.array_equal(model.A, [[1.0, -1.0], [1.0, 0.0]])
    assert np.array_equal(model.C, [[0.0, 1.0], [1.0, 0.0]])
    assert "linearized at the equilibrium x1 = 0, x0 = 0 reached from them" in plant.operating_point


def test_parameters_come_from_the_scenario_and_from_set(tmp_path):
    loaded = scenario.apply(scenario.load(VANDERPOL_SCENARIO), [("plant.fmu.parameters.mu", 2.5)])
    plant = build_plant(loaded.scenario)
    assert plant.linearize(continuous=True).A[1, 1] == 2.5  # μ (1 − x0²) at the equilibrium x0 = 0
    assert Path(loaded.scenario.plant.model).is_absolute() and Path(loaded.scenario.plant.model).is_file()


def test_the_vanderpol_scenario_estimates_its_states_until_the_bias(tmp_path):
    out = tmp_path / "vdp.mcap"
    result = run(scenario.load(VANDERPOL_SCENARIO), out, interface="virtual")
    assert result.status == "completed" and result.frames_lost == 0
    logged = truth(out)
    bias_from = round(4.0 / 0.01)
    assert np.all(logged["measured"][bias_from:, 0] - logged["x"][bias_from:, 0] > 0.49)
    report = subprocess.run(
        [sys.executable, "-m", "cosim.cli", "inspect", str(out), "--json"], capture_output=True, text=True
    )
    assert report.returncode == 0, report.stderr


@pytest.mark.slow
def test_the_vanderpol_scenario_runs_with_node_processes(tmp_path):
    out = tmp_path / "vdp-udp.mcap"
    result = subprocess.run(
        [sys.executable, "-m", "cosim.cli", "run", str(VANDERPOL_SCENARIO), "--out", str(out), "-q"],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr
    virtual = tmp_path / "vdp-virtual.mcap"
    run(scenario.load(VANDERPOL_SCENARIO), virtual, interface="virtual")
    assert np.array_equal(truth(out)["x"], truth(virtual)["x"])


def test_the_log_of_an_fmu_plant_opens_in_every_reader(tmp_path):
    from tests.test_mcap_readers import read_with_mcap, read_with_pybag

    out = tmp_path / "vdp.mcap"
    run(scenario.load(VANDERPOL_SCENARIO), out, interface="virtual")
    official = read_with_mcap(out)
    assert official["messageCount"] > 5000 and read_with_pybag(out) == official


@pytest.mark.slow
def test_the_log_of_an_fmu_plant_opens_in_the_typescript_reader(tmp_path):
    import json

    from tests.test_mcap_readers import read_with_mcap, typescript_reader

    folder = typescript_reader()
    out = tmp_path / "vdp.mcap"
    run(scenario.load(VANDERPOL_SCENARIO), out, interface="virtual")
    result = subprocess.run(["node", str(folder / "read_mcap.mjs"), str(out)], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    seen = json.loads(result.stdout)
    for key in ("library", "compression", "chunks", "profile"):
        seen.pop(key)
    assert seen == read_with_mcap(out)


def rewritten(source: Path, target: Path, change) -> Path:
    """A copy of an FMU with ``change(name, data) -> (name, data)`` applied to each member."""
    with zipfile.ZipFile(source) as old, zipfile.ZipFile(target, "w") as new:
        for item in old.infolist():
            name, data = change(item.filename, old.read(item))
            new.writestr(name, data)
    return target


def one_line_error(scenario_path: Path) -> str:
    result = subprocess.run(
        [sys.executable, "-m", "cosim.cli", "run", str(scenario_path), "--interface", "virtual", "-q"],
        capture_output=True,
        text=True,
    )
    assert result.returncode != 0 and "Traceback" not in result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    return lines[0]


@pytest.mark.slow
def test_a_bad_fmu_is_one_line_naming_the_file_and_the_problem(tmp_path):
    vdp = FMUS / "fmi3" / "VanDerPol.fmu"
    fmi1 = rewritten(vdp, tmp_path / "Old.fmu", lambda n, d: (n, d.replace(b'fmiVersion="3.0"', b'fmiVersion="1.0"')))
    elsewhere = rewritten(
        vdp,
        tmp_path / "Mac.fmu",
        lambda n, d: (n.replace("x86_64-linux", "aarch64-darwin").replace(".so", ".dylib"), d),
    )
    (tmp_path / "Text.fmu").write_text("not a zip")
    cases = {
        "Missing.fmu": ("", "no FMU at", "Missing.fmu"),
        "Text.fmu": ("", "is not an FMU", "Text.fmu"),
        fmi1.name: ("", "is an FMI 1.0 FMU; cosim runs FMI 2.0 and 3.0", "Old.fmu"),
        elsewhere.name: ("", "has binaries for darwin64, not for this machine", "Mac.fmu"),
        str(vdp): ('sensors = ["x9"]', "VanDerPol.fmu has no sensor 'x9'", "plant.sensors"),
    }
    for model, (plant_line, problem, names) in cases.items():
        path = tmp_path / f"bad-{len(problem)}.toml"
        path.write_text(f'name = "bad"\nduration = 1.0\nsample_time = 0.1\n[plant]\nmodel = "{model}"\n{plant_line}\n')
        line = one_line_error(path)
        assert line.startswith("error: ") and problem in line and names in line, line
    for table, problem in (
        (
            "parameters = { mux = 2.0 }",
            "plant.fmu.parameters: VanDerPol.fmu has no parameter 'mux' (did you mean 'mu'?)",
        ),
        ('states = ["y"]', "plant.fmu.states: VanDerPol.fmu has no Float variable 'y'"),
        ('disturbances = ["d"]', "plant.fmu.disturbances: VanDerPol.fmu has no input 'd'; it has no inputs"),
    ):
        path = tmp_path / "bad-table.toml"
        path.write_text(scenario_text(vdp, "co-simulation", duration=1.0, dt=0.1, fmu_table=table))
        line = one_line_error(path)
        assert problem in line, line


def test_a_design_model_replaces_the_linearization(tmp_path):
    from cosim.run.plan import RunPlan

    design = """
[plant.state_space]
A = [[-1.0, 0.0, 0.0], [0.0, -2.0, 0.0], [0.0, 0.0, -3.0]]
B = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
C = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
states = ["x_1", "x_2", "x_3"]
inputs = ["u_1", "u_2", "u_3"]
outputs = ["y_1", "y_2", "y_3"]
"""
    fmu = FMUS / "fmi3" / "StateSpace.fmu"
    loaded = load_text(scenario_text(fmu, "co-simulation", duration=1.0, dt=0.1, extra=design), tmp_path)
    model = RunPlan.build(loaded).model
    assert np.allclose(model.A, np.diag(np.exp([-0.1, -0.2, -0.3])), rtol=0, atol=1e-15)
    wrong = design.replace('states = ["x_1", "x_2", "x_3"]', 'states = ["a", "b", "c"]')
    with pytest.raises(ScenarioError) as error:
        load_text(scenario_text(fmu, "co-simulation", duration=1.0, dt=0.1, extra=wrong), tmp_path)
    assert "plant.state_space.states: the design model's states must be the FMU's, in order: x_1, x_2, x_3" in str(
        error.value
    )


def test_without_fmpy_an_fmu_plant_names_the_extra(tmp_path):
    probe = (
        "import sys; sys.modules['fmpy'] = None\n"
        "from cosim.cli import main\n"
        f"sys.exit(main(['run', {str(VANDERPOL_SCENARIO)!r}, '--interface', 'virtual', '-q']))\n"
    )
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True)
    assert result.returncode != 0 and "Traceback" not in result.stderr
    assert "needs the 'fmi' extra (fmpy is not installed): pip install 'cosim[fmi]'" in result.stderr


def commanded(log: Path) -> np.ndarray:
    with LogReader(log) as reader:
        return np.array(
            [list(TruthInputs.read(m).commanded.values()) for _, _, m in reader.messages([TruthInputs.TOPIC])]
        )


def exported_run(loaded: scenario.LoadedScenario, folder: Path, seed: int | None = None) -> tuple[Path, Path]:
    """The scenario run in-process and exported as an FMU: (log, FMU)."""
    from cosim.run.fmu_export import export

    log, fmu = folder / "run.mcap", folder / "plant.fmu"
    assert run(loaded, log, interface="virtual", seed=seed).status == "completed"
    return log, export(loaded, fmu)


def simulate_export(fmu: Path, log: Path, s: scenario.Scenario, **kwargs) -> np.ndarray:
    """FMPy's simulation of an exported FMU fed the log's commands: its sensor outputs per tick."""
    if s.actuators:
        kwargs["input"] = staircase([(name, ()) for name in s.actuators], commanded(log), s.sample_time)
    result = fmpy.simulate_fmu(
        str(fmu), stop_time=s.duration, output_interval=s.sample_time, output=list(s.sensors), **kwargs
    )
    return np.column_stack([result[name] for name in s.sensors])[:-1]


@pytest.mark.parametrize("name", [str(VANDERPOL_SCENARIO), "masses-faults-fd"])
def test_the_exported_fmu_is_valid_and_reproduces_the_logged_sensor_stream(name, tmp_path):
    from fmpy.validation import validate_fmu

    loaded = scenario.apply(scenario.load(name), [("duration", 3.0), ("seed", 3)])
    log, fmu = exported_run(loaded, tmp_path)
    assert validate_fmu(str(fmu)) == []
    measured = truth(log)["measured"]
    outputs = simulate_export(fmu, log, loaded.scenario)
    assert outputs.shape == measured.shape and np.array_equal(np.isnan(outputs), np.isnan(measured))
    assert np.nanmax(np.abs(outputs - measured)) <= TOLERANCE
    reseeded = simulate_export(fmu, log, loaded.scenario, start_values={"seed": 4})
    assert np.nanmax(np.abs(reseeded - measured)) > 1e-4  # another seed, other noise


def test_a_campaign_sweeps_an_fmu_parameter(tmp_path):
    pandas = pytest.importorskip("pandas")
    campaign = tmp_path / "mu.toml"
    campaign.write_text(
        f"""
name = "vanderpol-mu"
scenario = "{VANDERPOL_SCENARIO}"
seeds = 1
bus = "in-process"

[set]
duration = 1.0

[[axes]]
key = "plant.fmu.parameters.mu"
values = [0.5, 2.0]
name = "mu"
"""
    )
    out = tmp_path / "out"
    result = subprocess.run(
        [sys.executable, "-m", "cosim.cli", "campaign", str(campaign), "--out", str(out), "--engine", "inline"],
        capture_output=True,
        text=True,
    )
    assert result.returncode == 0, result.stderr
    table = pandas.read_parquet(out / "results.parquet")
    assert sorted(table["mu"]) == [0.5, 2.0] and set(table["status"]) == {"completed"}


def test_cosim_fmu_writes_a_valid_fmu_with_the_seed_given(tmp_path):
    from fmpy.validation import validate_fmu

    out = tmp_path / "vdp.fmu"
    result = subprocess.run(
        [sys.executable, "-m", "cosim.cli", "fmu", str(VANDERPOL_SCENARIO), "--out", str(out), "--seed", "5"],
        capture_output=True,
        text=True,
    )
    assert result.returncode == 0 and f"wrote {out}" in result.stderr, result.stderr
    assert validate_fmu(str(out)) == []
    description = fmpy.read_model_description(str(out))
    variables = {v.name: v for v in description.modelVariables}
    assert variables["seed"].start == "5" and variables["x0"].causality == "output"
    assert "state.x1" in variables and description.defaultExperiment.stepSize == "0.01"
