"""The schema of scenario and sweep files, declared once (pydantic v2 models, one per table).

Every key of a scenario (``[simulation]``, ``[[units]]``, ``[[connections]]``, ``[[inputs]]``,
``[[faults]]``, ``[log]``, ``[[foxglove.bodies]]``) and of a sweep file (``scenario``,
``[grid]``, ``[[variants]]``, ``[metrics]``, ``[plot]``) is a field here with its type, range
and unit; a key no model declares is refused with a "did you mean". :func:`validate` turns the
first violation into a :class:`~immersim.orchestrator.errors.ScenarioError` that names the file
and the key path (``units[2].parameters.M``, ``inputs[4].times``). The loaders
(:mod:`~immersim.orchestrator.scenario`, :mod:`~immersim.orchestrator.sweep.spec`) convert the
validated models into their dataclasses; what depends on the FMUs (a variable's FMI type and
range, causality, variability) is checked by :mod:`~immersim.orchestrator.values` once the
model descriptions are read.
"""
from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Annotated, Any, Dict, List, Literal, Optional, Tuple, Union

from pydantic import (AfterValidator, BaseModel, ConfigDict, Discriminator, Field, Tag,
                      ValidationError, ValidationInfo, model_validator)
from pydantic_core import PydanticCustomError

from .errors import ScenarioError
from .tomlfiles import did_you_mean, key_path
from .tomlfiles import show as _show

#: the largest time a scenario may name (s): times are int64 nanoseconds
MAX_TIME_S = 9.2e9
ALGORITHMS = ("gauss-seidel", "jacobi")
EXTRAPOLATIONS = ("zoh", "linear")
#: a connection may also say "angle": linear, the difference of two samples taken the short way
#: round the circle (an angle output wrapped to (-pi, pi] does not turn by 2 pi when it wraps)
CONNECTION_EXTRAPOLATIONS = EXTRAPOLATIONS + ("angle",)
INPUT_KINDS = ("constant", "step", "ramp", "sine", "table")
LOG_ENCODINGS = ("json", "ros1")
SHAPES = ("cube", "sphere", "cylinder")
REDUCE_NAMES = ("max", "min", "mean", "rms", "absmax", "final")
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_\-]*$")

# -- value types ---------------------------------------------------------------------------
def _fail(kind: str, message: str, **ctx: Any) -> PydanticCustomError:
    return PydanticCustomError(kind, message, ctx)


def _number(x: Any) -> float:
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        raise _fail("number", "expected a number, got {got}", got=_show(x))
    try:
        value = float(x)
    except OverflowError:
        raise _fail("number", "{got} is too large", got=_show(x)) from None
    if not math.isfinite(value):
        raise _fail("finite", "must be finite, got {got}", got=_show(x))
    return value


def _seconds(x: Any) -> float:
    value = _number(x)
    if abs(value) > MAX_TIME_S:
        raise _fail("time", "{got} s is outside +-{lim} s (times are int64 nanoseconds)", got=_show(x),
                    lim=f"{MAX_TIME_S:g}")
    return value


def _above(low: float, strict: bool = True):
    def check(x: float) -> float:
        if x <= low if strict else x < low:
            raise _fail("range", "must be {op} {low}, got {got}", op=">" if strict else ">=", low=f"{low:g}",
                        got=_show(x))
        return x
    return check


def _unit_interval(x: float) -> float:
    if not 0.0 <= x <= 1.0:
        raise _fail("range", "must be in 0..1, got {got}", got=_show(x))
    return x


def _scalar(x: Any) -> Any:
    if not isinstance(x, (bool, int, float, str)):
        raise _fail("scalar", "expected a number, true/false or a string, got {got}", got=_show(x))
    return x


def _ref(x: Any) -> str:
    if not isinstance(x, str):
        raise _fail("ref", "expected a 'unit.variable' string, got {got}", got=_show(x))
    unit, _, var = x.partition(".")
    if not unit.strip() or not var.strip():
        raise _fail("ref", "{got} is not of the form 'unit.variable'", got=_show(x))
    return x


def _ref_or_number(x: Any) -> Union[str, float]:
    if isinstance(x, str):
        return _ref(x)
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        raise _fail("ref", "expected a number or a 'unit.variable' reference, got {got}", got=_show(x))
    return _number(x)


