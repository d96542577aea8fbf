"""The worker process (``python -m immersim.orchestrator.transport.worker FD SPIN_S``).

It loads units, runs their queued calls and steps the units the master posts to it with the
master's own :class:`~immersim.orchestrator.stepping.Stepper`, replying with their outputs.
Every call goes through a real ``FmuInstance`` (same checks and messages); an exception goes
back typed (:func:`~.process.portable`). It ignores SIGINT, SIGTERM and SIGHUP (the master acts
on them between steps) and ends when its pipe closes or the master says ``close``.
"""
from __future__ import annotations

import logging
import os
import time
from pickle import dumps, loads
from typing import Any, Callable, Dict, List, Optional

from .. import fmu
from ..fmu import FmuInstance
from ..stepping import FloatFeed, OtherFeed, Slot, Stepper
from .process import RemoteConfig, portable
from .shm import Mailbox, SharedValues


def next_message(conn, spin_s: float, mailbox: List[Mailbox]) -> Callable[[], bytes]:
    """The worker's next message: from the master's mailbox (``mailbox``: empty until the
    master sets one up) or the socket, in the master's order (a message goes through the socket
    only when the mailbox is empty). It polls both for ``spin_s`` seconds, yielding the core
    between polls, then blocks on the socket, flagged in the mailbox. An empty message is a
    wake-up."""
    import select

    poller = select.poll()
    poller.register(conn.fileno(), select.POLLIN)
    poll, yield_cpu, now = poller.poll, os.sched_yield, time.perf_counter

    def take() -> bytes:
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
    return take


