"""Scenario signals, real-time pacing deadlines and a connection's offset under linear
extrapolation, against closed forms."""
import math

import numpy as np
import pytest

from immersim.orchestrator.execution import run_scenario
from immersim.orchestrator.mcapio import read_series
from immersim.orchestrator.pacing import Pacer
from immersim.orchestrator.signals import signal_function


def test_constant_step_ramp_and_sine_signals():
    const = signal_function("constant", {"value": 2.5})
    step = signal_function("step", {"at": 0.33, "value": 8.0, "initial": -1.0})
    ramp = signal_function("ramp", {"at": 1.0, "slope": 2.0, "initial": 0.5})
    sine = signal_function("sine", {"amplitude": 3.0, "frequency": 0.5, "offset": 1.0, "phase": 0.25})
    for t in (0.0, 0.2, 0.33, 0.99, 1.0, 1.5, 4.0):
        assert const(t) == 2.5
        assert step(t) == (8.0 if t >= 0.33 else -1.0)            # on at its own time
        assert ramp(t) == pytest.approx(0.5 + 2.0 * max(0.0, t - 1.0), abs=1e-15)
        assert sine(t) == pytest.approx(1.0 + 3.0 * math.sin(2 * math.pi * 0.5 * t + 0.25), abs=1e-15)
    assert step(0.33 - 1e-13) == 8.0 and step(0.329) == -1.0      # (a time a rounding below 'at' counts)


def test_pacing_deadline_is_the_simulated_time_since_start_over_the_factor():
    """Step k ending at simulated t is due at wall0 + (t - start) / factor (ns), wall0 the wall
    clock when the initial state was observed; a run starting at t = 5 s."""
    now = [1_000]
    pacer = Pacer(2.0, 5_000_000_000, clock=lambda: now[0], sleep=lambda s: now.__setitem__(0, now[0] + int(s * 1e9)))
    pacer(0, 5_000_000_000)
    assert pacer.wall0 == 1_000
    assert pacer.deadline(5_000_000_000) == 1_000
    assert pacer.deadline(6_000_000_000) == 1_000 + 500_000_000
    assert pacer.deadline(5_033_000_000) == 1_000 + 16_500_000


def _offset_run(tmp_path, fmu, offset, name):
    p = tmp_path / f"{name}.toml"
    p.write_text(f'''
[simulation]
stop = 0.66
algorithm = "gauss-seidel"
extrapolation = "linear"
[[units]]
name = "m2"
fmu = "{fmu}"
[[units]]
name = "m1"
fmu = "{fmu}"
parameters = {{ x0 = 1.0 }}
[[connections]]
from = "m1.x"
to = "m2.x_other"
gain = 2.0
offset = {offset}
''')
    out = tmp_path / f"{name}.mcap"
    run_scenario(p, out)
    return read_series(out, ["m1.x", "m2.x_other"])


def test_connection_offset_is_added_under_linear_extrapolation(tmp_path, test_fmus):
    """to = gain * from + offset whatever the extrapolation: the same run with offset 0.5 and 0
    gives inputs 0.5 apart at every step (m1 does not depend on m2, so its x is the same)."""
    a = _offset_run(tmp_path, test_fmus["oscillator"], 0.5, "a")
    b = _offset_run(tmp_path, test_fmus["oscillator"], 0.0, "b")
    np.testing.assert_array_equal(a["m1.x"][1], b["m1.x"][1])
    np.testing.assert_allclose(a["m2.x_other"][1] - b["m2.x_other"][1], 0.5, rtol=0, atol=1e-12)
    assert np.ptp(a["m1.x"][1]) > 0.01


def test_a_log_that_ends_early_reads_the_requested_channel_only(tmp_path, test_fmus):
    """A log cut short (no summary) is read record by record; asking for m1.x gives m1's complete
    messages, the same values as the full log's first ones."""
    full = _offset_run(tmp_path, test_fmus["oscillator"], 0.5, "full")
    out = tmp_path / "full.mcap"
    cut = tmp_path / "cut.mcap"
    data = out.read_bytes()
    cut.write_bytes(data[: int(len(data) * 0.8)])
    s = read_series(cut, ["m1.x"])
    assert set(s) == {"m1.x"}
    n = len(s["m1.x"][1])
    assert 0 < n <= len(full["m1.x"][1])
    np.testing.assert_array_equal(s["m1.x"][1], full["m1.x"][1][:n])


