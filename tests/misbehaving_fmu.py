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

SOURCE = ROOT / "tests" / "data" / "fmus" / "misbehaving" / "misbehaving.c"

DESCRIPTION = """<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="2.0" modelName="misbehaving" guid="{{8c4e810f-3df3-4a00-8276-176fa3c9f000}}"
  description="A first-order plant that misbehaves on request (cosim's tests)" generationTool="cosim tests (gcc)"
  variableNamingConvention="structured" numberOfEventIndicators="0">
  <ModelExchange modelIdentifier="misbehaving" {directional}/>
  <CoSimulation modelIdentifier="misbehaving" canHandleVariableCommunicationStepSize="true" {directional}/>
  <UnitDefinitions>
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
  <ModelVariables>
    <ScalarVariable name="x" valueReference="0" causality="local" variability="continuous" initial="exact">
      <Real start="1.0" unit="m" min="-10" max="10"/></ScalarVariable>
    <ScalarVariable name="der(x)" valueReference="1" causality="local" variability="continuous">
      <Real derivative="1" unit="m/s"/></ScalarVariable>
    <ScalarVariable name="u" valueReference="2" causality="input" variability="continuous">
      <Real start="0.5" unit="m/s"/></ScalarVariable>
    <ScalarVariable name="y" valueReference="3" causality="output" variability="continuous" initial="calculated">
      <Real unit="N" nominal="1e5"/></ScalarVariable>
    <ScalarVariable name="u_seen" valueReference="4" causality="output" variability="continuous" initial="calculated">
      <Real unit="m/s"/></ScalarVariable>
    <ScalarVariable name="k" valueReference="5" causality="parameter" variability="fixed" initial="exact">
      <Real start="1.0"/></ScalarVariable>
    <ScalarVariable name="gain" valueReference="6" causality="parameter" variability="fixed" initial="exact">
      <Real start="2e5" unit="N"/></ScalarVariable>
    <ScalarVariable name="trigger" valueReference="7" causality="parameter" variability="fixed" initial="exact">
      <Real start="0.5"/></ScalarVariable>
    <ScalarVariable name="mode" valueReference="0" causality="parameter" variability="fixed" initial="exact">
      <Integer start="0"/></ScalarVariable>
    <ScalarVariable name="gear" valueReference="1" causality="input" variability="discrete">
      <Enumeration declaredType="Gear" start="2"/></ScalarVariable>
    <ScalarVariable name="count" valueReference="2" causality="input" variability="discrete">
      <Integer start="7"/></ScalarVariable>
    <ScalarVariable name="gear_seen" valueReference="3" causality="output" variability="discrete" initial="calculated">
      <Integer/></ScalarVariable>
    <ScalarVariable name="count_seen" valueReference="4" causality="output" variability="discrete" initial="calculated">
      <Integer/></ScalarVariable>
    <ScalarVariable name="on" valueReference="0" causality="input" variability="discrete">
      <Boolean start="true"/></ScalarVariable>
    <ScalarVariable name="on_seen" valueReference="1" causality="output" variability="discrete" initial="calculated">
      <Boolean/></ScalarVariable>
  </ModelVariables>
  <ModelStructure>
    <Outputs>
      <Unknown index="4" dependencies="1"/>
      <Unknown index="5" dependencies="3"/>
      <Unknown index="12" dependencies="10"/>
      <Unknown index="13" dependencies="11"/>
      <Unknown index="15" dependencies="14"/>
    </Outputs>
    <Derivatives>
      <Unknown index="2" dependencies="1 3"/>
    </Derivatives>
    <InitialUnknowns>
      <Unknown index="2"/>
      <Unknown index="4"/>
      <Unknown index="5"/>
      <Unknown index="12"/>
      <Unknown index="13"/>
      <Unknown index="15"/>
    </InitialUnknowns>
  </ModelStructure>
</fmiModelDescription>
"""


#: The same FMU described with its integer and Boolean variables only (co-simulation): no Float
#: variable, no state.
DISCRETE = """<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="2.0" modelName="misbehaving" guid="{8c4e810f-3df3-4a00-8276-176fa3c9f000}"
  generationTool="cosim tests (gcc)" numberOfEventIndicators="0">
  <CoSimulation modelIdentifier="misbehaving" canHandleVariableCommunicationStepSize="true"/>
  <ModelVariables>
    <ScalarVariable name="count" valueReference="2" causality="input" variability="discrete">
      <Integer start="7"/></ScalarVariable>
    <ScalarVariable name="count_seen" valueReference="4" causality="output" variability="discrete" initial="calculated">
      <Integer/></ScalarVariable>
    <ScalarVariable name="on" valueReference="0" causality="input" variability="discrete">
      <Boolean start="true"/></ScalarVariable>
    <ScalarVariable name="on_seen" valueReference="1" causality="output" variability="discrete" initial="calculated">
      <Boolean/></ScalarVariable>
  </ModelVariables>
  <ModelStructure>
    <Outputs>
      <Unknown index="2" dependencies="1"/>
      <Unknown index="4" dependencies="3"/>
    </Outputs>
    <InitialUnknowns>
      <Unknown index="2"/>
      <Unknown index="4"/>
    </InitialUnknowns>
  </ModelStructure>
</fmiModelDescription>
"""


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
        command = [compiler() or "gcc", "-shared", "-fPIC", "-O1", *defines, "-I", str(headers)]
        subprocess.run([*command, "-o", str(library), str(source)], check=True, capture_output=True)
    fmu = folder / f"{name}.fmu"
    with zipfile.ZipFile(fmu, "w") as archive:
        archive.writestr("modelDescription.xml", description)
        archive.write(library, f"binaries/linux64/{identifier}.so")
    return fmu


def build(folder: Path, *, directional: bool = False, discrete: bool = False, name: str = "Misbehaving") -> Path:
    """The FMU at ``folder/<name>.fmu`` (its library compiled there); ``directional``: it declares
    directional derivatives; ``discrete``: described with its integer and Boolean variables only."""
    flag = 'providesDirectionalDerivative="true"' if directional else ""
    return packaged(folder, name, SOURCE, DISCRETE if discrete else DESCRIPTION.format(directional=flag))
