"""The misbehaving test FMU (tests/data/fmus/misbehaving/misbehaving.c), built with gcc against
FMPy's FMI 2.0 headers: an FMI 2.0 FMU (co-simulation and model exchange) whose parameter ``mode``
makes it loop forever, segfault, fail, print, or answer wrong directional derivatives from
t >= ``trigger`` on (the C file says what each mode does)."""

from __future__ import annotations

import shutil
import subprocess
import zipfile
from pathlib import Path

from tests.conftest import ROOT
from tests.fmi2_description import Variable, model_description

SOURCE = ROOT / "tests" / "data" / "fmus" / "misbehaving" / "misbehaving.c"

#: The FMU's variables, numbered as misbehaving.c numbers them (one count per type).
VARIABLES = [
    Variable("x", 0, "Real", "local", "continuous", "exact", 'start="1.0" unit="m" min="-10" max="10"'),
    Variable("der(x)", 1, "Real", "local", "continuous", attributes='unit="m/s"', derivative="x", depends=("x", "u")),
    Variable("u", 2, "Real", "input", "continuous", attributes='start="0.5" unit="m/s"'),
    Variable("y", 3, "Real", "output", "continuous", "calculated", 'unit="N" nominal="1e5"', depends=("x",)),
    Variable("u_seen", 4, "Real", "output", "continuous", "calculated", 'unit="m/s"', depends=("u",)),
    Variable("k", 5, "Real", "parameter", "fixed", "exact", 'start="1.0"'),
    Variable("gain", 6, "Real", "parameter", "fixed", "exact", 'start="2e5" unit="N"'),
    Variable("trigger", 7, "Real", "parameter", "fixed", "exact", 'start="0.5"'),
    Variable("mode", 0, "Integer", "parameter", "fixed", "exact", 'start="0"'),
    Variable("gear", 1, "Enumeration", "input", "discrete", attributes='declaredType="Gear" start="2"'),
    Variable("count", 2, "Integer", "input", "discrete", attributes='start="7"'),
    Variable("gear_seen", 3, "Integer", "output", "discrete", "calculated", depends=("gear",)),
    Variable("count_seen", 4, "Integer", "output", "discrete", "calculated", depends=("count",)),
    Variable("on", 0, "Boolean", "input", "discrete", attributes='start="true"'),
    Variable("on_seen", 1, "Boolean", "output", "discrete", "calculated", depends=("on",)),
]
GUID = "{8c4e810f-3df3-4a00-8276-176fa3c9f000}"
DEFINITIONS = """  <UnitDefinitions>
    <Unit name="m"><BaseUnit m="1"/></Unit>
    <Unit name="m/s"><BaseUnit m="1" s="-1"/></Unit>
    <Unit name="N"><BaseUnit kg="1" m="1" s="-2"/></Unit>
  </UnitDefinitions>
  <TypeDefinitions>
    <SimpleType name="Gear">
      <Enumeration>
        <Item name="first" value="1"/>
        <Item name="second" value="2"/>
        <Item name="third" value="3"/>
      </Enumeration>
    </SimpleType>
  </TypeDefinitions>
  <DefaultExperiment startTime="0" stopTime="1" stepSize="0.01"/>
"""


def description(directional: bool = False, discrete: bool = False) -> str:
    """The FMU's modelDescription.xml; ``directional``: it declares directional derivatives;
    ``discrete``: its integer and Boolean variables only (co-simulation): no Float variable, no state."""
    if discrete:
        kept = [v for v in VARIABLES if v.name in ("count", "count_seen", "on", "on_seen")]
        return model_description("misbehaving", GUID, kept, model_exchange=False)
    return model_description(
        "misbehaving",
        GUID,
        VARIABLES,
        header='description="A first-order plant that misbehaves on request (cosim\'s tests)" '
        'variableNamingConvention="structured" ',
        interfaces='providesDirectionalDerivative="true"' if directional else "",
        definitions=DEFINITIONS,
    )


def compiler() -> str | None:
    return shutil.which("gcc") or shutil.which("cc")


def packaged(folder: Path, name: str, source: Path, description: str, defines: tuple[str, ...] = ()) -> Path:
    """``folder/<name>.fmu``: ``description`` with the library of the C ``source`` (compiled into
    ``folder`` with gcc against FMPy's FMI 2.0 headers and ``defines``, once per distinct library),
    its model identifier the source's stem."""
    import fmpy

    identifier = source.stem
    library = folder / ("-".join([identifier, *(d.split("=", 1)[1] for d in defines)]) + ".so")
    if not library.exists():
        headers = Path(fmpy.__file__).parent / "c-code"
        shared = source.parent.parent / "common"  # fmi2_unsupported.h: what the test FMUs share
        command = [compiler() or "gcc", "-shared", "-fPIC", "-O1", *defines, "-I", str(headers), "-I", str(shared)]
        subprocess.run([*command, "-o", str(library), str(source)], check=True, capture_output=True)
    fmu = folder / f"{name}.fmu"
    with zipfile.ZipFile(fmu, "w") as archive:
        archive.writestr("modelDescription.xml", description)
        archive.write(library, f"binaries/linux64/{identifier}.so")
    return fmu


def build(folder: Path, *, directional: bool = False, discrete: bool = False, name: str = "Misbehaving") -> Path:
    """The FMU at ``folder/<name>.fmu`` (its library compiled there); ``directional``: it declares
    directional derivatives; ``discrete``: described with its integer and Boolean variables only."""
    return packaged(folder, name, SOURCE, description(directional, discrete))
