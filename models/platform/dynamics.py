"""Lagrangian dynamics of the platform, derived symbolically with CasADi (eq. 6-47..6-55).

Generalized coordinates ``q = (X_C, Y_C, Z_C, gamma, beta, alpha)`` (eq. 6-48). Assumptions of
§6.3.3: rods and actuators massless, the platform a rigid body of mass M with principal axes Cx,
Cy, Cz. We add an optional point payload (seated person) of mass ``payload_mass`` at
``(0, 0, payload_z)`` in the platform frame.

* kinetic energy, eq. 6-49, with body rates from Euler rates eq. 6-11 (``omega = E_b q'``), plus the
  payload's ``m_p |R_C' + Omega x A r_p|^2 / 2``;
* potential ``(M + m_p) g Z_C + m_p g (A r_p)_Z + k_C/2 sum(theta_j^2 + phi_j^2)``: gravity and the
  hinge stiffness at the universal joints C_j (eq. 6-54: the generalized force
  ``-(k_C theta + p_C theta') d theta'/d q'`` is ``-dV/dq`` of this potential);
* Rayleigh dissipation ``p_C/2 sum(theta_j'^2 + phi_j'^2) + p_B/2 sum |Omega - omega_j|^2`` (eq.
  6-54/6-55: damping at C_j and at the ball joints B_j on the relative angular velocity);
* actuator forces by virtual work, ``Q = J^T F`` with ``J = d(dl)/dq`` from the IK eq. 6-14..6-19.

Rod angles (fig. 6-4..6-6): rod 1 turns by phi about Z then theta about (-sin phi, cos phi, 0)
(``omega_1 = (-theta' sin phi, theta' cos phi, phi')``); rods 2, 3 by phi about Z then theta about
(cos phi, sin phi, 0); rods 4..6 by phi about X then theta about (0, cos phi, sin phi); all are
zero at the home pose. These are the angular velocities the thesis uses after eq. 6-55.

Lagrange's equations give ``M(q) q'' + h(q, q') = J(q)^T F`` with
``h = (d/dq (dT/dq')) q' - dT/dq + dV/dq + dD/dq'``; forward dynamics ``q'' = M^-1 (J^T F - h)``.
All functions are built once per process (``functools.lru_cache``) and take the parameter
vector :meth:`PlatformParams.vector`.
"""
from __future__ import annotations

import functools
from typing import Dict

import casadi as ca
import numpy as np

from .kinematics import SingularityError
from .params import PlatformParams

NQ = 6
PARAM_NAMES = PlatformParams.names()
NP = len(PARAM_NAMES)


def param_dict(pv: ca.SX) -> Dict[str, ca.SX]:
    """Name -> entry of a symbolic parameter vector (order of :class:`PlatformParams`)."""
    return {name: pv[i] for i, name in enumerate(PARAM_NAMES)}


def rotation_sx(ang):
    """A = A_x(gamma) A_y(beta) A_z(alpha), eq. 6-8/6-9, as a CasADi expression."""
    g, b, a = ang[0], ang[1], ang[2]
    Ax = ca.vertcat(ca.horzcat(1, 0, 0), ca.horzcat(0, ca.cos(g), -ca.sin(g)), ca.horzcat(0, ca.sin(g), ca.cos(g)))
    Ay = ca.vertcat(ca.horzcat(ca.cos(b), 0, ca.sin(b)), ca.horzcat(0, 1, 0), ca.horzcat(-ca.sin(b), 0, ca.cos(b)))
    Az = ca.vertcat(ca.horzcat(ca.cos(a), -ca.sin(a), 0), ca.horzcat(ca.sin(a), ca.cos(a), 0), ca.horzcat(0, 0, 1))
    return Ax @ Ay @ Az


def body_rates_sx(ang, dang):
    """Body angular velocity (omega_x, omega_y, omega_z) from Euler rates, eq. 6-11."""
    g, b, a = ang[0], ang[1], ang[2]
    dg, db, da = dang[0], dang[1], dang[2]
    return ca.vertcat(db * ca.sin(a) + dg * ca.cos(b) * ca.cos(a),
                      db * ca.cos(a) - dg * ca.cos(b) * ca.sin(a),
                      da + dg * ca.sin(b))


