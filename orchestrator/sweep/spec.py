"""Sweep files: parse and check grids, variants, metrics and plots."""
from __future__ import annotations

import itertools
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, Iterable, List, Optional, Sequence, Tuple

from .. import schema
from ..errors import ScenarioError
from ..tomlfiles import read_toml

from .common import BUILTIN_METRICS, FIXED_COLUMNS, TAIL_COLUMNS, _EDGE, _UNSAFE


# -- the sweep file ----------------------------------------------------------------------
@dataclass(frozen=True)
class MetricSpec:
    """One summary number per run.

    Attributes
    ----------
    name : str
        Column name in ``summary.csv``.
    builtin : str, optional
        ``wall_time`` (s, the whole run in the worker: loading the FMUs, the loop, closing
        the log), ``loop_time`` (s, the step loop only), ``realtime_factor`` (simulated time /
        loop time), ``steps``, ``status``, or ``unit_time:<unit>`` (s spent stepping that unit);
        then ``signal`` is unused.
    signal : str
        Pattern over ``unit.variable`` of the logged signals (``*`` and ``?`` are wildcards,
        brackets are literal: ``coll.pair[1].distance``); the samples of every matching signal
        are pooled before reducing.
    reduce : str
        One of :data:`REDUCERS`; ``final`` needs exactly one matching signal.
    after : float
        Only samples at simulation time ``t >= after`` (s) count.
    """

    name: str
    builtin: Optional[str] = None
    signal: str = ""
    reduce: str = "max"
    after: float = -math.inf


@dataclass(frozen=True)
class PlotSpec:
    """One comparison figure: a subplot per ``y`` column against ``x``, a line per ``hue`` group."""

    x: str
    y: Tuple[str, ...]
    hue: Optional[Tuple[str, ...]] = None
    logx: bool = False
    logy: bool = False
    name: str = ""


@dataclass(frozen=True)
class Variant:
    """One run of the sweep.

    Attributes
    ----------
    index : int
        Position in the sweep (grid first, then explicit variants).
    id : str
        Short, file-system-safe id, unique in the sweep (``<index>_<values or name>``).
    overrides : dict
        As written in the sweep file (shown in the summary).
    resolved : dict
        Passed to the run: FMU paths made absolute relative to the sweep file.
    """

    index: int
    id: str
    overrides: Dict[str, Any]
    resolved: Dict[str, Any]


@dataclass
class SweepSpec:
    """A parsed sweep file."""

    file: Path
    scenario: Path
    keys: List[str]
    variants: List[Variant]
    metrics: List[MetricSpec]
    plots: List[PlotSpec]


@dataclass
class SweepOptions:
    """How to run a sweep.

    Attributes
    ----------
    output_dir : path
        Folder for the MCAP files, ``summary.csv`` and the plots.
    workers : int, optional
        Local worker processes (default: ``os.cpu_count()``, at most one per run).
    scheduler : str, optional
        Dask scheduler address (``tcp://host:port``); runs go to that cluster instead.
    check : bool
        Raise :class:`SweepFailed` at the end if any run failed.
    progress : bool
        Show a progress bar of finished runs on stderr (only when it is a terminal).
    """

    output_dir: Path
    workers: Optional[int] = None
    scheduler: Optional[str] = None
    check: bool = True
    progress: bool = True


def _err(spec_file: Path, msg: str) -> ScenarioError:
    return ScenarioError(f"{spec_file}: {msg}")


def load_sweep(path: Path | str) -> SweepSpec:
    """Parse and check a sweep file; every variant is checked against the scenario's structure.

    Raises
    ------
    ScenarioError
        Naming the sweep file and the offending key (or variant).
    """
    path = Path(path)
    data, _ = read_toml(path, "sweep file")
    schema.validate(schema.SweepFile, data, path)   # keys, types and ranges: the parsers below rely on it
    scenario = _parse_scenario_path(data.get("scenario"), path)
    grid = _parse_grid(data.get("grid", {}), path)
    explicit = _parse_variants(data.get("variants", []), path)
    if not grid and not explicit:
        raise _err(path, "nothing to run: give a [grid] or [[variants]]")
    keys = list(dict.fromkeys(list(grid) + [k for _, ov in explicit for k in ov]))
    variants = _make_variants(grid, explicit, path)
    _check_variants(variants, scenario, path)
    metrics = _parse_metrics(data.get("metrics", {}), path, keys)
    plots = _parse_plots(data.get("plot", []), path, keys + [m.name for m in metrics])
    return SweepSpec(path, scenario, keys, variants, metrics, plots)


