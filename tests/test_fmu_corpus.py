"""Third-party FMUs as plants: each run through cosim equals FMPy's simulation of it.

The corpus (tests/data/fmus/third_party, README.md there: sources and licences) holds FMUs of five
exporting tools: Dymola (FMI 2.0 and 3.0, co-simulation and model exchange), 20-sim, fmiCpp,
OSP's cppfmu, Simulink's FMI Kit, and a Reference FMUs build. Each runs for 0.5 s at 10 ms with its
first Float input driven by a sine and the others held at their start values, in every interface it
has; the run's true sensor readings and states (``/truth/sensors``, ``/truth/state``) are compared
with ``fmpy.simulate_fmu`` fed the run's logged effective inputs as a step table, in a process of its
own (``simulated_apart``): a third-party FMU that crashes fails its test, not the test worker.

A direct-feedthrough output in model exchange is the exception: cosim reads the sensors of tick k
before it sets that tick's inputs (the runner's order: sense, then actuate), FMPy records its
output at t_k after its input step there; with no state, the two are the same values one tick apart.
"""

from __future__ import annotations

import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

import numpy as np
import pytest

from cosim import scenario
from cosim.log.reader import LogReader
from cosim.log.topics import TruthInputs, TruthSensors, TruthState
from cosim.plant import fmu_model
from cosim.run import run
from cosim.scenario.spec import FmuSpec
from tests.conftest import ROOT
from tests.fmu_scenario import scenario_text
from tests.test_fmu import staircase

fmpy = pytest.importorskip("fmpy", reason="the 'fmi' extra (FMPy) is not installed")

CORPUS = ROOT / "tests" / "data" / "fmus" / "third_party"
DURATION, DT = 0.5, 0.01
#: FMU → its [plant.fmu] lines: the FMI 3.0 Dymola export breaks the schema; the fmiCpp and 20-sim
#: FMUs declare no range for outputs that leave ±1000 (newtons, pascals).
TABLES = {
    "dymola/SpringPendulumExtForce1D_2023x_fmi3.fmu": "validate = false",
    "fmicpp/Wheel.fmu": "bound = 1e6",
    "fmicpp/Chassis.fmu": "bound = 1e6",
    "twenty-sim/CraneController.fmu": "bound = 1e7",
    "twenty-sim/KnuckleBoomCrane.fmu": "bound = 1e7",
}
FMUS = sorted(str(p.relative_to(CORPUS)) for p in CORPUS.glob("*/*.fmu"))
CASES = [
    (name, interface)
    for name in FMUS
    for interface, part in (("co-simulation", "coSimulation"), ("model-exchange", "modelExchange"))
    if getattr(fmpy.read_model_description(str(CORPUS / name), validate=False), part) is not None
]


def test_the_corpus_has_ten_fmus_of_four_exporting_tools():
    tools = {
        fmpy.read_model_description(str(CORPUS / name), validate=False).generationTool or name.split("/")[0]
        for name in FMUS
    }
    assert len(FMUS) >= 10 and len({name.split("/")[0] for name in FMUS}) >= 5, FMUS
    assert len(tools) >= 5, tools
    for folder in {name.split("/")[0] for name in FMUS}:
        assert (CORPUS / folder / "LICENSE.txt").stat().st_size > 0


def scenario_for(name: str, interface: str, folder: Path) -> scenario.LoadedScenario:
    table = TABLES.get(name, "")
    spec = FmuSpec.model_validate({"validate": "validate = false" not in table})
    model = fmu_model.read(CORPUS / name, spec)
    driven = next((e for e in model.actuators if not e.discrete), None)
    inputs = (
        f'inputs = [{{ actuator = "{driven.name}", signal = {{ kind = "sine", amplitude = 1.0, frequency = 2.0, '
        f"offset = {fmu_model.start_value(driven)} }} }}]"
        if driven is not None
        else ""
    )
    path = folder / "scenario.toml"
    path.write_text(
        scenario_text(CORPUS / name, interface, duration=DURATION, dt=DT, extra=inputs, fmu_table=table, name="corpus")
    )
    return scenario.load(path)


