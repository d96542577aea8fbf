"""Units in worker processes: parallel stepping of FMUs that run Python in the interpreter.

pythonfmu FMUs run their Python code in the interpreter of the process that loads them, under
its one GIL, so threads cannot step two of them at once. A unit given ``process = N``
(``[[units]]`` key, or the override ``"unit:process": N``) is loaded instead by worker process
N: a fresh interpreter running this module (``python -m immersim.orchestrator.remote FD``, one
end of a socket pair as a ``multiprocessing`` connection; nothing is inherited from the FMUs of
this process, and the caller's ``__main__`` is not imported again as *spawn* would). Units with
the same N share a worker; 0 is the master's process.

The master talks to a worker unit through a :class:`RemoteInstance`, which has the interface
of :class:`~immersim.orchestrator.fmu.FmuInstance` the master and the execution use. Calls
that return nothing (set inputs, ``doStep``) are queued and sent with the next read of the
outputs as **one message** (:meth:`RemoteInstance.post`); the reply carries the outputs
(through shared memory, :class:`_SharedValues`, unless a String is read).

The worker units that can start a step before the master's own units (Jacobi: all of them;
Gauss-Seidel: those fed by no unit stepped before them, and the units *chained* to them:
fed only, fresh, by such units of the same worker; ``Master._ahead``) are **stepped by their
worker**: the master posts each step with the inputs it gathered (a chained unit's inputs are
gathered by the worker from its sources' last two reads, :meth:`RemoteInstance.post_step`),
and the worker applies them, decides a lazy skip and catches up with the master's own
:class:`~immersim.orchestrator.master.Stepper` code, so the inputs and skips are those of the
one-process run bit for bit. The master posts a step as soon as its inputs are known, before
it takes the unit's last reply if need be (two posts in flight at most, answered through two
shared buffers in turn): the worker goes straight from one step to the next while the master
steps its own units and logs.

Inside the worker every call goes through a real ``FmuInstance``, so status checks, time
checks and error messages are the same; an exception raised there is rebuilt here with its type
and message (:func:`_portable`, :func:`_rebuild`). A worker that dies gives an
:class:`~immersim.orchestrator.errors.FmuCallError` naming the unit, the call, the time and the
exit code. Workers ignore SIGINT, SIGTERM and SIGHUP (the master acts on them between steps, see
:class:`~immersim.orchestrator.execution.DeferredSigint`) and end when their pipe closes.

The master's messages to a worker go through a mailbox in shared memory (:class:`_Mailbox`;
the socket for a message too long for it, and to wake a blocked worker): no system call per
post. While it waits for the next command a worker polls its mailbox and its pipe for
``spin_s`` seconds before it blocks, and the master polls the same way while it waits for a
reply: a blocked process takes ~25 us to wake on this kind of machine (measured: 45-50 us for
a round trip through a pipe or a semaphore), on the critical path of every step
(``RemoteConfig``).
"""
from __future__ import annotations

import builtins
import logging
import os
import platform
import time
from pickle import dumps, loads
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Dict, List, Optional, Sequence

from . import errors as _errors
from .child import message_sender, start_child
from .errors import FmuCallError, FmuLoadError
from .fmu import FmuInstance, VarInfo, read_model, step_error
from .master import Slot, Stepper

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RemoteConfig:
    """How a worker waits for commands.

    Attributes
    ----------
    spin_s : float
        Seconds a worker polls its mailbox and its pipe after a message before it blocks on
        the pipe (0: block at once). It yields the core between polls (``sched_yield``), so a
        process that waits for a core (the master on a loaded machine) gets it.
    """

    spin_s: float = 0.005


# -- errors across the pipe -------------------------------------------------------------------
def _portable(exc: BaseException) -> tuple:
    """An exception as (module, class name, message, attributes): plain data for the pipe
    (messages are plain pickles, protocol 5: ``Connection.send``'s ForkingPickler costs ~3x)."""
    attrs = {k: v for k, v in vars(exc).items() if isinstance(v, (str, int, float, bool, type(None)))}
    return type(exc).__module__, type(exc).__name__, str(exc), attrs


