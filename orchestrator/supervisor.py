"""A supervising parent for ``immersim run``: a unit that crashes the process still ends the run
with one line and a complete log.

``immersim run`` forks (:func:`supervise`) before it loads anything: the child runs the command,
the parent waits. They share two anonymous mappings: the *crumb* (:data:`CRUMB`: phase, the unit
last called and the time of that call, completed steps, unit names and log path) and the
*journal* (:class:`Journal`: the records of the MCAP chunk not on disk yet). When the child dies
by a signal the parent rebuilds the log (:func:`repair_log`; ``run`` status ``failed`` naming
unit and time), removes the child's temporary files and prints one line (exit status 1). Signals
sent to the parent are passed on to the child; a killed parent takes the child with it
(``PR_SET_PDEATHSIG``), and the next run removes what such runs left (:func:`remove_stale`).
"""
from __future__ import annotations

import ctypes
import glob
import json
import logging
import mmap
import os
import re
import shutil
import signal
import struct
import sys
import tempfile
from typing import Any, Dict, List, Optional

log = logging.getLogger(__name__)

#: crumb fields (int64 each)
SUPERVISED, PHASE, UNIT, T_NS, STEPS, JOURNAL, WRITER_PID, INFO = range(8)
#: phases of the run (crumb[PHASE])
IDLE, LOADING, INITIALIZING, STEPPING, CLOSING = range(5)
_PHASES = {LOADING: "while loading", INITIALIZING: "while initializing", STEPPING: "in a step",
           CLOSING: "while being freed"}
_INFO_AT, _INFO_MAX = 64, 65536 - 64
#: the chunk not yet on disk is at most McapObserver.CHUNK_BYTES plus one step
JOURNAL_BYTES = 32 << 20

_shared = mmap.mmap(-1, 65536)   # MAP_SHARED | MAP_ANONYMOUS: inherited by a fork
CRUMB = memoryview(_shared).cast("B")[:64].cast("q")
_journal_map = mmap.mmap(-1, JOURNAL_BYTES)   # pages are allocated only when written
_units: List[str] = []
_info: Dict[str, Any] = {}


def supervised() -> bool:
    """This process runs under a supervising parent (:func:`supervise`)."""
    return bool(CRUMB[SUPERVISED])


def reset() -> None:
    """Forget the units and the info of an earlier run of this process (a run's start)."""
    _units.clear()
    _info.clear()
    for i in range(1, 8):
        CRUMB[i] = 0
    CRUMB[UNIT] = -1


def unit_id(name: str) -> int:
    """The crumb's number for unit ``name`` (registered on first use; slow path)."""
    if name not in _units:
        _units.append(name)
        note(units=_units)
    return _units.index(name)


def note(**items: Any) -> None:
    """Record facts the parent needs after a crash (the log's path, the scenario, ...)."""
    _info.update(items)
    blob = json.dumps(_info).encode()[:_INFO_MAX]
    _shared[_INFO_AT:_INFO_AT + len(blob)] = blob
    CRUMB[INFO] = len(blob)


def _read_info() -> Dict[str, Any]:
    try:
        return json.loads(bytes(_shared[_INFO_AT:_INFO_AT + CRUMB[INFO]]) or b"{}")
    except ValueError:
        return {}


class Journal:
    """The records of the MCAP chunk in progress, in shared memory (see the module docstring).

    Parameters
    ----------
    stream : file
        The log's file object: flushed before the journal is emptied, so what leaves the
        journal is in the kernel's hands (it survives the process).
    """

    def __init__(self, stream: Any) -> None:
        self.stream = stream
        self.size = 0
        self.full = False
        CRUMB[JOURNAL] = 0

    def append(self, data: Any) -> None:
        """Add the bytes of a step's records (a bytes-like object); nothing once full."""
        if self.full:
            return
        end = self.size + len(data)
        if end > JOURNAL_BYTES:   # a chunk beyond the mapping: the repair says the tail is lost
            self.full = True
            CRUMB[JOURNAL] = -1
            return
        _journal_map[self.size:end] = data
        self.size = CRUMB[JOURNAL] = end

    def committed(self) -> None:
        """The chunk was written: flush the file, empty the journal."""
        self.stream.flush()
        self.size, self.full = 0, False
        CRUMB[JOURNAL] = 0


