"""Ablation sweeps: run a grid of scenario variants in parallel, summarise and compare them.

A sweep file (TOML) names a base scenario and the variants to run::

    scenario = "../campus_drive.toml"     # relative to the sweep file

    [grid]                                # cartesian product of override values
    "simulation.algorithm" = ["jacobi", "gauss-seidel"]
    "coll.backend" = ["fcl", "basis_point"]
    "net:fmu" = ["network", "other/network.fmu"]   # swap a unit's FMU (path relative to the sweep file)

    [[variants]]                          # explicit extra runs (overrides on the base scenario)
    name = "baseline"
    "simulation.step" = 0.01

    [metrics]                             # one number per run, computed from its MCAP log
    max_err = { signal = "net.inconsistency_max", reduce = "max" }  # max|min|mean|rms|final|absmax
    late = { signal = "plat.stroke*", reduce = "absmax", after = 2.0 }  # * ? wildcards; t >= 2 s
    hit = { signal = "coll.pair[1].in_contact", reduce = "max" }       # brackets are literal
    wall_s = "wall_time"                  # built-ins: wall_time, loop_time, realtime_factor,
    plat_s = "unit_time:plat"             #   steps, status, unit_time:<unit>

    [plot]                                # or [[plot]] for several figures
    x = "simulation.step"
    y = ["max_err"]
    hue = "coll.backend"                  # optional; default: every other override that varies
    logx = true                           # optional log axes

Override keys are those of :func:`immersim.orchestrator.scenario.load_scenario`:
``"unit.param"``, ``"simulation.<stop|step|start|algorithm|extrapolation|tolerance>"`` and
``"unit:fmu"``. Every variant is checked against the scenario before anything runs, so a bad
sweep file fails at once with a :class:`ScenarioError` naming the file and the key.

Runs execute in worker processes (``spawn`` start method: pythonfmu FMUs embed the
interpreter, so forking a process that has loaded FMUs is unsafe) or, given a scheduler
address, as tasks on a Dask cluster (whose workers must see the output folder, e.g. a shared
file system). Each run writes one MCAP file; the worker computes the metrics from it. A failed
run does not stop the sweep: its row in ``summary.csv`` says ``failed`` and why, and
:func:`run_sweep` raises :class:`SweepFailed` at the end (the CLI exits non-zero).
"""
from __future__ import annotations

import csv
import itertools
import logging
import math
import os
import re
import threading
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Dict, Iterable, List, Optional, Sequence, Tuple

import numpy as np

from .errors import ImmersimError, ScenarioError
from .scenario import tomllib

log = logging.getLogger(__name__)

REDUCERS: Dict[str, Callable[[np.ndarray], float]] = {
    "max": lambda y: float(np.max(y)),
    "min": lambda y: float(np.min(y)),
    "mean": lambda y: float(np.mean(y)),
    "rms": lambda y: float(np.sqrt(np.mean(np.square(y)))),
    "absmax": lambda y: float(np.max(np.abs(y))),
    "final": lambda y: float(y[-1]),
}
BUILTIN_METRICS = ("wall_time", "loop_time", "realtime_factor", "steps", "status", "unit_time:<unit>")
SIM_KEYS = ("start", "stop", "step", "algorithm", "extrapolation", "tolerance")
FIXED_COLUMNS = ("run", "id", "status", "steps", "t_end_s", "wall_time_s", "loop_time_s")
TAIL_COLUMNS = ("reason", "mcap")
_UNSAFE = re.compile(r"[^A-Za-z0-9_.+\-]+")
# One run at a time per process: pythonfmu FMUs share the embedding interpreter, and a Dask
# worker with several threads would otherwise step FMUs of different runs concurrently.
_RUN_LOCK = threading.Lock()
_EDGE = re.compile(r"^[^A-Za-z0-9_.+\-]+|[^A-Za-z0-9_.+\-]+$")