def world_rates_sx(ang, dang):
    """Angular velocity Omega in OXYZ from Euler rates (thesis, after eq. 6-55)."""
    g, b = ang[0], ang[1]
    dg, db, da = dang[0], dang[1], dang[2]
    return ca.vertcat(dg + da * ca.sin(b),
                      db * ca.cos(g) - da * ca.cos(b) * ca.sin(g),
                      db * ca.sin(g) + da * ca.cos(b) * ca.cos(g))


def kinematics_sx(q, P):
    """Strokes dl (6,), rod vectors B_j - C_j (list of 3-vectors) and rod angles (theta, phi)."""
    geo = PlatformParams()
    A = rotation_sx(q[3:])
    a, b, e, d, h, m, n, c = (P[k] for k in "abedhmnc")
    joints = [ca.vertcat(-a, 0, 0), ca.vertcat(-e, -b, 0), ca.vertcat(e, -b, 0),
              ca.vertcat(d, m, -h), ca.vertcat(-d, m, -h), ca.vertcat(0, -n, -h)]
    axes = [np.asarray(ax) for ax in geo.axes]
    dl, rods, thetas, phis = [], [], [], []
    for j, (r, ax) in enumerate(zip(joints, axes)):
        B = q[:3] + A @ r
        w = B - (r - c * ax)                      # B_j - C_j^0 (eq. 6-6)
        we = ca.dot(w, ax)
        s = ca.sqrt(c * c - (ca.dot(w, w) - we * we))
        dl_j = we - s                             # eq. 6-14..6-19
        u = (w - dl_j * ax) / c                   # unit rod vector (C_j -> B_j)
        if j == 0:
            phi, theta = ca.atan2(u[1], u[0]), ca.atan2(-u[2], ca.sqrt(u[0] ** 2 + u[1] ** 2))
        elif j < 3:
            phi, theta = ca.atan2(-u[0], u[1]), ca.atan2(u[2], ca.sqrt(u[0] ** 2 + u[1] ** 2))
        else:
            phi, theta = ca.atan2(-u[1], u[2]), ca.atan2(u[0], ca.sqrt(u[1] ** 2 + u[2] ** 2))
        dl.append(dl_j)
        rods.append(c * u)
        thetas.append(theta)
        phis.append(phi)
    return ca.vertcat(*dl), rods, ca.vertcat(*thetas), ca.vertcat(*phis)


def rod_angular_velocities_sx(theta, phi, dtheta, dphi):
    """omega_j of each rod in OXYZ from its universal-joint angles (thesis, after eq. 6-55)."""
    out = []
    for j in range(6):
        t_, p_ = dtheta[j], dphi[j]
        if j == 0:
            out.append(ca.vertcat(-t_ * ca.sin(phi[j]), t_ * ca.cos(phi[j]), p_))
        elif j < 3:
            out.append(ca.vertcat(t_ * ca.cos(phi[j]), t_ * ca.sin(phi[j]), p_))
        else:
            out.append(ca.vertcat(p_, t_ * ca.cos(phi[j]), t_ * ca.sin(phi[j])))
    return out


def lagrangian_sx(q, dq, pv) -> Dict[str, ca.SX]:
    """Symbolic terms of the Lagrangian model for symbols ``q, dq`` (6,) and parameters ``pv``.

    Returns a dict with ``M`` (6x6 mass matrix), ``h`` (bias: Coriolis/centrifugal, gravity,
    hinge stiffness and damping), ``J`` (6x6 d(dl)/dq), ``dl`` (strokes), ``T``, ``V`` (energies),
    ``D`` (Rayleigh function), ``theta``, ``phi``.
    """
    P = param_dict(pv)
    ang, dang = q[3:], dq[3:]
    A = rotation_sx(ang)
    omega = body_rates_sx(ang, dang)
    Omega = world_rates_sx(ang, dang)
    Jb = P["M"] / 12.0 * ca.vertcat(P["size_y"] ** 2 + P["size_z"] ** 2, P["size_x"] ** 2 + P["size_z"] ** 2,
                                    P["size_x"] ** 2 + P["size_y"] ** 2)
    r_p = A @ ca.vertcat(0, 0, P["payload_z"])
    v_p = dq[:3] + ca.cross(Omega, r_p)
    T = 0.5 * P["M"] * ca.dot(dq[:3], dq[:3]) + 0.5 * ca.dot(Jb, omega ** 2) \
        + 0.5 * P["payload_mass"] * ca.dot(v_p, v_p)                                   # eq. 6-49
    dl, rods, theta, phi = kinematics_sx(q, P)
    V = P["g"] * (P["M"] * q[2] + P["payload_mass"] * (q[2] + r_p[2])) \
        + 0.5 * P["k_C"] * (ca.sumsqr(theta) + ca.sumsqr(phi))
    J = ca.jacobian(dl, q)
    dtheta = ca.jtimes(theta, q, dq)
    dphi = ca.jtimes(phi, q, dq)
    rel = [Omega - w for w in rod_angular_velocities_sx(theta, phi, dtheta, dphi)]
    D = 0.5 * P["p_C"] * (ca.sumsqr(dtheta) + ca.sumsqr(dphi)) + 0.5 * P["p_B"] * sum(ca.sumsqr(r) for r in rel)
    dT_ddq = ca.gradient(T, dq)
    M = ca.jacobian(dT_ddq, dq)
    h = ca.jacobian(dT_ddq, q) @ dq - ca.gradient(T, q) + ca.gradient(V, q) + ca.gradient(D, dq)
    return {"M": M, "h": h, "J": J, "dl": dl, "T": T, "V": V, "D": D, "theta": theta, "phi": phi}


