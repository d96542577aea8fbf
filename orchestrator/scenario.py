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

Every problem is reported as a :class:`ScenarioError` naming the file and the key.
"""
from __future__ import annotations

import math
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, List, Optional, Tuple

from .errors import ScenarioError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

DEFAULT_STEP_NS = 33_000_000
ALGORITHMS = ("gauss-seidel", "jacobi")
EXTRAPOLATIONS = ("zoh", "linear")
#: a connection may also say "angle": linear, the difference of two samples taken the short way
#: round the circle (an angle output wrapped to (-pi, pi] does not turn by 2 pi when it wraps)
CONNECTION_EXTRAPOLATIONS = EXTRAPOLATIONS + ("angle",)
INPUT_KINDS = ("constant", "step", "ramp", "sine", "table")
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_\-]*$")


@dataclass
class UnitSpec:
    name: str
    fmu: str
    parameters: Dict[str, Any] = field(default_factory=dict)
    path: Optional[Path] = None  # resolved FMU file, set when loaded
    #: 0: the unit runs in the master's process; N >= 1: in worker process N (units with the
    #: same N share one), stepped in parallel with the others under Jacobi (orchestrator/remote.py)
    process: int = 0


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


LOG_ENCODINGS = ("json", "ros1")


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


def _process(value: Any, where: str) -> int:
    """A unit's ``process`` key: 0 (the master's process) or a worker number >= 1."""
    if isinstance(value, str) and value.strip().isdigit():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ScenarioError(f"{where}: 'process' must be an integer >= 0 (0: the master's process, "
                            f"N: worker process N), got {value!r}")
    return value


def seconds_to_ns(value: Any, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ScenarioError(f"{where} must be a number of seconds, got {value!r}")
    if not math.isfinite(value):
        raise ScenarioError(f"{where} must be finite, got {value!r}")
    return int(round(value * 1e9))


def split_ref(ref: Any, where: str) -> Tuple[str, str]:
    """Split ``unit.variable`` at the first dot (variable names may contain dots)."""
    if not isinstance(ref, str) or "." not in ref:
        raise ScenarioError(f"{where}: {ref!r} is not of the form 'unit.variable'")
    unit, var = ref.split(".", 1)
    if not unit or not var:
        raise ScenarioError(f"{where}: {ref!r} is not of the form 'unit.variable'")
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
        include, exclude, parameters) changes the ``[log]`` table.
    """
    path = Path(path)
    if not path.exists():
        raise ScenarioError(f"scenario file {path} does not exist")
    text = path.read_text()
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{path}: invalid TOML: {exc}") from None
    return parse_scenario(data, path, text, overrides)


