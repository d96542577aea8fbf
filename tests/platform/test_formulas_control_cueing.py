"""Controller, prefilter, washout and damping formulas against closed forms derived here.

Each test states the closed form it checks; none compares two implementations of the same code.
"""
import math

import numpy as np
import pytest

from immersim.models.platform.control import ControlParams, prefiltered_loop, simulate_tracking
from immersim.models.platform.cueing import Washout, WashoutParams, continuous_system
from immersim.models.platform.dynamics import functions, model_terms
from immersim.models.platform.params import PlatformParams
from immersim.models.platform.simulator import PlatformSim, SimConfig, StepInputs

H = 0.033


def _hold(q_ref):
    q_ref = np.asarray(q_ref, float)
    return lambda t: (q_ref, np.zeros(6), np.zeros(6))


def _second_order_error(e0, omega, zeta, t):
    """Free response of e'' + 2 zeta omega e' + omega^2 e = 0 from e(0) = e0, e'(0) = 0."""
    if zeta == 1.0:
        return e0 * (1.0 + omega * t) * np.exp(-omega * t)
    wd = omega * math.sqrt(1.0 - zeta * zeta)
    return e0 * np.exp(-zeta * omega * t) * (np.cos(wd * t) + zeta * omega / wd * np.sin(wd * t))


@pytest.mark.parametrize("omega, zeta", [(20.0, 1.0), (15.0, 0.5)])
def test_computed_torque_from_an_offset_follows_the_closed_loop_closed_form(omega, zeta):
    """Computed torque on the nominal model: e'' + K_d e' + K_p e = 0 with K_p = w^2, K_d = 2 zeta w.
    From a 25 mm sway offset at rest, e(t) = e0 (1 + w t) e^(-w t) (zeta = 1) or the underdamped form."""
    e0 = 0.025
    res = simulate_tracking(_hold(np.zeros(6)), 0.4, q0=[0, e0, 0, 0, 0, 0],
                            cparams=ControlParams(omega_c=omega, zeta_c=zeta), dt_out=0.02)
    expected = _second_order_error(e0, omega, zeta, res.t)
    np.testing.assert_allclose(-res.q[:, 1], -expected, atol=1e-8)   # e = q_r - q = -q here
    assert np.abs(res.q[:, [0, 2, 3, 4, 5]]).max() < 1e-8            # the other axes stay decoupled
    if zeta == 1.0:   # the figures of the critically damped loop: 10.15 / 2.29 / 0.076 mm
        for t, mm in ((0.1, 10.150), (0.2, 2.290), (0.4, 0.0755)):
            k = int(round(t / 0.02))
            assert abs(res.q[k, 1] * 1e3 - mm) < 2e-3 * max(mm, 1.0)


@pytest.mark.parametrize("omega_f", [15.0, 4.0])
def test_reference_prefilter_is_critically_damped_second_order(omega_f):
    """r'' = w_f^2 (u - r) - 2 w_f r' evaluated directly on the prefiltered loop's right-hand side."""
    f = prefiltered_loop("computed_torque", "full")
    rng = np.random.default_rng(3)
    x = np.zeros(24)
    x[12:18] = rng.normal(scale=0.01, size=6)
    x[18:24] = rng.normal(scale=0.05, size=6)
    u = np.concatenate([rng.normal(scale=0.02, size=6), np.zeros(6)])
    xdot = np.asarray(f(x, u, PlatformParams().vector(), ControlParams(omega_f=omega_f).vector())[0]).ravel()
    r, dr = x[12:18], x[18:24]
    np.testing.assert_allclose(xdot[12:18], dr, rtol=0, atol=1e-15)
    np.testing.assert_allclose(xdot[18:24], omega_f ** 2 * (u[:6] - r) - 2 * omega_f * dr, rtol=1e-12, atol=1e-12)