def _rebuild(data: tuple) -> BaseException:
    """The exception of :func:`_portable`: our own error types and builtins keep their type and
    message; anything else becomes a RuntimeError naming its type."""
    module, name, message, attrs = data
    cls = getattr(_errors, name, None) if module == _errors.__name__ else None
    if cls is None and module == "builtins":
        cls = getattr(builtins, name, None)
    if not (isinstance(cls, type) and issubclass(cls, BaseException)):
        return RuntimeError(f"{name}: {message}")
    exc = cls.__new__(cls)
    BaseException.__init__(exc, message)
    if cls is KeyError:   # str(KeyError) quotes its argument: keep the text as it was
        BaseException.__init__(exc, message.strip("'\""))
    exc.__dict__.update(attrs)
    return exc


def _readable(conn, spin_s: float) -> Callable[[], None]:
    """A function that returns once ``conn`` has data or ``spin_s`` seconds have passed: it
    polls the descriptor (one ``poll`` system call on a poller made once; ``Connection.poll``
    builds a selector per call) and yields the core between polls (``sched_yield``), so a
    process waiting for a core gets it. The caller's ``recv`` then blocks if nothing came."""
    import select

    if spin_s <= 0:
        return lambda: None
    poller = select.poll()
    poller.register(conn.fileno(), select.POLLIN)
    poll, yield_cpu, now = poller.poll, os.sched_yield, time.perf_counter

    def ready() -> None:
        if poll(0):
            return
        end = now() + spin_s
        while not poll(0) and now() < end:
            yield_cpu()
    return ready


def _next_message(conn, spin_s: float, mailbox: List["_Mailbox"]) -> Callable[[], bytes]:
    """The worker's next message: from the master's mailbox (``mailbox``: empty until the
    master sets one up) or the socket, in the master's order (a message goes through the socket
    only when the mailbox is empty: :meth:`WorkerProcess.flush`). It polls both for ``spin_s``
    seconds, yielding the core between polls, then blocks on the socket, flagged in the
    mailbox (:class:`_Mailbox`). An empty message is a wake-up."""
    import select

    poller = select.poll()
    poller.register(conn.fileno(), select.POLLIN)
    poll, yield_cpu, now = poller.poll, os.sched_yield, time.perf_counter

    def next_message() -> bytes:
        box = mailbox[0] if mailbox else None
        end = None
        while True:   # both, then again (yielding the core) until spin_s has passed
            if box is not None:
                data = box.take()
                if data is not None:
                    return data
            if poll(0):
                return conn.recv_bytes()
            if end is None:
                end = now() + spin_s
            elif now() >= end:
                break
            yield_cpu()
        if box is None:
            return conn.recv_bytes()
        box.blocked(True)
        try:
            while True:
                data = box.take()
                if data is not None:
                    return data
                if poll(box.BLOCKED_POLL_MS):
                    return conn.recv_bytes()
        finally:
            box.blocked(False)
    return next_message


