"""The oscillator test FMU (tests/data/fmus/oscillator/oscillator.c), built with gcc against FMPy's
FMI 2.0 headers: a mass on a spring and damper, or a pendulum, or a free mass pushed by a constant
force (its parameters choose), whose states x, v start wherever the scenario puts them, with
co-simulation and model exchange and, on request, exact directional derivatives; with ``x_max``
its derivatives fail beyond |x| = x_max (a Modelica assert)."""

from __future__ import annotations

from pathlib import Path

from tests.conftest import ROOT
from tests.misbehaving_fmu import packaged

SOURCE = ROOT / "tests" / "data" / "fmus" / "oscillator" / "oscillator.c"

DESCRIPTION = """<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="2.0" modelName="oscillator" guid="{{5d0c1f6e-7a43-4f6b-9a77-0c5e2d1b3a90}}"
  description="A mass-spring-damper, pendulum or pushed free mass (cosim's tests)" generationTool="cosim tests (gcc)"
  variableNamingConvention="structured" numberOfEventIndicators="0">
  <ModelExchange modelIdentifier="oscillator" {directional}/>
  <CoSimulation modelIdentifier="oscillator" canHandleVariableCommunicationStepSize="true" {directional}/>
  <UnitDefinitions>
    <Unit name="m"><BaseUnit m="1"/></Unit>
    <Unit name="m/s"><BaseUnit m="1" s="-1"/></Unit>
    <Unit name="m/s2"><BaseUnit m="1" s="-2"/></Unit>
    <Unit name="N"><BaseUnit kg="1" m="1" s="-2"/></Unit>
  </UnitDefinitions>
  <DefaultExperiment startTime="0" stopTime="10" stepSize="0.01"/>
  <ModelVariables>
    <ScalarVariable name="x" valueReference="0" causality="local" variability="continuous" initial="exact">
      <Real start="{x}" unit="m" min="-100" max="100"/></ScalarVariable>
    <ScalarVariable name="der(x)" valueReference="1" causality="local" variability="continuous">
      <Real derivative="1" unit="m/s"/></ScalarVariable>
    <ScalarVariable name="v" valueReference="2" causality="local" variability="continuous" initial="exact">
      <Real start="{v}" unit="m/s" min="-100" max="100"/></ScalarVariable>
    <ScalarVariable name="der(v)" valueReference="3" causality="local" variability="continuous">
      <Real derivative="3" unit="m/s2"/></ScalarVariable>
    <ScalarVariable name="u" valueReference="4" causality="input" variability="continuous">
      <Real start="{u}" unit="N" min="-100" max="100"/></ScalarVariable>
    <ScalarVariable name="position" valueReference="5" causality="output" variability="continuous" initial="calculated">
      <Real unit="m" min="-100" max="100"/></ScalarVariable>
    <ScalarVariable name="m" valueReference="6" causality="parameter" variability="fixed" initial="exact">
      <Real start="1"/></ScalarVariable>
    <ScalarVariable name="k" valueReference="7" causality="parameter" variability="fixed" initial="exact">
      <Real start="4"/></ScalarVariable>
    <ScalarVariable name="k3" valueReference="8" causality="parameter" variability="fixed" initial="exact">
      <Real start="0"/></ScalarVariable>
    <ScalarVariable name="c" valueReference="9" causality="parameter" variability="fixed" initial="exact">
      <Real start="0.4"/></ScalarVariable>
    <ScalarVariable name="g_l" valueReference="10" causality="parameter" variability="fixed" initial="exact">
      <Real start="0"/></ScalarVariable>
    <ScalarVariable name="force" valueReference="11" causality="parameter" variability="fixed" initial="exact">
      <Real start="0"/></ScalarVariable>
    <ScalarVariable name="x_max" valueReference="12" causality="parameter" variability="fixed" initial="exact">
      <Real start="0"/></ScalarVariable>
  </ModelVariables>
  <ModelStructure>
    <Outputs>
      <Unknown index="6" dependencies="1"/>
    </Outputs>
    <Derivatives>
      <Unknown index="2" dependencies="3"/>
      <Unknown index="4" dependencies="1 3 5"/>
    </Derivatives>
    <InitialUnknowns>
      <Unknown index="2"/>
      <Unknown index="4"/>
      <Unknown index="6"/>
    </InitialUnknowns>
  </ModelStructure>
</fmiModelDescription>
"""


def build(
    folder: Path, *, directional: bool = False, x: float = 0.0, v: float = 0.0, u: float = 0.0, name: str = "Oscillator"
) -> Path:
    """The FMU at ``folder/<name>.fmu`` (its library compiled there); ``directional``: it declares
    its directional derivatives; ``x``, ``v``, ``u``: the start values of its states and its input
    (what the input holds undriven)."""
    starts = (f"-DX_START={x!r}", f"-DV_START={v!r}", f"-DU_START={u!r}")  # compiled in, as an exporter's are
    flag = 'providesDirectionalDerivative="true"' if directional else ""
    return packaged(folder, name, SOURCE, DESCRIPTION.format(directional=flag, x=x, v=v, u=u), starts)
