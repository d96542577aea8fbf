"""Lagrangian dynamics (CasADi) against independent derivations: thesis closed forms, planar model,
Newton-Euler, energy conservation."""
import casadi as ca
import numpy as np
import pytest
from tests.platform.platform_thesis_forms import corrected_Q_gamma_F456, thesis_QF

from immersim.models.platform.dynamics import NP, energy, forward_dynamics, functions, model_terms
from immersim.models.platform.integrators import IntegratorConfig, StepIntegrator
from immersim.models.platform.kinematics import (SingularityError, actuator_jacobian, body_rate_matrix, ik_full,
                                                 inverse_kinematics, rotation, world_rate_matrix)
from immersim.models.platform.params import PlatformParams
from immersim.models.platform.planar import planar_forward

FRICTIONLESS = PlatformParams(k_C=0.0, p_C=0.0, p_B=0.0)
RNG = np.random.default_rng(7)


def _random_state(n=20, scale=1.0):
    q = RNG.uniform(-1, 1, (n, 6)) * np.array([0.03, 0.03, 0.03, 0.12, 0.12, 0.12]) * scale
    dq = RNG.uniform(-1, 1, (n, 6)) * np.array([0.3, 0.3, 0.3, 1.0, 1.0, 1.0])
    F = RNG.uniform(-1, 1, (n, 6)) * 800 + np.array([0, 0, 0, 780, 780, 800])
    return q, dq, F


def test_generalized_forces_match_thesis_eq_6_56_to_6_61():
    """Q = J^T F (virtual work) against the F-terms of eq. 6-56..6-61 as printed; eq. 6-59's F4..F6
    terms only after the typo fix (and the printed version is shown to differ)."""
    for q in _random_state(10)[0]:
        JT = actuator_jacobian(q).T
        T = thesis_QF(q)
        mask = np.ones((6, 6), bool)
        mask[3, 3:] = False
        np.testing.assert_allclose(JT[mask], T[mask], atol=1e-12)
        np.testing.assert_allclose(JT[3, 3:], corrected_Q_gamma_F456(q), atol=1e-12)
        assert np.max(np.abs(JT[3, 3:] - T[3, 3:])) > 1e-3  # the printed eq. 6-59 is wrong there


def test_full_model_matches_cauchy_form_eq_6_63_to_6_71():
    p = FRICTIONLESS
    Jx, Jy, Jz = p.inertia
    for q, dq, F in zip(*_random_state(20)):
        Q = actuator_jacobian(q, p).T @ F            # forces of the actuators only, eq. 6-55
        g_, b_, a_ = q[3:]
        wx, wy, wz = body_rate_matrix(q[3:]) @ dq[3:]  # eq. 6-11
        Qg, Qb, Qa = Q[3:]
        dV = np.array([Q[0], Q[1], Q[2] - p.M * p.g]) / p.M                                       # 6-63..6-65
        dgamma = (wx * np.cos(a_) - wy * np.sin(a_)) / np.cos(b_)                                 # 6-66
        dbeta = wx * np.sin(a_) + wy * np.cos(a_)                                                 # 6-67
        dalpha = wz - (wx * np.cos(a_) - wy * np.sin(a_)) * np.tan(b_)                            # 6-68
        dwx = ((Jy - Jz) * wy * wz + Qb * np.sin(a_) + np.cos(a_) / np.cos(b_) * (Qg - Qa * np.sin(b_))) / Jx  # 6-69
        dwy = ((Jz - Jx) * wx * wz + Qb * np.cos(a_) - np.sin(a_) / np.cos(b_) * (Qg - Qa * np.sin(b_))) / Jy  # 6-70
        dwz = ((Jx - Jy) * wx * wy + Qa) / Jz                                                     # 6-71
        np.testing.assert_allclose([dgamma, dbeta, dalpha], dq[3:], atol=1e-12)
        # Euler accelerations from body-rate derivatives: w' = E_b eta'' + E_b' eta'
        eps = 1e-7
        dEb = (body_rate_matrix(q[3:] + eps * dq[3:]) - body_rate_matrix(q[3:] - eps * dq[3:])) / (2 * eps)
        deta = np.linalg.solve(body_rate_matrix(q[3:]), np.array([dwx, dwy, dwz]) - dEb @ dq[3:])
        ddq = forward_dynamics(q, dq, F, p)
        np.testing.assert_allclose(ddq[:3], dV, atol=1e-10)
        np.testing.assert_allclose(ddq[3:], deta, rtol=1e-6, atol=1e-6)  # finite-difference E_b'