def logged(log: Path) -> dict[str, np.ndarray]:
    rows: dict[str, list[list[float]]] = {"x": [], "y": [], "u": []}
    with LogReader(log) as reader:
        for topic, _, message in reader.messages([TruthState.TOPIC, TruthSensors.TOPIC, TruthInputs.TOPIC]):
            if topic == TruthState.TOPIC:
                rows["x"].append(list(TruthState.read(message).values.values()))
            elif topic == TruthSensors.TOPIC:
                rows["y"].append(list(TruthSensors.read(message).values.values()))
            else:
                rows["u"].append(list(TruthInputs.read(message).effective.values()))
    return {key: np.array(value, dtype=float) for key, value in rows.items()}


def simulated_apart(path: Path, **options) -> np.ndarray:
    """``fmpy.simulate_fmu(path, **options)`` in a process of its own. FMPy loads the FMU's binary
    into the process that simulates it: one of the corpus segfaulted once in its fmi2Terminate under
    load, which killed a pytest-xdist worker, and the suite then waited for it without end."""
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as apart:
        try:
            return apart.submit(fmpy.simulate_fmu, str(path), **options).result(timeout=600)
        except BrokenProcessPool:
            pytest.fail(f"FMPy's simulation of {path.name} ended its process (the FMU crashed)")


@pytest.mark.slow
@pytest.mark.parametrize(("name", "interface"), CASES, ids=[f"{n}-{i}" for n, i in CASES])
def test_a_third_party_fmu_runs_as_a_plant_as_fmpy_simulates_it(name, interface, tmp_path):
    loaded = scenario_for(name, interface, tmp_path)
    result = run(loaded, tmp_path / "run.mcap", interface="virtual")
    assert result.status == "completed", result.error
    found = logged(tmp_path / "run.mcap")
    model = loaded.scenario.fmu_model()
    kwargs = {}
    if model.actuators:
        fields = [(e.variable.name, ()) for e in model.actuators]
        kwargs["input"] = staircase(fields, found["u"], DT)
    outputs = [e.variable.name for e in model.sensors] + [e.variable.name for e in model.states]
    expected = simulated_apart(
        CORPUS / name,
        validate=False,
        fmi_type="CoSimulation" if interface == "co-simulation" else "ModelExchange",
        stop_time=DURATION,
        output_interval=DT,
        output=outputs,
        record_events=False,
        **kwargs,
    )
    reference = np.column_stack([np.asarray(expected[n], dtype=float) for n in outputs])[: len(found["y"])]
    ours = np.column_stack([found["y"], found["x"]]) if found["x"].size else found["y"]
    assert ours.shape == reference.shape
    scale = max(1.0, np.abs(reference).max(initial=0.0))
    through = feedthrough(model, outputs) if interface == "model-exchange" else np.zeros(len(outputs), dtype=bool)
    assert np.abs(ours[:, ~through] - reference[:, ~through]).max(initial=0.0) <= 1e-12 * scale
    if through.any() and not model.states:
        assert np.abs(ours[1:, through] - reference[:-1, through]).max(initial=0.0) <= 1e-12 * scale
    assert np.abs(np.diff(ours, axis=0)).max(initial=0.0) > 0 or not model.actuators  # it moved


def feedthrough(model: fmu_model.FmuModel, outputs: list[str]) -> np.ndarray:
    """Which of ``outputs`` depend on an input directly (ModelStructure; no dependencies listed: all)."""
    inputs = {e.variable.name for e in model.actuators + model.disturbances}
    depends = {
        u.variable.name: u.dependencies is None or any(d.name in inputs for d in u.dependencies)
        for u in model.description.outputs
    }
    return np.array([depends.get(name, False) for name in outputs])


@pytest.mark.parametrize("setting", ['plant.fmu.parameters."mass.m"=3', "plant.fmu.parameters.mass.m=3"])
def test_a_dotted_parameter_is_set_quoted_or_not(setting, tmp_path):
    """Dymola's spring pendulum, mass.m = 3 kg instead of 1: ẍ = −(c/m) x with c = 10 N/m."""
    loaded = scenario_for("dymola/SpringPendulumExtForce1D_2022x_fmi2.fmu", "model-exchange", tmp_path)
    changed = scenario.apply(loaded, [scenario.parse_setting(setting)])
    assert changed.scenario.plant.fmu.parameters == {"mass.m": 3}
    from cosim.plant.fmu import FmuPlant

    plant = FmuPlant(changed.scenario.fmu_model(), DT, DURATION)
    assert np.allclose(plant.linearize(continuous=True).A, [[0.0, 1.0], [-10.0 / 3.0, 0.0]], rtol=1e-9)
    assert plant.warnings == []  # its directional derivatives agree with the differences
