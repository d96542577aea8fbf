"""§6.4.2 tracking on the nominal model, and the macro-step integrators against a tight reference."""
import numpy as np
import pytest

from immersim.models.platform.control import ControlParams, prefiltered_loop, simulate_tracking, sine_reference
from immersim.models.platform.integrators import IntegratorConfig, StepIntegrator
from immersim.models.platform.params import PlatformParams

H = 0.033


@pytest.mark.parametrize("a_z, q0", [(0.0, None), (0.025, np.array([-0.025, -0.025, -0.025, 0, 0, 0]))])
def test_computed_torque_tracks_scaled_6_4_2_trajectories_below_0_1_mm(a_z, q0):
    ref = sine_reference(a_y=0.05, a_z=a_z)
    ct = simulate_tracking(ref, 2 * np.pi, q0, control="computed_torque", rtol=1e-9, atol=1e-11)
    after = ct.t >= 2.0
    assert ct.position_error()[after].max() < 1e-4
    assert np.abs(ct.q[after, 3:]).max() < 1e-6  # no spurious rotation
    pd = simulate_tracking(ref, 2 * np.pi, q0, control="pd", rtol=1e-9, atol=1e-11)
    # the PD baseline has no feed-forward: bounded, but orders of magnitude worse
    assert 10 * ct.position_error()[after].max() < pd.position_error()[after].max() < 5e-3


def test_planar_plant_tracks_yz_ellipse_like_the_full_plant():
    p = PlatformParams(k_C=0.0, p_C=0.0, p_B=0.0)
    ref = sine_reference(a_y=0.05, a_z=0.025)
    full = simulate_tracking(ref, 3.0, params=p, model="full", rtol=1e-10, atol=1e-12)
    planar = simulate_tracking(ref, 3.0, params=p, model="planar", rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(planar.q, full.q, atol=1e-9)


def _run(cfg, n_steps=30, u=None):
    f = prefiltered_loop("computed_torque", "full")
    integ = StepIntegrator(f, cfg)
    p, c = PlatformParams().vector(), ControlParams().vector()
    x = np.zeros(24)
    u = np.array([0.01, 0.04, -0.02, 0.05, -0.03, 0.04, 0, 0, 0, 0, 0, 0]) if u is None else u
    for _ in range(n_steps):
        x = integ.step(x, u, p, c, H)
    return x


@pytest.fixture(scope="module")
def reference_state():
    return _run(IntegratorConfig("dop853", rtol=1e-13, atol=1e-15))


@pytest.mark.parametrize("cfg, tol", [
    (IntegratorConfig("rk4", 2), 1e-6),
    (IntegratorConfig("rk4", 8), 1e-9),
    (IntegratorConfig("implicit", 2), 1e-6),
    (IntegratorConfig("cvode_bdf", rtol=1e-8, atol=1e-10), 1e-6),
    (IntegratorConfig("cvode_adams", rtol=1e-8, atol=1e-10), 1e-6),
    (IntegratorConfig("cvode_bdf", rtol=1e-11, atol=1e-13), 1e-9),
])
def test_integrators_agree_with_tight_reference(cfg, tol, reference_state):
    x = _run(cfg)
    assert np.max(np.abs(x[:6] - reference_state[:6])) < tol


def test_rk4_is_fourth_order_in_the_substep_count(reference_state):
    errs = np.array([np.max(np.abs(_run(IntegratorConfig("rk4", n))[:6] - reference_state[:6])) for n in (2, 4, 8)])
    orders = np.log2(errs[:-1] / errs[1:])
    assert np.all(orders > 3.6) and np.all(orders < 4.6), (errs, orders)


def test_compiled_and_virtual_machine_rk4_agree():
    a = _run(IntegratorConfig("rk4", 3, compiled=True), n_steps=10)
    b = _run(IntegratorConfig("rk4", 3, compiled=False), n_steps=10)
    np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-15)
