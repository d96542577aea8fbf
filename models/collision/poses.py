"""The bodies' poses, kept once: per body a pose and its world transform as nested lists.

A pose is ``(x, y, z, roll, pitch, yaw)`` (m, rad); its world transform is the 4x4 of eq. 4-6,
``R = Rz(yaw) Ry(pitch) Rx(roll)`` (:func:`.geometry.pose_rows`). :class:`Poses` holds, per
body, the pose, the transform now (``rows``) and at the start of the current query's step
(``prev``), and the query in which it last moved. A move gives a body new lists, never
modifies them: ``prev[i] is rows[i]`` unless body ``i`` moved in the current query.
:class:`PoseArrays` is the cache of the array forms numpy code reads, each body's row
rewritten when its lists are not the ones it holds.
"""
from __future__ import annotations

import math
import struct
from typing import Dict, List, Tuple

import numpy as np

from .geometry import pose_rows

__all__ = ["Poses", "PoseArrays", "face_shift"]

#: the bits of (roll, pitch, yaw): the key of a body's last rotation (``-0.0`` is not ``0.0``)
_PACK3 = struct.Struct("3d").pack


def face_shift(T0: list, T1: list) -> Tuple[float, float]:
    """``(|t1 - t0|, ||R1 - R0||_F)`` of a move from ``T0`` to ``T1`` (4x4 nested lists; m, 1).

    Any point ``p`` of a body moves by at most ``|t1 - t0| + ||R1 - R0||_F |p|`` (Frobenius
    >= spectral norm): the bound of the far-pair skip, the fcl pair cache and the fast-mover
    test. Scalar code, the sums in row order."""
    (a0, a1, a2, a3), (b0, b1, b2, b3), (c0, c1, c2, c3) = T0[0], T0[1], T0[2]
    (p0, p1, p2, p3), (q0, q1, q2, q3), (r0, r1, r2, r3) = T1[0], T1[1], T1[2]
    d3, e3, f3 = p3 - a3, q3 - b3, r3 - c3
    d0, d1, d2, e0, e1, e2, f0, f1, f2 = p0 - a0, p1 - a1, p2 - a2, q0 - b0, q1 - b1, q2 - b2, r0 - c0, r1 - c1, r2 - c2
    return (math.sqrt(d3 * d3 + e3 * e3 + f3 * f3),
            math.sqrt(d0 * d0 + d1 * d1 + d2 * d2 + e0 * e0 + e1 * e1 + e2 * e2 + f0 * f0 + f1 * f1 + f2 * f2))


