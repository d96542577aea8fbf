"""The MCAP log of a run, written in the master's process or in a log-writer process.

A run's log is described once, at set-up, by a :class:`LogPlan`: plain data (metadata, the
channels with the slots and variables they log, the parameter messages, the 3D view's bodies
with their signals as (slot, variable) positions). :class:`LogWriter` turns a plan into an
open :class:`~immersim.orchestrator.observers.McapObserver` (plus the
:class:`~immersim.orchestrator.foxglove.FoxgloveObserver`) and writes one step from the slots'
current values, ``step(k, t_ns, values)`` with ``values[i]`` the values of slot ``i``.

With ``[log] process = true`` the same :class:`LogWriter` runs in a fresh interpreter
(:class:`LogProcess`, ``python -m immersim.orchestrator.logwriter FD``): the master pickles
each step's value lists (~3 kB for campus_drive, a few microseconds) into a socket and goes
on stepping, while the other process encodes the messages, compresses the chunks and writes
the file. The log is the same, byte for byte, as the one the master's process writes
(``tests/orchestrator/test_logwriter.py``).

Failures keep the rules of the in-process log:

* A file that cannot be opened fails at set-up with the same :class:`LogWriteError`.
* A write that fails (full disk) is reported by the writer with its message (path, time); the
  master raises it as :class:`LogWriteError` at its next step or at the close. The log keeps
  every step the writer finished before it.
* The writer ignores SIGINT, SIGTERM and SIGHUP (the master acts on them between steps and
  closes the log). When the master dies, its socket closes and the writer finishes the file
  with every step it got.
* A writer that dies gives a :class:`LogWriteError` naming the file, its exit code and the time.
"""
from __future__ import annotations

import logging
import sys
import time
from dataclasses import dataclass, field
from pickle import dumps, loads
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple

from .child import start_child
from .errors import LogWriteError
from .observers import McapObserver, write_parameters

log = logging.getLogger(__name__)


@dataclass
class LogPlan:
    """Everything a :class:`LogWriter` needs to open a run's log (picklable).

    Attributes
    ----------
    path : str
        The MCAP file.
    encoding : str
        ``"json"`` or ``"ros1"`` (``[log] encoding``).
    metadata : list of (name, dict)
        Metadata records, written first.
    channels : list of (topic, infos, slot, positions)
        A unit channel: its variables (``VarInfo``), the slot whose values it logs (index in the
        ``values`` of :meth:`LogWriter.step`) and the positions of the logged variables in them
        (None: all, in order).
    parameters : list of (unit, infos, values, t_ns)
        The parameter messages, written once.
    bodies : list of foxglove.Body
        The 3D view (``[[foxglove.bodies]]``); empty: none.
    refs : dict of str -> (slot, position)
        Where each signal the bodies refer to (``"unit.var"``) is in ``values``.
    time_offset_ns : int
        Added to every message's time (a run that starts before t = 0; see ``McapObserver``).
    steps_total : int, optional
        The run's steps (the ``run`` record of a writer whose master died names them).
    """

    path: str
    encoding: str = "json"
    metadata: List[Tuple[str, Dict[str, str]]] = field(default_factory=list)
    channels: List[tuple] = field(default_factory=list)
    parameters: List[tuple] = field(default_factory=list)
    bodies: List[Any] = field(default_factory=list)
    #: meshes the units describe (views.MeshEntity), written once with the 3D view
    meshes: List[Any] = field(default_factory=list)
    #: parts of the view redrawn every step (views.PlatformRods)
    view_steps: List[Any] = field(default_factory=list)
    refs: Dict[str, Tuple[int, int]] = field(default_factory=dict)
    #: added to every message's time (a run from t < 0; see McapObserver)
    time_offset_ns: int = 0
    #: the run's steps, for the ``run`` record a writer left alone writes (its master died)
    steps_total: Optional[int] = None


