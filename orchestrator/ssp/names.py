"""XML namespaces and names of SSP 1.0 (the prefixes are the standard's: OSP libcosim reads
the SSD with a parser that matches them literally)."""
from __future__ import annotations

import xml.etree.ElementTree as ET

NS = {
    "ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
    "ssc": "http://ssp-standard.org/SSP1/SystemStructureCommon",
    "ssv": "http://ssp-standard.org/SSP1/SystemStructureParameterValues",
    "ssm": "http://ssp-standard.org/SSP1/SystemStructureParameterMapping",
    "ssb": "http://ssp-standard.org/SSP1/SystemStructureSignalDictionary",
    "osp": "http://opensimulationplatform.com/SSP/OSPAnnotations",
    "im": "https://immersim.org/SSP/ScenarioAnnotation",
}
for _prefix, _uri in NS.items():
    ET.register_namespace(_prefix, _uri)

FMU_TYPE = "application/x-fmu-sharedlibrary"
#: the annotation of an SSD exported by immersim: the scenario file and the signal-source component
SCENARIO_ANNOTATION = "org.immersim.scenario"
OSP_ANNOTATION = "com.opensimulationplatform"
SCENARIO_RESOURCE = "resources/immersim/scenario.toml"
#: SSP connector / parameter types of each FMI type family
SSC_TYPE = {"float": "Real", "int": "Integer", "bool": "Boolean", "string": "String", "binary": "Binary"}


def q(name: str) -> str:
    """``"ssd:System"`` -> ``"{uri}System"`` (ElementTree's qualified name)."""
    prefix, local = name.split(":")
    return f"{{{NS[prefix]}}}{local}"


def fmt(value: float) -> str:
    """A float as XML text that reads back to the same double (``repr``)."""
    return repr(float(value))
