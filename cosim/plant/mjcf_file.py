"""A plant from the user's own MJCF file (``[plant] model = "robot.xml"``), described from the model.

What a built-in plant's module declares by hand (``mjcf/<plant>.py``) is read off the compiled
model here:

- the **state** is MuJoCo's [qpos, qvel, act]: a hinge or slide joint ``j`` gives ``j`` (rad or
  m) and ``j_dot`` (rad/s or m/s), an actuator ``a`` with an activation ``a_act``. Ball and free
  joints are refused: their quaternions have one coordinate more than their velocities, which a
  linear state cannot name (build a rigid body's six degrees of freedom from three slide and three
  hinge joints);
- the **sensors** are the model's sensors by name, a vector sensor ``s`` of n components giving
  ``s_0`` … ``s_{n−1}``; units follow the sensor's type (``jointpos`` of a hinge: rad, ``framepos``:
  m, ``accelerometer``: m/s², …);
- the **actuators** are the model's actuators, the inputs on the bus, except those that
  ``[plant.mjcf] disturbances`` names: unknown inputs, driven by ``[[disturbances]]`` and carried
  by no frame;
- signals get the bus range ±``bound`` and the classic-CAN resolution ``resolution`` of
  ``[plant.mjcf]`` (a state's, sensor's or actuator's own range comes from ``[bus.states]``,
  ``[bus.sensors]`` and ``[bus.actuators]`` as for any plant); an actuator with ``ctrlrange``
  gets that range;
- the operating point (initial state, and the estimators' design point) is the keyframe
  ``[plant.mjcf] keyframe`` names, default the model's first keyframe, or ``qpos0`` without one.

Nothing here integrates anything: the model runs in ``cosim.plant.physics.Plant`` like a built-in.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import mujoco

from cosim.bus.signals import Channel
from cosim.errors import ModelError
from cosim.files import once_per_version
from mjcf import PlantInfo

#: The unit of a sensor's reading by its MuJoCo type (joint sensors: see ``_joint_unit``).
SENSOR_UNITS = {
    "touch": "N",
    "accelerometer": "m/s^2",
    "velocimeter": "m/s",
    "gyro": "rad/s",
    "force": "N",
    "torque": "N m",
    "magnetometer": "T",
    "rangefinder": "m",
    "actuatorpos": "",
    "actuatorvel": "",
    "actuatorfrc": "",
    "framepos": "m",
    "framexaxis": "",
    "frameyaxis": "",
    "framezaxis": "",
    "framelinvel": "m/s",
    "frameangvel": "rad/s",
    "framelinacc": "m/s^2",
    "frameangacc": "rad/s^2",
    "subtreecom": "m",
    "subtreelinvel": "m/s",
    "tendonpos": "m",
    "tendonvel": "m/s",
    "clock": "s",
}


def is_mjcf(model: str) -> bool:
    """Whether ``[plant] model`` names an MJCF file (rather than a registered plant)."""
    return model.lower().endswith(".xml")


def compile_model(path: Path) -> mujoco.MjModel:
    """The compiled model; MuJoCo's own message (with the file and line) as a ModelError otherwise."""
    from cosim.plant.mujoco_model import CALLBACKS

    with CALLBACKS:  # the compiler must run without someone else's passive-force callback
        outer = mujoco.get_mjcb_passive()
        mujoco.set_mjcb_passive(None)
        try:
            return mujoco.MjModel.from_xml_path(str(path))
        except ValueError as error:
            message = " ".join(str(error).split())
            raise ModelError(f"plant.model: MuJoCo could not compile {path}: {message}") from None
        finally:
            mujoco.set_mjcb_passive(outer)


def plant_info(path: str | Path, spec: Any) -> PlantInfo:
    """The PlantInfo of the MJCF file at ``path`` (absolute) under the scenario's ``[plant.mjcf]``
    table (a validated ``MjcfSpec``); ModelError in one line if it cannot be a plant. Read once per
    file version and table."""
    path = Path(path)
    missing = ModelError(f"plant.model: no MJCF file at {path} (a path relative to the scenario file)")
    return once_per_version(_READ, path, spec, missing, _plant_info)


_READ: dict[tuple[Any, ...], PlantInfo] = {}


