"""Runs: the time base, FMI 3.0 units, failures mid-run, SIGINT, the info and plot commands."""
import math
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from immersim.orchestrator.errors import FmuCallError, NonFiniteOutputError
from immersim.orchestrator.execution import Execution, RunFailed, run_scenario
from immersim.orchestrator.mcapio import read_info, read_series
from immersim.orchestrator.scenario import load_scenario

from .helpers import oscillator_scenario

H_NS = 33_000_000


def test_time_base_has_no_drift_over_a_million_steps(tmp_path, test_fmus):
    """Step k starts at exactly k*33 ms: the FMU rejects any doStep whose current time is not
    the end of its previous step, and the last time is exactly 33000 s."""
    scn = tmp_path / "long.toml"
    scn.write_text(f'[simulation]\nstop = 33000.0\nstep = 0.033\n[[units]]\nname = "m"\n'
                   f'fmu = "{test_fmus["oscillator"]}"\n[log]\ninclude = ["m.x"]\n')
    sc = load_scenario(scn)
    assert sc.n_steps == 1_000_000
    times = [sc.step_time_ns(k) for k in (0, 1, 999_999, 1_000_000)]
    assert times == [0, H_NS, 999_999 * H_NS, 1_000_000 * H_NS]
    # accumulating 0.033 in floating point would drift; the integer base does not
    acc = 0.0
    for _ in range(1_000_000):
        acc += 0.033
    assert acc != 33000.0 and abs(acc - 33000.0) > 1e-9
    assert 1_000_000 * H_NS / 1e9 == 33000.0
    res = Execution(sc).run()
    assert res.steps_done == 1_000_000 and res.t_ns == 33_000_000_000_000


def test_fmi3_unit_in_a_scenario(tmp_path, test_fmus, fmi3_lag):
    """An FMI 3.0 FMU (pythonfmu3) fed by an FMI 2.0 one: y follows the exact lag of the held input."""
    scn = oscillator_scenario(tmp_path, test_fmus["oscillator"], step=0.033, stop=1.0, extra=f'''
[[units]]
name = "lag"
fmu = "{fmi3_lag}"
parameters = {{ tau = 0.2 }}

[[connections]]
from = "m1.x"
to = "lag.u"
''')
    out = tmp_path / "fmi3.mcap"
    run_scenario(scn, out)
    s = read_series(out, ["m1.x", "lag.y"])
    t, x, _ = s["m1.x"]
    _, y, _ = s["lag.y"]
    # Jacobi + ZOH: over [t_k, t_k+1] the lag sees u = x(t_k); the last step is 10 ms long
    assert len(t) == 32 and t[-1] - t[-2] == pytest.approx(0.010)
    expect = np.zeros_like(y)
    for k in range(len(t) - 1):
        a = math.exp(-(t[k + 1] - t[k]) / 0.2)
        expect[k + 1] = x[k] + (expect[k] - x[k]) * a
    np.testing.assert_allclose(y, expect, atol=1e-12)


@pytest.fixture(scope="session")
def fmi3_lag(tmp_path_factory):
    from pythonfmu3 import FmuBuilder

    from ..conftest import TESTS

    return FmuBuilder.build_FMU(TESTS / "units_fmi3" / "lag3.py", dest=tmp_path_factory.mktemp("fmi3"))


def test_error_mid_run_keeps_every_completed_step(tmp_path, test_fmus):
    """A NaN forced into an input at t = 0.33 s: the FMU logs an error and refuses the step
    (pythonfmu reports a refused step as fmi2Discard), the run stops with a message naming
    unit, function, variable and time, and the log holds steps 0..10."""
    scn = oscillator_scenario(tmp_path, test_fmus["oscillator"], step=0.033, stop=1.0, algorithm="gauss-seidel",
                              extra='[[faults]]\ntarget = "m2.x_other"\nat = 0.33\nvalue = nan\n')
    out = tmp_path / "fail.mcap"
    with pytest.raises(RunFailed, match=r"failed at t = 0.33 s after 10 of 31 steps: unit m2: fmi2DoStep returned "
                                        r"discard at t = 0.33 s: FmuInputError: m2: input x_other = nan at t = 0.33 s"):
        run_scenario(scn, out)
    info = read_info(out)
    assert info.channels["m1"].count == 11 and info.channels["m2"].count == 11
    assert info.channels["m2"].last_ns == 10 * H_NS
    assert info.metadata["run"]["status"] == "failed"


def test_nonfinite_output_is_stopped_before_logging(tmp_path, test_fmus):
    """An infinite input is refused before it can reach an output or the log."""
    scn = oscillator_scenario(tmp_path, test_fmus["oscillator"], step=0.033, stop=1.0,
                              extra='[[faults]]\ntarget = "m1.x_other"\nat = 0.099\nvalue = inf\n')
    out = tmp_path / "inf.mcap"
    with pytest.raises(RunFailed, match=r"after 3 of 31 steps: unit m1: fmi2DoStep returned discard at t = 0.099 s: "
                                        r"FmuInputError: m1: input x_other = inf"):
        run_scenario(scn, out)
    assert read_info(out).channels["m1"].count == 4