class SweepFailed(ImmersimError, RuntimeError):
    """Some runs of a sweep failed; ``result`` holds every row (the summary is written)."""

    def __init__(self, message: str, result: "SweepResult") -> None:
        super().__init__(message)
        self.result = result


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
    if not path.exists():
        raise ScenarioError(f"sweep file {path} does not exist")
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise _err(path, f"invalid TOML: {exc}") from None
    known = {"scenario", "grid", "variants", "metrics", "plot", "description", "title"}
    for key in data:
        if key not in known:
            raise _err(path, f"unknown top-level key {key!r} (expected one of {', '.join(sorted(known))})")
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


def _parse_scenario_path(value: Any, path: Path) -> Path:
    if not isinstance(value, str) or not value:
        raise _err(path, "'scenario' must be the path of a scenario file (relative to the sweep file)")
    scenario = (path.parent / value).resolve()
    if not scenario.exists():
        raise _err(path, f"scenario {value!r} does not exist (looked for {scenario})")
    return scenario


def _check_override_key(key: str, where: str, path: Path) -> None:
    if key.endswith(":fmu"):
        if not key[:-4]:
            raise _err(path, f"{where}: {key!r} names no unit (expected 'unit:fmu')")
        return
    if key.startswith("simulation."):
        if key.split(".", 1)[1] not in SIM_KEYS:
            raise _err(path, f"{where}: unknown simulation setting {key!r} "
                             f"(expected simulation.{'|'.join(SIM_KEYS)})")
        return
    unit, _, var = key.partition(".")
    if not unit or not var:
        raise _err(path, f"{where}: {key!r} is not an override key ('unit.param', 'simulation.<setting>' "
                         "or 'unit:fmu')")


def _parse_grid(grid: Any, path: Path) -> Dict[str, List[Any]]:
    if not isinstance(grid, dict):
        raise _err(path, "[grid] must be a table of override key -> list of values")
    for key, values in grid.items():
        _check_override_key(key, f"grid key {key!r}", path)
        if not isinstance(values, list) or not values:
            raise _err(path, f"grid key {key!r} must be a non-empty list of values, got {values!r}")
    return {k: list(v) for k, v in grid.items()}


def _parse_variants(raw: Any, path: Path) -> List[Tuple[str, Dict[str, Any]]]:
    if not isinstance(raw, list):
        raise _err(path, "'variants' must be an array of tables ([[variants]])")
    out: List[Tuple[str, Dict[str, Any]]] = []
    for i, v in enumerate(raw):
        where = f"variants[{i}]"
        if not isinstance(v, dict):
            raise _err(path, f"{where} must be a table")
        name = v.get("name", f"variant{i}")
        if not isinstance(name, str) or not name.strip():
            raise _err(path, f"{where}: 'name' must be a non-empty string, got {name!r}")
        if any(n == name for n, _ in out):
            raise _err(path, f"{where}: duplicate variant name {name!r}")
        overrides = {k: x for k, x in v.items() if k != "name"}
        for key, value in overrides.items():
            _check_override_key(key, f"{where} ({name}) key {key!r}", path)
            if isinstance(value, (dict, list)):
                raise _err(path, f"{where} ({name}) key {key!r}: expected a single value, got {value!r}")
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
    for key, value in overrides.items():
        if key.endswith(":fmu"):
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
    from .scenario import load_scenario

    for v in variants:
        try:
            load_scenario(scenario, v.resolved)
        except ScenarioError as exc:
            raise _err(path, f"variant {v.id} {v.overrides}: {exc}") from None


