"""One wrapper for every FMU call: load, instantiate, get/set by name, step.

Any FMI 2.0 or 3.0 co-simulation FMU is loaded through FMPy. The status of every FMI call is
checked: set-up calls go through :meth:`FmuInstance._guard` (FMPy's wrappers, whose
exceptions become typed errors), the functions called every step through
:meth:`FmuInstance._check`; both raise :class:`~immersim.orchestrator.errors.FmuCallError`
naming the instance, the function, the simulation time and the last message the FMU logged.

The per-step FMI 2.0 functions (doStep, get Real/Integer/Boolean, set Real) are called on the
addresses FMPy loaded through ctypes prototypes without ``argtypes``, with every argument
pre-built (component pointer, value references, counts, buffers read through NumPy views, the
time as a reused ``c_double``), and, for pythonfmu FMUs, without releasing the GIL: a macro
step costs well under a microsecond of ctypes overhead per call.

Beside this module: :mod:`.modeldesc` (model descriptions, archive checks), :mod:`.extraction`
(the FMU's files, cached between runs) and :mod:`.fmi2io` (the per-step readers and setters);
their public names are importable from here too.

Time is handled in integer nanoseconds and converted to seconds only here, at the FMI call.
"""
from __future__ import annotations

import ctypes
import logging
import os
import weakref
from collections import deque
from pathlib import Path
from typing import Any, Deque, Dict, List, Optional, Sequence

from . import phases
from . import supervisor as _supervisor
from .errors import FmuCallError, FmuLoadError
from .extraction import clear as _clear_extractions, extract as _extract, forget_python_code
from .fmi2io import DiscreteSetter, RealSetter, ValueReader
from .modeldesc import _MODELS, VarInfo, _unit_of, check_archive, read_model
from .pythonfmu_exit import install as _install_pythonfmu_exit

__all__ = ["FmuInstance", "VarInfo", "ValueReader", "RealSetter", "DiscreteSetter", "read_model", "check_archive",
           "forget_python_code", "clear_caches", "step_error", "ns_to_s", "ENDED"]


log = logging.getLogger(__name__)
_install_pythonfmu_exit()   # a process that loads pythonfmu FMUs can exit normally (see that module)

_STATUS = ["ok", "warning", "discard", "error", "fatal", "pending"]
#: the unit called last and the time of the call, for a supervising parent (two int64 stores
#: before each doStep; see :mod:`.supervisor`)
_CRUMB = _supervisor.CRUMB

#: the FMI 2.0 functions called every step; they are called through prototypes without
#: ``argtypes`` and with pre-built ctypes arguments (component pointer, counts, buffers, the
#: time as a reused c_double), which skips ctypes' per-argument ``from_param`` conversions
_FAST_FUNCTIONS = ("fmi2GetReal", "fmi2SetReal", "fmi2GetInteger", "fmi2GetBoolean", "fmi2SetInteger",
                   "fmi2SetBoolean", "fmi2DoStep")


def ns_to_s(t_ns: int) -> float:
    """Integer nanoseconds to seconds (the only place the master converts time).

    Division by 1e9 is correctly rounded, so ``k * 33_000_000`` ns gives the float nearest to
    ``k * 0.033`` s for every k, with no accumulated drift.
    """
    return t_ns / 1e9


#: (unit, time in ns) of every unit that asked to end the simulation (FMI 2.0 fmi2Terminated,
#: FMI 3.0 terminateSimulation) since the execution cleared it; the step it ends is complete (a
#: worker process sends its entries to the master with the step's reply: orchestrator/transport)
ENDED: List[tuple] = []


def step_error(unit: str, t_ns: int, h_ns: int, instance_ns: int) -> FmuCallError:
    """The master's mistake in a ``doStep`` (a step <= 0, or a start time that is not the
    instance's time, ns), as the error every instance raises for it (its condition is tested
    inline by the callers: this builds the message only)."""
    if h_ns <= 0:
        return FmuCallError(unit, "doStep", t_ns, 3, f"step size {h_ns} ns must be > 0")
    return FmuCallError(unit, "doStep", t_ns, 3, f"master time {t_ns} ns differs from the instance time {instance_ns} ns")


