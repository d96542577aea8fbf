"""Coupled oscillators converge to the analytic solution with the expected order in h.

m1 and m2 (m = k = kc = 1) start at x1 = 1, x2 = 0 at rest. The normal modes give
x1 = (cos t + cos(sqrt(3) t))/2 and x2 = (cos t - cos(sqrt(3) t))/2. Each FMU integrates its
own mass exactly for a held input, so the whole error is the coupling error of the master:
first order for zero-order hold, second order for linear extrapolation/interpolation.
"""
import math

import numpy as np
import pytest

from immersim.orchestrator.execution import run_scenario
from immersim.orchestrator.mcapio import read_series

from .helpers import oscillator_scenario


def exact(t):
    return 0.5 * (np.cos(t) + np.cos(math.sqrt(3) * t)), 0.5 * (np.cos(t) - np.cos(math.sqrt(3) * t))


def max_error(tmp_path, fmu, h, algorithm, extrapolation):
    scn = oscillator_scenario(tmp_path, fmu, step=h, stop=4.0, algorithm=algorithm,
                              extrapolation=extrapolation, name=f"osc_{h}_{algorithm}_{extrapolation}.toml")
    out = tmp_path / f"{scn.stem}.mcap"
    run_scenario(scn, out)
    s = read_series(out, ["m1.x", "m2.x"])
    t, x1, _ = s["m1.x"]
    _, x2, _ = s["m2.x"]
    e1, e2 = exact(t)
    assert t[-1] == pytest.approx(4.0, abs=1e-12)
    return max(np.abs(x1 - e1).max(), np.abs(x2 - e2).max())


@pytest.mark.parametrize("algorithm", ["jacobi", "gauss-seidel"])
@pytest.mark.parametrize("extrapolation,order", [("zoh", 1.0), ("linear", 2.0)])
def test_convergence_order(tmp_path, test_fmus, algorithm, extrapolation, order):
    fmu = test_fmus["oscillator"]
    hs = [0.02, 0.01, 0.005]
    errs = [max_error(tmp_path, fmu, h, algorithm, extrapolation) for h in hs]
    orders = [math.log(errs[i] / errs[i + 1], 2) for i in range(2)]
    assert all(abs(p - order) < 0.25 for p in orders), (errs, orders)
    assert errs[-1] < (0.02 if order == 1 else 2e-4)


def test_gauss_seidel_beats_jacobi_at_equal_step(tmp_path, test_fmus):
    fmu = test_fmus["oscillator"]
    ej = max_error(tmp_path, fmu, 0.01, "jacobi", "zoh")
    eg = max_error(tmp_path, fmu, 0.01, "gauss-seidel", "zoh")
    assert eg < ej


def test_angle_extrapolation_takes_the_short_way_round():
    """``extrapolation = "angle"``: an angle wrapped to (-pi, pi] that passes pi between two
    samples (3.1 -> -3.1 rad, a turn of +0.083 rad) is interpolated (a source stepped before)
    and extrapolated (one not yet stepped) along that turn; plain linear gives a half turn off.
    Away from a wrap it equals linear to rounding."""
    import math

    from immersim.orchestrator.stepping import FloatFeed, Slot, gather as gather_inputs

    def gather(mode, cur, prev, stepped):
        src = Slot("src", None, ["yaw"])
        src.cur, src.prev, src.stepped = [cur], [prev], stepped
        dst = Slot("dst", None, [])
        dst.inputs.values = [0.0]
        dst.inputs.float_feeds = [FloatFeed(0, src, 0, not stepped, 1.0, 0.0, mode)]
        return gather_inputs(dst.inputs, 0)[0][0]

    turn = 2 * math.pi - 6.2
    assert gather(2, -3.1, 3.1, True) == pytest.approx(3.1 + turn / 2, abs=1e-15)     # mid-step: ~pi
    assert gather(2, -3.1, 3.1, False) == pytest.approx(-3.1 + turn / 2, abs=1e-15)   # extrapolated
    assert gather(1, -3.1, 3.1, True) == 0.0 and gather(1, -3.1, 3.1, False) == pytest.approx(-6.2)
    for cur, prev in ((0.3, 0.1), (-1.0, -1.2), (3.0, 2.9)):
        for stepped in (True, False):
            assert gather(2, cur, prev, stepped) == pytest.approx(gather(1, cur, prev, stepped), abs=1e-15)
