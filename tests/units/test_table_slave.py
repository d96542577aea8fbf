"""The base class's bulk access and checks, in Python (no FMI layer): cached value-reference
lists read current values, type errors and unknown references are refused, a non-finite
input is refused at the next step however it arrived, and a non-finite output is never
handed out."""
from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import pytest

from immersim.fmus.common import OUTPUTS_UNCHANGED, TableSlave, Var

_SPEC = importlib.util.spec_from_file_location(
    "oscillator_fmu", Path(__file__).parent / "oscillator" / "oscillator_fmu.py")
_MOD = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(_MOD)
oscillator = _MOD.oscillator


def _slave(cls=oscillator, **params):
    s = cls(instance_name="u1", resources=".")
    for name, value in params.items():
        s.values[name] = value
    s.setup_experiment(0.0, None, None)
    s.enter_initialization_mode()
    s.exit_initialization_mode()
    return s


def _vr(s, *names):
    by_name = {v.name: vr for vr, v in s.vars.items()}
    return [by_name[n] for n in names]


def test_cached_reads_follow_the_values():
    s = _slave(x0=1.0)
    vrs = _vr(s, "x", "v", "f_coupling")
    first = s.get_real(list(vrs))
    assert first == [1.0, 0.0, -1.0]
    assert s.do_step(0.0, 0.1)
    # same reference list again (cached getter): the new values, as plain floats
    w = math.sqrt(2.0)
    x, v = math.cos(w * 0.1), -w * math.sin(w * 0.1)  # x_other = 0: x_eq = 0
    assert s.get_real(list(vrs)) == pytest.approx([x, v, -x], rel=1e-15)
    assert s.get_real(vrs[1:2]) == pytest.approx([v], rel=1e-15)
    assert s.get_real([]) == []
    assert s.get_boolean(_vr(s, "at_rest")) == [False]


def test_set_real_writes_floats_and_refuses_other_types():
    s = _slave()
    (vx,) = _vr(s, "x_other")
    s.set_real([vx], [2])
    assert s.values["x_other"] == 2.0 and isinstance(s.values["x_other"], float)
    with pytest.raises(TypeError, match=r"u1: valueReference \d+ \(at_rest\) is not Real"):
        s.set_real(_vr(s, "at_rest"), [1.0])
    with pytest.raises(TypeError, match=r"\(x\) is not Boolean"):
        s.get_boolean(_vr(s, "x"))
    with pytest.raises(KeyError, match="no variable with valueReference 999"):
        s.get_real([999])


def test_nonfinite_input_is_refused_until_replaced():
    s = _slave(x0=1.0)
    (vx,) = _vr(s, "x_other")
    assert s.do_step(0.0, 0.1)
    s.set_real([vx], [float("nan")])
    assert not s.do_step(0.1, 0.1)
    assert s.failed == "FmuInputError: u1: input x_other = nan at t = 0.1 s is not finite"
    assert not s.do_step(0.1, 0.1)  # still there: refused again, time not advanced
    s.set_real([vx], [0.25])
    assert s.do_step(0.1, 0.1)


def test_restored_state_is_checked():
    s = _slave(x0=1.0)
    state = s._get_fmu_state()
    state["values"]["x_other"] = math.inf
    s._set_fmu_state(state)
    assert not s.do_step(0.0, 0.1)
    assert "input x_other = inf" in s.failed


class _Blowup(TableSlave):
    """Writes the output ``y = 1 / (1 - t)``: infinite at t = 1, unchanged once ``hold`` is set."""

    modelName = "blowup"
    VARIABLES = (Var("hold", "input", "Real", 0.0), Var("y", "output", "Real", 1.0),
                 Var("n", "output", "Integer", 0))

    def step_model(self, t, h):
        if self.values["hold"]:
            return OUTPUTS_UNCHANGED
        self.values["y"] = math.inf if t + h == 1.0 else 1.0 / (1.0 - (t + h))
        self.values["n"] += 1
        return None


def test_nonfinite_output_is_refused():
    s = _slave(_Blowup)
    assert s.do_step(0.0, 0.5)
    assert s.get_real(_vr(s, "y")) == [2.0] and s.get_integer(_vr(s, "n")) == [1]
    assert not s.do_step(0.5, 0.5)
    assert s.failed == "FmuModelError: u1: output y = inf at t = 1 s is not finite"


def test_unchanged_outputs_skip_the_model_output():
    s = _slave(_Blowup)
    s.set_real(_vr(s, "hold"), [1.0])
    assert s.do_step(0.0, 0.5) and s.do_step(0.5, 0.5)
    assert s.get_real(_vr(s, "y")) == [1.0] and s.get_integer(_vr(s, "n")) == [0]
