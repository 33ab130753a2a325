"""``cosim fmu``: a scenario's plant with its sensor and actuator faults, noise and disturbances,
packaged as an FMI 3.0 or 2.0 co-simulation FMU; and the packaging that the other FMUs (an
estimator's, ``cosim.run.fmu_estimator``; a system's, ``cosim.run.fmu_system``) share with it.

The FMU is Python-backed (the ``fmi`` extra): its binary is pythonfmu3's prebuilt library (FMI
3.0) or pythonfmu's (FMI 2.0), which runs the adapter of its version (``cosim.run.fmu_fmi3``,
``cosim.run.fmu_fmi2``) in the host's Python, and that the slave its content names (the plant's:
``cosim.run.fmu_slave``), so exporting needs no compiler; running it needs a Python with cosim
installed. Its resources hold ``content.json`` (what the slave builds itself from: the resolved
scenario, the signal names and units) and, for an FMU plant, that FMU. The bus (frames, bus
faults, estimators, controller) is not part of the plant's FMU: it is the plant side of a run,
whose outputs are the sensor stream ``cosim run`` logs (/truth/faults ``measured``) given the same
commands (docs/fmi.md).

What the packaging adds to the libraries': the variables' units as FMI units (``fmi_units``, their
SI form from pint), only the binaries of the platforms every part of the FMU runs on (a nested FMU
plant's included), and a model description that FMI's schema accepts (NaN start values as
``NaN``; FMI 3.0: the sample time as the fixed internal step size; FMI 2.0: the initial unknowns).
"""

from __future__ import annotations

import functools
import json
import re
import shutil
import tempfile
import zipfile
from collections.abc import Iterable
from pathlib import Path
from typing import Any
from xml.etree import ElementTree

import numpy as np

from cosim.bus.signals import Channel
from cosim.errors import CosimError
from cosim.extras import require
from cosim.plant import build_plant
from cosim.plant.fmu_model import is_fmu
from cosim.run.fmu_interface import CONTENT
from cosim.scenario import LoadedScenario, Scenario

PLANT_FILE = "plant.fmu"
#: The FMI versions ``cosim fmu`` writes: the adapter each FMU carries, and the library that builds it.
ADAPTERS = {3: ("fmu_fmi3.py", "pythonfmu3.builder"), 2: ("fmu_fmi2.py", "pythonfmu.builder")}
#: pythonfmu3's binary folders and the FMI platforms they are (as ``fmpy.supported_platforms`` names
#: them); pythonfmu's folders (FMI 2.0) are named as the platforms.
BINARY_PLATFORMS = {"x86_64-linux": "linux64", "x86_64-windows": "win64", "x86_64-darwin": "darwin64"}
#: FMI 2.0's Integer: 32 bits.
INT32 = range(-(2**31), 2**31)
#: pint's base units and FMI's names of them (FMI 3.0, 2.4.3: the exponents of a BaseUnit).
FMI_BASE_UNITS = {
    "kilogram": "kg",
    "meter": "m",
    "second": "s",
    "ampere": "A",
    "kelvin": "K",
    "mole": "mol",
    "candela": "cd",
    "radian": "rad",
}


def model_identifier(name: str) -> str:
    """The FMU's model identifier (a C identifier: the name of its binary) for a scenario name."""
    cleaned = re.sub(r"[^A-Za-z0-9_]+", "_", name).strip("_")
    return cleaned if cleaned[:1].isalpha() else f"cosim_{cleaned}"


def variable(channel: Channel) -> dict[str, str]:
    """A signal as the slaves declare it: its name, description and unit."""
    return {"name": channel.name, "description": channel.description, "unit": channel.unit}


@functools.cache
def _units_registry() -> Any:
    pint = require("pint", "cosim fmu", "fmi")
    return pint.UnitRegistry()


