"""Connections with gain and offset; units initialize from their sources' initial outputs."""
import numpy as np
import pytest

from immersim.orchestrator.errors import ScenarioError
from immersim.orchestrator.execution import run_scenario
from immersim.orchestrator.mcapio import read_series


def scenario(tmp_path, fmu, conn_extra="gain = 2.0\noffset = 0.5"):
    p = tmp_path / "gain.toml"
    p.write_text(f'''
[simulation]
stop = 0.66
algorithm = "gauss-seidel"
extrapolation = "zoh"  # the exact relation below holds for the held value
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
{conn_extra}
''')
    return p


def test_gain_offset_and_consistent_initialization(tmp_path, test_fmus):
    out = tmp_path / "g.mcap"
    run_scenario(scenario(tmp_path, test_fmus["oscillator"]), out)
    s = read_series(out, ["m1.x", "m2.x_other", "m2.f_coupling"])
    x1, u2 = s["m1.x"][1], s["m2.x_other"][1]
    # Gauss-Seidel (m1 steps first though listed second): m2 sees 2 * x1 + 0.5 of the same instant
    np.testing.assert_array_equal(u2, 2.0 * x1 + 0.5)
    # at t = 0 too: m2 was initialized after m1, with its input already set
    assert u2[0] == 2.5
    assert s["m2.f_coupling"][1][0] == pytest.approx(2.5)  # -kc (x - x_other) computed at initialization


def test_gain_on_a_boolean_connection_is_rejected(tmp_path, test_fmus):
    fmu = test_fmus["oscillator"]
    p = tmp_path / "b.toml"
    p.write_text(f'''
[[units]]
name = "a"
fmu = "{fmu}"
[[units]]
name = "b"
fmu = "{fmu}"
[[connections]]
from = "a.at_rest"
to = "b.x_other"
gain = 3.0
''')
    with pytest.raises(ScenarioError, match=r"type mismatch Boolean -> Real"):
        run_scenario(p)


def test_bad_gain(tmp_path, test_fmus):
    with pytest.raises(ScenarioError, match=r"connections\[0\].gain: expected a number, got 'big'"):
        run_scenario(scenario(tmp_path, test_fmus["oscillator"], 'gain = "big"'))


@pytest.mark.parametrize("workers, chained", [((1, 1), ["m2"]), ((1, 2), [])])
def test_a_unit_fed_fresh_only_by_its_worker_mate_is_chained_to_it(tmp_path, test_fmus, workers, chained):
    """Gauss-Seidel over the two coupled oscillators (order m1, m2; m2 reads m1.x fresh, m1 reads
    m2.x delayed): with both units in one worker, m2's every input comes fresh from m1, posted
    in that worker, so m2 is chained to it; in another worker it is not. Either way the log is
    the one-process log bit for bit."""
    from immersim.orchestrator.execution import Execution

    from .helpers import oscillator_scenario

    scn = oscillator_scenario(tmp_path, test_fmus["oscillator"], step=0.01, stop=0.5, algorithm="gauss-seidel")
    here, there = tmp_path / "here.mcap", tmp_path / "there.mcap"
    run_scenario(scn, here)
    ex = Execution(scn, there, overrides={"m1:process": workers[0], "m2:process": workers[1]})
    ex.run()
    assert [s.name for s in ex.master._chained] == chained
    a, b = read_series(here, ["m1.x", "m2.x"]), read_series(there, ["m1.x", "m2.x"])
    for k in a:
        np.testing.assert_array_equal(a[k][0], b[k][0])
        np.testing.assert_array_equal(a[k][1], b[k][1])
