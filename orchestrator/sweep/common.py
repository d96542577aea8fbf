"""Constants and errors shared by the sweep modules."""
from __future__ import annotations

import logging
import re
import threading
from typing import Any, Callable, Dict

import numpy as np

from ..errors import ImmersimError

log = logging.getLogger("immersim.orchestrator.sweep")

REDUCERS: Dict[str, Callable[[np.ndarray], float]] = {
    "max": lambda y: float(np.max(y)),
    "min": lambda y: float(np.min(y)),
    "mean": lambda y: float(np.mean(y)),
    "rms": lambda y: float(np.sqrt(np.mean(np.square(y)))),
    "absmax": lambda y: float(np.max(np.abs(y))),
    "final": lambda y: float(y[-1]),
}
BUILTIN_METRICS = ("wall_time", "loop_time", "realtime_factor", "steps", "status", "unit_time:<unit>")
FIXED_COLUMNS = ("run", "id", "status", "steps", "t_end_s", "wall_time_s", "loop_time_s")
TAIL_COLUMNS = ("reason", "mcap")
_UNSAFE = re.compile(r"[^A-Za-z0-9_.+\-]+")
# One run at a time per process: pythonfmu FMUs share the embedding interpreter, and a Dask
# worker with several threads would otherwise step FMUs of different runs concurrently.
_RUN_LOCK = threading.Lock()
_EDGE = re.compile(r"^[^A-Za-z0-9_.+\-]+|[^A-Za-z0-9_.+\-]+$")


class SweepFailed(ImmersimError, RuntimeError):
    """Some runs of a sweep failed; ``result`` holds every row (the summary is written)."""

    def __init__(self, message: str, result: Any) -> None:  # a SweepResult
        super().__init__(message)
        self.result = result


