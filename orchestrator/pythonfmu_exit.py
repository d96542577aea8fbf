"""Let a process that loaded pythonfmu FMUs exit normally.

The problem (pythonfmu 0.7.0's binary, ``libpythonfmu-export.so``, copied into every FMU):
the binary keeps its Python state in a namespace-scope ``std::shared_ptr<PyState>`` and resets
it from an ``__attribute__((destructor))`` function, ``onLibraryUnload`` ->
``finalizePythonInterpreter()``. The binary exports STL "unique" symbols, so glibc never
unloads it (``dlclose`` is a no-op) and both run at process exit, in this order:
``exit()`` first runs the handlers registered with ``__cxa_atexit`` (the shared_ptr's
destructor: it frees the ``PyState`` block), and only then ``_dl_fini`` calls the library's
destructor functions, which assign ``nullptr`` to the destroyed shared_ptr and so release the
freed block a second time. valgrind reports it as an invalid read in
``finalizePythonInterpreter`` of a 128-byte block freed in ``__run_exit_handlers`` and
allocated in ``pythonfmu::createInstance``. When that memory has been reused by then, the
write corrupts the heap and glibc aborts the process after all its work is done ("corrupted
double-linked list", exit 134), more often the more FMU copies a process loaded (one
per extracted FMU: a test suite, a benchmark, a sweep worker).

The fix: while the interpreter is still running (an :mod:`atexit` handler), call each loaded
copy's exported ``finalizePythonInterpreter()`` ourselves. The shared_ptr is then empty when its
destructor and the library's destructor run, and neither frees anything. Instances still alive
keep their own references to the state; an FMU instantiated later makes a new one. This covers
every loader in the process (our wrapper, plain FMPy, OSP libcosim), since the loaded copies are
found in the process's memory map, not in our own bookkeeping.
"""
from __future__ import annotations

import atexit
import ctypes
import logging
import os
from typing import List

log = logging.getLogger(__name__)

#: the exported function that resets the binary's Python state (pythonfmu >= 0.6.3)
_RESET = "finalizePythonInterpreter"
#: a pythonfmu binary also exports one of these (FMI 2.0 / FMI 3.0)
_FMI_ENTRY = ("fmi2Instantiate", "fmi3InstantiateCoSimulation")


class _PhdrInfo(ctypes.Structure):
    """The leading fields of glibc's ``struct dl_phdr_info``."""

    _fields_ = [("dlpi_addr", ctypes.c_void_p), ("dlpi_name", ctypes.c_char_p)]


_PHDR_CALLBACK = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.POINTER(_PhdrInfo), ctypes.c_size_t, ctypes.c_void_p)


def _loaded_objects() -> List[str]:
    """The names of the shared objects loaded in this process, as the dynamic linker knows them
    (``dl_iterate_phdr``): ``dlopen`` of such a name with ``RTLD_NOLOAD`` returns the loaded
    object even when its file was deleted since (FMPy removes an FMU's extracted folder)."""
    try:
        iterate = ctypes.CDLL(None).dl_iterate_phdr
    except (OSError, AttributeError):   # not glibc
        return []
    names: List[str] = []

    def collect(info, size, data):
        name = info.contents.dlpi_name
        if name:
            names.append(os.fsdecode(name))
        return 0

    iterate(_PHDR_CALLBACK(collect), None)
    return names


def release_pythonfmu_states() -> List[str]:
    """Reset the Python state of every loaded pythonfmu binary (see the module docstring).

    Safe to call at any time and more than once: FMU instances alive keep their own reference,
    and the next ``fmi2Instantiate`` of a binary makes a new state.

    Returns
    -------
    list of str
        The paths of the binaries whose state was reset.
    """
    done = []
    noload = getattr(os, "RTLD_NOLOAD", 0)
    if not noload:
        return done
    for path in _loaded_objects():
        try:
            lib = ctypes.CDLL(path, mode=noload | os.RTLD_LAZY)   # already loaded: same handle
            reset = getattr(lib, _RESET)
        except (OSError, AttributeError):
            continue
        if not any(hasattr(lib, name) for name in _FMI_ENTRY):
            continue
        reset.restype = None
        reset()
        done.append(path)
    if done:
        log.debug("reset the Python state of %d pythonfmu binaries before exit", len(done))
    return done


def install() -> None:
    """Register :func:`release_pythonfmu_states` to run at interpreter exit (once per process)."""
    global _installed
    if not _installed:
        atexit.register(release_pythonfmu_states)
        _installed = True


_installed = False
