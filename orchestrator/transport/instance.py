"""Units in worker processes: the master's handle on each (:class:`RemoteInstance`).

A :class:`RemoteInstance` implements :class:`~immersim.orchestrator.instance.Instance` for a
unit loaded by a :class:`~.process.WorkerProcess`. Calls that return nothing (set inputs,
``doStep``) are queued and sent with the next read of the outputs as one message
(:meth:`RemoteInstance.post`); the reply carries the outputs (through shared memory when a
float64 holds each exactly: no String, Binary or 64-bit integer) and, for a unit that asked to
end the simulation in that step, the end (added to ``fmu.ENDED`` here, as in this process). A
unit its worker steps itself (``Master._ahead``) is posted a step at a time with the inputs the
master gathered (:meth:`RemoteInstance.post_step`), two posts in flight at most, answered
through two shared buffers in turn.
"""
from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any, Callable, Dict, List, Optional, Sequence

from ..errors import FmuLoadError
from ..fmu import ENDED, FmuInstance, VarInfo, read_model, step_error
from .process import WorkerProcess
from .shm import SharedValues, shared_file

log = logging.getLogger(__name__)

#: what a posted step's errors name as the function: its inputs, doStep and output read
_RUN = "fmi2DoStep/read"


def _exact_in_float64(inst: "RemoteInstance", name: str) -> bool:
    """A value of ``name`` is carried exactly by a float64 slot of :class:`SharedValues`: a
    Real (Float32 too), a Boolean, an integer of at most 32 bits (FMI 2.0 Integer and
    Enumeration); not a String or Binary, nor an FMI 3.0 Int64, UInt64 or Enumeration (64 bits)."""
    v = inst.var(name)
    if v.family in ("float", "bool"):
        return True
    return v.family == "int" and not (v.type in ("Int64", "UInt64")
                                       or (v.type == "Enumeration" and inst.fmi_version.startswith("3")))


class RemoteReader:
    """The outputs of a :class:`RemoteInstance`: :meth:`read` posts its queued calls (if not
    posted yet) and returns the values of the reply. The worker's reader checks them."""

    check_finite = True

    def __init__(self, inst: "RemoteInstance", names: Sequence[str], check_finite: bool) -> None:
        self.inst = inst
        self.names = inst.worker.call(inst.name, "reader", list(names), True, function="reader")
        fams = [inst.var(n).family for n in self.names]
        if all(_exact_in_float64(inst, n) for n in self.names):   # the outputs through shared memory
            layout = (fams.count("float"), fams.count("int"), fams.count("bool"))

            def attach(path: str) -> None:
                inst.worker.call(inst.name, "shared", path, layout, function="reader")
                inst.shared = SharedValues(path, layout)

            shared_file(inst.name, SharedValues.nbytes(layout), attach)

    def read(self) -> List[Any]:
        return self.inst.collect()


class RemoteSetter:
    """Inputs of a :class:`RemoteInstance` (``kind`` "reals": a ``RealSetter`` in the worker,
    "discrete": a ``DiscreteSetter``), queued until the next post."""

    def __init__(self, inst: "RemoteInstance", names: List[str], kind: str = "reals") -> None:
        self.inst = inst
        self.names = names
        self.kind = kind
        inst.worker.call(inst.name, "setter", list(names), kind, function="setter")

    def set(self, values: Sequence[Any]) -> None:
        self.inst.queue.append((self.kind, tuple(values)))


