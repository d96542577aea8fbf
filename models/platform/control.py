"""Trajectory-tracking controllers of the platform (§6.4.2) and the closed-loop right-hand sides.

* ``computed_torque`` (feedback linearisation on the full Lagrangian model):
  ``F = J^-T (M(q) (q_r'' + K_d e' + K_p e) + h(q, q'))`` with ``e = q_r - q``; on the nominal
  model the error obeys ``e'' + K_d e' + K_p e = 0`` exactly (until a force saturates).
* ``pd`` (ablation baseline): task-space PD with constant gravity compensation and no model:
  ``F = J^-T (diag(M_0) (K_d e' + K_p e) + h_0)``, ``M_0``, ``h_0`` taken at the home pose at rest.
* ``direct``: the actuator forces are inputs.

Gains: ``K_p = omega_c^2``, ``K_d = 2 zeta_c omega_c`` on every axis. Forces are clipped to
``+-F_max`` (the plant sees the clipped force; the unclipped demand is reported so saturation can
be flagged). The closed-loop state is ``x = (q, q')`` (12); the reference enters as
``(q_r, q_r', q_r'')`` (18). With the reference prefilter (used by the FMU) the state grows by
``(r, r')`` (12): ``r'' = omega_f^2 (u - r) - 2 omega_f r'`` for a raw reference ``u``.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from .dynamics import NP, functions, lagrangian_sx
from .planar import planar_accel_sx

CONTROLS = ("computed_torque", "pd", "direct")
MODELS = ("full", "planar")


@dataclass(frozen=True)
class ControlParams:
    """Controller and prefilter parameters.

    Attributes
    ----------
    omega_c : float
        Closed-loop natural frequency, rad/s (K_p = omega_c^2).
    zeta_c : float
        Closed-loop damping ratio (K_d = 2 zeta_c omega_c).
    F_max : float
        Actuator force limit, N.
    omega_f : float
        Natural frequency of the critically damped reference prefilter, rad/s.
    """

    omega_c: float = field(default=20.0, metadata={"unit": "rad/s", "doc": "closed-loop natural frequency, K_p = omega_c^2"})
    zeta_c: float = field(default=1.0, metadata={"unit": "1", "doc": "closed-loop damping ratio, K_d = 2 zeta_c omega_c"})
    F_max: float = field(default=10000.0, metadata={"unit": "N", "doc": "actuator force limit"})
    omega_f: float = field(default=15.0, metadata={"unit": "rad/s", "doc": "reference prefilter natural frequency (critically damped)"})

    def vector(self) -> np.ndarray:
        return np.array([self.omega_c, self.zeta_c, self.F_max, self.omega_f], float)


NC = 4


def _control_forces(control: str, q, dq, ref, Fcmd, pv, cv, terms):
    if control == "direct":
        return Fcmd
    wc, zc = cv[0], cv[1]
    e, de = ref[:6] - q, ref[6:12] - dq
    v = wc * wc * e + 2 * zc * wc * de
    J = terms["J"]
    if control == "computed_torque":
        Q = terms["M"] @ (ref[12:18] + v) + terms["h"]
    elif control == "pd":
        M0, h0, _, _ = functions()["terms"](ca.DM.zeros(6), ca.DM.zeros(6), pv)
        Q = ca.diag(ca.diag(M0)) @ v + h0
    else:
        raise ValueError(f"control {control!r} not in {CONTROLS}")
    return ca.solve(J.T, Q)


@functools.lru_cache(maxsize=None)
def closed_loop(control: str = "computed_torque", model: str = "full") -> ca.Function:
    """``f(x[12], ref[18], Fcmd[6], p[NP], c[NC]) -> (xdot[12], F[6])`` (built once per process).

    ``F`` is the unclipped force demand; the plant gets ``clip(F, -F_max, F_max)``. The controller
    always uses the full model with the plant's parameters (nominal model).
    """
    if control not in CONTROLS:
        raise ValueError(f"control {control!r} not in {CONTROLS}")
    if model not in MODELS:
        raise ValueError(f"model {model!r} not in {MODELS}")
    x, ref, Fcmd = ca.SX.sym("x", 12), ca.SX.sym("ref", 18), ca.SX.sym("Fcmd", 6)
    pv, cv = ca.SX.sym("p", NP), ca.SX.sym("c", NC)
    q, dq = x[:6], x[6:]
    t = lagrangian_sx(q, dq, pv)
    F = _control_forces(control, q, dq, ref, Fcmd, pv, cv, t)
    Fs = ca.fmin(ca.fmax(F, -cv[2]), cv[2])
    if model == "full":
        ddq = ca.solve(t["M"], t["J"].T @ Fs - t["h"])
    else:
        ddq = planar_accel_sx(q, Fs, pv)
    xdot, F = ca.cse([ca.vertcat(dq, ddq), F])  # jointly: both outputs share one graph
    return ca.Function(f"cl_{control}_{model}", [x, ref, Fcmd, pv, cv], [xdot, F],
                       ["x", "ref", "Fcmd", "p", "c"], ["xdot", "F"])


@functools.lru_cache(maxsize=None)
def prefiltered_loop(control: str = "computed_torque", model: str = "full") -> ca.Function:
    """Closed loop with the reference prefilter: ``f(x[24], u[12], p[NP], c[NC]) -> (xdot[24], F[6])``.

    ``x = (q, q', r, r')``, ``u = (raw pose reference[6], Fcmd[6])``.
    """
    x, u = ca.SX.sym("x", 24), ca.SX.sym("u", 12)
    pv, cv = ca.SX.sym("p", NP), ca.SX.sym("c", NC)
    wf = cv[3]
    r, dr = x[12:18], x[18:24]
    ddr = wf * wf * (u[:6] - r) - 2 * wf * dr
    xdot_cl, F = closed_loop(control, model)(x[:12], ca.vertcat(r, dr, ddr), u[6:], pv, cv)
    return ca.Function(f"pf_{control}_{model}", [x, u, pv, cv], [ca.vertcat(xdot_cl, dr, ddr), F],
                       ["x", "u", "p", "c"], ["xdot", "F"])


@functools.lru_cache(maxsize=None)
def _library(fun: ca.Function):
    from .codegen import compile_library

    return compile_library(fun.name(), [fun])


@dataclass
class TrackingResult:
    """Closed-loop run against an analytic reference: t (N,), q (N, 6), dq (N, 6), ref (N, 6), F (N, 6)."""

    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    ref: np.ndarray
    F: np.ndarray

    def position_error(self) -> np.ndarray:
        """|C - C_ref| over time, m, shape (N,)."""
        return np.linalg.norm(self.q[:, :3] - self.ref[:, :3], axis=1)


def simulate_tracking(reference, t_end: float, q0=None, control: str = "computed_torque", model: str = "full",
                      params=None, cparams: ControlParams = ControlParams(), dt_out: float = 0.01,
                      rtol: float = 1e-10, atol: float = 1e-12) -> TrackingResult:
    """Track an analytic reference (§6.4.2) with the continuous controller; scipy DOP853.

    Parameters
    ----------
    reference : callable t -> (q_r (6,), q_r' (6,), q_r'' (6,))
    t_end : float
        Duration, s.
    q0 : array (6,), optional
        Initial pose (default: the reference at t = 0, at rest).
    """
    from scipy.integrate import solve_ivp

    from .codegen import FastFunction
    from .params import PlatformParams

    params = params or PlatformParams()
    fun = closed_loop(control, model)
    f = FastFunction(fun, _library(fun))
    pv, cv, zero = params.vector(), cparams.vector(), np.zeros(6)

    def ref18(t):
        return np.concatenate(reference(t))

    def rhs(t, x):
        return f(x, ref18(t), zero, pv, cv)[0]

    q0 = reference(0.0)[0] if q0 is None else np.asarray(q0, float)
    t_out = np.arange(0.0, t_end + 0.5 * dt_out, dt_out)
    sol = solve_ivp(rhs, (0.0, t_out[-1]), np.concatenate([q0, zero]), method="DOP853", t_eval=t_out,
                    rtol=rtol, atol=atol)
    if not sol.success:
        raise RuntimeError(f"tracking simulation failed: {sol.message}")
    X = sol.y.T
    refs = np.array([reference(t)[0] for t in sol.t])
    F = np.array([f(x, ref18(t), zero, pv, cv)[1] for t, x in zip(sol.t, X)])
    return TrackingResult(sol.t, X[:, :6], X[:, 6:], refs, F)


def sine_reference(a_y: float = 0.05, a_z: float = 0.0, omega: float = 1.0, z0: float = 0.0):
    """§6.4.2 references: Y = a_y sin(w t), Z = z0 + a_z cos(w t), gamma = 0 (a_z = 0: single axis)."""
    def ref(t):
        s, c = np.sin(omega * t), np.cos(omega * t)
        q = np.array([0, a_y * s, z0 + a_z * c, 0, 0, 0])
        dq = np.array([0, a_y * omega * c, -a_z * omega * s, 0, 0, 0])
        ddq = np.array([0, -a_y * omega**2 * s, -a_z * omega**2 * c, 0, 0, 0])
        return q, dq, ddq
    return ref