def test_prefiltered_pose_step_follows_the_critically_damped_step_response():
    """Pose cueing, a held 10 mm heave step: the prefilter state r(t) = u (1 - (1 + w_f t) e^(-w_f t))
    at the end of every macro step (RK4 substeps: agreement to 1e-6 m, 1e-4 of the step)."""
    sim = PlatformSim(SimConfig(cueing="pose"))
    wf = ControlParams().omega_f
    u = 0.01
    ref = np.array([0, 0, u, 0, 0, 0])
    for k in range(1, 16):
        sim.step(StepInputs(ref=ref), H, (k - 1) * H)
        t = k * H
        assert abs(sim.x[14] - u * (1 - (1 + wf * t) * math.exp(-wf * t))) < 1e-6
        assert abs(sim.x[20] - u * wf * wf * t * math.exp(-wf * t)) < 1e-5
        out = sim.out   # the tracking error output is |C - C_ref| against the prefiltered reference
        assert out.track_err == pytest.approx(np.linalg.norm(out.pose[:3] - sim.x[12:15]), rel=1e-9, abs=1e-12)


# -- washout: transfer functions of eq. (classical washout) -------------------------------------
def _tf(A, B, C, s):
    """C (sI - A)^-1 B at complex s."""
    return C @ np.linalg.solve(s * np.eye(A.shape[0]) - A, B)


WP = WashoutParams(k_t=0.7, omega_t=2.0, zeta_t=0.8, omega_b=0.4, k_r=0.6, omega_r=1.3, zeta_r=0.7,
                   omega_tc=1.7, jolt_heave=0.35)


@pytest.mark.parametrize("w", [0.05, 0.3, 1.0, 2.5, 10.0])
def test_washout_frequency_responses_are_the_transfer_functions(w):
    """Every channel of the continuous washout system against its transfer function at s = j w."""
    p = WP
    A, B, C_pos, C_ang, C_lp = continuous_system(p)
    s = 1j * w
    G_t = p.k_t * s / ((s * s + 2 * p.zeta_t * p.omega_t * s + p.omega_t ** 2) * (s + p.omega_b))
    G_r = p.k_r * s / (s * s + 2 * p.zeta_r * p.omega_r * s + p.omega_r ** 2)
    G_lp = p.omega_tc ** 2 / (s + p.omega_tc) ** 2
    C = np.vstack([C_pos, C_ang, C_lp])
    G = np.array([_tf(A, B[:, k], C, s) for k in range(7)]).T    # (8 outputs, 7 inputs)
    expected = np.zeros((8, 7), complex)
    for i in range(3):
        expected[i, i] = G_t                     # f_x, f_y, f_z -> x, y, z
        expected[3 + i, 3 + i] = G_r             # w_x, w_y, w_z -> gamma, beta, alpha (high-passed)
    expected[6, 0] = expected[7, 1] = G_lp       # tilt low-pass of f_x, f_y
    expected[0, 6] = G_t                         # jolt -> surge
    expected[2, 6] = p.jolt_heave * G_t          # jolt share -> heave
    np.testing.assert_allclose(G, expected, rtol=1e-10, atol=1e-13)


def test_tilt_low_pass_step_response_is_critically_damped():
    """lp(t) = F (1 - (1 + w_tc t) e^(-w_tc t)) for a held f_x step; exact at the sample times (ZOH)
    and never above F (a critically damped filter does not overshoot)."""
    p = WashoutParams(tilt_max=0.5, tilt_rate=10.0)
    wo = Washout(p)
    F = 1.2
    lp = []
    for k in range(1, 120):
        wo.step(np.array([F, -0.5 * F, 0.0]), np.zeros(3), 0.0, H)
        t = k * H
        lp.append((wo.C_lp @ wo.x))
        np.testing.assert_allclose(lp[-1], np.array([F, -0.5 * F]) * (1 - (1 + p.omega_tc * t) * math.exp(-p.omega_tc * t)),
                                   rtol=1e-11, atol=1e-14)
    assert max(v[0] for v in lp) <= F


def _rotation(gamma, beta, alpha):
    """A = A_x(gamma) A_y(beta) A_z(alpha) (eq. 6-8), written out here."""
    cg, sg, cb, sb, ca_, sa = (math.cos(gamma), math.sin(gamma), math.cos(beta), math.sin(beta),
                               math.cos(alpha), math.sin(alpha))
    Ax = np.array([[1, 0, 0], [0, cg, -sg], [0, sg, cg]])
    Ay = np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
    Az = np.array([[ca_, -sa, 0], [sa, ca_, 0], [0, 0, 1]])
    return Ax @ Ay @ Az


