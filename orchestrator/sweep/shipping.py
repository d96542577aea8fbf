"""Runs that carry their inputs and bring their log back (a cluster without a shared disk).

On a Dask cluster a run must not read or write the client's folders. The client gives each
:class:`~immersim.orchestrator.sweep.runs.RunTask` the scenario's text and, per unit
instance, the sha256 and the client-side path of the FMU it resolved (:func:`attach_inputs`).
The FMU files themselves travel separately, once per worker and sweep: the executor scatters
one blob per distinct hash and hands each run the blobs it needs; the worker keeps them in its
own cache (:func:`store_fmus`, content-addressed: each file written once per machine). The run
writes its log into a private temporary folder and returns the bytes; the client writes them
to the sweep's output folder and computes the metrics from that file.

A run on a worker names the scenario file and the FMU files as the client resolved them (the
log's ``scenario`` and ``fmus`` metadata), so its log holds the records of the same run on the
client's own processes bit for bit (the chunk layout, cut on wall-clock time, may differ).
"""
from __future__ import annotations

import hashlib
import os
import tempfile
import time
from pathlib import Path
from typing import Dict, Iterable, Optional, Tuple

from ..errors import ScenarioError

#: sha256 hex digest -> file contents of one FMU
Blobs = Dict[str, bytes]


def attach_inputs(tasks: Iterable, scenario_file: Path) -> Tuple[Dict[str, Path], Dict[int, str]]:
    """Give every task the scenario's text and its units' FMUs (sha256, client path).

    Returns the FMU files to ship, by sha256 (each distinct file hashed once), and the runs
    that cannot start, by task index, with the reason a local run gives (an FMU file that does
    not exist: ``FmuLoadError: unit ...: FMU '...' not found``).
    """
    from ..errors import ImmersimError
    from ..scenario import load_scenario
    from ..system import resolve_fmu, sha256

    text = Path(scenario_file).read_text()
    resolved: Dict[tuple, Path] = {}
    hashed: Dict[Path, str] = {}
    failed: Dict[int, str] = {}
    for task in tasks:
        task.text, task.fmus = text, {}
        try:
            sc = load_scenario(scenario_file, task.overrides)
            task.included = sc.included
            for u in sc.units:
                key = (u.fmu, tuple(sorted(u.build.items())))   # a built-in unit at its build size
                if key not in resolved:
                    resolved[key] = resolve_fmu(u.fmu, sc.file, u.name, u.build)
                path = resolved[key]
                if path not in hashed:
                    hashed[path] = sha256(path)
                task.fmus[u.name] = (hashed[path], str(path))
        except ImmersimError as exc:
            failed[task.index] = f"{type(exc).__name__}: {exc}"
    return {h: p for p, h in hashed.items()}, failed


def shipped_dir() -> Path:
    """Where a worker keeps the FMUs shipped to it: ``shipped/`` in the user's cache folder."""
    from ..build import user_cache_dir

    return user_cache_dir() / "shipped"


def store_fmus(blobs: Blobs, folder: Optional[Path] = None) -> Dict[str, Path]:
    """Write each blob to ``folder/<sha256>.fmu`` unless it is there already; returns the paths.

    The name is the content's sha256 (checked: a corrupted transfer raises ``ValueError``);
    the file appears atomically, so worker processes sharing the folder never read half of it.
    """
    folder = Path(folder) if folder is not None else shipped_dir()
    folder.mkdir(parents=True, exist_ok=True)
    out = {}
    for digest, data in blobs.items():
        path = folder / f"{digest}.fmu"
        if not path.exists():
            got = hashlib.sha256(data).hexdigest()
            if got != digest:
                raise ValueError(f"shipped FMU {digest[:12]}: the bytes received hash to {got[:12]}")
            fd, tmp = tempfile.mkstemp(dir=folder, suffix=".part")
            with os.fdopen(fd, "wb") as fh:
                fh.write(data)
            os.replace(tmp, path)
        out[digest] = path
    return out


def shipped_scenario(task, local: Dict[str, Path]):
    """The task's scenario, parsed from its text under the client's file name, each unit
    given its local FMU copy (``UnitSpec.path``) and the client's path as its name (``fmu``)."""
    from ..scenario import parse_scenario
    from ..tomlfiles import tomllib

    sc = parse_scenario(tomllib.loads(task.text), Path(task.scenario), task.text, task.overrides,
                        texts=task.included)
    for u in sc.units:
        if u.name not in task.fmus:
            raise ScenarioError(f"{task.scenario}: unit {u.name}: no FMU was shipped with the run")
        digest, origin = task.fmus[u.name]
        u.fmu, u.path = origin, local[digest]
    return sc


def run_shipped(task, blobs: Blobs) -> Tuple[object, Optional[bytes]]:
    """Run ``task`` from its shipped inputs in a private folder; return its row (without
    metrics: the client computes them from the log) and the bytes of its log (None if none).
    ``row.timing['ship']`` is the worker's share of the shipping: storing the FMUs, reading
    the log back."""
    from .runs import execute_run

    t0 = time.perf_counter()
    local = store_fmus(blobs)
    ship = time.perf_counter() - t0
    with tempfile.TemporaryDirectory(prefix="immersim_task_") as tmp:
        mcap = Path(tmp) / Path(task.mcap).name
        row = execute_run(task, mcap, lambda: shipped_scenario(task, local))
        t0 = time.perf_counter()
        data = mcap.read_bytes() if mcap.exists() else None
        ship += time.perf_counter() - t0
    row.timing["ship"] = ship
    return row, data
