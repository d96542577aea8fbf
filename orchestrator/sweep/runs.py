"""One run of a sweep (in a worker process or on a Dask worker) and its metrics."""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple

import numpy as np

from .common import REDUCERS, _RUN_LOCK
from .spec import MetricSpec


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
    #: for a run shipped to a worker without the client's folders (see .shipping): the
    #: scenario's text, and per unit instance the sha256 and client path of its FMU
    text: str = ""
    fmus: Dict[str, Tuple[str, str]] = field(default_factory=dict)
    #: the texts of the files the scenario includes, by path (``Scenario.included``)
    included: Dict[str, str] = field(default_factory=dict)


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
    from ..mcapio import LogReadError, read_series
    from ..patterns import matches

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
    return add_metrics(execute_run(task, Path(task.mcap)), task)


def execute_run(task: RunTask, mcap: Path, scenario: Optional[Callable[[], Any]] = None) -> RunRow:
    """Run one variant into the log ``mcap`` (no metrics); never raises for a failed run.

    ``scenario`` makes the :class:`~immersim.orchestrator.scenario.Scenario` to run (a shipped
    run's, see :mod:`.shipping`); by default the task's scenario file with its overrides.
    """
    from ..execution import Execution, RunFailed

    global _INTERRUPTED
    row = RunRow(task.index, task.id, "failed", mcap=mcap.name)
    mcap.unlink(missing_ok=True)  # never report the log of an earlier sweep
    if _INTERRUPTED:
        row.status, row.reason, row.mcap = "interrupted", "sweep interrupted before this run started", ""
        return row
    with _RUN_LOCK:
        t0 = time.perf_counter()
        try:
            sc = scenario() if scenario is not None else task.scenario
            ex = Execution(sc, mcap, progress=False, overrides=None if scenario is not None else task.overrides)
            ex.observers.append(_stop_if_interrupted)
            _take(row, ex.run())
        except RunFailed as exc:
            _take(row, exc.result)
            _INTERRUPTED = _INTERRUPTED or exc.result.status == "interrupted"
        except Exception as exc:  # a bad FMU swap, a parameter the FMU refuses, ... : the row says why
            row.reason = f"{type(exc).__name__}: {exc}"
        row.wall_time_s = time.perf_counter() - t0
    if not mcap.exists():
        row.mcap = ""
    return row


def add_metrics(row: RunRow, task: RunTask) -> RunRow:
    """Compute the metrics of a completed run from its log ``task.mcap``; a metric that cannot
    be computed fails the row (its other metrics are kept)."""
    if row.status == "completed":
        row.metrics, errors = compute_metrics(task.mcap, task.metrics, row)
        if errors:  # the run itself completed: keep its other metrics, fail the row loudly
            row.status, row.reason = "failed", "; ".join(errors)
    return row
