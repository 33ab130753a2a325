"""Every registered plant conforms to what the testbed expects of a plant (MJCF file + module)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

import mjcf
from cosim import scenario
from cosim.plant.mujoco_model import load_model
from cosim.plant.physics import Plant
from cosim.run import run
from tests.snippets import plant_only

PLANTS = sorted(mjcf.PLANTS)


@pytest.mark.parametrize("name", PLANTS)
def test_the_mjcf_compiles_with_every_declared_signal(name):
    info = mjcf.get(name)
    model = load_model(info)
    for channel in (*info.actuators, *info.disturbances):
        assert mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, channel.name) >= 0, channel.name
    for channel in info.sensors:
        assert mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, channel.source or channel.name) >= 0, channel.name
    names = [c.name for c in (*info.states, *info.sensors, *info.actuators, *info.disturbances)]
    assert all(
        c.unit is not None and c.minimum < c.maximum and c.resolution > 0 for c in (*info.sensors, *info.actuators)
    )
    assert len(set(c.name for c in info.sensors)) == len(info.sensors) and names


@pytest.mark.parametrize("name", PLANTS)
def test_the_keyframes_exist_and_every_parameter_cites_its_source(name):
    info = mjcf.get(name)
    model = load_model(info)
    for key in filter(None, (info.keyframe, info.design_keyframe)):
        assert mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, key) >= 0, f"{name}: no keyframe {key!r}"
    assert info.parameters and all(p.source and p.unit for p in info.parameters.values())


@pytest.mark.parametrize("name", PLANTS)
def test_the_linearization_at_the_operating_point_is_finite(name):
    info = mjcf.get(name)
    plant = Plant(info, 0.1 if name != "three_tank" else 1.0)
    if info.design_keyframe:
        plant.reset(keyframe=info.design_keyframe)
    for continuous in (False, True):
        model = plant.linearize(continuous=continuous)
        for matrix in (model.A, model.B, model.C, model.D, model.E):
            assert np.all(np.isfinite(matrix))
        assert model.A.shape == (len(info.states), len(info.states)) and model.C.shape[0] == len(info.sensors)


@pytest.mark.parametrize("name", PLANTS)
def test_a_scenario_of_the_plant_runs_one_second(name, tmp_path):
    info = mjcf.get(name)
    dt = {"three_tank": 0.5}.get(name, 0.1)
    text = plant_only(name, dt)
    loaded = scenario.LoadedScenario(scenario.parse(text), "conformance", text)
    result = run(loaded, tmp_path / "one-second.mcap")
    assert result.status == "completed" and result.ticks == round(1.0 / dt) and result.frames_lost == 0
    assert info.name == name
