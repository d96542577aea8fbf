"""Scenario files (TOML): units, parameters, connections, inputs, faults, time, logging.

Example::

    [simulation]
    start = 0.0            # s
    stop = 10.0            # s
    step = 0.033           # s, the macro step (default 0.033)
    algorithm = "gauss-seidel"   # or "jacobi"
    extrapolation = "linear"     # or "zoh" (default linear: see results/cosim/README.md)
    lazy = true                  # step units that report at_rest lazily (false: always step)

    [[units]]
    name = "plat"                # instance name
    fmu = "platform"             # a built-in unit or a path to any FMI 2.0/3.0 CS FMU
    [units.parameters]
    M = 240.0

    [[connections]]
    from = "net.avatar[1].f_x"
    to = "plat.cue.f_x"
    gain = 1.0                   # optional, Real only: to = gain * from + offset
    offset = 0.0
    extrapolation = "zoh"        # optional: this connection only (e.g. event-like signals; "angle"
                                 # for an angle wrapped to (-pi, pi]: linear, the short way round)
    delayed = true               # optional (Gauss-Seidel): read the previous step's value, as Jacobi

    [[inputs]]                   # scenario inputs (manipulators)
    target = "net.avatar[1].throttle"
    kind = "step"                # constant | step | ramp | sine | table
    at = 1.0
    value = 0.5

    [log]
    include = ["*"]              # glob patterns over unit.variable
    exclude = []

A file may use the shorthand of :mod:`~immersim.orchestrator.expand` (signal groups such as
``from = "net.avatar[1..3].{x,y,yaw}"``, parameter groups, the collision scene as tables) and
``include = ["common.toml"]`` (:mod:`~immersim.orchestrator.include`); both expand into the
one-signal-per-entry form before it is checked. Every key, its type and range are declared once
in :mod:`~immersim.orchestrator.schema`; every problem is reported as a :class:`ScenarioError`
``<file>: <key path>: <reason>``, naming the file and key where it was written. A file checked
before, with the same texts and overrides, is read from the checked-scenario cache
(:mod:`~immersim.orchestrator.scenariocache`) without importing the schema.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Dict, List, Optional, Tuple

from .errors import ScenarioError
from .tomlfiles import did_you_mean, key_path, read_toml, tomllib

DEFAULT_STEP_NS = 33_000_000


@dataclass
class UnitSpec:
    name: str
    fmu: str
    parameters: Dict[str, Any] = field(default_factory=dict)
    path: Optional[Path] = None  # resolved FMU file, set when loaded
    #: 0: the unit runs in the master's process; N >= 1: in worker process N (units with the
    #: same N share one), stepped in parallel with the others (orchestrator/transport/)
    process: int = 0
    #: build options of a built-in unit (``{"players": 8}``): the FMU is built to that size
    build: Dict[str, int] = field(default_factory=dict)


@dataclass(frozen=True)
class Connection:
    """``dst = gain * src + offset`` (gain and offset only for Real variables)."""

    src_unit: str
    src_var: str
    dst_unit: str
    dst_var: str
    gain: float = 1.0
    offset: float = 0.0
    extrapolation: Optional[str] = None  # None: the scenario's simulation.extrapolation
    #: Gauss-Seidel: the destination always reads the source's value of the previous step (as
    #: under Jacobi), and the connection does not order the two units
    delayed: bool = False

    @property
    def scaled(self) -> bool:
        return self.gain != 1.0 or self.offset != 0.0

    def __str__(self) -> str:
        scale = f" (x {self.gain:g} + {self.offset:g})" if self.scaled else ""
        return f"{self.src_unit}.{self.src_var} -> {self.dst_unit}.{self.dst_var}{scale}"


@dataclass
class InputSpec:
    """A scenario input signal applied to one unit input before each step."""

    unit: str
    var: str
    kind: str
    params: Dict[str, Any]


@dataclass
class FaultSpec:
    """Set ``unit.var`` to ``value`` from time ``at_ns`` on (fault injection)."""

    unit: str
    var: str
    at_ns: int
    value: Any


@dataclass
class LogSpec:
    include: List[str] = field(default_factory=lambda: ["*"])
    exclude: List[str] = field(default_factory=list)
    parameters: bool = True
    #: message encoding of the units' channels: "json" (JSON objects, any reader) or "ros1"
    #: (packed little-endian fields with a ROS 1 schema: ~4x cheaper to write, ~2.5x smaller;
    #: Foxglove reads both, orchestrator/mcapio.py too)
    encoding: str = "json"
    #: write the log in a process of its own (orchestrator/logwriter.py): the master only
    #: hands each step's values over, the other core encodes, compresses and writes
    process: bool = False



@dataclass
class Scenario:
    file: Path
    text: str
    units: List[UnitSpec]
    connections: List[Connection]
    inputs: List[InputSpec]
    faults: List[FaultSpec]
    log: LogSpec
    start_ns: int = 0
    stop_ns: int = 10 * 33_000_000
    step_ns: int = DEFAULT_STEP_NS
    algorithm: str = "gauss-seidel"
    extrapolation: str = "linear"
    tolerance: Optional[float] = None
    lazy: bool = True
    foxglove: List[Any] = field(default_factory=list)  # foxglove.Body list (3D view)
    #: the [simulation] keys the file (or an override) gives; the others may come from the FMUs'
    #: DefaultExperiment (system.apply_default_experiment). None: take none from the FMUs
    given: Optional[frozenset] = None
    #: inputs driven by live clients (``[[live_inputs]]``, :class:`~immersim.orchestrator.live.LiveInput`)
    live_inputs: List[Any] = field(default_factory=list)
    #: ``[foxglove] units``: draw what the units describe (orchestrator/views.py), and the
    #: static-triangle budget of those meshes (``mesh_triangles``)
    view_units: bool = False
    mesh_triangles: int = 500_000
    #: ``[foxglove] rods``: draw the platforms' rods (redrawn every step)
    view_rods: bool = True
    #: the text of every file the scenario includes, by path (the including file's folder
    #: joined to the name it gives), for a copy of the scenario elsewhere (SSP, a sweep's worker)
    included: Dict[str, str] = field(default_factory=dict)
    #: ``place(loc)``: a key path of the expanded scenario (``("connections", 12, "from")``) as
    #: ``<file>: <key path>`` where it was written (an included file, a signal group)
    place: Optional[Callable[[tuple], str]] = field(default=None, repr=False, compare=False)

    def where(self, *loc: Any) -> str:
        """``<file>: <key path>`` of a key path of the expanded scenario, as written."""
        place = self.place or _Sources(self.file, {}).place   # (a scenario built directly: its own file)
        return place(tuple(loc))

    @property
    def n_steps(self) -> int:
        """Number of macro steps (the last one may be shorter to land on ``stop``)."""
        span = self.stop_ns - self.start_ns
        return -(-span // self.step_ns)

    def step_time_ns(self, k: int) -> int:
        """Time of step ``k``: ``start + k*h`` from the integer ``k`` (never accumulated)."""
        return min(self.start_ns + k * self.step_ns, self.stop_ns)

    def unit(self, name: str) -> UnitSpec:
        for u in self.units:
            if u.name == name:
                return u
        raise KeyError(name)


def seconds_to_ns(value: float) -> int:
    """Seconds (a finite float the schema checked) to integer nanoseconds."""
    return int(round(value * 1e9))


def split_ref(ref: str) -> Tuple[str, str]:
    """Split ``unit.variable`` at the first dot (variable names may contain dots)."""
    unit, var = ref.split(".", 1)
    return unit.strip(), var.strip()


def load_scenario(path: Path | str, overrides: Optional[Dict[str, Any]] = None) -> Scenario:
    """Parse and check a scenario file (structure only; FMUs are checked when loaded).

    Parameters
    ----------
    path : path-like
        The TOML file (its ``include`` files are read relative to it).
    overrides : dict, optional
        Applied on top of the file (used by sweeps and ``immersim run --set``), keys as
        :func:`parse_override` reads them: ``"unit.param": value`` sets a parameter,
        ``"simulation.stop": value`` (or step, algorithm, extrapolation, start, tolerance) a
        simulation setting, ``"unit:fmu": path`` swaps the unit's FMU for another one,
        ``"unit:process": N`` runs the unit in worker process N (0: the master's process),
        ``"log.encoding": "json"`` (or include, exclude, parameters) changes the ``[log]``
        table. Overridden values are checked as the file's own.
    """
    path = Path(path)
    if path.suffix.lower() == ".ssp":   # an SSP 1.0 archive (orchestrator/ssp/)
        from .ssp import load_ssp

        return load_ssp(path, overrides)
    from . import scenariocache

    data, text = read_toml(path, "scenario file")
    sc = scenariocache.load(path, text, overrides)
    if sc is None:
        sc = parse_scenario(data, path, text, overrides)
        scenariocache.store(sc, overrides)
    return sc


OVERRIDE_FORMS = "'unit.param', 'unit:fmu', 'unit:process', 'simulation.<key>' or 'log.<key>'"


def parse_override(key: str) -> Tuple[str, str, str]:
    """What an override key sets: ``(table, unit, key)``, one of ``("simulation", "", key)``,
    ``("log", "", key)``, ``("parameters", unit, name)``, ``("fmu", unit, "")`` and
    ``("process", unit, "")``. The one reader of override keys (``--set``, sweep grids and
    variants); raises :class:`ScenarioError` ``override 'k': not of the form ...``."""
    table, dot, rest = key.partition(".")
    if table in ("simulation", "log") and dot and rest:
        return table, "", rest
    if ":" in key:
        unit, field_ = key.rsplit(":", 1)
        if field_ in ("fmu", "process") and unit and "." not in unit:
            return field_, unit, ""
    elif table and rest and table not in ("simulation", "log"):
        return "parameters", table, rest
    raise ScenarioError(f"override {key!r}: not of the form {OVERRIDE_FORMS}")


def apply_overrides(data: Dict[str, Any], path: Path, overrides: Dict[str, Any]) -> Dict[tuple, str]:
    """Write ``overrides`` into the raw scenario ``data`` (in place); returns the key path
    (schema location) each override set, so that an error in it names the override too."""
    origins: Dict[tuple, str] = {}
    units = data.get("units") if isinstance(data.get("units"), list) else []
    index = {u.get("name"): i for i, u in enumerate(units) if isinstance(u, dict)}
    for key, value in overrides.items():
        table, unit, rest = parse_override(key)
        if table in ("simulation", "log"):
            if not isinstance(data.setdefault(table, {}), dict):
                continue   # the schema reports the table itself
            data[table][rest] = value
            origins[(table, rest)] = key
            continue
        if unit not in index:
            raise ScenarioError(f"override {key!r}: no unit {unit!r} in {path}"
                                f"{did_you_mean(unit, [n for n in index if isinstance(n, str)])}")
        i = index[unit]
        if table == "parameters":
            params = units[i].setdefault("parameters", {})
            for name, v in _override_group(key, rest, value):
                if isinstance(params, dict):
                    params[name] = v
                origins[("units", i, "parameters", name)] = key
        else:
            units[i][table] = str(value) if table == "fmu" else value
            origins[("units", i, table)] = key
    return origins


def _override_group(key: str, name: str, value: Any) -> List[Tuple[str, Any]]:
    """The parameters an override sets: a group (``coll.body[1..3].z``) sets each of its
    variables, to one value or to one value each from an array."""
    from .expand import is_group, names

    if not is_group(name):
        return [(name, value)]
    try:
        keys = names(name)
    except ValueError as exc:
        raise ScenarioError(f"override {key!r}: {exc}") from None
    if not isinstance(value, list):
        return [(k, value) for k in keys]
    if len(value) != len(keys):
        raise ScenarioError(f"override {key!r}: names {len(keys)} variables, the array has {len(value)} values")
    return list(zip(keys, value))


def _reader(texts: Optional[Dict[str, str]]):
    """``read(path)`` for included files: from ``texts`` (a scenario shipped with its
    included files' texts), else from the disk; None for no such file."""
    def read(file: Path):
        if texts is not None and str(file) in texts:
            return tomllib.loads(texts[str(file)]), texts[str(file)]
        if texts is not None or not file.is_file():
            return None
        return read_toml(file, "scenario file")
    return read


class _Sources:
    """Where each key path of the expanded data was written: ``sources`` maps a key path (or
    its start) to ``(file, key path there)``, any other path is ``path``'s own. A plain
    object, so that a :class:`Scenario` holding its :meth:`place` can be pickled."""

    def __init__(self, path: Path, sources: Dict[tuple, Tuple[Path, tuple]]) -> None:
        self.path, self.sources = path, sources

    def written(self, loc: tuple) -> Tuple[Path, tuple]:
        for n in range(len(loc), 0, -1):
            if loc[:n] in self.sources:
                file, at = self.sources[loc[:n]]
                return file, at + tuple(loc[n:])
        return self.path, tuple(loc)

    def place(self, loc: tuple) -> str:
        file, at = self.written(loc)
        return f"{file}: {key_path(at)}" if at else str(file)

    def ref(self, loc: tuple) -> str:
        file, at = self.written(loc)
        return key_path(at) if file == self.path else f"{file}: {key_path(at)}"


def expanded_data(data: Dict[str, Any], path: Path, overrides: Optional[Dict[str, Any]] = None,
                  texts: Optional[Dict[str, str]] = None):
    """The raw tables of a scenario with its includes merged, the overrides applied and every
    group expanded (one signal per entry: :mod:`~immersim.orchestrator.expand`).

    Returns ``(data, origins, place, ref, included)``: the override origins, the namers of
    key paths (:class:`_Sources`) and the included files' texts by path."""
    from .expand import expand
    from .include import compose

    data, origin, included = compose(copy.deepcopy(data), path, _reader(texts))
    place = _Sources(path, origin).place
    sources = expand(data, origin, place)
    named = _Sources(path, sources)
    place, ref = named.place, named.ref
    origins = apply_overrides(data, path, overrides) if overrides else {}   # onto the expanded names
    return data, origins, place, ref, included


def parse_scenario(data: Dict[str, Any], path: Path, text: str = "",
                   overrides: Optional[Dict[str, Any]] = None, texts: Optional[Dict[str, str]] = None) -> Scenario:
    """Validate raw TOML data against :class:`~immersim.orchestrator.schema.ScenarioFile` and
    convert it into a :class:`Scenario` (``texts``: the included files' texts by path, for a
    scenario shipped without its folder; default: read from the disk)."""
    from . import schema

    data, origins, place, ref, included = expanded_data(data, path, overrides, texts)
    model: schema.ScenarioFile = schema.validate(schema.ScenarioFile, data, path, origins, place, ref)
    sim = model.simulation
    start_ns, step_ns = seconds_to_ns(sim.start), seconds_to_ns(sim.step)
    if step_ns <= 0:
        raise ScenarioError(f"{path}: simulation.step = {sim.step!r} s must be > 0 (at least 1 ns)")
    stop_ns = seconds_to_ns(sim.stop) if sim.stop is not None else start_ns + 10 * step_ns
    if stop_ns <= start_ns:
        raise ScenarioError(f"{path}: simulation.stop = {stop_ns / 1e9:g} s must be after simulation.start = "
                            f"{start_ns / 1e9:g} s")
    units = [UnitSpec(u.name, u.fmu, dict(data["units"][i].get("parameters", {})), process=u.process,
                      build=dict(u.build)) for i, u in enumerate(model.units)]
    connections = []
    for c in model.connections:
        if isinstance(c, str):
            src, dst = (split_ref(r.strip()) for r in c.split("->", 1))
            connections.append(Connection(*src, *dst))
        else:
            connections.append(Connection(*split_ref(c.src), *split_ref(c.dst), c.gain, c.offset,
                                          c.extrapolation, c.delayed))
    inputs = [InputSpec(*split_ref(s.target), s.kind,
                        {k: getattr(s, k) for k in s.model_fields_set if k not in ("target", "kind")})
              for s in model.inputs]
    faults = [FaultSpec(*split_ref(f.target), seconds_to_ns(f.at), f.value) for f in model.faults]
    lg = model.log
    logspec = LogSpec(list(lg.include), list(lg.exclude), lg.parameters, lg.encoding, lg.process)
    from .foxglove import Body
    from .live import LiveInput

    bodies = [Body(b.name, b.parent, tuple(b.position), tuple(b.euler), b.order, tuple(b.offset), b.shape,
                   tuple(b.size), tuple(b.color)) for b in (model.foxglove.bodies if model.foxglove else [])]
    return Scenario(path, text, units, connections, inputs, faults, logspec, start_ns, stop_ns, step_ns,
                    sim.algorithm, sim.extrapolation, sim.tolerance, sim.lazy, bodies,
                    given=frozenset(sim.model_fields_set),
                    live_inputs=[LiveInput(s.topic, s.field, s.target.strip(), s.scale, s.offset, s.initial)
                                 for s in model.live_inputs],
                    view_units=bool(model.foxglove and model.foxglove.units),
                    mesh_triangles=model.foxglove.mesh_triangles if model.foxglove else 500_000,
                    view_rods=model.foxglove.rods if model.foxglove else True,
                    included=included, place=place)
