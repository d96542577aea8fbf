"""Helpers of the boundary tests: run ``immersim`` as a user does, check its one line and its log."""
from __future__ import annotations

import glob
import os
import re
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List

CLI = [sys.executable, "-m", "immersim.orchestrator.cli"]


@dataclass
class Outcome:
    code: int
    stdout: str
    stderr: str

    @property
    def lines(self) -> List[str]:
        return [ln for ln in self.stderr.splitlines() if ln.strip()]


def one_line(out: Outcome, code: int, pattern: str) -> str:
    """Assert exit ``code``, exactly one stderr line, matching ``pattern``, and no traceback."""
    assert "Traceback" not in out.stderr, out.stderr
    assert out.code == code, (out.code, out.stderr)
    assert len(out.lines) == 1, out.stderr
    assert re.search(pattern, out.lines[0]), (pattern, out.lines[0])
    return out.lines[0]


def _default_signals() -> None:
    """In the child before exec: SIGINT, SIGTERM and SIGHUP at their default actions (a test run
    in the background, or under nohup, would hand them down ignored, and they stay ignored)."""
    import signal

    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, signal.SIG_DFL)


def start(args: List[str], tmpdir: Path, **kw) -> subprocess.Popen:
    """``immersim ARGS`` in a fresh process whose temporary folder is ``tmpdir``, with the
    default signal actions."""
    env = dict(os.environ, TMPDIR=str(tmpdir))
    env.update(kw.pop("env", {}))
    pre = kw.pop("preexec_fn", None)

    def preexec() -> None:
        _default_signals()
        if pre is not None:
            pre()
    return subprocess.Popen(CLI + args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            preexec_fn=preexec, **kw)


def run(args: List[str], tmpdir: Path, timeout: float = 120, **kw) -> Outcome:
    p = start(args, tmpdir, **kw)
    out, err = p.communicate(timeout=timeout)
    return Outcome(p.returncode, out, err)


@dataclass
class LogContent:
    steps: Dict[str, List[int]]   # topic -> message sequences (step numbers)
    run: Dict[str, str]


def read_log(path: Path) -> LogContent:
    """Every message of a log read with CRC checks (a file without a summary fails here)."""
    from mcap.reader import make_reader

    steps: Dict[str, List[int]] = {}
    with open(path, "rb") as fh:
        reader = make_reader(fh, validate_crcs=True)
        for _, channel, message in reader.iter_messages():
            steps.setdefault(channel.topic, []).append(message.sequence)
        meta = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    return LogContent(steps, meta.get("run", {}))


def completed_steps(line: str) -> int:
    """K of a run's ``after K of N steps``."""
    return int(re.search(r"after (\d+) of \d+ steps", line).group(1))


def assert_log_holds(path: Path, topic: str, k: int, status: str) -> None:
    """The log validates with CRCs and ``topic`` holds exactly steps 0..k; ``run`` says ``status``."""
    content = read_log(path)
    assert content.steps[topic] == list(range(k + 1)), (content.steps[topic][:3], content.steps[topic][-3:], k)
    assert content.run.get("status") == status, content.run
    assert int(content.run["steps_done"]) == k


def leftovers(tmpdir: Path, since: float) -> List[str]:
    """Run folders in ``tmpdir`` and this user's ``/dev/shm/immersim_*`` files made since
    ``since`` (wall clock) whose process is gone."""
    out = [p for p in glob.glob(str(tmpdir / "immersim_*"))]
    for p in glob.glob("/dev/shm/immersim_*"):
        try:
            if os.stat(p).st_mtime < since:
                continue
        except FileNotFoundError:
            continue
        m = re.match(r"immersim_(\d+)_", os.path.basename(p))
        if m and not _alive(int(m.group(1))):
            out.append(p)
    return out


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
        return True
    except ProcessLookupError:
        return False
    except PermissionError:
        return True


def scenario(tmp: Path, units: str, stop: float, step: float = 0.033, extra: str = "",
             name: str = "s.toml") -> Path:
    """A scenario file (Jacobi: two coupled units step with no cycle to break)."""
    path = tmp / name
    path.write_text(f'[simulation]\nstop = {stop}\nstep = {step}\nalgorithm = "jacobi"\n\n{units}\n{extra}\n')
    return path


def crash_units(fmu: Path, crash_at: float, how: str = "segv") -> str:
    return (f'[[units]]\nname = "boom"\nfmu = "{fmu}"\n[units.parameters]\ncrash_at = {crash_at}\n'
            f'how = "{how}"\n')


def oscillator_units(fmu: Path) -> str:
    return (f'[[units]]\nname = "m1"\nfmu = "{fmu}"\nparameters = {{ x0 = 1.0 }}\n\n'
            f'[[units]]\nname = "m2"\nfmu = "{fmu}"\n\n'
            '[[connections]]\nfrom = "m1.x"\nto = "m2.x_other"\n\n'
            '[[connections]]\nfrom = "m2.x"\nto = "m1.x_other"\n')


def catches(pid: int, sig: int) -> bool:
    """Process ``pid`` has a handler for ``sig`` (``SigCgt`` of /proc/PID/status): past the
    interpreter's own start-up, whose signals take their default action."""
    try:
        with open(f"/proc/{pid}/status") as fh:
            mask = next(int(ln.split()[1], 16) for ln in fh if ln.startswith("SigCgt:"))
    except (OSError, StopIteration):
        return False
    return bool(mask >> (sig - 1) & 1)


def wait_for(predicate, timeout: float, poll: float = 0.02) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(poll)
    return False


def steps_of_crash(crash_at: float, step: float) -> int:
    """Steps a crasher unit completes: it crashes in the first step ending at or after ``crash_at``."""
    k = 0
    while round((k + 1) * step, 12) < crash_at - 1e-9:
        k += 1
    return k

