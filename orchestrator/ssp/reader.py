"""Read an SSP 1.0 archive into a scenario (see the package docstring)."""
from __future__ import annotations

import hashlib
import shutil
import sys
import tempfile
import xml.etree.ElementTree as ET
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, List, Optional, Tuple

from ..errors import ScenarioError
from .names import NS, OSP_ANNOTATION, SCENARIO_ANNOTATION, q

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

#: elements of an SSD this reader runs; anything else under a System is refused by name
_SYSTEM_CHILDREN = {"Connectors", "ElementGeometry", "ParameterBindings", "Elements", "Connections",
                    "SystemGeometry", "GraphicalElements", "Annotations"}
_COMPONENT_CHILDREN = {"Connectors", "ElementGeometry", "ParameterBindings", "Annotations"}
_PARAMETER_TYPES = {"Real": float, "Integer": int, "Enumeration": int, "String": str,
                    "Boolean": lambda v: v.strip() in ("true", "1")}


@dataclass
class _Flat:
    """The flattened system: components (unit name -> FMU path, parameters), connection edges."""

    units: Dict[str, Tuple[Path, Dict[str, Any]]] = field(default_factory=dict)
    kinds: Dict[tuple, str] = field(default_factory=dict)   # endpoint -> connector kind
    #: endpoint -> [(other endpoint, factor, offset)]: ``this = factor * other + offset`` along the edge
    edges: Dict[tuple, List[tuple]] = field(default_factory=dict)
    #: the components' connectors, and their inputs in the order the connections name them
    component_ends: set = field(default_factory=set)
    inputs: List[tuple] = field(default_factory=list)


def _local(tag: str) -> Tuple[str, str]:
    uri, _, name = tag[1:].partition("}")
    return uri, name


def extract(path: Path) -> Path:
    """Unpack the archive once (a folder per content, under the temporary directory)."""
    digest = hashlib.sha256(path.read_bytes()).hexdigest()[:16]
    folder = Path(tempfile.gettempdir()) / "immersim_ssp" / digest
    if not (folder / "SystemStructure.ssd").is_file():
        folder.parent.mkdir(parents=True, exist_ok=True)
        part = Path(tempfile.mkdtemp(prefix=digest, dir=folder.parent))   # (another process may extract too)
        try:
            with zipfile.ZipFile(path) as z:
                z.extractall(part)
            if not (part / "SystemStructure.ssd").is_file():
                raise ScenarioError(f"{path}: no SystemStructure.ssd at the root of the archive")
            try:
                part.rename(folder)
            except OSError:   # extracted by another process meanwhile
                pass
        finally:
            if part.exists():
                shutil.rmtree(part, ignore_errors=True)
    return folder


def _parameters(binding: ET.Element, folder: Path, where: str) -> Dict[str, Any]:
    """The parameter values of one ``ssd:ParameterBinding`` (its ``.ssv`` or inline values)."""
    for child in binding:
        if _local(child.tag)[1] == "ParameterMapping":
            raise ScenarioError(f"{where}: ssd:ParameterMapping is not supported (bind the FMU's own names)")
    source = binding.get("source")
    if source is not None:
        if source.startswith("#"):
            raise ScenarioError(f"{where}: a ParameterBinding source fragment ({source}) is not supported")
        try:
            pset = ET.parse(folder / source).getroot()
        except (OSError, ET.ParseError) as exc:
            raise ScenarioError(f"{where}: cannot read parameter values {source}: {exc}") from None
    else:
        pset = binding.find("ssd:ParameterValues/ssv:ParameterSet", NS)
        if pset is None:
            return {}
    prefix = binding.get("prefix", "")
    out = {}
    for p in pset.findall("ssv:Parameters/ssv:Parameter", NS):
        name = p.get("name", "")
        typed = [c for c in p if _local(c.tag)[0] == NS["ssv"]]
        kind = _local(typed[0].tag)[1] if typed else "?"
        if kind not in _PARAMETER_TYPES:
            raise ScenarioError(f"{where}: parameter {name!r}: type {kind} is not supported")
        if prefix and name.startswith(prefix):
            name = name[len(prefix):]
        out[name] = _PARAMETER_TYPES[kind](typed[0].get("value"))
    return out