def test_sigint_leaves_a_readable_log(tmp_path, test_fmus):
    # 10^6 steps: far more than 4 s of loop even when the master is fast (the signal must land mid-run)
    scn = oscillator_scenario(tmp_path, test_fmus["oscillator"], step=0.033, stop=33000.0)
    out = tmp_path / "int.mcap"
    proc = subprocess.Popen([sys.executable, "-m", "immersim.orchestrator.cli", "run", str(scn), "-o", str(out), "-q"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(4.0)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "interrupted at t = " in err and "interrupted by SIGINT" in err and str(out) in err
    info = read_info(out)
    run = info.metadata["run"]
    assert run["status"] == "interrupted"
    done = int(run["steps_done"])
    assert 0 < done < 1_000_000
    assert info.channels["m1"].count == done + 1
    assert info.channels["m1"].last_ns == done * H_NS


def test_info_and_plot_commands(tmp_path, test_fmus):
    scn = oscillator_scenario(tmp_path, test_fmus["oscillator"], step=0.033, stop=0.99)
    out = tmp_path / "p.mcap"
    cli = [sys.executable, "-m", "immersim.orchestrator.cli"]
    subprocess.run(cli + ["run", str(scn), "-o", str(out), "-q"], check=True, timeout=120)
    info = subprocess.run(cli + ["info", str(out)], capture_output=True, text=True, check=True).stdout
    assert "channel m1: 31 messages, 0 .. 0.99 s, 5 signals" in info
    assert "m1.x [m]" in info and "run: completed after 30 of 30 steps" in info
    assert "step 0.033 s" in info                        # the macro step from the log's metadata
    png = tmp_path / "p.png"
    subprocess.run(cli + ["plot", str(out), "m*.x", "m1.v", "-o", str(png)], check=True, timeout=120)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    bad = subprocess.run(cli + ["plot", str(out), "zz.*", "-o", str(png)], capture_output=True, text=True)
    assert bad.returncode == 2 and "no signal matches zz.*" in bad.stderr


def test_unneeded_unit_is_not_loaded(tmp_path, test_fmus):
    fmu = test_fmus["oscillator"]
    scn = tmp_path / "skip.toml"
    scn.write_text(f'[simulation]\nstop = 0.33\n[[units]]\nname = "a"\nfmu = "{fmu}"\n'
                   f'[[units]]\nname = "idle"\nfmu = "{fmu}"\n[log]\ninclude = ["a.*"]\n')
    ex = Execution(scn)
    assert ex.system.needed == ["a"] and ex.system.skipped == ["idle"]
    res = ex.run()
    assert set(res.values) == {"a"}


def test_linear_is_the_default_and_a_connection_may_hold(tmp_path, test_fmus):
    """Without simulation.extrapolation, Gauss-Seidel feeds the mid-step (interpolated) value of a
    continuous Real source; a connection with extrapolation = "zoh" gets the step's end value."""
    fmu = test_fmus["oscillator"]
    text = (f'[simulation]\nstop = 0.66\nalgorithm = "gauss-seidel"\n'
            f'[[units]]\nname = "m1"\nfmu = "{fmu}"\nparameters = {{ x0 = 1.0 }}\n'
            f'[[units]]\nname = "m2"\nfmu = "{fmu}"\n'
            f'[[units]]\nname = "m3"\nfmu = "{fmu}"\n'
            '[[connections]]\nfrom = "m1.x"\nto = "m2.x_other"\n'
            '[[connections]]\nfrom = "m1.x"\nto = "m3.x_other"\nextrapolation = "zoh"\n')
    scn = tmp_path / "lin.toml"
    scn.write_text(text)
    assert load_scenario(scn).extrapolation == "linear"
    run_scenario(scn, tmp_path / "lin.mcap")
    s = read_series(tmp_path / "lin.mcap", ["m1.x", "m2.x_other", "m3.x_other"])
    x, lin, zoh = s["m1.x"][1], s["m2.x_other"][1], s["m3.x_other"][1]
    assert np.ptp(x) > 0.1  # m1 swings: the two feeds differ
    np.testing.assert_array_equal(zoh[1:], x[1:])
    np.testing.assert_allclose(lin[2:], 0.5 * (x[1:-1] + x[2:]), rtol=0, atol=1e-15)


def test_the_loop_time_holds_the_logging_and_the_units_not_step_0s_log(tmp_path, test_fmus):
    """The summary splits the step loop's wall time into units, logging and the master, each
    measured inside the loop, so their sum is within it: step 0's log (written with the set-up,
    the units' meshes with it) is not the loop's logging. Here an observer that takes 50 ms at
    step 0 and a loop of 3 short steps."""
    scn = tmp_path / "osc.toml"
    scn.write_text(f'[simulation]\nstop = 0.099\nstep = 0.033\n[[units]]\nname = "m"\n'
                   f'fmu = "{test_fmus["oscillator"]}"\n[log]\ninclude = ["m.x"]\n')
    ex = Execution(load_scenario(scn), tmp_path / "osc.mcap")

    def slow_first(k, t_ns):
        if k == 0:
            end = time.perf_counter() + 0.05
            while time.perf_counter() < end:
                pass
    ex.observers.append(slow_first)
    res = ex.run()
    assert res.steps_done == 3
    inside = res.timing["logging"] + sum(v for k, v in res.timing.items() if k.startswith("unit:"))
    assert 0 < inside <= res.timing["loop"]
    assert " master -" not in res.timing_summary()
