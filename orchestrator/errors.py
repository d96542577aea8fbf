"""Typed errors of the orchestrator. Each subclasses a builtin so callers can catch broadly.

User errors (:class:`ScenarioError`, :class:`ConnectionError_`, :class:`FmuLoadError`) are
reported by the CLI as one clear line and a non-zero exit, without a traceback.
"""
from __future__ import annotations


class ImmersimError(Exception):
    """Base of every error the CLI reports as a user-facing message."""


class ScenarioError(ImmersimError, ValueError):
    """A scenario file is malformed: names the file and the offending key."""


class BuildError(ImmersimError, RuntimeError):
    """A unit folder could not be built into an FMU."""


class FmuLoadError(ImmersimError, OSError):
    """An FMU file is missing, corrupt or not a co-simulation FMU."""


class FmuCallError(ImmersimError, RuntimeError):
    """An FMI function returned error, fatal or discard.

    Attributes
    ----------
    unit : str
        Instance name.
    function : str
        FMI function, e.g. ``fmi2DoStep``.
    time_ns : int
        Simulation time of the call in nanoseconds.
    status : int
        FMI status returned.
    """

    def __init__(self, unit: str, function: str, time_ns: int, status: int, detail: str = "") -> None:
        self.unit, self.function, self.time_ns, self.status = unit, function, time_ns, status
        names = {1: "warning", 2: "discard", 3: "error", 4: "fatal", 5: "pending"}
        msg = (f"unit {unit}: {function} returned {names.get(status, status)} "
               f"at t = {time_ns / 1e9:.9g} s")
        if detail:
            msg += f": {detail}"
        super().__init__(msg)


class LogWriteError(ImmersimError, OSError):
    """The MCAP log could not be written (disk full, file size limit, I/O error)."""


class NonFiniteOutputError(ImmersimError, ArithmeticError):
    """An FMU output is NaN or infinite: names unit, variable and time."""