def _picker(idx: Optional[List[int]]) -> Optional[Callable[[Sequence[Any]], tuple]]:
    """``values -> tuple(values[i] for i in idx)`` (an ``itemgetter``), None for all values."""
    from operator import itemgetter

    if idx is None:
        return None
    if len(idx) == 1:
        i = idx[0]
        return lambda values: (values[i],)
    return itemgetter(*idx)


class _Values:
    """Where a :class:`LogWriter` in its own process keeps a slot's values of the step (the
    master's slots have the same ``cur``)."""

    __slots__ = ("cur",)

    def __init__(self) -> None:
        self.cur: Sequence[Any] = ()


class _Signal:
    """``signal()``: the current value of variable ``index`` of ``source`` (a slot, whose
    ``cur`` is replaced at each read); the 3D view reads ``source.cur[index]`` directly."""

    __slots__ = ("source", "index")

    def __init__(self, source: Any, index: int) -> None:
        self.source, self.index = source, index

    def __call__(self) -> Any:
        return self.source.cur[self.index]


class LogWriter:
    """Opens the log of a :class:`LogPlan` and writes steps into it.

    Parameters
    ----------
    plan : LogPlan
    flush_seconds : float
        See :class:`~immersim.orchestrator.observers.McapObserver`.
    sources : sequence, optional
        Objects whose ``cur`` holds each slot's current values when a step is written (the
        master's slots: :meth:`write`); None: the values come with each :meth:`step`.
    tee : LiveServer, optional
        See :class:`~immersim.orchestrator.observers.McapObserver`.
    """

    def __init__(self, plan: LogPlan, flush_seconds: float = 1.0, sources: Optional[Sequence[Any]] = None,
                 tee: Any = None) -> None:
        self.path = plan.path
        self.steps_total = plan.steps_total if plan.steps_total is not None else "unknown"
        obs = self.mcap = McapObserver(plan.path, flush_seconds=flush_seconds, encoding=plan.encoding, tee=tee,
                                       time_offset_ns=plan.time_offset_ns)
        for name, data in plan.metadata:
            obs.add_metadata(name, data)
        if sources is None:
            sources = [_Values() for _ in range(1 + max([c[2] for c in plan.channels]
                                                        + [s for s, _ in plan.refs.values()], default=-1))]
        self._sources = sources
        #: (channel id, its encoder's encode, source, picker of its values or None: all)
        self._plan: List[tuple] = []
        for topic, infos, slot, idx in plan.channels:
            cid, encoder = obs.add_channel(topic, infos)
            self._plan.append((cid, encoder.encode, sources[slot], _picker(idx)))
        for unit, infos, values, t_ns in plan.parameters:
            write_parameters(obs, unit, infos, values, t_ns)
        self._view = None   # the 3D view (FoxgloveObserver): /tf with each step, /scene when due
        if plan.bodies:
            from .foxglove import FoxgloveObserver

            def lookup(ref: str) -> Callable[[], Any]:
                return _Signal(sources[plan.refs[ref][0]], plan.refs[ref][1])

            self._view = FoxgloveObserver(obs, plan.bodies, lookup, meshes=plan.meshes, steps=plan.view_steps)

    @property
    def closed(self) -> bool:
        return self.mcap._closed

    def write(self, k: int, t_ns: int) -> None:
        """Log step ``k`` ending at ``t_ns`` from the sources' current values: the units'
        messages and the 3D view's ``/tf`` (and parts redrawn every step) as one step, then
        ``/scene`` when due."""
        items = [(cid, encode(src.cur if pick is None else pick(src.cur))) for cid, encode, src, pick in self._plan]
        view = self._view
        if view is not None:
            items += view.step_items(k, t_ns)
        self.mcap.write_step(t_ns, k, items)
        if view is not None:
            view.scene_due(k, t_ns)

    def step(self, k: int, t_ns: int, values: Sequence[Sequence[Any]]) -> None:
        """:meth:`write` with ``values[i]``, the current values of slot ``i``."""
        for src, v in zip(self._sources, values):
            src.cur = v
        self.write(k, t_ns)

    def close(self, run: Dict[str, Any]) -> None:
        """Write the run's metadata (``run``) and finish the file; raises LogWriteError."""
        obs = self.mcap
        if obs._closed:
            return
        try:
            obs.add_metadata("run", run)
        except OSError:   # add_metadata's LogWriteError names the file once already
            obs._closed = True
            raise
        obs.close()


