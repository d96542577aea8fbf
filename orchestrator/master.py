"""Master algorithms: Jacobi and Gauss-Seidel, with zero-order-hold or linear input extrapolation;
units in worker processes (``process = N``, :mod:`.remote`) step in parallel under Jacobi.

Each unit occupies a :class:`Slot` holding the values it last reported (``cur``) and the
ones before (``prev``). Before a unit steps over ``[t, t+h]`` its inputs are gathered:

* from a connection whose source has *not* stepped yet in this macro step (Jacobi, a
  Gauss-Seidel connection delayed where a cycle is broken, or one the scenario declares
  ``delayed``: its destination's inputs are then gathered at the step's start, before any unit
  steps): ZOH uses ``y(t)``; linear extrapolation uses
  ``y(t) + (y(t) - y(t-h))/2``, the extrapolated value at the middle of the step;
* from a source that has already stepped (Gauss-Seidel): ZOH uses ``y(t+h)``; linear uses
  ``(y(t) + y(t+h))/2``, the interpolated mid-step value.

Both linear variants make the coupling error second order in ``h`` for smooth signals;
ZOH is first order (tests/orchestrator/test_convergence.py measures both). Linear is the
default (results/cosim/README.md: 5-10x lower coupling error at 33 ms, no extra cost). It
applies to Real sources of variability ``continuous`` only: a ``discrete`` (or fixed) output is
piecewise constant and is held; a connection may choose ``extrapolation = "zoh"`` for itself
(event-like signals such as a contact normal, whose extrapolation across an event means
nothing), or ``extrapolation = "angle"`` for an angle wrapped to (-pi, pi]: linear, with the
change ``y(t+h) - y(t)`` taken the short way round (plain linear interpolation of 3.1 and -3.1
rad gives 0, a half turn off; on the circle it gives pi).
"""
from __future__ import annotations

import logging
from math import copysign, pi
from time import perf_counter_ns
from dataclasses import dataclass, field
from typing import Any, Callable, Dict, List, Optional, Tuple

from .codegen import Generated
from .fmu import DiscreteSetter, FmuInstance, RealSetter, ValueReader
from .graph import gauss_seidel_order
from .manipulators import Fault, signal
from .errors import ScenarioError
from .scenario import Connection, Scenario

log = logging.getLogger(__name__)


@dataclass
class Slot:
    """One unit instance in the master: what it reads, what feeds its inputs."""

    name: str
    inst: FmuInstance
    read_names: List[str]
    reader: ValueReader = None
    cur: List[Any] = field(default_factory=list)
    prev: List[Any] = field(default_factory=list)
    real_inputs: List[str] = field(default_factory=list)
    setter: Optional[RealSetter] = None
    in_vals: List[float] = field(default_factory=list)
    # (input index, source slot, source index, delayed?, gain, offset, 0 hold / 1 linear / 2 angle)
    float_feeds: List[Tuple[int, "Slot", int, bool, float, float, bool]] = field(default_factory=list)
    other_feeds: List[Tuple[str, "Slot", int]] = field(default_factory=list)
    other_setter: Optional[DiscreteSetter] = None  # sets the other_feeds' values (Integer, Boolean)
    signals: List[Tuple[int, Callable[[float], float]]] = field(default_factory=list)
    faults: List[Tuple[Fault, Optional[int]]] = field(default_factory=list)
    stepped: bool = False
    gatherer: Optional[Callable[[int], tuple]] = None  # compile_gather(self), made at the first gather
    has_inputs: bool = False  # anything to gather before a step
    rest_idx: Optional[int] = None  # index of the at_rest output when the unit may be stepped lazily
    applied: Optional[tuple] = None  # inputs applied for the last real step
    pending_start: int = 0  # lazily skipped interval [pending_start, pending_start + pending_ns)
    pending_ns: int = 0
    skipped_steps: int = 0
    busy_ns: int = 0  # wall time spent in this unit's FMI calls (gather, step, read)
    waits_for: List["Slot"] = field(default_factory=list)  # Gauss-Seidel: units before it that feed it
    sources: List["Slot"] = field(default_factory=list)    # a worker unit posted early: the units feeding it
    chained: bool = False     # a worker unit stepped by its worker right after its sources there

    def index(self, name: str) -> int:
        return self.read_names.index(name)

    def read(self) -> None:
        """Read the unit's values; a NaN/inf Real raises NonFiniteOutputError (naming unit,
        variable and time) before it is used or logged."""
        values = self.reader.read()
        if not self.reader.check_finite:  # a reader made without the check: the same error
            self.reader._raise_nonfinite(values)
        self.prev, self.cur = self.cur, values


