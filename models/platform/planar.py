"""Simplified symmetric planar model of §6.4.1, eq. 6-72..6-74 (motion in the YZ plane).

Assumptions of the thesis: alpha = beta = 0, X_C = 0, hinge stiffness and friction neglected,
actuator 1 neglected, F_2 = F_3 and F_4 = F_5. The thesis writes one F_2 and one F_4 for each
symmetric pair; here the pair totals ``F_2 + F_3`` and ``F_4 + F_5`` enter (identical to the thesis
when it means the pair, and exactly what the full model gives under the stated symmetry):

    MY(gamma) = m - m cos(gamma) - h sin(gamma) - Y_C
    NY(gamma) = n - n cos(gamma) + h sin(gamma) + Y_C
    BZ(gamma) = Z_C - b sin(gamma)
    M Y''     = F23 + F45 (-MY)/sqrt(c^2-MY^2) + F6 NY/sqrt(c^2-NY^2)                      (6-72)
    M Z''     = -M g + F23 BZ/sqrt(c^2-BZ^2) + F45 + F6                                    (6-73)
    J_x g''   = F23 b [sin g - cos g BZ/sqrt(c^2-BZ^2)]
              + F45 [m cos g + h sin g + MY (m sin g - h cos g)/sqrt(c^2-MY^2)]
              + F6  [h sin g - n cos g + NY (n sin g + h cos g)/sqrt(c^2-NY^2)]             (6-74)

(the first, hinge-carrying listing of Q_gamma in the seed has ``- NY(...)`` in the F6 term; the
second listing and the IK both give ``+``.) The payload is not part of the planar model.
"""
from __future__ import annotations

import functools

import casadi as ca
import numpy as np

from .dynamics import NP, param_dict
from .params import PlatformParams


def planar_accel_sx(q, F, pv):
    """Generalized accelerations (6,) of the planar model: zero for X, beta, alpha."""
    P = param_dict(pv)
    Y, Z, g = q[1], q[2], q[3]
    b, c, h, m, n, M = P["b"], P["c"], P["h"], P["m"], P["n"], P["M"]
    Jx = M / 12.0 * (P["size_y"] ** 2 + P["size_z"] ** 2)
    MY = m - m * ca.cos(g) - h * ca.sin(g) - Y
    NY = n - n * ca.cos(g) + h * ca.sin(g) + Y
    BZ = Z - b * ca.sin(g)
    sM, sN, sB = ca.sqrt(c * c - MY * MY), ca.sqrt(c * c - NY * NY), ca.sqrt(c * c - BZ * BZ)
    F23, F45, F6 = F[1] + F[2], F[3] + F[4], F[5]
    QY = F23 + F45 * (-MY) / sM + F6 * NY / sN
    QZ = -M * P["g"] + F23 * BZ / sB + F45 + F6
    Qg = (F23 * b * (ca.sin(g) - ca.cos(g) * BZ / sB)
          + F45 * (m * ca.cos(g) + h * ca.sin(g) + MY * (m * ca.sin(g) - h * ca.cos(g)) / sM)
          + F6 * (h * ca.sin(g) - n * ca.cos(g) + NY * (n * ca.sin(g) + h * ca.cos(g)) / sN))
    return ca.vertcat(0, QY / M, QZ / M, Qg / Jx, 0, 0)


@functools.lru_cache(maxsize=None)
def planar_function() -> ca.Function:
    """``planar(q, F, p) -> ddq`` (built once per process)."""
    q, F, pv = ca.SX.sym("q", 6), ca.SX.sym("F", 6), ca.SX.sym("p", NP)
    return ca.Function("planar", [q, F, pv], [planar_accel_sx(q, F, pv)], ["q", "F", "p"], ["ddq"])


def planar_forward(q, F, p: PlatformParams = PlatformParams()) -> np.ndarray:
    """q'' (6,) of the planar model eq. 6-72..6-74 for pose q (6,) and forces F (6,), N."""
    return np.asarray(planar_function()(q, F, p.vector())).ravel()