def _parse_scenario_path(value: str, path: Path) -> Path:
    scenario = (path.parent / value).resolve()
    if not scenario.exists():
        raise _err(path, f"scenario: {value!r} does not exist (looked for {scenario})")
    if not scenario.is_file():
        raise _err(path, f"scenario: {value!r} is not a file ({scenario})")
    return scenario


def _check_override_key(key: str, where: str, path: Path) -> None:
    """The override keys ``immersim run --set`` takes (:func:`~immersim.orchestrator.scenario.parse_override`),
    their ``simulation.`` and ``log.`` keys checked against the schema's tables."""
    from ..scenario import OVERRIDE_FORMS, parse_override

    try:
        table, _, rest = parse_override(key)
    except ScenarioError:
        raise _err(path, f"{where}: {key!r} is not an override key ({OVERRIDE_FORMS})") from None
    known = {"simulation": schema.SimulationTable, "log": schema.LogTable}.get(table)
    if known is not None and rest not in known.model_fields:
        raise _err(path, f"{where}: unknown {table} setting {key!r} "
                         f"(expected {table}.{'|'.join(known.model_fields)})")


def _parse_grid(grid: Dict[str, List[Any]], path: Path) -> Dict[str, List[Any]]:
    for key in grid:
        _check_override_key(key, f"grid key {key!r}", path)
    return {k: list(v) for k, v in grid.items()}


def _parse_variants(raw: List[Dict[str, Any]], path: Path) -> List[Tuple[str, Dict[str, Any]]]:
    out: List[Tuple[str, Dict[str, Any]]] = []
    for i, v in enumerate(raw):
        where = f"variants[{i}]"
        name = v.get("name", f"variant{i}")
        if any(n == name for n, _ in out):
            raise _err(path, f"{where}: duplicate variant name {name!r}")
        overrides = {k: x for k, x in v.items() if k != "name"}
        for key in overrides:
            _check_override_key(key, f"{where} ({name}) key {key!r}", path)
        out.append((name, overrides))
    return out


def _short(value: Any) -> str:
    """A short text for a value in a run id (file names shortened to their stem)."""
    if isinstance(value, str) and (value.endswith(".fmu") or "/" in value):
        value = Path(value).stem
    return f"{value:g}" if isinstance(value, float) else str(value)


def safe_id(index: int, parts: Iterable[Any], part_len: int = 24, max_len: int = 60) -> str:
    """``<index>_<part>_<part>...``, characters outside ``[A-Za-z0-9_.+-]`` replaced by ``-``,
    each part cut to ``part_len`` characters and the whole to ``max_len`` after the index."""
    body = "_".join(_UNSAFE.sub("-", _EDGE.sub("", _short(p)))[:part_len] for p in parts)
    return f"{index:03d}" + (f"_{body[:max_len]}" if body else "")


_SEPARATORS = ",;: /&"


def distinct_labels(values: Sequence[Any], min_len: int = 16) -> List[str]:
    """Short labels that still tell long string values apart: the common prefix and suffix
    of the values are dropped, cut back to a separator (``,;: /&``) so that the differing
    field keeps its name (``"tanks:n=10,tris=5.4k"``, ``"tanks:n=100,tris=5.4k"`` ->
    ``"n=10"``, ``"n=100"``). Other values get :func:`_short`."""
    texts = [_short(v) for v in values]
    if len(set(texts)) < 2 or max(map(len, texts)) < min_len or not all(isinstance(v, str) for v in values):
        return texts
    pre = os.path.commonprefix(texts)
    suf = os.path.commonprefix([t[::-1] for t in texts])[::-1]
    cut_pre = max((pre.rfind(c) + 1 for c in _SEPARATORS), default=0)
    cut_suf = min((i for i, c in enumerate(suf) if c in _SEPARATORS), default=len(suf))
    n_suf = len(suf) - cut_suf
    out = [t[cut_pre:len(t) - n_suf] for t in texts]
    return out if all(out) and len(set(out)) == len(set(texts)) else texts


