"""Real-time pacing on a simulated clock: deadlines, late steps caught up, none skipped."""
from __future__ import annotations

import pytest
from mcap.reader import make_reader

from immersim.orchestrator.execution import Execution
from immersim.orchestrator.mcapio import read_info
from immersim.orchestrator.pacing import Pacer

from .helpers import oscillator_scenario

H = 33_000_000   # the macro step, ns


class FakeClock:
    """A wall clock that moves only when the code sleeps, spins (1 ns per read) or a step works."""

    def __init__(self) -> None:
        self.t = 1_000_000_000
        self.slept = []

    def clock(self) -> int:
        self.t += 1
        return self.t

    def sleep(self, seconds: float) -> None:
        self.slept.append(seconds)
        self.t += round(seconds * 1e9)


def drive(pacer: Pacer, fake: FakeClock, costs_ns, start_ns=0):
    """Observer calls of a run whose step k costs costs_ns[k] of wall time; returns the wall
    time (fake clock) at which each step's observation returned."""
    pacer(0, start_ns)
    done = []
    for k, cost in enumerate(costs_ns, 1):
        fake.t += cost
        pacer(k, start_ns + k * H)
        done.append(fake.t)
    return done


@pytest.mark.parametrize("factor", [1.0, 2.0, 0.5])
def test_a_fast_run_is_held_to_wall_time_times_the_factor(factor):
    fake = FakeClock()
    pacer = Pacer(factor, 0, clock=fake.clock, sleep=fake.sleep, spin_ns=0)
    done = drive(pacer, fake, [5_000_000] * 30)
    wall0 = pacer.wall0
    for k, t in enumerate(done, 1):   # each step released at its deadline (+ the clock reads of the spin)
        assert 0 <= t - (wall0 + round(k * H / factor)) <= 3
    s = pacer.summary()
    assert (s["steps"], s["late_steps"], s["worst_ms"]) == (30, 0, 0.0)


def test_a_late_step_is_caught_up_without_skipping():
    """Step 3 costs 4 budgets: it ends 3 h late; the next steps (10 ms each, 23 ms spare a
    step) run without waiting until the run is back on time: ceil(99/23) - 1 = 4 more late steps."""
    fake = FakeClock()
    pacer = Pacer(1.0, 0, clock=fake.clock, sleep=fake.sleep, spin_ns=0)
    costs = [10_000_000] * 20
    costs[2] = 4 * H   # 132 ms
    done = drive(pacer, fake, costs)
    late = [x for x in pacer.lateness if x > 0]
    assert len(pacer.lateness) == 20   # every step observed: none skipped
    assert late[0] == pytest.approx(3 * H, abs=10)   # step 3: its 132 ms against its 33 ms budget
    # then 10 ms a step against 33 ms of budget: lateness falls by 23 ms a step while it lasts
    assert [round(x / 1e6) for x in late] == [99, 76, 53, 30, 7]
    assert pacer.summary()["late_steps"] == 5
    assert done[-1] - pacer.wall0 == pytest.approx(20 * H, abs=10)   # back on the schedule
    assert pacer.summary()["worst_ms"] == pytest.approx(99.0, abs=1e-5)


def test_p99_is_the_lateness_below_which_99_percent_of_steps_end():
    fake = FakeClock()
    pacer = Pacer(1.0, 0, clock=fake.clock, sleep=fake.sleep, spin_ns=0)
    pacer.lateness = [0] * 98 + [1_000_000, 5_000_000]
    assert pacer.summary()["p99_ms"] == 1.0
    pacer.lateness = [0] * 100 + [5_000_000]
    assert pacer.summary()["p99_ms"] == 0.0


@pytest.mark.parametrize("factor", [0, -1.0, float("nan"), float("inf"), "2"])
def test_bad_factor_is_refused(factor):
    with pytest.raises(ValueError, match="real-time factor .* must be a finite number > 0"):
        Pacer(factor, 0)


def _messages(path):
    with open(path, "rb") as f:
        return [(c.topic, m.log_time, m.data) for _, c, m in make_reader(f).iter_messages()]


def test_a_paced_run_logs_the_same_messages_and_its_lateness(tmp_path, test_fmus):
    scen = oscillator_scenario(tmp_path, test_fmus["oscillator"], step=0.01, stop=0.3)
    plain, paced = tmp_path / "plain.mcap", tmp_path / "paced.mcap"
    Execution(scen, plain).run()
    ex = Execution(scen, paced, realtime=20.0)
    res = ex.run()
    assert _messages(plain) == _messages(paced)
    run = read_info(paced).metadata["run"]
    assert run["status"] == "completed"
    assert int(run["realtime_steps"]) == res.steps_done == 30
    assert float(run["realtime_factor"]) == 20.0
    assert int(run["realtime_late_steps"]) <= 30 and float(run["realtime_worst_ms"]) >= 0.0


def test_cli_realtime_reports_lateness_and_refuses_bad_factors(tmp_path, test_fmus, capsys):
    from immersim.orchestrator.cli import main

    scen = oscillator_scenario(tmp_path, test_fmus["oscillator"], step=0.01, stop=0.2)
    assert main(["run", str(scen), "-o", str(tmp_path / "rt.mcap"), "-q", "--realtime", "40"]) == 0
    out = capsys.readouterr().out
    assert "real time x40: " in out and "of 20 steps late" in out and "none skipped" in out
    for bad in ("0", "-1", "nan", "inf"):
        assert main(["run", str(scen), "-o", str(tmp_path / "bad.mcap"), "-q", "--realtime", bad]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "the factor must be a finite number > 0" in err
