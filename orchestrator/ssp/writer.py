"""Export a scenario as an SSP 1.0 archive (see the package docstring for what goes where)."""
from __future__ import annotations

import logging
import os
import posixpath
import tempfile
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path
from typing import Any, Dict, Optional

from ..errors import ScenarioError
from ..scenario import Scenario, load_scenario
from .names import (FMU_TYPE, OSP_ANNOTATION, SCENARIO_ANNOTATION, SCENARIO_RESOURCE, SSC_TYPE, fmt, q)
from .source import MODEL as SOURCE_MODEL, build_source_fmu, spec_of

log = logging.getLogger(__name__)

#: the name of the signal-source component (another name if a unit has it)
SOURCE_NAME = "inputs"


class _STRING:   # the signal-source FMU's ``spec`` parameter, as the FMU declares it
    family = "string"


def _ssv(unit: str, params: Dict[str, Any], variables: Dict[str, Any]) -> bytes:
    """The parameter set of one unit (``ssv:ParameterSet``), typed by the FMU's variables."""
    root = ET.Element(q("ssv:ParameterSet"), {"version": "1.0", "name": unit})
    plist = ET.SubElement(root, q("ssv:Parameters"))
    for name, value in params.items():
        fam = variables[name].family
        p = ET.SubElement(plist, q("ssv:Parameter"), {"name": name})
        if fam == "float":
            text = fmt(value)
        elif fam == "bool":
            text = "true" if value else "false"
        elif fam == "int":
            text = str(int(value))
        else:
            text = str(value)
        ET.SubElement(p, q(f"ssv:{SSC_TYPE[fam]}"), {"value": text})
    return _xml(root)


def _xml(root: ET.Element) -> bytes:
    ET.indent(root)
    return ET.tostring(root, encoding="utf-8", xml_declaration=True)


def _connector(parent: ET.Element, name: str, kind: str, family: str) -> None:
    c = ET.SubElement(parent, q("ssd:Connector"), {"name": name, "kind": kind})
    ET.SubElement(c, q(f"ssc:{SSC_TYPE[family]}"))


