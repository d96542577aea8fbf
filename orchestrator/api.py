"""Run a scenario from Python: ``immersim.run`` (what ``immersim run`` does, without a terminal)."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Dict, Optional

from .execution import RunResult, run_scenario


def default_output(scenario: Path | str) -> Path:
    """``results/runs/<scenario stem>.mcap`` (relative to the working directory)."""
    return Path("results") / "runs" / f"{Path(scenario).stem}.mcap"


def execute(scenario: Path | str, overrides: Optional[Dict[str, Any]] = None, output: Path | str | None = None,
            progress: bool = False, **options: Any) -> RunResult:
    """Run ``scenario`` and return its :class:`~immersim.orchestrator.execution.RunResult`
    (steps done, timings, ``output``: the log); :func:`run` returns only the log's path.
    ``options``: ``realtime`` (factor), ``live`` (a :class:`~immersim.orchestrator.live.LiveServer`),
    ``replay`` (a log whose recorded live inputs drive the run); see
    :class:`~immersim.orchestrator.execution.Execution`.

    Raises
    ------
    ScenarioError
        A bad scenario file or override (nothing ran).
    RunFailed
        The run stopped early (``RunInterrupted`` on SIGINT); its log holds every completed step
        and ``exc.result`` tells how far it got.
    """
    out = Path(output) if output is not None else default_output(scenario)
    return run_scenario(Path(scenario), out, progress=progress, overrides=dict(overrides or {}), **options)


def run(scenario: Path | str, overrides: Optional[Dict[str, Any]] = None, output: Path | str | None = None,
        progress: bool = False) -> Path:
    """Run a scenario file and log every signal to MCAP.

    Parameters
    ----------
    scenario : path-like
        Scenario TOML file.
    overrides : dict, optional
        ``{"unit.param": value, "simulation.stop": 2.0, "coll:fmu": "other.fmu", ...}``: the keys of
        ``immersim run --set`` with Python values.
    output : path-like, optional
        The MCAP file (default :func:`default_output`).
    progress : bool
        A progress bar on stderr.

    Returns
    -------
    Path
        The log, e.g. for :func:`immersim.read_log`.
    """
    return execute(scenario, overrides, output, progress).output
