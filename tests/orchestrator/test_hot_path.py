"""The per-step path makes exactly the FMI calls a macro step needs, and logs exactly once.

No timing here (benchmarks/bench_orchestrator.py measures); these tests pin the structure the
benchmark relies on: one fmi2DoStep, one fmi2GetReal and one fmi2GetBoolean for all the
variables of a unit, one fmi2SetReal for all its connected Real inputs, one message per unit.
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
