"""FMI 3.0 co-simulation specifics: typed batched value access, array variables, the step's flags.

Every FMI 3.0 type goes through its own functions (``fmi3GetFloat32`` ... ``fmi3GetUInt64``,
``fmi3GetBoolean``, ``fmi3GetString``, ``fmi3GetBinary``; an Enumeration through the Int64
ones), one call per type for a fixed list of variables, into pre-built ctypes buffers, called
through prototypes without ``argtypes`` (as the FMI 2.0 fast path of :mod:`.fmu`).

Array variables (``<Dimension>``, fixed sizes or sizes held by structural parameters) appear
as one variable per element, ``name[i]`` (1-based) or ``name[i,j]`` (row-major, the FMI 3.0
serialisation order), each with the array's value reference, its shape and its flat index: an
element is logged, connected and driven like a scalar; a whole array is connected, set or
driven by its bare name (:func:`expand_arrays` spells it out element by element). A read or
write of some elements moves the whole array (FMI 3.0 passes arrays whole).

Binary values are Python ``bytes`` (logged as base64 text in JSON).
"""
from __future__ import annotations

import ctypes
import functools
import itertools
import logging
import math
import operator
from dataclasses import replace
from typing import TYPE_CHECKING, Any, Callable, Dict, List, Mapping, Optional, Sequence, Tuple

from .errors import FmuCallError, FmuLoadError, ScenarioError

log = logging.getLogger(__name__)

if TYPE_CHECKING:  # pragma: no cover
    from .fmu import FmuInstance, VarInfo

#: FMI 3.0 type -> (ctypes type of a value, the function suffix)
_CTYPE = {
    "Float32": (ctypes.c_float, "Float32"), "Float64": (ctypes.c_double, "Float64"),
    "Int8": (ctypes.c_int8, "Int8"), "UInt8": (ctypes.c_uint8, "UInt8"),
    "Int16": (ctypes.c_int16, "Int16"), "UInt16": (ctypes.c_uint16, "UInt16"),
    "Int32": (ctypes.c_int32, "Int32"), "UInt32": (ctypes.c_uint32, "UInt32"),
    "Int64": (ctypes.c_int64, "Int64"), "UInt64": (ctypes.c_uint64, "UInt64"),
    "Enumeration": (ctypes.c_int64, "Int64"), "Boolean": (ctypes.c_bool, "Boolean"),
    "String": (ctypes.c_char_p, "String"), "Binary": (ctypes.c_void_p, "Binary"),
}
#: ``(address, size) -> bytes``, a copy of the FMU's memory (the C API's PyBytes_FromStringAndSize:
#: ``ctypes.string_at`` without its Python wrapper)
_bytes_at = ctypes.PYFUNCTYPE(ctypes.py_object, ctypes.c_void_p, ctypes.c_ssize_t)(
    ("PyBytes_FromStringAndSize", ctypes.pythonapi))
#: the order of type families in a read (Reals first: the finite check looks at a prefix)
_FAMILY_ORDER = {"float": 0, "int": 1, "bool": 2, "string": 3, "binary": 4}


def check_supported(md: Any, path: Any, unit: str) -> None:
    """Refuse what a co-simulation master cannot run: a scheduled-execution-only FMU, Clocks."""
    if md.coSimulation is None and getattr(md, "scheduledExecution", None) is not None:
        raise FmuLoadError(f"unit {unit}: {path} supports FMI 3.0 scheduled execution only (no CoSimulation "
                           f"interface): immersim runs co-simulation FMUs")
    clocks = [v.name for v in md.modelVariables if v.type == "Clock"]
    if clocks:
        raise FmuLoadError(f"unit {unit}: {path} has Clock variables ({', '.join(clocks[:4])}): clocked "
                           f"co-simulation is not supported")


