"""Wall time of a run's phases, from the process's start to the log's close (``immersim -v run``).

A phase ends with :func:`mark` and lasts from the previous mark: the interpreter's start-up
(from the process's start, as the kernel records it, to the first import of this module), the
imports, the scenario's parse and check, each unit's extraction, instantiation and
initialisation, the log's opening, the first step, the others and the log's close. A process
that runs several scenarios starts the record again with each run (:func:`run_started`).
"""
from __future__ import annotations

import logging
import os
import time
from typing import List, Tuple

log = logging.getLogger(__name__)

#: marks kept per run (a process that loads thousands of units keeps the first ones)
_MAX = 256


def _process_start() -> float:
    """The ``perf_counter`` time the process started (Linux ``/proc``, 10 ms resolution; now
    elsewhere)."""
    now = time.perf_counter()
    try:
        with open("/proc/self/stat", "rb") as fh:
            ticks = int(fh.read().rsplit(b")", 1)[1].split()[19])   # field 22, starttime
        with open("/proc/uptime", "rb") as fh:
            uptime = float(fh.read().split()[0])
        age = uptime - ticks / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return now
    return now - max(0.0, age)


_START = _process_start()
_last = time.perf_counter()
_marks: List[Tuple[str, float]] = [("interpreter", _last - _START)]
_runs = 0


def mark(name: str) -> None:
    """End the phase ``name`` now (it began at the previous mark)."""
    global _last
    now = time.perf_counter()
    if len(_marks) < _MAX:
        _marks.append((name, now - _last))
    _last = now


def run_started() -> None:
    """A run begins: the process's first, when nothing was marked since the interpreter's
    start-up, ends the "imports" phase; any other starts a new record."""
    global _runs, _last
    _runs += 1
    if _runs == 1 and len(_marks) == 1:
        mark("imports")
    else:
        _marks.clear()
        _last = time.perf_counter()


def phases() -> List[Tuple[str, float]]:
    """``(phase, wall seconds)`` in order, for the current run."""
    return list(_marks)


def summary() -> str:
    """One line: each phase's wall time, and the time to the first step."""
    names = [n for n, _ in _marks]
    first = names.index("first step") + 1 if "first step" in names else len(names)
    to_first = sum(s for _, s in _marks[:first])
    parts = ", ".join(f"{n} {s:.3f}" for n, s in _marks)
    return f"phases (s): {parts}; {to_first:.3f} s to the end of the first step"
