"""Where runs execute: local spawned processes or a Dask cluster."""
from __future__ import annotations

import os
import uuid
from pathlib import Path
from typing import Callable, List, Sequence

from ..errors import ImmersimError

from .common import log
from .runs import RunRow, RunTask, _worker_init, run_one


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