def _parse_start(type_: str, text: Any) -> List[Any]:
    """The start values of a variable (a scalar or an array's, space-separated) as Python values."""
    if text is None:
        return []
    if type_ == "String":
        return [text]
    if type_ == "Binary":
        return [bytes.fromhex(str(text))]
    words = str(text).split()
    if type_ in ("Float32", "Float64"):
        return [float(w) for w in words]
    if type_ == "Boolean":
        return [w in ("true", "1") for w in words]
    return [int(w) for w in words]


def _dimension(d: Any, by_vr: Dict[int, Any], structural: Mapping[str, Any]) -> int:
    if d.start is not None:
        return int(d.start)
    v = by_vr[d.valueReference]
    value = structural.get(v.name, v.start)
    return int(value)


def variables(md: Any, structural: Optional[Mapping[str, Any]] = None) -> Dict[str, "VarInfo"]:
    """The variables of an FMI 3.0 model description, arrays spelled out element by element.

    Parameters
    ----------
    md : fmpy ModelDescription
    structural : mapping, optional
        Values of structural parameters (name -> value) that size arrays; others keep their start.
    """
    from .fmu import VarInfo, _unit_of

    structural = structural or {}
    by_vr = {v.valueReference: v for v in md.modelVariables}
    out: Dict[str, VarInfo] = {}
    for v in md.modelVariables:
        info = VarInfo(v.name, v.valueReference, v.type, v.causality or "local", v.variability or "",
                       _unit_of(v), v.start, v.description or "", initial=v.initial or "")
        if not v.dimensions:
            out[v.name] = info
            continue
        shape = tuple(_dimension(d, by_vr, structural) for d in v.dimensions)
        starts = _parse_start(v.type, v.start)
        for k, idx in enumerate(itertools.product(*(range(1, n + 1) for n in shape))):
            name = f"{v.name}[{','.join(map(str, idx))}]"
            out[name] = replace(info, name=name, start=starts[k] if k < len(starts) else None,
                                shape=shape, index=k)
    return out


def has_arrays(md: Any) -> bool:
    return any(v.dimensions for v in md.modelVariables)


def array_elements(variables_: Mapping[str, "VarInfo"], name: str) -> List[str]:
    """The element names of array ``name`` in flat order ([] when it is not an array)."""
    prefix = name + "["
    elems = [v for n, v in variables_.items() if v.index >= 0 and n.startswith(prefix) and n.endswith("]")
             and n[:n.index("[")] == name]
    return [v.name for v in sorted(elems, key=lambda v: v.index)]


def _flatten(value: Any) -> List[Any]:
    if isinstance(value, (list, tuple)):
        return [x for item in value for x in _flatten(item)]
    return [value]


def expand_arrays(scenario: Any, variables_: Mapping[str, Mapping[str, "VarInfo"]]) -> None:
    """Spell out references to whole arrays in ``scenario`` element by element (in place):
    an array parameter given as a (nested) list, a connection between two arrays of one size,
    a scenario input driving every element of an array with one signal."""
    from .scenario import InputSpec

    f = scenario.file
    for u in scenario.units:
        vs = variables_[u.name]
        for pname in list(u.parameters):
            if pname in vs:
                continue
            elems = array_elements(vs, pname)
            if elems:
                values = _flatten(u.parameters.pop(pname))
                if len(values) != len(elems):
                    raise ScenarioError(f"{f}: parameter {u.name}.{pname}: the array has {len(elems)} elements, "
                                        f"the scenario gives {len(values)} values")
                u.parameters.update(zip(elems, values))
    conns = []
    for c in scenario.connections:
        src, dst = variables_[c.src_unit], variables_[c.dst_unit]
        se = array_elements(src, c.src_var) if c.src_var not in src else []
        de = array_elements(dst, c.dst_var) if c.dst_var not in dst else []
        if not se and not de:
            conns.append(c)
            continue
        if len(se) != len(de):
            raise ScenarioError(f"{f}: connection {c}: {len(se) or 'not an array of'} elements -> "
                                f"{len(de) or 'not an array of'} elements (connect arrays of one size, or elements)")
        conns += [replace(c, src_var=a, dst_var=b) for a, b in zip(se, de)]
    scenario.connections[:] = conns
    inputs = []
    for s in scenario.inputs:
        elems = array_elements(variables_[s.unit], s.var) if s.var not in variables_[s.unit] else []
        inputs += [InputSpec(s.unit, e, s.kind, s.params) for e in elems] if elems else [s]
    scenario.inputs[:] = inputs