def _identifier(x: Any) -> str:
    if not isinstance(x, str) or not _NAME.match(x):
        raise _fail("name", "must be an identifier (letters, digits, _ and -), got {got}", got=_show(x))
    return x


def _process(x: Any) -> int:
    if isinstance(x, str) and x.strip().isdigit():
        x = int(x)
    if isinstance(x, bool) or not isinstance(x, int) or x < 0:
        raise _fail("process", "must be an integer >= 0 (0: the master's process, N: worker process N), "
                               "got {got}", got=_show(x))
    return x


def _build_size(x: Any) -> int:
    if isinstance(x, bool) or not isinstance(x, int):
        raise _fail("build", "a build option is an integer (a capacity), got {got}", got=_show(x))
    return x


def _nonempty(x: str) -> str:
    if not x.strip():
        raise _fail("empty", "must not be empty")
    return x


Number = Annotated[Any, AfterValidator(_number)]
Seconds = Annotated[Any, AfterValidator(_seconds)]
Positive = Annotated[Any, AfterValidator(_number), AfterValidator(_above(0.0))]
NonNegative = Annotated[Any, AfterValidator(_number), AfterValidator(_above(0.0, strict=False))]
UnitInterval = Annotated[Any, AfterValidator(_number), AfterValidator(_unit_interval)]
Scalar = Annotated[Any, AfterValidator(_scalar)]
Ref = Annotated[Any, AfterValidator(_ref)]
RefOrNumber = Annotated[Any, AfterValidator(_ref_or_number)]
Identifier = Annotated[Any, AfterValidator(_identifier)]
Text = Annotated[str, AfterValidator(_nonempty)]


def _array(item: Any, n: int) -> Any:
    """An array of exactly ``n`` items (TOML arrays are lists)."""
    return Annotated[List[item], Field(min_length=n, max_length=n)]


Triple = _array(RefOrNumber, 3)


class Table(BaseModel):
    """A TOML table: the declared keys only (an unknown key gets a "did you mean")."""

    model_config = ConfigDict(strict=True, extra="forbid", frozen=True, populate_by_name=False)

    @model_validator(mode="before")
    @classmethod
    def _known_keys(cls, data: Any) -> Any:
        if not isinstance(data, dict):
            raise _fail("table", "expected a table, got {got}", got=_show(data))
        if cls.model_config.get("extra") == "forbid":
            known = [f.alias or name for name, f in cls.model_fields.items()]
            for key in data:
                if key not in known:
                    raise _fail("unknown_key", "unknown key {key}{hint}", key=_show(key), hint=did_you_mean(key, known))
        return data


# -- scenario files ------------------------------------------------------------------------
class SimulationTable(Table):
    """``[simulation]``: the time grid (s) and the master algorithm."""

    start: Seconds = Field(0.0, description="start time, s")
    stop: Optional[Seconds] = Field(None, description="stop time, s (default: start + 10 steps)")
    step: Annotated[Any, AfterValidator(_seconds), AfterValidator(_above(0.0))] = Field(
        0.033, description="macro step, s")
    algorithm: Literal[ALGORITHMS] = "gauss-seidel"
    extrapolation: Literal[EXTRAPOLATIONS] = "linear"
    tolerance: Optional[Positive] = Field(None, description="relative tolerance handed to the units")
    lazy: bool = Field(True, description="step units that report at_rest lazily")


class UnitTable(Table):
    """``[[units]]``: one FMU instance and its parameters (checked against the FMU's types)."""

    name: Identifier
    fmu: Text = Field(description="a built-in unit name or the path of an FMI 2.0/3.0 CS FMU")
    parameters: Dict[str, Scalar] = Field(default_factory=dict)
    process: Annotated[Any, AfterValidator(_process)] = Field(0, description="0: the master's process, N: worker N")
    build: Dict[str, Annotated[Any, AfterValidator(_build_size)]] = Field(
        default_factory=dict, description="build options of a built-in unit (its capacities), e.g. { players = 8 }")


class ConnectionTable(Table):
    """``[[connections]]``: ``to = gain * from + offset`` (gain and offset for Real variables)."""

    src: Ref = Field(alias="from")
    dst: Ref = Field(alias="to")
    gain: Number = 1.0
    offset: Number = 0.0
    extrapolation: Optional[Literal[CONNECTION_EXTRAPOLATIONS]] = None
    delayed: bool = False