#: the signals that stop a run between macro steps (SIGINT, SIGTERM, SIGHUP): exit 128 + signal
STOP_SIGNALS = ("SIGINT", "SIGTERM", "SIGHUP")


class DeferredSigint:
    """Turn SIGINT, SIGTERM and SIGHUP into a flag checked between macro steps.

    A KeyboardInterrupt raised inside an FMU's own Python code (pythonfmu FMUs share this
    interpreter) would leave the FMU in a fatal state, and SIGTERM's default action would end
    the process with the log unfinished; deferring them to the end of the step stops the run
    cleanly with every completed step logged. Only the main thread can install the handlers;
    elsewhere the signals keep their default behaviour.

    Parameters
    ----------
    restore : bool
        Put the previous handlers back on exit. False (a program's entry point): ignore the
        signals from then on, so a late signal cannot kill the interpreter while it frees the
        FMUs (Python's finalization puts a Python-level handler back to the default, not SIG_IGN).

    Attributes
    ----------
    requested : bool
        A signal came.
    signum : int or None
        The first signal that came.
    """

    def __init__(self, restore: bool = True) -> None:
        self.requested = False
        self.signum: Optional[int] = None
        self.restore = restore
        self._old: Dict[int, Any] = {}

    def __enter__(self) -> "DeferredSigint":
        import signal
        import threading

        if threading.current_thread() is threading.main_thread():
            for name in STOP_SIGNALS:
                sig = getattr(signal, name)
                if signal.getsignal(sig) is signal.SIG_IGN:   # ignored by whoever started us (nohup, a
                    continue                                    # background job): it stays ignored
                self._old[sig] = signal.signal(sig, self._handle)
                outer = getattr(self._old[sig], "__self__", None)
                if isinstance(outer, DeferredSigint) and outer.requested and not self.requested:
                    self.requested, self.signum = True, outer.signum   # came before: acted on here
        return self

    def _handle(self, signum, frame) -> None:
        self.requested = True
        if self.signum is None:
            self.signum = signum

    @property
    def name(self) -> str:
        """The signal's name (``"SIGTERM"``), ``"SIGINT"`` when none came."""
        import signal

        return signal.Signals(self.signum).name if self.signum else "SIGINT"

    def __exit__(self, *exc) -> None:
        import signal

        for sig, old in self._old.items():
            if not self.restore:
                signal.signal(sig, signal.SIG_IGN)
                continue
            signal.signal(sig, old)
            outer = getattr(old, "__self__", None)
            if self.requested and isinstance(outer, DeferredSigint) and not outer.requested:
                outer.requested = True  # not acted on here (it came after the last check): pass it on
                outer.signum = self.signum
        self._old = {}


# -- the parent ---------------------------------------------------------------------------------
def _prctl(option: int, arg: int) -> bool:
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(option, arg, 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def available() -> bool:
    """A supervising parent can be used here (Linux: fork and prctl)."""
    return sys.platform.startswith("linux") and hasattr(os, "fork")


def supervise(deferred: Optional[DeferredSigint] = None) -> Optional[int]:
    """Fork: in the child return None (it goes on with the command); in the parent wait for
    the child, report a crash (:func:`report_crash`) and return the exit status to use.

    ``deferred``: the command's :class:`DeferredSigint`, installed before anything heavy was
    imported; a signal it caught before the fork ends the command here (exit 128 + signal).
    """
    if deferred is not None and deferred.requested:
        sys.stderr.write(f"immersim: interrupted by {deferred.name} before the run started; no log was written\n")
        return 128 + (deferred.signum or 2)
    parent = os.getpid()
    _prctl(36, 1)   # PR_SET_CHILD_SUBREAPER: the child's helpers become ours if it dies
    reset()
    CRUMB[SUPERVISED] = 1
    sys.stdout.flush()
    sys.stderr.flush()
    try:
        pid = os.fork()
    except OSError as exc:   # no process to spare: the run goes on unsupervised
        log.warning("running without a supervising parent: fork failed: %s", exc)
        CRUMB[SUPERVISED] = 0
        return None
    if pid == 0:
        _prctl(1, signal.SIGKILL)   # PR_SET_PDEATHSIG: end with the parent
        if os.getppid() != parent:
            os._exit(137)
        return None

    def forward(signum, frame) -> None:
        try:
            os.kill(pid, signum)
        except ProcessLookupError:
            pass
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        if signal.getsignal(sig) is not signal.SIG_IGN:   # (one ignored by our starter stays so)
            signal.signal(sig, forward)
    if deferred is not None and deferred.requested:   # came between the check and the fork
        forward(deferred.signum, None)
    _, status = os.waitpid(pid, 0)
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, signal.SIG_IGN)
    if os.WIFSIGNALED(status):
        code = report_crash(pid, os.WTERMSIG(status))
    else:
        code = os.WEXITSTATUS(status)
    _reap_helpers()
    remove_files_of(pid)
    return code