class _Group:
    """One FMI 3.0 type's share of a batched access: the value references (arrays whole), the
    buffer of all their values, and where each requested variable sits in it."""

    def __init__(self, inst: "FmuInstance", type_: str, infos: Sequence["VarInfo"], setter: bool) -> None:
        ctype, suffix = _CTYPE[type_]
        self.type = type_
        self.function = f"fmi3{'Set' if setter else 'Get'}{suffix}"
        vrs, offset, size = [], {}, 0
        for v in infos:
            if v.vr not in offset:
                offset[v.vr] = size
                vrs.append(v.vr)
                size += math.prod(v.shape) if v.index >= 0 else 1
        self.positions = [offset[v.vr] + max(v.index, 0) for v in infos]
        self.identity = self.positions == list(range(size))
        self.vrs = (ctypes.c_uint32 * len(vrs))(*vrs)
        self.nvr = ctypes.c_size_t(len(vrs))
        self.n = ctypes.c_size_t(size)
        self.buf = (ctype * size)()
        self.sizes = (ctypes.c_size_t * size)() if type_ == "Binary" else None
        self._keep: Dict[int, Any] = {}   # the bytes a String/Binary buffer points into, by position
        self.fn = inst._fast_function(self.function)
        #: the arguments of the call, pre-built (Binary: with the sizes)
        self.args = ((inst._c_component, self.vrs, self.nvr, self.buf, self.n) if self.sizes is None
                     else (inst._c_component, self.vrs, self.nvr, self.sizes, self.buf, self.n))
        if setter:   # elements not set by the caller keep their start values (arrays move whole)
            by_pos = {}
            for v in inst.variables.values():
                if v.vr in offset and _CTYPE[v.type][1] == type_:
                    start = v.start if v.index >= 0 else (_parse_start(v.type, v.start) or [None])[0]
                    if start is not None:
                        by_pos[offset[v.vr] + max(v.index, 0)] = start
            for pos, value in by_pos.items():
                self.put(pos, value)

    def put(self, pos: int, value: Any) -> None:
        if self.type == "String":
            raw = str(value).encode("utf-8")
            self._keep[pos] = raw
            self.buf[pos] = raw
        elif self.type == "Binary":
            value = bytes.fromhex(value) if isinstance(value, str) else bytes(value)   # hex, as in the XML
            raw = ctypes.create_string_buffer(value, max(len(value), 1))
            self._keep[pos] = raw
            self.buf[pos] = ctypes.cast(raw, ctypes.c_void_p).value
            self.sizes[pos] = len(value)
        elif self.type in ("Float32", "Float64"):
            self.buf[pos] = float(value)
        elif self.type == "Boolean":
            self.buf[pos] = bool(value)
        else:
            self.buf[pos] = int(value)

    def converter(self) -> Callable[[], List[Any]]:
        """A function returning :meth:`values` (made once: no branch on the type per call)."""
        buf, sizes, positions = self.buf, self.sizes, self.positions
        # a ctypes array is sliced to a list first: iterating it item by item (the sequence
        # protocol, ended by an IndexError) costs more than the copy
        if self.type == "String":
            def raw():
                return [b.decode("utf-8", "replace") if b is not None else "" for b in buf[:]]
        elif self.type == "Binary":
            def raw():
                ptrs = buf[:]
                if None in ptrs:   # a NULL value (none of its bytes): b""
                    return [_bytes_at(p, n) if p else b"" for p, n in zip(ptrs, sizes[:])]
                return list(map(_bytes_at, ptrs, sizes[:]))
        else:
            raw = functools.partial(operator.getitem, buf, slice(None))   # buf[:]: a list
        if self.identity:
            return raw
        pick = operator.itemgetter(*positions)
        if len(positions) == 1:
            return lambda: [pick(raw())]
        return lambda: list(pick(raw()))

    def call(self, inst: "FmuInstance") -> None:
        try:
            status = self.fn(*self.args)
        except Exception as exc:
            raise inst._raised(self.function, exc) from None
        if status > 1:
            inst._check(self.function, status)


