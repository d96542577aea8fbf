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
non-finite outputs, each with a message naming instance, variable and time. A raised
exception becomes ``fmi2Error`` in the pythonfmu binary and its text reaches the master's
logger.
"""
from __future__ import annotations

import copy
import math
import pickle
from typing import Any, ClassVar, Dict, List, Tuple
from xml.etree.ElementTree import Element, SubElement

from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability
from pythonfmu.enums import Fmi2Status
from pythonfmu.variables import Boolean, Integer, Real, String

from .variables import Var

_PY_TYPES = {"Real": Real, "Integer": Integer, "Boolean": Boolean, "String": String}
_CAST = {"Real": float, "Integer": int, "Boolean": bool, "String": str}


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
        self.setup_model()
        self._initialized = True

    def do_step(self, current_time: float, step_size: float) -> bool:
        """One communication step. A failure is logged with status error (naming instance,
        variable and time) and returned as ``False``: the pythonfmu binary then reports a
        failed step instead of a fatal Python exception that would poison the instance."""
        try:
            self._check_master(current_time, step_size)
            self.step_model(current_time, step_size)
            self._check_outputs(current_time + step_size)
        except Exception as exc:
            self.log(f"{type(exc).__name__}: {exc}", Fmi2Status.error)
            self.failed = f"{type(exc).__name__}: {exc}"
            return False
        self._time = current_time + step_size
        return True

    def _check_master(self, t: float, h: float) -> None:
        if not h > 0.0:
            raise FmuInputError(f"{self.instance_name}: communication step size {h!r} s at t = {t:g} s must be > 0")
        if abs(t - self._time) > self.TIME_RTOL * max(1.0, abs(self._time)):
            raise FmuInputError(
                f"{self.instance_name}: doStep current time t = {t!r} s but the FMU is at t = {self._time!r} s")
        values = self.values
        for name in self._real_inputs:
            value = values[name]
            if not math.isfinite(value):
                raise FmuInputError(f"{self.instance_name}: input {name} = {value} at t = {t:g} s is not finite")

    def _check_outputs(self, t: float) -> None:
        values = self.values
        for name in self._real_outputs:
            value = values[name]
            if not math.isfinite(value):
                raise FmuModelError(f"{self.instance_name}: output {name} = {value} at t = {t:g} s is not finite")

    # -- fast bulk access (pythonfmu calls these once per fmi2Get/Set call) -------------
    def get_real(self, vrs: List[int]) -> List[float]:
        values, vars_ = self.values, self.vars
        return [float(values[vars_[vr].name]) for vr in vrs]

    def set_real(self, vrs: List[int], values_in: List[float]) -> None:
        values, vars_ = self.values, self.vars
        for vr, value in zip(vrs, values_in):
            var = vars_[vr]
            if not isinstance(var, Real):
                raise TypeError(f"{self.instance_name}: valueReference {vr} ({var.name}) is not Real")
            values[var.name] = float(value)

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

    def step_model(self, t: float, h: float) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def get_model_state(self) -> Any:
        raise NotImplementedError

    def set_model_state(self, state: Any) -> None:
        raise NotImplementedError
