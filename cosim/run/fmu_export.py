"""``cosim fmu``: a scenario's plant with its sensor and actuator faults, noise and disturbances,
packaged as an FMI 3.0 co-simulation FMU.

The FMU is Python-backed (pythonfmu3, the ``fmi`` extra): its binary is pythonfmu3's prebuilt
library (Linux x86-64, Windows x86-64), which runs ``cosim.run.fmu_slave`` in the host's Python,
so exporting needs no compiler; running it needs a Python with cosim installed. Its resources hold
the scenario (``scenario.json``: the resolved scenario and the signal names) and, for an FMU plant,
that FMU. The bus (frames, bus faults, estimators, controller) is not part of it: it is the plant
side of a run, whose outputs are the sensor stream ``cosim run`` logs (/truth/faults ``measured``)
given the same commands (docs/fmi.md).
"""

from __future__ import annotations

import json
import re
import shutil
import tempfile
from pathlib import Path
from typing import Any

from cosim.errors import CosimError
from cosim.extras import require
from cosim.plant import build_plant
from cosim.plant.fmu_model import is_fmu
from cosim.scenario import LoadedScenario, Scenario

SLAVE = Path(__file__).with_name("fmu_slave.py")
#: The module name of the slave inside the FMU (pythonfmu3 imports it from the FMU's resources).
SLAVE_MODULE = "cosim_fmu_slave"
PLANT_FILE = "plant.fmu"


def model_identifier(name: str) -> str:
    """The FMU's model identifier (a C identifier: the name of its binary) for a scenario name."""
    cleaned = re.sub(r"[^A-Za-z0-9_]+", "_", name).strip("_")
    return cleaned if cleaned[:1].isalpha() else f"cosim_{cleaned}"


def exported(loaded: LoadedScenario) -> dict[str, Any]:
    """What the FMU's ``scenario.json`` holds: the resolved scenario, its signals and the inputs'
    start values (the plant's operating point)."""
    s = loaded.scenario
    sensors, actuators, states = s.channels()
    plant = build_plant(s)
    data = json.loads(s.model_dump_json())
    if is_fmu(s.plant.model):
        data["plant"]["model"] = PLANT_FILE

    def described(channels: list[Any]) -> list[list[str]]:
        return [[c.name, f"{c.description} [{c.unit}]" if c.unit else c.description] for c in channels]

    return {
        "model_identifier": model_identifier(s.name),
        "description": f"cosim scenario {s.name}: {s.description}" if s.description else f"cosim scenario {s.name}",
        "scenario": data,
        "sample_time": s.sample_time,
        "duration": s.duration,
        "seed": s.seed,
        "u_op": plant.linearize().u_op.tolist(),
        "actuators": described(actuators),
        "sensors": described(sensors),
        "states": described(states),
    }


def export(loaded: LoadedScenario, out: Path) -> Path:
    """Write the scenario's plant as an FMU to ``out``; returns ``out``."""
    builder = require("pythonfmu3.builder", "cosim fmu", "fmi")
    content = exported(loaded)
    with tempfile.TemporaryDirectory(prefix="cosim-fmu-") as folder:
        work = Path(folder)
        (work / "scenario.json").write_text(json.dumps(content), encoding="utf-8")
        project = [work / "scenario.json"]
        if is_fmu(loaded.scenario.plant.model):
            shutil.copyfile(loaded.scenario.plant.model, work / PLANT_FILE)
            project.append(work / PLANT_FILE)
        script = work / f"{SLAVE_MODULE}.py"
        shutil.copyfile(SLAVE, script)
        try:
            built = builder.FmuBuilder.build_FMU(script, dest=work / "built", project_files=project)
        except Exception as error:  # noqa: BLE001 (pythonfmu3 raises plain Exceptions)
            raise CosimError(f"cosim fmu: pythonfmu3 could not build the FMU: {error}") from None
        out.parent.mkdir(parents=True, exist_ok=True)
        shutil.move(built, out)
    return out


def plant_source(content: dict[str, Any], resources: Path, seed: int) -> Any:
    """The exported scenario's ``PlantSource`` (plant, faults, disturbances, as a run builds them)
    with ``seed``: the plant side of a run, without its estimators, controller and clients."""
    from cosim.run.loop import PlantSource
    from cosim.run.plan import RunPlan

    data = dict(content["scenario"])
    if is_fmu(data["plant"]["model"]):
        data["plant"] = {**data["plant"], "model": str(resources / PLANT_FILE)}
    scenario = Scenario.from_resolved(json.dumps(data))
    alone = scenario.model_copy(update={"estimators": [], "controller": None, "clients": []})
    return PlantSource(RunPlan.build(LoadedScenario(alone, "exported FMU", ""), seed=seed))
