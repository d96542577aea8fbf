"""A unit that crashes the process (segfault, abort) in the master's process: one line naming
the unit and the simulated time, exit 1, and a log that validates with CRCs and holds exactly
the completed steps (``immersim run``'s supervising parent, orchestrator/supervisor.py)."""
from __future__ import annotations

import time

import pytest

import boundlib as bl


@pytest.mark.parametrize("how, crash_at, log_process", [
    ("segv", 2.0, False),    # in a later chunk: the complete chunks plus the journal
    ("abort", 0.5, False),
    ("segv", 0.04, False),   # the second step: only the first chunk is on disk
    ("segv", 1.0, True),     # the log written by its own process: every step was sent
])
def test_crash_ends_with_one_line_and_complete_log(test_fmus, tmp_path, how, crash_at, log_process):
    step = 0.033
    sc = bl.scenario(tmp_path, bl.crash_units(test_fmus["crasher"], crash_at, how), stop=5.0, step=step)
    out = tmp_path / "run.mcap"
    since = time.time()
    args = ["run", str(sc), "-o", str(out), "-q"] + (["--set", "log.process=true"] if log_process else [])
    res = bl.run(args, tmp_path)
    k = bl.steps_of_crash(crash_at, step)
    signame = "SIGSEGV" if how == "segv" else "SIGABRT"
    line = bl.one_line(res, 1, rf"^immersim: error: run of .*s\.toml failed after {k} of 152 steps: unit boom "
                               rf"crashed the process \({signame}\) in a step at t = {k * step:.9g} s; "
                               rf"the log .*run\.mcap holds steps 0\.\.{k}$")
    assert "lost" not in line
    bl.assert_log_holds(out, "boom", k, "failed")
    assert "boom crashed the process" in bl.read_log(out).run["reason"]
    assert bl.leftovers(tmp_path, since) == []


def test_crash_in_the_first_step(test_fmus, tmp_path):
    """A crash in the first step: the log holds the initial values (step 0) only."""
    sc = bl.scenario(tmp_path, bl.crash_units(test_fmus["crasher"], 0.0), stop=1.0)
    out = tmp_path / "run.mcap"
    res = bl.run(["run", str(sc), "-o", str(out), "-q"], tmp_path)
    bl.one_line(res, 1, r"failed after 0 of 31 steps: unit boom crashed the process \(SIGSEGV\) in a step at t = 0 s")
    bl.assert_log_holds(out, "boom", 0, "failed")


def test_unsupervised_crash_is_the_plain_signal(test_fmus, tmp_path):
    """The control: without the supervising parent the same unit kills the run (exit -11)."""
    sc = bl.scenario(tmp_path, bl.crash_units(test_fmus["crasher"], 0.5), stop=1.0)
    res = bl.run(["run", str(sc), "-o", str(tmp_path / "run.mcap"), "-q"], tmp_path,
                 env={"IMMERSIM_SUPERVISE": "0"})
    assert res.code == -11