def fmi_unit(name: str) -> dict[str, Any]:
    """The FMI unit definition of a unit name: its SI form v_SI = factor·v + offset with the
    exponents of the base units, e.g. ``cm^3/s`` → factor 1e-6, m³·s⁻¹. A name pint does not
    parse, or whose SI form is not in FMI's base units, is declared by its name alone (no ``base``)."""
    registry = _units_registry()
    try:
        zero = registry.Quantity(0.0, name).to_base_units()
        one = registry.Quantity(1.0, name).to_base_units()
    except Exception:  # noqa: BLE001 (pint raises several parse and definition errors)
        return {}
    base = {}
    for unit, exponent in one.unit_items():
        if unit not in FMI_BASE_UNITS or exponent != int(exponent):
            return {}
        base[FMI_BASE_UNITS[unit]] = int(exponent)
    offset = float(zero.magnitude)
    # the factor to 15 digits: pint's arithmetic leaves 1.0000000000000002e-06 for cm³
    return {"factor": float(f"{float(one.magnitude) - offset:.15g}"), "offset": offset, "base": base}


def fmi_units(variables: Iterable[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """The unit definitions of the variables' units (a variable without a unit has none)."""
    return {v["unit"]: fmi_unit(v["unit"]) for v in variables if v["unit"]}


def held_commands(s: Scenario) -> np.ndarray:
    """What the actuators hold before a command, as in a run (``cosim.run.loop.held_inputs``): an
    FMU plant's start values (linearizing it would fail for a co-simulation-only FMU, and give its
    design model's zero with ``[plant.state_space]``), else the operating point's inputs."""
    plant = build_plant(s)
    try:
        start = getattr(plant, "start_inputs", None)
        return np.asarray(start[: len(s.actuators)] if start is not None else plant.linearize().u_op, dtype=float)
    finally:
        close = getattr(plant, "close", None)
        if close is not None:
            close()  # an FMU plant's instance (in its host process)


def exported(loaded: LoadedScenario) -> dict[str, Any]:
    """What the plant FMU's ``content.json`` holds: the resolved scenario, its signals and the
    actuators' start values (what they hold before a command, as in a run)."""
    s = loaded.scenario
    sensors, actuators, states = s.channels()
    data = json.loads(s.model_dump_json())
    if is_fmu(s.plant.model):
        data["plant"]["model"] = PLANT_FILE
    signals = {"actuators": actuators, "sensors": sensors, "states": states}
    variables = {group: [variable(c) for c in channels] for group, channels in signals.items()}
    return {
        "slave": "plant",
        "model_identifier": model_identifier(s.name),
        "description": f"cosim scenario {s.name}: {s.description}" if s.description else f"cosim scenario {s.name}",
        "scenario": data,
        "sample_time": s.sample_time,
        "duration": s.duration,
        "seed": s.seed,
        "u_op": held_commands(s).tolist(),
        **variables,
        "units": fmi_units(v for group in variables.values() for v in group),
    }


def export(loaded: LoadedScenario, out: Path, fmi: int = 3) -> Path:
    """Write the scenario's plant as an FMI ``fmi`` FMU to ``out``; returns ``out``."""
    return package(exported(loaded), out, fmi, *plant_files(loaded.scenario))


def plant_files(s: Scenario) -> tuple[dict[str, Path], set[str] | None]:
    """The files the plant's FMU carries (an FMU plant's FMU) and the platforms it can run on
    (None: all of the library's; an FMU plant's platforms)."""
    model = s.plant.model
    if not is_fmu(model):
        return {}, None
    return {PLANT_FILE: Path(model)}, _fmu_platforms(Path(model))


def package(
    content: dict[str, Any],
    out: Path,
    fmi: int = 3,
    files: dict[str, Path] | None = None,
    platforms: set[str] | None = None,
) -> Path:
    """Build the FMI ``fmi`` FMU of the slave ``content`` names, with ``content`` and ``files``
    (name → file) in its resources, keeping the binaries of ``platforms`` only (None: all of the
    library's); returns ``out``."""
    adapter, library = ADAPTERS[fmi]
    builder = require(library, "cosim fmu", "fmi")
    if fmi == 2:
        _check_fmi2(content)
    slave = Path(__file__).with_name(adapter)
    with tempfile.TemporaryDirectory(prefix="cosim-fmu-") as folder:
        work = Path(folder)
        (work / CONTENT).write_text(json.dumps(content), encoding="utf-8")
        project = [work / CONTENT]
        for name, source in (files or {}).items():
            target = work / name
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(source, target)
            project.append(work / Path(name).parts[0])
        script = work / f"cosim_{slave.name}"  # its module's name in the host: one per FMI version
        script.write_bytes(_ascii_source(slave))
        try:
            built = builder.FmuBuilder.build_FMU(script, dest=work / "built", project_files=set(project))
        except Exception as error:  # noqa: BLE001 (pythonfmu3 and pythonfmu raise plain Exceptions)
            raise CosimError(f"cosim fmu: {library.partition('.')[0]} could not build the FMU: {error}") from None
        out.parent.mkdir(parents=True, exist_ok=True)
        system = content.get("system")
        _finish(Path(built), out, platforms, float(system["step"]) if system else content["sample_time"])
    return out


def _check_fmi2(content: dict[str, Any]) -> None:
    """Refuse, in one line, an integer FMI 2.0's 32-bit Integer cannot hold (the seed, a parameter)."""
    integers = {"seed": content.get("seed", 0)}
    integers |= {p["name"]: p["value"] for p in content.get("parameters", []) if p["type"] == "Int64"}
    for name, value in integers.items():
        if value not in INT32:
            raise CosimError(
                f"cosim fmu --fmi 2: {name} = {value} does not fit FMI 2.0's Integer (32 bits): give a smaller "
                "value (--seed, --set), or export FMI 3.0"
            )


def _ascii_source(slave: Path) -> bytes:
    """The slave's source, which must be ASCII: pythonfmu3 reads it (for its class name) in the
    locale's encoding, which is ASCII where ``LC_ALL=C`` (without Python's UTF-8 mode) and in a
    process where an FMU's runtime has called ``setlocale(LC_ALL, "C")`` (Dymola's does)."""
    source = slave.read_bytes()
    if not source.isascii():
        line = next(n for n, text in enumerate(source.splitlines(), 1) if not text.isascii())
        raise CosimError(
            f"cosim fmu: {slave} line {line} is not ASCII; pythonfmu3 reads the slave in the locale's encoding"
        )
    return source


def _fmu_platforms(fmu: Path) -> set[str]:
    """The platforms a nested FMU has binaries for."""
    from fmpy import supported_platforms

    return set(supported_platforms(str(fmu)))


def _finish(built: Path, out: Path, platforms: set[str] | None, step: float) -> None:
    """Copy the built FMU to ``out`` without the binaries of the platforms not in ``platforms``
    and with its model description fixed (``_fixed``)."""
    with zipfile.ZipFile(built) as source, zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as target:
        for item in source.infolist():
            parts = Path(item.filename).parts
            platform = BINARY_PLATFORMS.get(parts[1], parts[1]) if parts[0] == "binaries" else None
            if platform is not None and platforms is not None and platform not in platforms:
                continue
            data = source.read(item)
            if item.filename == "modelDescription.xml":
                data = _fixed(data, step)
            target.writestr(item, data)


def _fixed(xml: bytes, step: float) -> bytes:
    """pythonfmu3's or pythonfmu's model description with ``nan``/``inf`` start values spelled as
    XML Schema's doubles (``NaN``, ``INF``, ``-INF``), and in FMI 3.0 the step (the sample time, or
    the system's) as the co-simulation's fixed internal step size (a ``doStep`` spans whole
    multiples of it; FMI 2.0 has no such attribute)."""
    root = ElementTree.fromstring(xml)
    spelled = {"nan": "NaN", "inf": "INF", "-inf": "-INF"}
    for element in root.iter():
        start = element.get("start")
        if start is not None:
            element.set("start", " ".join(spelled.get(token, token) for token in start.split()))
    cosimulation = root.find("CoSimulation")
    if cosimulation is not None and root.get("fmiVersion", "").startswith("3"):
        cosimulation.set("fixedInternalStepSize", repr(step))
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + ElementTree.tostring(root, encoding="unicode").encode()


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