def _groups(inst: "FmuInstance", names: Sequence[str], setter: bool) -> Tuple[List[str], List[_Group]]:
    """The variables ``names`` in the order of their calls, and one group per FMI function (an
    Enumeration shares the Int64 call)."""
    infos = [inst.var(n) for n in dict.fromkeys(names)]
    suffix = [t for t in _CTYPE if t != "Enumeration"]   # the functions, in call order
    infos.sort(key=lambda v: (_FAMILY_ORDER.get(v.family, 5), suffix.index(_CTYPE[v.type][1]), v.vr, v.index))
    groups = [_Group(inst, t, list(vs), setter)
              for t, vs in itertools.groupby(infos, key=lambda v: _CTYPE[v.type][1])]
    return [v.name for v in infos], groups


class Reader:
    """Reads a fixed set of FMI 3.0 variables, one call per type (the interface of
    :class:`~immersim.orchestrator.fmu.ValueReader`: ``names`` in the order :meth:`read`
    returns them, Reals first)."""

    def __init__(self, inst: "FmuInstance", names: Sequence[str], check_finite: bool = False) -> None:
        from .fmu import ValueReader

        self.inst, self.check_finite = inst, check_finite
        self.names, self._groups = _groups(inst, names, setter=False)
        self.n_real = sum(inst.var(n).family == "float" for n in self.names)
        self.nonfinite = ValueReader.nonfinite.__get__(self)
        self._raise_nonfinite = ValueReader._raise_nonfinite.__get__(self)

        #: (function, its arguments, the converter of its buffer, function name) per type
        self._calls = [(g.fn, g.args, g.converter(), g.function) for g in self._groups]
        self.read = self._reader()

    def _reader(self) -> Callable[[], List[Any]]:
        """The :meth:`read` closure: every look-up bound once, one pre-built call per type."""
        calls, inst, isfinite = self._calls, self.inst, math.isfinite
        n_real = self.n_real if self.check_finite else 0

        def read() -> List[Any]:
            out: List[Any] = []
            for fn, args, convert, name in calls:
                try:
                    status = fn(*args)
                except Exception as exc:
                    raise inst._raised(name, exc) from None
                if status > 1:
                    inst._check(name, status)
                out += convert()
            if n_real and not isfinite(sum(out[:n_real])):
                self._raise_nonfinite(out)
            return out
        return read

    def read(self) -> List[Any]:
        """Current values, in the order of ``self.names`` (replaced by the :meth:`_reader`
        closure at construction)."""
        raise NotImplementedError


class Setter:
    """Sets a fixed list of FMI 3.0 variables, one call per type; :meth:`set` takes the values
    in the order of ``names``. Elements of an array not in the list keep their start values."""

    def __init__(self, inst: "FmuInstance", names: Sequence[str]) -> None:
        self.inst = inst
        self.names = list(names)
        ordered, self._groups = _groups(inst, self.names, setter=True)
        where = {n: i for i, n in enumerate(self.names)}
        self._take = [[where[n] for n in ordered[a:a + len(g.positions)]]
                      for g, a in zip(self._groups, itertools.accumulate([0] + [len(g.positions) for g in self._groups]))]

    def set(self, values: Sequence[Any]) -> None:
        for g, take in zip(self._groups, self._take):
            for pos, i in zip(g.positions, take):
                g.put(pos, values[i])
            g.call(self.inst)


