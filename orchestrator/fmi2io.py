"""Fast FMI 2.0 access of a fixed set of variables: one FMI call per type family and step.

:class:`ValueReader` reads outputs, :class:`RealSetter` and :class:`DiscreteSetter` set inputs,
each on the ctypes functions :meth:`~immersim.orchestrator.fmu.FmuInstance._fast_function`
prepared (pre-built value references, counts and buffers; the status of every call checked).
FMI 3.0 units use :mod:`.fmi3`'s ``Reader`` and ``Setter``.
"""
from __future__ import annotations

import ctypes
import math
from typing import TYPE_CHECKING, Any, Callable, List, Optional, Sequence

import numpy as np

from .errors import FmuCallError

if TYPE_CHECKING:
    from .fmu import FmuInstance


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