def export_ssp(scenario: Scenario | Path | str, output: Path | str,
               overrides: Optional[Dict[str, Any]] = None) -> Path:
    """Write ``scenario`` (a TOML file or a loaded scenario) as the SSP archive ``output``.

    Returns the path written. Raises :class:`~immersim.orchestrator.errors.ScenarioError` for a
    scenario that cannot be checked or exported (e.g. a live input).
    """
    from ..system import check_system

    sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario, overrides)
    system = check_system(sc)
    output = Path(output)
    names = {u.name for u in sc.units}
    source_name = SOURCE_NAME
    while source_name in names:
        source_name += "_"
    # each FMU file once
    resources: Dict[Path, str] = {}
    for u in sc.units:
        p = system.paths[u.name]
        if p not in resources:
            stem, k = p.stem, 1
            while f"resources/{stem}.fmu" in resources.values() or stem == SOURCE_MODEL:
                k += 1
                stem = f"{p.stem}_{k}"
            resources[p] = f"resources/{stem}.fmu"
    used: Dict[str, Dict[str, str]] = {u.name: {} for u in sc.units}   # unit -> connector -> kind
    for c in sc.connections:
        used[c.src_unit][c.src_var] = "output"
        used[c.dst_unit][c.dst_var] = "input"
    for s in sc.inputs:
        used[s.unit][s.var] = "input"

    root = ET.Element(q("ssd:SystemStructureDescription"), {"version": "1.0", "name": sc.file.stem})
    sysel = ET.SubElement(root, q("ssd:System"), {"name": sc.file.stem})
    elements = ET.SubElement(sysel, q("ssd:Elements"))
    ssv_files: Dict[str, bytes] = {}
    for u in sc.units:
        comp = ET.SubElement(elements, q("ssd:Component"), {
            "name": u.name, "type": FMU_TYPE, "source": resources[system.paths[u.name]]})
        variables = system.variables[u.name]
        if used[u.name]:
            conns = ET.SubElement(comp, q("ssd:Connectors"))
            for var, kind in used[u.name].items():
                _connector(conns, var, kind, variables[var].family)
        if u.parameters:
            ssv_files[f"resources/{u.name}.ssv"] = _ssv(u.name, u.parameters, variables)
            pb = ET.SubElement(comp, q("ssd:ParameterBindings"))
            ET.SubElement(pb, q("ssd:ParameterBinding"), {
                "type": "application/x-ssp-parameter-set", "source": f"resources/{u.name}.ssv"})
    if sc.inputs:
        comp = ET.SubElement(elements, q("ssd:Component"), {
            "name": source_name, "type": FMU_TYPE, "source": f"resources/{SOURCE_MODEL}.fmu"})
        conns = ET.SubElement(comp, q("ssd:Connectors"))
        for i, _ in enumerate(sc.inputs):
            _connector(conns, f"u{i + 1}", "output", "float")
        ssv_files[f"resources/{source_name}.ssv"] = _ssv(source_name, {"spec": spec_of(sc.inputs)},
                                                          {"spec": _STRING})
        pb = ET.SubElement(comp, q("ssd:ParameterBindings"))
        ET.SubElement(pb, q("ssd:ParameterBinding"), {
            "type": "application/x-ssp-parameter-set", "source": f"resources/{source_name}.ssv"})
    connections = ET.SubElement(sysel, q("ssd:Connections"))
    for c in sc.connections:
        el = ET.SubElement(connections, q("ssd:Connection"), {
            "startElement": c.src_unit, "startConnector": c.src_var,
            "endElement": c.dst_unit, "endConnector": c.dst_var})
        if c.scaled:
            ET.SubElement(el, q("ssc:LinearTransformation"), {"factor": fmt(c.gain), "offset": fmt(c.offset)})
    for i, s in enumerate(sc.inputs):
        ET.SubElement(connections, q("ssd:Connection"), {
            "startElement": source_name, "startConnector": f"u{i + 1}", "endElement": s.unit, "endConnector": s.var})
    if not len(connections):
        sysel.remove(connections)
    de = ET.SubElement(root, q("ssd:DefaultExperiment"), {
        "startTime": fmt(sc.start_ns / 1e9), "stopTime": fmt(sc.stop_ns / 1e9)})
    ann = ET.SubElement(ET.SubElement(de, q("ssd:Annotations")), q("ssc:Annotation"), {"type": OSP_ANNOTATION})
    ET.SubElement(ET.SubElement(ann, q("osp:Algorithm")), q("osp:FixedStepAlgorithm"),
                  {"baseStepSize": fmt(sc.step_ns / 1e9)})
    ann = ET.SubElement(ET.SubElement(root, q("ssd:Annotations")), q("ssc:Annotation"), {"type": SCENARIO_ANNOTATION})
    ET.SubElement(ann, q("im:Scenario"), {"source": SCENARIO_RESOURCE, "file": sc.file.name,
                                          "sourceComponent": source_name if sc.inputs else ""})

    output.parent.mkdir(parents=True, exist_ok=True)
    tmp_out = output.with_name(output.name + ".part")
    with zipfile.ZipFile(tmp_out, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("SystemStructure.ssd", _xml(root))
        for path, name in resources.items():
            z.write(path, name)
        for name, data in ssv_files.items():
            z.writestr(name, data)
        z.writestr(SCENARIO_RESOURCE, sc.text)
        for file, text in sc.included.items():   # the files it includes, at their relative place
            name = posixpath.normpath(posixpath.join(posixpath.dirname(SCENARIO_RESOURCE),
                                                     Path(os.path.relpath(file, sc.file.parent)).as_posix()))
            if name.startswith(".."):
                raise ScenarioError(f"{sc.file}: include {file!r} lies outside the archive's tree: copy it beside the scenario")
            z.writestr(name, text)
        if sc.inputs:
            with tempfile.TemporaryDirectory(prefix="immersim_ssp_") as tmp:
                fmu = build_source_fmu(sc.inputs, Path(tmp) / f"{SOURCE_MODEL}.fmu")
                z.write(fmu, f"resources/{SOURCE_MODEL}.fmu")
    tmp_out.replace(output)
    log.info("exported %s -> %s", sc.file, output)
    return output
