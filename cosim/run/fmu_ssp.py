"""A system of FMUs (``cosim.run.fmu_system.System``) as the files co-simulation engines read, written
with its FMUs by ``export`` (``cosim fmu --system``): an SSP archive (the Modelica Association's
System Structure and Parameterization 1.0: ``.ssp``, a zip of ``SystemStructure.ssd`` and the FMUs
under ``resources/``) and the Open Simulation Platform's ``OspSystemStructure.xml`` (libcosim's own
format, version 0.1) beside the FMUs.

Both name each FMU as a component (the plant, the estimators, the controller), wire its outputs to
inputs, and give the system's fixed step: in the SSD as OSP's annotation of the default
experiment (``osp:FixedStepAlgorithm baseStepSize``, which libcosim reads), in the OSP file as its
``BaseStepSize``. A component's connectors in the SSD are its connected inputs (FMPy's SSP reader
needs every declared input connected) and all its outputs.
"""

from __future__ import annotations

import zipfile
from pathlib import Path
from typing import Any

from lxml import etree  # FMPy's XML library (the fmi extra): each document declares its own prefixes

from cosim.errors import CosimError
from cosim.run.fmu_export import package
from cosim.run.fmu_system import Component, System, build
from cosim.scenario import LoadedScenario

SubElement = etree.SubElement

SSD = "http://ssp-standard.org/SSP1/SystemStructureDescription"
SSC = "http://ssp-standard.org/SSP1/SystemStructureCommon"
OSP_ANNOTATIONS = "http://opensimulationplatform.com/SSP/OSPAnnotations"
OSP_SYSTEM = "http://opensimulationplatform.com/MSMI/OSPSystemStructure"
#: The annotation type libcosim reads the algorithm from.
OSP_ANNOTATION_TYPE = "com.opensimulationplatform"
SSD_FILE = "SystemStructure.ssd"
OSP_FILE = "OspSystemStructure.xml"
FMU_MIME = "application/x-fmu-sharedlibrary"


def fmu_file(component: str) -> str:
    """The file of a component's FMU."""
    return f"{component}.fmu"


def ssd(system: System, folder: str = "resources/") -> bytes:
    """The system's ``SystemStructure.ssd``, its FMUs in ``folder`` (relative to it)."""
    namespaces = {"ssd": SSD, "ssc": SSC, "osp": OSP_ANNOTATIONS}  # libcosim reads the elements by these prefixes
    root = etree.Element(
        f"{{{SSD}}}SystemStructureDescription", {"name": system.name, "version": "1.0"}, nsmap=namespaces
    )
    described = {"description": system.description} if system.description else {}
    top = SubElement(root, f"{{{SSD}}}System", {"name": system.name, **described})
    elements = SubElement(top, f"{{{SSD}}}Elements")
    for component in system.components:
        attributes = {"name": component.name, "type": FMU_MIME, "source": folder + fmu_file(component.name)}
        element = SubElement(elements, f"{{{SSD}}}Component", attributes)
        connectors = SubElement(element, f"{{{SSD}}}Connectors")
        for name, kind in _connectors(system, component):
            connector = SubElement(connectors, f"{{{SSD}}}Connector", {"name": name, "kind": kind})
            SubElement(connector, f"{{{SSC}}}Real")
    connections = SubElement(top, f"{{{SSD}}}Connections")
    for c in system.connections:
        ends = {"startElement": c.source, "startConnector": c.output, "endElement": c.target, "endConnector": c.input}
        SubElement(connections, f"{{{SSD}}}Connection", ends)
    experiment = SubElement(
        root, f"{{{SSD}}}DefaultExperiment", {"startTime": "0.0", "stopTime": repr(system.duration)}
    )
    annotation = SubElement(
        SubElement(experiment, f"{{{SSD}}}Annotations"), f"{{{SSC}}}Annotation", {"type": OSP_ANNOTATION_TYPE}
    )
    algorithm = SubElement(annotation, f"{{{OSP_ANNOTATIONS}}}Algorithm")
    SubElement(algorithm, f"{{{OSP_ANNOTATIONS}}}FixedStepAlgorithm", {"baseStepSize": repr(system.step)})
    return _document(root)


def _connectors(system: System, component: Component) -> list[tuple[str, str]]:
    """A component's connectors: its connected inputs, in the order of the connections, then all
    its outputs (an engine records them: the estimates, the states)."""
    inputs = [c.input for c in system.connections if c.target == component.name]
    return [(name, "input") for name in inputs] + [(name, "output") for name in component.outputs]


def osp_system_structure(system: System) -> bytes:
    """The system's ``OspSystemStructure.xml``, its FMUs beside it."""
    root = etree.Element(f"{{{OSP_SYSTEM}}}OspSystemStructure", {"version": "0.1"}, nsmap={None: OSP_SYSTEM})
    for tag, text in (("StartTime", "0.0"), ("EndTime", repr(system.duration)), ("BaseStepSize", repr(system.step))):
        SubElement(root, f"{{{OSP_SYSTEM}}}{tag}").text = text
    SubElement(root, f"{{{OSP_SYSTEM}}}Algorithm").text = "fixedStep"
    simulators = SubElement(root, f"{{{OSP_SYSTEM}}}Simulators")
    for component in system.components:
        attributes = {"name": component.name, "source": fmu_file(component.name), "stepSize": repr(system.step)}
        SubElement(simulators, f"{{{OSP_SYSTEM}}}Simulator", attributes)
    connections = SubElement(root, f"{{{OSP_SYSTEM}}}Connections")
    for c in system.connections:
        connection = SubElement(connections, f"{{{OSP_SYSTEM}}}VariableConnection")
        SubElement(connection, f"{{{OSP_SYSTEM}}}Variable", {"simulator": c.source, "name": c.output})
        SubElement(connection, f"{{{OSP_SYSTEM}}}Variable", {"simulator": c.target, "name": c.input})
    return _document(root)


def _document(root: Any) -> bytes:
    return bytes(etree.tostring(root, xml_declaration=True, encoding="UTF-8", pretty_print=True))


def write_ssp(system: System, fmus: dict[str, Path], out: Path) -> Path:
    """The SSP archive ``out``: ``SystemStructure.ssd`` and each component's FMU (``fmus``, by
    component) under ``resources/``."""
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.writestr(SSD_FILE, ssd(system))
        for component, path in fmus.items():
            archive.write(path, f"resources/{fmu_file(component)}")
    return out


def export(loaded: LoadedScenario, folder: Path, fmi: int = 3, force: bool = False) -> list[Path]:
    """Write the scenario's system to ``folder``: each component's FMU, ``OspSystemStructure.xml``
    beside them and the SSP archive ``<scenario>.ssp``; returns the files written. A file that is
    there already is refused unless ``force``."""
    system = build(loaded)
    fmus = {c.name: folder / fmu_file(c.name) for c in system.components}
    osp, ssp = folder / OSP_FILE, folder / f"{system.name}.ssp"
    taken = [str(p) for p in [*fmus.values(), osp, ssp] if p.exists()]
    if taken and not force:
        raise CosimError(f"{', '.join(taken)} exist: choose another folder, or pass --force to replace them")
    folder.mkdir(parents=True, exist_ok=True)
    for component in system.components:
        package(component.content, fmus[component.name], fmi, component.files, component.platforms)
    osp.write_bytes(osp_system_structure(system))
    return [*fmus.values(), osp, write_ssp(system, fmus, ssp)]