def clear_caches() -> None:
    """Forget parsed model descriptions and shared extractions (as in a fresh process)."""
    _MODELS.clear()
    _clear_extractions()


#: FMI 2.0 log messages are routed by instance name: FMPy's native proxy that formats the
#: variadic message keeps one Python callback per process, so one callback serves all.
_BY_NAME: "weakref.WeakValueDictionary[str, FmuInstance]" = weakref.WeakValueDictionary()
_CALLBACKS = None


def _route_fmi2_log(env, instance, status, category, message) -> None:
    name = instance.decode("utf-8", "replace") if instance else ""
    target = _BY_NAME.get(name)
    if target is not None:
        target._record(status, message)
    else:
        log.warning("FMU %s: %s", name, message.decode("utf-8", "replace") if message else "")


def _fmi2_callbacks():
    """The process-wide fmi2CallbackFunctions with the routing logger."""
    global _CALLBACKS
    if _CALLBACKS is None:
        from fmpy.fmi1 import calloc, free
        from fmpy.fmi2 import (fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                               fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)
        from fmpy.logging import addLoggerProxy

        cb = fmi2CallbackFunctions()
        cb.logger = fmi2CallbackLoggerTYPE(_route_fmi2_log)
        cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        addLoggerProxy(ctypes.byref(cb))
        _CALLBACKS = cb
    return _CALLBACKS


