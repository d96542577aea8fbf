"""Platform simulator: long-run boundedness, lazy rest, washout behaviour, config errors."""
import numpy as np
import pytest

from immersim.models.platform.cueing import Washout, WashoutParams
from immersim.models.platform.integrators import IntegratorConfig
from immersim.models.platform.kinematics import OutsideWorkspaceError, workspace_check
from immersim.models.platform.simulator import PlatformSim, SimConfig, StepInputs

H = 0.033


@pytest.mark.slow
def test_one_hour_of_avatar_motion_stays_bounded():
    sim = PlatformSim(SimConfig(integrator=IntegratorConfig("rk4", 1)))  # cheap: 109 091 steps
    rng = np.random.default_rng(3)
    n = int(3600 / H)
    t = np.arange(n) * H
    # avatar driving: surge/sway from a few incommensurate sines, yaw rate, collisions every ~20 s
    f = np.column_stack([1.2 * np.sin(0.31 * t) + 0.6 * np.sin(1.7 * t), 0.8 * np.sin(0.53 * t + 1),
                         0.5 * np.sin(2.9 * t)])
    w = np.column_stack([0.1 * np.sin(0.7 * t), 0.08 * np.sin(0.41 * t), 0.2 * np.sin(0.23 * t)])
    jolt = np.where(rng.random(n) < H / 20, rng.uniform(-15, 15, n), 0.0)
    worst = np.zeros(6)
    clamped = 0
    for k in range(n):
        out = sim.step(StepInputs(f=f[k], omega=w[k], jolt=jolt[k]), H, t[k])
        worst = np.maximum(worst, np.abs(out.pose))
        clamped += out.outside_workspace
    assert np.all(np.isfinite(worst)) and clamped < n // 10
    assert np.all(worst[:3] < 0.15) and np.all(worst[3:] < 0.5)
    assert workspace_check(out.pose).inside[0]
    # it comes back to rest once the avatar stops
    for k in range(int(60 / H)):
        out = sim.step(StepInputs(), H, 3600 + k * H)
    np.testing.assert_allclose(out.pose, 0.0, atol=2e-4)


def test_lazy_rest_skips_steps_and_wakes_up():
    sim = PlatformSim(SimConfig())
    for k in range(5):
        out = sim.step(StepInputs(), H, k * H)
    assert out.at_rest and sim.skipped_steps == 5
    out = sim.step(StepInputs(jolt=5.0), H, 5 * H)
    assert not out.at_rest and sim.skipped_steps == 5 and out.pose[0] > 0


def test_with_direct_forces_zero_inputs_do_not_skip_gravity():
    sim = PlatformSim(SimConfig(control_mode="direct", cueing="pose"))
    for k in range(3):
        out = sim.step(StepInputs(), H, k * H)
    assert sim.skipped_steps == 0 and not out.at_rest
    # free fall for 0.099 s, the rods' hinges hardly resist yet: z = -g t^2 / 2
    np.testing.assert_allclose(out.pose[2], -0.5 * 9.81 * (3 * H) ** 2, rtol=0.05)


def test_washout_returns_to_centre_and_tilts_for_sustained_surge():
    w = Washout(WashoutParams())
    for _ in range(int(30 / H)):
        ref = w.step(np.array([1.0, 0, 0]), np.zeros(3), 0.0, H)
    # translation washed out, sustained specific force rendered by a nose-up tilt: -g sin(beta) = f_x
    assert abs(ref[0]) < 1e-3
    np.testing.assert_allclose(-9.81 * np.sin(ref[4]), 1.0, rtol=1e-3)


def test_tilt_rate_is_limited():
    p = WashoutParams()
    w = Washout(p)
    prev = 0.0
    for _ in range(100):
        ref = w.step(np.array([5.0, 0, 0]), np.zeros(3), 0.0, H)
        assert abs(w.tilt[1] - prev) <= p.tilt_rate * H + 1e-15
        prev = w.tilt[1]


def test_direct_forces_that_throw_the_platform_out_raise():
    sim = PlatformSim(SimConfig(control_mode="direct", cueing="pose"))
    with pytest.raises((OutsideWorkspaceError, ArithmeticError), match="reach"):
        for k in range(200):
            sim.step(StepInputs(force_cmd=np.array([0, 0, 0, 3000.0, 3000.0, 3000.0])), H, k * H)


def test_bad_configuration_names_the_setting():
    with pytest.raises(ValueError, match="control_mode = 'lqr'"):
        SimConfig(control_mode="lqr")
    with pytest.raises(ValueError, match="integrator 'euler'"):
        IntegratorConfig("euler")