class _SharedValues:
    """A worker unit's outputs in a shared file mapping (``/dev/shm``), instead of a reply.

    Two buffers, used in turn by the posts (post ``seq`` writes buffer ``seq % 2``), so the
    worker can answer a unit's next post while the master has not read the last one yet.
    Layout of a buffer, float64: a header ``[sequence, status, busy ns, 0]`` then the values
    (Reals, Integers, Booleans, in the reader's order). The worker writes the values, then the
    status, busy time and, last, the sequence number of the post; the master waits for its
    sequence number (x86 keeps the order of stores, so the values are complete when it
    appears; used only where :data:`STORE_ORDERED`). A status 1 means the step failed: its
    error comes as a normal reply.

    Parameters
    ----------
    path : str
        The file (created by the master, :meth:`nbytes` long).
    layout : tuple of int
        Counts of Reals, Integers and Booleans.
    """

    HEADER = 4

    def __init__(self, path: str, layout: tuple) -> None:
        import mmap

        import numpy as np

        self.path, self.layout = path, tuple(layout)
        with open(path, "r+b") as fh:
            self._map = mmap.mmap(fh.fileno(), self.nbytes(layout))
        n = self.HEADER + sum(self.layout)
        self.a = np.frombuffer(self._map, dtype=np.float64, count=2 * n)
        #: (header, values) of each buffer
        self.bufs = [(self.a[k * n:k * n + self.HEADER], self.a[k * n + self.HEADER:(k + 1) * n]) for k in (0, 1)]

    @classmethod
    def nbytes(cls, layout: tuple) -> int:
        return 2 * 8 * (cls.HEADER + sum(layout))

    def head(self, seq: int):
        """The header of post ``seq``'s buffer."""
        return self.bufs[seq & 1][0]

    def put(self, seq: int, values: Sequence[Any], busy_ns: int) -> None:
        head, data = self.bufs[seq & 1]
        data[:] = values
        head[1], head[2] = 0.0, float(busy_ns)
        head[0] = float(seq)

    def fail(self, seq: int) -> None:
        head = self.bufs[seq & 1][0]
        head[1] = 1.0
        head[0] = float(seq)

    def values(self, seq: int) -> List[Any]:
        n_real, n_int, n_bool = self.layout
        d = self.bufs[seq & 1][1]
        out = d[:n_real].tolist()
        if n_int:
            out += [int(x) for x in d[n_real:n_real + n_int].tolist()]
        if n_bool:
            out += [x != 0.0 for x in d[n_real + n_int:].tolist()]
        return out

    def close(self) -> None:
        self.bufs = self.a = None
        try:
            self._map.close()
        except BufferError:   # a view still alive: the mapping goes with the process
            pass


class _Mailbox:
    """The master's messages to a worker through a shared file mapping (``/dev/shm``): no
    system call per message (a socket write costs ~4.5 us here, the worker's poll and read as
    much again).

    A ring of ``SLOTS`` slots of ``SLOT_BYTES`` after a header of four int64: messages written
    (by the master), messages taken (by the worker), the worker's *blocked* flag, 0. The master
    writes a message's bytes and length into the next slot, then the count (x86 keeps the order
    of stores, so the worker never sees a count before its message; used only where
    :data:`STORE_ORDERED`); the worker takes messages in order. A worker that found nothing for
    ``spin_s`` sets its flag and blocks on its socket; the master sends an empty message to wake
    it when it sees the flag, and the blocked worker looks at the ring every ``BLOCKED_POLL_MS``
    anyway (the flag and the count can cross unseen: a late wake, never a lost message). A
    message too long for a slot goes through the socket once the worker has taken every earlier
    one (the order is kept).

    Parameters
    ----------
    path : str
        The file (created by the master, :meth:`nbytes` long).
    """

    SLOTS = 8
    SLOT_BYTES = 1 << 16
    HEAD = 32
    BLOCKED_POLL_MS = 2

    def __init__(self, path: str) -> None:
        import mmap

        with open(path, "r+b") as fh:
            self._map = mmap.mmap(fh.fileno(), self.nbytes())
        self._view = memoryview(self._map)
        self.head = self._view[:self.HEAD].cast("q")   # (a memoryview reads faster than numpy)
        self._taken = 0   # the worker's count (the master reads head[1])

    @classmethod
    def nbytes(cls) -> int:
        return cls.HEAD + cls.SLOTS * cls.SLOT_BYTES

    def fits(self, n: int) -> bool:
        return n <= self.SLOT_BYTES - 8

    # -- the master's side
    def full(self) -> bool:
        head = self.head
        return head[0] - head[1] >= self.SLOTS

    def empty(self) -> bool:
        """Every message written has been taken."""
        head = self.head
        return head[0] == head[1]

    def put(self, data: bytes) -> bool:
        """Write a message (room checked by the caller: not :meth:`full`); True when the
        worker is blocked on its socket (wake it)."""
        head = self.head
        k = head[0]
        off = self.HEAD + (k % self.SLOTS) * self.SLOT_BYTES
        self._map[off:off + 8 + len(data)] = len(data).to_bytes(8, "little") + data
        head[0] = k + 1
        return head[2] != 0

    # -- the worker's side
    def take(self) -> Optional[bytes]:
        """The next message, or None."""
        k = self._taken
        if self.head[0] == k:
            return None
        off = self.HEAD + (k % self.SLOTS) * self.SLOT_BYTES
        n = int.from_bytes(self._map[off:off + 8], "little")
        data = self._map[off + 8:off + 8 + n]
        self._taken = k + 1
        self.head[1] = k + 1
        return data

    def blocked(self, flag: bool) -> None:
        self.head[2] = int(flag)

    def close(self) -> None:
        self.head.release()
        self._view.release()
        self.head = self._view = None
        try:
            self._map.close()
        except BufferError:
            pass