class Worker:  # pragma: no cover - runs in the worker process
    """The worker's units and the handler of each command (``op_<command>``); a handler
    returns the reply ``(unit, "ok", payload)``, or None when the outputs went through
    shared memory."""

    def __init__(self) -> None:
        self.units: Dict[str, FmuInstance] = {}
        self.readers: Dict[str, Any] = {}
        self.setters: Dict[tuple, Any] = {}
        self.shared: Dict[str, SharedValues] = {}   # units whose outputs go back through shared memory
        #: slots of the units this worker steps and of the sources of its chained units: each
        #: holds the unit's last two reads (updated at every read)
        self.slots: Dict[str, Slot] = {}
        self.stepper = Stepper()
        self.mailbox: List[Mailbox] = []   # the master's messages come through it once it is set up
        self.clock = time.perf_counter_ns

    def slot_of(self, name: str) -> Slot:
        """The slot of ``name`` (made with the reader's values now)."""
        if name not in self.slots:
            reader = self.readers[name]
            slot = self.slots[name] = Slot(name, self.units[name], reader.names, reader=reader)
            slot.cur = reader.read()
            slot.stepped = True   # a chained unit reads its sources fresh, after their step
        return self.slots[name]

    def answer(self, name: str, msg: tuple, values: Any, t0: int) -> Optional[tuple]:
        """The reply to a step or run: ``(values, busy ns)``, and the ends of the simulation its
        unit asked for (``fmu.ENDED``, moved here) as a third item; the outputs of a step that
        ended nothing through shared memory when set up (no message)."""
        sv = self.shared.get(name) if msg[-2] else None
        if fmu.ENDED:   # the master ends the run after this step: the reply says so
            ended, fmu.ENDED[:] = list(fmu.ENDED), []
            if sv is not None:
                sv.fail(msg[-1])   # the master reads this reply
            return name, "ok", (values, self.clock() - t0, ended)
        if sv is not None:   # the outputs through shared memory: no message
            sv.put(msg[-1], values, self.clock() - t0)
            return None
        return name, "ok", (values, self.clock() - t0)

    def handle(self, msg: tuple) -> Optional[tuple]:
        op, name = msg[0], msg[1]
        try:
            handler = getattr(self, "op_" + op, None)
            if handler is None:
                raise ValueError(f"worker: unknown command {op!r}")
            return handler(name, msg)
        except BaseException as exc:   # every failure goes back to the master, typed
            if op in ("run", "step") and msg[-2] and name in self.shared:
                self.shared[name].fail(msg[-1])   # the master stops waiting there and reads this reply
            return name, "err", portable(exc)

    def op_step(self, name: str, msg: tuple) -> Optional[tuple]:
        """("step", unit, t_ns, h_ns, inputs or None, read?, sequence number)"""
        t0 = self.clock()
        slot = self.slots[name]
        self.stepper.step_slot(slot, msg[2], msg[3], msg[4])
        return self.answer(name, msg, slot.cur, t0)

    def op_run(self, name: str, msg: tuple) -> Optional[tuple]:
        """("run", unit, queued calls, read?, sequence number)"""
        t0 = self.clock()
        inst = self.units[name]
        for call in msg[2]:
            kind = call[0]
            if kind == "reals" or kind == "discrete":
                self.setters[name, kind].set(call[1])
            elif kind == "step":
                inst.do_step(call[1], call[2])
            else:            # ("set", {name: value})
                inst.set_values(call[1])
        values = self.readers[name].read() if msg[3] else None
        if values is not None and name in self.slots:
            slot = self.slots[name]
            slot.prev, slot.cur = slot.cur, values
        return self.answer(name, msg, values, t0)

    def op_stepping(self, name: str, msg: tuple) -> tuple:
        """("stepping", unit, spec): this worker steps the unit (``Master._ahead``)."""
        spec, slot = msg[2], self.slot_of(name)
        ins = slot.inputs
        ins.setter, ins.other_setter = self.setters.get((name, "reals")), self.setters.get((name, "discrete"))
        ins.values, slot.lazy.rest_idx = list(spec["in_vals"]), spec["rest_idx"]
        if spec["chained"]:   # inputs gathered here, from its sources' slots
            ins.float_feeds = [FloatFeed(i, self.slot_of(src), j, False, gain, offset, mode)
                               for i, src, j, gain, offset, mode in spec["float_feeds"]]
            ins.other_feeds = [OtherFeed(var, self.slot_of(src), j) for var, src, j in spec["other_feeds"]]
            ins.active = True
        return name, "ok", None

    def op_finish(self, name: str, msg: tuple) -> tuple:
        """("finish", unit): catch up a lazy skip; replies the skipped steps."""
        slot = self.slots[name]
        self.stepper.catch_up(slot)
        return name, "ok", slot.skipped_steps

    def op_mailbox(self, name: str, msg: tuple) -> tuple:
        """("mailbox", "", file): the master's messages come through it."""
        self.mailbox.append(Mailbox(msg[2]))
        return name, "ok", None

    def op_load(self, name: str, msg: tuple) -> tuple:
        """("load", unit, path, unzip dir, variables or None: those of the model description)"""
        inst = self.units[name] = FmuInstance(name, msg[2], msg[3])
        if msg[4] is not None:   # FMI 3.0 arrays sized by structural parameters
            inst.variables = msg[4]
        return name, "ok", os.getpid()

    def op_reader(self, name: str, msg: tuple) -> tuple:
        """("reader", unit, names, check_finite)"""
        self.readers[name] = self.units[name].reader(msg[2], msg[3])
        return name, "ok", self.readers[name].names

    def op_shared(self, name: str, msg: tuple) -> tuple:
        """("shared", unit, file, layout): the unit's outputs through that file."""
        self.shared[name] = SharedValues(msg[2], msg[3])
        return name, "ok", None

    def op_setter(self, name: str, msg: tuple) -> tuple:
        """("setter", unit, names, "reals" | "discrete")"""
        inst = self.units[name]
        self.setters[name, msg[3]] = (inst.real_setter if msg[3] == "reals" else inst.discrete_setter)(msg[2])
        return name, "ok", None

    def op_call(self, name: str, msg: tuple) -> tuple:
        """("call", unit, method, args)"""
        result = getattr(self.units[name], msg[2])(*msg[3])
        if msg[2] == "terminate":   # freed: "close" must not free it again
            del self.units[name]
        return name, "ok", result

    def op_close(self, name: str, msg: tuple) -> tuple:
        for inst in self.units.values():
            inst.terminate()
        self.units.clear()
        return name, "ok", None

    def close(self) -> None:
        for sv in self.shared.values():
            sv.close()
        for box in self.mailbox:
            box.close()


def serve(conn, config: RemoteConfig) -> None:  # pragma: no cover - runs in the worker process
    """Worker main loop: take each message (a ``("batch", "", [messages])`` gets one reply per
    message, in order) and send the replies that did not go through shared memory."""
    import signal

    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):   # the master acts on them
        signal.signal(sig, signal.SIG_IGN)
    logging.basicConfig(level=logging.WARNING, format="worker %(process)d: %(levelname)s %(name)s: %(message)s")
    worker = Worker()
    take = next_message(conn, config.spin_s, worker.mailbox)
    while True:
        try:
            data = take()
        except (EOFError, OSError):
            break
        if not data:   # a wake-up (the master saw this worker blocked)
            continue
        msg = loads(data)
        if msg[0] == "batch":
            reply = [r for r in map(worker.handle, msg[2]) if r is not None]
        else:
            reply = worker.handle(msg)
        if reply is None or reply == []:   # every output went through shared memory
            continue
        try:
            conn.send_bytes(dumps(reply, 5))
        except (EOFError, OSError):
            break
        if msg[0] == "close":
            break
    worker.close()
    conn.close()
    logging.shutdown()
    os._exit(0)   # all is flushed and closed: the interpreter's teardown would only cost time


if __name__ == "__main__":  # pragma: no cover - a worker process (WorkerProcess starts it)
    import sys
    from multiprocessing.connection import Connection

    serve(Connection(int(sys.argv[1])), RemoteConfig(spin_s=float(sys.argv[2])))