@functools.lru_cache(maxsize=None)
def functions() -> Dict[str, ca.Function]:
    """CasADi Functions of the full model (built once per process).

    ``ik(q, p) -> (dl, reach)`` (strokes, eq. 6-14..6-19, and (rod . slider axis) / c; NaN out of reach),
    ``terms(q, dq, p) -> (M, h, J, dl)``, ``forward(q, dq, F, p) -> ddq``,
    ``energy(q, dq, p) -> (T, V)``, ``rod_angles(q, p) -> (theta, phi)``.
    """
    q, dq, F = ca.SX.sym("q", NQ), ca.SX.sym("dq", NQ), ca.SX.sym("F", 6)
    pv = ca.SX.sym("p", NP)
    t = lagrangian_sx(q, dq, pv)
    ddq = ca.solve(t["M"], t["J"].T @ F - t["h"])
    P = param_dict(pv)
    dl, rods, _, _ = kinematics_sx(q, P)
    reach = ca.vertcat(*[ca.dot(r, ax) for r, ax in zip(rods, PlatformParams().axes)]) / P["c"]
    return {
        "ik": ca.Function("platform_ik", [q, pv], [dl, reach], ["q", "p"], ["dl", "reach"]),
        "terms": ca.Function("terms", [q, dq, pv], [t["M"], t["h"], t["J"], t["dl"]],
                             ["q", "dq", "p"], ["M", "h", "J", "dl"]),
        "forward": ca.Function("forward", [q, dq, F, pv], [ddq], ["q", "dq", "F", "p"], ["ddq"]),
        "energy": ca.Function("energy", [q, dq, pv], [t["T"], t["V"]], ["q", "dq", "p"], ["T", "V"]),
        "rod_angles": ca.Function("rod_angles", [q, pv], [t["theta"], t["phi"]], ["q", "p"], ["theta", "phi"]),
    }


def _check_pose(q) -> None:
    if abs(np.cos(q[4])) < 1e-6:
        raise SingularityError(f"beta = {q[4]:.6g} rad: the Euler-angle mass matrix is singular at beta = +-90 deg")


def forward_dynamics(q, dq, F, p: PlatformParams = PlatformParams()) -> np.ndarray:
    """q'' of the full model for pose q, rates dq and actuator forces F (N), all (6,)."""
    q = np.asarray(q, float)
    _check_pose(q)
    return np.asarray(functions()["forward"](q, dq, F, p.vector())).ravel()


def model_terms(q, dq, p: PlatformParams = PlatformParams()):
    """(M (6,6), h (6,), J (6,6), dl (6,)) of the full model as numpy arrays."""
    q = np.asarray(q, float)
    _check_pose(q)
    M, h, J, dl = functions()["terms"](q, dq, p.vector())
    return np.asarray(M), np.asarray(h).ravel(), np.asarray(J), np.asarray(dl).ravel()


def energy(q, dq, p: PlatformParams = PlatformParams()) -> float:
    """Total mechanical energy T + V (gravity and hinge stiffness), J."""
    T, V = functions()["energy"](q, dq, p.vector())
    return float(T) + float(V)
