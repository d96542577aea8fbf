"""Master algorithms: Jacobi and Gauss-Seidel, with zero-order-hold or linear input extrapolation.

Before a unit steps over ``[t, t+h]`` its inputs are gathered (:func:`.stepping.gather`):
from a source that has *not* stepped yet in this macro step (Jacobi, a Gauss-Seidel connection
delayed where a cycle is broken or declared ``delayed``) ZOH uses ``y(t)`` and linear the
extrapolated mid-step value ``y(t) + (y(t) - y(t-h))/2``; from a source that has stepped
(Gauss-Seidel) ZOH uses ``y(t+h)`` and linear ``(y(t) + y(t+h))/2``. Linear (the default, second
order in ``h``) applies to ``continuous`` Real sources; other outputs are held; a connection may
choose ``"zoh"``, or ``"angle"`` (linear, the change taken the short way round the circle).
Units in worker processes (``process = N``, :mod:`.transport`) step in parallel with this
process's units under both algorithms (Gauss-Seidel: those fed by no unit before them, and
the units chained to them in their worker).
"""
from __future__ import annotations

import logging
from time import perf_counter_ns
from typing import Dict, List, Optional, Tuple

from .errors import ScenarioError
from .graph import gauss_seidel_order
from .manipulators import Fault, signal
from .scenario import Connection, Scenario
from .stepping import MODES, FloatFeed, OtherFeed, Slot, Stepper

log = logging.getLogger(__name__)

__all__ = ["Master", "Slot", "Stepper"]