def _arrow(x: Any) -> str:
    if "->" not in x:
        raise _fail("arrow", "{got} is not of the form 'unit.out -> unit.in'", got=_show(x))
    for ref in x.split("->", 1):
        _ref(ref.strip())
    return x


def _table_or_string(x: Any) -> str:
    return "<string>" if isinstance(x, str) else "<table>"


ConnectionEntry = Annotated[Union[Annotated[Annotated[str, AfterValidator(_arrow)], Tag("<string>")],
                                  Annotated[ConnectionTable, Tag("<table>")]], Discriminator(_table_or_string)]


class _Input(Table):
    target: Ref = Field(description="the Real input driven, 'unit.variable'")


class ConstantInput(_Input):
    kind: Literal["constant"] = "constant"
    value: Number


class StepInput(_Input):
    kind: Literal["step"]
    at: Seconds
    value: Number
    initial: Number = Field(0.0, description="value before 'at'")


class RampInput(_Input):
    kind: Literal["ramp"]
    at: Seconds
    slope: Number = Field(description="per s")
    initial: Number = 0.0


class SineInput(_Input):
    kind: Literal["sine"]
    amplitude: Number
    frequency: NonNegative = Field(description="Hz")
    offset: Number = 0.0
    phase: Number = Field(0.0, description="rad")


class TableInput(_Input):
    kind: Literal["table"]
    times: Annotated[List[Seconds], Field(min_length=1)]
    values: Annotated[List[Number], Field(min_length=1)]

    @model_validator(mode="after")
    def _increasing(self) -> "TableInput":
        if len(self.times) != len(self.values):
            raise ValueError(f"'times' has {len(self.times)} entries, 'values' {len(self.values)}: "
                             "they must be as long")
        for j, (a, b) in enumerate(zip(self.times, self.times[1:])):
            if b < a:
                raise ValueError(f"'times' must be increasing: times[{j + 1}] = {b:g} < times[{j}] = {a:g}")
        return self


def _input_kind(x: Any) -> Any:
    return f"<{x.get('kind', 'constant')}>" if isinstance(x, dict) else None


InputEntry = Annotated[Union[Annotated[ConstantInput, Tag("<constant>")], Annotated[StepInput, Tag("<step>")],
                             Annotated[RampInput, Tag("<ramp>")], Annotated[SineInput, Tag("<sine>")],
                             Annotated[TableInput, Tag("<table>")]], Discriminator(_input_kind)]


class FaultTable(Table):
    """``[[faults]]``: from ``at`` on, force an input (or tunable parameter) to ``value``."""

    target: Ref
    at: Seconds = Field(0.0, description="s")
    value: Scalar = Field(description="of the target's FMI type; NaN/inf only into a Real input")


class LogTable(Table):
    """``[log]``: what the MCAP log holds and how it is written."""

    include: List[str] = Field(default_factory=lambda: ["*"], description="glob patterns over unit.variable")
    exclude: List[str] = Field(default_factory=list)
    parameters: bool = True
    encoding: Literal[LOG_ENCODINGS] = "json"
    process: bool = False


class BodyTable(Table):
    """``[[foxglove.bodies]]``: one body of the 3D view (see orchestrator/foxglove.py)."""

    name: Text
    parent: Text = "world"
    position: Triple = Field((0.0, 0.0, 0.0), description="m, numbers or signal references")
    euler: Triple = Field((0.0, 0.0, 0.0), description="rad, numbers or signal references")
    order: Literal["xyz", "zyx"] = "xyz"
    offset: _array(Number, 3) = Field((0.0, 0.0, 0.0), description="m")
    shape: Literal[SHAPES] = "cube"
    size: _array(NonNegative, 3) = Field((1.0, 1.0, 1.0), description="m")
    color: _array(UnitInterval, 4) = Field((0.6, 0.6, 0.6, 1.0), description="RGBA, each in 0..1")


class LiveInputTable(Table):
    """``[[live_inputs]]``: a Real input driven by what a live client publishes (``--live``)."""

    topic: Text = Field(description="the topic a client publishes JSON messages on, e.g. '/cmd_vel'")
    field: str = Field("", description="dotted path into the message, list items by index: 'linear.x', 'axes.1'")
    target: Ref = Field(description="the Real input driven, 'unit.variable'")
    scale: Number = 1.0
    offset: Number = 0.0
    initial: Number = Field(0.0, description="value until the first message arrives (and without --live)")


