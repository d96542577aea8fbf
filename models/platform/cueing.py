"""Classical washout motion cueing: avatar specific force and angular rate -> platform pose reference.

Per axis (all filters linear, discretised exactly for inputs held over the macro step, ZOH):

* translation: ``p(s) = k_t s / ((s^2 + 2 zeta_t omega_t s + omega_t^2)(s + omega_b)) f(s)``, i.e. the
  specific force high-passed by a third-order filter and integrated twice, so a sustained
  acceleration washes out back to the centre;
* tilt coordination (x, y): ``f_lp = omega_tc^2 / (s + omega_tc)^2 f``; target tilt
  ``beta_t = -asin(f_lp,x / g)``, ``gamma_t = asin(f_lp,y / g)`` (gravity in the tilted seat supplies the
  sustained specific force; with ``A = A_x A_y A_z`` the body specific force of gravity is
  ``(-g sin beta, g sin gamma cos beta, ...)``), limited to ``tilt_max`` and rate-limited to ``tilt_rate``;
* rotation: ``angle(s) = k_r s / (s^2 + 2 zeta_r omega_r s + omega_r^2) w(s)`` (high-passed rate,
  integrated) on gamma (w_x), beta (w_y), alpha (w_z);
* collision jolt: ``jolt`` (m/s^2) is added to the surge specific force for the step, and
  ``jolt_heave`` times it to heave, through the translational channel only (no tilt).

Inputs are the avatar's specific force with the static 1 g removed (zero at rest, m/s^2) and its
angular rate (rad/s), both in the avatar's body frame. The pose reference is
``(x, y, z, gamma_hp + gamma_t, beta_hp + beta_t, alpha_hp)``; clamping into the workspace is the
caller's job (:func:`.kinematics.clamp_to_workspace`).
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

NW = 19          #: washout filter states
NWS = NW + 2     #: washout state with the rate-limited tilt (gamma_t, beta_t)
NWM = NW * NW + NW * 7 + 8 * NW + 3  #: packed washout matrices, see :func:`washout_matrices`


@dataclass(frozen=True)
class WashoutParams:
    """Washout filter parameters (rad/s, dimensionless gains, rad, rad/s)."""

    k_t: float = field(default=0.5, metadata={"unit": "1", "doc": "washout translational gain"})
    omega_t: float = field(default=2.5, metadata={"unit": "rad/s", "doc": "washout translational high-pass break frequency"})
    zeta_t: float = field(default=1.0, metadata={"unit": "1", "doc": "washout translational high-pass damping"})
    omega_b: float = field(default=0.5, metadata={"unit": "rad/s", "doc": "washout first-order high-pass (return to centre)"})
    k_r: float = field(default=0.5, metadata={"unit": "1", "doc": "washout rotational gain"})
    omega_r: float = field(default=1.0, metadata={"unit": "rad/s", "doc": "washout rotational high-pass break frequency"})
    zeta_r: float = field(default=1.0, metadata={"unit": "1", "doc": "washout rotational high-pass damping"})
    omega_tc: float = field(default=2.0, metadata={"unit": "rad/s", "doc": "tilt-coordination low-pass frequency"})
    tilt_max: float = field(default=float(np.deg2rad(10.0)), metadata={"unit": "rad", "doc": "tilt-coordination angle limit"})
    tilt_rate: float = field(default=float(np.deg2rad(3.0)), metadata={"unit": "rad/s", "doc": "tilt-coordination rate limit"})
    jolt_heave: float = field(default=0.3, metadata={"unit": "1", "doc": "share of the jolt that goes to heave"})
    g: float = field(default=9.81, metadata={"unit": "m/s2", "doc": "gravity used by tilt coordination"})

    def __post_init__(self) -> None:
        for name in ("omega_t", "zeta_t", "omega_b", "omega_r", "zeta_r", "omega_tc", "g"):
            if not getattr(self, name) > 0:
                raise ValueError(f"WashoutParams.{name} = {getattr(self, name)} must be > 0")


def _companion(den, num):
    """Controllable canonical (A, B, C) of num(s)/den(s), den monic of degree n (coefficients high->low)."""
    n = len(den) - 1
    A = np.zeros((n, n))
    A[:-1, 1:] = np.eye(n - 1)
    A[-1, :] = -np.asarray(den[::-1][:-1])
    B = np.zeros(n)
    B[-1] = 1.0
    C = np.zeros(n)
    num = np.asarray(num, float)[::-1]
    C[: len(num)] = num
    return A, B, C


def continuous_system(w: WashoutParams):
    """Block-diagonal continuous LTI system: state (19,), input (f_x, f_y, f_z, w_x, w_y, w_z, jolt).

    The jolt column drives the surge and (scaled by ``jolt_heave``) the heave translation blocks
    only, not the tilt low-pass. Returns (A (19,19), B (19,7), C_pos (3,19), C_ang (3,19), C_lp (2,19)).
    """
    a1, a0 = 2 * w.zeta_t * w.omega_t, w.omega_t**2
    # (s^2 + a1 s + a0)(s + omega_b), written out so that the C port of the FMU's native build
    # (fmus/platform/native/washout.c) performs the same floating-point operations
    tr_den = [1.0, a1 + w.omega_b, a0 + a1 * w.omega_b, a0 * w.omega_b]
    At, Bt, Ct = _companion(tr_den, [w.k_t, 0.0])
    Ar, Br, Cr = _companion([1, 2 * w.zeta_r * w.omega_r, w.omega_r**2], [w.k_r, 0.0])
    Al, Bl, Cl = _companion([1, 2 * w.omega_tc, w.omega_tc**2], [w.omega_tc**2])
    blocks = [(At, Bt, 0), (At, Bt, 1), (At, Bt, 2), (Ar, Br, 3), (Ar, Br, 4), (Ar, Br, 5), (Al, Bl, 0), (Al, Bl, 1)]
    n = sum(b[0].shape[0] for b in blocks)
    A, B = np.zeros((n, n)), np.zeros((n, 7))
    C_pos, C_ang, C_lp = np.zeros((3, n)), np.zeros((3, n)), np.zeros((2, n))
    i = 0
    for k, (Ab, Bb, inp) in enumerate(blocks):
        m = Ab.shape[0]
        A[i:i + m, i:i + m] = Ab
        B[i:i + m, inp] = Bb
        if k < 3:
            C_pos[k, i:i + m] = Ct
        elif k < 6:
            C_ang[k - 3, i:i + m] = Cr
        else:
            C_lp[k - 6, i:i + m] = Cl
        i += m
    nt = At.shape[0]
    B[0:nt, 6] = Bt                       # surge block
    B[2 * nt:3 * nt, 6] = w.jolt_heave * Bt  # heave block
    return A, B, C_pos, C_ang, C_lp


def _matmul(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``A @ B`` with each entry summed in order k = 0, 1, ... (a fixed operation order, unlike BLAS)."""
    out = A[:, :1] * B[:1, :]
    for k in range(1, A.shape[1]):
        out = out + A[:, k:k + 1] * B[k:k + 1, :]
    return out


