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

Every key, its type and range are declared once in :mod:`~immersim.orchestrator.schema`; every
problem is reported as a :class:`ScenarioError` ``<file>: <key path>: <reason>``.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, List, Optional, Tuple

from . import schema
from .errors import ScenarioError
from .schema import tomllib  # noqa: F401  (the TOML reader the loaders share)

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
        The TOML file.
    overrides : dict, optional
        Applied on top of the file (used by sweeps and ``immersim run --set``):
        ``"unit.param": value`` sets a parameter, ``"simulation.stop": value`` (or step,
        algorithm, extrapolation, start, tolerance) a simulation setting, and
        ``"unit:fmu": path`` swaps the unit's FMU for another one, ``"unit:process": N`` runs the
        unit in worker process N (0: the master's process), ``"log.encoding": "json"`` (or
        include, exclude, parameters) changes the ``[log]`` table. Overridden values are
        checked as the file's own.
    """
    path = Path(path)
    if path.suffix.lower() == ".ssp":   # an SSP 1.0 archive (orchestrator/ssp/)
        from .ssp import load_ssp

        return load_ssp(path, overrides)
    data, text = schema.read_toml(path, "scenario file")
    return parse_scenario(data, path, text, overrides)


def apply_overrides(data: Dict[str, Any], path: Path, overrides: Dict[str, Any]) -> Dict[tuple, str]:
    """Write ``overrides`` into the raw scenario ``data`` (in place); returns the key path
    (schema location) each override set, so that an error in it names the override too."""
    origins: Dict[tuple, str] = {}
    units = data.get("units") if isinstance(data.get("units"), list) else []
    index = {u.get("name"): i for i, u in enumerate(units) if isinstance(u, dict)}
    for key, value in overrides.items():
        table, dot, rest = key.partition(".")
        if table in ("simulation", "log") and dot:
            if not isinstance(data.setdefault(table, {}), dict):
                continue   # the schema reports the table itself
            data[table][rest] = value
            origins[(table, rest)] = key
            continue
        unit, field_ = (key.rsplit(":", 1) + [""])[:2] if ":" in key else (table, "parameters")
        if field_ not in ("fmu", "process", "parameters") or not unit or (field_ == "parameters" and not rest):
            raise ScenarioError(f"override {key!r}: not of the form 'unit.param', 'unit:fmu', 'unit:process', "
                                "'simulation.<key>' or 'log.<key>'")
        if unit not in index:
            raise ScenarioError(f"override {key!r}: no unit {unit!r} in {path}"
                                f"{schema.did_you_mean(unit, [n for n in index if isinstance(n, str)])}")
        i = index[unit]
        if field_ == "parameters":
            params = units[i].setdefault("parameters", {})
            if isinstance(params, dict):
                params[rest] = value
            origins[("units", i, "parameters", rest)] = key
        else:
            units[i][field_] = str(value) if field_ == "fmu" else value
            origins[("units", i, field_)] = key
    return origins


def parse_scenario(data: Dict[str, Any], path: Path, text: str = "",
                   overrides: Optional[Dict[str, Any]] = None) -> Scenario:
    """Validate raw TOML data against :class:`~immersim.orchestrator.schema.ScenarioFile` and
    convert it into a :class:`Scenario`."""
    data = copy.deepcopy(data)
    origins = apply_overrides(data, path, overrides) if overrides else {}
    model: schema.ScenarioFile = schema.validate(schema.ScenarioFile, data, path, origins)
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
                    mesh_triangles=model.foxglove.mesh_triangles if model.foxglove else 500_000)
