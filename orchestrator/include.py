"""``include = ["common.toml"]``: scenario files built from shared pieces.

A scenario file may include other scenario files (paths relative to the including file; an
included file may include in turn). The included data is a fallback, as if appended to the
file:

* a table (``[simulation]``, ``[log]``, ``[foxglove]``) is merged key by key, the including
  file's keys winning;
* ``[[units]]`` are merged by ``name``: a unit the file names takes the included unit's keys it
  does not give, its ``parameters`` merged key by key (the file's winning); the included units
  it does not name follow its own, in the included order;
* other arrays of tables (``[[connections]]``, ``[[inputs]]``, ...) hold the file's entries,
  then the included ones;
* any other value the file gives replaces the included one.

A missing file and a cycle are refused with one line naming the including file and the key.
Every merged entry remembers its file (:data:`~immersim.orchestrator.expand.Sources`).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Dict, List, Optional, Tuple

from .errors import ScenarioError
from .expand import ARRAYS, Sources as Origin

#: ``read(path)``: the file's data and text, or None if there is no such file
Reader = Callable[[Path], Optional[Tuple[Dict[str, Any], str]]]


def _own(data: Dict[str, Any], path: Path) -> Origin:
    """The origin of a file's own entries: itself."""
    origin: Origin = {}
    for key, value in data.items():
        if isinstance(value, list):
            origin.update({(key, i): (path, (key, i)) for i in range(len(value))})
        elif isinstance(value, dict):
            origin.update({(key, k): (path, (key, k)) for k in value})
    for i, u in enumerate(data.get("units") if isinstance(data.get("units"), list) else []):
        if isinstance(u, dict) and isinstance(u.get("parameters"), dict):
            origin.update({("units", i, "parameters", k): (path, ("units", i, "parameters", k))
                           for k in u["parameters"]})
    return origin


def _merge(a: Dict[str, Any], oa: Origin, b: Dict[str, Any], ob: Origin) -> Tuple[Dict[str, Any], Origin]:
    """``a`` (the including file) over ``b`` (an included one), with their origins."""
    out, origin = dict(a), {k: v for k, v in oa.items() if k[0] != "units"}
    for key, value in b.items():
        if key == "units" or key not in a:
            if key != "units":
                out[key] = value
                origin.update({k: v for k, v in ob.items() if k[0] == key})
        elif isinstance(a[key], dict) and isinstance(value, dict):
            out[key] = {**value, **a[key]}
            origin.update({k: v for k, v in ob.items() if k[0] == key and k[1] not in a[key]})
        elif key in ARRAYS and isinstance(a[key], list) and isinstance(value, list):
            out[key] = a[key] + value
            origin.update({(key, len(a[key]) + i): ob[(key, i)] for i in range(len(value)) if (key, i) in ob})
    ua = a.get("units") if isinstance(a.get("units"), list) else None
    ub = b.get("units") if isinstance(b.get("units"), list) else None
    if ua is None or ub is None:
        src, so = (ua, oa) if ua is not None else (ub, ob)
        if src is not None:
            out["units"] = src
            origin.update({k: v for k, v in so.items() if k[0] == "units"})
        return out, origin
    name_of = lambda u: u.get("name") if isinstance(u, dict) else None   # noqa: E731
    index_b = {name_of(u): j for j, u in enumerate(ub) if name_of(u) is not None}
    units: List[Any] = []
    for i, u in enumerate(ua):
        k = len(units)
        j = index_b.get(name_of(u))
        origin.update({("units", k, *loc[2:]): o for loc, o in oa.items() if loc[:2] == ("units", i)})
        if j is not None and isinstance(u, dict) and isinstance(ub[j], dict):
            merged = {**ub[j], **u}
            pa, pb = u.get("parameters"), ub[j].get("parameters")
            if isinstance(pa, dict) and isinstance(pb, dict):
                merged["parameters"] = {**pa, **{p: v for p, v in pb.items() if p not in pa}}
            for loc, o in ob.items():
                if loc[:2] == ("units", j) and len(loc) == 4 and loc[3] not in (pa or {}):
                    origin[("units", k, *loc[2:])] = o
            u = merged
        units.append(u)
    named = {name_of(u) for u in ua}
    for j, u in enumerate(ub):
        if name_of(u) is None or name_of(u) not in named:
            k = len(units)
            origin.update({("units", k, *loc[2:]): o for loc, o in ob.items() if loc[:2] == ("units", j)})
            units.append(u)
    out["units"] = units
    return out, origin


def compose(data: Dict[str, Any], path: Path, read: Reader,
            _stack: Tuple[Path, ...] = ()) -> Tuple[Dict[str, Any], Origin, Dict[str, str]]:
    """``data`` of the file ``path`` with its includes merged in (see the module docstring).

    Returns the merged data (no ``include`` key), the origin of its entries and the text of
    every included file by its path (as the including file names it, joined to its folder).
    """
    data = dict(data)
    origin = _own(data, path)
    texts: Dict[str, str] = {}
    inc = data.pop("include", [])
    if isinstance(inc, str):
        inc = [inc]
    if not isinstance(inc, list) or not all(isinstance(x, str) and x for x in inc):
        raise ScenarioError(f"{path}: include: expected a file name or an array of file names, got {inc!r}")
    stack = _stack + (path.resolve(),)
    for n, name in enumerate(inc):
        where = f"{path}: include[{n}]" if len(inc) > 1 else f"{path}: include"
        file = path.parent / name
        if file.resolve() in stack:
            chain = " -> ".join(p.name for p in stack + (file.resolve(),))
            raise ScenarioError(f"{where}: {name!r} includes itself ({chain})")
        got = read(file)
        if got is None:
            raise ScenarioError(f"{where}: {name!r} does not exist (looked for {file})")
        sub, text = got
        texts[str(file)] = text
        sub, sub_origin, sub_texts = compose(sub, file, read, stack)
        texts.update(sub_texts)
        data, origin = _merge(data, origin, sub, sub_origin)
    return data, origin, texts
