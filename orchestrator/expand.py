"""Scenario shorthand: signal groups, parameter lists, scene tables.

A scenario's raw TOML data is expanded into the one-signal-per-entry form the schema checks
(:mod:`~immersim.orchestrator.schema`), before validation:

* a reference may name several signals: ``[a..b]`` is the integers a to b (``[1]`` ... ``[b]``
  in the name) and ``{x,y,yaw}`` the listed names; the name is expanded in writing order, the
  leftmost part varying slowest: ``net.avatar[1..2].{x,y}`` is ``avatar[1].x, avatar[1].y,
  avatar[2].x, avatar[2].y``. A connection's ``from`` and ``to`` are zipped (they must name as
  many signals); ``gain``, ``offset`` and ``extrapolation`` hold for every signal of the entry,
  or, given as a table (``extrapolation = { yaw = "zoh" }``), for the signals whose destination
  name ends in that part. An input's, fault's or live input's ``target`` gives one entry per signal.
* a parameter key may name several variables: its value is one value for all, or an array of
  one value per variable (``"body[1..3].{x,y}" = [43.0, 49.2, 48.1, 54.4, 47.8, 51.3]``).
* a String parameter given as an array of tables is written in the item-list language of the
  collision unit's ``scene`` (``{ kind = "box", name = "a", sx = 4 }`` -> ``box:name=a,sx=4``,
  items joined by ``;``; true/false as 1/0, numbers as TOML reads them, strings as written);
  as an array of strings, they are joined by ``"; "`` (the collision unit's ``pairs``).

Each expanded entry remembers where it was written (:data:`Sources`), so an error names the
file and the key as the person wrote them.
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Dict, List, Tuple

from .errors import ScenarioError

#: an expanded key path -> (file, key path as written there)
Sources = Dict[tuple, Tuple[Path, tuple]]
_PART = re.compile(r"\[(-?\d+)\.\.(-?\d+)\]|\{([^{}]*)\}")
OPTIONS = ("gain", "offset", "extrapolation")
ARRAYS = ("connections", "inputs", "faults", "live_inputs")


def is_group(name: Any) -> bool:
    """Whether ``name`` is a string with a ``[a..b]`` or ``{...}`` part."""
    return isinstance(name, str) and (_PART.search(name) is not None or "{" in name or ".." in name)


def names(pattern: str) -> List[str]:
    """Every name ``pattern`` stands for, in order (leftmost part slowest); raises ValueError."""
    out, pos = [""], 0
    for m in _PART.finditer(pattern):
        if m.group(3) is not None:
            alts = [s.strip() for s in m.group(3).split(",")]
            if not all(alts):
                raise ValueError(f"{pattern!r}: an empty name in {{{m.group(3)}}}")
        else:
            a, b = int(m.group(1)), int(m.group(2))
            if b < a:
                raise ValueError(f"{pattern!r}: the range [{a}..{b}] is empty (it must count up)")
            alts = [f"[{i}]" for i in range(a, b + 1)]
        out = [o + pattern[pos:m.start()] + x for o in out for x in alts]
        pos = m.end()
    out = [o + pattern[pos:] for o in out]
    bad = next((o for o in out if "{" in o or "}" in o or ".." in o), None)
    if bad is not None:
        raise ValueError(f"{pattern!r} is not a signal group (write [a..b] with integers a <= b, "
                         "or {a,b,c})")
    return out


def _names(pattern: str, at: str) -> List[str]:
    try:
        return names(pattern)
    except ValueError as exc:
        raise ScenarioError(f"{at}: {exc}") from None


def _member(dst: str) -> str:
    return dst.rsplit(".", 1)[-1].strip()


def _connection(entry: Any, at: str) -> List[Any]:
    """The one-signal entries of one ``[[connections]]`` entry (others unchanged, for the schema)."""
    if isinstance(entry, str) and "->" in entry:
        src, dst = (s.strip() for s in entry.split("->", 1))
        if not (is_group(src) or is_group(dst)):
            return [entry]
        pairs = _zip(src, dst, at, "the left side", "the right side")
        return [f"{a} -> {b}" for a, b in pairs]
    if not isinstance(entry, dict) or not isinstance(entry.get("from"), str) or not isinstance(entry.get("to"), str):
        return [entry]
    pairs = _zip(entry["from"], entry["to"], at, "'from'", "'to'")
    members = list(dict.fromkeys(_member(b) for _, b in pairs))
    for key in OPTIONS:
        if isinstance(entry.get(key), dict):
            unknown = [k for k in entry[key] if k not in members]
            if unknown:
                raise ScenarioError(f"{at}.{key}: {unknown[0]!r} names no signal of this connection "
                                    f"(its destinations end in {', '.join(members)})")
    out = []
    for a, b in pairs:
        one = {k: v for k, v in entry.items() if not isinstance(v, dict) or k not in OPTIONS}
        one["from"], one["to"] = a, b
        for key in OPTIONS:
            if isinstance(entry.get(key), dict) and _member(b) in entry[key]:
                one[key] = entry[key][_member(b)]
        out.append(one)
    return out


def _zip(src: str, dst: str, at: str, left: str, right: str) -> List[Tuple[str, str]]:
    a, b = _names(src, at), _names(dst, at)
    if len(a) != len(b):
        raise ScenarioError(f"{at}: {left} {src!r} names {len(a)} signal{'s' * (len(a) != 1)}, {right} "
                            f"{dst!r} names {len(b)}: they must name as many")
    return list(zip(a, b))


def _targets(entry: Any, at: str) -> List[Any]:
    if not isinstance(entry, dict) or not is_group(entry.get("target")):
        return [entry]
    return [{**entry, "target": t} for t in _names(entry["target"], f"{at}.target")]


def item_list(value: List[Any], at: str) -> Any:
    """An array parameter as the string the unit takes (see the module docstring); other
    arrays unchanged (the schema refuses them)."""
    if value and all(isinstance(v, str) for v in value):
        return "; ".join(value)
    if not value or not all(isinstance(v, dict) for v in value):
        return value
    items = []
    for j, item in enumerate(value):
        kind = item.get("kind")
        if not isinstance(kind, str) or not kind:
            raise ScenarioError(f"{at}[{j}]: an item needs kind = \"...\" (e.g. kind = \"box\")")
        fields = []
        for k, v in item.items():
            if k == "kind":
                continue
            if isinstance(v, bool):
                v = int(v)
            if isinstance(v, (dict, list)) or v is None:
                raise ScenarioError(f"{at}[{j}].{k}: expected a number, true/false or a string, got {v!r}")
            fields.append(f"{k}={v}")
        items.append(kind + (":" + ",".join(fields) if fields else ""))
    return ";".join(items)


def _parameters(params: Dict[str, Any], at: str) -> Tuple[Dict[str, Any], Dict[str, str]]:
    """Expanded parameters and, per expanded name, the key it was written as."""
    out: Dict[str, Any] = {}
    written: Dict[str, str] = {}
    for key, value in params.items():
        where = f"{at}[{key!r}]" if not re.fullmatch(r"[A-Za-z_]\w*", key) else f"{at}.{key}"
        if is_group(key):
            keys = _names(key, where)
            if isinstance(value, list):
                if len(value) != len(keys):
                    raise ScenarioError(f"{where}: the key names {len(keys)} variables, the array has "
                                        f"{len(value)} values: give one value, or one per variable")
                values = value
            else:
                values = [value] * len(keys)
        else:
            keys, values = [key], [item_list(value, where) if isinstance(value, list) else value]
        for k, v in zip(keys, values):
            if k in out:
                raise ScenarioError(f"{where}: {k!r} is set twice (also by {written[k]!r})")
            out[k], written[k] = v, key
    return out, written


def expand(data: Dict[str, Any], origin: Dict[tuple, Tuple[Path, tuple]], place) -> Sources:
    """Expand ``data`` (raw scenario tables, includes merged) in place; return its sources.

    ``origin``: the key paths of the merged data -> (file, key path written there) of every
    array entry, unit and unit parameter (:mod:`~immersim.orchestrator.include`); ``place(loc)``
    names a merged key path as ``<file>: <key path>`` for an error.
    """
    sources: Sources = {loc: o for loc, o in origin.items() if loc[0] not in ARRAYS}
    for table in ARRAYS:
        entries = data.get(table)
        if not isinstance(entries, list):
            continue
        out: List[Any] = []
        for i, entry in enumerate(entries):
            at = place((table, i))
            parts = _connection(entry, at) if table == "connections" else _targets(entry, at)
            if (table, i) in origin:
                sources.update({(table, len(out) + j): origin[(table, i)] for j in range(len(parts))})
            out += parts
        data[table] = out
    for i, unit in enumerate(data["units"] if isinstance(data.get("units"), list) else []):
        if isinstance(unit, dict) and isinstance(unit.get("parameters"), dict):
            params, written = _parameters(unit["parameters"], place(("units", i, "parameters")))
            unit["parameters"] = params
            for k, key in written.items():
                o = origin.get(("units", i, "parameters", key))
                if o is not None:
                    sources[("units", i, "parameters", k)] = o
    return sources