_LINEAR = {"zoh": 0, "linear": 1, "angle": 2}
_TAU = 2.0 * pi


def _forced(slot: "Slot", vals: List[float], t_ns: int) -> tuple:
    """Apply the slot's active faults at ``t_ns``: a fault on a Real input of the slot's
    setter overwrites its value in ``vals``; the others are returned as (variable, value)."""
    forced = []
    for fault, idx in slot.faults:
        if fault.active(t_ns):
            if idx is None:
                forced.append((fault.spec.var, fault.spec.value))
            else:
                vals[idx] = float(fault.spec.value)
    return tuple(forced)


def compile_gather(slot: "Slot") -> Callable[[int], tuple]:
    """The function ``t_ns -> (Real inputs, other inputs, forced inputs)`` of a slot's step
    from ``t_ns`` (module docstring): straight-line code generated from its feeds, signals and
    faults, so a step runs no loop over feed tuples and no branch on a feed's mode.

    Per Real feed ``(i, source, j, delayed, gain, offset, mode)`` it computes ``gain * y +
    offset`` with ``y`` the source's value ``cur[j]`` (hold), or, with the source's previous
    value ``y0 = prev[j]`` (none before the first step: hold), the interpolated mid-step value
    ``0.5 * (y + y0)`` when the source has stepped in this macro step and the feed is not
    delayed, else the extrapolated ``y + 0.5 * (y - y0)``; an angle (mode 2) takes its change
    ``y - y0`` the short way round first. The arithmetic is the same, operation for operation,
    in every case, so the inputs are the same bit for bit whatever the feeds' order.
    """
    gen = Generated(V=slot.in_vals, TAU=_TAU, SLOT=slot, forced_inputs=_forced)
    lines: List[str] = []
    for i, src, j, delayed, gain, offset, linear in slot.float_feeds:
        n = gen.obj(src)[1:]   # the source's values, previous values, stepped flag: cN, pN, mN
        g, o = gen.const(gain), gen.const(offset)
        if not linear:
            lines.append(f"vals[{i}] = {g} * c{n}[{j}] + {o}")
            continue
        mid = f"m{n}" if not delayed else "False"
        if linear == 2:   # an angle: its change over the step the short way round
            step = ["d = y - y0", "d -= TAU * round(d / TAU)",
                    f"y = y0 + 0.5 * d if {mid} else y + 0.5 * d"]
        else:
            step = [f"y = 0.5 * (y + y0) if {mid} else y + 0.5 * (y - y0)"]
        lines += [f"y = c{n}[{j}]", f"if p{n}:", f"    y0 = p{n}[{j}]"] + [f"    {x}" for x in step]
        lines.append(f"vals[{i}] = {g} * y + {o}")
    if slot.signals:
        lines.append("t = t_ns / 1e9")
        lines += [f"vals[{i}] = {gen.const(fn)}(t)" for i, fn in slot.signals]
    lines.append("forced = forced_inputs(SLOT, vals, t_ns)" if slot.faults else "forced = ()")
    others = [f"c{gen.obj(src)[1:]}[{j}]" for _, src, j in slot.other_feeds]
    lines.append(f"others = ({', '.join(others)}{',' if others else ''})")
    head = ["vals = V"] + [f"c{s[1:]} = {s}.cur; p{s[1:]} = {s}.prev; m{s[1:]} = {s}.stepped" for s in gen.objects]
    return gen.function("gather(t_ns)", head + lines + ["return tuple(vals), others, forced"], f"gather {slot.name}")