def _system(el: ET.Element, path: Tuple[str, ...], flat: _Flat, folder: Path, where: str,
            inherited: Dict[str, Any]) -> None:
    """Flatten one ``ssd:System`` (recursively) into ``flat``."""
    for child in el:
        local = _local(child.tag)[1]
        if local not in _SYSTEM_CHILDREN:
            raise ScenarioError(f"{where}: system {el.get('name')!r}: ssd:{local} is not supported")
    params = dict(inherited)   # "element.parameter" bound at this level, for the elements below
    for b in el.findall("ssd:ParameterBindings/ssd:ParameterBinding", NS):
        params.update(_parameters(b, folder, f"{where}: system {el.get('name')!r}"))
    for c in el.findall("ssd:Connectors/ssd:Connector", NS):
        flat.kinds[(path, None, c.get("name"))] = c.get("kind", "")
    for child in el.findall("ssd:Elements/*", NS):
        local = _local(child.tag)[1]
        cname = child.get("name")
        sub = {k.split(".", 1)[1]: v for k, v in params.items() if k.startswith(f"{cname}.")}
        if local == "System":
            _system(child, path + (cname,), flat, folder, where, sub)
            for c in child.findall("ssd:Connectors/ssd:Connector", NS):   # its outside is its inside
                outer, inner = (path, cname, c.get("name")), (path + (cname,), None, c.get("name"))
                flat.kinds[outer] = c.get("kind", "")
                if c.get("kind") == "input":
                    _join(flat, inner, outer, 1.0, 0.0)
                else:
                    _join(flat, outer, inner, 1.0, 0.0)
            continue
        if local != "Component":
            raise ScenarioError(f"{where}: element {cname!r}: ssd:{local} is not supported")
        ctype = child.get("type", "application/x-fmu-sharedlibrary")
        if ctype != "application/x-fmu-sharedlibrary":
            raise ScenarioError(f"{where}: component {cname!r}: type {ctype} is not supported (FMUs only)")
        for sub_el in child:
            if _local(sub_el.tag)[1] not in _COMPONENT_CHILDREN:
                raise ScenarioError(f"{where}: component {cname!r}: ssd:{_local(sub_el.tag)[1]} is not supported")
        for b in child.findall("ssd:ParameterBindings/ssd:ParameterBinding", NS):
            sub.update(_parameters(b, folder, f"{where}: component {cname!r}"))
        unit = "-".join(path[1:] + (cname,))
        source = child.get("source", "")
        if "://" in source and not source.startswith("file:"):
            raise ScenarioError(f"{where}: component {cname!r}: source {source!r} is not in the archive")
        flat.units[unit] = (folder / source.replace("file:", "", 1).lstrip("/"), sub)
        for c in child.findall("ssd:Connectors/ssd:Connector", NS):
            flat.kinds[(path, cname, c.get("name"))] = c.get("kind", "")
            flat.component_ends.add((path, cname, c.get("name")))
    for conn in el.findall("ssd:Connections/ssd:Connection", NS):
        a = (path, conn.get("startElement"), conn.get("startConnector"))
        b = (path, conn.get("endElement"), conn.get("endConnector"))
        for end in (a, b):
            if end not in flat.kinds:
                raise ScenarioError(f"{where}: connection {_show(a)} -> {_show(b)}: {_show(end)} is not a declared "
                                    f"connector of system {el.get('name')!r} or its elements")
        factor, offset = 1.0, 0.0
        for t in conn:
            local = _local(t.tag)[1]
            if local == "LinearTransformation":
                factor, offset = float(t.get("factor", 1.0)), float(t.get("offset", 0.0))
            elif local not in ("ConnectionGeometry", "Annotations"):
                raise ScenarioError(f"{where}: connection {_show(a)} -> {_show(b)}: {local} is not supported "
                                    f"(linear transformations only)")
        # the value flows from the output (or a system input) to the input
        if _is_source(flat, a) or not _is_source(flat, b):
            a, b = b, a   # a: the destination
        _join(flat, a, b, factor, offset)
        if a in flat.component_ends:
            flat.inputs.append(a)


def _is_source(flat: _Flat, end: tuple) -> bool:
    """Does the value flow out of this end of a connection in system ``path``?"""
    kind = flat.kinds.get(end, "")
    if end[1] is None:   # the system's own connector, seen from inside: an input feeds in
        return kind in ("input", "parameter", "calculatedParameter")
    return kind in ("output", "calculatedParameter")


def _join(flat: _Flat, dst: tuple, src: tuple, factor: float, offset: float) -> None:
    flat.edges.setdefault(dst, []).append((src, factor, offset))


def _show(end: tuple) -> str:
    return ".".join(x for x in (end[1], end[2]) if x)


def _connections(flat: _Flat, where: str) -> List[Dict[str, Any]]:
    """Each component input traced back to the component output it reads, with the composed
    linear transformation (``dst = gain * src + offset``)."""
    out = []
    for dst in flat.inputs:
        if flat.kinds.get(dst) != "input":
            raise ScenarioError(f"{where}: connection into {_show(dst)}: a component's connector that is "
                                f"{flat.kinds.get(dst)!r}, not an input, cannot be fed")
        node, gain, offset, seen = dst, 1.0, 0.0, set()
        while True:
            links = flat.edges.get(node, [])
            if len(links) != 1 or node in seen:
                if node == dst and not links:
                    break
                if not links:
                    raise ScenarioError(f"{where}: input {_show(dst)} is connected to {_show(node)}, which no "
                                        f"component output feeds")
                raise ScenarioError(f"{where}: input {_show(dst)}: ambiguous or cyclic connection at {_show(node)}")
            seen.add(node)
            src, f, o = links[0]
            gain, offset = gain * f, gain * o + offset
            if src in flat.component_ends and flat.kinds.get(src) in ("output", "calculatedParameter"):
                out.append({"from": f"{'-'.join(src[0][1:] + (src[1],))}.{src[2]}",
                            "to": f"{'-'.join(dst[0][1:] + (dst[1],))}.{dst[2]}", "gain": gain, "offset": offset})
                break
            node = src
    return out


