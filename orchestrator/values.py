"""Scenario values against the FMI types of the variables they are set into.

The schema (:mod:`~immersim.orchestrator.schema`) checks a scenario's shape; once the units'
model descriptions are read, every value the master will set before or during a run (unit
parameters and start values, fault values) is checked against its variable here: a Boolean
takes true/false, an integer type an integer inside the type's range and the variable's
``min``/``max`` (never wrapped), a Real a finite number (NaN/inf only as a fault forced into a
Real input, the deliberate way to provoke a unit's error), a String a string. A fault may force
an input or a tunable parameter only.
"""
from __future__ import annotations

import ast
import math
import re
from pathlib import Path
from typing import Any, Dict, Optional, Tuple

from .errors import ScenarioError
from .tomlfiles import show as _show

#: range of each FMI integer type (FMI 2.0 ``Integer`` and ``Enumeration`` are 32-bit)
INT_RANGES: Dict[str, Tuple[int, int]] = {
    "Integer": (-2 ** 31, 2 ** 31 - 1), "Enumeration": (-2 ** 31, 2 ** 31 - 1),
    "Int8": (-2 ** 7, 2 ** 7 - 1), "UInt8": (0, 2 ** 8 - 1),
    "Int16": (-2 ** 15, 2 ** 15 - 1), "UInt16": (0, 2 ** 16 - 1),
    "Int32": (-2 ** 31, 2 ** 31 - 1), "UInt32": (0, 2 ** 32 - 1),
    "Int64": (-2 ** 63, 2 ** 63 - 1), "UInt64": (0, 2 ** 64 - 1),
}
REAL_TYPES = ("Real", "Float64", "Float32")
#: the largest finite Float32 (a larger value would become inf)
FLOAT32_MAX = 3.4028234663852886e38
Bounds = Tuple[Optional[int], Optional[int]]


def type_error(value: Any, fmi_type: str) -> Optional[str]:
    """Why ``value`` is not of a kind an FMI ``fmi_type`` variable takes (a number for a Real,
    an integer for an integer type, true/false for a Boolean, a string for a String or a
    Binary given as hex text); None if it is. The one check of a scenario value's type."""
    if fmi_type in REAL_TYPES:
        ok = not isinstance(value, bool) and isinstance(value, (int, float))
        return None if ok else f"{fmi_type} takes a number, got {_show(value)}"
    if fmi_type == "Boolean":
        return None if isinstance(value, bool) else f"Boolean takes true or false, got {_show(value)}"
    if fmi_type in ("String", "Binary"):
        return None if isinstance(value, str) else f"{fmi_type} takes a string, got {_show(value)}"
    if fmi_type in INT_RANGES and (isinstance(value, bool) or not isinstance(value, int)):
        return f"{fmi_type} takes an integer, got {_show(value)}"
    return None


def check_value(value: Any, fmi_type: str, bounds: Bounds = (None, None), non_finite: bool = False) -> Optional[str]:
    """Why ``value`` cannot be set into a variable of FMI type ``fmi_type``; None if it can.

    Parameters
    ----------
    value : bool, int, float or str
        As the scenario gives it (TOML).
    fmi_type : str
        ``Real``, ``Integer``, ``Boolean``, ``String`` (FMI 2.0) or an FMI 3.0 type name.
    bounds : (int or None, int or None)
        The variable's declared ``min`` and ``max`` (integer types).
    non_finite : bool
        Accept NaN/inf for a Real (a fault forced into a Real input).
    """
    return type_error(value, fmi_type) or range_error(value, fmi_type, bounds, non_finite)


def range_error(value: Any, fmi_type: str, bounds: Bounds = (None, None), non_finite: bool = False) -> Optional[str]:
    """Why ``value``, of a kind ``fmi_type`` takes (:func:`type_error` says None), is out of its
    range (finite, Float32, the integer type's range and ``bounds``); None if it is in. Parameters
    as :func:`check_value`."""
    if fmi_type in REAL_TYPES:
        try:
            number = float(value)
        except OverflowError:
            return f"{_show(value)} is too large for {fmi_type}"
        if not non_finite and not math.isfinite(number):
            return f"{fmi_type} value must be finite, got {_show(value)}"
        if fmi_type == "Float32" and math.isfinite(number) and abs(number) > FLOAT32_MAX:
            return f"{_show(value)} is outside the Float32 range +-{FLOAT32_MAX:.8g}"
    elif fmi_type in INT_RANGES:
        lo, hi = INT_RANGES[fmi_type]
        lo = lo if bounds[0] is None else max(lo, bounds[0])
        hi = hi if bounds[1] is None else min(hi, bounds[1])
        if not lo <= value <= hi:
            return f"{value} is outside the range {lo}..{hi} of this {fmi_type} variable"
    return None