def parse_scenario(data: Dict[str, Any], path: Path, text: str = "",
                   overrides: Optional[Dict[str, Any]] = None) -> Scenario:
    f = str(path)
    known = {"simulation", "units", "connections", "inputs", "faults", "log", "description", "title", "foxglove"}
    for key in data:
        if key not in known:
            raise ScenarioError(f"{f}: unknown top-level key {key!r} (expected one of {', '.join(sorted(known))})")
    sim = data.get("simulation", {})
    if not isinstance(sim, dict):
        raise ScenarioError(f"{f}: [simulation] must be a table")
    sim = dict(sim)
    for k, v in (overrides or {}).items():
        if k.startswith("simulation."):
            sim[k.split(".", 1)[1]] = v
    for key in sim:
        if key not in ("start", "stop", "step", "algorithm", "extrapolation", "tolerance", "lazy"):
            raise ScenarioError(f"{f}: [simulation] unknown key {key!r}")
    start_ns = seconds_to_ns(sim.get("start", 0.0), f"{f}: simulation.start")
    step_ns = seconds_to_ns(sim.get("step", 0.033), f"{f}: simulation.step")
    if step_ns <= 0:
        raise ScenarioError(f"{f}: simulation.step = {sim.get('step')!r} s must be > 0")
    stop_ns = seconds_to_ns(sim.get("stop", start_ns / 1e9 + 10 * step_ns / 1e9), f"{f}: simulation.stop")
    if stop_ns <= start_ns:
        raise ScenarioError(f"{f}: simulation.stop = {stop_ns / 1e9:g} s must be after simulation.start = {start_ns / 1e9:g} s")
    algorithm = sim.get("algorithm", "gauss-seidel")
    if algorithm not in ALGORITHMS:
        raise ScenarioError(f"{f}: simulation.algorithm {algorithm!r} is not one of {', '.join(ALGORITHMS)}")
    extrapolation = sim.get("extrapolation", "linear")
    if extrapolation not in EXTRAPOLATIONS:
        raise ScenarioError(f"{f}: simulation.extrapolation {extrapolation!r} is not one of {', '.join(EXTRAPOLATIONS)}")
    tolerance = sim.get("tolerance")
    lazy = sim.get("lazy", True)
    if not isinstance(lazy, bool):
        raise ScenarioError(f"{f}: simulation.lazy must be true or false, got {lazy!r}")

    raw_units = data.get("units")
    if not isinstance(raw_units, list) or not raw_units:
        raise ScenarioError(f"{f}: no [[units]] defined")
    units: List[UnitSpec] = []
    for i, u in enumerate(raw_units):
        where = f"{f}: units[{i}]"
        if not isinstance(u, dict):
            raise ScenarioError(f"{where} must be a table")
        for key in u:
            if key not in ("name", "fmu", "parameters", "process"):
                raise ScenarioError(f"{where}: unknown key {key!r}")
        name, fmu = u.get("name"), u.get("fmu")
        if not isinstance(name, str) or not _NAME.match(name):
            raise ScenarioError(f"{where}: 'name' must be an identifier, got {name!r}")
        if any(x.name == name for x in units):
            raise ScenarioError(f"{where}: duplicate unit instance name {name!r}")
        if not isinstance(fmu, str) or not fmu:
            raise ScenarioError(f"{where} ({name}): 'fmu' must be a built-in unit name or an FMU path")
        params = u.get("parameters", {})
        if not isinstance(params, dict):
            raise ScenarioError(f"{where} ({name}): 'parameters' must be a table")
        units.append(UnitSpec(name, fmu, dict(params), process=_process(u.get("process", 0), f"{where} ({name})")))
    names = {u.name for u in units}
    for k, v in (overrides or {}).items():
        if k.startswith(("simulation.", "log.")):
            continue
        if k.endswith(":fmu"):  # swap a unit's FMU (ablation): "unit:fmu" = path or built-in name
            unit = k[:-4]
            if unit not in names:
                raise ScenarioError(f"override {k!r}: no unit {unit!r} in {f}")
            next(u for u in units if u.name == unit).fmu = str(v)
            continue
        if k.endswith(":process"):  # move a unit into worker process N (0: the master's)
            unit = k[:-8]
            if unit not in names:
                raise ScenarioError(f"override {k!r}: no unit {unit!r} in {f}")
            next(u for u in units if u.name == unit).process = _process(v, f"override {k!r}")
            continue
        unit, var = split_ref(k, f"override {k!r}")
        if unit not in names:
            raise ScenarioError(f"override {k!r}: no unit {unit!r} in {f}")
        next(u for u in units if u.name == unit).parameters[var] = v

    def check_ref(ref: Any, where: str) -> Tuple[str, str]:
        unit, var = split_ref(ref, where)
        if unit not in names:
            raise ScenarioError(f"{where}: unknown unit {unit!r} in {ref!r} (units: {', '.join(sorted(names))})")
        return unit, var

    connections: List[Connection] = []
    raw_conns = data.get("connections", [])
    if not isinstance(raw_conns, list):
        raise ScenarioError(f"{f}: 'connections' must be an array")
    for i, c in enumerate(raw_conns):
        where = f"{f}: connections[{i}]"
        gain, offset, extrap, delayed = 1.0, 0.0, None, False
        if isinstance(c, str):
            if "->" not in c:
                raise ScenarioError(f"{where}: {c!r} is not of the form 'unit.out -> unit.in'")
            src, dst = (s.strip() for s in c.split("->", 1))
        elif isinstance(c, dict):
            unknown = set(c) - {"from", "to", "gain", "offset", "extrapolation", "delayed"}
            if unknown:
                raise ScenarioError(f"{where}: unknown key {sorted(unknown)[0]!r} "
                                    "(from, to, gain, offset, extrapolation, delayed)")
            delayed = c.get("delayed", False)
            if not isinstance(delayed, bool):
                raise ScenarioError(f"{where}: delayed must be true or false, got {delayed!r}")
            extrap = c.get("extrapolation")
            if extrap is not None and extrap not in CONNECTION_EXTRAPOLATIONS:
                raise ScenarioError(f"{where}: extrapolation {extrap!r} is not one of "
                                    f"{', '.join(CONNECTION_EXTRAPOLATIONS)}")
            src, dst = c.get("from"), c.get("to")
            for key in ("gain", "offset"):
                v = c.get(key, 1.0 if key == "gain" else 0.0)
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                    raise ScenarioError(f"{where}: {key} must be a finite number, got {v!r}")
            gain, offset = float(c.get("gain", 1.0)), float(c.get("offset", 0.0))
        else:
            raise ScenarioError(f"{where} must be a string 'a.x -> b.y' or a table with from/to")
        su, sv = check_ref(src, where)
        du, dv = check_ref(dst, where)
        conn = Connection(su, sv, du, dv, gain, offset, extrap, delayed)
        if any((x.dst_unit, x.dst_var) == (du, dv) for x in connections):
            raise ScenarioError(f"{where}: input {du}.{dv} is already connected")
        connections.append(conn)

    inputs: List[InputSpec] = []
    for i, s in enumerate(data.get("inputs", [])):
        where = f"{f}: inputs[{i}]"
        if not isinstance(s, dict):
            raise ScenarioError(f"{where} must be a table")
        unit, var = check_ref(s.get("target"), where)
        kind = s.get("kind", "constant")
        if kind not in INPUT_KINDS:
            raise ScenarioError(f"{where}: kind {kind!r} is not one of {', '.join(INPUT_KINDS)}")
        params = {k: v for k, v in s.items() if k not in ("target", "kind")}
        _check_input_params(kind, params, where)
        inputs.append(InputSpec(unit, var, kind, params))

    faults: List[FaultSpec] = []
    for i, s in enumerate(data.get("faults", [])):
        where = f"{f}: faults[{i}]"
        if not isinstance(s, dict):
            raise ScenarioError(f"{where} must be a table")
        unit, var = check_ref(s.get("target"), where)
        if "value" not in s:
            raise ScenarioError(f"{where}: missing 'value'")
        faults.append(FaultSpec(unit, var, seconds_to_ns(s.get("at", 0.0), f"{where}.at"), s["value"]))

    raw_log = data.get("log", {})
    if not isinstance(raw_log, dict):
        raise ScenarioError(f"{f}: [log] must be a table")
    raw_log = dict(raw_log)
    for k, v in (overrides or {}).items():
        if k.startswith("log."):
            raw_log[k.split(".", 1)[1]] = v
    for key in raw_log:
        if key not in ("include", "exclude", "parameters", "encoding", "process"):
            raise ScenarioError(f"{f}: [log] unknown key {key!r}")
    encoding = raw_log.get("encoding", "json")
    if encoding not in LOG_ENCODINGS:
        raise ScenarioError(f"{f}: [log] encoding {encoding!r} is not one of {', '.join(LOG_ENCODINGS)}")
    log_process = raw_log.get("process", False)
    if not isinstance(log_process, bool):
        raise ScenarioError(f"{f}: [log] process must be true or false, got {log_process!r}")
    logspec = LogSpec(list(raw_log.get("include", ["*"])), list(raw_log.get("exclude", [])),
                      bool(raw_log.get("parameters", True)), encoding, log_process)
    from .foxglove import parse_bodies

    bodies = parse_bodies(data.get("foxglove"), f)
    for b in bodies:
        for ref in b.refs():
            check_ref(ref, f"foxglove body {b.name!r}")
    return Scenario(path, text, units, connections, inputs, faults, logspec, start_ns, stop_ns, step_ns,
                    algorithm, extrapolation, tolerance, lazy, bodies)


def _check_input_params(kind: str, p: Dict[str, Any], where: str) -> None:
    need = {"constant": ("value",), "step": ("at", "value"), "ramp": ("at", "slope"),
            "sine": ("amplitude", "frequency"), "table": ("times", "values")}[kind]
    for key in need:
        if key not in p:
            raise ScenarioError(f"{where}: input kind {kind!r} needs {key!r}")
    if kind == "table":
        t, v = p["times"], p["values"]
        if len(t) != len(v) or not t or any(b < a for a, b in zip(t, t[1:])):
            raise ScenarioError(f"{where}: 'times' must be increasing and as long as 'values'")