class FoxgloveTable(Table):
    """``[foxglove]``: the 3D view."""

    bodies: List[BodyTable] = Field(default_factory=list)
    units: bool = Field(False, description="also draw what the units describe (the collision unit's meshes)")
    mesh_triangles: Annotated[int, Field(ge=0)] = Field(
        500_000, description="static triangles drawn as meshes; beyond, static bodies as bounding boxes")
    rods: bool = Field(True, description="draw a platform's rods, redrawn every step (its inverse kinematics each step)")


class ScenarioFile(Table):
    """A whole scenario file; cross-references between tables are checked here."""

    simulation: SimulationTable = Field(default_factory=SimulationTable)
    units: Annotated[List[UnitTable], Field(min_length=1)]
    connections: List[ConnectionEntry] = Field(default_factory=list)
    inputs: List[InputEntry] = Field(default_factory=list)
    faults: List[FaultTable] = Field(default_factory=list)
    log: LogTable = Field(default_factory=LogTable)
    description: str = ""
    title: str = ""
    foxglove: Optional[FoxgloveTable] = None
    live_inputs: List[LiveInputTable] = Field(default_factory=list)

    @model_validator(mode="after")
    def _references(self, info: ValidationInfo) -> "ScenarioFile":
        ctx = info.context or {}
        place = ctx.get("place", key_path)     # a key path as "<file>: <key path>" (where written)
        ref = ctx.get("ref", key_path)         # ... as a short reference inside a message

        def fail(loc: tuple, message: str) -> PydanticCustomError:
            return PydanticCustomError("placed", "{text}", {"text": f"{place(loc)}: {message}"})

        sim = self.simulation
        if sim.stop is not None and sim.stop <= sim.start:
            raise fail((), f"simulation.stop = {sim.stop:g} s must be after simulation.start = {sim.start:g} s")
        names: List[str] = []
        for i, u in enumerate(self.units):
            if u.name in names:
                raise fail(("units", i, "name"), f"duplicate unit instance name {u.name!r}")
            names.append(u.name)

        def known(ref_: str, loc: tuple) -> Tuple[str, str]:
            unit, var = (s.strip() for s in ref_.split(".", 1))
            if unit not in names:
                raise fail(loc, f"unknown unit {unit!r} in {ref_!r}{did_you_mean(unit, names)}")
            return unit, var

        fed: Dict[Tuple[str, str], str] = {}
        for i, c in enumerate(self.connections):
            src, dst = (c.split("->", 1) if isinstance(c, str) else (c.src, c.dst))
            known(src, ("connections", i))
            target = known(dst, ("connections", i))
            if target in fed:
                raise fail(("connections", i), f"input {'.'.join(target)} is already connected ({fed[target]})")
            fed[target] = ref(("connections", i))
        for table in ("inputs", "live_inputs"):
            for i, s in enumerate(getattr(self, table)):
                target = known(s.target, (table, i, "target"))
                if target in fed:
                    raise fail((table, i, "target"), f"{'.'.join(target)} is already driven by {fed[target]}")
                fed[target] = ref((table, i))
        for i, f in enumerate(self.faults):
            known(f.target, ("faults", i, "target"))
        for i, b in enumerate(self.foxglove.bodies if self.foxglove else []):
            for key in ("position", "euler"):
                for j, r in enumerate(getattr(b, key)):
                    if isinstance(r, str):
                        known(r, ("foxglove", "bodies", i, key, j))
        return self


# -- sweep files ---------------------------------------------------------------------------
class MetricTable(Table):
    """A metric reduced from logged samples (``summary.csv`` column)."""

    signal: Annotated[str, AfterValidator(_ref)] = Field(description="pattern over unit.variable")
    reduce: Literal[REDUCE_NAMES] = "max"
    after: Seconds = Field(None, description="only samples at t >= after (s) count")


class PlotTable(Table):
    """``[plot]``: one comparison figure, a subplot per ``y`` column against ``x``."""

    x: Union[str, List[str]]
    y: Union[str, List[str]]
    hue: Optional[Union[str, List[str]]] = None
    logx: bool = False
    logy: bool = False
    name: str = ""


class VariantTable(Table):
    """``[[variants]]``: a name and override keys (``unit.param``, ``simulation.<key>``, ...)."""

    model_config = ConfigDict(strict=True, extra="allow", frozen=True)
    name: Optional[Text] = None

    @model_validator(mode="after")
    def _single_values(self) -> "VariantTable":
        for key, value in (self.model_extra or {}).items():
            if not isinstance(value, (bool, int, float, str)):
                raise ValueError(f"key {key!r}: expected a single value, got {value!r}")
        return self


