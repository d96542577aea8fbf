"""Where runs execute: local spawned processes or a Dask cluster."""
from __future__ import annotations

import os
import time
import uuid
from pathlib import Path
from typing import Callable, Dict, List, Optional, Sequence

from ..errors import ImmersimError

from .common import log
from .runs import RunRow, RunTask, _worker_init, add_metrics, run_one
from .shipping import attach_inputs, run_shipped


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
    """Run ``tasks`` on the Dask cluster at ``address``; ``on_row`` gets each row as it completes.

    The workers need no shared disk (see :mod:`.shipping`): each task carries its scenario,
    the FMU files are scattered once and reach each worker once, and each log comes back as
    bytes, written to ``task.mcap`` here, where the metrics are computed.
    """
    fmus, unresolved = attach_inputs(tasks, Path(tasks[0].scenario)) if tasks else ({}, {})
    for t in tasks:
        if t.index in unresolved:  # an FMU file that does not exist: failed before it starts
            Path(t.mcap).unlink(missing_ok=True)
            on_row(RunRow(t.index, t.id, "failed", reason=unresolved[t.index]))
    tasks = [t for t in tasks if t.index not in unresolved]
    log.info("%d FMU files to ship", len(fmus))
    try:
        from distributed import Client, as_completed
    except ImportError:
        raise ImmersimError("--scheduler needs dask.distributed: pip install 'immersim[dask]'") from None
    try:
        client = Client(address, timeout="10s")
    except (OSError, TimeoutError) as exc:
        raise ImmersimError(f"cannot connect to the Dask scheduler at {address}: {exc}") from None
    try:
        for t in tasks:  # never report the log of an earlier sweep
            Path(t.mcap).unlink(missing_ok=True)
        t0 = time.perf_counter()
        blobs = client.scatter({f"immersim-fmu-{h}": p.read_bytes() for h, p in fmus.items()}, hash=False)
        scatter_s = time.perf_counter() - t0
        tag = uuid.uuid4().hex[:8]
        futures = [client.submit(run_shipped, t, {h: blobs[f"immersim-fmu-{h}"] for h, _ in t.fmus.values()},
                                 key=f"immersim-run-{t.id}-{tag}", pure=False) for t in tasks]
        by_key = {f.key: t for f, t in zip(futures, tasks)}
        try:
            for fut in as_completed(futures):
                task = by_key[fut.key]
                try:
                    row, data = fut.result()
                except Exception as exc:  # KilledWorker, lost connection, ...
                    on_row(_failed_row(task, exc))
                    continue
                on_row(_receive(task, row, data, scatter_s / len(tasks)))
        except BaseException:
            client.cancel(futures)
            raise
    finally:
        client.close()


def _receive(task: RunTask, row: RunRow, data: Optional[bytes], scatter_s: float) -> RunRow:
    """Write a shipped run's log to ``task.mcap`` and compute its metrics from that file;
    ``row.timing['ship']`` adds this side's shipping time (its share of the scatter, the write)."""
    t0 = time.perf_counter()
    if data is not None:
        Path(task.mcap).write_bytes(data)
    row.timing["ship"] = row.timing.get("ship", 0.0) + scatter_s + time.perf_counter() - t0
    return add_metrics(row, task)