def _reap_helpers(timeout: float = 30.0) -> None:
    """Wait (bounded) for the helpers of a dead child (workers, log writer) now ours."""
    import time

    end = time.monotonic() + timeout
    while time.monotonic() < end:
        try:
            pid, _ = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return
        if pid == 0:
            time.sleep(0.02)
    log.warning("helper processes of the run still running after %g s", timeout)


def report_crash(pid: int, signum: int) -> int:
    """The child died by ``signum``: repair the log, print one line, return 1."""
    info = _read_info()
    name = signal.Signals(signum).name if signum in signal.Signals._value2member_map_ else f"signal {signum}"
    units = info.get("units", [])
    u = CRUMB[UNIT]
    phase = CRUMB[PHASE]
    who = f"unit {units[u]}" if 0 <= u < len(units) else "the master process"
    t_ns, steps, total = CRUMB[T_NS], CRUMB[STEPS], info.get("steps_total", "?")
    writer = CRUMB[WRITER_PID]
    if writer > 0:   # [log] process: the writer finishes the file at the end of its input
        try:
            os.waitpid(writer, 0)
        except ChildProcessError:
            pass
    reason = f"{who} crashed the process ({name}) {_PHASES.get(phase, '')}".strip()
    if phase >= STEPPING or phase == INITIALIZING:
        reason += f" at t = {t_ns / 1e9:.9g} s"
    where = ""
    path = info.get("log")
    if path and phase == CLOSING:
        where = f"; the log {path} was closed before"
    elif path and phase == STEPPING and os.path.exists(path):
        run = {"status": "failed", "steps_done": steps, "steps_total": total, "t_ns": info.get("start_ns", 0)
               + steps * info.get("step_ns", 0), "reason": reason}
        try:
            kept, lost = repair_log(path, bytes(_journal_map[:max(CRUMB[JOURNAL], 0)]), run)
            where = f"; the log {path} holds steps 0..{kept}" + (f" ({lost} lost)" if lost else "")
        except Exception as exc:  # noqa: BLE001 - report the crash whatever the file holds
            where = f"; the log {path} could not be repaired: {exc}"
    elif path:
        where = f"; no log was written (the crash came before {path} was opened)"
    scenario = info.get("scenario", "the scenario")
    done = f" after {steps} of {total} steps" if phase == STEPPING else ""
    sys.stderr.write(f"immersim: error: run of {scenario} failed{done}: {reason}{where}\n")
    return 1


# -- the log's repair ---------------------------------------------------------------------------
_MESSAGE = struct.Struct("<BQHIQQ")


def _journal_messages(data: bytes) -> List[tuple]:
    """(channel, sequence, log time, publish time, data) of the message records in ``data``."""
    out, pos, n = [], 0, len(data)
    while pos + 9 <= n:
        op, length = struct.unpack_from("<BQ", data, pos)
        if pos + 9 + length > n:
            break
        if op == 0x05:
            _, _, cid, seq, lt, pt = _MESSAGE.unpack_from(data, pos)
            out.append((cid, seq, lt, pt, data[pos + 31:pos + 9 + length]))
        pos += 9 + length
    return out


