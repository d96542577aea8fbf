"""Small geometric kernels shared by the collision backends (numpy, vectorised).

Poses are 6-vectors ``(x, y, z, roll, pitch, yaw)`` in metres and radians. The rotation is
``R = Rz(yaw) Ry(pitch) Rx(roll)``, the column-vector form of the thesis's eq. 4-4 / 5-4
(``M_R = T_Rz T_Ry T_Rx``); a body point ``p`` maps to ``R p + t`` (eq. 4-6 / 5-6 with the
translation applied in the world frame).
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["norm3", "rotation", "pose_rows", "pose_matrix", "transform_points", "point_triangle_distance",
           "rotation_angle", "Slerp", "slerp_pose"]


_EYE3 = np.eye(3)
_EYE3.flags.writeable = False


def norm3(v: np.ndarray) -> float:
    """Euclidean norm of a vector, shape (3,): the number ``np.linalg.norm(v)`` returns (numpy
    computes ``sqrt(v . v)`` for a real vector), without its Python-level overhead."""
    return math.sqrt(v.dot(v))


def rotation(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Rotation matrix ``Rz(yaw) Ry(pitch) Rx(roll)`` (eq. 4-3/4-4), shape (3, 3)."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])


def pose_rows(pose) -> list:
    """The 4x4 transform of a pose ``(x, y, z, roll, pitch, yaw)`` (eq. 4-6) as nested lists
    of floats (what :func:`pose_matrix` wraps in an array; scalar code for the per-step path)."""
    x, y, z, roll, pitch, yaw = map(float, pose)
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return [
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr, x],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr, y],
        [-sp, cp * sr, cp * cr, z],
        [0.0, 0.0, 0.0, 1.0],
    ]


def pose_matrix(pose) -> np.ndarray:
    """Homogeneous 4x4 transform of a pose ``(x, y, z, roll, pitch, yaw)`` (eq. 4-6)."""
    return np.array(pose_rows(pose))


def transform_points(T: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Apply a 4x4 transform to points of shape (n, 3)."""
    return pts @ T[:3, :3].T + T[:3, 3]


def rotation_angle(R: np.ndarray) -> float:
    """Angle (rad) of the rotation ``R`` (axis-angle magnitude)."""
    r = R.tolist()  # scalar code: this runs per pair and step (numpy's call overhead dominates)
    c = ((r[0][0] + r[1][1]) + r[2][2] - 1.0) / 2.0
    return math.acos(min(1.0, max(-1.0, c)))


class Slerp:
    """The interpolation of two 4x4 rigid transforms: linear translation, constant-rate
    rotation about the relative axis (the motion used for time of impact). What does not
    depend on the fraction (relative rotation, its angle and axis) is computed once.

    Parameters
    ----------
    T0, T1 : ndarray, shape (4, 4)
        The transforms at fractions 0 and 1.
    """

    def __init__(self, T0: np.ndarray, T1: np.ndarray) -> None:
        self.R0, self.t0, self.t1 = T0[:3, :3], T0[:3, 3], T1[:3, 3]
        self._t01 = list(zip(self.t0.tolist(), self.t1.tolist()))  # for at(), scalar code
        R_rel = T1[:3, :3] @ T0[:3, :3].T
        self.ang = rotation_angle(R_rel)
        self.K = None
        #: unit axis of the relative rotation (world frame; the rotation turns about it through
        #: the body origin), None when the rotation is below 1e-12 rad (kept at R0 then)
        self.axis = None
        if self.ang < 1e-12:
            return
        w = np.array([R_rel[2, 1] - R_rel[1, 2], R_rel[0, 2] - R_rel[2, 0], R_rel[1, 0] - R_rel[0, 1]])
        nw = norm3(w)
        if nw < 1e-12:  # rotation by pi: axis from the symmetric part
            vals, vecs = np.linalg.eigh((R_rel + np.eye(3)) / 2)
            axis = vecs[:, np.argmax(vals)]
        else:
            axis = w / nw
        self.axis = axis
        self.K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])

    def at(self, s: float) -> np.ndarray:
        """The transform at fraction ``s`` in [0, 1], shape (4, 4)."""
        T = np.eye(4)
        r = 1 - s  # (1 - s) t0 + s t1 per coordinate: the numbers of the array expression
        T[:3, 3] = [r * t0 + s * t1 for t0, t1 in self._t01]
        if self.K is None:
            T[:3, :3] = self.R0
            return T
        K = self.K
        a = s * self.ang
        R_s = _EYE3 + np.sin(a) * K + (1 - np.cos(a)) * K @ K
        T[:3, :3] = R_s @ self.R0
        return T


def slerp_pose(T0: np.ndarray, T1: np.ndarray, s: float) -> np.ndarray:
    """Interpolate two 4x4 rigid transforms at fraction ``s`` in [0, 1] (:class:`Slerp`)."""
    return Slerp(T0, T1).at(s)


def point_triangle_distance(p: np.ndarray, tri: np.ndarray):
    """Exact distance from points to triangles (Ericson's closest-point regions).

    Parameters
    ----------
    p : ndarray, shape (n, 3)
    tri : ndarray, shape (n, 3, 3)
        Triangle vertices, broadcast against ``p``.

    Returns
    -------
    dist : ndarray, shape (n,)
    closest : ndarray, shape (n, 3)
    """
    p = np.asarray(p, float)
    a, b, c = tri[..., 0, :], tri[..., 1, :], tri[..., 2, :]
    ab, ac, ap = b - a, c - a, p - a
    d1 = np.einsum("...i,...i", ab, ap)
    d2 = np.einsum("...i,...i", ac, ap)
    bp = p - b
    d3 = np.einsum("...i,...i", ab, bp)
    d4 = np.einsum("...i,...i", ac, bp)
    cp = p - c
    d5 = np.einsum("...i,...i", ab, cp)
    d6 = np.einsum("...i,...i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v = np.where(denom != 0, vb / denom, 0.0)
        w = np.where(denom != 0, vc / denom, 0.0)
        out = a + ab * v[..., None] + ac * w[..., None]  # interior
        # edge regions
        t_ab = np.clip(np.where(d1 - d3 != 0, d1 / (d1 - d3), 0.0), 0, 1)
        t_ac = np.clip(np.where(d2 - d6 != 0, d2 / (d2 - d6), 0.0), 0, 1)
        t_bc = np.clip(np.where((d4 - d3) + (d5 - d6) != 0, (d4 - d3) / ((d4 - d3) + (d5 - d6)), 0.0), 0, 1)
    on_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
    on_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
    on_bc = (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0)
    out = np.where(on_bc[..., None], b + (c - b) * t_bc[..., None], out)
    out = np.where(on_ac[..., None], a + ac * t_ac[..., None], out)
    out = np.where(on_ab[..., None], a + ab * t_ab[..., None], out)
    in_c = (d6 >= 0) & (d5 <= d6)
    in_b = (d3 >= 0) & (d4 <= d3)
    in_a = (d1 <= 0) & (d2 <= 0)
    out = np.where(in_c[..., None], c, out)
    out = np.where(in_b[..., None], b, out)
    out = np.where(in_a[..., None], a, out)
    return np.linalg.norm(p - out, axis=-1), out
