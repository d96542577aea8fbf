"""Scenario input signals: the table signal is numpy.interp's arithmetic in Python floats."""
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from immersim.orchestrator.manipulators import signal
from immersim.orchestrator.scenario import InputSpec


def table(times, values):
    return signal(InputSpec("u", "x", "table", {"times": times, "values": values}))


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(st.sampled_from([0.0, 0.033, 0.5, 1.0, 2.5, 2.5, 6.0, 12.0]),
                          st.floats(-10, 10)), min_size=1, max_size=7),
       st.lists(st.floats(-1.0, 15.0), min_size=1, max_size=20))
def test_table_is_bit_identical_to_numpy_interp(points, ts):
    """Every value equals numpy.interp's (same slope, same products), repeated times (a jump)
    and the held ends included."""
    points = sorted(points, key=lambda p: p[0])
    times, values = [p[0] for p in points], [p[1] for p in points]
    f = table(times, values)
    for t in ts + times + [k * 0.033 for k in range(400)]:
        assert f(t) == float(np.interp(t, times, values))


def test_table_holds_outside_and_interpolates_inside():
    f = table([1.0, 3.0], [2.0, 6.0])
    assert f(0.0) == 2.0 and f(5.0) == 6.0       # held before and after
    assert f(2.0) == pytest.approx(4.0, abs=0)   # midpoint of a straight line
    assert f(1.5) == 3.0
    assert math.isnan(f(float("nan")))          # as numpy.interp
