"""Shared helpers of the benchmark scripts: machine and commit stamps, medians, tables."""
from __future__ import annotations

import os
import platform
import statistics
import subprocess
import time
from pathlib import Path
from typing import Callable, Dict, List

ROOT = Path(__file__).resolve().parent.parent


def commit() -> str:
    try:
        out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True)
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT,
                               capture_output=True, text=True).stdout.strip()
        return out.stdout.strip() + ("+dirty" if dirty else "")
    except OSError:
        return "unknown"


def machine() -> str:
    cpu = platform.processor() or ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{os.cpu_count()} cores, {cpu}, Python {platform.python_version()}"


def stamp(command: str) -> str:
    return (f"Command: `{command}`  \nCommit: `{commit()}`  \nMachine: {machine()}  \n"
            f"Date: {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}\n")


def interleaved(fns: Dict[str, Callable[[], float]], repeats: int) -> Dict[str, List[float]]:
    """Run each function ``repeats`` times, interleaved (a, b, a, b, ...), so a noisy shared
    machine affects all of them alike. Each function returns its own measured seconds."""
    out: Dict[str, List[float]] = {k: [] for k in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            out[name].append(fn())
    return out


def median(xs: List[float]) -> float:
    return statistics.median(xs)


def fmpy_slave(path: Path, md, prefix: str = "bench_"):
    """Extract ``path`` into a fresh temporary folder and instantiate it with FMPy's
    ``FMU2Slave`` (model description ``md``), set up at t = 0 and ready for initialization
    mode. Returns ``(fmu, folder)``; the caller frees the instance and removes the folder."""
    import tempfile
    import zipfile

    from fmpy.fmi2 import FMU2Slave

    tmp = tempfile.mkdtemp(prefix=prefix)
    zipfile.ZipFile(path).extractall(tmp)
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=tmp, modelIdentifier=md.coSimulation.modelIdentifier,
                    instanceName="bench")
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    return fmu, tmp
