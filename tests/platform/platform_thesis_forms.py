"""Closed forms of the seed transcribed as printed (used by the cross-check tests).

``thesis_QF(q)``: the actuator-force coefficients of the generalized forces eq. 6-56..6-61
(row i: Q_i, column j: F_j), hinge terms left out. ``corrected_Q_gamma_F456`` is eq. 6-59's
F4..F6 part with the two typos fixed (see fmus/platform/README.md).
"""
import numpy as np
from immersim.models.platform.kinematics import rotation, ik_full
from immersim.models.platform.params import PlatformParams
P = PlatformParams()

def thesis_QF(q, P=P):
    """F-coefficients (6 gen. forces x 6 actuators) of eq. 6-56..6-61 as printed."""
    X, Y, Z, g, be, al = q
    a, b, c, d, e, h, m, n = P.a, P.b, P.c, P.d, P.e, P.h, P.m, P.n
    A = rotation(q[3:])
    a11, a12, a13, a21, a22, a23, a31, a32, a33 = A.ravel()
    res = ik_full(q, P)
    R = -res.rods[0]  # C - B
    dX, dY, dZ = R[:, 0], R[:, 1], R[:, 2]
    Q = np.zeros((6, 6))
    # 6-56
    Q[0] = [1, dX[1] / dY[1], dX[2] / dY[2], dX[3] / dZ[3], dX[4] / dZ[4], dX[5] / dZ[5]]
    # 6-57
    Q[1] = [dY[0] / dX[0], 1, 1, dY[3] / dZ[3], dY[4] / dZ[4], dY[5] / dZ[5]]
    # 6-58
    Q[2] = [dZ[0] / dX[0], dZ[1] / dY[1], dZ[2] / dY[2], 1, 1, 1]
    # 6-59 (F terms)
    Q[3, 0] = a / dX[0] * (Y * (a13 * a22 - a12 * a23) + Z * (a13 * a32 - a12 * a33))
    Q[3, 1] = -b * (a11 * a23 - a13 * a21) + e * (a12 * a23 - a13 * a22) + 1 / dY[1] * (
        (e * a21 + b * a22) * (b * (a11 * a23 - a13 * a21) - e * (a12 * a23 - a13 * a22))
        + Z * (b * (a11 * a33 - a13 * a31) - e * (a12 * a33 - a13 * a32)))
    Q[3, 2] = -b * (a11 * a23 - a13 * a21) - e * (a12 * a23 - a13 * a22) + 1 / dY[2] * (
        (-e * a21 + b * a22) * (b * (a11 * a23 - a13 * a21) + e * (a12 * a23 - a13 * a22))
        + Z * (b * (a11 * a33 - a13 * a31) + e * (a12 * a33 - a13 * a32)))
    Q[3, 3] = h * (a11 * a32 - a12 * a31) + m * (a11 * a33 - a13 * a31) + d * (a11 * a33 - a13 * a31)
    Q[3, 4] = h * (a11 * a32 - a12 * a31) + m * (a11 * a33 - a13 * a31) - d * (a11 * a33 - a13 * a31)
    Q[3, 5] = h * (a11 * a32 - a12 * a31) - n * (a11 * a33 - a13 * a31)
    # 6-60 (F terms)
    sg, cg, sb, cb, sa, ca_ = np.sin(g), np.cos(g), np.sin(be), np.cos(be), np.sin(al), np.cos(al)
    Q[4, 0] = a * ca_ * (a13 - (a * a11 * a13 + Y * a23 + Z * a33) / dX[0])
    Q[4, 1] = -(b * sa - e * ca_) * (a23 - ((e + X) * a13 + (e * a21 + b * a22) * a23 + Z * a33) / dY[1])
    Q[4, 2] = -(b * sa + e * ca_) * (a23 - ((-e + X) * a13 + (-e * a21 + b * a22) * a23 + Z * a33) / dY[2])
    k4 = -d * a31 - m * a32 + h * a33
    k5 = d * a31 - m * a32 + h * a33
    k6 = n * a32 + h * a33
    Q[4, 3] = h * cg * sb + a33 * (sa * m - d * ca_) - 1 / dZ[3] * (
        h * (cb * (d - X) + sb * ((m - Y) * sg + k4 * cg)) - (m * sa - d * ca_) * ((d - X) * a13 + (m - Y) * a23 - k4 * a33))
    Q[4, 4] = h * cg * sb + a33 * (sa * m + d * ca_) - 1 / dZ[4] * (
        h * (cb * (-d - X) + sb * ((m - Y) * sg + k5 * cg)) - (m * sa + d * ca_) * ((-d - X) * a13 + (m - Y) * a23 - k5 * a33))
    Q[4, 5] = h * cg * sb - a33 * sa * n - 1 / dZ[5] * (
        h * (-X * cb + sb * ((-n - Y) * sg + k6 * cg)) + n * sa * (-X * a13 + (-n - Y) * a23 - k6 * a33))
    # 6-61 (F terms)
    Q[5, 0] = a * (-a12 + (a * a11 * a12 + Y * a22 + Z * a32) / dX[0])
    Q[5, 1] = (b * a21 - e * a22) - ((e + X) * (b * a11 - e * a12) + (b * a21 - e * a22) * (e * a21 + b * a22) + Z * (b * a31 - e * a32)) / dY[1]
    Q[5, 2] = (b * a21 + e * a22) - ((-e + X) * (b * a11 + e * a12) + (b * a21 + e * a22) * (-e * a21 + b * a22) + Z * (b * a31 + e * a32)) / dY[2]
    Q[5, 3] = -(m * a31 - d * a32) - 1 / dZ[3] * ((m * a21 - d * a22) * (m - Y) + (m * a11 - d * a12) * (d - X) - (m * a31 - d * a32) * k4)
    Q[5, 4] = -(m * a31 + d * a32) - 1 / dZ[4] * ((m * a21 + d * a22) * (m - Y) + (m * a11 + d * a12) * (-d - X) - (m * a31 + d * a32) * k5)
    Q[5, 5] = n * a31 + 1 / dZ[5] * (n * a21 * (-n - Y) - n * a11 * X - n * a31 * k6)
    return Q


def corrected_Q_gamma_F456(q, P=P):
    """Eq. 6-59, F4..F6 coefficients with the d-cofactor fixed (a21 = a13 a32 - a12 a33, not
    a11 a33 - a13 a31) and the rod-inclination terms (Y_B - Y_C) dZ_B/dgamma / (Z_B - Z_C) restored."""
    X, Y, Z = q[:3]
    d, m, h, n = P.d, P.m, P.h, P.n
    A = rotation(q[3:])
    a11, a12, a13, a21, a22, a23, a31, a32, a33 = A.ravel()
    R = -ik_full(q, P).rods[0]
    dY, dZ = R[:, 1], R[:, 2]
    c4 = h * (a11 * a32 - a12 * a31) + m * (a11 * a33 - a13 * a31) + d * (a13 * a32 - a12 * a33) \
        + dY[3] / dZ[3] * (-d * a31 - m * a32 + h * a33)
    c5 = h * (a11 * a32 - a12 * a31) + m * (a11 * a33 - a13 * a31) - d * (a13 * a32 - a12 * a33) \
        + dY[4] / dZ[4] * (d * a31 - m * a32 + h * a33)
    c6 = h * (a11 * a32 - a12 * a31) - n * (a11 * a33 - a13 * a31) + dY[5] / dZ[5] * (n * a32 + h * a33)
    return np.array([c4, c5, c6])
