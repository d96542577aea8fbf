"""The cyclic garbage collector during a run (execution.run_scenario): paused for the set-up,
collecting again from the first step, as before once the run ends (also a failed one)."""
import gc

import pytest

from immersim.orchestrator.execution import Execution, run_scenario

SCENARIO = '''
[simulation]
stop = 0.5
step = 0.1
[[units]]
name = "a"
fmu = "{fmu}"
'''


def test_collector_paused_for_the_set_up_and_collecting_while_stepping(tmp_path, test_fmus, monkeypatch):
    p = tmp_path / "s.toml"
    p.write_text(SCENARIO.format(fmu=test_fmus["oscillator"]))
    seen = []
    setup, step = Execution._setup, Execution._observe

    def setup_watched(self):
        seen.append(("set-up", gc.isenabled()))
        return setup(self)

    def observe_watched(self, master, k, t_ns):
        step(self, master, k, t_ns)
        seen.append((k, gc.isenabled(), gc.get_freeze_count() > 0))
    monkeypatch.setattr(Execution, "_setup", setup_watched)
    monkeypatch.setattr(Execution, "_observe", observe_watched)
    assert gc.isenabled()
    res = run_scenario(p, tmp_path / "s.mcap")
    assert res.status == "completed"
    assert seen[0] == ("set-up", False) and seen[1] == (0, False, False)   # step 0 is logged in the set-up
    assert seen[2:] == [(k, True, True) for k in range(1, 6)]
    assert gc.isenabled() and gc.get_freeze_count() == 0


def test_a_disabled_collector_stays_disabled_and_a_failed_run_resumes_it(tmp_path, test_fmus):
    p = tmp_path / "s.toml"
    p.write_text(SCENARIO.format(fmu=test_fmus["oscillator"]))
    gc.disable()
    try:
        run_scenario(p, tmp_path / "s.mcap")
        assert not gc.isenabled()
    finally:
        gc.enable()
    bad = tmp_path / "bad.toml"
    bad.write_text(SCENARIO.format(fmu=tmp_path / "missing.fmu"))
    with pytest.raises(Exception):
        run_scenario(bad, tmp_path / "bad.mcap")
    assert gc.isenabled() and gc.get_freeze_count() == 0