class Poses:
    """Poses and transforms of a scene's bodies (module docstring).

    Attributes
    ----------
    pose : list of tuple
        Per body ``(x, y, z, roll, pitch, yaw)``, m and rad.
    rows, prev : list of list
        Per body its 4x4 transform now and at the start of the current query's step.
    moved_at, same_rotation_at : list of int
        Per body the query in which it last moved (-1: never), last moved keeping its rotation.
    motion : dict
        Per body moved in the current query: ``face_shift`` of its move.

    ``flat``, ``reuse``: the shortcuts ``flat_poses`` and ``rotation_reuse`` (.backend.Shortcuts).
    """

    def __init__(self, scene, flat: bool = True, reuse: bool = True) -> None:
        self._flat, self._reuse = flat, reuse
        self.names = [b.name for b in scene.bodies]
        self.dyn: List[int] = list(scene.dynamic)
        self.pose: List[tuple] = [tuple(np.asarray(b.pose, float).tolist()) for b in scene.bodies]
        self.rows = [pose_rows(p) for p in self.pose]
        self.prev = list(self.rows)
        self.qn = 0  # queries so far
        self.moved_at = [-1] * len(self.pose)
        self.same_rotation_at = [-1] * len(self.pose)
        #: per dynamic body the bits of the (roll, pitch, yaw) its rotation was made of
        self.rot_key: Dict[int, bytes | None] = {i: _PACK3(*self.pose[i][3:]) for i in self.dyn}
        self.motion: Dict[int, Tuple[float, float]] = {}
        self._moved: List[int] = []  # bodies moved in the current query
        self._dyn_six = list(zip(self.dyn, range(0, 6 * len(self.dyn), 6)))

    def changed(self, poses) -> List[Tuple[int, tuple]]:
        """The dynamic bodies whose pose differs from their last one, with the new pose.

        ``poses``: array_like (n_dynamic, 6), or the flat tuple of ``6 n_dynamic`` numbers the
        FMU passes (sliced as it is when its sum is finite: then every entry is). Raises
        ValueError naming the body and coordinate of a non-finite entry."""
        pose = self.pose
        if self._flat and type(poses) is tuple and len(poses) == 6 * len(self.dyn):
            try:
                fast = math.isfinite(sum(poses))
            except (TypeError, ValueError, OverflowError):
                fast = False
            if fast:
                return [(i, row) for i, k in self._dyn_six if (row := poses[k:k + 6]) != pose[i]]
        arr = np.asarray(poses, dtype=float).reshape(len(self.dyn), 6)
        if not math.isfinite(float(arr.sum())) and not np.isfinite(arr).all():
            i, k = np.argwhere(~np.isfinite(arr))[0]
            raise ValueError(f"pose of dynamic body {self.names[self.dyn[i]]!r} "
                             f"({'x y z roll pitch yaw'.split()[k]}) = {arr[i, k]} is not finite")
        return [(i, row) for i, row in zip(self.dyn, map(tuple, arr.tolist())) if row != pose[i]]

    def begin(self) -> None:
        """Start a query: no body has moved in it yet."""
        self.qn += 1
        prev, rows = self.prev, self.rows
        for i in self._moved:
            prev[i] = rows[i]
        self._moved = []
        self.motion = {}

    def move(self, changed: List[Tuple[int, tuple]], first: bool) -> List[int]:
        """Move the bodies of ``changed`` (body, new pose); returns them. A body that keeps the
        bits of its roll, pitch and yaw keeps its rotation rows (the numbers :func:`pose_rows`
        would compute). ``first``: the query's poses are the initial ones (no motion: ``prev``
        becomes the new transform)."""
        pose, rows, prev, motion = self.pose, self.rows, self.prev, self.motion
        rot_key, same_at, moved_at, qn = self.rot_key, self.same_rotation_at, self.moved_at, self.qn
        reuse = self._reuse
        for i, row in changed:
            pose[i] = row
            old = rows[i]
            key = _PACK3(row[3], row[4], row[5])
            if reuse and key == rot_key[i]:
                r0, r1, r2 = old[0], old[1], old[2]
                x, y, z = float(row[0]), float(row[1]), float(row[2])
                new = [[r0[0], r0[1], r0[2], x], [r1[0], r1[1], r1[2], y], [r2[0], r2[1], r2[2], z],
                       [0.0, 0.0, 0.0, 1.0]]
                same_at[i] = qn
                dx, dy, dz = x - r0[3], y - r1[3], z - r2[3]  # face_shift's arithmetic, rotation term 0
                motion[i] = (math.sqrt(dx * dx + dy * dy + dz * dz), 0.0)
            else:
                new = pose_rows(row)
                rot_key[i] = key
                motion[i] = face_shift(old, new)
            rows[i] = new
            if first:
                prev[i] = new
            moved_at[i] = qn
        self._moved = [i for i, _ in changed]
        return self._moved

    def moved_now(self, i: int) -> bool:
        """Body ``i`` has another transform than at the start of the current query's step."""
        before = self.prev[i]
        return before is not self.rows[i] and before != self.rows[i]

    def state(self) -> tuple:
        """The dynamic bodies' poses and transforms (copied)."""
        return [self.pose[i] for i in self.dyn], [[list(r) for r in self.rows[i]] for i in self.dyn]

    def restore(self, state: tuple) -> None:
        """Set the dynamic bodies' poses and transforms of :meth:`state` as if they had just
        moved there, in a query of their own, without motion."""
        self.qn += 1
        for i, p, rows in zip(self.dyn, *state):
            self.pose[i] = p
            self.rows[i] = self.prev[i] = [list(r) for r in rows]
            self.rot_key[i] = None
            self.moved_at[i] = self.qn
        self._moved, self.motion = [], {}


class PoseArrays:
    """Array forms of :class:`Poses`: ``poses`` (n, 6), ``T`` and ``prev_T`` (n, 4, 4), a cache
    whose body rows are rewritten when read after the body's lists changed."""

    def __init__(self, poses: Poses) -> None:
        self._p = poses
        self._T = np.array(poses.rows, dtype=float).reshape(-1, 4, 4)
        self._prev = self._T.copy()
        self._pose = np.array(poses.pose, dtype=float).reshape(-1, 6)
        self._src = [list(poses.rows), list(poses.prev), list(poses.pose)]  # what each row holds

    def _sync(self, arr: np.ndarray, src: list, lists: list, bodies) -> np.ndarray:
        for i in bodies:
            x = lists[i]
            if src[i] is not x:
                arr[i] = x
                src[i] = x
        return arr

    def T(self) -> np.ndarray:
        return self._sync(self._T, self._src[0], self._p.rows, self._p.dyn)

    def prev_T(self) -> np.ndarray:
        return self._sync(self._prev, self._src[1], self._p.prev, self._p.dyn)

    def poses(self) -> np.ndarray:
        return self._sync(self._pose, self._src[2], self._p.pose, self._p.dyn)

    def T_of(self, i: int) -> np.ndarray:
        """Body ``i``'s transform, shape (4, 4) (a view of the cache: read it before the next move)."""
        return self._sync(self._T, self._src[0], self._p.rows, (i,))[i]

    def prev_T_of(self, i: int) -> np.ndarray:
        return self._sync(self._prev, self._src[1], self._p.prev, (i,))[i]