def set_values(inst: "FmuInstance", values: Mapping[str, Any]) -> None:
    """Set values by name (slow path, set-up and faults): structural parameters first, in
    Configuration Mode (they size arrays), then everything else, one call per type."""
    structural = [n for n in values if inst.var(n).causality == "structuralParameter"]
    rest = [n for n in values if n not in structural]
    if structural:   # set in Configuration Mode (FMI 3.0 §3.2.4)
        inst._guard("fmi3EnterConfigurationMode", inst.fmu.enterConfigurationMode)
        Setter(inst, structural).set([values[n] for n in structural])
        inst._guard("fmi3ExitConfigurationMode", inst.fmu.exitConfigurationMode)
    if rest:
        Setter(inst, rest).set([values[n] for n in rest])


def get_values(inst: "FmuInstance", names: Sequence[str]) -> List[Any]:
    """Read values by name, in the order given (slow path)."""
    reader = Reader(inst, names)
    got = dict(zip(reader.names, reader.read()))
    return [got[n] for n in names]


def stepper(inst: "FmuInstance") -> Callable[[int, int], Optional[int]]:
    """The function ``(t_ns, h_ns) -> end`` that calls ``fmi3DoStep`` from ``t_ns`` over ``h_ns``
    with pre-built ctypes arguments. Returns the time (ns) at which the FMU asked to end the
    simulation (``terminateSimulation``; at ``lastSuccessfulTime`` when it also returned early,
    else at the step's end), or None.

    Early return: the master instantiates with ``earlyReturnAllowed = false`` (it has no use for
    an intermediate time: it exchanges values at macro steps only), so a conforming FMU never
    returns early. One that does (``earlyReturn`` without ``terminateSimulation``) is called
    again from its ``lastSuccessfulTime`` to the step's end, as often as it returns early (each
    logged at DEBUG), so the macro step completes as if it had not; one that returns early
    without advancing raises :class:`~.errors.FmuCallError` (it would never reach the end)."""
    fn, comp, no_set = inst._do_step, inst._c_component, inst._c_true
    event, terminate, early, last = ctypes.c_bool(), ctypes.c_bool(), ctypes.c_bool(), ctypes.c_double()
    c_t, c_h = ctypes.c_double(), ctypes.c_double()
    #: the call's arguments, made once (the times are set in c_t and c_h)
    args = (comp, c_t, c_h, no_set, ctypes.byref(event), ctypes.byref(terminate), ctypes.byref(early),
            ctypes.byref(last))

    def do_step(t_ns: int, h_ns: int) -> Optional[int]:
        end = t_ns + h_ns
        c_t.value, c_h.value = t_ns / 1e9, h_ns / 1e9
        while True:
            try:
                status = fn(*args)
            except Exception as exc:
                raise inst._raised("fmi3DoStep", exc) from None
            if status > 1:
                inst._check("fmi3DoStep", status)
            if not (early.value or terminate.value):
                return None
            reached = int(round(last.value * 1e9)) if early.value else end
            if terminate.value:
                return min(reached, end)
            if reached >= end:
                return None
            if reached / 1e9 <= c_t.value:   # returned early without advancing: it would never end
                raise FmuCallError(inst.name, "fmi3DoStep", t_ns, 2,
                                   f"returned early at t = {last.value:.9g} s without advancing "
                                   f"(step from {c_t.value:.9g} s to {end / 1e9:.9g} s)")
            log.debug("unit %s: fmi3DoStep returned early at t = %.9g s; continued to %.9g s",
                      inst.name, last.value, end / 1e9)
            c_t.value, c_h.value = reached / 1e9, (end - reached) / 1e9
    return do_step
