"""Time of impact of the fcl backend: fast movers and conservative advancement.

A body is a fast mover when its travel in the step (translation + rotation angle x radius)
exceeds ``ccd_fast`` x its thinnest extent; only those can tunnel. For a fast mover the
swept AABB of the step is queried against the members, and each candidate gets conservative
advancement (Mirtich 1996): ``s += d(s) / mu`` on ``fcl.distance``, ``mu`` a bound on the
relative speed of any surface point (:meth:`TimeOfImpact.speed`), until ``d <= TOI_TOL``
(contact at fraction ``s``) or ``s > 1``. (fcl's ``continuousCollide`` rejects mesh-mesh
requests in python-fcl 0.7.) A body of at most ``CHUNK_OTHER_MAX_FACES`` triangles against a
static chunked mesh advances on the chunks (:func:`.chunks.chunked_distance`).
"""
from __future__ import annotations

import math
from typing import List, Optional

import fcl
import numpy as np

from .chunks import chunked_distance
from .fcl_objects import BodyShapes, FclObjects, fcl_transform
from .geometry import _EYE3, Slerp, norm3, rotation_angle
from .poses import PoseArrays, Poses

__all__ = ["TimeOfImpact"]

#: a rotation by theta <= pi has ||R1 - R0||_F = 2 sqrt(2) sin(theta / 2) >= 2 sqrt(2) theta / pi
_ANGLE_PER_FRO = math.pi / (2.0 * math.sqrt(2.0)) * (1.0 + 1e-12)