@pytest.mark.parametrize("f", [(0.6, 0.0), (0.0, 0.6), (-0.4, 0.3)])
def test_tilt_coordination_sign_reproduces_the_sustained_force_with_gravity(f):
    """After a sustained specific force the translation has washed out and the seat is tilted so
    that gravity's specific force in the seat frame, A^T (0, 0, g), has the input's x and y."""
    p = WashoutParams()
    wo = Washout(p)
    fx, fy = f
    for _ in range(int(40 / H)):
        ref = wo.step(np.array([fx, fy, 0.0]), np.zeros(3), 0.0, H)
    assert np.abs(ref[:3]).max() < 2e-3              # translation washed out
    A = _rotation(ref[3], ref[4], ref[5])
    seat = A.T @ np.array([0.0, 0.0, p.g])
    np.testing.assert_allclose(seat[:2], [fx, fy], atol=2e-3)


def test_platform_tilt_from_the_native_washout_has_the_same_sign_as_gravity_requires():
    """The same law through the simulator's native macro step (its own washout expression): the
    platform's pose after 40 s of a sustained (0.5, -0.3) m/s^2 gives A^T (0, 0, g) with those x, y."""
    sim = PlatformSim(SimConfig())
    f = np.array([0.5, -0.3, 0.0])
    for k in range(int(40 / H)):
        out = sim.step(StepInputs(f=f), H, k * H)
    pose = out.pose
    assert np.abs(pose[:3]).max() < 2e-3
    seat = _rotation(pose[3], pose[4], pose[5]).T @ np.array([0.0, 0.0, WashoutParams().g])
    np.testing.assert_allclose(seat[:2], f[:2], atol=3e-3)


def test_jolt_goes_to_surge_and_its_share_to_heave_never_to_sway_or_tilt():
    """An 8 m/s^2 jolt for one step: heave = jolt_heave * surge at every step, sway and the tilt
    low-pass stay exactly zero, and the surge is the translational channel's response to f_x."""
    p = WashoutParams()
    jolted, forced = Washout(p), Washout(p)
    for k in range(60):
        j = 8.0 if k == 0 else 0.0
        a = jolted.step(np.zeros(3), np.zeros(3), j, H)
        b = forced.step(np.array([j, 0.0, 0.0]), np.zeros(3), 0.0, H)
        assert a[1] == 0.0 and a[3] == 0.0 and a[4] == 0.0 and a[5] == 0.0
        assert np.all(jolted.C_lp @ jolted.x == 0.0)
        np.testing.assert_allclose(a[0], b[0], rtol=1e-12, atol=1e-16)
        np.testing.assert_allclose(a[2], p.jolt_heave * a[0], rtol=1e-12, atol=1e-16)
    assert abs(a[0]) > 0 and max(abs(jolted.step(np.zeros(3), np.zeros(3), 0.0, H)[0]), 1e-9) > 0