#: the shared-memory channels rely on stores becoming visible to the other process in program
#: order, which x86 guarantees (total store order); on other machines (ARM, POWER) the writes
#: could be seen out of order without barriers, which Python cannot issue: the socket is used
STORE_ORDERED = platform.machine().lower() in ("x86_64", "amd64", "i386", "i686", "x86")


def _shared_file(label: str, nbytes: int, attach: Callable[[str], None]) -> bool:
    """Make a zeroed file of ``nbytes`` in ``/dev/shm`` and let ``attach(path)`` map it (the worker
    and this process); the file is removed right after (both sides keep their mapping, nothing
    is left behind). False when there is no ``/dev/shm`` or the machine does not keep the order
    of stores (:data:`STORE_ORDERED`): the messages and outputs then go through the socket."""
    if not STORE_ORDERED or not os.path.isdir("/dev/shm"):
        return False
    import tempfile

    try:
        fd, path = tempfile.mkstemp(prefix=f"immersim_{os.getpid()}_{label}_", dir="/dev/shm")
    except OSError:   # /dev/shm full or not ours: the socket it is
        return False
    try:
        try:
            with os.fdopen(fd, "wb") as fh:
                fh.truncate(nbytes)
        except OSError as exc:   # EFBIG under a file-size limit (ulimit -f), ENOSPC: the socket it is
            log.info("shared memory %s not used: %s", path, exc)
            return False
        attach(path)
    finally:
        os.unlink(path)
    return True


