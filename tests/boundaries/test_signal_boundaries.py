"""SIGINT, SIGTERM and SIGHUP at random instants of ``immersim run``: exit 128 + signal with one
line, a log that validates with CRCs and holds exactly the completed steps (status
``interrupted``), and no temporary folder or ``/dev/shm`` file left. The long sweep (50 tries
per signal) is ``benchmarks/bench_stress.py --only signals``."""
from __future__ import annotations

import os
import random
import signal
import time
from pathlib import Path

import pytest

import boundlib as bl

STEPS = 50000


def signal_run(fmu: Path, tmp: Path, sig: int, delay: float, extra_args=(), after_log: bool = True) -> str:
    """Start a run of two coupled oscillators (50 s at 1 ms: seconds of loop), send ``sig``
    ``delay`` s after its log appears (or after its start), check the outcome; returns what
    happened."""
    sc = bl.scenario(tmp, bl.oscillator_units(fmu), stop=STEPS / 1000, step=0.001)
    out = tmp / "run.mcap"
    since = time.time()
    p = bl.start(["run", str(sc), "-o", str(out), "-q", *extra_args], tmp)
    if after_log:
        assert bl.wait_for(lambda: out.exists() and out.stat().st_size > 0, 120)
    else:   # past the interpreter's own start-up (its signals take the default action)
        assert bl.wait_for(lambda: bl.catches(p.pid, signal.SIGHUP), 60)
    time.sleep(delay)
    p.send_signal(sig)
    stdout, stderr = p.communicate(timeout=120)
    res = bl.Outcome(p.returncode, stdout, stderr)
    name = signal.Signals(sig).name
    assert bl.leftovers(tmp, since) == []
    if res.code == 0:   # the run ended before the signal came: a complete log
        assert not res.stderr.strip(), res.stderr
        bl.assert_log_holds(out, "m1", STEPS, "completed")
        return "completed"
    line = bl.one_line(res, 128 + sig, rf"^immersim: (run of .* interrupted at t = [-0-9.e]+ s after \d+ of {STEPS} "
                                       rf"steps: interrupted by {name}|interrupted by {name} (before the run started|while starting))")
    if "no log was written" in line or "nothing was done" in line:
        assert not out.exists()
        return "before the log"
    k = bl.completed_steps(line)
    bl.assert_log_holds(out, "m1", k, "interrupted")
    return f"step {k}"


@pytest.mark.parametrize("sig, extra", [
    (signal.SIGINT, ()),
    (signal.SIGTERM, ("--set", "log.process=true")),
    (signal.SIGHUP, ("--set", "m2:process=1")),   # a worker process and its shared memory
])
def test_signal_mid_run(test_fmus, tmp_path, sig, extra):
    delay = random.Random(sig).uniform(0.05, 0.8)
    what = signal_run(test_fmus["oscillator"], tmp_path, sig, delay, extra)
    assert what != "before the log"


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_signal_during_start_up(test_fmus, tmp_path, sig):
    """A signal while the command starts, loads and checks the scenario stops it (it was once
    caught there and then ignored: the run went on to its end). Sent 0 .. 0.5 s after the
    program's handlers are in place."""
    what = signal_run(test_fmus["oscillator"], tmp_path, sig, random.Random(sig).uniform(0.0, 0.5), after_log=False)
    assert what != "completed"


def test_leftovers_of_a_killed_run_are_removed_by_the_next(test_fmus, tmp_path):
    """SIGKILL leaves the run folder of its (dead) process; the next run removes it."""
    sc = bl.scenario(tmp_path, bl.oscillator_units(test_fmus["oscillator"]), stop=5.0, step=0.001)
    out = tmp_path / "run.mcap"
    p = bl.start(["run", str(sc), "-o", str(out), "-q", "--set", "log.process=true"], tmp_path)
    assert bl.wait_for(lambda: out.exists() and out.stat().st_size > 0, 120)
    p.kill()
    p.communicate(timeout=60)
    assert bl.wait_for(lambda: not any(bl._alive(int(d.name.split("_")[2])) for d in tmp_path.glob("immersim_run_*")), 30)
    left = list(tmp_path.glob("immersim_run_*"))
    assert left, "a killed run leaves its folder (the control)"
    assert bl.wait_for(lambda: bl.read_log(out).run.get("status") == "aborted", 30)  # its writer finished the file
    info = bl.run(["info", str(out)], tmp_path)
    assert info.code == 0
    assert "run: aborted after" in info.stdout and "None" not in info.stdout, info.stdout
    res = bl.run(["run", str(bl.scenario(tmp_path, bl.oscillator_units(test_fmus["oscillator"]), stop=0.1,
                                         name="short.toml")), "-o", str(tmp_path / "b.mcap"), "-q"], tmp_path)
    assert res.code == 0, res.stderr
    assert list(tmp_path.glob("immersim_run_*")) == []
    assert os.path.exists(out)


def test_a_signal_ignored_by_the_starter_stays_ignored(test_fmus, tmp_path):
    """``nohup immersim run ...``: SIGHUP was ignored when the program started, and stays so
    (the run goes on); SIGTERM still stops it."""
    sc = bl.scenario(tmp_path, bl.oscillator_units(test_fmus["oscillator"]), stop=STEPS / 1000, step=0.001)
    out = tmp_path / "run.mcap"
    p = bl.start(["run", str(sc), "-o", str(out), "-q"], tmp_path,
                 preexec_fn=lambda: signal.signal(signal.SIGHUP, signal.SIG_IGN))
    assert bl.wait_for(lambda: out.exists() and out.stat().st_size > 0, 120)
    p.send_signal(signal.SIGHUP)
    time.sleep(0.2)
    assert p.poll() is None, "SIGHUP ignored by the starter ended the run"
    p.send_signal(signal.SIGTERM)
    stdout, stderr = p.communicate(timeout=120)
    line = bl.one_line(bl.Outcome(p.returncode, stdout, stderr), 143, r"interrupted by SIGTERM")
    bl.assert_log_holds(out, "m1", bl.completed_steps(line), "interrupted")
