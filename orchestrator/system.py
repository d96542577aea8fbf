"""Resolve, check and load the units of a scenario.

Every connection, input, fault and parameter is checked against the FMUs' model
descriptions before anything is instantiated: existence, causality and type family. Units
whose variables nothing logs and nothing downstream consumes are not loaded at all.
"""
from __future__ import annotations

import difflib
import logging
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, List, Optional, Set

from .errors import FmuLoadError, ScenarioError
from .extraction import digest as sha256   # a file's sha256, memoised: the extraction cache keys by it too
from .fmu import FmuInstance, VarInfo, read_model
from .patterns import matches
from .scenario import Connection, Scenario, seconds_to_ns

log = logging.getLogger(__name__)


def resolve_fmu(spec: str, scenario_file: Path, unit: str, build: Optional[Dict[str, int]] = None) -> Path:
    """A built-in unit name (built on demand, incrementally, sized by the ``build`` options) or
    a path relative to the scenario."""
    from .build import build_all, builtin_names, check_build_options

    p = Path(spec)
    if p.suffix != ".fmu" and "/" not in spec and spec in builtin_names():
        if build:   # checked first: the error names the scenario's unit
            check_build_options(spec, build, who=f"{scenario_file}: unit {unit} ({spec})")
        return build_all([spec], options=build)[0]
    if build:
        raise ScenarioError(f"{scenario_file}: unit {unit}: build options size a built-in unit; {spec!r} is an FMU file")
    if not p.is_absolute():
        p = (scenario_file.parent / p).resolve()
    if not p.exists():
        known = ", ".join(builtin_names())
        raise FmuLoadError(f"unit {unit}: FMU {spec!r} not found (looked for {p}; built-in units: {known})")
    return p


def read_variables(path: Path, unit: str, parameters: Optional[Dict[str, Any]] = None) -> Dict[str, VarInfo]:
    """Variables of an FMU from its model description, without instantiating it (FMI 3.0
    arrays sized by the structural parameters among ``parameters``)."""
    md, variables = read_model(path, unit)
    if parameters and md.fmiVersion.startswith("3"):
        from .fmi3 import has_arrays, variables as fmi3_variables

        if has_arrays(md):
            return fmi3_variables(md, parameters)
    return variables


#: what a scenario may set before initialization besides parameters and inputs: a variable
#: with initial = exact or approx (FMI 2.0 §2.2.7, FMI 3.0 §2.4.7.5), e.g. a state's start
_SETTABLE = ("parameter", "structuralParameter", "input")


def settable(v: VarInfo) -> bool:
    return v.causality in _SETTABLE or (v.initial in ("exact", "approx") and v.variability != "constant"
                                        and v.causality != "independent")


def apply_default_experiment(scenario: Scenario, paths: Dict[str, Path]) -> None:
    """Fill the [simulation] settings the scenario leaves out (start, stop, step, tolerance)
    from the ``DefaultExperiment`` of its units' FMUs: the first unit, in scenario order, whose
    FMU gives the value. Without one: start 0, step 33 ms, stop 10 steps after start, no tolerance."""
    given = scenario.given
    if given is None:
        return
    found = {}
    for key, attr in (("start", "startTime"), ("stop", "stopTime"), ("step", "stepSize"), ("tolerance", "tolerance")):
        if key in given:
            continue
        for u in scenario.units:
            de = read_model(paths[u.name], u.name)[0].defaultExperiment
            value = getattr(de, attr, None) if de is not None else None
            if value not in (None, ""):
                found[key] = float(value)
                break
    if not found:
        return
    f = scenario.file
    if "start" in found:
        scenario.start_ns = seconds_to_ns(found["start"])
    if "step" in found:
        scenario.step_ns = seconds_to_ns(found["step"])
        if scenario.step_ns <= 0:
            raise ScenarioError(f"{f}: the DefaultExperiment's stepSize {found['step']!r} s must be > 0")
    if "stop" in found:
        scenario.stop_ns = seconds_to_ns(found["stop"])
    elif "stop" not in given:
        scenario.stop_ns = scenario.start_ns + 10 * scenario.step_ns
    if "tolerance" in found:
        scenario.tolerance = found["tolerance"]
    if scenario.stop_ns <= scenario.start_ns:
        raise ScenarioError(f"{f}: stop {scenario.stop_ns / 1e9:g} s (from the DefaultExperiment) must be "
                            f"after start {scenario.start_ns / 1e9:g} s")
    log.info("from the FMUs' DefaultExperiment: %s", ", ".join(f"{k} = {v:g}" for k, v in found.items()))