def expm_small(M: np.ndarray) -> np.ndarray:
    """Matrix exponential of a small square matrix by scaling and squaring of its Taylor series.

    Numpy only (no scipy.linalg, whose OpenBLAS worker threads would spin for a while after
    every call on this shared machine); the scaled matrix has 1-norm <= 1/2 and 20 Taylor
    terms, so the truncation error is below 1e-25 relative before the squarings. Every sum
    runs in a fixed order (:func:`_matmul`, row by row for the norm) and the scaling is found by
    exact halvings, so the C port of the native FMU build (``fmus/platform/native/washout.c``)
    gives the same bits.
    """
    colsum = np.abs(M[0])
    for row in M[1:]:
        colsum = colsum + np.abs(row)
    norm, s = float(colsum.max()), 0
    while norm > 0.5:  # s = ceil(log2(norm / 0.5)), by exact halvings
        norm, s = norm / 2.0, s + 1
    X = M / 2.0 ** s
    E = np.eye(M.shape[0])
    term = np.eye(M.shape[0])
    for k in range(1, 21):
        term = _matmul(term, X) / k
        E = E + term
    for _ in range(s):
        E = _matmul(E, E)
    return E


@functools.lru_cache(maxsize=32)
def discrete_system(w: WashoutParams, h: float):
    """Exact ZOH discretisation (Phi, Gamma) for step h (s): ``exp([[A, B], [0, 0]] h)``, cached."""
    A, B, *_ = continuous_system(w)
    n, m = B.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n], M[:n, n:] = A, B
    E = expm_small(M * h)
    return E[:n, :n], E[:n, n:]