def _resolve(overrides: Dict[str, Any], path: Path) -> Dict[str, Any]:
    """Make ``unit:fmu`` file paths absolute relative to the sweep file (built-in names stay)."""
    out = dict(overrides)
    from ..scenario import parse_override

    for key, value in overrides.items():
        if parse_override(key)[0] == "fmu":
            if not isinstance(value, str) or not value:
                raise _err(path, f"{key!r} must be a built-in unit name or an FMU path, got {value!r}")
            p = Path(value)
            if p.suffix == ".fmu" or "/" in value:
                out[key] = str(p if p.is_absolute() else (path.parent / p).resolve())
    return out


def _make_variants(grid: Dict[str, List[Any]], explicit: List[Tuple[str, Dict[str, Any]]],
                   path: Path) -> List[Variant]:
    varying = [k for k, vs in grid.items() if len(vs) > 1]
    labels = {k: distinct_labels(grid[k]) for k in varying}
    variants: List[Variant] = []
    if grid:
        for pos in itertools.product(*(range(len(vs)) for vs in grid.values())):
            ov = {k: grid[k][j] for k, j in zip(grid, pos)}
            parts = [labels[k][j] for k, j in zip(grid, pos) if k in labels]
            i = len(variants)
            variants.append(Variant(i, safe_id(i, parts), ov, _resolve(ov, path)))
    for name, ov in explicit:
        i = len(variants)
        variants.append(Variant(i, safe_id(i, [name]), ov, _resolve(ov, path)))
    return variants


def _check_variants(variants: Sequence[Variant], scenario: Path, path: Path) -> None:
    """Each variant's scenario is checked as a run would check it at load (schema, then the
    FMUs' variables, types and ranges), so a bad value fails the sweep before any run. A
    variant whose FMU file does not exist is left to fail alone, with its reason, as its run."""
    from ..errors import FmuLoadError
    from ..scenario import load_scenario
    from ..system import check_system

    for v in variants:
        try:
            check_system(load_scenario(scenario, v.resolved))
        except FmuLoadError:
            continue
        except ScenarioError as exc:
            raise _err(path, f"variant {v.id} {v.overrides}: {exc}") from None


def _parse_metrics(raw: Dict[str, Any], path: Path, keys: Sequence[str]) -> List[MetricSpec]:
    taken = set(FIXED_COLUMNS) | set(TAIL_COLUMNS) | set(keys)
    out: List[MetricSpec] = []
    for name, m in raw.items():
        where = f"metrics.{name}"
        if name in taken:
            raise _err(path, f"{where}: the name {name!r} is already a summary column")
        if isinstance(m, str):
            if m not in BUILTIN_METRICS[:-1] and not (m.startswith("unit_time:") and len(m) > 10):
                raise _err(path, f"{where}: unknown built-in metric {m!r} (expected one of "
                                 f"{', '.join(BUILTIN_METRICS)}, or a table {{signal, reduce}})")
            out.append(MetricSpec(name, builtin=m))
            continue
        # keys and types were checked by schema.MetricTable
        out.append(MetricSpec(name, None, m["signal"], m.get("reduce", "max"), float(m.get("after", -math.inf))))
    return out


def _names(value: Any, where: str, path: Path, columns: Sequence[str]) -> Tuple[str, ...]:
    names = (value,) if isinstance(value, str) else tuple(value) if isinstance(value, list) else None
    if not names or not all(isinstance(n, str) for n in names):
        raise _err(path, f"{where} must be a column name or a list of them, got {value!r}")
    for n in names:
        if n not in columns:
            raise _err(path, f"{where}: {n!r} is not an override key or metric (columns: {', '.join(columns)})")
    return names


def _parse_plots(raw: Any, path: Path, columns: Sequence[str]) -> List[PlotSpec]:
    """``raw``: a [plot] table or an array of them, keys and types checked by schema.PlotTable."""
    tables = [raw] if isinstance(raw, dict) else raw
    cols = list(columns) + list(FIXED_COLUMNS[3:])
    plots: List[PlotSpec] = []
    for i, t in enumerate(tables):
        where = f"plot[{i}]" if isinstance(raw, list) else "plot"
        x = _names(t["x"], f"{where}.x", path, cols)
        if len(x) != 1:
            raise _err(path, f"{where}.x must be one column, got {t['x']!r}")
        y = _names(t["y"], f"{where}.y", path, cols)
        hue = _names(t["hue"], f"{where}.hue", path, cols) if "hue" in t else None
        plots.append(PlotSpec(x[0], y, hue, bool(t.get("logx", False)), bool(t.get("logy", False)),
                              t.get("name", "")))
    return plots