def _plant_info(path: Path, spec: Any) -> PlantInfo:
    model = compile_model(path)
    if model.nsensor == 0:
        raise ModelError(f"plant.model: {path.name} has no <sensor>: a plant needs sensors to be estimated from")
    bound, resolution = spec.bound, spec.resolution
    actuators = [_name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, i, "actuator") for i in range(model.nu)]
    unknown = [name for name in spec.disturbances if name not in actuators]
    if unknown:
        raise ModelError(
            f"plant.mjcf.disturbances: {path.name} has no actuator {unknown[0]!r} (it has: {', '.join(actuators)})"
        )

    def actuator(i: int, name: str) -> Channel:
        low, high = model.actuator_ctrlrange[i] if model.actuator_ctrllimited[i] else (-bound, bound)
        return Channel(name, "", f"actuator {name} of {path.name}", float(low), float(high), resolution)

    keyframe = spec.keyframe or (_name(model, mujoco.mjtObj.mjOBJ_KEY, 0, "key") if model.nkey else "")
    if keyframe and mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, keyframe) < 0:
        raise ModelError(f"plant.mjcf.keyframe: {path.name} has no keyframe named {keyframe!r}")
    return PlantInfo(
        name=path.stem,
        description=f"MJCF plant {path.name}",
        model_file=str(path),
        states=_states(model, path, bound, resolution),
        sensors=_sensors(model, bound, resolution),
        actuators=tuple(actuator(i, n) for i, n in enumerate(actuators) if n not in spec.disturbances),
        disturbances=tuple(actuator(i, n) for i, n in enumerate(actuators) if n in spec.disturbances),
        keyframe=keyframe,
    )


def _name(model: mujoco.MjModel, kind: mujoco.mjtObj, index: int, what: str) -> str:
    return mujoco.mj_id2name(model, kind, index) or f"{what}{index}"


def _joint_unit(model: mujoco.MjModel, joint: int) -> str:
    return "rad" if int(model.jnt_type[joint]) == int(mujoco.mjtJoint.mjJNT_HINGE) else "m"


def _states(model: mujoco.MjModel, path: Path, bound: float, resolution: float) -> tuple[Channel, ...]:
    positions, velocities = [], []
    for j in range(model.njnt):
        name = _name(model, mujoco.mjtObj.mjOBJ_JOINT, j, "joint")
        if int(model.jnt_type[j]) not in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
            raise ModelError(
                f"plant.model: {path.name}: joint {name!r} is a ball or free joint, whose quaternion a linear "
                "state cannot name; build the body's degrees of freedom from slide and hinge joints"
            )
        unit = _joint_unit(model, j)
        positions.append(Channel(name, unit, f"joint {name}", -bound, bound, resolution))
        velocities.append(Channel(f"{name}_dot", f"{unit}/s", f"velocity of joint {name}", -bound, bound, resolution))
    activations = [
        Channel(
            f"{_name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, a, 'actuator')}_act",
            "",
            "activation",
            -bound,
            bound,
            resolution,
        )
        for a in range(model.nu)
        if model.actuator_dyntype[a] != mujoco.mjtDyn.mjDYN_NONE
    ]
    return (*positions, *velocities, *activations)


def _sensors(model: mujoco.MjModel, bound: float, resolution: float) -> tuple[Channel, ...]:
    channels = []
    for s in range(model.nsensor):
        name = _name(model, mujoco.mjtObj.mjOBJ_SENSOR, s, "sensor")
        kind = mujoco.mjtSensor(model.sensor_type[s]).name.removeprefix("mjSENS_").lower()
        unit = SENSOR_UNITS.get(kind, "")
        if kind in ("jointpos", "jointvel"):
            unit = _joint_unit(model, int(model.sensor_objid[s])) + ("/s" if kind == "jointvel" else "")
        dim = int(model.sensor_dim[s])
        for c in range(dim):
            channels.append(
                Channel(
                    name if dim == 1 else f"{name}_{c}",
                    unit,
                    f"{kind} sensor {name}" + ("" if dim == 1 else f", component {c}"),
                    -bound,
                    bound,
                    resolution,
                    source=name,
                    component=None if dim == 1 else c,
                )
            )
    return tuple(channels)