def _parse_metrics(raw: Any, path: Path, keys: Sequence[str]) -> List[MetricSpec]:
    if not isinstance(raw, dict):
        raise _err(path, "[metrics] must be a table of name -> {signal, reduce} or a built-in name")
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
        if not isinstance(m, dict):
            raise _err(path, f"{where} must be a built-in name or a table {{signal, reduce}}")
        extra = set(m) - {"signal", "reduce", "after"}
        if extra:
            raise _err(path, f"{where}: unknown key {sorted(extra)[0]!r} (expected signal, reduce, after)")
        signal, reduce, after = m.get("signal"), m.get("reduce", "max"), m.get("after", -math.inf)
        if not isinstance(signal, str) or "." not in signal:
            raise _err(path, f"{where}: 'signal' must be a 'unit.variable' pattern, got {signal!r}")
        if reduce not in REDUCERS:
            raise _err(path, f"{where}: reduce {reduce!r} is not one of {'|'.join(REDUCERS)}")
        if isinstance(after, bool) or not isinstance(after, (int, float)):
            raise _err(path, f"{where}: 'after' must be a time in s, got {after!r}")
        out.append(MetricSpec(name, None, signal, reduce, float(after)))
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
    tables = [raw] if isinstance(raw, dict) else raw
    if not isinstance(tables, list) or not all(isinstance(t, dict) for t in tables):
        raise _err(path, "[plot] must be a table or an array of tables")
    cols = list(columns) + list(FIXED_COLUMNS[3:])
    plots: List[PlotSpec] = []
    for i, t in enumerate(tables):
        where = f"plot[{i}]" if isinstance(raw, list) else "plot"
        extra = set(t) - {"x", "y", "hue", "logx", "logy", "name"}
        if extra:
            raise _err(path, f"{where}: unknown key {sorted(extra)[0]!r} (expected x, y, hue, logx, logy, name)")
        if "x" not in t or "y" not in t:
            raise _err(path, f"{where}: needs 'x' and 'y'")
        x = _names(t["x"], f"{where}.x", path, cols)
        if len(x) != 1:
            raise _err(path, f"{where}.x must be one column, got {t['x']!r}")
        y = _names(t["y"], f"{where}.y", path, cols)
        hue = _names(t["hue"], f"{where}.hue", path, cols) if "hue" in t else None
        name = t.get("name", "")
        if not isinstance(name, str):
            raise _err(path, f"{where}.name must be a string")
        plots.append(PlotSpec(x[0], y, hue, bool(t.get("logx", False)), bool(t.get("logy", False)), name))
    return plots


# -- one run (executed in a worker process or on a Dask worker) --------------------------
@dataclass
class RunTask:
    """Everything a worker needs for one run (picklable)."""

    scenario: str
    overrides: Dict[str, Any]
    mcap: str
    metrics: List[MetricSpec]
    index: int = 0
    id: str = ""


@dataclass
class RunRow:
    """The outcome of one run: a row of ``summary.csv``."""

    index: int
    id: str
    status: str
    steps: int = 0
    t_end_s: float = math.nan
    wall_time_s: float = math.nan
    loop_time_s: float = math.nan
    timing: Dict[str, float] = field(default_factory=dict)
    metrics: Dict[str, Any] = field(default_factory=dict)
    reason: str = ""
    mcap: str = ""


def reduce_signals(series: Dict[str, Tuple[np.ndarray, np.ndarray, str]], metric: MetricSpec) -> float:
    """Reduce the pooled samples (``t >= after``) of every matched signal to one number.

    Parameters
    ----------
    series : dict
        ``unit.variable`` -> (t in s, values, unit) as returned by
        :func:`immersim.orchestrator.mcapio.read_series`.
    metric : MetricSpec

    Returns
    -------
    float
        The reduced value; NaN when no sample lies after ``metric.after``.
    """
    if metric.reduce == "final" and len(series) != 1:
        raise ValueError(f"metric {metric.name}: reduce 'final' needs exactly one signal, "
                         f"{metric.signal!r} matches {len(series)}: {', '.join(sorted(series))}")
    pooled = [y[t >= metric.after] for t, y, _ in series.values()]
    y = np.concatenate(pooled) if pooled else np.empty(0)
    return REDUCERS[metric.reduce](y) if y.size else math.nan


def builtin_metric(row: RunRow, name: str) -> Any:
    """The value of a built-in metric (see :class:`MetricSpec`) for one run; NaN if unknown."""
    if name.startswith("unit_time:"):
        return row.timing.get(f"unit:{name[10:]}", math.nan)
    if name == "realtime_factor":
        return row.timing.get("simulated", math.nan) / row.loop_time_s if row.loop_time_s > 0 else math.nan
    return {"wall_time": row.wall_time_s, "loop_time": row.loop_time_s, "steps": row.steps,
            "status": row.status}[name]


