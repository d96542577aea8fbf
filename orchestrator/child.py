"""Helper processes of a run: a fresh interpreter running one of our modules, talking over a
socket pair (the worker processes of :mod:`.transport`, the log writer of :mod:`.logwriter`)."""
from __future__ import annotations

import os
import socket
import struct
import subprocess
import sys
from multiprocessing.connection import Connection
from typing import Callable, Tuple

_LENGTH = struct.Struct("!i")


def start_child(module: str, *args: str) -> Tuple[subprocess.Popen, Connection]:
    """Start ``python -m module FD *args``, FD its end of a socket pair.

    A fresh interpreter, not ``multiprocessing``'s *spawn*, which imports the caller's
    ``__main__`` again (a script without a main guard would run twice); nothing else is
    inherited (``close_fds``, stdin from /dev/null). The child wraps FD in a
    ``multiprocessing.connection.Connection``.

    Returns
    -------
    (process, connection)
        The child and this side's end, as a ``Connection``.

    Raises
    ------
    OSError
        The process did not start (both ends are closed then).
    """
    ours, theirs = socket.socketpair()
    fd = theirs.fileno()
    try:
        proc = subprocess.Popen([sys.executable, "-m", module, str(fd), *args], pass_fds=(fd,), close_fds=True,
                                stdin=subprocess.DEVNULL)
    except BaseException:
        ours.close()
        raise
    finally:
        theirs.close()
    return proc, Connection(ours.detach())


def message_sender(conn: Connection) -> Callable[[bytes], None]:
    """``send(data)``: ``conn.send_bytes(data)`` (the same bytes: ``multiprocessing``'s 4-byte
    big-endian length, then the data) in one ``os.write`` without the ``Connection``'s checks
    and copies around it. Raises ``OSError`` as ``send_bytes``
    does when the other end is gone; ``ValueError`` when ``conn`` is closed."""
    write, fd, length = os.write, conn.fileno(), _LENGTH.pack

    def send(data: bytes) -> None:
        if conn.closed or len(data) > 0x7FFFFFF0:   # closed: its error; huge: multiprocessing's framing
            conn.send_bytes(data)
            return
        buf = length(len(data)) + data
        while buf:
            buf = buf[write(fd, buf):]
    return send
