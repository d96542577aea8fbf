"""The scenario input signals as plain functions of time (no immersim imports).

One implementation for the master's manipulators (:mod:`.manipulators`) and the signal-source
FMU an SSP export carries (:mod:`.ssp.source`), which packs this file as a module of its own.
"""
from __future__ import annotations

import math
from typing import Any, Callable, Dict

import numpy as np


def signal_function(kind: str, params: Dict[str, Any]) -> Callable[[float], float]:
    """The time function ``u(t)`` (t in s) of a scenario input of ``kind`` with ``params``.

    Kinds: ``constant`` (value), ``step`` (value after ``at``, ``initial`` before),
    ``ramp`` (slope after ``at``, starting from ``initial``), ``sine`` (offset + amplitude
    sin(2 pi frequency t + phase)), ``table`` (linear interpolation of times/values, held
    outside the range).
    """
    p = params
    if kind == "constant":
        v = float(p["value"])
        return lambda t: v
    if kind == "step":
        at, v, v0 = float(p["at"]), float(p["value"]), float(p.get("initial", 0.0))
        return lambda t: v if t >= at - 1e-12 else v0
    if kind == "ramp":
        at, slope, v0 = float(p["at"]), float(p["slope"]), float(p.get("initial", 0.0))
        return lambda t: v0 + slope * max(0.0, t - at)
    if kind == "sine":
        a, fr = float(p["amplitude"]), float(p["frequency"])
        off, ph = float(p.get("offset", 0.0)), float(p.get("phase", 0.0))
        return lambda t: off + a * math.sin(2 * math.pi * fr * t + ph)
    return _table([float(x) for x in p["times"]], [float(y) for y in p["values"]])


def _table(times: list, values: list) -> Callable[[float], float]:
    """Linear interpolation of a table with increasing ``times`` (checked by the scenario
    parser), held outside the range: ``numpy.interp``'s arithmetic (the same slope and the same
    products, so bit-identical results; tests/orchestrator/test_manipulators.py compares) in
    Python floats, without a NumPy call per step and input."""
    from bisect import bisect_right

    t0, t1, v0, v1 = times[0], times[-1], values[0], values[-1]
    # a repeated time (a jump) spans no interval: its slope is never used
    slopes = [(values[j + 1] - values[j]) / (times[j + 1] - times[j]) if times[j + 1] != times[j] else 0.0
              for j in range(len(times) - 1)]

    def table(t: float) -> float:
        if not t < t1:   # at or after the last time (NaN: the last value, as np.interp gives NaN below)
            return v1 if t >= t1 else float(np.interp(t, times, values))
        if t < t0:
            return v0
        j = bisect_right(times, t) - 1
        return slopes[j] * (t - times[j]) + values[j]
    return table