def test_ball_joint_damping_dissipates_p_B_times_relative_rates_squared():
    """The damping part of h is dD/dq' with D = p_B/2 sum |Omega - omega_j|^2 (eq. 6-54/6-55), so
    q' . (h(p_B) - h(0)) = 2 D (D quadratic in q'). Omega and omega_j are computed here from the
    thesis's formulas, the rod-angle rates by central differences of the rod angles."""
    base = PlatformParams(p_C=0.0, k_C=0.0, g=0.0)
    damped = PlatformParams(p_C=0.0, k_C=0.0, g=0.0, p_B=0.7)
    undamped = PlatformParams(p_C=0.0, k_C=0.0, g=0.0, p_B=0.0)
    rng = np.random.default_rng(5)
    rod = functions()["rod_angles"]
    for _ in range(4):
        q = rng.normal(scale=[0.02, 0.02, 0.02, 0.05, 0.05, 0.05])
        dq = rng.normal(scale=[0.1, 0.1, 0.1, 0.3, 0.3, 0.3])
        _, h1, _, _ = model_terms(q, dq, damped)
        _, h0, _, _ = model_terms(q, dq, undamped)
        eps = 1e-6
        thp, php = (np.asarray(v).ravel() for v in rod(q + eps * dq, base.vector()))
        thm, phm = (np.asarray(v).ravel() for v in rod(q - eps * dq, base.vector()))
        th, ph = (np.asarray(v).ravel() for v in rod(q, base.vector()))
        dth, dph = (thp - thm) / (2 * eps), (php - phm) / (2 * eps)
        g, b = q[3], q[4]
        dg, db, da = dq[3:]
        Omega = np.array([dg + da * math.sin(b), db * math.cos(g) - da * math.cos(b) * math.sin(g),
                          db * math.sin(g) + da * math.cos(b) * math.cos(g)])
        D = 0.0
        for j in range(6):
            t_, p_, s, c = dth[j], dph[j], math.sin(ph[j]), math.cos(ph[j])
            if j == 0:
                wj = np.array([-t_ * s, t_ * c, p_])
            elif j < 3:
                wj = np.array([t_ * c, t_ * s, p_])
            else:
                wj = np.array([p_, t_ * c, t_ * s])
            D += 0.5 * damped.p_B * np.sum((Omega - wj) ** 2)
        assert D > 1e-6
        np.testing.assert_allclose(dq @ (h1 - h0), 2 * D, rtol=1e-6)


def test_tilt_grows_at_the_rate_limit_up_to_the_tilt_limit():
    """A sustained 5 m/s^2 surge asks for more than tilt_max (asin(5/9.81) > 10 deg). Per step the
    pitch tilt moves towards its target -asin(clip(lp / g, +-sin tilt_max)) by at most
    tilt_rate h: beta_k = beta_(k-1) + clip(target_k - beta_(k-1), +-tilt_rate h)."""
    p = WashoutParams()
    wo = Washout(p)
    beta, limited = 0.0, 0
    for k in range(1, 160):
        wo.step(np.array([5.0, 0.0, 0.0]), np.zeros(3), 0.0, H)
        lp = (wo.C_lp @ wo.x)[0]
        target = -math.asin(min(max(lp / p.g, -math.sin(p.tilt_max)), math.sin(p.tilt_max)))
        step = p.tilt_rate * H
        limited += abs(target - beta) > step
        beta += min(max(target - beta, -step), step)
        assert wo.tilt[1] == pytest.approx(beta, rel=1e-12, abs=1e-15)
    assert limited > 50                                          # the rate limit was active
    assert wo.tilt[1] == pytest.approx(-p.tilt_max, rel=1e-12)   # and the angle limit reached


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_plant_gets_the_force_demand_clipped_at_plus_minus_F_max(sign):
    """closed_loop's xdot is the forward dynamics under clip(F, -F_max, F_max), F the unclipped
    demand it reports; a 30 mm heave error up asks for about 1.7 kN, down for about -170 N."""
    from immersim.models.platform.control import closed_loop
    from immersim.models.platform.dynamics import forward_dynamics

    cp, pp = ControlParams(F_max=150.0), PlatformParams()
    x = np.zeros(12)
    x[2] = -sign * 0.03
    ref = np.zeros(18)
    xdot, F = (np.asarray(v).ravel() for v in closed_loop("computed_torque", "full")(x, ref, np.zeros(6), pp.vector(),
                                                                                        cp.vector()))
    assert (sign * F > cp.F_max).any()
    np.testing.assert_allclose(xdot[:6], x[6:], atol=0)
    np.testing.assert_allclose(xdot[6:], forward_dynamics(x[:6], x[6:], np.clip(F, -cp.F_max, cp.F_max), pp),
                               rtol=1e-9, atol=1e-9)


def test_step_inputs_are_zero_only_without_any_input():
    assert StepInputs().is_zero()
    assert not StepInputs(jolt=8.0).is_zero()
    assert not StepInputs(ref=np.array([0, 0, 0.01, 0, 0, 0])).is_zero()
