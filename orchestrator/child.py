"""Helper processes of a run: a fresh interpreter running one of our modules, talking over a
socket pair (the worker processes of :mod:`.remote`, the log writer of :mod:`.logwriter`)."""
from __future__ import annotations

import socket
import subprocess
import sys
from multiprocessing.connection import Connection
from typing import Tuple


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