def _int(text: Any) -> Optional[int]:
    try:
        return int(text) if text is not None else None
    except (TypeError, ValueError):
        return None


def declared_bounds(path: Path, unit: str) -> Dict[str, Bounds]:
    """``name -> (min, max)`` of the integer variables of an FMU that declare them (its own or
    its declared type's)."""
    from .fmu import read_model

    out: Dict[str, Bounds] = {}
    for v in read_model(path, unit)[0].modelVariables:
        if v.type not in INT_RANGES:
            continue
        declared = getattr(v, "declaredType", None)
        lo, hi = (_int(getattr(v, key, None) if getattr(v, key, None) is not None else getattr(declared, key, None))
                  for key in ("min", "max"))
        if lo is not None or hi is not None:
            out[v.name] = (lo, hi)
    return out


def check_values(scenario, variables: Dict[str, Dict[str, Any]], paths: Dict[str, Path]) -> None:
    """Check every parameter and fault value of ``scenario`` against its variable's FMI type.

    ``variables``: unit -> name -> :class:`~immersim.orchestrator.fmu.VarInfo` (every name the
    scenario uses exists: checked before). Raises :class:`ScenarioError` ``<file>: <key path>:
    <reason>``.
    """

    at = scenario.where
    bounds = {name: declared_bounds(p, name) for name, p in paths.items()}
    for i, u in enumerate(scenario.units):
        for pname, value in u.parameters.items():
            v = variables[u.name].get(pname)
            if v is None:
                continue
            where = at("units", i, "parameters", pname)
            if type_error(value, v.type):
                raise ScenarioError(f"{where}: parameter {u.name}.{pname}: type mismatch, the FMU declares "
                                    f"{v.type} but the scenario gives {type(value).__name__} {value!r}")
            why = range_error(value, v.type, bounds[u.name].get(pname, (None, None)))
            if why:
                raise ScenarioError(f"{where}: {u.name}.{pname}: {why}")
    for i, s in enumerate(scenario.faults):
        v = variables[s.unit].get(s.var)
        if v is None:
            continue
        if v.causality in ("parameter", "structuralParameter") and v.variability != "tunable":
            raise ScenarioError(f"{at('faults', i, 'target')}: {s.unit}.{s.var} is a {v.variability or 'fixed'} "
                                f"parameter; a fault forces an input or a tunable parameter")
        why = check_value(s.value, v.type, bounds[s.unit].get(s.var, (None, None)),
                          non_finite=v.causality == "input")
        if why:
            raise ScenarioError(f"{at('faults', i, 'value')}: {s.unit}.{s.var}: {why}")


_RAISED = re.compile(r"^\s*(\w+)\((['\"])(.*)\2\)\s*$", re.S)


def unit_reason(message: str, unit: str) -> str:
    """The reason a unit gave, out of an FMI call's error text: the Python exception a
    pythonfmu unit raised (``ValueError('plat: bad parameter: ...')``) unwrapped from the
    binary's ``Fatal py exception`` preamble, without the instance name and ``(t = 0 s)``."""
    text = message.split(" s: ", 1)[1] if re.match(r"unit \S+: \w+ returned \w+ at t = ", message) else message
    last = text.strip().splitlines()[-1] if text.strip() else text
    raised = _RAISED.match(last)
    if raised:
        try:
            text = ast.literal_eval(raised.group(2) + raised.group(3) + raised.group(2))
        except (ValueError, SyntaxError):
            text = raised.group(3)
    text = " ".join(text.split())
    for prefix in (f"{unit}: ", "bad parameter: ", "parameters: "):
        text = text.removeprefix(prefix)
    return re.sub(r"\s*\(t = [^)]*\)$", "", text)


def refused_at_initialization(scenario, unit: str, error: Exception) -> ScenarioError:
    """The error of a unit that refused its parameters when initialized, as one line naming
    the scenario file, the key of the parameter the unit's reason names (its value) and the
    reason: ``<file>: units[1].parameters.M = -240.0: unit plat refused it: M = -240.0 must be > 0``."""
    reason = unit_reason(str(error), unit)
    i, spec = next((i, u) for i, u in enumerate(scenario.units) if u.name == unit)
    named = [p for p in spec.parameters if re.search(rf"(?<![\w\[]){re.escape(p)}(?![\w\[\]])", reason)]
    named = named or [p for p, v in spec.parameters.items() if isinstance(v, str) and repr(v) in reason]
    if named:
        p = max(named, key=len)
        where = f"{scenario.where('units', i, 'parameters', p)} = {spec.parameters[p]!r}"
        return ScenarioError(f"{where}: unit {unit} refused it at initialization: {reason}")
    return ScenarioError(f"{scenario.file}: units[{i}] ({unit}): the unit refused its parameters at "
                         f"initialization: {reason}")