class FmuInstance:
    """A loaded, instantiated co-simulation FMU.

    Parameters
    ----------
    name : str
        Instance name (unique within a scenario).
    path : Path
        The ``.fmu`` file.
    unzip_dir : Path, optional
        The instance's folder of the FMU's files (a link to the cached extraction, see
        :mod:`.extraction`); the cache entry itself by default. Instances of one FMU file
        given folders with the same parent share the first one's folder when the FMU allows
        several instances per process.
    """

    #: loaded in this process (a unit in a worker process is a ``transport.RemoteInstance``)
    remote = False

    def __init__(self, name: str, path: Path | str, unzip_dir: Optional[Path] = None) -> None:
        self.name = name
        self.path = Path(path)
        self.t_ns = 0
        self.fatal = False
        self.failed = False   # an FMI call returned error: the standard allows only free (or reset)
        self.initialized = False   # out of initialization mode: terminate is allowed (else free only)
        self.error_logged = False   # the FMU logged a message with status error or fatal
        self.messages: Deque[str] = deque(maxlen=20)
        if not self.path.exists():
            raise FmuLoadError(f"unit {name}: FMU file {self.path} does not exist")
        self._crumb_id = _supervisor.unit_id(name)
        md, self.variables = read_model(self.path, name)
        self.model_description = md
        self.fmi_version = md.fmiVersion
        self.unzip_dir = self._extract(md, unzip_dir)
        phases.mark(f"extract {name}")
        self._instantiate(md)
        phases.mark(f"instantiate {name}")

    def _extract(self, md: Any, unzip_dir: Optional[Path]) -> str:
        """The folder of the FMU's files (:func:`.extraction.extract`: the cached extraction,
        or the one a sibling instance of the same file uses)."""
        return _extract(self.path, md, unzip_dir, self.name)

    # -- loading -----------------------------------------------------------------------
    def _instantiate(self, md: Any) -> None:
        from fmpy.fmi2 import FMU2Slave
        from fmpy.fmi3 import FMU3Slave

        kwargs = dict(guid=md.guid, unzipDirectory=self.unzip_dir,
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName=self.name)
        cwd = os.getcwd()  # FMPy changes into the binaries folder and does not return on failure
        _CRUMB[_supervisor.PHASE], _CRUMB[_supervisor.UNIT] = _supervisor.LOADING, self._crumb_id
        try:
            cls = FMU2Slave if self.fmi_version.startswith("2") else FMU3Slave
            if not self.fmi_version.startswith(("2", "3")):
                raise FmuLoadError(f"unit {self.name}: FMI version {self.fmi_version} is not supported (2.0 or 3.0)")
            try:
                self.fmu = cls(**kwargs)
            except Exception as exc:  # FMPy raises a bare Exception for a missing or unloadable binary
                raise FmuLoadError(f"unit {self.name}: cannot load the binary of {self.path}: {exc}") from None
            finally:
                os.chdir(cwd)
            if self.fmi_version.startswith("2"):
                cb = _fmi2_callbacks()
                _BY_NAME[self.name] = self
                self._guard("fmi2Instantiate", lambda: self.fmu.instantiate(callbacks=cb, loggingOn=True))
            else:
                self._guard("fmi3InstantiateCoSimulation",
                            lambda: self.fmu.instantiate(loggingOn=True, logMessage=self._log3))
        except FmuCallError as exc:
            raise FmuLoadError(str(exc)) from exc
        except FmuLoadError:
            raise
        except OSError as exc:
            raise FmuLoadError(f"unit {self.name}: cannot load the binary of {self.path}: {exc}") from exc
        self._setup_fast_path()

    def _log3(self, env, status, category, message) -> None:
        self._record(status, message)

    def _record(self, status: int, message: bytes) -> None:
        text = message.decode("utf-8", "replace") if message else ""
        self.messages.append(text)
        if status >= 3:
            self.error_logged = True
        # an error (status >= 2) comes back as the FmuCallError of the call, which carries the
        # message: reported once, by whoever handles that error
        level = logging.WARNING if status == 1 else logging.DEBUG
        log.log(level, "unit %s [%s]: %s", self.name, _STATUS[status] if status < 6 else status, text)

    def _setup_fast_path(self) -> None:
        self._fmi2 = self.fmi_version.startswith("2")
        gen = getattr(self.model_description, "generationTool", None) or ""
        #: the FMU runs Python code in this interpreter (pythonfmu): its hot functions are
        #: called without releasing the GIL, which the FMU would take back at once
        self.in_process_python = gen.startswith("PythonFMU")
        self._c_component = ctypes.c_void_p(self.fmu.component)
        if self._fmi2:
            self._c_t, self._c_h, self._h_ns = ctypes.c_double(), ctypes.c_double(), None
            self._c_true = ctypes.c_int(1)  # noSetFMUStatePriorToCurrentPoint
            self._do_step = self._fast_function("fmi2DoStep")
            self._set_real = self._fast_function("fmi2SetReal")
        else:
            from .fmi3 import stepper

            self._c_true = ctypes.c_bool(True)  # noSetFMUStatePriorToCurrentPoint
            self._do_step = self._fast_function("fmi3DoStep")
            self._step3 = stepper(self)

    def _fast_function(self, name: str):
        """A ctypes function for the FMI 2.0 function ``name`` (one of ``_FAST_FUNCTIONS``),
        returning the status as int; it takes ctypes arguments only (no ``argtypes``).

        It is built on the address FMPy loaded, so FMPy's own wrappers are untouched. For an
        FMU that runs Python code in this interpreter (pythonfmu) the call keeps the GIL
        (``PYFUNCTYPE``): releasing it only for the FMU to take it back costs more than the
        call. Any other FMU is called with the GIL released (``CFUNCTYPE``), as FMPy does, so
        its own threads may call back into Python.
        """
        if name not in _FAST_FUNCTIONS and not name.startswith("fmi3"):
            raise ValueError(f"{name} has no fast prototype")
        factory = ctypes.PYFUNCTYPE if self.in_process_python else ctypes.CFUNCTYPE
        address = ctypes.cast(getattr(self.fmu.dll, name), ctypes.c_void_p).value
        return factory(ctypes.c_int)(address)

    # -- the one checked call ----------------------------------------------------------
    def _guard(self, function: str, thunk) -> Any:
        from fmpy.fmi1 import FMICallException

        try:
            return thunk()
        except FMICallException as exc:
            self.fatal = self.fatal or exc.status == 4
            self.failed = self.failed or exc.status == 3
            raise FmuCallError(self.name, function, self.t_ns, exc.status, self._last_message()) from None
        except Exception as exc:
            if isinstance(exc, FmuCallError):
                raise
            raise FmuCallError(self.name, function, self.t_ns, 3, f"{exc} {self._last_message()}".strip()) from None

    def _last_message(self) -> str:
        return self.messages[-1] if self.messages else ""

    def _raised(self, function: str, exc: Exception) -> FmuCallError:
        """A Python exception a fast-path call raised (an in-process FMU, called without
        releasing the GIL, left it set) as the typed error of a failed call."""
        return FmuCallError(self.name, function, self.t_ns, 3,
                            f"{type(exc).__name__}: {exc} {self._last_message()}".strip())

    def _check(self, function: str, status: int) -> None:
        if status > 1:
            self.fatal = self.fatal or status == 4
            self.failed = self.failed or status == 3
            raise FmuCallError(self.name, function, self.t_ns, status, self._last_message())

    # -- life cycle --------------------------------------------------------------------
    def initialize(self, start_ns: int, stop_ns: Optional[int], parameters: Dict[str, Any],
                   tolerance: Optional[float] = None) -> None:
        """Set parameters and start values, enter and exit initialization mode."""
        self.t_ns = start_ns
        _CRUMB[_supervisor.PHASE], _CRUMB[_supervisor.UNIT] = _supervisor.INITIALIZING, self._crumb_id
        _CRUMB[_supervisor.T_NS] = start_ns
        t0 = ns_to_s(start_ns)
        t1 = ns_to_s(stop_ns) if stop_ns is not None else None
        if self.fmi_version.startswith("2"):
            self._guard("fmi2SetupExperiment", lambda: self.fmu.setupExperiment(tolerance=tolerance, startTime=t0, stopTime=t1))
            self.set_values(parameters)
            self._guard("fmi2EnterInitializationMode", self.fmu.enterInitializationMode)
            self._guard("fmi2ExitInitializationMode", self.fmu.exitInitializationMode)
            self.initialized = True
        else:
            self.set_values(parameters)
            self._guard("fmi3EnterInitializationMode",
                        lambda: self.fmu.enterInitializationMode(tolerance=tolerance, startTime=t0, stopTime=t1))
            self._guard("fmi3ExitInitializationMode", self.fmu.exitInitializationMode)
            self.initialized = True
        phases.mark(f"initialise {self.name}")

    def do_step(self, t_ns: int, h_ns: int) -> None:
        """Advance from ``t_ns`` by ``h_ns`` (integer nanoseconds)."""
        if h_ns <= 0 or t_ns != self.t_ns:
            raise step_error(self.name, t_ns, h_ns, self.t_ns)
        _CRUMB[2] = self._crumb_id   # supervisor.UNIT, T_NS
        _CRUMB[3] = t_ns
        if self._fmi2:
            if h_ns != self._h_ns:
                self._c_h.value, self._h_ns = h_ns / 1e9, h_ns
            self._c_t.value = t_ns / 1e9  # ns_to_s, inlined
            try:
                status = self._do_step(self._c_component, self._c_t, self._c_h, self._c_true)
            except Exception as exc:
                raise self._raised("fmi2DoStep", exc) from None
            if status > 1 and not (status == 2 and self._fmi2_terminated(t_ns + h_ns)):
                self._check("fmi2DoStep", status)
        else:
            ended = self._step3(t_ns, h_ns)
            if ended is not None:
                self._ended(ended)
        self.t_ns = t_ns + h_ns

    def _fmi2_terminated(self, end_ns: int) -> bool:
        """After a discarded ``fmi2DoStep``: did the FMU ask to end the simulation
        (``fmi2Terminated``, FMI 2.0 §4.2.3)? Then the end is recorded in :data:`ENDED` (at
        ``fmi2LastSuccessfulTime``) and the step counts as done. Not after the FMU logged an
        error: pythonfmu reports every refused step as terminated too."""
        from fmpy.fmi2 import fmi2LastSuccessfulTime, fmi2Terminated

        if self.error_logged:
            return False
        try:
            if not self.fmu.getBooleanStatus(fmi2Terminated):
                return False
            last = self.fmu.getRealStatus(fmi2LastSuccessfulTime)
        except Exception:   # the FMU does not report it: a plain discard
            return False
        self._ended(min(int(round(last * 1e9)), end_ns))
        return True

    def _ended(self, t_ns: int) -> None:
        """The unit asked to end the simulation at ``t_ns``: recorded in :data:`ENDED` (the
        execution ends the run after this step)."""
        ENDED.append((self.name, t_ns))

    def terminate(self) -> None:
        """Terminate and free the instance; errors here are logged, not raised.

        After ``fmi2Fatal`` the FMI standard allows no further call on the instance (and the
        pythonfmu binary crashes on one), so a fatal instance is left alone; after an error (or
        before initialization ended) only free is allowed (FMI 2.0 §4.3.3, FMI 3.0 §4.2.3).
        """
        if self.fatal:
            log.debug("unit %s: not terminated after a fatal error", self.name)
            return
        calls = (("terminate", self.fmu.terminate), ("freeInstance", self.fmu.freeInstance))
        for fn, call in calls if self.initialized and not self.failed else calls[1:]:  # else free only
            try:
                call()
            except Exception as exc:  # a failed unit may refuse to terminate
                log.debug("unit %s: %s failed: %s", self.name, fn, exc)

    # -- values by name ----------------------------------------------------------------
    def var(self, name: str) -> VarInfo:
        try:
            return self.variables[name]
        except KeyError:
            raise KeyError(f"unit {self.name}: no variable {name!r}") from None

    def set_values(self, values: Dict[str, Any]) -> None:
        """Set any typed values by name (parameters, inputs); slow path, used at set-up."""
        if not self.fmi_version.startswith("2"):
            from .fmi3 import set_values

            return set_values(self, values)
        for name, value in values.items():
            v = self.var(name)
            fam = v.family
            if fam == "float":
                value = float(value)
                fn = "setReal" if self.fmi_version.startswith("2") else f"set{v.type}"
            elif fam == "int":
                value = int(value)
                fn = "setInteger" if self.fmi_version.startswith("2") else f"set{v.type if v.type != 'Enumeration' else 'Int64'}"
            elif fam == "bool":
                value = bool(value)
                fn = "setBoolean"
            else:
                value = str(value)
                fn = "setString"
            self._guard(fn, lambda f=fn, vr=v.vr, val=value: getattr(self.fmu, f)([vr], [val]))

    def get_values(self, names: Sequence[str]) -> List[Any]:
        """Read typed values by name (slow path)."""
        if not self.fmi_version.startswith("2"):
            from .fmi3 import get_values

            return get_values(self, names)
        out = []
        for name in names:
            v = self.var(name)
            fam = v.family
            if fam == "float":
                fn = "getReal" if self.fmi_version.startswith("2") else f"get{v.type}"
            elif fam == "int":
                fn = "getInteger" if self.fmi_version.startswith("2") else f"get{v.type if v.type != 'Enumeration' else 'Int64'}"
            elif fam == "bool":
                fn = "getBoolean"
            else:
                fn = "getString"
            val = self._guard(fn, lambda f=fn, vr=v.vr: getattr(self.fmu, f)([vr]))[0]
            out.append(val.decode() if isinstance(val, bytes) else val)
        return out

    def reader(self, names: Sequence[str], check_finite: bool = False) -> "ValueReader":
        """A fast reader of a fixed list of variables (one FMI call per type family; FMI 3.0:
        per type, :class:`.fmi3.Reader`)."""
        if not self._fmi2:
            from .fmi3 import Reader

            return Reader(self, list(names), check_finite)
        return ValueReader(self, list(names), check_finite)

    def real_setter(self, names: Sequence[str]) -> "RealSetter":
        if not self._fmi2:
            from .fmi3 import Setter

            return Setter(self, list(names))
        return RealSetter(self, list(names))

    def discrete_setter(self, names: Sequence[str]) -> "DiscreteSetter":
        if not self._fmi2:
            from .fmi3 import Setter

            return Setter(self, list(names))
        return DiscreteSetter(self, list(names))
