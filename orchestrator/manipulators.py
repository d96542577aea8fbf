"""Manipulators: scenario input signals and fault injection (they write unit inputs).

Signals are functions of the simulation time in seconds, evaluated at the start of each
macro step (the value is held over the step).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Dict

import numpy as np

from .scenario import FaultSpec, InputSpec


def signal(spec: InputSpec) -> Callable[[float], float]:
    """The time function ``u(t)`` of a scenario input.

    Kinds: ``constant`` (value), ``step`` (value after ``at``, ``initial`` before),
    ``ramp`` (slope after ``at``, starting from ``initial``), ``sine`` (offset + amplitude
    sin(2 pi frequency t + phase)), ``table`` (linear interpolation of times/values, held
    outside the range).
    """
    p: Dict[str, Any] = spec.params
    if spec.kind == "constant":
        v = float(p["value"])
        return lambda t: v
    if spec.kind == "step":
        at, v, v0 = float(p["at"]), float(p["value"]), float(p.get("initial", 0.0))
        return lambda t: v if t >= at - 1e-12 else v0
    if spec.kind == "ramp":
        at, slope, v0 = float(p["at"]), float(p["slope"]), float(p.get("initial", 0.0))
        return lambda t: v0 + slope * max(0.0, t - at)
    if spec.kind == "sine":
        a, fr = float(p["amplitude"]), float(p["frequency"])
        off, ph = float(p.get("offset", 0.0)), float(p.get("phase", 0.0))
        return lambda t: off + a * math.sin(2 * math.pi * fr * t + ph)
    times, values = np.asarray(p["times"], float), np.asarray(p["values"], float)
    return lambda t: float(np.interp(t, times, values))


@dataclass
class Fault:
    """From ``at_ns`` on, force ``unit.var`` to ``value`` (e.g. NaN to provoke an error)."""

    spec: FaultSpec

    def active(self, t_ns: int) -> bool:
        return t_ns >= self.spec.at_ns