class Washout:
    """Stateful classical washout filter (one per platform instance)."""

    def __init__(self, params: WashoutParams = WashoutParams()) -> None:
        self.params = params
        _, _, self.C_pos, self.C_ang, self.C_lp = continuous_system(params)
        self._C = np.vstack([self.C_pos, self.C_ang, self.C_lp])
        self.x = np.zeros(self.C_pos.shape[1])
        self.tilt = np.zeros(2)  # (gamma_t, beta_t), rate-limited
        self._u = np.zeros(7)
        self._h = None

    def state(self):
        return (self.x.copy(), self.tilt.copy())

    def set_state(self, s) -> None:
        self.x, self.tilt = s[0].copy(), s[1].copy()

    def step(self, f: np.ndarray, omega: np.ndarray, jolt: float, h: float) -> np.ndarray:
        """Advance by h with inputs held; return the pose reference (6,) at the end of the step."""
        w = self.params
        if self._h != h:
            self._h, (self._Phi, self._Gam) = h, discrete_system(w, float(h))
        self._u[:3], self._u[3:6], self._u[6] = f, omega, jolt
        self.x = self._Phi @ self.x + self._Gam @ self._u
        y = self._C @ self.x  # (x, y, z, gamma_hp, beta_hp, alpha_hp, lp_x, lp_y)
        smax = math.sin(w.tilt_max)
        step = w.tilt_rate * h
        tilt = self.tilt
        for i, target in enumerate((math.asin(min(max(y[7] / w.g, -smax), smax)),      # gamma_t from f_y
                                    -math.asin(min(max(y[6] / w.g, -smax), smax)))):    # beta_t from f_x
            tilt[i] += min(max(target - tilt[i], -step), step)
        y[3] += tilt[0]
        y[4] += tilt[1]
        return y[:6]

    def at_rest(self, tol: float = 1e-12) -> bool:
        return bool(np.all(np.abs(self.x) < tol) and np.all(np.abs(self.tilt) < tol))


def washout_matrices(params: WashoutParams, h: float) -> np.ndarray:
    """Everything :func:`washout_sx` needs for a step h (s), packed into one vector (NWM,).

    Layout: ``Phi`` (19, 19), ``Gamma`` (19, 7), ``C`` (8, 19) (each column-major, as CasADi
    reshapes), then ``sin(tilt_max)``, ``tilt_rate h`` and ``g``.
    """
    Phi, Gam = discrete_system(params, float(h))
    _, _, C_pos, C_ang, C_lp = continuous_system(params)
    C = np.vstack([C_pos, C_ang, C_lp])
    return np.concatenate([Phi.ravel(order="F"), Gam.ravel(order="F"), C.ravel(order="F"),
                           [math.sin(params.tilt_max), params.tilt_rate * h, params.g]])


def washout_sx(w, cue, wm):
    """One washout step as a CasADi expression: the same arithmetic as :meth:`Washout.step`.

    Parameters
    ----------
    w : SX (NWS,)
        Filter state (19) and rate-limited tilt (gamma_t, beta_t) (2).
    cue : SX (7,)
        Specific force (3, m/s^2), angular rate (3, rad/s), jolt (m/s^2), held over the step.
    wm : SX (NWM,)
        :func:`washout_matrices` of the step.

    Returns
    -------
    (w_next (NWS,), ref (6,))
        State at the end of the step and the pose reference (x, y, z, gamma, beta, alpha).
    """
    i = 0
    mats = []
    for rows, cols in ((NW, NW), (NW, 7), (8, NW)):
        mats.append(ca.reshape(wm[i:i + rows * cols], rows, cols))
        i += rows * cols
    Phi, Gam, C = mats
    smax, step, g = wm[i], wm[i + 1], wm[i + 2]
    x = ca.mtimes(Phi, w[:NW]) + ca.mtimes(Gam, cue)
    y = ca.mtimes(C, x)  # (x, y, z, gamma_hp, beta_hp, alpha_hp, lp_x, lp_y)
    targets = (ca.asin(ca.fmin(ca.fmax(y[7] / g, -smax), smax)),     # gamma_t from f_y
               -ca.asin(ca.fmin(ca.fmax(y[6] / g, -smax), smax)))    # beta_t from f_x
    tilt = [w[NW + k] + ca.fmin(ca.fmax(targets[k] - w[NW + k], -step), step) for k in range(2)]
    ref = ca.vertcat(y[0], y[1], y[2], y[3] + tilt[0], y[4] + tilt[1], y[5])
    return ca.vertcat(x, *tilt), ref
