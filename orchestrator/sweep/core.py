"""Run a sweep: build once, execute the runs, write the summary and plots."""
from __future__ import annotations

import errno
import os
import re
from pathlib import Path
from typing import List, Optional

from ..errors import LogWriteError, ScenarioError

from .common import log, SweepFailed
from .executors import _run_dask, _run_local
from .runs import RunRow, RunTask
from .spec import SweepOptions, SweepSpec, load_sweep
from .summary import SweepResult, plot_comparison, plot_file_name, write_info, write_summary

#: a Dask scheduler address: an optional protocol, a host name or address, a port
_SCHEDULER = re.compile(r"^(?:(?:tcp|tls|ws|wss|ucx)://)?(?:[A-Za-z0-9_.\-]+|\[[0-9A-Fa-f:.]+\]):\d{1,5}$")


# -- the sweep ---------------------------------------------------------------------------
def _prebuild(spec: SweepSpec) -> None:
    """Build the built-in units the variants use once, before workers start (no build races)."""
    from ..build import build_all, builtin_names
    from ..scenario import load_scenario

    builtin = set(builtin_names())
    used = {(u.fmu, tuple(sorted(u.build.items()))) for v in spec.variants
            for u in load_scenario(spec.scenario, v.resolved).units}
    names = sorted(u for u in used if u[0] in builtin)
    if names:
        log.info("building built-in units %s", ", ".join(name for name, _ in names))
        for name, options in names:   # each at the size its scenario builds it (build = {...})
            build_all([name], options=dict(options))


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
    summary = out / "summary.csv"
    try:
        if out.exists() and not out.is_dir():
            raise NotADirectoryError(errno.ENOTDIR, "a file is there, not a folder")
        out.mkdir(parents=True, exist_ok=True)
        write_info(spec, out / "sweep.json")
    except OSError as exc:
        raise LogWriteError(f"sweep -o {out}: cannot write the sweep's folder: {exc.strerror or exc}") from None
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

    _prebuild(spec)  # also for Dask: the FMUs are built here and shipped to the workers
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
    if scheduler is not None and not _SCHEDULER.match(scheduler):
        raise ScenarioError(f"--scheduler {scheduler!r} is not a Dask scheduler address "
                            "([tcp|tls|ws|wss|ucx]://host:port)")
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