@dataclass
class System:
    """The checked, loaded set of units of a scenario."""

    scenario: Scenario
    paths: Dict[str, Path]
    variables: Dict[str, Dict[str, VarInfo]]
    needed: List[str]
    skipped: List[str]
    logged: Dict[str, List[str]]
    instances: Dict[str, FmuInstance] = field(default_factory=dict)
    hashes: Dict[str, str] = field(default_factory=dict)
    workers: Dict[int, Any] = field(default_factory=dict)   # process number -> transport.WorkerProcess

    def origin(self, unit: str) -> str:
        """The FMU file of ``unit`` as the log names it: the resolved file, or for a unit given
        a local copy (``UnitSpec.path``: a sweep's FMU shipped to a worker) its ``fmu``, the file
        the copy was made from."""
        spec = self.scenario.unit(unit)
        return spec.fmu if spec.path else str(self.paths[unit])

    def connections(self) -> List[Connection]:
        return [c for c in self.scenario.connections if c.dst_unit in self.needed]

    def instantiate(self, unzip_root: Optional[Path] = None) -> None:
        """Load every needed unit: a unit with ``process = N >= 1`` in worker process N
        (:mod:`~immersim.orchestrator.transport`), the others here. Workers load while this
        process loads its own units."""
        where = {name: self.scenario.unit(name).process for name in self.needed}
        if any(where.values()):   # (the worker transport only for a run that has workers)
            from .transport import RemoteInstance, WorkerProcess
        for name in self.needed:
            n = where[name]
            if n and n not in self.workers:
                self.workers[n] = WorkerProcess(n)
            folder = unzip_root / name if unzip_root else None
            if n:
                inst = RemoteInstance(name, self.paths[name], folder, self.workers[n], self.variables[name])
                self.instances[name] = inst
                inst.start_loading()
        for name in self.needed:
            if not where[name]:
                self.instances[name] = FmuInstance(name, self.paths[name], unzip_root / name if unzip_root else None)
                self.instances[name].variables = self.variables[name]   # (FMI 3.0 arrays sized as checked)
        for name in self.needed:
            if where[name]:
                self.instances[name].finish_loading()
        self.instances = {name: self.instances[name] for name in self.needed}

    def terminate(self) -> None:
        """Terminate and free every instance, then end the worker processes."""
        try:
            for inst in self.instances.values():
                inst.terminate()
        finally:
            for w in self.workers.values():
                w.close()


