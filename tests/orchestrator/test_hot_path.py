"""The per-step path makes exactly the FMI calls a macro step needs, and logs exactly once.

No timing here (benchmarks/bench_orchestrator.py measures); these tests pin the structure the
benchmark relies on: one fmi2DoStep, one fmi2GetReal and one fmi2GetBoolean for all the
variables of a unit, one fmi2SetReal for all its connected Real inputs (none when they equal
the last step's), one message per unit.
"""
from collections import Counter

import pytest
from mcap.reader import make_reader

from immersim.orchestrator import fmu as fmu_module
from immersim.orchestrator.execution import run_scenario

from .helpers import oscillator_scenario


@pytest.fixture
def counted_calls(monkeypatch):
    """Count the fast-path FMI calls per (instance, function)."""
    calls: Counter = Counter()
    original = fmu_module.FmuInstance._fast_function

    def counting(self, name):
        fn = original(self, name)
        key = (self.name, name)

        def call(*args):
            calls[key] += 1
            return fn(*args)
        return call

    monkeypatch.setattr(fmu_module.FmuInstance, "_fast_function", counting)
    return calls


@pytest.mark.parametrize("algorithm", ["jacobi", "gauss-seidel"])
def test_one_call_per_function_and_unit_per_step(tmp_path, test_fmus, counted_calls, algorithm):
    n = 25
    out = tmp_path / "run.mcap"
    res = run_scenario(oscillator_scenario(tmp_path, test_fmus["oscillator"], step=0.033, stop=n * 0.033,
                                           algorithm=algorithm), out)
    assert res.steps_done == n
    for unit in ("m1", "m2"):
        assert counted_calls[(unit, "fmi2DoStep")] == n
        assert counted_calls[(unit, "fmi2SetReal")] == n  # x_other, set once per step
        # x_other, x, v, f_coupling in one call, at_rest in another; plus the two reads at
        # initialization (after the unit's own, and the master's initial values)
        assert counted_calls[(unit, "fmi2GetReal")] == n + 2
        assert counted_calls[(unit, "fmi2GetBoolean")] == n + 2
        assert counted_calls[(unit, "fmi2GetInteger")] == 0
    with open(out, "rb") as fh:
        per_topic = Counter(channel.topic for _, channel, _ in make_reader(fh).iter_messages())
    assert per_topic == {"m1": n + 1, "m2": n + 1, "m1/parameters": 1, "m2/parameters": 1}


def test_inputs_equal_to_the_last_step_s_are_not_set_again(tmp_path, test_fmus, counted_calls):
    """A step signal on the only input: fmi2SetReal at the first step and when the value
    changes (FMI keeps an input until it is set), and the log still has the input's values."""
    import numpy as np

    from immersim.orchestrator.mcapio import read_series

    text = f'''
[simulation]
stop = 0.66
step = 0.033

[[units]]
name = "m"
fmu = "{test_fmus['oscillator']}"
parameters = {{ x0 = 1.0 }}

[[inputs]]
target = "m.x_other"
kind = "step"
at = 0.3
value = 0.5
'''
    (tmp_path / "one.toml").write_text(text)
    run_scenario(tmp_path / "one.toml", tmp_path / "one.mcap")
    assert counted_calls[("m", "fmi2SetReal")] == 2 and counted_calls[("m", "fmi2DoStep")] == 20
    t, x = read_series(tmp_path / "one.mcap", ["m.x_other"])["m.x_other"][:2]
    # logged at a step's end: the value set at its start (the signal at t - h)
    np.testing.assert_array_equal(x, np.where(t - 0.033 >= 0.3 - 1e-12, 0.5, 0.0))


def test_a_changed_zero_sign_or_a_fault_sets_the_inputs_again():
    """``_apply`` compares with the last step's inputs bit for bit (0.0 and -0.0 differ) and
    sets everything again after a step in which a fault forced an input."""
    from immersim.orchestrator.stepping import Slot, Stepper

    calls = []

    class Recorder:
        def __init__(self, tag):
            self.tag = tag

        def set(self, values):
            calls.append((self.tag, values))

        def set_values(self, values):
            calls.append(("forced", values))

    slot = Slot("u", Recorder("inst"), [])
    slot.inst.set_values = Recorder("forced").set
    slot.inputs.setter, slot.inputs.other_setter = Recorder("real"), Recorder("discrete")
    steps = [((1.0, 0.0), (True,), ()),
             ((1.0, 0.0), (True,), ()),            # the same: nothing set
             ((1.0, -0.0), (True,), ()),           # -0.0 is not 0.0 for a model
             ((1.0, -0.0), (False,), ()),          # only the Boolean changed
             ((1.0, -0.0), (False,), (("x", 2.0),)),
             ((1.0, -0.0), (False,), ())]          # after a forced step: everything again
    for inputs in steps:
        Stepper._apply(slot, inputs)
    assert calls == [("real", (1.0, 0.0)), ("discrete", (True,)),
                     ("real", (1.0, -0.0)),
                     ("discrete", (False,)),
                     ("forced", {"x": 2.0}),
                     ("real", (1.0, -0.0)), ("discrete", (False,))]
    assert str(calls[2][1][1]) == "-0.0"