def newton_euler(q, dq, F, p):
    """Rigid-body accelerations by Newton-Euler, written independently of the Lagrangian code.

    Platform (mass M, inertia diag(J) about C) plus a point payload m_p at A (0,0,z_p); rod j
    pushes B_j with F_j u_j / (u_j . e_j) (massless rod, slider in force balance).
    """
    A = rotation(q[3:])
    Ew = world_rate_matrix(q[3:])
    Om = Ew @ dq[3:]
    res = ik_full(q, p)
    u = res.rods[0]
    f = F[:, None] * u / np.einsum("ki,ki->k", u, p.axes)[:, None]
    r = res.joints[0] - q[:3]
    gvec = np.array([0, 0, -p.g])
    mp = p.payload_mass
    rp = A @ np.array([0, 0, p.payload_z])
    mtot = p.M + mp
    s = mp * rp
    Ic = A @ np.diag(p.inertia) @ A.T + mp * (rp @ rp * np.eye(3) - np.outer(rp, rp))
    force = f.sum(0) + mtot * gvec
    torque = np.cross(r, f).sum(0) + np.cross(rp, mp * gvec)

    def skew(v):
        return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])

    lhs = np.block([[mtot * np.eye(3), -skew(s)], [skew(s), Ic]])
    rhs = np.concatenate([force - np.cross(Om, np.cross(Om, s)), torque - np.cross(Om, Ic @ Om)])
    acc = np.linalg.solve(lhs, rhs)
    g_, b_ = q[3], q[4]
    dg, db = dq[3], dq[4]
    dEw = np.array([[0, 0, np.cos(b_) * db],
                    [0, -np.sin(g_) * dg, np.sin(b_) * np.sin(g_) * db - np.cos(b_) * np.cos(g_) * dg],
                    [0, np.cos(g_) * dg, -np.sin(b_) * np.cos(g_) * db - np.cos(b_) * np.sin(g_) * dg]])
    eta_dd = np.linalg.solve(Ew, acc[3:] - dEw @ dq[3:])
    return np.concatenate([acc[:3], eta_dd])


@pytest.mark.parametrize("payload", [0.0, 80.0])
def test_lagrangian_matches_newton_euler_1e_9(payload):
    p = FRICTIONLESS.replace(payload_mass=payload)
    for q, dq, F in zip(*_random_state(25)):
        np.testing.assert_allclose(forward_dynamics(q, dq, F, p), newton_euler(q, dq, F, p), atol=1e-9, rtol=0)


def test_mass_matrix_symmetric_positive_and_rigid_body_form():
    p = PlatformParams()
    q, dq, _ = _random_state(1)
    M, h, J, dl = model_terms(q[0], dq[0], p)
    np.testing.assert_allclose(M, M.T, atol=1e-12)
    assert np.all(np.linalg.eigvalsh(M) > 0)
    np.testing.assert_allclose(M[:3, :3], p.M * np.eye(3), atol=1e-12)
    Eb = body_rate_matrix(q[0, 3:])
    np.testing.assert_allclose(M[3:, 3:], Eb.T @ np.diag(p.inertia) @ Eb, atol=1e-12)
    np.testing.assert_allclose(dl, inverse_kinematics(q[0]), atol=1e-14)
    np.testing.assert_allclose(J, actuator_jacobian(q[0]), atol=1e-12)


def test_planar_model_matches_full_model_on_yz_motions():
    p = FRICTIONLESS
    for _ in range(20):
        q = np.zeros(6)
        q[1:4] = RNG.uniform(-1, 1, 3) * [0.04, 0.04, 0.15]
        dq = np.zeros(6)
        dq[1:4] = RNG.uniform(-1, 1, 3) * [0.3, 0.3, 1.0]
        F = np.zeros(6)
        F[1] = F[2] = RNG.uniform(-300, 300)
        F[3] = F[4] = RNG.uniform(400, 1200)
        F[5] = RNG.uniform(400, 1200)
        full = forward_dynamics(q, dq, F, p)
        np.testing.assert_allclose(full, planar_forward(q, F, p), atol=1e-10)
        np.testing.assert_allclose(full[[0, 4, 5]], 0.0, atol=1e-12)  # the motion stays in the YZ plane


def test_singular_euler_angles_raise_instead_of_nan():
    q = np.array([0, 0, 0, 0, np.pi / 2, 0])
    with pytest.raises(SingularityError, match="beta"):
        forward_dynamics(q, np.zeros(6), np.zeros(6))


def _spring_system():
    """Frictionless platform on six actuator springs F = F0 - k dl (conservative)."""
    x, F0 = ca.SX.sym("x", 12), ca.SX.sym("F0", 6)
    pv, cv = ca.SX.sym("p", NP), ca.SX.sym("k", 1)
    q, dq = x[:6], x[6:]
    dl = functions()["terms"](q, dq, pv)[3]
    F = F0 - cv[0] * dl
    ddq = functions()["forward"](q, dq, F, pv)
    return ca.Function("platform_spring_test", [x, F0, pv, cv], [ca.vertcat(dq, ddq), F])


def test_energy_conserved_60s_without_friction():
    p = PlatformParams(p_C=0.0, p_B=0.0, k_C=20.0, payload_mass=60.0)   # hinge springs on, no damping
    k = 3.0e4
    F0 = np.array([0, 0, 0, 1.0, 1.0, 1.0]) * (p.M + p.payload_mass) * p.g / 3
    rhs = _spring_system()
    x = np.concatenate([[0.01, -0.02, 0.015, 0.05, -0.04, 0.06], [0.05, 0.0, -0.05, 0.1, 0.2, -0.1]])

    def total(x):
        dl = inverse_kinematics(x[:6], p)
        return energy(x[:6], x[6:], p) + np.sum(0.5 * k * dl**2 - F0 * dl)

    E0 = total(x)
    integ = StepIntegrator(rhs, IntegratorConfig("cvode_adams", rtol=1e-11, atol=1e-13))
    worst = 0.0
    for _ in range(int(60 / 0.033)):
        x = integ.step(x, F0, p.vector(), [k], 0.033)
        worst = max(worst, abs(total(x) - E0))
    assert np.all(np.abs(x[:3]) < 0.1)
    # E0 is about 333 J; CVODE at rtol 1e-11 holds it to ~3e-9 relative over 60 s (1818 restarts)
    assert worst < 1e-8 * abs(E0), (worst, E0)
