"""One wrapper for every FMU call: load, instantiate, get/set by name, step.

Any FMI 2.0 or 3.0 co-simulation FMU is loaded through FMPy. Every FMI function goes through
:meth:`FmuInstance._call`, which checks the returned status and raises
:class:`~immersim.orchestrator.errors.FmuCallError` naming the instance, the function, the
simulation time and the last message the FMU logged (FMPy's ``_call`` pattern). The hot
functions (get/set Real, doStep) use pre-built ctypes buffers so a macro step costs a few
microseconds of master overhead.

Time is handled in integer nanoseconds and converted to seconds only here, at the FMI call.
"""
from __future__ import annotations

import ctypes
import logging
import math
import weakref
import zipfile
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Deque, Dict, List, Optional, Sequence

import numpy as np

from .errors import FmuCallError, FmuLoadError

log = logging.getLogger(__name__)

#: type families that may be connected to each other
_FAMILY = {
    "Real": "float", "Float64": "float", "Float32": "float",
    "Integer": "int", "Enumeration": "int", "Int8": "int", "UInt8": "int", "Int16": "int",
    "UInt16": "int", "Int32": "int", "UInt32": "int", "Int64": "int", "UInt64": "int",
    "Boolean": "bool", "String": "string",
}
_STATUS = ["ok", "warning", "discard", "error", "fatal", "pending"]


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

    @property
    def family(self) -> str:
        return _FAMILY.get(self.type, self.type)


def ns_to_s(t_ns: int) -> float:
    """Integer nanoseconds to seconds (the only place the master converts time).

    Division by 1e9 is correctly rounded, so ``k * 33_000_000`` ns gives the float nearest to
    ``k * 0.033`` s for every k, with no accumulated drift.
    """
    return t_ns / 1e9


