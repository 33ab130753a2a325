"""The modelDescription.xml of cosim's FMI 2.0 test FMUs (tests/misbehaving_fmu.py,
tests/oscillator_fmu.py), written from a table of their variables: each row a variable as the
FMU's C file numbers it, its dependencies by name; the ModelStructure follows from the rows
(outputs, then the derivatives, their indices counted in the table, as FMI 2.0 counts them)."""

from __future__ import annotations

from dataclasses import dataclass
from xml.sax.saxutils import quoteattr


@dataclass(frozen=True)
class Variable:
    """A ScalarVariable: ``kind`` is its type element (Real, Integer, Boolean or Enumeration),
    ``attributes`` that element's own (start, unit, min, ...), ``derivative`` the state it is the
    derivative of, ``depends`` what an output or a derivative depends on."""

    name: str
    vr: int
    kind: str
    causality: str
    variability: str
    initial: str = ""
    attributes: str = ""
    derivative: str = ""
    depends: tuple[str, ...] = ()


def model_description(
    identifier: str,
    guid: str,
    variables: list[Variable],
    *,
    header: str = "",
    interfaces: str = "",
    definitions: str = "",
    model_exchange: bool = True,
) -> str:
    """The XML of an FMU whose model identifier is ``identifier``: ``header`` the root element's
    further attributes, ``interfaces`` the attributes both interface elements get (directional
    derivatives), ``definitions`` what stands between the interfaces and the variables (units,
    types, the default experiment); co-simulation, and with ``model_exchange`` model exchange."""
    index = {v.name: i for i, v in enumerate(variables, 1)}

    def row(v: Variable) -> str:
        initial = f' initial="{v.initial}"' if v.initial else ""
        attributes = [v.attributes] if v.attributes else []
        if v.derivative:
            attributes.insert(0, f'derivative="{index[v.derivative]}"')
        return (
            f'    <ScalarVariable name={quoteattr(v.name)} valueReference="{v.vr}" causality="{v.causality}"'
            f' variability="{v.variability}"{initial}>\n'
            f"      <{v.kind} {' '.join(attributes)}/></ScalarVariable>"
        )

    def unknowns(chosen: list[Variable], with_depends: bool = True) -> str:
        lines = [
            f'      <Unknown index="{index[v.name]}"'
            + (f' dependencies="{" ".join(str(index[d]) for d in v.depends)}"' if with_depends else "")
            + "/>"
            for v in chosen
        ]
        return "\n".join(lines)

    outputs = [v for v in variables if v.causality == "output"]
    derivatives = [v for v in variables if v.derivative]
    structure = f"    <Outputs>\n{unknowns(outputs)}\n    </Outputs>\n"
    if derivatives:
        structure += f"    <Derivatives>\n{unknowns(derivatives)}\n    </Derivatives>\n"
    initial = sorted(outputs + derivatives, key=lambda v: index[v.name])
    structure += f"    <InitialUnknowns>\n{unknowns(initial, with_depends=False)}\n    </InitialUnknowns>\n"
    exchange = f'  <ModelExchange modelIdentifier="{identifier}" {interfaces}/>\n' if model_exchange else ""
    return (
        '<?xml version="1.0" encoding="UTF-8"?>\n'
        f'<fmiModelDescription fmiVersion="2.0" modelName="{identifier}" guid="{guid}"\n'
        f'  {header}generationTool="cosim tests (gcc)" numberOfEventIndicators="0">\n'
        f"{exchange}"
        f'  <CoSimulation modelIdentifier="{identifier}" canHandleVariableCommunicationStepSize="true" {interfaces}/>\n'
        f"{definitions}"
        "  <ModelVariables>\n" + "\n".join(row(v) for v in variables) + "\n  </ModelVariables>\n"
        f"  <ModelStructure>\n{structure}  </ModelStructure>\n"
        "</fmiModelDescription>\n"
    )
