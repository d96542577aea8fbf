"""Lazy stepping: a unit at rest with unchanged inputs is not called; one catch-up step when
its inputs change; the log is identical to eager stepping."""
import numpy as np

from immersim.orchestrator.execution import Execution
from immersim.orchestrator.mcapio import read_series


def scenario(tmp_path, fmu, lazy):
    p = tmp_path / f"lazy_{lazy}.toml"
    p.write_text(f'''
[simulation]
stop = 4.0
step = 0.033
lazy = {str(lazy).lower()}
[[units]]
name = "a"
fmu = "{fmu}"
[[units]]
name = "idle"
fmu = "{fmu}"
[[inputs]]
target = "a.x_other"
kind = "table"
times = [0.0, 1.98, 1.99, 10.0]
values = [0.0, 0.0, 0.6, 0.6]
''')
    return p


def test_lazy_equals_eager_and_skips_idle_steps(tmp_path, test_fmus):
    fmu = test_fmus["oscillator"]
    runs = {}
    for lazy in (False, True):
        ex = Execution(scenario(tmp_path, fmu, lazy), tmp_path / f"lazy_{lazy}.mcap")
        res = ex.run()
        runs[lazy] = (res, read_series(tmp_path / f"lazy_{lazy}.mcap", ["a.*", "idle.*"]))
    (_, eager), (_, lazy) = runs[False], runs[True]
    assert eager.keys() == lazy.keys()
    for name in eager:
        np.testing.assert_array_equal(eager[name][0], lazy[name][0])
        np.testing.assert_array_equal(eager[name][1], lazy[name][1], err_msg=name)
    # the input steps at 1.98 < t <= 2.013: 'a' moves afterwards, 'idle' never does
    x = lazy["a.x"][1]
    assert np.all(x[:61] == 0.0) and np.abs(x[62:]).max() > 0.1


def test_lazy_skips_calls(tmp_path, test_fmus):
    ex = Execution(scenario(tmp_path, test_fmus["oscillator"], True))
    res = ex.run()
    assert res.steps_done == 122
    master = ex.master
    assert master.slots["idle"].skipped_steps == 122
    assert 55 <= master.slots["a"].skipped_steps <= 61
    assert master.slots["idle"].inst.t_ns == 4_000_000_000  # caught up at the end