def load_ssp(path: Path | str, overrides: Optional[Dict[str, Any]] = None):
    """A :class:`~immersim.orchestrator.scenario.Scenario` from an SSP archive (see the package
    docstring). ``overrides`` as for :func:`~immersim.orchestrator.scenario.load_scenario`."""
    from ..scenario import parse_scenario

    path = Path(path)
    if not path.exists():
        raise ScenarioError(f"SSP file {path} does not exist")
    if not zipfile.is_zipfile(path):
        raise ScenarioError(f"{path}: not an SSP archive (a zip file with SystemStructure.ssd)")
    folder = extract(path)
    try:
        root = ET.parse(folder / "SystemStructure.ssd").getroot()
    except ET.ParseError as exc:
        raise ScenarioError(f"{path}: SystemStructure.ssd: {exc}") from None
    if root.tag != q("ssd:SystemStructureDescription"):
        raise ScenarioError(f"{path}: SystemStructure.ssd is not an SSP 1.0 system structure description")
    where = f"{path}: SystemStructure.ssd"
    flat = _Flat()
    system = root.find("ssd:System", NS)
    if system is None:
        raise ScenarioError(f"{where}: no ssd:System")
    _system(system, (system.get("name", "system"),), flat, folder, where, {})
    sim: Dict[str, Any] = {}
    de = root.find("ssd:DefaultExperiment", NS)
    if de is not None:
        for key, attr in (("start", "startTime"), ("stop", "stopTime")):
            if de.get(attr) is not None:
                sim[key] = float(de.get(attr))
        for ann in de.findall("ssd:Annotations/ssc:Annotation", NS):
            fixed = ann.find("osp:Algorithm/osp:FixedStepAlgorithm", NS)
            if ann.get("type") == OSP_ANNOTATION and fixed is not None:
                sim["step"] = float(fixed.get("baseStepSize"))
    data: Dict[str, Any] = {
        "simulation": sim,
        "units": [{"name": n, "fmu": str(p), "parameters": params} for n, (p, params) in flat.units.items()],
        "connections": _connections(flat, where)}
    text = (folder / "SystemStructure.ssd").read_text()
    ann = next((a for a in root.findall("ssd:Annotations/ssc:Annotation", NS)
                if a.get("type") == SCENARIO_ANNOTATION), None)
    if ann is not None and ann.find("im:Scenario", NS) is not None:
        text = _merge_scenario(data, ann.find("im:Scenario", NS), folder, where)
    return parse_scenario(data, path, text, overrides)


def _merge_scenario(data: Dict[str, Any], el: ET.Element, folder: Path, where: str) -> str:
    """Add what the SSD cannot say from the scenario file an immersim export carries: the
    simulation settings other than start/stop/step, each connection's extrapolation and delay,
    each unit's worker process, and every other table (inputs, faults, log selection, 3D view,
    live inputs, ...). The signal-source
    component and its connections are dropped: immersim applies the inputs itself."""
    try:
        text = (folder / el.get("source", "")).read_text()
        emb = tomllib.loads(text)
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise ScenarioError(f"{where}: the immersim scenario annotation's file: {exc}") from None
    from ..scenario import expanded_data

    emb = expanded_data(emb, folder / el.get("source", ""))[0]   # its includes and signal groups
    source = el.get("sourceComponent") or None
    if source is not None:
        data["units"] = [u for u in data["units"] if u["name"] != source]
        data["connections"] = [c for c in data["connections"] if not c["from"].startswith(f"{source}.")]
    sim = data["simulation"]
    for key, value in emb.get("simulation", {}).items():
        sim.setdefault(key, value)
    by_name = {u.get("name"): u for u in emb.get("units", []) if isinstance(u, dict)}
    for u in data["units"]:
        if "process" in by_name.get(u["name"], {}):
            u["process"] = by_name[u["name"]]["process"]
    extras = {}
    for c in emb.get("connections", []):
        if isinstance(c, dict):
            extras[str(c.get("to", "")).strip()] = {k: c[k] for k in ("extrapolation", "delayed") if k in c}
    for c in data["connections"]:
        c.update(extras.get(c["to"], {}))
        if c["gain"] == 1.0 and c["offset"] == 0.0:
            del c["gain"], c["offset"]
    for key, value in emb.items():   # inputs, faults, log, foxglove, live inputs, ...
        if key not in ("simulation", "units", "connections"):
            data[key] = value
    return text
