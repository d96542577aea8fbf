"""World AABBs and bounding spheres of the bodies (eq. 5-1), brought up to date when read.

A body's world AABB is exact: the box of its mesh's convex-hull vertices rotated, plus the
translation (the hull has the mesh's extreme points, fewer to rotate). Rotated boxes are
kept per rotation (static bodies: per mesh and rotation; a dynamic body: its last one, so a
body that only translates never rotates its vertices again).
"""
from __future__ import annotations

import math
from typing import Dict, Tuple

import numpy as np

from .poses import PoseArrays, Poses

__all__ = ["Bounds", "local_shapes"]


def local_shapes(scene) -> Dict[str, Tuple[np.ndarray, np.ndarray, float]]:
    """Per mesh key: hull vertices (k, 3), bounding-sphere centre (3,) and radius (m) in the
    body frame (eq. 5-1: the centre of the local AABB, the farthest vertex from it)."""
    out = {}
    for key, mesh in scene.meshes.items():
        v = np.asarray(mesh.vertices, float)
        c = (v.min(0) + v.max(0)) / 2
        try:
            hull = np.asarray(mesh.convex_hull.vertices, float) if len(v) > 64 else v
        except Exception:  # degenerate (flat) meshes: qhull fails, keep every vertex
            hull = v
        out[key] = (hull, c, float(np.linalg.norm(v - c, axis=1).max()))
    return out


class Bounds:
    """``aabb`` (n, 2, 3) as (lo, hi) rows, ``sphere_c`` (n, 3), ``sphere_r`` (n,) in m, world
    frame; ``stale`` marks bodies moved since their row was written."""

    def __init__(self, scene, poses: Poses, arrays: PoseArrays) -> None:
        self._p, self._arrays = poses, arrays
        self.local = local_shapes(scene)
        self._keys = [b.mesh_key for b in scene.bodies]
        n = len(self._keys)
        self._is_dyn = [b.dynamic for b in scene.bodies]
        self.aabb = np.zeros((n, 2, 3))
        self.sphere_c = np.zeros((n, 3))
        self.sphere_r = np.array([self.local[k][2] for k in self._keys])
        self._rotated: Dict[tuple, np.ndarray] = {}  # static bodies' boxes by (mesh, rotation)
        #: per dynamic body its last rotated local box: (rotation key, box)
        self._dyn_box: Dict[int, tuple] = {}
        self._static_lists: Dict[int, tuple] = {}  # static bodies' AABBs as (lo, hi) lists
        self.stale = np.zeros(n, bool)
        self._sphere_stale = np.zeros(n, bool)  # AABB current, bounding-sphere centre not
        self.update(np.arange(n))

    def moved(self, bodies) -> None:
        for i in bodies:
            self.stale[i] = True

    def ensure(self, idx) -> None:
        """Bring ``aabb`` / ``sphere_c`` of bodies ``idx`` up to date."""
        idx = np.asarray(idx, dtype=int).ravel()
        stale = idx[self.stale[idx] | self._sphere_stale[idx]]
        if len(stale):
            self.update(stale)

    def update(self, idx, spheres: bool = True) -> None:
        """Write the rows of bodies ``idx`` (without ``spheres`` the centres stay stale)."""
        self.stale[idx] = False
        self._sphere_stale[idx] = not spheres
        Ts = self._arrays.T() if len(idx) != 1 else None
        rot_key = self._p.rot_key
        for i in idx:
            key = self._keys[i]
            v, c, _ = self.local[key]
            T = Ts[i] if Ts is not None else self._arrays.T_of(i)
            if self._is_dyn[i]:  # named by the bits of roll, pitch, yaw (its own bits after a restore)
                rkey = rot_key.get(i) or T[:3, :3].tobytes()
                last = self._dyn_box.get(i)
                box = last[1] if last is not None and last[0] == rkey else None
            else:
                rkey = (key, T[:3, :3].round(12).tobytes())
                box = self._rotated.get(rkey)
            if box is None:
                pts = v @ T[:3, :3].T
                box = np.empty((2, 3))  # (lo, hi): the reductions written in place
                np.minimum.reduce(pts, 0, out=box[0])
                np.maximum.reduce(pts, 0, out=box[1])
                if self._is_dyn[i]:
                    self._dyn_box[i] = (rkey, box)
                else:
                    self._rotated[rkey] = box
            self.aabb[i] = box + T[:3, 3]
            if spheres:
                self.sphere_c[i] = T[:3, :3] @ c + T[:3, 3]

    def lists(self, i: int) -> Tuple[list, list]:
        """Body ``i``'s world AABB as ``(lo, hi)`` lists, up to date (a static body's listed once)."""
        if not self._is_dyn[i]:
            box = self._static_lists.get(i)
            if box is None:
                box = self._static_lists[i] = tuple(self.aabb[i].tolist())
            return box
        if self.stale[i]:
            self.update([i], spheres=False)
        return self.aabb[i].tolist()

    def gap(self, a: int, b: int) -> float:
        """AABB gap of two bodies (m, 0 if overlapping); scalar code on :meth:`lists`."""
        (alo, ahi), (blo, bhi) = self.lists(a), self.lists(b)
        g = 0.0
        for k in range(3):
            d = max(blo[k] - ahi[k], alo[k] - bhi[k], 0.0)
            g += d * d
        return math.sqrt(g)

    def gaps(self, a: int, members: np.ndarray) -> np.ndarray:
        """AABB gaps (m) of ``a`` to each of ``members``, shape (len(members),)."""
        if self.stale[a]:
            self.update([a])
        if self.stale[members].any():
            self.ensure(members)
        lo = np.maximum(self.aabb[members, 0] - self.aabb[a, 1], 0)
        hi = np.maximum(self.aabb[a, 0] - self.aabb[members, 1], 0)
        return np.linalg.norm(np.maximum(lo, hi), axis=1)

    def state(self) -> tuple:
        return self.aabb.copy(), self.sphere_c.copy()

    def restore(self, state: tuple) -> None:
        self.aabb, self.sphere_c = state[0].copy(), state[1].copy()
        for i, dyn in enumerate(self._is_dyn):
            if dyn:
                self.stale[i] = True