def compute_metrics(mcap: Path | str, metrics: Sequence[MetricSpec], row: RunRow) -> Tuple[Dict[str, Any], List[str]]:
    """Every metric of one run: built-ins from ``row``, signal metrics from the MCAP log (read once).

    Returns
    -------
    values : dict
        Metric name -> value (NaN for a metric that could not be computed).
    errors : list of str
        One message per metric that could not be computed (e.g. no signal matches).
    """
    from .mcapio import LogReadError, read_series
    from .patterns import matches

    globs = {m.name: m.signal for m in metrics if not m.builtin}
    try:
        series = read_series(mcap, list(dict.fromkeys(globs.values()))) if globs else {}
    except LogReadError as exc:
        if "no signal matches" not in str(exc):
            raise
        series = {}
    out: Dict[str, Any] = {}
    errors: List[str] = []
    for m in metrics:
        if m.builtin:
            out[m.name] = builtin_metric(row, m.builtin)
            continue
        matched = {k: v for k, v in series.items() if matches(k, [globs[m.name]])}
        try:
            if not matched:
                raise ValueError(f"metric {m.name}: no logged signal matches {m.signal!r} "
                                 f"(see immersim info --signals {Path(mcap).name})")
            out[m.name] = reduce_signals(matched, m)
        except ValueError as exc:
            out[m.name] = math.nan
            errors.append(str(exc))
    return out, errors


def _take(row: RunRow, res: Any) -> None:
    """Copy status, steps, end time, reason and timing of a RunResult into ``row``."""
    row.status, row.steps, row.reason = res.status, res.steps_done, res.reason
    row.t_end_s = res.t_ns / 1e9
    row.timing = dict(getattr(res, "timing", {}) or {})
    row.timing["simulated"] = (res.t_ns - getattr(res, "start_ns", 0)) / 1e9
    row.loop_time_s = row.timing.get("loop", math.nan)


_INTERRUPTED = False  # set in a worker process by SIGINT: runs not yet started are skipped


def _on_sigint(signum, frame) -> None:
    global _INTERRUPTED
    _INTERRUPTED = True


def _stop_if_interrupted(k: int, t_ns: int) -> None:
    """Step observer: end the run (log closed, status interrupted) once SIGINT was noted."""
    if _INTERRUPTED:
        raise KeyboardInterrupt


def _worker_init() -> None:
    """Worker processes note SIGINT instead of raising KeyboardInterrupt: an exception inside
    an FMU being loaded would leave it fatal, and the run in progress stops by itself at the
    next step boundary (see :class:`immersim.orchestrator.execution.Execution`)."""
    import signal

    signal.signal(signal.SIGINT, _on_sigint)


def run_one(task: RunTask) -> RunRow:
    """Run one variant and compute its metrics; never raises for a failed run.

    The returned row has status ``completed``, ``failed`` or ``interrupted`` and the reason.
    Metrics are computed only for completed runs (a partial log would bias the comparison).
    """
    from .execution import Execution, RunFailed

    global _INTERRUPTED
    row = RunRow(task.index, task.id, "failed", mcap=Path(task.mcap).name)
    Path(task.mcap).unlink(missing_ok=True)  # never report the log of an earlier sweep
    if _INTERRUPTED:
        row.status, row.reason, row.mcap = "interrupted", "sweep interrupted before this run started", ""
        return row
    with _RUN_LOCK:
        t0 = time.perf_counter()
        try:
            ex = Execution(task.scenario, task.mcap, progress=False, overrides=task.overrides)
            ex.observers.append(_stop_if_interrupted)
            _take(row, ex.run())
        except RunFailed as exc:
            _take(row, exc.result)
            _INTERRUPTED = _INTERRUPTED or exc.result.status == "interrupted"
        except Exception as exc:  # a bad FMU swap, a parameter the FMU refuses, ... : the row says why
            row.reason = f"{type(exc).__name__}: {exc}"
        row.wall_time_s = time.perf_counter() - t0
    if not Path(task.mcap).exists():
        row.mcap = ""
    if row.status == "completed":
        row.metrics, errors = compute_metrics(task.mcap, task.metrics, row)
        if errors:  # the run itself completed: keep its other metrics, fail the row loudly
            row.status, row.reason = "failed", "; ".join(errors)
    return row