def _same_floats(a: tuple, b: tuple) -> bool:
    """The two tuples hold the same floats, bit for bit but for NaN payloads (``==`` and the
    signs of zeros: 0.0 == -0.0, and a model may tell them apart)."""
    if a != b:
        return False
    if 0.0 not in a:
        return True
    return all(x != 0.0 or copysign(1.0, x) == copysign(1.0, y) for x, y in zip(a, b))


class Stepper:
    """How one slot is stepped: its inputs gathered from its feeds, applied, and the step taken
    or skipped lazily. Stateless (everything lives in the slots): the :class:`Master` steps its
    own slots with it, and a worker process (:mod:`.remote`) the units posted to it ahead of
    the step, so both give the same inputs and the same skips bit for bit."""

    def _gather(self, slot: Slot, t_ns: int) -> tuple:
        """The inputs of ``slot`` for the step starting at ``t_ns`` (not yet applied); only
        for a slot that ``has_inputs`` (:meth:`step` passes None for the others). Runs the
        slot's gatherer (:func:`compile_gather`), made at its first call from its feeds."""
        gather = slot.gatherer
        if gather is None:
            gather = slot.gatherer = compile_gather(slot)
        return gather(t_ns)

    def _apply(self, slot: Slot, inputs: tuple) -> None:
        """Set a step's inputs. Values equal to those the last step set are not set again (an
        FMU keeps an input until it is set: FMI 2.0 §3.2.3), unless a fault forced some input
        then (it may have overwritten one of them)."""
        vals, others, forced = inputs
        prev = slot.applied
        fresh = prev is None or bool(prev[2])
        if slot.setter is not None and (fresh or not _same_floats(vals, prev[0])):
            slot.setter.set(vals)
        if others and (fresh or others != prev[1]):
            slot.other_setter.set(others)
        if forced:
            slot.inst.set_values(dict(forced))
        slot.applied = inputs

    @staticmethod
    def _skips(slot: Slot, inputs: Optional[tuple]) -> bool:
        """The slot is at rest and its inputs are those of its last step: it is skipped lazily."""
        return (slot.rest_idx is not None and slot.cur[slot.rest_idx] and inputs == slot.applied
                and not (inputs is not None and inputs[2]))

    def _advance(self, slot: Slot, t_ns: int, h_ns: int, inputs: Optional[tuple]) -> bool:
        """Step one slot (or skip it lazily). Returns whether the FMU was called."""
        if self._skips(slot, inputs):
            if slot.pending_ns == 0:
                slot.pending_start = t_ns
            slot.pending_ns += h_ns
            slot.skipped_steps += 1
            slot.prev = slot.cur
            return False
        if slot.pending_ns:
            self.catch_up(slot)
        if inputs is not None:
            self._apply(slot, inputs)
        slot.inst.do_step(t_ns, h_ns)
        return True

    def step_slot(self, slot: Slot, t_ns: int, h_ns: int, inputs: Optional[tuple]) -> None:
        """Step a slot (or skip it lazily) and read it: a worker's step of a unit it steps
        itself (``inputs`` None: gathered here from the slot's feeds, a chained unit)."""
        if inputs is None and slot.has_inputs:
            inputs = self._gather(slot, t_ns)
        if self._advance(slot, t_ns, h_ns, inputs):
            slot.read()

    def catch_up(self, slot: Slot) -> None:
        """One step over the lazily skipped interval, with the inputs it was skipped with."""
        if slot.pending_ns:
            start, span = slot.pending_start, slot.pending_ns
            slot.pending_ns = 0
            slot.inst.do_step(start, span)


