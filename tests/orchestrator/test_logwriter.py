"""``[log] process = true``: the log written by a process of its own is the master's own log,
and every failure keeps the rules of the in-process log (clear error, every step kept)."""
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from immersim.orchestrator.errors import LogWriteError, ScenarioError
from immersim.orchestrator.execution import Execution, RunFailed, run_scenario
from immersim.orchestrator.logwriter import LogPlan, LogProcess
from immersim.orchestrator.mcapio import read_info, read_series
from immersim.orchestrator.scenario import load_scenario

from .helpers import MASS_BODY, oscillator_scenario

VIEW = MASS_BODY


@pytest.mark.parametrize("encoding", ["json", "ros1"])
def test_the_writer_process_writes_the_same_file(tmp_path, test_fmus, encoding):
    """Units' channels, parameters, the 3D view (/tf, /scene) and the run's metadata: the two
    files are equal byte for byte (a run shorter than the 1 s flush interval, so the chunks
    are cut at the same steps)."""
    scn = oscillator_scenario(tmp_path, test_fmus["oscillator"], step=0.033, stop=2.0,
                              extra=f'[log]\nencoding = "{encoding}"\n' + VIEW)
    a, b = tmp_path / "in.mcap", tmp_path / "proc.mcap"
    run_scenario(scn, a)
    res = run_scenario(scn, b, overrides={"log.process": True})
    assert res.status == "completed" and res.steps_done == 61
    assert res.timing["log writer cpu"] > 0 and "log writer process" in res.timing_summary()
    assert a.read_bytes() == b.read_bytes()
    info = read_info(b)
    assert info.channels["m1"].count == info.channels["/tf"].count == 62
    assert info.metadata["run"]["status"] == "completed"


def test_a_log_that_cannot_be_opened_fails_with_the_in_process_message(tmp_path, test_fmus):
    scn = oscillator_scenario(tmp_path, test_fmus["oscillator"], stop=0.1)
    bad = tmp_path / "file"
    bad.write_text("")
    out = bad / "run.mcap"   # a directory that is a file
    msgs = []
    for process in (False, True):
        with pytest.raises(RunFailed) as e:
            run_scenario(scn, out, overrides={"log.process": process})
        msgs.append(str(e.value))
    assert msgs[0] == msgs[1]
    assert f"cannot write the log {out}: " in msgs[1]


def test_a_plan_that_cannot_be_opened_leaves_no_writer_behind(tmp_path):
    out = tmp_path / "missing" / "x"
    (tmp_path / "missing").write_text("")
    with pytest.raises(LogWriteError, match=f"cannot write the log {out}"):
        LogProcess(LogPlan(str(out)))


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="no /dev/full")
def test_a_full_disk_fails_the_run_naming_the_file(tmp_path, test_fmus):
    scn = oscillator_scenario(tmp_path, test_fmus["oscillator"], step=0.033, stop=1.0)
    with pytest.raises(RunFailed, match=r"cannot write the log /dev/full at t = 0 s: No space left on device"):
        run_scenario(scn, "/dev/full", overrides={"log.process": True})


def test_a_writer_that_dies_stops_the_run(tmp_path, test_fmus):
    """SIGKILL to the writer after step 5 is handed over: the master notices when it sends its
    first batch (steps 0..7, with step 7's log) and fails naming the file, the time and the
    writer's exit code, after 6 completed steps (the log of step 7 is the one that failed)."""
    scn = oscillator_scenario(tmp_path, test_fmus["oscillator"], step=0.033, stop=3.0)
    ex = Execution(load_scenario(scn, {"log.process": True}), tmp_path / "w.mcap")

    def kill_at_step_5(k, t_ns):
        if k == 5:
            os.kill(ex.observer.proc.pid, signal.SIGKILL)
            ex.observer.proc.wait()

    ex.observers.append(kill_at_step_5)
    with pytest.raises(RunFailed, match=rf"cannot write the log {tmp_path / 'w.mcap'} at t = [\d.]+ s: "
                                        r"the log-writer process ended \(exit code -9\)") as e:
        ex.run()
    assert e.value.result.steps_done == 6


def test_when_the_master_is_killed_the_writer_finishes_the_file(tmp_path, test_fmus):
    """``immersim run`` killed with SIGKILL mid-run: its writer gets the end of its input and
    finishes the file (summary and index), with every step it was sent, marked aborted."""
    scn = oscillator_scenario(tmp_path, test_fmus["oscillator"], step=0.001, stop=600.0,
                              extra="[log]\nprocess = true\n")
    out = tmp_path / "killed.mcap"
    cli = [str(Path(sys.executable).with_name("immersim")), "run", str(scn), "-o", str(out), "-q"]
    proc = subprocess.Popen(cli, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while (not out.exists() or out.stat().st_size < 20_000) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert out.exists(), "the run never wrote its log"
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    deadline = time.monotonic() + 30
    while True:
        try:
            info = read_info(out)
            if "run" in info.metadata or time.monotonic() > deadline:   # (a partial file reads too)
                break
        except Exception:   # the writer is still finishing the file
            if time.monotonic() > deadline:
                raise
        time.sleep(0.1)
    assert info.metadata["run"]["status"] == "aborted"
    n = info.channels["m1"].count
    assert 10 < n < 600_001 and info.channels["m2"].count == n
    t, x = read_series(out, ["m1.x"])["m1.x"][:2]
    assert len(t) == n and t[-1] == pytest.approx((n - 1) * 0.001)


def test_process_must_be_a_boolean(tmp_path, test_fmus):
    scn = oscillator_scenario(tmp_path, test_fmus["oscillator"], extra='[log]\nprocess = "yes"\n')
    with pytest.raises(ScenarioError, match=r"osc.toml: log.process: expected true or false, got 'yes'"):
        load_scenario(scn)
    assert load_scenario(scn, {"log.process": True}).log.process is True


def test_a_close_that_failed_is_not_retried(tmp_path, monkeypatch):
    """The disk refuses the run's metadata: the first close raises one line naming the file, the log
    counts as closed, and a second close (the execution's cleanup) is a no-op, not a second
    write to a broken file."""
    import errno
    import re

    from immersim.orchestrator.logwriter import LogWriter

    out = tmp_path / "run.mcap"
    w = LogWriter(LogPlan(str(out)))
    calls = []

    def refuse(name, data):
        calls.append(name)
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(w.mcap.writer, "add_metadata", refuse)
    with pytest.raises(LogWriteError, match=f"^cannot write the log {re.escape(str(out))}: No space left on device$"):
        w.close({"status": "completed"})
    assert w.closed
    assert w.close({"status": "completed"}) is None
    assert calls == ["run"]