def check_system(scenario: Scenario) -> System:
    """Resolve FMUs, check every reference against the model descriptions, pick needed units."""
    f = scenario.file
    paths: Dict[str, Path] = {}
    variables: Dict[str, Dict[str, VarInfo]] = {}
    for u in scenario.units:
        paths[u.name] = Path(u.path) if u.path else resolve_fmu(u.fmu, f, u.name, u.build)  # path: a local copy
        variables[u.name] = read_variables(paths[u.name], u.name, u.parameters)
    apply_default_experiment(scenario, paths)
    from .fmi3 import expand_arrays

    expand_arrays(scenario, variables)   # whole FMI 3.0 arrays -> their elements

    def lookup(unit: str, var: str, where: str) -> VarInfo:
        try:
            return variables[unit][var]
        except KeyError:
            close = [n for n in variables[unit] if n.split(".")[-1] == var.split(".")[-1]][:3]
            close = close or difflib.get_close_matches(var, list(variables[unit]), n=3, cutoff=0.75)
            hint = f"; did you mean {', '.join(close)}?" if close else ""
            if re.sub(r"\[\d+\]", "[1]", var) in variables[unit]:   # an index beyond a capacity
                from .build import capacity_hint

                spec = next(u for u in scenario.units if u.name == unit)
                hint += capacity_hint(spec.fmu, spec.build) if not spec.path else ""
            raise ScenarioError(f"{where}: unit {unit} ({paths[unit].name}) has no variable {var!r}{hint}") from None

    at = scenario.where
    for i, u in enumerate(scenario.units):
        for pname in u.parameters:
            where = f"{at('units', i, 'parameters', pname)}: parameter {u.name}.{pname}"
            v = lookup(u.name, pname, where)
            if not settable(v):
                raise ScenarioError(f"{where}: variable has causality {v.causality}, "
                                    f"not parameter or input, and no initial = exact/approx start value")
    for i, c in enumerate(scenario.connections):
        src = lookup(c.src_unit, c.src_var, f"{at('connections', i, 'from')}: connection {c}")
        dst = lookup(c.dst_unit, c.dst_var, f"{at('connections', i, 'to')}: connection {c}")
        where = f"{at('connections', i)}: connection {c}"
        if src.causality != "output":
            raise ScenarioError(f"{where}: source {c.src_unit}.{c.src_var} has causality "
                                f"{src.causality}, expected output")
        if dst.causality != "input":
            raise ScenarioError(f"{where}: destination {c.dst_unit}.{c.dst_var} "
                                f"has causality {dst.causality}, expected input")
        if src.family != dst.family:
            raise ScenarioError(f"{where}: type mismatch {src.type} -> {dst.type}")
        if c.scaled and src.family != "float":
            raise ScenarioError(f"{where}: gain and offset apply to Real variables only, not {src.type}")
    for i, s in enumerate(scenario.inputs):
        where = f"{at('inputs', i, 'target')}: input {s.unit}.{s.var}"
        v = lookup(s.unit, s.var, where)
        if v.causality != "input":
            raise ScenarioError(f"{where}: variable has causality {v.causality}, expected input")
        if v.family != "float":
            raise ScenarioError(f"{where}: scenario signals drive Real inputs, this one is {v.type}")
        if any((c.dst_unit, c.dst_var) == (s.unit, s.var) for c in scenario.connections):
            raise ScenarioError(f"{where} is also the destination of a connection")
    for i, s in enumerate(scenario.faults):
        where = f"{at('faults', i, 'target')}: fault {s.unit}.{s.var}"
        v = lookup(s.unit, s.var, where)
        if v.causality not in ("input", "parameter"):
            raise ScenarioError(f"{where}: only inputs can be forced, causality is {v.causality}")
    from .values import check_values

    check_values(scenario, variables, paths)   # parameter and fault values against the FMI types

    for i, b in enumerate(scenario.foxglove):
        for ref in b.refs():
            unit, var = ref.split(".", 1)
            lookup(unit, var, f"{at('foxglove', 'bodies', i)}: foxglove body {b.name!r}")

    # what is logged
    logged: Dict[str, List[str]] = {}
    for u in scenario.units:
        names = []
        for name, v in variables[u.name].items():
            if v.causality not in ("input", "output", "local"):
                continue
            full = f"{u.name}.{name}"
            if matches(full, scenario.log.include) and not matches(full, scenario.log.exclude):
                names.append(name)
        logged[u.name] = names
    # needed: logs something, or feeds (transitively) a needed unit
    needed: Set[str] = {u for u, names in logged.items() if any(
        variables[u][n].causality in ("output", "local") for n in names)}
    needed |= {ref.split(".", 1)[0] for b in scenario.foxglove for ref in b.refs()}
    changed = True
    while changed:
        changed = False
        for c in scenario.connections:
            if c.dst_unit in needed and c.src_unit not in needed:
                needed.add(c.src_unit)
                changed = True
    order = [u.name for u in scenario.units]
    skipped = [u for u in order if u not in needed]
    for u in skipped:
        log.info("unit %s is not loaded: nothing logs or consumes its outputs", u)
    if not needed:
        raise ScenarioError(f"{f}: the [log] selection selects no output of any unit: nothing to simulate")
    return System(scenario, paths, variables, [u for u in order if u in needed], skipped, logged)


def fmu_hashes(system: System) -> Dict[str, str]:
    """sha256 of each loaded unit's FMU file (several instances of one file: hashed once)."""
    used = {u: p for u, p in system.paths.items() if u in system.needed}
    hashes = {p: sha256(p) for p in set(used.values())}
    return {u: hashes[p] for u, p in used.items()}