def repair_log(path: str, journal: bytes, run: Dict[str, Any]) -> tuple:
    """Rewrite the MCAP file ``path`` of a run whose process died: its complete records (CRCs
    checked), then the messages of ``journal`` (records of the chunk that never reached the
    disk), metadata ``run`` replacing any the file had. The file is replaced atomically.

    Returns
    -------
    (last step, steps lost)
        The last step the log holds, and how many completed steps it could not keep (the
        journal overflowed: ``run["steps_done"]`` minus the last step).
    """
    from mcap.records import Channel, Header, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader
    from mcap.writer import CompressionType, Writer

    header, schemas, channels, metas, messages = None, [], [], [], []
    with open(path, "rb") as fh:
        try:
            for r in StreamReader(fh, validate_crcs=True).records:
                if isinstance(r, Header):
                    header = r
                elif isinstance(r, Schema) and all(s.id != r.id for s in schemas):
                    schemas.append(r)
                elif isinstance(r, Channel) and all(c.id != r.id for c in channels):
                    channels.append(r)
                elif isinstance(r, Metadata) and r.name != "run":
                    metas.append(r)
                elif isinstance(r, Message):
                    messages.append((r.channel_id, r.sequence, r.log_time, r.publish_time, r.data))
        except Exception:  # noqa: BLE001 - the file ends early: its complete records are kept
            pass
    seen = {(m[0], m[1]) for m in messages}
    messages += [m for m in _journal_messages(journal) if (m[0], m[1]) not in seen]
    last = max((m[1] for m in messages), default=0)
    tmp = f"{path}.repair"
    with open(tmp, "wb") as out:
        w = Writer(out, chunk_size=256 * 1024, compression=CompressionType.LZ4)
        w.start(profile=header.profile if header else "", library=header.library if header else "immersim")
        sid = {0: 0}
        for s in schemas:
            sid[s.id] = w.register_schema(s.name, s.encoding, s.data)
        cid = {}
        for c in channels:
            cid[c.id] = w.register_channel(c.topic, c.message_encoding, sid.get(c.schema_id, 0), c.metadata)
        for m in metas:
            w.add_metadata(m.name, m.metadata)
        for c, seq, lt, pt, data in messages:
            if c in cid:
                w.add_message(cid[c], lt, data, pt, seq)
        run = dict(run)
        lost = max(0, int(run.get("steps_done", last)) - last)
        if lost:
            run["reason"] = f"{run.get('reason', '')}; steps {last + 1}..{run['steps_done']} were lost"
        w.add_metadata("run", {k: str(v) for k, v in run.items()})
        w.finish()
    os.replace(tmp, path)
    return last, lost


# -- temporary files ----------------------------------------------------------------------------
def _tmp_patterns(pid: str) -> List[str]:
    return [os.path.join(tempfile.gettempdir(), f"immersim_run_{pid}_*"), f"/dev/shm/immersim_{pid}_*"]


def remove_files_of(pid: int) -> None:
    """Remove the temporary folders and shared-memory files of process ``pid``."""
    for pattern in _tmp_patterns(str(pid)):
        for p in glob.glob(pattern):
            shutil.rmtree(p, ignore_errors=True) if os.path.isdir(p) else _unlink(p)


def _unlink(p: str) -> None:
    try:
        os.unlink(p)
    except OSError:
        pass


def remove_stale() -> int:
    """Remove what runs whose process is gone (killed with SIGKILL) left in the temporary
    folder and ``/dev/shm``. Returns the number of processes whose files were removed."""
    pids = set()
    for pattern in _tmp_patterns("*"):
        for p in glob.glob(pattern):
            m = re.match(r"immersim_(?:run_)?(\d+)_", os.path.basename(p))
            if m:
                pids.add(int(m.group(1)))
    gone = 0
    for pid in pids:
        try:
            os.kill(pid, 0)
            continue
        except ProcessLookupError:
            pass
        except PermissionError:   # alive, someone else's
            continue
        remove_files_of(pid)
        gone += 1
    return gone