# -- the worker side ----------------------------------------------------------------------------
def _serve(conn, config: RemoteConfig) -> None:  # pragma: no cover - runs in the worker process
    """Worker main loop: load units, run their queued calls, reply with outputs."""
    import signal

    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):   # the master acts on them
        signal.signal(sig, signal.SIG_IGN)
    logging.basicConfig(level=logging.WARNING, format="worker %(process)d: %(levelname)s %(name)s: %(message)s")
    from . import fmu

    fmu.IN_WORKER = True   # a unit asking to end the simulation is an error here (FmuInstance._ended)
    units: Dict[str, FmuInstance] = {}
    readers: Dict[str, Any] = {}
    setters: Dict[tuple, Any] = {}
    shared: Dict[str, "_SharedValues"] = {}   # units whose outputs go back through shared memory
    #: slots (master.Slot) of the units this worker steps (Master._ahead) and of the sources of
    #: its chained units: each holds the unit's last two reads (updated at every read)
    slots: Dict[str, Any] = {}
    stepper = Stepper()   # the master's own code steps the units this worker steps
    mailbox: List[_Mailbox] = []   # the master's messages come through it once it is set up
    clock = time.perf_counter_ns

    def slot_of(name: str):
        """The slot of ``name`` (made with the reader's values now)."""
        if name not in slots:
            slot = slots[name] = Slot(name, units[name], readers[name].names, reader=readers[name])
            slot.cur = readers[name].read()
            slot.stepped = True   # a chained unit reads its sources fresh, after their step
        return slots[name]

    def answer(name: str, msg: tuple, values, t0: int) -> Optional[tuple]:
        sv = shared.get(name) if msg[-2] else None
        if sv is not None:   # the outputs through shared memory: no message
            sv.put(msg[-1], values, clock() - t0)
            return None
        return name, "ok", (values, clock() - t0)

    def handle(msg: tuple) -> Optional[tuple]:
        op, name = msg[0], msg[1]
        try:
            if op == "step":         # ("step", unit, t_ns, h_ns, inputs or None, read?, sequence number)
                t0 = clock()
                slot = slots[name]
                stepper.step_slot(slot, msg[2], msg[3], msg[4])
                return answer(name, msg, slot.cur, t0)
            if op == "run":          # ("run", unit, queued calls, read?, sequence number)
                t0 = clock()
                inst = units[name]
                for call in msg[2]:
                    kind = call[0]
                    if kind == "reals" or kind == "discrete":
                        setters[name, kind].set(call[1])
                    elif kind == "step":
                        inst.do_step(call[1], call[2])
                    else:            # ("set", {name: value})
                        inst.set_values(call[1])
                values = readers[name].read() if msg[3] else None
                if values is not None and name in slots:
                    slot = slots[name]
                    slot.prev, slot.cur = slot.cur, values
                return answer(name, msg, values, t0)
            if op == "stepping":     # ("stepping", unit, spec): this worker steps the unit (Master._ahead)
                spec, slot = msg[2], slot_of(name)
                slot.setter, slot.other_setter = setters.get((name, "reals")), setters.get((name, "discrete"))
                slot.in_vals, slot.rest_idx = list(spec["in_vals"]), spec["rest_idx"]
                if spec["chained"]:   # inputs gathered here, from its sources' slots
                    slot.float_feeds = [(i, slot_of(src), j, False, gain, offset, linear)
                                        for i, src, j, gain, offset, linear in spec["float_feeds"]]
                    slot.other_feeds = [(var, slot_of(src), j) for var, src, j in spec["other_feeds"]]
                    slot.has_inputs = True
                return name, "ok", None
            if op == "finish":       # ("finish", unit): catch up a lazy skip; the skipped steps
                slot = slots[name]
                stepper.catch_up(slot)
                return name, "ok", slot.skipped_steps
            if op == "mailbox":      # ("mailbox", "", file): the master's messages come through it
                mailbox.append(_Mailbox(msg[2]))
                return name, "ok", None
            if op == "load":         # ("load", unit, path, unzip dir)
                units[name] = FmuInstance(name, msg[2], msg[3])
                return name, "ok", os.getpid()
            if op == "reader":       # ("reader", unit, names, check_finite)
                readers[name] = units[name].reader(msg[2], msg[3])
                return name, "ok", readers[name].names
            if op == "shared":       # ("shared", unit, file, layout): outputs through that file
                shared[name] = _SharedValues(msg[2], msg[3])
                return name, "ok", None
            if op == "setter":       # ("setter", unit, names, "reals" | "discrete")
                inst = units[name]
                setters[name, msg[3]] = (inst.real_setter if msg[3] == "reals" else inst.discrete_setter)(msg[2])
                return name, "ok", None
            if op == "call":         # ("call", unit, method, args)
                result = getattr(units[name], msg[2])(*msg[3])
                if msg[2] == "terminate":   # freed: "close" must not free it again
                    del units[name]
                return name, "ok", result
            if op == "close":
                for inst in units.values():
                    inst.terminate()
                units.clear()
                return name, "ok", None
            raise ValueError(f"worker: unknown command {op!r}")
        except BaseException as exc:   # every failure goes back to the master, typed
            if op in ("run", "step") and msg[-2] and name in shared:
                shared[name].fail(msg[-1])   # the master stops waiting there and reads this reply
            return name, "err", _portable(exc)

    next_message = _next_message(conn, config.spin_s, mailbox)
    while True:
        try:
            data = next_message()
        except (EOFError, OSError):
            break
        if not data:   # a wake-up (the master saw this worker blocked)
            continue
        msg = loads(data)
        # ("batch", "", [messages]): several units' steps in one message, one reply each, in order
        if msg[0] == "batch":
            reply = [r for r in map(handle, msg[2]) if r is not None]
        else:
            reply = handle(msg)
        if reply is None or reply == []:   # every output went through shared memory
            continue
        try:
            conn.send_bytes(dumps(reply, 5))
        except (EOFError, OSError):
            break
        if msg[0] == "close":
            break
    for sv in shared.values():
        sv.close()
    for box in mailbox:
        box.close()
    conn.close()
    logging.shutdown()
    os._exit(0)   # all is flushed and closed: the interpreter's teardown would only cost time


