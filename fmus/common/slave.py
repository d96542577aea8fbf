"""Base class of every immersim FMU: a pythonfmu ``Fmi2Slave`` driven by a :class:`Var` table.

A unit subclasses :class:`TableSlave`, sets ``VARIABLES`` (and ``modelName``), and implements

``setup_model()``
    called when initialization mode ends; parameters are in ``self.values``.
``step_model(t, h)``
    advance the model from ``t`` to ``t + h`` seconds; read inputs from and write outputs
    into ``self.values``.
``get_model_state()`` / ``set_model_state(state)``
    optional; when a unit implements them it sets ``CAN_HANDLE_STATE = True`` and the FMU
    declares ``canGetAndSetFMUstate``. The returned state must cover every hidden state
    (solver, collision cache, network queues); otherwise the unit leaves the flag False and
    the FMU declares it cannot.

The base class checks the master (current time must be the end of the previous step, step
size > 0, following the FMI Reference-FMUs), rejects NaN/inf inputs and refuses to hand out
non-finite outputs, each with a message naming instance, variable and time. An exception
raised in ``fmi2DoStep`` makes the pythonfmu binary return ``fmi2Discard``; its text reaches
the master's logger. What the packed models log (Python ``logging``) while an instance sets up
or steps goes to that instance's FMI logger (status ok, warning for warnings and above), not
to the logging of the process that loaded the FMU.

``get_real`` / ``set_real`` resolve each distinct list of value references once (a master asks
for the same list every step) into an ``operator.itemgetter`` over ``self.values``; inputs are
checked only after a non-finite value arrives, outputs by one sum. A step that changed no
output returns :data:`OUTPUTS_UNCHANGED` from ``step_model`` and skips the output check.
"""
from __future__ import annotations

import copy
import logging
import math
import pickle
import threading
from operator import itemgetter
from typing import Any, Callable, ClassVar, Dict, List, Sequence, Tuple
from xml.etree.ElementTree import Element, SubElement

from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability
from pythonfmu.enums import Fmi2Status
from pythonfmu.variables import Boolean, Integer, Real, String

from .variables import Var

_PY_TYPES = {"Real": Real, "Integer": Integer, "Boolean": Boolean, "String": String}
_CAST = {"Real": float, "Integer": int, "Boolean": bool, "String": str}

#: returned by ``step_model`` when the step changed no output (the base class then skips the
#: output check); any other return value (``None``) means outputs may have changed
OUTPUTS_UNCHANGED = True
#: distinct value-reference lists remembered per type (a master uses a handful)
_CACHE_LIMIT = 256


def _tuple_getter(names: Sequence[str]) -> Callable[[Dict[str, Any]], tuple]:
    """``values -> tuple of values[name] for name in names`` (an ``itemgetter`` for >= 2)."""
    if len(names) >= 2:
        return itemgetter(*names)
    if len(names) == 1:
        name = names[0]
        return lambda values: (values[name],)
    return lambda values: ()


def _first_nonfinite(names: Sequence[str], values: Dict[str, Any]):
    """(name, value) of the first non-finite Real among ``names``, or None."""
    for name in names:
        value = values[name]
        if not math.isfinite(value):
            return name, value
    return None


class _FmiLog(logging.Handler):
    """Records of the packed package's loggers, handed to the FMI logger of the instance that is
    setting up or stepping in this thread (:meth:`TableSlave.exit_initialization_mode`,
    :meth:`TableSlave.do_step`); a record outside those calls is dropped."""

    def __init__(self) -> None:
        super().__init__()
        self.active = threading.local()

    def emit(self, record: logging.LogRecord) -> None:
        slave = getattr(self.active, "slave", None)
        if slave is not None:
            slave.log(record.getMessage(), Fmi2Status.warning if record.levelno >= logging.WARNING else Fmi2Status.ok)


