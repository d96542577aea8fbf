"""Shared memory between the master and a worker process (``/dev/shm`` file mappings).

:class:`Mailbox` carries the master's messages to a worker, :class:`SharedValues` a unit's
outputs back: no system call per message. Both rely on stores becoming visible to the other
process in program order (:data:`STORE_ORDERED`); elsewhere the socket carries everything.
"""
from __future__ import annotations

import logging
import os
import platform
from typing import Any, Callable, List, Optional, Sequence

log = logging.getLogger(__name__)


class SharedValues:
    """A worker unit's outputs in a shared file mapping, instead of a reply.

    Two buffers used in turn (post ``seq`` writes buffer ``seq % 2``), so the worker can answer
    a unit's next post before the master has read the last one. A buffer is float64: a header
    ``[sequence, status, busy ns, 0]``, then the values (Reals, Integers, Booleans in the
    reader's order). The worker writes the values, the status and busy time, and last the
    sequence number the master waits for; status 1: the reply goes through the socket (the
    step failed: its error; or its unit asked to end the simulation).

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


class Mailbox:
    """The master's messages to a worker through a shared file mapping.

    A ring of ``SLOTS`` slots of ``SLOT_BYTES`` after a header of four int64: messages written
    (by the master), messages taken (by the worker), the worker's *blocked* flag, 0. The master
    writes a message's length and bytes into the next slot, then the count; the worker takes
    messages in order. A worker that found nothing for a while sets its flag and blocks on its
    socket; the master then wakes it with an empty socket message, and the blocked worker looks
    at the ring every ``BLOCKED_POLL_MS`` anyway (a late wake, never a lost message). A message
    too long for a slot goes through the socket once every earlier one is taken.
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


def shared_file(label: str, nbytes: int, attach: Callable[[str], None]) -> bool:
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