class TimeOfImpact:
    """Fast-mover test and time of impact of moved bodies (module docstring)."""

    #: distance (m) below which conservative advancement reports contact
    TOI_TOL = 1e-4
    #: relative and absolute (m) inflation of the motion bound between two iterations
    #: (rounding of the interpolated pose and of fcl's distances, ~1e-15 relative)
    CA_MOTION_REL = 1e-9
    CA_MOTION_ABS = 1e-9

    def __init__(self, config, frames: Poses, arrays: PoseArrays, bounds, fclo: FclObjects,
                 shapes: BodyShapes, scene, pretests: bool = True) -> None:
        self._pretests = pretests  # the toi_pretests shortcut (.backend.Shortcuts)
        self._config, self._frames, self._arrays, self._bounds = config, frames, arrays, bounds
        self._fclo, self._shapes, self._bodies = fclo, shapes, scene.bodies
        self._is_dyn = [b.dynamic for b in scene.bodies]
        radius, thin = shapes.radius, shapes.thin
        self.threshold = [config.ccd_fast * t for t in thin]
        # the scalar estimate of the travel is within this of travel() (m): rounding of the
        # translation, and of acos near 1 (~1.4e-7 rad for traces ~1e-14 apart) times the radius
        self.slack = [1e-9 * max(config.ccd_fast * t, 1e-300) + 1e-12 + 4e-7 * r for t, r in zip(thin, radius)]
        #: a move whose face_shift bound is below this is no fast mover's
        self.clear = [t - 2.0 * s for t, s in zip(self.threshold, self.slack)]

    def travel(self, a: int) -> float:
        """Bound (m) on the travel of any surface point of ``a`` over the step."""
        T0, T1 = self._arrays.prev_T_of(a), self._arrays.T_of(a)
        return (norm3(T1[:3, 3] - T0[:3, 3])
                + rotation_angle(T1[:3, :3] @ T0[:3, :3].T) * self._shapes.radius[a])

    def needs(self, a: int) -> bool:
        """``travel(a) > ccd_fast * thin`` for ``a`` moved in this query. The move's
        ``(t, f) = face_shift`` settles clear slow moves (the angle is at most ``pi f / (2
        sqrt 2)``); a scalar estimate the clear cases; ``travel`` the ones within its rounding."""
        if not self._config.ccd:
            return False
        if not self._pretests:
            return bool(self.travel(a) > self.threshold[a])
        frames = self._frames
        motion = frames.motion.get(a)
        if motion is not None and motion[0] + _ANGLE_PER_FRO * motion[1] * self._shapes.radius[a] < self.clear[a]:
            return False
        T0, T1 = frames.prev[a], frames.rows[a]
        if T0 == T1:
            return False
        threshold = self.threshold[a]
        (a0, a1, a2, ax), (b0, b1, b2, by), (c0, c1, c2, cz) = T0[0], T0[1], T0[2]
        (p0, p1, p2, px), (q0, q1, q2, qy), (r0, r1, r2, rz) = T1[0], T1[1], T1[2]
        dx, dy, dz = px - ax, qy - by, rz - cz
        estimate = math.sqrt(dx * dx + dy * dy + dz * dz)
        if frames.same_rotation_at[a] != frames.qn:  # (the same rotation: angle 0)
            # trace(R1 R0^T) = sum of the element-wise products (rotation_angle's formula)
            c = p0 * a0 + p1 * a1 + p2 * a2 + q0 * b0 + q1 * b1 + q2 * b2 + r0 * c0 + r1 * c1 + r2 * c2
            estimate += math.acos(min(1.0, max(-1.0, (c - 1.0) / 2.0))) * self._shapes.radius[a]
        if abs(estimate - threshold) > self.slack[a]:
            return estimate > threshold
        return bool(self.travel(a) > threshold)

    def first_contact(self, a: int, stat, dyn, mask, counts: List[int], dt: float, prev) -> float:
        """Time of impact (s, -1 when none) of ``a`` over the step against the static members
        ``stat`` (through the tree, ``mask``) and dynamic members ``dyn`` whose boxes meet its
        swept AABB; ``prev`` is the pair's result at the start of the step."""
        arrays, frames = self._arrays, self._frames
        T0, T1 = arrays.prev_T_of(a), arrays.T_of(a)
        # swept AABB of a (padded by the rotation's chord at the bounding radius)
        ang = rotation_angle(T1[:3, :3] @ T0[:3, :3].T)
        pad = 2 * self._shapes.radius[a] * math.sin(min(ang, math.pi) / 2)
        box_lo, box_hi = self._bounds.lists(a)
        R0, R1 = frames.prev[a], frames.rows[a]
        lo, hi = [], []
        for k in range(3):
            shift = R0[k][3] - R1[k][3]
            lo.append(min(box_lo[k], box_lo[k] + shift) - pad)
            hi.append(max(box_hi[k], box_hi[k] + shift) + pad)
        cands = []
        for b in dyn.tolist():
            blo, bhi = self._bounds.lists(b)
            if all(blo[k] <= hi[k] and bhi[k] >= lo[k] for k in range(3)):
                cands.append(b)
        if len(stat):
            probe = fcl.CollisionObject(fcl.Box(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]),
                                        fcl.Transform(_EYE3, [(lo[k] + hi[k]) / 2 for k in range(3)]))
            found: List[int] = []
            self._fclo.manager.collide(probe, None, self._fclo.collector(found, mask))
            cands += sorted(set(found))
        toi = math.inf
        for b in cands:
            counts[0] += 1
            # the distance at the start of the step is known for the previous nearest member,
            # and is 0 for the previous contact's partner (counted as a narrow-phase test)
            d0 = None
            if prev is not None and prev.partner == b:
                if prev.in_contact:
                    d0 = 0.0
                    counts[1] += 1
                elif prev.distance >= 0:
                    d0 = prev.distance
            s = self.advance(a, b, counts, min(toi, 1.0), d0)
            if s is not None:
                toi = min(toi, s)
        return toi * dt if math.isfinite(toi) else -1.0

    def speed(self, i: int, path: Slerp, T0: np.ndarray, T1: np.ndarray) -> float:
        """Bound (m per unit fraction of the step) on the displacement of any surface point of
        ``i`` along ``path``: ``|t1 - t0| + theta rho``, ``rho`` the largest distance of its
        hull vertices from the rotation axis through its origin (chord <= rho dtheta)."""
        trans = norm3(T1[:3, 3] - T0[:3, 3])
        if path.axis is None:
            return trans
        u = T0[:3, :3].T @ path.axis  # the axis in the body frame
        hull = self._shapes.hull[i]
        along = hull @ u
        rho2 = float(np.max(np.einsum("ij,ij->i", hull, hull) - along * along))
        return trans + path.ang * math.sqrt(max(rho2, 0.0))

    def advance(self, a: int, b: int, counts, s_max: float, d0: Optional[float] = None) -> Optional[float]:
        """Conservative advancement of (a, b) over the step: the first contact fraction, or
        None. ``d0``: the distance at the start of the step when known."""
        arrays, shapes = self._arrays, self._shapes
        A0, A1, B0, B1 = arrays.prev_T_of(a), arrays.T_of(a), arrays.prev_T_of(b), arrays.T_of(b)
        path_a, path_b = Slerp(A0, A1), Slerp(B0, B1)
        mu = self.speed(a, path_a, A0, A1) + self.speed(b, path_b, B0, B1)
        if d0 is not None:  # the first iteration, before any fcl object is made
            if d0 <= self.TOI_TOL:
                return 0.0
            if mu <= 0 or 0.0 + d0 / mu > s_max:
                return None
        dgeoms = self._fclo.dgeoms
        oa = fcl.CollisionObject(dgeoms[self._bodies[a].mesh_key], fcl_transform(A0))
        ob = fcl.CollisionObject(dgeoms[self._bodies[b].mesh_key], fcl_transform(B0))
        req = fcl.DistanceRequest()
        # a static chunked partner: its chunks at its fixed pose, a's pose interpolated
        chunks = shapes.chunks[b] if not self._is_dyn[b] and shapes.chunk_partner[a] else None
        if chunks is not None:
            tag, tf = self._fclo.chunk_tf(b)
            other = (shapes.hull[a], shapes.box_c[a], shapes.box_h[a])
            path_b = None
        TA = A0
        within = math.inf  # chunks: a bound above the distance at this iteration's pose
        s = 0.0
        for it in range(200):
            if it == 0 and d0 is not None:
                d = d0
            else:
                counts[1] += 1
                if chunks is None:
                    d = fcl.distance(oa, ob, req, fcl.DistanceResult())
                else:
                    res = fcl.DistanceResult()
                    chunked_distance(chunks, tag, tf, B1, TA, other, oa, False, req, res, within)
                    d = res.min_distance
            if d <= self.TOI_TOL:
                return s
            if mu <= 0:
                return None
            s_last = s
            s += d / mu
            if s > s_max:
                return None
            # no surface point moves farther than mu (s - s_last) between the two poses
            motion = mu * (s - s_last) * (1.0 + self.CA_MOTION_REL) + self.CA_MOTION_ABS
            within = d + motion
            TA = path_a.at(s)
            oa.setTransform(fcl_transform(TA))
            if path_b is not None:
                ob.setTransform(fcl_transform(path_b.at(s)))
        return s