# -- executors ---------------------------------------------------------------------------
def _failed_row(task: RunTask, exc: BaseException) -> RunRow:
    return RunRow(task.index, task.id, "failed", reason=f"worker: {type(exc).__name__}: {exc}",
                  mcap=Path(task.mcap).name if Path(task.mcap).exists() else "")


def _pool(workers: int):
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    return ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                               initializer=_worker_init)


def _interrupt_workers(pool) -> None:
    """Forward SIGINT to the pool's processes (when only this process received it)."""
    import signal

    for proc in list(getattr(pool, "_processes", {}).values()):  # CPython keeps them here
        try:
            os.kill(proc.pid, signal.SIGINT)
        except OSError:
            pass


def _run_pool(tasks: Sequence[RunTask], workers: int, on_row: Callable[[RunRow], None]) -> List[RunTask]:
    """Run ``tasks`` on one pool; returns the tasks lost because a worker process died."""
    from concurrent.futures import as_completed
    from concurrent.futures.process import BrokenProcessPool

    lost: List[RunTask] = []
    with _pool(workers) as pool:
        futures = {pool.submit(run_one, t): t for t in tasks}
        done = set()

        def collect(fut) -> None:
            done.add(fut)
            try:
                on_row(fut.result())
            except BrokenProcessPool:
                lost.append(futures[fut])
            except Exception as exc:  # e.g. a row that cannot be pickled back
                on_row(_failed_row(futures[fut], exc))

        try:
            for fut in as_completed(futures):
                collect(fut)
        except KeyboardInterrupt:
            # Runs in progress stop at their next step (logs closed), queued ones are skipped;
            # their rows still reach the summary before the interrupt goes on.
            for fut in futures:
                fut.cancel()
            _interrupt_workers(pool)
            for fut in as_completed(futures):
                if fut not in done and not fut.cancelled():
                    collect(fut)
            for fut, task in futures.items():
                if fut.cancelled():
                    on_row(RunRow(task.index, task.id, "interrupted", reason="sweep interrupted before this run started"))
            raise
    return lost


def _run_local(tasks: Sequence[RunTask], workers: int, on_row: Callable[[RunRow], None]) -> None:
    """Run ``tasks`` on a pool of spawned processes; ``on_row`` gets each row as it completes.

    A worker that dies (a crash inside an FMU) breaks the whole pool and every unfinished run
    with it; those runs are then retried one per fresh process, so only the run that crashes
    again is reported failed.
    """
    lost = _run_pool(tasks, workers, on_row)
    if lost:
        log.warning("a worker process died; retrying %d unfinished runs one per process", len(lost))
    for task in sorted(lost, key=lambda t: t.index):
        if _run_pool([task], 1, on_row):
            on_row(RunRow(task.index, task.id, "failed", reason="worker process died (crash inside an FMU?)",
                          mcap=Path(task.mcap).name if Path(task.mcap).exists() else ""))


def _run_dask(tasks: Sequence[RunTask], address: str, on_row: Callable[[RunRow], None]) -> None:
    """Run ``tasks`` on the Dask cluster at ``address``; ``on_row`` gets each row as it completes."""
    try:
        from distributed import Client, as_completed
    except ImportError:
        raise ImmersimError("--scheduler needs dask.distributed: pip install 'immersim[dask]'") from None
    try:
        client = Client(address, timeout="10s")
    except (OSError, TimeoutError) as exc:
        raise ImmersimError(f"cannot connect to the Dask scheduler at {address}: {exc}") from None
    try:
        tag = uuid.uuid4().hex[:8]
        futures = client.map(run_one, list(tasks), key=[f"immersim-run-{t.id}-{tag}" for t in tasks], pure=False)
        by_key = {f.key: t for f, t in zip(futures, tasks)}
        try:
            for fut in as_completed(futures):
                try:
                    on_row(fut.result())
                except Exception as exc:  # KilledWorker, lost connection, ...
                    on_row(_failed_row(by_key[fut.key], exc))
        except BaseException:
            client.cancel(futures)
            raise
    finally:
        client.close()