def _metric_kind(x: Any) -> str:
    return "<builtin>" if isinstance(x, str) else "<table>"


MetricEntry = Annotated[Union[Annotated[str, Tag("<builtin>")], Annotated[MetricTable, Tag("<table>")]],
                        Discriminator(_metric_kind)]
PlotEntry = Annotated[Union[Annotated[PlotTable, Tag("<table>")], Annotated[List[PlotTable], Tag("<array>")]],
                      Discriminator(lambda x: "<array>" if isinstance(x, list) else "<table>")]


class SweepFile(Table):
    """A whole sweep file (orchestrator/sweep/spec.py checks what needs the scenario: the override
    keys against its units, the plot columns against the grid and the metrics)."""

    scenario: Text = Field(description="scenario file, relative to the sweep file")
    grid: Dict[str, Annotated[List[Scalar], Field(min_length=1)]] = Field(default_factory=dict)
    variants: List[VariantTable] = Field(default_factory=list)
    metrics: Dict[str, MetricEntry] = Field(default_factory=dict)
    plot: Optional[PlotEntry] = None
    description: str = ""
    title: str = ""


# -- reporting -------------------------------------------------------------------------------
def _message(err: Dict[str, Any]) -> str:
    kind, msg = err["type"], err["msg"]
    if kind == "value_error":
        return msg.removeprefix("Value error, ")
    if kind == "missing":
        return "missing (required)"
    if kind == "union_tag_not_found":
        return f"expected a table, got {_show(err['input'])}"
    if kind == "union_tag_invalid":
        ctx = err.get("ctx", {})
        return f"kind {str(ctx.get('tag')).strip('<>')!r} is not one of {', '.join(INPUT_KINDS)}"
    if kind == "literal_error":
        expected = err["ctx"]["expected"].replace(" or ", ", ").replace("'", "")
        return f"{_show(err['input'])} is not one of {expected}"
    if kind in ("bool_type", "string_type", "list_type", "dict_type", "tuple_type", "model_type",
                "model_attributes_type"):
        want = {"bool_type": "true or false", "string_type": "a string", "list_type": "an array",
                "tuple_type": "an array", "dict_type": "a table", "model_type": "a table",
                "model_attributes_type": "a table"}[kind]
        return f"expected {want}, got {_show(err['input'])}"
    if kind == "too_short":
        n = err['ctx']['min_length']
        return f"must have at least {n} entries, got {_show(err['input'])}" if n > 1 else "must not be empty"
    if kind == "too_long":
        return f"must have at most {err['ctx']['max_length']} entries, got {_show(err['input'])}"
    if err.get("ctx") is not None or kind in ("number", "finite", "range", "ref", "name", "process", "scalar",
                                                "table", "unknown_key", "time", "arrow", "empty"):
        return msg
    return f"{msg.replace('Input should be', 'must be')}, got {_show(err['input'])}"


def validate(model: type, data: Dict[str, Any], path: Path, origins: Optional[Dict[tuple, str]] = None,
             place: Optional[Any] = None, ref: Optional[Any] = None):
    """Validate ``data`` against ``model``; the first violation as a :class:`ScenarioError`
    ``<file>: <key path>: <reason>`` (``origins``: key paths set by an override, named too;
    ``place(loc)``: a key path as ``<file>: <key path>`` where it was written, for data merged
    from several files or expanded, and ``ref(loc)`` as a reference inside a message)."""
    place = place or (lambda loc: f"{path}: {key_path(loc)}" if loc else str(path))
    try:
        return model.model_validate(data, context={"place": place, "ref": ref or key_path})
    except ValidationError as exc:
        err = exc.errors(include_url=False)[0]
        if err["type"] == "placed":
            raise ScenarioError(err["msg"]) from None
        loc = tuple(p for p in err["loc"] if not (isinstance(p, str) and p.startswith("<") and p.endswith(">")))
        where = place(loc)
        for n in range(len(loc), 0, -1):
            if loc[:n] in (origins or {}):
                where += f" (set by override {origins[loc[:n]]!r})"
                break
        raise ScenarioError(f"{where}: {_message(err)}") from None