@pytest.mark.parametrize("times, bad", [([0.0, 1.0, 0.5], "times[2] = 0.5 < times[1] = 1"),
                                        ([0.0, -1.0], "times[1] = -1 < times[0] = 0")])
def test_table_times_must_increase_at_every_consecutive_pair(tmp_path, test_fmus, times, bad):
    from immersim.orchestrator.errors import ScenarioError

    p = tmp_path / "table.toml"
    p.write_text(f'[[units]]\nname = "m"\nfmu = "{test_fmus["oscillator"]}"\n'
                 f'[[inputs]]\ntarget = "m.x_other"\nkind = "table"\ntimes = {times}\nvalues = {[0.0] * len(times)}\n')
    with pytest.raises(ScenarioError, match=f"'times' must be increasing: {bad.replace('[', '.').replace(']', '.')}"):
        run_scenario(p)


def test_seconds_to_integer_nanoseconds_rounds_to_the_nearest():
    from immersim.orchestrator.scenario import seconds_to_ns

    assert seconds_to_ns(1.001) == 1_001_000_000     # 1.001 * 1e9 = 1000999999.9999999
    assert seconds_to_ns(0.033) == 33_000_000 and seconds_to_ns(-0.5) == -500_000_000


def test_simulation_and_log_overrides_write_their_table():
    from pathlib import Path

    from immersim.orchestrator.scenario import apply_overrides

    data = {"simulation": {"stop": 1.0}, "units": [{"name": "m", "fmu": "x.fmu"}]}
    origins = apply_overrides(data, Path("s.toml"), {"simulation.stop": 2.5, "log.encoding": "ros1", "m.k": 3.0})
    assert data["simulation"]["stop"] == 2.5 and data["log"] == {"encoding": "ros1"}
    assert data["units"][0]["parameters"] == {"k": 3.0}
    assert origins[("simulation", "stop")] == "simulation.stop"


def test_a_fault_is_active_from_its_own_time_on():
    from immersim.orchestrator.manipulators import Fault
    from immersim.orchestrator.scenario import FaultSpec

    f = Fault(FaultSpec("m", "x_other", 330_000_000, float("nan")))
    assert not f.active(329_999_999) and f.active(330_000_000) and f.active(10 ** 12)


def _feedthrough_pair(tmp_path, extrapolation):
    from pathlib import Path

    fmu = Path(__file__).resolve().parents[1] / "conformance" / "reference-fmus" / "fmi2" / "Feedthrough.fmu"
    sine = 'kind = "sine"\namplitude = 1.0\nfrequency = 0.7\n'
    p = tmp_path / f"feed_{extrapolation}.toml"
    p.write_text(f'''[simulation]
stop = 0.8
step = 0.1
extrapolation = "{extrapolation}"
[[units]]
name = "a"
fmu = "{fmu}"
[[units]]
name = "b"
fmu = "{fmu}"
[[inputs]]
target = "a.Float64_discrete_input"
{sine}
[[inputs]]
target = "a.Float64_continuous_input"
{sine}
[[connections]]
from = "a.Float64_discrete_output"
to = "b.Float64_continuous_input"
[[connections]]
from = "a.Float64_continuous_output"
to = "b.Float64_discrete_input"
''')
    out = tmp_path / f"feed_{extrapolation}.mcap"
    run_scenario(p, out)
    return read_series(out, ["a.Float64_discrete_output", "b.Float64_continuous_input", "b.Float64_discrete_input"])


def test_a_discrete_source_is_held_under_linear_extrapolation(tmp_path):
    """The Reference FMU Feedthrough's ``Float64_discrete_output`` (variability discrete) feeds
    b under ``extrapolation = "linear"``: a discrete value is piecewise constant, so it is held
    (the zoh run's input at every step, each a value a output), while the continuous output of
    the same sine, on the other connection, is extrapolated (differs from the zoh run)."""
    lin, zoh = _feedthrough_pair(tmp_path, "linear"), _feedthrough_pair(tmp_path, "zoh")
    held = lin["b.Float64_continuous_input"][1]
    np.testing.assert_array_equal(held, zoh["b.Float64_continuous_input"][1])
    assert set(held.tolist()) <= set(lin["a.Float64_discrete_output"][1].tolist())
    assert np.ptp(held) > 0.5
    extrapolated = lin["b.Float64_discrete_input"][1] - zoh["b.Float64_discrete_input"][1]
    assert np.abs(extrapolated).max() > 0.05