class WorkerProcess:
    """One worker process and its pipe (see the module docstring).

    Parameters
    ----------
    number : int
        The ``process`` number of its units (>= 1), for messages.
    config : RemoteConfig
    """

    def __init__(self, number: int, config: RemoteConfig = RemoteConfig()) -> None:
        self.number = number
        self.proc, self.conn = start_child(__name__, repr(config.spin_s))
        self._send = message_sender(self.conn)
        self.closed = False
        self._ready = _readable(self.conn, config.spin_s)   # the master waits for a reply the same way
        #: messages held for one batch (:meth:`send` with ``hold``, then :meth:`flush`)
        self._outbox: List[tuple] = []
        self._outbox_err: Optional[tuple] = None   # (unit, function, time) for a failed flush
        #: replies read but not taken yet, by unit (a unit has at most one message outstanding)
        self._arrived: Dict[str, tuple] = {}
        self._box: Optional[_Mailbox] = None   # the master's messages through shared memory

        def attach(path: str) -> None:
            self.call("", "mailbox", path, function="mailbox")
            self._box = _Mailbox(path)

        try:
            _shared_file(f"mailbox{number}", _Mailbox.nbytes(), attach)
        except Exception:
            self.close()
            raise

    def send(self, msg: tuple, function: str = "", t_ns: Optional[int] = None, hold: bool = False) -> None:
        """Send ``msg`` now, or with ``hold`` keep it for the next :meth:`flush` (several units'
        steps then travel as one message)."""
        self._outbox.append(msg)
        if self._outbox_err is None:
            self._outbox_err = (msg[1], function or msg[0], t_ns)
        if not hold:
            self.flush()

    def flush(self) -> None:
        """Send the held messages: one as it is, several as one batch."""
        box = self._outbox
        if not box:
            return
        msg = box[0] if len(box) == 1 else ("batch", "", list(box))
        unit, function, t_ns = self._outbox_err
        self._outbox, self._outbox_err = [], None
        data, mb = dumps(msg, 5), self._box
        try:
            if mb is not None and mb.fits(len(data)):
                if mb.full():
                    self._wait_box(mb.full, unit, function, t_ns)
                if mb.put(data):    # the worker is blocked on its socket: wake it
                    self._send(b"")
                return
            if mb is not None:      # too long for a slot: after every message of the mailbox
                self._wait_box(lambda: not mb.empty(), unit, function, t_ns)
            self._send(data)
        except (OSError, EOFError, ValueError):
            raise self._died(unit, function, t_ns) from None

    def _wait_box(self, busy: Callable[[], bool], unit: str, function: str, t_ns: Optional[int]) -> None:
        """Wait while ``busy()`` (the mailbox is full, or not empty yet), checking now and then
        that the worker is alive."""
        k = 0
        while busy():
            k += 1
            if not k & 1023 and self.proc.poll() is not None:
                raise self._died(unit, function, t_ns)
            os.sched_yield()

    def receive(self, unit: str, function: str, t_ns: Optional[int]) -> Any:
        """The reply to ``unit``'s outstanding message (replies are routed by unit: a batch's or
        another unit's reply read first is kept for its unit); raises the worker's exception,
        or FmuCallError when the worker is gone."""
        self.flush()
        arrived = self._arrived
        while unit not in arrived:
            try:
                self._ready()
                reply = loads(self.conn.recv_bytes())
            except (EOFError, OSError, ValueError):
                raise self._died(unit, function, t_ns) from None
            for name, kind, payload in (reply if isinstance(reply, list) else (reply,)):
                arrived[name] = (kind, payload)
        kind, payload = arrived.pop(unit)
        if kind == "err":
            raise _rebuild(payload)
        return payload

    def call(self, unit: str, op: str, *args: Any, function: str = "", t_ns: Optional[int] = None) -> Any:
        self.send((op, unit) + args)
        return self.receive(unit, function or op, t_ns)

    def _died(self, unit: str, function: str, t_ns: Optional[int]) -> FmuCallError:
        try:
            code = self.proc.wait(timeout=1.0)
        except Exception:
            code = None
        return FmuCallError(unit, function, t_ns or 0, 4,
                            f"worker process {self.number} (pid {self.proc.pid}) ended"
                            + (f" with exit code {code}" if code is not None else ""))

    def close(self) -> None:
        """Terminate its units and end the process (errors are logged, not raised)."""
        if self.closed:
            return
        self.closed = True
        try:
            if self.proc.poll() is None:
                self.call("", "close")
        except Exception as exc:
            log.debug("worker %d: close failed: %s", self.number, exc)
        self.conn.close()
        if self._box is not None:
            self._box.close()
            self._box = None
        try:
            self.proc.wait(timeout=5.0)
        except Exception:
            self.proc.kill()
            self.proc.wait(timeout=5.0)


