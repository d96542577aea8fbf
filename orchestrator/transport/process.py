"""Worker processes: the master's side of the pipe to each one.

A unit given ``process = N`` is loaded by worker process N (:mod:`.worker`, a fresh
interpreter talking over a socket pair); units with the same N share a worker. Messages are
plain pickles (protocol 5): the master's through the worker's :class:`~.shm.Mailbox` when it
fits, else the socket; replies through the socket (or a unit's :class:`~.shm.SharedValues`).
An exception raised in the worker is rebuilt here with its type and message; a worker that
dies gives an :class:`~immersim.orchestrator.errors.FmuCallError` naming unit, call and time.
"""
from __future__ import annotations

import builtins
import logging
import os
import time
from dataclasses import dataclass
from pickle import dumps, loads
from typing import Any, Callable, Dict, List, Optional

from .. import errors as _errors
from ..child import message_sender, start_child
from ..errors import FmuCallError
from .shm import Mailbox, shared_file

log = logging.getLogger(__name__)

WORKER_MODULE = "immersim.orchestrator.transport.worker"


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
def portable(exc: BaseException) -> tuple:
    """An exception as (module, class name, message, attributes): plain data for the pipe
    (messages are plain pickles, protocol 5, not ``Connection.send``'s ForkingPickler)."""
    attrs = {k: v for k, v in vars(exc).items() if isinstance(v, (str, int, float, bool, type(None)))}
    return type(exc).__module__, type(exc).__name__, str(exc), attrs


def rebuild(data: tuple) -> BaseException:
    """The exception of :func:`portable`: our own error types and builtins keep their type and
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
        self.proc, self.conn = start_child(WORKER_MODULE, repr(config.spin_s))
        self._send = message_sender(self.conn)
        self.closed = False
        self._ready = _readable(self.conn, config.spin_s)   # the master waits for a reply the same way
        #: messages held for one batch (:meth:`send` with ``hold``, then :meth:`flush`)
        self._outbox: List[tuple] = []
        self._outbox_err: Optional[tuple] = None   # (unit, function, time) for a failed flush
        #: replies read but not taken yet, by unit (a unit has at most one message outstanding)
        self._arrived: Dict[str, tuple] = {}
        self._box: Optional[Mailbox] = None   # the master's messages through shared memory

        def attach(path: str) -> None:
            self.call("", "mailbox", path, function="mailbox")
            self._box = Mailbox(path)

        try:
            shared_file(f"mailbox{number}", Mailbox.nbytes(), attach)
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
            raise rebuild(payload)
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