class Master(Stepper):
    """Steps a set of slots with Jacobi or Gauss-Seidel.

    ``POST_AHEAD``: a worker unit's next step is posted as soon as its inputs are known, even
    before its last reply is taken (:meth:`_post_ahead`). ``CHAIN``: under Gauss-Seidel, a
    worker unit fed only, fresh, by units posted with the step in its own worker and with no
    signal or fault is stepped by that worker right after them (:meth:`_chainable`). Either
    way the log is the same (tests/orchestrator/test_remote.py).

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
        #: some unit runs in a worker process; ``wait_ns``: time spent waiting for their replies
        self.remote = any(s.inst.remote for s in slots.values())
        self.wait_ns = 0
        self._posted: Optional[tuple] = None   # (step start, slots posted, ids handled) of post_remote
        #: (start, end, macro step) of the run in ns, set by the execution: lets a worker unit's
        #: next step be posted during this one (:meth:`_post_ahead`); None: no posting ahead
        self.schedule: Optional[Tuple[int, int, int]] = None
        self._ahead_error: Optional[Exception] = None   # a failed post ahead, raised at the next step
        self.order, self.delayed = self._stepping_order(connections)
        self._order_slots = [slots[n] for n in self.order]   # the slots in stepping order
        self._connect(scenario, connections)
        self._manipulate(scenario)
        #: Gauss-Seidel: units fed through a declared-delayed connection by a unit that steps
        #: before them; their inputs are gathered at the step's start, before that unit steps
        self._start_gathered = self._link(scenario, connections)
        self._finish_inputs(scenario)
        self._schedule_workers(connections)

    def _stepping_order(self, connections: List[Connection]) -> Tuple[List[str], List[Connection]]:
        """The units' order and the connections read from the previous step (all under Jacobi)."""
        if self.algorithm != "gauss-seidel":
            return list(self.slots), list(connections)
        order, delayed = gauss_seidel_order(list(self.slots), connections)
        for c in delayed:
            if not c.delayed:
                log.warning("Gauss-Seidel: cycle broken at %s (its destination steps first and reads the "
                            "value of the previous step)", c)
        return order, delayed

    def _connect(self, scenario: Scenario, connections: List[Connection]) -> None:
        """Each connection as a feed of its destination."""
        slots, delayed = self.slots, set(self.delayed)
        for c in connections:
            dst, src = slots[c.dst_unit], slots[c.src_unit]
            if dst.inst.var(c.dst_var).family == "float":
                mode = MODES.get(c.extrapolation or scenario.extrapolation, 0)
                if src.inst.var(c.src_var).variability not in ("continuous", ""):
                    mode = 0   # a discrete or fixed output is piecewise constant: held
                dst.inputs.float_feeds.append(FloatFeed(dst.real_inputs.index(c.dst_var), src, src.index(c.src_var),
                                                        c in delayed, c.gain, c.offset, mode))
            else:
                dst.inputs.other_feeds.append(OtherFeed(c.dst_var, src, src.index(c.src_var)))

    def _manipulate(self, scenario: Scenario) -> None:
        """The scenario's input signals and faults on the slots' inputs."""
        for s in scenario.inputs:
            slot = self.slots.get(s.unit)
            if slot is not None:
                slot.inputs.signals.append((slot.real_inputs.index(s.var), signal(s)))
        for fs in scenario.faults:
            slot = self.slots.get(fs.unit)
            if slot is not None:
                idx = slot.real_inputs.index(fs.var) if fs.var in slot.real_inputs else None
                slot.inputs.faults.append((Fault(fs), idx))

    def _link(self, scenario: Scenario, connections: List[Connection]) -> List[Slot]:
        """Under Gauss-Seidel, the units before each unit that feed it fresh (``waits_for``);
        returns the units of this process gathered at the step's start. Raises ScenarioError
        for a unit reading the units before it both fresh and declared delayed."""
        if self.algorithm != "gauss-seidel":
            return []
        slots, delayed = self.slots, set(self.delayed)
        rank = {name: i for i, name in enumerate(self.order)}
        start_gathered = []
        for slot in self._order_slots:
            into = [c for c in connections if c.dst_unit == slot.name and rank[c.src_unit] < rank[slot.name]]
            fresh = [c for c in into if c not in delayed]
            slot.links.waits_for = list({c.src_unit: slots[c.src_unit] for c in fresh}.values())
            ahead = [c for c in into if c.delayed]
            if ahead and fresh:
                raise ScenarioError(
                    f"{scenario.file}: connection {ahead[0]} is delayed but {slot.name} also reads "
                    f"{fresh[0]} in the same step: a unit reads all the units stepped before it either "
                    f"fresh or delayed (declare this one delayed too, or neither)")
            if ahead and not slot.inst.remote:
                start_gathered.append(slot)
        return start_gathered

    def _finish_inputs(self, scenario: Scenario) -> None:
        """The setter of the non-Real feeds, whether a unit has inputs to gather, lazy stepping."""
        for slot in self.slots.values():
            ins = slot.inputs
            if ins.other_feeds:
                ins.other_setter = slot.inst.discrete_setter([f.var for f in ins.other_feeds])
            ins.active = bool(ins.float_feeds or ins.other_feeds or ins.signals or ins.faults)
            if "at_rest" in slot.read_names and scenario.lazy:
                slot.lazy.rest_idx = slot.index("at_rest")

    def _schedule_workers(self, connections: List[Connection]) -> None:
        """Which worker units are posted at a step's start (Jacobi: all; Gauss-Seidel: those fed
        by no unit before them: :attr:`_early`) or chained to them, and let their workers step them."""
        slots = self.slots
        self._early: List[Slot] = [s for s in self._order_slots if s.inst.remote and not s.links.waits_for]
        for slot in self._early:   # the units whose outputs its next step's inputs are made of
            slot.links.sources = list({c.src_unit: slots[c.src_unit] for c in connections
                                       if c.dst_unit == slot.name}.values())
        early = set(map(id, self._early))
        #: the units a Gauss-Seidel step goes through itself (the early ones are posted before it)
        self._gs_work = [s for s in self._order_slots if id(s) not in early]
        #: Gauss-Seidel: worker units chained to units of their own worker (posted with them)
        self._chained: List[Slot] = []
        if self.algorithm == "gauss-seidel" and self.CHAIN:
            posted = set(early)
            for slot in self._order_slots:
                if self._chainable(slot, posted):
                    posted.add(id(slot))
                    self._chained.append(slot)
                    slot.links.chained = True
            chained = set(map(id, self._chained))
            self._gs_work = [s for s in self._gs_work if id(s) not in chained]
        #: the worker units posted at a step's start or ahead of it (heads before their chains)
        self._ahead = self._early + self._chained
        for slot in self._ahead:
            ins, chained = slot.inputs, slot.links.chained
            slot.inst.setup_stepping({
                "rest_idx": slot.lazy.rest_idx, "in_vals": list(ins.values), "chained": chained,
                "float_feeds": [(f.index, f.source.name, f.source_index, f.gain, f.offset, f.mode)
                                for f in ins.float_feeds] if chained else [],
                "other_feeds": [(f.var, f.source.name, f.source_index) for f in ins.other_feeds] if chained else []})

    @staticmethod
    def _chainable(slot: Slot, posted: set) -> bool:
        """A worker unit whose every input comes fresh (not delayed) from units posted with the
        step (``posted``: ids) in its own worker, and that has no scenario signal or fault
        (values only this process knows): its worker can gather its inputs and step it."""
        inst, feeds, ins = slot.inst, slot.links.waits_for, slot.inputs
        return bool(inst.remote and feeds and not ins.signals and not ins.faults
                    and all(id(w) in posted and w.inst.worker is inst.worker for w in feeds)
                    and all(not f.delayed and any(f.source is w for w in feeds) for f in ins.float_feeds)
                    and all(any(f.source is w for w in feeds) for f in ins.other_feeds))

    def _post(self, slot: Slot, t_ns: int, h_ns: int, hold: bool = False) -> None:
        """Post the step from ``t_ns`` of a unit its worker steps: with the inputs gathered
        here, or, chained, to be gathered there."""
        inputs = self._gather(slot, t_ns) if slot.inputs.active and not slot.links.chained else None
        slot.inst.post_step(t_ns, h_ns, inputs, hold)

    def step(self, t_ns: int, h_ns: int) -> None:
        """Advance every slot from ``t_ns`` by ``h_ns``."""
        if self.remote:
            return self._parallel_step(t_ns, h_ns)
        if self.algorithm == "jacobi":
            gathered = [(slot, self._gather(slot, t_ns) if slot.inputs.active else None)
                        for slot in self._order_slots]
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
            if inputs is None and slot.inputs.active:
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
            if not (all(id(src) in handled for src in slot.links.waits_for) if slot.links.chained
                    else all(src.stepped for src in slot.links.sources)):
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
            work = [(slot, self._gather(slot, t_ns) if slot.inputs.active else None)
                    for slot in self._order_slots if not slot.inst.remote]
        else:
            ready = {id(slot): self._gather(slot, t_ns) for slot in self._start_gathered}
            work = [(slot, ready.get(id(slot))) for slot in self._gs_work]
        # clock: a unit's own calls are its time, taking replies is waiting, posting ahead and
        # the bookkeeping are the master's
        wait = 0
        for slot, inputs in work:
            for src in slot.links.waits_for:             # Gauss-Seidel: its sources' replies first
                if any(p is src for p in pending):
                    pending = [p for p in pending if p is not src]
                    t0 = perf_counter_ns()
                    src.read()
                    wait += perf_counter_ns() - t0
                    src.stepped = True
                    self._post_ahead(t_ns, h_ns, pending)
            t0 = perf_counter_ns()
            if self.algorithm != "jacobi" and slot.inputs.active and inputs is None:
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
