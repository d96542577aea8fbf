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

Time is handled in integer nanoseconds and converted to seconds only here, at the FMI call.
"""
from __future__ import annotations

import ctypes
import importlib
import logging
import math
import os
import weakref
import zipfile
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Deque, Dict, List, Optional, Sequence

import numpy as np

from . import supervisor as _supervisor
from .errors import FmuCallError, FmuLoadError
from .pythonfmu_exit import install as _install_pythonfmu_exit

log = logging.getLogger(__name__)
_install_pythonfmu_exit()   # a process that loads pythonfmu FMUs can exit normally (see that module)

#: type families that may be connected to each other
_FAMILY = {
    "Real": "float", "Float64": "float", "Float32": "float",
    "Integer": "int", "Enumeration": "int", "Int8": "int", "UInt8": "int", "Int16": "int",
    "UInt16": "int", "Int32": "int", "UInt32": "int", "Int64": "int", "UInt64": "int",
    "Boolean": "bool", "String": "string", "Binary": "binary",
}
_STATUS = ["ok", "warning", "discard", "error", "fatal", "pending"]
#: the unit called last and the time of the call, for a supervising parent (two int64 stores
#: before each doStep; see :mod:`.supervisor`)
_CRUMB = _supervisor.CRUMB

#: the FMI 2.0 functions called every step; they are called through prototypes without
#: ``argtypes`` and with pre-built ctypes arguments (component pointer, counts, buffers, the
#: time as a reused c_double), which skips ctypes' per-argument ``from_param`` conversions
_FAST_FUNCTIONS = ("fmi2GetReal", "fmi2SetReal", "fmi2GetInteger", "fmi2GetBoolean", "fmi2SetInteger",
                   "fmi2SetBoolean", "fmi2DoStep")


@dataclass(frozen=True)
class VarInfo:
    """What the master knows of one FMU variable."""

    name: str
    vr: int
    type: str
    causality: str
    variability: str
    unit: str
    start: Any
    description: str
    initial: str = ""       # "exact", "approx", "calculated" or "" (the standard's default)
    shape: tuple = ()       # FMI 3.0 array element: the array's shape (fmi3.variables)
    index: int = -1         # FMI 3.0 array element: its flat (row-major) position, else -1

    @property
    def family(self) -> str:
        return _FAMILY.get(self.type, self.type)


def ns_to_s(t_ns: int) -> float:
    """Integer nanoseconds to seconds (the only place the master converts time).

    Division by 1e9 is correctly rounded, so ``k * 33_000_000`` ns gives the float nearest to
    ``k * 0.033`` s for every k, with no accumulated drift.
    """
    return t_ns / 1e9


#: (unit, time in ns) of every unit that asked to end the simulation (FMI 2.0 fmi2Terminated,
#: FMI 3.0 terminateSimulation) since the execution cleared it; the step it ends is complete
ENDED: List[tuple] = []
#: this is a worker process (orchestrator/remote.py): see FmuInstance._ended
IN_WORKER = False

#: parsed model descriptions by (path, mtime, size): a scenario reads each FMU at check time
#: and again when it instantiates it, often several instances of one FMU
_MODELS: Dict[tuple, tuple] = {}


def step_error(unit: str, t_ns: int, h_ns: int, instance_ns: int) -> FmuCallError:
    """The master's mistake in a ``doStep`` (a step <= 0, or a start time that is not the
    instance's time, ns), as the error every instance raises for it (its condition is tested
    inline by the callers: this builds the message only)."""
    if h_ns <= 0:
        return FmuCallError(unit, "doStep", t_ns, 3, f"step size {h_ns} ns must be > 0")
    return FmuCallError(unit, "doStep", t_ns, 3, f"master time {t_ns} ns differs from the instance time {instance_ns} ns")


def forget_python_code(folder: Path) -> int:
    """Drop the Python modules and ``sys.path`` entries that live under ``folder``.

    A pythonfmu FMU runs in this interpreter: loading it puts its ``resources/`` on ``sys.path``
    and imports its modules from there. When the run's extraction folder is removed, those module
    objects would stay in ``sys.modules`` pointing at deleted files, and a later run of the same
    FMU in this process (a sweep worker, a benchmark) would reuse them and fail on its first
    lazy import of a sibling module. Call this after the instances are freed, before the folder
    goes. Returns the number of modules dropped.

    A module is under ``folder`` when its file (or package path) starts with one of the folder's
    spellings: as given, absolute, resolved, or a ``sys.path`` entry that resolves into it (the
    spelling its modules were found through). Only the few ``sys.path`` entries are resolved (not
    every loaded module's file): ~0.3 ms per call instead of ~4 ms.
    """
    import sys

    folder = Path(folder)
    real = os.path.join(os.path.realpath(folder), "")
    spellings = {os.path.join(str(p), "") for p in (folder, folder.absolute())} | {real}
    inside_path = []   # the sys.path entries to drop
    for entry in sys.path:
        try:
            spelled = os.path.join(os.fspath(entry), "")
        except TypeError:
            continue
        if spelled.startswith(tuple(spellings)) or os.path.join(os.path.realpath(spelled), "").startswith(real):
            inside_path.append(entry)
            spellings.add(spelled)
    prefixes = tuple(spellings)

    def inside(p) -> bool:
        try:
            return p is not None and os.fspath(p).startswith(prefixes)
        except TypeError:
            return False

    def module_inside(m) -> bool:
        file = getattr(m, "__file__", None)
        if file is not None:   # a module, or a package by its __init__ (its __path__ is that folder)
            return inside(file)
        # a namespace package: the folders of its last search (``_NamespacePath._path``, as
        # iterating would search sys.path again: a listdir per entry) when it has them
        path = getattr(m, "__path__", None)   # (no truth test: len() searches too)
        return path is not None and any(inside(p) for p in list(getattr(path, "_path", path)))

    names = [n for n, m in list(sys.modules.items()) if module_inside(m)]
    for n in names:
        del sys.modules[n]
    dropped = set(map(id, inside_path))
    sys.path[:] = [p for p in sys.path if id(p) not in dropped]
    importlib.invalidate_caches()
    return len(names)


def clear_caches() -> None:
    """Forget parsed model descriptions and shared extractions (as in a fresh process)."""
    _MODELS.clear()
    _EXTRACTED.clear()


def read_model(path: Path, unit: str):
    """Read and validate an FMU's model description without instantiating it.

    A file read before (same path, modification time and size) is not parsed again.

    Returns
    -------
    (fmpy ModelDescription, dict of name -> VarInfo)
    """
    try:
        st = os.stat(path)
        key = (os.path.abspath(path), st.st_mtime_ns, st.st_size)
    except OSError:
        key = None
    if key in _MODELS:
        md, variables = _MODELS[key]
        return md, dict(variables)
    md, variables = _read_model(path, unit)
    if key is not None:
        if len(_MODELS) >= 64:
            _MODELS.clear()
        _MODELS[key] = md, variables
    return md, dict(variables)


def _read_model(path: Path, unit: str):
    import fmpy
    from fmpy.model_description import ValidationError

    if not zipfile.is_zipfile(path):
        raise FmuLoadError(f"unit {unit}: FMU file {path} is not a valid zip archive (corrupt or not an FMU)")
    try:
        md = fmpy.read_model_description(str(path), validate=True)
    except ValidationError as exc:
        raise FmuLoadError(f"unit {unit}: {path}: invalid modelDescription.xml: {exc}") from exc
    except Exception as exc:
        raise FmuLoadError(f"unit {unit}: {path}: cannot read modelDescription.xml: {exc}") from exc
    if md.fmiVersion.startswith("3"):
        from . import fmi3

        fmi3.check_supported(md, path, unit)
    if md.coSimulation is None:
        raise FmuLoadError(f"unit {unit}: {path} is not a co-simulation FMU")
    check_archive(path, md, unit)
    if md.fmiVersion.startswith("3"):
        return md, fmi3.variables(md)
    variables = {}
    for v in md.modelVariables:
        variables[v.name] = VarInfo(v.name, v.valueReference, v.type, v.causality or "local",
                                    v.variability or "", _unit_of(v), v.start, v.description or "",
                                    initial=v.initial or "")
    return md, variables


def _unit_of(v: Any) -> str:
    """A model variable's unit, or its declared type's."""
    declared = getattr(v, "declaredType", None)
    return v.unit or (getattr(declared, "unit", None) if declared is not None else None) or ""


#: extracted FMUs by (FMU path, mtime, size, parent of the unzip folder): see FmuInstance._extract
_EXTRACTED: Dict[tuple, str] = {}

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
        Where to extract; a temporary folder by default. Instances of one FMU file given
        folders with the same parent share the first one's extraction when the FMU allows
        several instances per process.
    """

    #: loaded in this process (a unit in a worker process is a ``remote.RemoteInstance``)
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
        self._instantiate(md)

    def _extract(self, md: Any, unzip_dir: Optional[Path]) -> str:
        """Extract the FMU, or reuse the folder a sibling instance of the same file extracted.

        Instances whose ``unzip_dir`` share a parent folder (one run) load one extraction of
        an FMU that may be instantiated several times per process (FMI 2.0
        ``canBeInstantiatedOnlyOncePerProcess = false``, FMI 3.0 likewise), as other masters
        do; an FMU that may not gets its own copy (a library loaded from another path).
        """
        import fmpy

        once = bool(getattr(md.coSimulation, "canBeInstantiatedOnlyOncePerProcess", False))
        key = None
        if unzip_dir is not None and not once:
            st = os.stat(self.path)
            key = (os.path.abspath(self.path), st.st_mtime_ns, st.st_size, os.path.abspath(Path(unzip_dir).parent))
            done = _EXTRACTED.get(key)
            if done is not None and os.path.isfile(os.path.join(done, "modelDescription.xml")):
                return done
        try:
            folder = fmpy.extract(str(self.path), unzipdir=str(unzip_dir) if unzip_dir else None)
        except Exception as exc:
            raise FmuLoadError(f"unit {self.name}: cannot extract {self.path}: {exc}") from exc
        if key is not None:
            if len(_EXTRACTED) >= 256:
                _EXTRACTED.clear()
            _EXTRACTED[key] = folder
        return folder

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
        self._component = self.fmu.component
        gen = getattr(self.model_description, "generationTool", None) or ""
        #: the FMU runs Python code in this interpreter (pythonfmu): its hot functions are
        #: called without releasing the GIL, which the FMU would take back at once
        self.in_process_python = gen.startswith("PythonFMU")
        if self._fmi2:
            self._c_component = ctypes.c_void_p(self._component)
            self._c_t, self._c_h, self._h_ns = ctypes.c_double(), ctypes.c_double(), None
            self._c_true = ctypes.c_int(1)  # noSetFMUStatePriorToCurrentPoint
            self._do_step = self._fast_function("fmi2DoStep")
            self._set_real = self._fast_function("fmi2SetReal")
        else:
            from .fmi3 import stepper

            self._c_component = ctypes.c_void_p(self._component)
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
        execution ends the run after this step). A unit in a worker process cannot end the run
        cleanly (its reply carries outputs only): there it is an error that says so."""
        if IN_WORKER:
            raise FmuCallError(self.name, "doStep", self.t_ns, 2,
                               f"the unit asked to end the simulation at t = {t_ns / 1e9:.9g} s; a unit in a "
                               f"worker process cannot end the run cleanly: run it in the master's (process = 0)")
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


class ValueReader:
    """Reads a fixed set of FMI 2.0 variables with one FMI call per type family (FMI 3.0:
    :class:`.fmi3.Reader`).

    ``names`` is reordered by family (floats, integers, booleans, strings) and :meth:`read`
    returns the values in that order, so a step costs one ``fmi2GetReal`` (plus one
    ``fmi2GetInteger``/``fmi2GetBoolean`` when such variables are read) into pre-built buffers,
    converted to Python values through NumPy views of those buffers.

    Parameters
    ----------
    inst : FmuInstance
    names : sequence of str
    check_finite : bool
        :meth:`read` raises :class:`~immersim.orchestrator.errors.NonFiniteOutputError` when
        a Real read is NaN or infinite (the master's check before a value is used or logged).
    """

    _ORDER = {"float": 0, "int": 1, "bool": 2, "string": 3}

    def __init__(self, inst: FmuInstance, names: Sequence[str], check_finite: bool = False) -> None:
        self.inst = inst
        self.check_finite = check_finite
        infos = sorted((inst.var(n) for n in dict.fromkeys(names)), key=lambda v: self._ORDER.get(v.family, 3))
        self.names = [v.name for v in infos]
        self.fmi2 = inst.fmi_version.startswith("2")
        fam = [v.family for v in infos]
        self.n_real = fam.count("float")
        n_int, n_bool = fam.count("int"), fam.count("bool")
        #: (FMI function, value references, count as c_size_t, buffer, NumPy view, function name,
        #: as Boolean?)
        self._groups = []
        start = 0
        for n, getter, ctype, dtype, as_bool in ((self.n_real, "fmi2GetReal", ctypes.c_double, np.float64, False),
                                                 (n_int, "fmi2GetInteger", ctypes.c_int, np.int32, False),
                                                 (n_bool, "fmi2GetBoolean", ctypes.c_int, np.int32, True)):
            if n:
                vrs = (ctypes.c_uint * n)(*[v.vr for v in infos[start:start + n]])
                buf = (ctype * n)()
                fn = inst._fast_function(getter) if self.fmi2 else None
                self._groups.append((fn, vrs, ctypes.c_size_t(n), buf, np.frombuffer(buf, dtype=dtype), getter,
                                     as_bool))
            start += n
        self._strings = [v.name for v in infos[start:]]
        if self.fmi2 and not n_int and not self._strings and self._groups:
            self.read = self._reals_and_booleans_reader()  # the common layout, straight-line code

    def _reals_and_booleans_reader(self) -> Callable[[], List[Any]]:
        """:meth:`read` for Reals and/or Booleans only: one or two calls, no loop."""
        inst, comp, check = self.inst, self.inst._c_component, self.check_finite
        isfinite = math.isfinite
        groups = self._groups
        if len(groups) == 2:
            (f1, v1, n1, b1, view1, name1, _), (f2, v2, n2, b2, view2, name2, _) = groups

            def read() -> List[Any]:
                try:
                    status = f1(comp, v1, n1, b1)
                    if status > 1:
                        inst._check(name1, status)
                    status = f2(comp, v2, n2, b2)
                    if status > 1:
                        inst._check(name2, status)
                except FmuCallError:
                    raise
                except Exception as exc:
                    raise inst._raised(f"{name1}/{name2}", exc) from None
                out = view1.tolist()
                if check and not isfinite(sum(out)):
                    self._raise_nonfinite(out)
                if one_bool:
                    out.append(b2[0] != 0)
                else:
                    out += map(bool, view2.tolist())
                return out
            one_bool = n2.value == 1  # e.g. an at_rest flag: no map over a one-element list
            return read
        (f1, v1, n1, b1, view1, name1, as_bool), = groups

        def read_one() -> List[Any]:
            try:
                status = f1(comp, v1, n1, b1)
            except Exception as exc:
                raise inst._raised(name1, exc) from None
            if status > 1:
                inst._check(name1, status)
            if as_bool:
                return list(map(bool, view1.tolist()))
            out = view1.tolist()
            if check and not isfinite(sum(out)):
                self._raise_nonfinite(out)
            return out
        return read_one

    def read(self) -> List[Any]:
        """Current values, in the order of ``self.names`` (Reals as float, Integers as int,
        Booleans as bool)."""
        inst = self.inst
        comp = inst._c_component
        out: List[Any] = []
        for fn, vrs, n, buf, view, getter, as_bool in self._groups:
            try:
                status = fn(comp, vrs, n, buf)
            except Exception as exc:
                raise inst._raised(getter, exc) from None
            if status > 1:
                inst._check(getter, status)
            out += [v != 0 for v in view.tolist()] if as_bool else view.tolist()
        if self.check_finite and self.n_real and not math.isfinite(sum(out[:self.n_real])):
            self._raise_nonfinite(out)
        if self._strings:
            out.extend(inst.get_values(self._strings))
        return out

    def _raise_nonfinite(self, values: Sequence[Any]) -> None:
        bad = self.nonfinite(values)
        if bad is not None:
            from .errors import NonFiniteOutputError

            inst = self.inst
            raise NonFiniteOutputError(
                f"unit {inst.name}: output {bad} = {values[self.names.index(bad)]} "
                f"at t = {inst.t_ns / 1e9:.9g} s is not finite")

    def nonfinite(self, values: Sequence[Any]) -> Optional[str]:
        """Name of the first NaN/inf Real among ``values`` (as returned by :meth:`read`), or None.

        The sum of finite floats is finite unless it overflows, so one ``sum`` screens the
        common case; only a non-finite sum triggers the element-wise search.
        """
        n = self.n_real
        if not n or math.isfinite(sum(values[:n]) if n < len(values) else sum(values)):
            return None
        for i in range(n):
            if not math.isfinite(values[i]):
                return self.names[i]
        return None


class RealSetter:
    """Sets a fixed list of FMI 2.0 Real variables from a sequence of values (one FMI call)."""

    def __init__(self, inst: FmuInstance, names: List[str]) -> None:
        self.inst = inst
        self.names = names
        self._vrs = (ctypes.c_uint * len(names))(*[inst.var(n).vr for n in names])
        self._buf = (ctypes.c_double * len(names))()
        self._n = ctypes.c_size_t(len(names))
        self.set = self._fmi2_setter()  # a closure: no attribute look-ups per call

    def _fmi2_setter(self) -> Callable[[Sequence[float]], None]:
        inst, fn, comp, vrs, n, buf = self.inst, self.inst._set_real, self.inst._c_component, self._vrs, self._n, self._buf

        def set_values(values: Sequence[float]) -> None:
            buf[:] = values
            try:
                status = fn(comp, vrs, n, buf)
            except Exception as exc:
                raise inst._raised("fmi2SetReal", exc) from None
            if status > 1:
                inst._check("fmi2SetReal", status)
        return set_values

    def set(self, values: Sequence[float]) -> None:
        """Set the values (in the order of ``names``) with one ``fmi2SetReal``: the
        :meth:`_fmi2_setter` closure replaces this method at construction (FMI 3.0 units use
        :class:`.fmi3.Setter`)."""
        raise NotImplementedError


class DiscreteSetter:
    """Sets a fixed list of Integer and Boolean variables (FMI 2.0: one ``fmi2SetInteger`` and
    one ``fmi2SetBoolean``), e.g. the connected Boolean inputs of a step; other variables and
    FMI 3.0 go through :meth:`FmuInstance.set_values`.

    Parameters
    ----------
    inst : FmuInstance
    names : list of str
        :meth:`set` takes the values in this order.
    """

    def __init__(self, inst: FmuInstance, names: List[str]) -> None:
        self.inst = inst
        self.names = names
        fams = [inst.var(n).family for n in names]
        #: (FMI function name, fast function, positions in ``names``, value references, count, buffer)
        self._groups = []
        self._fast = inst._fmi2 and all(f in ("int", "bool") for f in fams)
        if self._fast:
            for fam, fn in (("int", "fmi2SetInteger"), ("bool", "fmi2SetBoolean")):
                pos = [i for i, f in enumerate(fams) if f == fam]
                if pos:
                    self._groups.append((fn, inst._fast_function(fn), pos,
                                         (ctypes.c_uint * len(pos))(*[inst.var(names[i]).vr for i in pos]),
                                         ctypes.c_size_t(len(pos)), (ctypes.c_int * len(pos))()))

    def set(self, values: Sequence[Any]) -> None:
        """Set the values (in the order of ``names``); Booleans as 0/1, Integers as int."""
        if not self._fast:
            self.inst.set_values(dict(zip(self.names, values)))
            return
        inst, comp = self.inst, self.inst._c_component
        for name, fn, pos, vrs, n, buf in self._groups:
            buf[:] = [int(values[i]) for i in pos]
            try:
                status = fn(comp, vrs, n, buf)
            except Exception as exc:
                raise inst._raised(name, exc) from None
            if status > 1:
                inst._check(name, status)


def is_finite(value: Any) -> bool:
    return not isinstance(value, float) or math.isfinite(value)


def check_archive(path: Path, md: Any, unit: str) -> None:
    """Refuse at load an FMU whose archive cannot run here: no binary of its
    ``modelIdentifier`` for this platform (FMI 2.0 ``binaries/linux64/<id>.so``, FMI 3.0
    ``binaries/x86_64-linux/<id>.so``), or, for a pythonfmu FMU, a ``resources/slavemodule.txt``
    that is missing, empty or names a module the archive lacks (pythonfmu's binary crashes the
    process on those). Raises :class:`~immersim.orchestrator.errors.FmuLoadError`."""
    import fmpy

    with zipfile.ZipFile(path) as z:
        names = set(z.namelist())
        mid = md.coSimulation.modelIdentifier
        folder = fmpy.platform if md.fmiVersion.startswith("2") else fmpy.platform_tuple
        binary = f"binaries/{folder}/{mid}{fmpy.sharedLibraryExtension}"
        if binary not in names:
            have = sorted({n.split("/")[1] for n in names if n.startswith("binaries/") and n.count("/") >= 2})
            others = sorted(n for n in names if n.startswith(f"binaries/{folder}/") and not n.endswith("/"))
            raise FmuLoadError(
                f"unit {unit}: FMU {path} has no binary for {folder}: "
                f"{binary} (modelIdentifier {mid!r}) is not in the archive"
                + (f"; it has {', '.join(others)}" if others else f"; platforms: {', '.join(have) or 'none'}"))
        if (getattr(md, "generationTool", None) or "").startswith("PythonFMU"):
            where = f"unit {unit}: pythonfmu FMU {path}"
            if "resources/slavemodule.txt" not in names:
                raise FmuLoadError(f"{where}: resources/slavemodule.txt is missing (it names the slave's module)")
            module = z.read("resources/slavemodule.txt").decode("utf-8", "replace").strip()
            if not module:
                raise FmuLoadError(f"{where}: resources/slavemodule.txt names no module")
            if f"resources/{module}.py" not in names:
                raise FmuLoadError(f"{where}: resources/{module}.py is missing (named by resources/slavemodule.txt)")
