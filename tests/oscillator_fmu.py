"""The oscillator test FMU (tests/data/fmus/oscillator/oscillator.c), built with gcc against FMPy's
FMI 2.0 headers: a mass on a spring and damper, or a pendulum, or a free mass pushed by a constant
force (its parameters choose), whose states x, v start wherever the scenario puts them, with
co-simulation and model exchange and, on request, exact directional derivatives; with ``x_max``
its derivatives fail beyond |x| = x_max (a Modelica assert)."""

from __future__ import annotations

from pathlib import Path

from tests.conftest import ROOT
from tests.fmi2_description import Variable, model_description
from tests.misbehaving_fmu import packaged

SOURCE = ROOT / "tests" / "data" / "fmus" / "oscillator" / "oscillator.c"

#: The FMU's variables, numbered as oscillator.c numbers them; the start values of the states and
#: the input are the scenario's (``build``).
PARAMETERS = {"m": 1, "k": 4, "k3": 0, "c": 0.4, "g_l": 0, "force": 0, "x_max": 0}
DEFINITIONS = """  <UnitDefinitions>
    <Unit name="m"><BaseUnit m="1"/></Unit>
    <Unit name="m/s"><BaseUnit m="1" s="-1"/></Unit>
    <Unit name="m/s2"><BaseUnit m="1" s="-2"/></Unit>
    <Unit name="N"><BaseUnit kg="1" m="1" s="-2"/></Unit>
  </UnitDefinitions>
  <DefaultExperiment startTime="0" stopTime="10" stepSize="0.01"/>
"""


def variables(x: float, v: float, u: float) -> list[Variable]:
    """The table, with the start values ``x``, ``v`` and ``u``."""
    bounds = 'min="-100" max="100"'
    return [
        Variable("x", 0, "Real", "local", "continuous", "exact", f'start="{x}" unit="m" {bounds}'),
        Variable("der(x)", 1, "Real", "local", "continuous", attributes='unit="m/s"', derivative="x", depends=("v",)),
        Variable("v", 2, "Real", "local", "continuous", "exact", f'start="{v}" unit="m/s" {bounds}'),
        Variable(
            "der(v)",
            3,
            "Real",
            "local",
            "continuous",
            attributes='unit="m/s2"',
            derivative="v",
            depends=("x", "v", "u"),
        ),
        Variable("u", 4, "Real", "input", "continuous", attributes=f'start="{u}" unit="N" {bounds}'),
        Variable("position", 5, "Real", "output", "continuous", "calculated", f'unit="m" {bounds}', depends=("x",)),
        *(
            Variable(name, vr, "Real", "parameter", "fixed", "exact", f'start="{start}"')
            for vr, (name, start) in enumerate(PARAMETERS.items(), 6)
        ),
    ]


def build(
    folder: Path, *, directional: bool = False, x: float = 0.0, v: float = 0.0, u: float = 0.0, name: str = "Oscillator"
) -> Path:
    """The FMU at ``folder/<name>.fmu`` (its library compiled there); ``directional``: it declares
    its directional derivatives; ``x``, ``v``, ``u``: the start values of its states and its input
    (what the input holds undriven)."""
    starts = (f"-DX_START={x!r}", f"-DV_START={v!r}", f"-DU_START={u!r}")  # compiled in, as an exporter's are
    description = model_description(
        "oscillator",
        "{5d0c1f6e-7a43-4f6b-9a77-0c5e2d1b3a90}",
        variables(x, v, u),
        header='description="A mass-spring-damper, pendulum or pushed free mass (cosim\'s tests)" '
        'variableNamingConvention="structured" ',
        interfaces='providesDirectionalDerivative="true"' if directional else "",
        definitions=DEFINITIONS,
    )
    return packaged(folder, name, SOURCE, description, starts)