# -- the log-writer process ---------------------------------------------------------------------
def _serve(conn) -> None:  # pragma: no cover - runs in the writer process
    """The writer process: ``("open", plan)``, then ``("step", k, t_ns, values)`` messages
    (no reply) and ``("close", run)``; replies ``("ok", ...)`` (to the close: with the CPU
    seconds the writer spent since the file was opened) or ``("error", message)``. After a
    failed step it reports the error once and ignores further steps; at the end of its input
    (the master died) it finishes the file."""
    writer: Optional[LogWriter] = None
    failed = False
    opened = 0.0
    last = (0, 0)   # the last step written: (k, t_ns)
    while True:
        try:
            msg = loads(conn.recv_bytes())
        except (EOFError, OSError):
            if writer is not None and not writer.closed:
                try:
                    writer.close({"status": "aborted", "steps_done": last[0], "steps_total": writer.steps_total,
                                  "t_ns": last[1], "reason": "the master process ended without closing the log"})
                except LogWriteError as exc:   # (already reported to the master after a failed step)
                    log.log(logging.DEBUG if failed else logging.ERROR, "%s", exc)
            return
        op = msg[0]
        if op == "steps":
            if failed:
                continue
            try:
                for k, t_ns, values in msg[1]:
                    writer.step(k, t_ns, values)
                    last = (k, t_ns)
            except LogWriteError as exc:
                failed = True
                conn.send_bytes(dumps(("error", str(exc)), 5))
            continue
        try:
            if op == "open":
                writer = LogWriter(msg[1], msg[2])
                opened = time.process_time()
            elif op == "close":
                if writer is not None:
                    writer.close(msg[1])
                conn.send_bytes(dumps(("ok", time.process_time() - opened), 5))
                return
            conn.send_bytes(dumps(("ok",), 5))
        except LogWriteError as exc:
            conn.send_bytes(dumps(("error", str(exc)), 5))
            if op == "close":
                return