#: the package a unit is packed with (``immersim_<digest>``): its loggers end at the FMI
#: logger; the ``immersim`` package itself (the slave imported from it, as tests do) keeps its own.
#: A package imported again (a later run in this process) replaces its earlier handler.
_PACKAGE = __name__.split(".")[0]
_FMI_LOG = _FmiLog()
if _PACKAGE != "immersim":
    _logger = logging.getLogger(_PACKAGE)
    for _old in [h for h in _logger.handlers if type(h).__name__ == "_FmiLog"]:
        _logger.removeHandler(_old)
    _logger.addHandler(_FMI_LOG)
    _logger.propagate = False


class FmuInputError(ValueError):
    """A master handed an FMU a bad value (NaN, inf, out of range) or a bad time."""


class FmuModelError(RuntimeError):
    """The model failed inside a step (solver failure, non-finite output)."""


class TableSlave(Fmi2Slave):
    """pythonfmu slave whose interface is generated from ``VARIABLES``."""

    VARIABLES: ClassVar[Tuple[Var, ...]] = ()
    CAN_HANDLE_STATE: ClassVar[bool] = False
    #: relative tolerance when checking the master's ``current_time``
    TIME_RTOL: ClassVar[float] = 1e-9

    author = "immersim"
    license = "MIT"
    version = "0.1.0"

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.values: Dict[str, Any] = {}
        self._vars: List[Var] = []
        self._time = 0.0
        self._real_inputs: List[str] = []
        self._real_outputs: List[str] = []
        self._initialized = False
        for var in self.VARIABLES:
            self._declare(var)
        #: name and type of each value reference (pythonfmu numbers variables 0, 1, ... in order)
        types = {v.name: v.type for v in self._vars}
        self._vr_name: List[str] = [self.vars[vr].name for vr in range(len(self.vars))]
        self._vr_type: List[str] = [types.get(name, "") for name in self._vr_name]
        self._get_cache: Dict[str, Dict[tuple, Callable]] = {"Real": {}, "Integer": {}, "Boolean": {}}
        self._set_cache: Dict[tuple, List[str]] = {}  # set_real: Real only
        self._inputs_getter = _tuple_getter(self._real_inputs)
        self._outputs_getter = _tuple_getter(self._real_outputs)
        #: a non-finite value may be among the inputs (set since the last passed input check)
        self._check_inputs = True

    # -- declaration -------------------------------------------------------------------
    def _declare(self, var: Var) -> None:
        if var.name in self.values:
            raise ValueError(f"{type(self).__name__}: variable {var.name!r} declared twice")
        self.values[var.name] = _CAST[var.type](var.start)
        self._vars.append(var)
        name, cast, values = var.name, _CAST[var.type], self.values
        py_var = _PY_TYPES[var.type](
            var.name,
            causality=getattr(Fmi2Causality, var.causality),
            variability=getattr(Fmi2Variability, var.effective_variability),
            description=var.description or None,
            getter=lambda: values[name],
            setter=lambda value: values.__setitem__(name, cast(value)),
        )
        self.register_variable(py_var, nested=False)
        if var.type == "Real" and var.causality == "input":
            self._real_inputs.append(var.name)
        if var.type == "Real" and var.causality == "output":
            self._real_outputs.append(var.name)

    # -- model description --------------------------------------------------------------
    def to_xml(self, model_options: Dict[str, str] = dict()) -> Element:  # noqa: B006 (pythonfmu signature)
        root = super().to_xml(model_options)
        cosim = root.find("CoSimulation")
        cosim.set("canGetAndSetFMUstate", str(self.CAN_HANDLE_STATE).lower())
        cosim.set("canSerializeFMUstate", str(self.CAN_HANDLE_STATE).lower())
        cosim.set("canHandleVariableCommunicationStepSize", "true")
        cosim.set("canBeInstantiatedOnlyOncePerProcess", "false")
        units = sorted({v.unit for v in self._vars if v.unit and v.type == "Real"})
        if units:
            unit_defs = Element("UnitDefinitions")
            for u in units:
                SubElement(unit_defs, "Unit", name=u)
            # UnitDefinitions must follow CoSimulation and precede LogCategories
            root.insert(list(root).index(cosim) + 1, unit_defs)
        by_name = {v.name: v for v in self._vars}
        outputs: List[int] = []
        for i, sv in enumerate(root.find("ModelVariables"), start=1):
            var = by_name[sv.get("name")]
            typed = sv[0]
            if var.unit and var.type == "Real":
                typed.set("unit", var.unit)
            if var.causality == "output":  # initial="calculated" (the default): set by setup_model
                outputs.append(i)
        structure = root.find("ModelStructure")
        for child in list(structure):
            structure.remove(child)
        if outputs:
            out = SubElement(structure, "Outputs")
            for i in outputs:
                SubElement(out, "Unknown", index=str(i))
            init = SubElement(structure, "InitialUnknowns")
            for i in outputs:
                SubElement(init, "Unknown", index=str(i))
        return root

    # -- FMI life cycle ---------------------------------------------------------------
    def setup_experiment(self, start_time: float, stop_time: float | None, tolerance: float | None) -> None:
        self._time = float(start_time)
        self.tolerance = tolerance

    def exit_initialization_mode(self) -> None:
        for var in self._vars:
            if var.type == "Real" and var.causality in ("parameter", "input"):
                value = self.values[var.name]
                if not math.isfinite(value):
                    raise FmuInputError(
                        f"{self.instance_name}: {var.causality} {var.name} = {value} is not finite "
                        f"at initialization (t = {self._time:g} s)")
        _FMI_LOG.active.slave = self
        try:
            self.setup_model()
        finally:
            _FMI_LOG.active.slave = None
        self._initialized = True

    def do_step(self, current_time: float, step_size: float) -> bool:
        """One communication step. A failure is logged with status error (naming instance,
        variable and time) and returned as ``False``: the pythonfmu binary then reports a
        failed step instead of a fatal Python exception that would poison the instance."""
        _FMI_LOG.active.slave = self
        try:
            self._check_master(current_time, step_size)
            if self.step_model(current_time, step_size) is not OUTPUTS_UNCHANGED:
                self._check_outputs(current_time + step_size)
        except Exception as exc:
            self.log(f"{type(exc).__name__}: {exc}", Fmi2Status.error)
            self.failed = f"{type(exc).__name__}: {exc}"
            return False
        finally:
            _FMI_LOG.active.slave = None
        self._time = current_time + step_size
        return True

    def _check_master(self, t: float, h: float) -> None:
        if not h > 0.0:
            raise FmuInputError(f"{self.instance_name}: communication step size {h!r} s at t = {t:g} s must be > 0")
        if abs(t - self._time) > self.TIME_RTOL * max(1.0, abs(self._time)):
            raise FmuInputError(
                f"{self.instance_name}: doStep current time t = {t!r} s but the FMU is at t = {self._time!r} s")
        if self._check_inputs:
            bad = self._nonfinite(self._real_inputs, self._inputs_getter)
            if bad is not None:
                raise FmuInputError(f"{self.instance_name}: input {bad[0]} = {bad[1]} at t = {t:g} s is not finite")
            self._check_inputs = False

    def _check_outputs(self, t: float) -> None:
        bad = self._nonfinite(self._real_outputs, self._outputs_getter)
        if bad is not None:
            raise FmuModelError(f"{self.instance_name}: output {bad[0]} = {bad[1]} at t = {t:g} s is not finite")

    def _nonfinite(self, names: List[str], getter: Callable[[Dict[str, Any]], tuple]):
        """(name, value) of the first non-finite value of ``names``, or None.

        One ``sum`` screens the common case (a sum of finite floats is finite unless it
        overflows); only a non-finite sum, or a term ``sum`` cannot add, triggers the
        element-wise search (which names the variable, or raises ``TypeError`` for a value
        that is not a number)."""
        try:
            if math.isfinite(sum(getter(self.values))):
                return None
        except TypeError:
            pass
        return _first_nonfinite(names, self.values)

    # -- fast bulk access (pythonfmu calls these once per fmi2Get/Set call) -------------
    def _getter(self, kind: str, vrs: Sequence[int]) -> Callable[[Dict[str, Any]], tuple]:
        """The cached ``values -> tuple`` reader of ``vrs`` (variables of type ``kind``)."""
        key = tuple(vrs)
        cache = self._get_cache[kind]
        get = cache.get(key)
        if get is None:
            get = _tuple_getter(self._names_of(kind, key))
            if len(cache) >= _CACHE_LIMIT:
                cache.clear()
            cache[key] = get
        return get

    def _names_of(self, kind: str, vrs: Sequence[int]) -> List[str]:
        names, types = self._vr_name, self._vr_type
        out = []
        for vr in vrs:
            if not 0 <= vr < len(names):
                raise KeyError(f"{self.instance_name}: no variable with valueReference {vr}")
            if types[vr] != kind:
                raise TypeError(f"{self.instance_name}: valueReference {vr} ({names[vr]}) is not {kind}")
            out.append(names[vr])
        return out

    def get_real(self, vrs: List[int]) -> List[float]:
        # pythonfmu converts each item with PyFloat_AsDouble (ints, bools and numpy scalars
        # included); the output check has made sure each output is a number
        get = self._get_cache["Real"].get(tuple(vrs)) or self._getter("Real", vrs)
        return list(get(self.values))

    def get_integer(self, vrs: List[int]) -> List[int]:
        get = self._get_cache["Integer"].get(tuple(vrs)) or self._getter("Integer", vrs)
        return list(map(int, get(self.values)))

    def get_boolean(self, vrs: List[int]) -> List[bool]:
        get = self._get_cache["Boolean"].get(tuple(vrs)) or self._getter("Boolean", vrs)
        return list(map(bool, get(self.values)))

    def set_real(self, vrs: List[int], values_in: List[float]) -> None:
        key = tuple(vrs)
        names = self._set_cache.get(key)
        if names is None:
            names = self._names_of("Real", key)
            if len(self._set_cache) >= _CACHE_LIMIT:
                self._set_cache.clear()
            self._set_cache[key] = names
        new = list(map(float, values_in))
        if len(new) != len(names):
            raise ValueError(f"{self.instance_name}: set_real got {len(new)} values for {len(names)} references")
        self.values.update(zip(names, new))
        if not math.isfinite(sum(new)):
            self._check_inputs = True

    # -- FMU state ---------------------------------------------------------------------
    def _get_fmu_state(self) -> Dict[str, Any]:
        if not self.CAN_HANDLE_STATE:
            raise NotImplementedError(f"{self.instance_name}: this FMU cannot get/set its state")
        return {"values": dict(self.values), "time": self._time,
                "model": copy.deepcopy(self.get_model_state())}

    def _set_fmu_state(self, state: Dict[str, Any]) -> None:
        if not self.CAN_HANDLE_STATE:
            raise NotImplementedError(f"{self.instance_name}: this FMU cannot get/set its state")
        self.values.update(state["values"])
        self._check_inputs = True
        self._time = state["time"]
        self.set_model_state(copy.deepcopy(state["model"]))

    @staticmethod
    def _fmu_state_to_bytes(state: Dict[str, Any]) -> bytes:
        return pickle.dumps(state)

    @staticmethod
    def _fmu_state_from_bytes(state: bytes) -> Dict[str, Any]:
        return pickle.loads(state)

    # -- to be provided by units -------------------------------------------------------
    def setup_model(self) -> None:
        """Build the model from the parameters in ``self.values`` and set initial outputs."""

    def step_model(self, t: float, h: float) -> Any:  # pragma: no cover - abstract
        """Advance the model from ``t`` to ``t + h`` (s). Return :data:`OUTPUTS_UNCHANGED` when
        no output changed in the step (skips the output check), else ``None``."""
        raise NotImplementedError

    def get_model_state(self) -> Any:
        raise NotImplementedError

    def set_model_state(self, state: Any) -> None:
        raise NotImplementedError
