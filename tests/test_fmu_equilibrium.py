"""A Kalman filter on an FMU plant that starts off its equilibrium: the design model is taken at
the equilibrium reached from the start values, or kept there as an affine model where there is
none, and the run says which.

The FMUs are cosim's own oscillator (tests/data/fmus/oscillator, built with gcc) and Dymola's
SpringPendulumExtForce1D (tests/data/fmus/third_party). Each run's filter is held against the
plant's motion, and against the filter the same readings gave before models had a drift: the plant
linearized at its start values, that drift dropped.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cosim import scenario
from cosim.analysis.series import load
from cosim.log.metadata import RunRecord
from cosim.log.reader import LogReader
from cosim.plant import build_plant, fmu_model
from cosim.plant.fmu import FmuPlant
from cosim.run import run
from cosim.scenario.spec import FmuSpec
from estimators import LinearModel
from estimators.kalman import KalmanFilter
from tests import oscillator_fmu
from tests.misbehaving_fmu import compiler
from tests.test_fmu import FMUS, truth

pytest.importorskip("fmpy", reason="the 'fmi' extra (FMPy) is not installed")
pytestmark = pytest.mark.skipif(compiler() is None, reason="no C compiler to build the test FMU")

KALMAN = {"measurement_std": 1e-3, "process_std": 1e-2}
SETTLED = 50  # ticks: the filter starts at the operating point, not where the plant starts


def scenario_file(
    folder: Path, fmu: Path, sensors: list[str], *, interface: str, table: str = "", initial: str = ""
) -> Path:
    path = folder / "scenario.toml"
    path.write_text(
        f"""
name = "off-equilibrium"
duration = 3.0
sample_time = 0.01

[plant]
model = "{fmu}"
sensors = {sensors}
{f"initial_state = {{ {initial} }}" if initial else ""}

[plant.fmu]
interface = "{interface}"
{table}

[[noise]]
kind = "gaussian_noise"
std = 1e-3