class Master(Stepper):
    """Steps a set of slots with Jacobi or Gauss-Seidel.

    ``POST_AHEAD`` (default True): a worker unit's next step is posted as soon as its inputs
    are known (:meth:`_post_ahead`), even before its last step's reply has been taken; False
    posts it only when the step is over (the log is the same either way,
    tests/orchestrator/test_remote.py).

    ``CHAIN`` (default True): under Gauss-Seidel, a worker unit that reads only units posted
    with the step in its own worker, fresh, and has no scenario signal or fault is *chained*
    to them (:meth:`_chainable`): its step is posted with theirs, and the worker gathers its
    inputs and steps it right after them, with no round trip through this process. False:
    its inputs are gathered here once its sources' replies are in.

    The units posted ahead of a step (:attr:`_ahead`: worker units that can start a step at
    once, and the units chained to them) are stepped by their worker: this process sends the
    inputs it gathered (none for a chained unit), the worker applies them, decides a lazy
    skip and catches up with the same :class:`Stepper` code, so a post does not wait for the
    unit's last reply.

    Parameters
    ----------
    scenario : Scenario
    slots : dict of name -> Slot
        In scenario order; their ``read_names`` must include every connection source.
    connections : list of Connection
        Connections among the slots.
    """

    POST_AHEAD = True
    CHAIN = True

    def __init__(self, scenario: Scenario, slots: Dict[str, Slot], connections: List[Connection]) -> None:
        self.algorithm = scenario.algorithm
        self.slots = slots
        #: some unit runs in a worker process (orchestrator/remote.py); ``wait_ns``: the time
        #: the Jacobi step spent waiting for their replies after stepping its own units
        self.remote = any(s.inst.remote for s in slots.values())
        self.wait_ns = 0
        self._posted: Optional[tuple] = None   # (step start, slots posted, ids handled) of post_remote
        #: (start, end, macro step) of the run in ns, set by the execution: lets a worker unit's
        #: next step be posted during this one (:meth:`_post_ahead`); None: no posting ahead
        self.schedule: Optional[Tuple[int, int, int]] = None
        self._ahead_error: Optional[Exception] = None   # a failed post ahead, raised at the next step
        self._early: List[Slot] = []           # worker units that can start a step at once
        if self.algorithm == "gauss-seidel":
            self.order, self.delayed = gauss_seidel_order(list(slots), connections)
            for c in self.delayed:
                if not c.delayed:
                    log.warning("Gauss-Seidel: cycle broken at %s (its destination steps first and reads the "
                                "value of the previous step)", c)
        else:
            self.order, self.delayed = list(slots), list(connections)
        delayed = set(self.delayed)
        self._order_slots = [slots[n] for n in self.order]   # the slots in stepping order
        for c in connections:
            dst, src = slots[c.dst_unit], slots[c.src_unit]
            fam = dst.inst.var(c.dst_var).family
            if fam == "float":
                mode = c.extrapolation or scenario.extrapolation
                linear = (_LINEAR.get(mode, 0)   # 0: hold, 1: linear, 2: linear on the circle
                          if src.inst.var(c.src_var).variability in ("continuous", "") else 0)
                dst.float_feeds.append((dst.real_inputs.index(c.dst_var), src, src.index(c.src_var), c in delayed,
                                        c.gain, c.offset, linear))
            else:
                dst.other_feeds.append((c.dst_var, src, src.index(c.src_var)))
        for s in scenario.inputs:
            slot = slots.get(s.unit)
            if slot is not None:
                slot.signals.append((slot.real_inputs.index(s.var), signal(s)))
        for fs in scenario.faults:
            slot = slots.get(fs.unit)
            if slot is not None:
                idx = slot.real_inputs.index(fs.var) if fs.var in slot.real_inputs else None
                slot.faults.append((Fault(fs), idx))
        # units in worker processes: which of them can be posted at a step's start (Jacobi: all;
        # Gauss-Seidel: those fed by no unit before them in the order), and, under Gauss-Seidel,
        # the sources a unit waits for (the units before it that feed it)
        rank = {name: i for i, name in enumerate(self.order)}
        for slot in slots.values():
            before = {c.src_unit: slots[c.src_unit] for c in connections
                      if c.dst_unit == slot.name and c not in delayed and rank[c.src_unit] < rank[slot.name]}
            slot.waits_for = list(before.values()) if self.algorithm == "gauss-seidel" else []
        #: Gauss-Seidel: units fed through a declared-delayed connection by a unit that steps
        #: before them; their inputs are gathered at the step's start, before that unit steps
        self._start_gathered: List[Slot] = []
        if self.algorithm == "gauss-seidel":
            for slot in map(slots.__getitem__, self.order):
                ahead = [c for c in connections if c.dst_unit == slot.name and c.delayed
                         and rank[c.src_unit] < rank[slot.name]]
                if ahead and slot.waits_for:
                    fresh = next(c for c in connections if c.dst_unit == slot.name and c not in delayed
                                 and rank[c.src_unit] < rank[slot.name])
                    raise ScenarioError(
                        f"{scenario.file}: connection {ahead[0]} is delayed but {slot.name} also reads "
                        f"{fresh} in the same step: a unit reads all the units stepped before it either "
                        f"fresh or delayed (declare this one delayed too, or neither)")
                if ahead and not slot.inst.remote:
                    self._start_gathered.append(slot)
        self._early = [slots[n] for n in self.order if slots[n].inst.remote and not slots[n].waits_for]
        for slot in self._early:   # the units whose outputs its next step's inputs are made of
            slot.sources = list({c.src_unit: slots[c.src_unit] for c in connections
                                 if c.dst_unit == slot.name}.values())
        early = set(map(id, self._early))
        #: the units a Gauss-Seidel step goes through itself (the early ones are posted before it)
        self._gs_work = [slots[n] for n in self.order if id(slots[n]) not in early]
        for slot in slots.values():
            if slot.other_feeds:
                slot.other_setter = slot.inst.discrete_setter([name for name, _, _ in slot.other_feeds])
            slot.has_inputs = bool(slot.float_feeds or slot.other_feeds or slot.signals or slot.faults)
            if "at_rest" in slot.read_names and scenario.lazy:
                slot.rest_idx = slot.index("at_rest")
        #: Gauss-Seidel: worker units chained to units of their own worker (posted with them)
        self._chained: List[Slot] = []
        if self.algorithm == "gauss-seidel" and self.CHAIN:
            posted = set(map(id, self._early))
            for slot in map(slots.__getitem__, self.order):
                if self._chainable(slot, posted):
                    posted.add(id(slot))
                    self._chained.append(slot)
                    slot.chained = True
            chained = set(map(id, self._chained))
            self._gs_work = [s for s in self._gs_work if id(s) not in chained]
        #: the worker units posted at a step's start or ahead of it (heads before their chains),
        #: stepped by their workers
        self._ahead = self._early + self._chained
        for slot in self._ahead:
            slot.inst.setup_stepping({
                "rest_idx": slot.rest_idx, "in_vals": list(slot.in_vals), "chained": slot.chained,
                "float_feeds": [(i, src.name, j, gain, offset, linear)
                                for i, src, j, _, gain, offset, linear in slot.float_feeds] if slot.chained else [],
                "other_feeds": [(var, src.name, j) for var, src, j in slot.other_feeds] if slot.chained else []})

    @staticmethod
    def _chainable(slot: Slot, posted: set) -> bool:
        """A worker unit whose every input comes fresh (not delayed) from units posted with the
        step (``posted``: ids) in its own worker, and that has no scenario signal or fault
        (values only this process knows): its worker can gather its inputs and step it."""
        inst, feeds = slot.inst, slot.waits_for
        return bool(inst.remote and feeds and not slot.signals and not slot.faults
                    and all(id(w) in posted and w.inst.worker is inst.worker for w in feeds)
                    and all(not delayed and any(src is w for w in feeds)
                            for _, src, _, delayed, _, _, _ in slot.float_feeds)
                    and all(any(src is w for w in feeds) for _, src, _ in slot.other_feeds))

    def _post(self, slot: Slot, t_ns: int, h_ns: int, hold: bool = False) -> None:
        """Post the step from ``t_ns`` of a unit its worker steps: with the inputs gathered
        here, or, chained, to be gathered there."""
        inputs = self._gather(slot, t_ns) if slot.has_inputs and not slot.chained else None
        slot.inst.post_step(t_ns, h_ns, inputs, hold)

    def step(self, t_ns: int, h_ns: int) -> None:
        """Advance every slot from ``t_ns`` by ``h_ns``."""
        slots = self.slots
        if self.remote:
            return self._parallel_step(t_ns, h_ns)
        if self.algorithm == "jacobi":
            gathered = [(slot, self._gather(slot, t_ns) if slot.has_inputs else None)
                        for slot in map(slots.__getitem__, self.order)]
            t0 = perf_counter_ns()
            for slot, inputs in gathered:
                if self._advance(slot, t_ns, h_ns, inputs):
                    slot.read()
                t1 = perf_counter_ns()  # one clock reading per unit: its end is the next one's start
                slot.busy_ns += t1 - t0
                t0 = t1
            return
        order = self._order_slots
        for slot in order:
            slot.stepped = False
        ready = {id(slot): self._gather(slot, t_ns) for slot in self._start_gathered} if self._start_gathered else None
        t0 = perf_counter_ns()
        for slot in order:
            inputs = ready.get(id(slot)) if ready else None
            if inputs is None and slot.has_inputs:
                inputs = self._gather(slot, t_ns)
            if self._advance(slot, t_ns, h_ns, inputs):
                slot.read()
            slot.stepped = True
            t1 = perf_counter_ns()
            slot.busy_ns += t1 - t0
            t0 = t1

    @property
    def pipelined(self) -> bool:
        """Some unit in a worker process can start a step before the units of this process
        (Jacobi: every one; Gauss-Seidel: one fed by no unit before it): the execution posts
        their next step (:meth:`post_remote`) before it logs the last one, so they step while
        it logs."""
        return bool(self._early)

    def post_remote(self, t_ns: int, h_ns: int) -> None:
        """Gather the inputs of the worker units that can start the step from ``t_ns`` at once
        (:attr:`pipelined`: their inputs are outputs at ``t_ns``) and post their steps, one
        message each, without waiting; :meth:`step` at ``t_ns`` takes their replies. Units
        posted already (:meth:`_post_ahead`) are left as they are."""
        if self._ahead_error is not None:
            exc, self._ahead_error = self._ahead_error, None
            raise exc
        if self._posted is not None and self._posted[0] != t_ns:
            self._posted = None
        posted, handled = self._posted[1:] if self._posted is not None else ([], set())
        held = []
        for slot in self._ahead:
            if id(slot) in handled:
                continue
            handled.add(id(slot))
            self._post(slot, t_ns, h_ns, hold=True)   # one message per worker (its units' steps batched)
            held.append(slot)
        for slot in held:
            slot.inst.worker.flush()
        self._posted = (t_ns, posted + held, handled)

    def _post_ahead(self, t_ns: int, h_ns: int, pending: List[Slot]) -> None:
        """During the step from ``t_ns``: post the next step of each unit of :attr:`_ahead` whose
        inputs are known already (every unit feeding it stepped; a chained unit: its sources'
        next steps posted), so the worker goes on while this process finishes the step (and logs
        it). A unit whose last step is still pending is posted too when its worker can hold two
        replies (outputs through shared memory), else once that reply is taken."""
        if self.schedule is None or not self.POST_AHEAD:
            return
        t_next = t_ns + h_ns
        _, stop, h = self.schedule
        if self._posted is None or self._posted[0] != t_next:
            if t_next >= stop:
                return
            self._posted = (t_next, [], set())
        _, posted, handled = self._posted
        if len(handled) == len(self._ahead):   # every one posted already
            return
        h_next = min(t_next + h, stop) - t_next
        new = []
        for slot in self._ahead:
            if id(slot) in handled or (not slot.inst.queues and any(p is slot for p in pending)):
                continue
            if not (all(id(src) in handled for src in slot.waits_for) if slot.chained
                    else all(src.stepped for src in slot.sources)):
                continue
            handled.add(id(slot))
            try:   # held: the posts of one worker (a unit and the units chained to it) in one message
                self._post(slot, t_next, h_next, hold=True)
            except Exception as exc:   # (a dead worker): raised where the next step starts, as it
                self._ahead_error = exc   # would be without posting ahead; this step completes
                return
            new.append(slot)
        try:
            for slot in new:
                slot.inst.worker.flush()
        except Exception as exc:
            self._ahead_error = exc
            return
        posted += new

    def _parallel_step(self, t_ns: int, h_ns: int) -> None:
        """A step with units in worker processes. Those that can start at once are posted (now,
        unless :meth:`post_remote` did it); the others follow the algorithm: under Jacobi the
        units of this process step on the outputs at ``t_ns``; under Gauss-Seidel the units step
        in order, a unit in a worker is posted when the units before it that feed it have
        stepped, and a reply is taken when a later unit needs it. Every reply is taken before
        the step ends. The inputs every unit gets are those of the one-process algorithm."""
        if (self._posted is None or self._posted[0] != t_ns or len(self._posted[2]) < len(self._ahead)
                or self._ahead_error is not None):
            self.post_remote(t_ns, h_ns)
        pending = list(self._posted[1])
        self._posted = None
        for slot in self._order_slots:   # a worker unit: stepped once its reply is taken
            slot.stepped = False
        if self.algorithm == "jacobi":
            work = [(slot, self._gather(slot, t_ns) if slot.has_inputs else None)
                    for slot in self._order_slots if not slot.inst.remote]
        else:
            ready = {id(slot): self._gather(slot, t_ns) for slot in self._start_gathered}
            work = [(slot, ready.get(id(slot))) for slot in self._gs_work]
        # clock: a unit's own calls are its time, taking replies is waiting, posting ahead and
        # the bookkeeping are the master's
        wait = 0
        for slot, inputs in work:
            for src in slot.waits_for:             # Gauss-Seidel: its sources' replies first
                if any(p is src for p in pending):
                    pending = [p for p in pending if p is not src]
                    t0 = perf_counter_ns()
                    src.read()
                    wait += perf_counter_ns() - t0
                    src.stepped = True
                    self._post_ahead(t_ns, h_ns, pending)
            t0 = perf_counter_ns()
            if self.algorithm != "jacobi" and slot.has_inputs and inputs is None:
                inputs = self._gather(slot, t_ns)
            if self._advance(slot, t_ns, h_ns, inputs):
                if slot.inst.remote:
                    slot.inst.post()
                    pending.append(slot)
                else:
                    slot.read()
            slot.busy_ns += perf_counter_ns() - t0
            if not slot.inst.remote:
                slot.stepped = True
                self._post_ahead(t_ns, h_ns, pending)
        while pending:
            slot = pending.pop(0)
            t0 = perf_counter_ns()
            slot.read()
            wait += perf_counter_ns() - t0
            slot.stepped = True
            self._post_ahead(t_ns, h_ns, pending)
        self.wait_ns += wait

    def finish(self) -> None:
        """Bring lazily stepped units to the final time (counted as the unit's time)."""
        for slot in self.slots.values():
            t0 = perf_counter_ns()
            self.catch_up(slot)
            if slot.inst.remote:
                slot.inst.sync()
            if any(a is slot for a in self._ahead):   # its worker catches up a lazy skip
                slot.skipped_steps = slot.inst.finish_stepping()
            slot.busy_ns += perf_counter_ns() - t0

    def initial(self, t_ns: int) -> None:
        """Read the values after initialization and apply initial inputs."""
        for slot in self.slots.values():
            slot.read()
            slot.prev = []