def read_model(path: Path, unit: str):
    """Read and validate an FMU's model description without instantiating it.

    Returns
    -------
    (fmpy ModelDescription, dict of name -> VarInfo)
    """
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
    if md.coSimulation is None:
        raise FmuLoadError(f"unit {unit}: {path} is not a co-simulation FMU")
    variables = {}
    for v in md.modelVariables:
        declared = getattr(v, "declaredType", None)
        unit_str = v.unit or (getattr(declared, "unit", None) if declared is not None else None) or ""
        variables[v.name] = VarInfo(v.name, v.valueReference, v.type, v.causality or "local",
                                    v.variability or "", unit_str, v.start, v.description or "")
    return md, variables


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
        Where to extract; a temporary folder by default.
    """

    def __init__(self, name: str, path: Path | str, unzip_dir: Optional[Path] = None) -> None:
        import fmpy

        self.name = name
        self.path = Path(path)
        self.t_ns = 0
        self.fatal = False
        self.messages: Deque[str] = deque(maxlen=20)
        if not self.path.exists():
            raise FmuLoadError(f"unit {name}: FMU file {self.path} does not exist")
        md, self.variables = read_model(self.path, name)
        self.model_description = md
        self.fmi_version = md.fmiVersion
        try:
            self.unzip_dir = fmpy.extract(str(self.path), unzipdir=str(unzip_dir) if unzip_dir else None)
        except Exception as exc:
            raise FmuLoadError(f"unit {name}: cannot extract {self.path}: {exc}") from exc
        self._instantiate(md)

    # -- loading -----------------------------------------------------------------------
    def _instantiate(self, md: Any) -> None:
        from fmpy.fmi2 import FMU2Slave
        from fmpy.fmi3 import FMU3Slave

        kwargs = dict(guid=md.guid, unzipDirectory=self.unzip_dir,
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName=self.name)
        try:
            if self.fmi_version.startswith("2"):
                self.fmu = FMU2Slave(**kwargs)
                cb = _fmi2_callbacks()
                _BY_NAME[self.name] = self
                self._guard("fmi2Instantiate", lambda: self.fmu.instantiate(callbacks=cb, loggingOn=True))
            elif self.fmi_version.startswith("3"):
                self.fmu = FMU3Slave(**kwargs)
                self._guard("fmi3InstantiateCoSimulation",
                            lambda: self.fmu.instantiate(loggingOn=True, logMessage=self._log3))
            else:
                raise FmuLoadError(f"unit {self.name}: FMI version {self.fmi_version} is not supported (2.0 or 3.0)")
        except FmuCallError as exc:
            raise FmuLoadError(str(exc)) from exc
        except OSError as exc:
            raise FmuLoadError(f"unit {self.name}: cannot load the binary of {self.path}: {exc}") from exc
        self._setup_fast_path()

    def _log3(self, env, status, category, message) -> None:
        self._record(status, message)

    def _record(self, status: int, message: bytes) -> None:
        text = message.decode("utf-8", "replace") if message else ""
        self.messages.append(text)
        level = logging.DEBUG if status == 0 else logging.WARNING if status == 1 else logging.ERROR
        log.log(level, "unit %s [%s]: %s", self.name, _STATUS[status] if status < 6 else status, text)

    def _setup_fast_path(self) -> None:
        self._fmi2 = self.fmi_version.startswith("2")
        self._component = self.fmu.component
        if self._fmi2:
            dll = self.fmu.dll  # fmpy has set argtypes/restype on these ctypes functions
            self._do_step = dll.fmi2DoStep
            self._do_step.argtypes = [ctypes.c_void_p, ctypes.c_double, ctypes.c_double, ctypes.c_int]
            self._do_step.restype = ctypes.c_int
            self._get_real = dll.fmi2GetReal
            self._set_real = dll.fmi2SetReal

    # -- the one checked call ----------------------------------------------------------
    def _guard(self, function: str, thunk) -> Any:
        from fmpy.fmi1 import FMICallException

        try:
            return thunk()
        except FMICallException as exc:
            self.fatal = self.fatal or exc.status == 4
            raise FmuCallError(self.name, function, self.t_ns, exc.status, self._last_message()) from None
        except Exception as exc:
            if isinstance(exc, FmuCallError):
                raise
            raise FmuCallError(self.name, function, self.t_ns, 3, f"{exc} {self._last_message()}".strip()) from None

    def _last_message(self) -> str:
        return self.messages[-1] if self.messages else ""

    def _check(self, function: str, status: int) -> None:
        if status > 1:
            self.fatal = self.fatal or status == 4
            raise FmuCallError(self.name, function, self.t_ns, status, self._last_message())

    # -- life cycle --------------------------------------------------------------------
    def initialize(self, start_ns: int, stop_ns: Optional[int], parameters: Dict[str, Any],
                   tolerance: Optional[float] = None) -> None:
        """Set parameters and start values, enter and exit initialization mode."""
        self.t_ns = start_ns
        t0 = ns_to_s(start_ns)
        t1 = ns_to_s(stop_ns) if stop_ns is not None else None
        if self.fmi_version.startswith("2"):
            self._guard("fmi2SetupExperiment", lambda: self.fmu.setupExperiment(tolerance=tolerance, startTime=t0, stopTime=t1))
            self.set_values(parameters)
            self._guard("fmi2EnterInitializationMode", self.fmu.enterInitializationMode)
            self._guard("fmi2ExitInitializationMode", self.fmu.exitInitializationMode)
        else:
            self.set_values(parameters)
            self._guard("fmi3EnterInitializationMode",
                        lambda: self.fmu.enterInitializationMode(tolerance=tolerance, startTime=t0, stopTime=t1))
            self._guard("fmi3ExitInitializationMode", self.fmu.exitInitializationMode)

    def do_step(self, t_ns: int, h_ns: int) -> None:
        """Advance from ``t_ns`` by ``h_ns`` (integer nanoseconds)."""
        if h_ns <= 0:
            raise FmuCallError(self.name, "doStep", t_ns, 3, f"step size {h_ns} ns must be > 0")
        if t_ns != self.t_ns:
            raise FmuCallError(self.name, "doStep", t_ns, 3,
                               f"master time {t_ns} ns differs from the instance time {self.t_ns} ns")
        if self._fmi2:
            status = self._do_step(self._component, t_ns / 1e9, h_ns / 1e9, 1)  # ns_to_s, inlined
            if status > 1:
                self._check("fmi2DoStep", status)
        else:
            out = self._guard("fmi3DoStep", lambda: self.fmu.doStep(ns_to_s(t_ns), ns_to_s(h_ns)))
            if out[1]:
                raise FmuCallError(self.name, "fmi3DoStep", t_ns, 2, "FMU requested termination")
        self.t_ns = t_ns + h_ns

    def terminate(self) -> None:
        """Terminate and free the instance; errors here are logged, not raised.

        After ``fmi2Fatal`` the FMI standard allows no further call on the instance (and the
        pythonfmu binary crashes on one), so a fatal instance is left alone.
        """
        if self.fatal:
            log.warning("unit %s: not terminated after a fatal error", self.name)
            return
        for fn, call in (("terminate", self.fmu.terminate), ("freeInstance", self.fmu.freeInstance)):
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

    def reader(self, names: Sequence[str]) -> "ValueReader":
        """A fast reader of a fixed list of variables (one FMI call per type family)."""
        return ValueReader(self, list(names))

    def real_setter(self, names: Sequence[str]) -> "RealSetter":
        return RealSetter(self, list(names))


class ValueReader:
    """Reads a fixed list of variables of any types into a Python list, in that order."""

    def __init__(self, inst: FmuInstance, names: List[str]) -> None:
        self.inst, self.names = inst, names
        infos = [inst.var(n) for n in names]
        self.families = [v.family for v in infos]
        fmi2 = inst.fmi_version.startswith("2")
        real_idx = [i for i, v in enumerate(infos) if v.family == "float" and (fmi2 or v.type == "Float64")]
        self._real_idx = real_idx
        self._real_vrs = (ctypes.c_uint * len(real_idx))(*[infos[i].vr for i in real_idx])
        self._real_buf = (ctypes.c_double * len(real_idx))()
        self._real_np = np.frombuffer(self._real_buf, dtype=np.float64) if real_idx else np.zeros(0)
        self._other = [(i, infos[i].name) for i in range(len(infos)) if i not in set(real_idx)]
        self._fast = fmi2 and bool(real_idx)
        self._n_real = len(real_idx)
        self._all_real_fast = self._fast and len(real_idx) == len(names)

    def read(self) -> List[Any]:
        """Current values, in the order of ``names``."""
        inst = self.inst
        if self._all_real_fast:
            status = inst._get_real(inst.fmu.component, self._real_vrs, self._n_real, self._real_buf)
            if status > 1:
                inst._check("fmi2GetReal", status)
            return self._real_np.tolist()
        out: List[Any] = [None] * len(self.names)
        if self._real_idx:
            if self._fast:
                inst._check("fmi2GetReal", inst._get_real(inst.fmu.component, self._real_vrs,
                                                         self._n_real, self._real_buf))
                vals = self._real_np.tolist()
            else:
                vals = inst._guard("fmi3GetFloat64", lambda: inst.fmu.getFloat64(list(self._real_vrs)))
                self._real_np[:] = vals
            for i, val in zip(self._real_idx, vals):
                out[i] = val
        if self._other:
            vals = inst.get_values([n for _, n in self._other])
            for (i, _), val in zip(self._other, vals):
                out[i] = val
        return out

    def nonfinite(self, values: Sequence[Any]) -> Optional[str]:
        """Name of the first NaN/inf Real among ``values`` (as returned by :meth:`read`), or None.

        The sum of finite floats is finite unless it overflows, so one ``sum`` screens the
        common case; only a non-finite sum triggers the element-wise search.
        """
        if not self._real_idx:
            return None
        if self._all_real_fast:
            if math.isfinite(sum(values)):
                return None
        elif math.isfinite(sum(values[i] for i in self._real_idx)):
            return None
        for i in self._real_idx:
            if not math.isfinite(values[i]):
                return self.names[i]
        return None


class RealSetter:
    """Sets a fixed list of float variables from a sequence of values (one FMI call)."""

    def __init__(self, inst: FmuInstance, names: List[str]) -> None:
        self.inst = inst
        self.names = names
        self._vrs = (ctypes.c_uint * len(names))(*[inst.var(n).vr for n in names])
        self._buf = (ctypes.c_double * len(names))()
        self._fmi2 = inst.fmi_version.startswith("2")

    def set(self, values: Sequence[float]) -> None:
        inst = self.inst
        if self._fmi2:
            self._buf[:] = values
            inst._check("fmi2SetReal", inst._set_real(inst.fmu.component, self._vrs, len(self.names), self._buf))
        else:
            inst._guard("fmi3SetFloat64", lambda: inst.fmu.setFloat64(list(self._vrs), list(values)))


def is_finite(value: Any) -> bool:
    return not isinstance(value, float) or math.isfinite(value)