class RemoteInstance:
    """A unit loaded by a :class:`WorkerProcess`, with the interface of ``FmuInstance``.

    Attributes
    ----------
    busy_ns : int
        Time the worker spent in this unit's calls (its own clock: set inputs, step, read).
    """

    remote = True

    def __init__(self, name: str, path: Path | str, unzip_dir: Optional[Path], worker: WorkerProcess,
                 variables: Optional[Dict[str, VarInfo]] = None) -> None:
        self.name = name
        self.path = Path(path)
        self.worker = worker
        self.t_ns = 0
        self.fatal = False
        self.busy_ns = 0
        self.queue: List[tuple] = []
        #: posts whose reply is not taken yet, oldest first: (sequence number, through shared
        #: memory?, start of its step); at most two, the second only through shared memory
        self._out: List[tuple] = []
        self._step_start = 0   # start of the last step queued (errors of a posted step name it)
        self._seq = 0          # posts so far: the worker writes the shared outputs under this number
        #: the outputs come back through shared memory (set by the reader, unless a String is read)
        self.shared: Optional[SharedValues] = None
        if not self.path.exists():
            raise FmuLoadError(f"unit {name}: FMU file {self.path} does not exist")
        md, self.variables = read_model(self.path, name)
        #: FMI 3.0 arrays sized by the scenario's structural parameters (``system.read_variables``):
        #: the worker's instance gets the same variables
        self._sized = variables if variables is not None and variables != self.variables else None
        if self._sized is not None:
            self.variables = variables
        self.model_description = md
        self.fmi_version = md.fmiVersion
        self._unzip = str(unzip_dir) if unzip_dir else None
        self._loading = False

    # -- loading (split so that workers load while the master loads its own units) --------------
    def start_loading(self) -> None:
        self.worker.send(("load", self.name, str(self.path), self._unzip, self._sized))
        self._loading = True

    def finish_loading(self) -> None:
        if self._loading:
            self._loading = False
            self.worker.receive(self.name, "load", None)

    # -- queued calls and their one message ------------------------------------------------------
    @property
    def queues(self) -> bool:
        """A next step can be posted before the last one's reply is taken (the outputs come
        back through shared memory, in two buffers used in turn)."""
        return self.shared is not None

    def _send(self, msg_of: Callable[[int], tuple], read: bool, hold: bool, step_start: int, keep: int = 1) -> None:
        """Send the message ``msg_of(sequence number)``; at most ``keep`` earlier posts may
        stay outstanding (older ones' replies are taken and dropped: a run that failed)."""
        while len(self._out) >= keep:
            self._drop()
        self._seq += 1
        self._out.append((self._seq, read and self.shared is not None, step_start))
        self.worker.send(msg_of(self._seq), _RUN, step_start, hold)

    def post(self, read: bool = True, hold: bool = False) -> None:
        """Send the queued calls (and a read of the outputs) without waiting for the reply;
        ``hold``: in the worker's next batch (``WorkerProcess.flush``)."""
        queue, self.queue = self.queue, []
        self._send(lambda seq: ("run", self.name, queue, read, seq), read, hold, self._step_start)

    def post_step(self, t_ns: int, h_ns: int, inputs: Optional[tuple], hold: bool = False) -> None:
        """Post the step from ``t_ns`` of a unit its worker steps (``Master._ahead``): the
        worker applies ``inputs`` (as gathered by ``Master._gather``; None: gathered there, a
        chained unit), steps or skips lazily, and sends the outputs (:meth:`collect`). May be
        posted before the last post's reply is taken (:attr:`queues`)."""
        if h_ns <= 0 or t_ns != self.t_ns:
            raise step_error(self.name, t_ns, h_ns, self.t_ns)
        if ENDED:   # a unit asked to end the simulation: the run ends with this step, no next one
            return
        self._step_start, self.t_ns = t_ns, t_ns + h_ns
        self._send(lambda seq: ("step", self.name, t_ns, h_ns, inputs, True, seq), True, hold, t_ns,
                   2 if self.queues else 1)

    def setup_stepping(self, spec: Dict[str, Any]) -> None:
        """Let the worker step this unit (``Master._ahead``): ``spec`` holds the index of
        ``at_rest`` when stepped lazily, the inputs' start values, and, for a chained unit,
        its feeds by source unit name (``Master._chainable``)."""
        self.worker.call(self.name, "stepping", spec, function="stepping")

    def finish_stepping(self) -> int:
        """The worker catches up a lazily skipped interval; returns the steps it skipped."""
        self._drain()
        return self.worker.call(self.name, "finish", function="finish", t_ns=self.t_ns)

    def collect(self) -> Optional[List[Any]]:
        """The reply of the oldest post (posting the queued calls first if nothing is posted):
        the outputs."""
        if not self._out:
            self.post()
        seq, via_shared, start = self._out.pop(0)
        if via_shared and self._wait_shared(seq, start):
            sv = self.shared
            self.busy_ns += int(sv.head(seq)[2])
            return sv.values(seq)
        values, busy, *ended = self.worker.receive(self.name, _RUN, start)
        self.busy_ns += busy
        if ended:   # the unit asked to end the simulation: as if it ran here (FmuInstance._ended)
            ENDED.extend(ended[0])
        return values

    def _wait_shared(self, seq: int, start: int) -> bool:
        """Wait for the worker to write the outputs of post ``seq`` (polling the shared
        header, yielding the core between polls, checking now and then that the worker is
        alive). True when they are there, False when the reply is a message (an error, an end)."""
        w = self.worker
        w.flush()
        head, target = self.shared.head(seq), float(seq)
        alive, yield_cpu = w.proc.poll, os.sched_yield
        k = 0
        while head[0] != target:
            k += 1
            if not k & 1023 and alive() is not None:
                raise w._died(self.name, _RUN, start)
            yield_cpu()
        return head[1] == 0.0

    def sync(self) -> None:
        """Run the queued calls now (no read)."""
        if self.queue:
            self.post(read=False)
            self.collect()

    def _drop(self) -> None:
        """Take the reply of the oldest post and drop it (a run that failed elsewhere)."""
        seq, via_shared, start = self._out.pop(0)
        try:
            if not (via_shared and self._wait_shared(seq, start)):
                self.worker.receive(self.name, _RUN, start)
        except Exception as exc:
            log.debug("unit %s: a dropped reply failed: %s", self.name, exc)

    def _drain(self) -> None:
        """Take the replies of the posts nobody collected (a run that failed elsewhere)."""
        while self._out:
            self._drop()

    def _call(self, method: str, *args: Any) -> Any:
        self.finish_loading()
        self._drain()
        self.sync()
        return self.worker.call(self.name, "call", method, args, function=method, t_ns=self.t_ns)

    # -- FmuInstance's interface -------------------------------------------------------------------
    def var(self, name: str) -> VarInfo:
        return FmuInstance.var(self, name)

    def initialize(self, start_ns: int, stop_ns: Optional[int], parameters: Dict[str, Any],
                   tolerance: Optional[float] = None) -> None:
        self.t_ns = start_ns
        self._call("initialize", start_ns, stop_ns, dict(parameters), tolerance)

    def do_step(self, t_ns: int, h_ns: int) -> None:
        """Queue a step (checked as ``FmuInstance.do_step`` checks it, here and in the worker)."""
        if h_ns <= 0 or t_ns != self.t_ns:
            raise step_error(self.name, t_ns, h_ns, self.t_ns)
        self.queue.append(("step", t_ns, h_ns))
        self._step_start, self.t_ns = t_ns, t_ns + h_ns

    def set_values(self, values: Dict[str, Any]) -> None:
        self.queue.append(("set", dict(values)))

    def get_values(self, names: Sequence[str]) -> List[Any]:
        return self._call("get_values", list(names))

    def reader(self, names: Sequence[str], check_finite: bool = False) -> RemoteReader:
        self.finish_loading()
        return RemoteReader(self, names, check_finite)

    def real_setter(self, names: Sequence[str]) -> RemoteSetter:
        self.finish_loading()
        return RemoteSetter(self, list(names))

    def discrete_setter(self, names: Sequence[str]) -> RemoteSetter:
        self.finish_loading()
        return RemoteSetter(self, list(names), "discrete")

    def terminate(self) -> None:
        """Terminate and free the unit in its worker (errors are logged, not raised)."""
        try:
            self._call("terminate")
        except Exception as exc:
            log.debug("unit %s: terminate failed: %s", self.name, exc)