# -- the summary -------------------------------------------------------------------------
@dataclass
class SweepResult:
    """Rows of a finished sweep and the files written."""

    spec: SweepSpec
    rows: List[RunRow]
    summary: Path
    plots: List[Path] = field(default_factory=list)

    @property
    def failed(self) -> List[RunRow]:
        return [r for r in self.rows if r.status != "completed"]

    def __str__(self) -> str:
        cols = ["id", "status", "steps", "wall_time_s"] + [m.name for m in self.spec.metrics]
        table = [cols] + [[_fmt(_cell(r, c, self.spec)) for c in cols] for r in self.rows]
        widths = [max(len(line[i]) for line in table) for i in range(len(cols))]
        lines = ["  ".join(c.ljust(w) for c, w in zip(line, widths)).rstrip() for line in table]
        lines.append(f"{len(self.rows) - len(self.failed)} of {len(self.rows)} runs completed; "
                     f"summary: {self.summary}")
        lines += [f"plot: {p}" for p in self.plots]
        return "\n".join(lines)


def _cell(row: RunRow, col: str, spec: SweepSpec) -> Any:
    if col in spec.keys:
        v = spec.variants[row.index].overrides
        return v.get(col, "")
    if col in ("run",):
        return row.index
    if hasattr(row, col) and col not in ("metrics",):
        return getattr(row, col)
    return row.metrics.get(col, "")


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return "" if math.isnan(value) else f"{value:.6g}"
    return str(value)


def summary_columns(spec: SweepSpec) -> List[str]:
    """Columns of ``summary.csv``: run, id, every override key, status, steps, t_end_s,
    wall_time_s, loop_time_s, every metric, reason, mcap."""
    return ["run", "id"] + spec.keys + list(FIXED_COLUMNS[2:]) + [m.name for m in spec.metrics] + list(TAIL_COLUMNS)


