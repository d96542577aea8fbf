"""Manipulators: scenario input signals and fault injection (they write unit inputs).

Signals are functions of the simulation time in seconds, evaluated at the start of each
macro step (the value is held over the step).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from .scenario import FaultSpec, InputSpec
from .signals import signal_function


def signal(spec: InputSpec) -> Callable[[float], float]:
    """The time function ``u(t)`` of a scenario input (:func:`.signals.signal_function`; a live
    input, :func:`.live.attach_live_inputs`, brings its own)."""
    if spec.kind == "live":
        return spec.params["signal"]
    return signal_function(spec.kind, spec.params)


@dataclass
class Fault:
    """From ``at_ns`` on, force ``unit.var`` to ``value`` (e.g. NaN to provoke an error)."""

    spec: FaultSpec

    def active(self, t_ns: int) -> bool:
        return t_ns >= self.spec.at_ns