[[estimators]]
name = "kf"
kind = "kalman"
params = {{ measurement_std = {KALMAN["measurement_std"]}, process_std = {KALMAN["process_std"]} }}
"""
    )
    return path


def errors(loaded: scenario.LoadedScenario, log: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """RMS of the plant's motion (about its mean), of the run's filter's error, and of the error of
    the filter on the plant linearized at its start values without the drift, per state, after
    ``SETTLED`` ticks."""
    logged = truth(log)
    x = logged["x"]
    values = load(log).estimators["kf"].values
    names = [f"xhat_{state.name}" for state in loaded.scenario.channels()[2]]
    estimated = np.array([[values[k][name] for name in names] for k in sorted(values)])
    plant = build_plant(loaded.scenario)
    try:
        plant.reset(loaded.scenario.plant.initial_state)
        at_start = plant.linearize(plant.state())
    finally:
        plant.close()
    m = at_start
    before = LinearModel(m.A, m.B, m.C, m.D, m.dt, m.states, m.inputs, m.outputs, m.x_op, m.u_op, m.y_op)
    kf = KalmanFilter.from_params(before, KALMAN, loaded.scenario.sample_time)
    u = np.zeros(before.m)
    old = np.array([kf.step(y, u).x for y in logged["measured"]])

    def rms(a: np.ndarray) -> np.ndarray:
        return np.sqrt((a[SETTLED:] ** 2).mean(axis=0))

    return rms(x - x.mean(axis=0)), rms(estimated - x), rms(old - x)


#: name: (parameters, start values built into the FMU, the scenario's initial state, plant interface,
#: the sentence's end, the error bound as a fraction of the motion).
CASES = {
    "spring-stretched-and-moving": (
        "",
        {"x": 0.5, "v": 1.0},
        "",
        "co-simulation",
        "linearized at the equilibrium x = 0, v = 0 reached from them",
        0.01,
    ),
    "damper-without-spring": (
        "k = 0.0, c = 0.5",
        {},
        "x = 0.5, v = 1.0",
        "model-exchange",
        "linearized at the equilibrium x = 0.5, v = 0 reached from them; one of a continuum (A is singular there): "
        "the plant may come to rest at another",
        0.05,
    ),
    "pendulum": (
        "k = 0.0, c = 0.1, g_l = 9.81",
        {},
        "x = 0.5",
        "co-simulation",
        "linearized at the equilibrium x = 0, v = 0 reached from them",
        0.05,
    ),
    "pushed-free-mass": (
        "k = 0.0, c = 0.0, force = 1.0",
        {},
        "x = 0.5, v = 1.0",
        "co-simulation",
        "affine model with drift dx/dt = 1, dv/dt = 1 about them",
        0.01,
    ),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_the_kalman_filter_follows_an_fmu_started_off_its_equilibrium(case, tmp_path):
    """Errors after 0.5 s as a fraction of the motion (RMS; position, velocity), the run's filter
    against the one on the start's linearization without its drift (before), measured: spring
    stretched and moving 0.0027, 0.0087 against 0.0027, 2.95; damper without spring 0.0029, 0.037
    against 0.0029, 5.7; pendulum from 0.5 rad (nonlinear) 0.0032, 0.026 against 0.0032, 2.9; free
    mass pushed by a constant force (no equilibrium) 0.0005, 0.0016 against 0.0005, 0.50."""
    parameters, starts, initial, interface, said, bound = CASES[case]
    fmu = oscillator_fmu.build(tmp_path, directional=case == "spring-stretched-and-moving", **starts)
    table = f"parameters = {{ {parameters} }}" if parameters else ""
    loaded = scenario.load(
        scenario_file(tmp_path, fmu, ["position"], interface=interface, table=table, initial=initial)
    )
    log = tmp_path / "run.mcap"
    result = run(loaded, log, interface="virtual")
    assert result.status == "completed", result.error
    motion, error, before = errors(loaded, log)
    assert np.all(error < bound * motion), (error / motion).tolist()
    assert before[1] > 0.05 * motion[1] and before[1] > 10 * error[1], (before / motion).tolist()
    with LogReader(log) as reader:
        record = RunRecord.from_metadata(reader.metadata()["cosim.run"], [])
    assert record.operating_point is not None and record.operating_point.endswith(said), record.operating_point
    assert record.operating_point.startswith("Oscillator.fmu: ")
    assert ("drift" in record.model) == case.startswith("pushed")


def test_a_third_party_fmu_started_off_its_equilibrium_is_estimated_from_its_acceleration(tmp_path):
    """Dymola's mass on a spring under gravity starts at s = 0.5 m at rest; its equilibrium is
    s = 1.1 m. Its filter on the acceleration alone, measured: errors 0.0002 (s) and 0.0004 (v) of
    the motion, against 0.0002 and 3.1 with the model of the start values without their drift (a
    velocity estimate off by up to 4.1 m/s for a motion of 1.3 m/s RMS)."""
    fmu = FMUS / "third_party" / "dymola" / "SpringPendulumExtForce1D_2022x_fmi2.fmu"
    loaded = scenario.load(scenario_file(tmp_path, fmu, ["a"], interface="co-simulation"))
    log = tmp_path / "run.mcap"
    assert run(loaded, log, interface="virtual").status == "completed"
    motion, error, before = errors(loaded, log)
    assert np.all(error < 0.01 * motion), (error / motion).tolist()
    assert before[1] > motion[1], (before / motion).tolist()
    with LogReader(log) as reader:
        said = RunRecord.from_metadata(reader.metadata()["cosim.run"], []).operating_point
    assert said == (
        "SpringPendulumExtForce1D_2022x_fmi2.fmu: its start values (mass_s = 0.5, mass_v = 0) are no equilibrium (the "
        "derivatives there: dmass_s/dt = 0, dmass_v/dt = 6): linearized at the equilibrium mass_s = 1.1, mass_v = 0 "
        "reached from them"
    )


@pytest.mark.slow
def test_cosim_run_says_where_the_model_was_taken_at_its_start(tmp_path):
    fmu = oscillator_fmu.build(tmp_path)
    path = scenario_file(
        tmp_path, fmu, ["position"], interface="co-simulation", table="parameters = { k = 0.0, c = 0.0, force = 1.0 }"
    )
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "cosim.cli",
            "run",
            str(path),
            "--interface",
            "virtual",
            "--out",
            str(tmp_path / "r.mcap"),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr
    lines = out.stderr.splitlines()
    said = (
        "design model: Oscillator.fmu: no equilibrium near its start values (x = 0, v = 0); the search from them "
        "ended at dx/dt = 0, dv/dt = 1: affine model with drift dx/dt = 0, dv/dt = 1 about them"
    )
    assert said in lines, out.stderr
    assert lines.index(said) == next(i for i, line in enumerate(lines) if line.startswith("off-equilibrium: ")) + 1


def test_an_fmu_that_fails_on_the_way_to_its_equilibrium_keeps_an_affine_model_and_its_plant(tmp_path):
    """The spring pushed to its equilibrium x = 2 by a force of 8 N, with an assert at |x| > 1:
    the search's first step fails in the FMU; the model stays at the start with its drift, and the
    plant's own instance runs on."""
    fmu = oscillator_fmu.build(tmp_path, x=0.5)
    spec = FmuSpec.model_validate({"parameters": {"force": 8.0, "x_max": 1.0}})
    plant = FmuPlant(fmu_model.read(fmu, spec), 0.01, 1.0)
    model = plant.linearize()
    assert model.affine and model.x_op.tolist() == [0.5, 0.0]
    assert plant.operating_point.startswith(
        "Oscillator.fmu: no equilibrium near its start values (x = 0.5, v = 0); the search from them stopped: "
        "Oscillator.fmu: fmi2GetDerivatives returned Error at t = 0 s; its last message:"
    )
    assert plant.operating_point.endswith("x out of range: affine model with drift dx/dt = 0, dv/dt = 6 about them")
    plant.step(np.zeros(1))
    assert plant.state()[0] > 0.5
    plant.close()