def write_summary(spec: SweepSpec, rows: Sequence[RunRow], path: Path) -> Path:
    """Write ``summary.csv`` (floats with full precision, ``repr``), rows in sweep order."""
    cols = summary_columns(spec)
    tmp = path.with_suffix(".csv.tmp")
    with open(tmp, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        for r in sorted(rows, key=lambda r: r.index):
            w.writerow([_csv_value(_cell(r, c, spec)) for c in cols])
    os.replace(tmp, path)
    return path


def _csv_value(value: Any) -> str:
    if isinstance(value, float):
        return "" if math.isnan(value) else repr(value)
    return str(value)


def read_summary(path: Path | str) -> List[Dict[str, str]]:
    """The rows of a ``summary.csv`` as dicts of strings."""
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


# -- plots -------------------------------------------------------------------------------
def _as_number(v: Any) -> Optional[float]:
    if isinstance(v, bool):
        return None
    if isinstance(v, (int, float)):
        return float(v)
    return None


@dataclass
class ComparisonData:
    """What a comparison plot draws.

    Attributes
    ----------
    numeric : bool
        ``x`` is numeric (else categories, plotted at 0, 1, ... with ``categories`` as labels).
    categories : list of str
    lines : dict
        ``y column -> {hue label -> (x values, y values)}``, sorted by x, non-finite y dropped.
    plotted : int
        Runs drawn (completed and setting ``x``).
    """

    numeric: bool
    categories: List[str]
    lines: Dict[str, Dict[str, Tuple[List[float], List[float]]]]
    plotted: int


def _value_labels(values: Sequence[Any]) -> Dict[str, str]:
    """``str(value) -> short label`` for the distinct values (see :func:`distinct_labels`)."""
    uniq = list(dict.fromkeys(values))
    return dict(zip(map(str, uniq), distinct_labels(uniq)))


def comparison_data(spec: SweepSpec, rows: Sequence[RunRow], plot: PlotSpec) -> ComparisonData:
    """The lines of one comparison plot: completed runs that set ``plot.x``, grouped by hue
    (default: every other override key that varies), one line per group and ``y`` column."""
    done = [r for r in sorted(rows, key=lambda r: r.index)
            if r.status == "completed" and _cell(r, plot.x, spec) != ""]
    xs = [_cell(r, plot.x, spec) for r in done]
    numeric = bool(xs) and all(_as_number(x) is not None for x in xs)
    cats = list(dict.fromkeys(map(str, xs)))
    hue = plot.hue if plot.hue is not None else tuple(
        k for k in spec.keys if k != plot.x and len({str(v.overrides.get(k, "")) for v in spec.variants}) > 1)
    short = {h: _value_labels([_cell(r, h, spec) for r in done]) for h in hue}
    groups: Dict[str, List[Tuple[float, RunRow]]] = {}
    for r, x in zip(done, xs):
        label = ", ".join(f"{h}={short[h][str(_cell(r, h, spec))]}" for h in hue)
        groups.setdefault(label, []).append((_as_number(x) if numeric else float(cats.index(str(x))), r))
    lines: Dict[str, Dict[str, Tuple[List[float], List[float]]]] = {}
    for ycol in plot.y:
        lines[ycol] = {}
        for label, pts in groups.items():
            xy = sorted((x, _as_number(_cell(r, ycol, spec))) for x, r in pts)
            xy = [(x, y) for x, y in xy if y is not None and math.isfinite(y)]
            if xy:
                lines[ycol][label] = ([x for x, _ in xy], [y for _, y in xy])
    return ComparisonData(numeric, cats, lines, len(done))


def plot_comparison(spec: SweepSpec, rows: Sequence[RunRow], plot: PlotSpec, output: Path) -> Path:
    """One PNG (matplotlib Agg): a subplot per ``plot.y`` column against ``plot.x``, a line per
    hue group; see :func:`comparison_data`."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    data = comparison_data(spec, rows, plot)
    fig, axes = plt.subplots(len(plot.y), 1, figsize=(7, 2.6 * len(plot.y) + 0.8), squeeze=False)
    for ax, ycol in zip(axes[:, 0], plot.y):
        width = 0.8 / max(1, len(data.lines[ycol]))
        for i, (label, (x, y)) in enumerate(data.lines[ycol].items()):
            if data.numeric:
                ax.plot(x, y, marker="o", lw=1.2, label=label or None)
            else:  # categories: grouped bars, one colour per hue group
                offset = (i - (len(data.lines[ycol]) - 1) / 2) * width
                ax.bar([xi + offset for xi in x], y, width=width, label=label or None)
        ax.set_xscale("log" if plot.logx and data.numeric else "linear")  # (resets the tick locator)
        if not data.numeric:
            ax.set_xticks(range(len(data.categories)), distinct_labels(data.categories))
        if plot.logy:
            ax.set_yscale("log")
        else:
            ax.ticklabel_format(axis="y", useOffset=False)
        ax.set_ylabel(ycol)
        ax.grid(True, alpha=0.3)
        if any(data.lines[ycol]) and ax is axes[0, 0] and len(data.lines[ycol]) > 1:
            ax.legend(fontsize=7)
    axes[-1, 0].set_xlabel(plot.x)
    fig.suptitle(f"{spec.file.name}: {data.plotted} of {len(rows)} runs plotted (completed, with {plot.x})",
                 fontsize=9)
    fig.tight_layout()
    fig.savefig(output, dpi=110)
    plt.close(fig)
    return output


def plot_file_name(plot: PlotSpec) -> str:
    """``<name>.png`` or ``<y1>-<y2>_vs_<x>.png``, file-system safe."""
    stem = plot.name or f"{'-'.join(plot.y)}_vs_{plot.x}"
    return _UNSAFE.sub("-", stem).strip("-") + ".png"


# -- the sweep ---------------------------------------------------------------------------
def _prebuild(spec: SweepSpec) -> None:
    """Build the built-in units the variants use once, before workers start (no build races)."""
    from .build import build_all, unit_names
    from .scenario import load_scenario

    builtin = set(unit_names())
    used = {u.fmu for v in spec.variants for u in load_scenario(spec.scenario, v.resolved).units}
    names = sorted(used & builtin)
    if names:
        log.info("building built-in units %s", ", ".join(names))
        build_all(names)


def make_tasks(spec: SweepSpec, output_dir: Path) -> List[RunTask]:
    """One :class:`RunTask` per variant, its MCAP at ``output_dir/<id>.mcap``."""
    return [RunTask(str(spec.scenario), v.resolved, str((output_dir / f"{v.id}.mcap").resolve()), spec.metrics,
                    v.index, v.id) for v in spec.variants]


def execute(spec: SweepSpec, options: SweepOptions) -> SweepResult:
    """Run every variant of ``spec`` as ``options`` say; write ``summary.csv`` and the plots.

    The summary is rewritten after every finished run, so an interrupted sweep leaves a
    readable table of the runs done.
    """
    out = Path(options.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    summary = out / "summary.csv"
    tasks = make_tasks(spec, out)
    rows: List[RunRow] = []

    bar = _progress_bar(len(tasks), spec.file.stem, options.progress)

    def on_row(row: RunRow) -> None:
        rows.append(row)
        log.info("run %s %s (%d/%d)%s", row.id, row.status, len(rows), len(tasks),
                 f": {row.reason}" if row.reason else "")
        write_summary(spec, rows, summary)
        if bar is not None:
            bar.update(1)

    _prebuild(spec)  # also for Dask: workers on this machine share the build folder
    try:
        if options.scheduler:
            log.info("sweep %s: %d runs on the Dask cluster at %s", spec.file, len(tasks), options.scheduler)
            _run_dask(tasks, options.scheduler, on_row)
        else:
            workers = max(1, min(options.workers or os.cpu_count() or 1, len(tasks)))
            log.info("sweep %s: %d runs on %d local processes", spec.file, len(tasks), workers)
            _run_local(tasks, workers, on_row)
    finally:
        if bar is not None:
            bar.close()
    rows.sort(key=lambda r: r.index)
    write_summary(spec, rows, summary)
    plots = [plot_comparison(spec, rows, p, out / plot_file_name(p)) for p in spec.plots]
    return SweepResult(spec, rows, summary, plots)


def _progress_bar(total: int, desc: str, enabled: bool):
    """A tqdm bar on stderr counting finished runs (off when stderr is not a terminal)."""
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(total=total, unit="run", desc=desc, leave=False, disable=None)


def default_output_dir(sweepfile: Path | str) -> Path:
    """``results/sweeps/<sweep file stem>`` (relative to the working directory)."""
    return Path("results") / "sweeps" / Path(sweepfile).stem


def run_sweep(sweepfile: Path | str, output_dir: Path | str | None = None, workers: Optional[int] = None,
              scheduler: Optional[str] = None, check: bool = True, progress: bool = True) -> SweepResult:
    """Run the sweep file; the entry point of ``immersim sweep``.

    Parameters
    ----------
    sweepfile : path-like
        The sweep TOML file.
    output_dir : path-like, optional
        Default :func:`default_output_dir`.
    workers : int, optional
        Local worker processes (default: the number of cores).
    scheduler : str, optional
        Dask scheduler address; when given the runs go to that cluster.
    check : bool
        Raise :class:`SweepFailed` (after writing everything) if any run failed.
    progress : bool
        Progress bar of finished runs on stderr (only when it is a terminal).

    Returns
    -------
    SweepResult
        ``str()`` of it is the summary table printed by the CLI.
    """
    spec = load_sweep(sweepfile)
    if workers is not None and workers < 1:
        raise ScenarioError(f"--workers must be >= 1, got {workers}")
    opts = SweepOptions(Path(output_dir) if output_dir else default_output_dir(sweepfile), workers, scheduler,
                        check, progress)
    result = execute(spec, opts)
    if opts.check and result.failed:
        raise SweepFailed(failure_message(result), result)
    return result


def failure_message(result: SweepResult, shown: int = 5) -> str:
    """One line naming the failed runs (the first ``shown`` with their reasons)."""
    bad = [f"{r.id}: {r.status}: {r.reason}" for r in result.failed]
    more = f"; and {len(bad) - shown} more" if len(bad) > shown else ""
    return (f"sweep {result.spec.file}: {len(bad)} of {len(result.rows)} runs did not complete "
            f"({'; '.join(bad[:shown])}{more}); summary: {result.summary}")