#: what a posted step's errors name as the function: its inputs, doStep and output read
_RUN = "fmi2DoStep/read"


class RemoteReader:
    """The outputs of a :class:`RemoteInstance`: :meth:`read` posts its queued calls (if not
    posted yet) and returns the values of the reply. The worker's reader checks them."""

    check_finite = True

    def __init__(self, inst: "RemoteInstance", names: Sequence[str], check_finite: bool) -> None:
        self.inst = inst
        self.names = inst.worker.call(inst.name, "reader", list(names), True, function="reader")
        fams = [inst.var(n).family for n in self.names]
        if "string" not in fams:   # the outputs through shared memory
            layout = (fams.count("float"), fams.count("int"), fams.count("bool"))

            def attach(path: str) -> None:
                inst.worker.call(inst.name, "shared", path, layout, function="reader")
                inst.shared = _SharedValues(path, layout)

            _shared_file(inst.name, _SharedValues.nbytes(layout), attach)

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

    def __init__(self, name: str, path: Path | str, unzip_dir: Optional[Path], worker: WorkerProcess) -> None:
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
        self.shared: Optional[_SharedValues] = None
        if not self.path.exists():
            raise FmuLoadError(f"unit {name}: FMU file {self.path} does not exist")
        md, self.variables = read_model(self.path, name)
        self.model_description = md
        self.fmi_version = md.fmiVersion
        self._unzip = str(unzip_dir) if unzip_dir else None
        self._loading = False

    # -- loading (split so that workers load while the master loads its own units) --------------
    def start_loading(self) -> None:
        self.worker.send(("load", self.name, str(self.path), self._unzip))
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
        values, busy = self.worker.receive(self.name, _RUN, start)
        self.busy_ns += busy
        return values

    def _wait_shared(self, seq: int, start: int) -> bool:
        """Wait for the worker to write the outputs of post ``seq`` (polling the shared
        header, yielding the core between polls, checking now and then that the worker is
        alive). True when they are there, False when the step failed (its error is a reply)."""
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
        if self.shared is not None:
            self.shared.close()
            self.shared = None


if __name__ == "__main__":  # pragma: no cover - a worker process (WorkerProcess starts it)
    import sys
    from multiprocessing.connection import Connection

    _serve(Connection(int(sys.argv[1])), RemoteConfig(spin_s=float(sys.argv[2])))