class LogProcess:
    """A :class:`LogWriter` in a process of its own (``[log] process = true``).

    Steps are sent ``BATCH`` at a time: a writer that sleeps between messages takes tens of
    microseconds to wake, and the waker pays for it. The pending steps are sent
    before the log is closed, whatever ends the run; only a master killed outright loses
    them (at most ``BATCH`` - 1 steps; the in-process log loses its unfinished chunk then).
    Under ``immersim run``'s supervising parent (:mod:`.supervisor`) each step is sent at
    once, so a master that crashes loses none.

    Parameters
    ----------
    plan : LogPlan
    flush_seconds : float
        See :class:`~immersim.orchestrator.observers.McapObserver`.

    Raises
    ------
    LogWriteError
        The file cannot be opened (the writer's message), or the process did not start.
    """

    BATCH = 8

    def __init__(self, plan: LogPlan, flush_seconds: float = 1.0) -> None:
        import select

        self.path = plan.path
        self.closed = False
        #: CPU seconds the writer spent on the steps and the close (set by a successful :meth:`close`)
        self.cpu_s: Optional[float] = None
        try:
            self.proc, self.conn = start_child(__name__)
        except OSError as exc:
            raise LogWriteError(f"cannot write the log {self.path}: the log-writer process did not start: "
                                f"{exc}") from None
        from . import supervisor

        supervisor.CRUMB[supervisor.WRITER_PID] = self.proc.pid   # a supervising parent waits for it
        if supervisor.supervised():   # a crash of the master then loses no step (each is sent at once)
            self.BATCH = 1
        self._poller = select.poll()
        self._poller.register(self.conn.fileno(), select.POLLIN)
        self._send, self._poll = self.conn.send_bytes, self._poller.poll
        self._t_ns = 0
        self._pending: List[tuple] = []
        try:
            self._send(dumps(("open", plan, flush_seconds), 5))
            self._reply(None)
        except BaseException:
            self.reap()
            raise

    def _reply(self, t_ns: Optional[int]) -> tuple:
        """Wait for the writer's reply; raise its error as LogWriteError."""
        try:
            msg = loads(self.conn.recv_bytes())
        except (EOFError, OSError):
            raise self._died(t_ns) from None
        if msg[0] == "error":
            self.closed = True
            raise LogWriteError(msg[1])
        return msg

    def _broken(self, t_ns: Optional[int]) -> LogWriteError:
        """The writer stopped reading: the error it reported before it ended, if any, else
        that it ended (:meth:`_died`)."""
        try:
            if self._poll(0):
                msg = loads(self.conn.recv_bytes())
                if msg[0] == "error":
                    self.closed = True
                    return LogWriteError(msg[1])
        except (EOFError, OSError):
            pass
        return self._died(t_ns)

    def _died(self, t_ns: Optional[int]) -> LogWriteError:
        self.closed = True
        try:
            code = self.proc.wait(timeout=5)
        except Exception:  # noqa: BLE001 - still running: report what is known
            code = None
        at = f" at t = {t_ns / 1e9:.9g} s" if t_ns is not None else ""
        return LogWriteError(f"cannot write the log {self.path}{at}: the log-writer process ended "
                             f"(exit code {code})")

    def step(self, k: int, t_ns: int, values: Sequence[Sequence[Any]]) -> None:
        """Hand step ``k`` to the writer (sent with the next ``BATCH`` - 1 steps); raises the
        error the writer reported for an earlier step."""
        self._pending.append((k, t_ns, values))
        self._t_ns = t_ns
        if len(self._pending) >= self.BATCH:
            self.flush()

    def flush(self) -> None:
        """Send the pending steps now."""
        if self._poll(0):   # the writer only speaks after a failure (or when it died)
            self._reply(self._t_ns)
        if self._pending:
            try:
                self._send(dumps(("steps", self._pending), 5))
            except OSError:
                raise self._broken(self._t_ns) from None
            self._pending = []

    def close(self, run: Dict[str, Any]) -> None:
        """Write the run's metadata, finish the file, wait for the writer; raises LogWriteError."""
        if self.closed:
            return
        try:
            self.flush()
            try:
                self._send(dumps(("close", run), 5))
            except OSError:
                raise self._broken(self._t_ns) from None
            self.cpu_s = self._reply(self._t_ns)[1]
        finally:
            self.closed = True
            self.conn.close()

    def reap(self) -> None:
        """Wait for the writer process to exit (after :meth:`close`, which returns as soon as
        the file is complete); a writer still running then (after a failure) is stopped, and
        it finishes the file at the end of its input."""
        self.closed = True
        self.conn.close()   # (again: closing a closed connection does nothing)
        try:
            self.proc.wait(timeout=60)
        except Exception:  # noqa: BLE001 - never hang the master on its writer
            self.proc.kill()
            self.proc.wait()


def _main(argv: List[str]) -> None:  # pragma: no cover - runs in the writer process
    import signal
    from multiprocessing.connection import Connection

    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):   # the master acts on them
        signal.signal(sig, signal.SIG_IGN)
    logging.basicConfig(level=logging.WARNING, format="immersim log writer: %(message)s")
    _serve(Connection(int(argv[0])))


if __name__ == "__main__":  # pragma: no cover
    _main(sys.argv[1:])
