"""One unit's step as the master algorithm takes it: inputs gathered from its feeds, applied,
the step taken or skipped lazily, the outputs read.

The same code runs in the master (:mod:`.master`) and in a worker process for the units it
steps itself (:mod:`.transport`), so both give the same inputs and skips bit for bit.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from math import copysign, pi
from typing import Any, Callable, List, Optional, Tuple

from .instance import Instance
from .manipulators import Fault

TAU = 2.0 * pi
#: a Real feed's mode: hold the source's value, extrapolate it linearly, or as an angle
HOLD, LINEAR, ANGLE = 0, 1, 2
MODES = {"zoh": HOLD, "linear": LINEAR, "angle": ANGLE}


@dataclass(frozen=True, slots=True)
class FloatFeed:
    """A Real input ``index`` of a unit fed by output ``source_index`` of ``source``:
    ``gain * y + offset``, ``y`` held or extrapolated by ``mode`` (module :mod:`.master`)."""

    index: int
    source: "Slot"
    source_index: int
    delayed: bool
    gain: float
    offset: float
    mode: int


@dataclass(frozen=True, slots=True)
class OtherFeed:
    """An Integer or Boolean input ``var`` fed by output ``source_index`` of ``source`` (held)."""

    var: str
    source: "Slot"
    source_index: int


@dataclass(eq=False)
class Inputs:
    """What sets a unit's inputs before a step: its feeds, scenario signals and faults.

    ``values`` are the Real inputs ``names`` (start values first, overwritten in place by each
    gather); ``applied`` the inputs of the last step taken (``(reals, others, forced)``).
    """

    names: List[str] = field(default_factory=list)
    values: List[float] = field(default_factory=list)
    setter: Any = None          # sets ``values`` (a RealSetter)
    other_setter: Any = None    # sets the other feeds' values (a DiscreteSetter)
    float_feeds: List[FloatFeed] = field(default_factory=list)
    other_feeds: List[OtherFeed] = field(default_factory=list)
    signals: List[Tuple[int, Callable[[float], float]]] = field(default_factory=list)
    faults: List[Tuple[Fault, Optional[int]]] = field(default_factory=list)
    active: bool = False        # anything to gather before a step
    applied: Optional[tuple] = None


@dataclass(eq=False)
class Lazy:
    """Lazy stepping of a unit at rest: ``rest_idx`` (index of its ``at_rest`` output, None:
    always stepped) and the skipped interval ``[pending_start, pending_start + pending_ns)``."""

    rest_idx: Optional[int] = None
    pending_start: int = 0
    pending_ns: int = 0
    skipped: int = 0


@dataclass(eq=False)
class Links:
    """A worker unit's place in the master's schedule: the units before it that feed it
    (``waits_for``), the units its inputs come from (``sources``), and whether its worker
    steps it right after its sources there (``chained``)."""

    waits_for: List["Slot"] = field(default_factory=list)
    sources: List["Slot"] = field(default_factory=list)
    chained: bool = False


@dataclass(eq=False)
class Slot:
    """One unit in the master: the values it last reported (``cur``) and before (``prev``),
    whether it stepped in this macro step, its inputs, lazy state and links."""

    name: str
    inst: Instance
    read_names: List[str]
    reader: Any = None
    cur: List[Any] = field(default_factory=list)
    prev: List[Any] = field(default_factory=list)
    stepped: bool = False
    busy_ns: int = 0  # wall time spent in this unit's FMI calls (gather, step, read)
    inputs: Inputs = field(default_factory=Inputs)
    lazy: Lazy = field(default_factory=Lazy)
    links: Links = field(default_factory=Links)

    def index(self, name: str) -> int:
        return self.read_names.index(name)

    def read(self) -> None:
        """Read the unit's values; a NaN/inf Real raises NonFiniteOutputError (naming unit,
        variable and time) before it is used or logged."""
        values = self.reader.read()
        if not self.reader.check_finite:  # a reader made without the check: the same error
            self.reader._raise_nonfinite(values)
        self.prev, self.cur = self.cur, values

    # the names other modules read
    real_inputs = property(lambda self: self.inputs.names)
    setter = property(lambda self: self.inputs.setter)
    in_vals = property(lambda self: self.inputs.values)

    @property
    def skipped_steps(self) -> int:
        return self.lazy.skipped

    @skipped_steps.setter
    def skipped_steps(self, n: int) -> None:
        self.lazy.skipped = n


def _forced(inputs: Inputs, vals: List[float], t_ns: int) -> tuple:
    """Apply the active faults at ``t_ns``: a fault on a Real input overwrites its value in
    ``vals``; the others are returned as (variable, value)."""
    forced = []
    for fault, idx in inputs.faults:
        if fault.active(t_ns):
            if idx is None:
                forced.append((fault.spec.var, fault.spec.value))
            else:
                vals[idx] = float(fault.spec.value)
    return tuple(forced)


def gather(inputs: Inputs, t_ns: int) -> tuple:
    """The inputs ``(Reals, others, forced)`` of a step from ``t_ns`` (module :mod:`.master`).

    Per Real feed, ``gain * y + offset`` with ``y`` the source's value ``cur[j]`` (hold), or,
    with its previous value ``y0 = prev[j]`` (none before the first step: hold), the mid-step
    value ``0.5 * (y + y0)`` when the source has stepped in this macro step and the feed is
    not delayed, else the extrapolated ``y + 0.5 * (y - y0)``; an angle takes its change
    ``y - y0`` the short way round first.
    """
    vals = inputs.values
    for feed in inputs.float_feeds:
        src = feed.source
        y = src.cur[feed.source_index]
        if feed.mode:
            p = src.prev
            if p:
                y0 = p[feed.source_index]
                mid = src.stepped and not feed.delayed
                if feed.mode == ANGLE:
                    d = y - y0
                    d -= TAU * round(d / TAU)
                    y = y0 + 0.5 * d if mid else y + 0.5 * d
                else:
                    y = 0.5 * (y + y0) if mid else y + 0.5 * (y - y0)
        vals[feed.index] = feed.gain * y + feed.offset
    if inputs.signals:
        t = t_ns / 1e9
        for i, fn in inputs.signals:
            vals[i] = fn(t)
    forced = _forced(inputs, vals, t_ns) if inputs.faults else ()
    others = tuple([f.source.cur[f.source_index] for f in inputs.other_feeds])
    return tuple(vals), others, forced


def _same_floats(a: tuple, b: tuple) -> bool:
    """The two tuples hold the same floats, bit for bit but for NaN payloads (``==`` and the
    signs of zeros: 0.0 == -0.0, and a model may tell them apart)."""
    if a != b:
        return False
    if 0.0 not in a:
        return True
    return all(x != 0.0 or copysign(1.0, x) == copysign(1.0, y) for x, y in zip(a, b))


class Stepper:
    """How one slot is stepped: inputs gathered, applied, the step taken or skipped lazily.
    Stateless (everything lives in the slots)."""

    @staticmethod
    def _gather(slot: Slot, t_ns: int) -> tuple:
        """The inputs of ``slot`` for the step from ``t_ns`` (for a slot with active inputs)."""
        return gather(slot.inputs, t_ns)

    @staticmethod
    def _apply(slot: Slot, inputs: tuple) -> None:
        """Set a step's inputs. Values equal to those the last step set are not set again (an
        FMU keeps an input until it is set: FMI 2.0 §3.2.3), unless a fault forced some input
        then (it may have overwritten one of them)."""
        vals, others, forced = inputs
        ins = slot.inputs
        prev = ins.applied
        fresh = prev is None or bool(prev[2])
        if ins.setter is not None and (fresh or not _same_floats(vals, prev[0])):
            ins.setter.set(vals)
        if others and (fresh or others != prev[1]):
            ins.other_setter.set(others)
        if forced:
            slot.inst.set_values(dict(forced))
        ins.applied = inputs

    @staticmethod
    def _skips(slot: Slot, inputs: Optional[tuple]) -> bool:
        """The slot is at rest and its inputs are those of its last step: it is skipped lazily."""
        idx = slot.lazy.rest_idx
        return (idx is not None and slot.cur[idx] and inputs == slot.inputs.applied
                and not (inputs is not None and inputs[2]))

    def _advance(self, slot: Slot, t_ns: int, h_ns: int, inputs: Optional[tuple]) -> bool:
        """Step one slot (or skip it lazily). Returns whether the FMU was called."""
        lazy = slot.lazy
        if self._skips(slot, inputs):
            if lazy.pending_ns == 0:
                lazy.pending_start = t_ns
            lazy.pending_ns += h_ns
            lazy.skipped += 1
            slot.prev = slot.cur
            return False
        if lazy.pending_ns:
            self.catch_up(slot)
        if inputs is not None:
            self._apply(slot, inputs)
        slot.inst.do_step(t_ns, h_ns)
        return True

    def step_slot(self, slot: Slot, t_ns: int, h_ns: int, inputs: Optional[tuple]) -> None:
        """Step a slot (or skip it lazily) and read it; ``inputs`` None: gathered here from
        the slot's feeds (a worker's chained unit)."""
        if inputs is None and slot.inputs.active:
            inputs = gather(slot.inputs, t_ns)
        if self._advance(slot, t_ns, h_ns, inputs):
            slot.read()

    @staticmethod
    def catch_up(slot: Slot) -> None:
        """One step over the lazily skipped interval, with the inputs it was skipped with."""
        lazy = slot.lazy
        if lazy.pending_ns:
            start, span = lazy.pending_start, lazy.pending_ns
            lazy.pending_ns = 0
            slot.inst.do_step(start, span)
