"""python-fcl objects of a scene and the fixed per-body numbers the fcl backend's bounds use.

* :class:`FclObjects`: one ``fcl.BVHModel`` (OBBRSS) per distinct mesh, shared by every body
  using it; a second BVH per mesh with a distance triangulation (:func:`.fans.distance_faces`)
  for exact distances; a ``CollisionObject`` per body; the static bodies in one
  ``DynamicAABBTreeCollisionManager`` built once. A body's fcl transform is set when a pair
  that needs it is evaluated after the body moved.
* :class:`BodyShapes`: per body its mesh's hull, local box, radii and chunks, as lists for
  scalar code, and the body-frame box gap (:meth:`BodyShapes.frame_gap`).
"""
from __future__ import annotations

import math
from typing import Dict, List, Tuple

import fcl
import numpy as np

from .chunks import CHUNK_MIN_FACES, CHUNK_OTHER_MAX_FACES, ChunkedMesh
from .fans import distance_faces
from .poses import PoseArrays, Poses

__all__ = ["bvh_model", "fcl_transform", "FclObjects", "BodyShapes"]


def bvh_model(vertices: np.ndarray, faces: np.ndarray) -> "fcl.BVHModel":
    """An fcl BVH (OBBRSS) of a triangle mesh."""
    g = fcl.BVHModel()
    g.beginModel(len(faces), len(vertices))  # (num_tris, num_vertices)
    g.addSubModel(np.asarray(vertices, float), np.asarray(faces, np.int64))
    g.endModel()
    return g


def fcl_transform(T: np.ndarray) -> "fcl.Transform":
    """The fcl transform of a 4x4 rigid transform (python-fcl copies rotation and translation)."""
    return fcl.Transform(T[:3, :3], T[:3, 3])


class FclObjects:
    """The fcl side of a scene (module docstring); ``dfaces[key]`` is a mesh's distance
    triangulation, None when it is the mesh's own."""

    def __init__(self, scene, frames: Poses, arrays: PoseArrays, max_contacts: int) -> None:
        self._frames, self._arrays, self._bodies = frames, arrays, scene.bodies
        self.geoms = {key: bvh_model(m.vertices, m.faces) for key, m in scene.meshes.items()}
        self.dfaces = {key: distance_faces(m.vertices, m.faces) for key, m in scene.meshes.items()}
        self.dgeoms = {key: (self.geoms[key] if F is None else bvh_model(scene.meshes[key].vertices, F))
                       for key, F in self.dfaces.items()}
        #: per body its distance object when its mesh has a distance triangulation (made when
        #: first needed), else None (its CollisionObject serves both)
        self._dist_own: List = [None] * len(scene.bodies)
        self._dist_distinct = [self.dfaces[b.mesh_key] is not None for b in scene.bodies]
        T = arrays.T()
        self.objs = [fcl.CollisionObject(self.geoms[b.mesh_key], fcl_transform(T[i]))
                     for i, b in enumerate(scene.bodies)]
        self.static_idx = np.asarray(scene.static, dtype=int)
        self.manager = fcl.DynamicAABBTreeCollisionManager()
        if len(self.static_idx):
            self.manager.registerObjects([self.objs[i] for i in self.static_idx])
        self.manager.setup()
        # the callbacks receive fresh wrappers: static bodies are known by their translation
        self.by_pose: Dict[bytes, List[int]] = {}
        for i in self.static_idx:
            self.by_pose.setdefault(self.key(self.objs[i]), []).append(int(i))
        #: per body the query of the last move whose transform its fcl objects hold
        self._fcl_at = list(frames.moved_at)
        self._tf_cache: Dict[int, tuple] = {}
        self.creq = fcl.CollisionRequest(num_max_contacts=max_contacts, enable_contact=True)
        self.dreq = fcl.DistanceRequest(enable_nearest_points=True)

    @staticmethod
    def key(obj) -> bytes:
        return obj.getTranslation().tobytes()

    def collector(self, found: List[int], mask: np.ndarray):
        """Broad-phase callback: record the bodies of ``mask`` among the overlapping objects."""
        by_pose, key = self.by_pose, self.key

        def on_overlap(o1, o2, _data):
            for other in (o1, o2):
                for b in by_pose.get(key(other), ()):
                    if mask[b]:
                        found.append(b)
            return False
        return on_overlap

    def sync(self, bodies: List[int]) -> None:
        """Set the fcl transforms of ``bodies`` that moved since theirs was set."""
        moved_at, fcl_at, own = self._frames.moved_at, self._fcl_at, self._dist_own
        for i in bodies:
            if fcl_at[i] != moved_at[i]:
                tf = fcl_transform(self._arrays.T_of(i))
                self.objs[i].setTransform(tf)
                if own[i] is not None:
                    own[i].setTransform(tf)
                fcl_at[i] = moved_at[i]

    def dobj(self, i: int) -> "fcl.CollisionObject":
        """Body ``i``'s object for exact distances (on its distance triangulation); its
        transform is the collision object's (call after :meth:`sync`)."""
        if not self._dist_distinct[i]:
            return self.objs[i]
        obj = self._dist_own[i]
        if obj is None:
            obj = self._dist_own[i] = fcl.CollisionObject(self.dgeoms[self._bodies[i].mesh_key],
                                                          fcl_transform(self._arrays.T_of(i)))
        return obj

    def chunk_tf(self, i: int) -> Tuple[tuple, "fcl.Transform"]:
        """The tag (body, query of its last move) and fcl transform of body ``i`` for its chunks."""
        tag = (i, self._frames.moved_at[i])
        cached = self._tf_cache.get(i)
        if cached is None or cached[0] != tag:
            cached = self._tf_cache[i] = (tag, fcl_transform(self._arrays.T_of(i)))
        return cached


class BodyShapes:
    """Per body (lists, scalar code): ``faces`` (triangle count), ``hull`` (hull vertices,
    body frame), ``box_c`` / ``box_h`` (local AABB centre and half extents, arrays),
    ``radius`` (m, largest distance of a surface point from the body origin), ``thin`` (m,
    smallest mesh extent), ``chunks`` (:class:`.chunks.ChunkedMesh` or None) and
    ``chunk_partner`` (few enough triangles to be the other side of a chunked query)."""

    #: m; the body-frame gap must beat the best distance by this much to skip a query
    FRAME_GAP_MARGIN = 1e-9

    def __init__(self, scene, fclo: FclObjects, local, T: np.ndarray, chunk_faces: int) -> None:
        bodies, meshes = scene.bodies, scene.meshes
        self.faces = [len(meshes[b.mesh_key].faces) for b in bodies]
        self.chunked: Dict[str, ChunkedMesh] = {}
        if chunk_faces > 0:
            for key, m in meshes.items():
                if len(m.faces) >= CHUNK_MIN_FACES:
                    F = m.faces if fclo.dfaces[key] is None else fclo.dfaces[key]
                    self.chunked[key] = ChunkedMesh(m.vertices, F, chunk_faces, split_by=m.faces)
        self.chunks = [self.chunked.get(b.mesh_key) for b in bodies]
        self.chunk_partner = [f <= CHUNK_OTHER_MAX_FACES for f in self.faces]
        self.hull = [local[b.mesh_key][0] for b in bodies]
        boxes = {key: (np.asarray(m.vertices, float).min(0), np.asarray(m.vertices, float).max(0))
                 for key, m in meshes.items()}
        self.box_c = [(boxes[b.mesh_key][0] + boxes[b.mesh_key][1]) / 2 for b in bodies]
        self.box_h = [(boxes[b.mesh_key][1] - boxes[b.mesh_key][0]) / 2 for b in bodies]
        lists = {key: (lo.tolist(), hi.tolist(), ((lo + hi) / 2).tolist(), ((hi - lo) / 2).tolist())
                 for key, (lo, hi) in boxes.items()}
        self._box_lists = [lists[b.mesh_key] for b in bodies]  # lo, hi, centre, half extents
        self._sphere_r = [local[b.mesh_key][2] for b in bodies]
        self._is_dyn = [b.dynamic for b in bodies]
        self._unrotated = [not b.dynamic and bool((T[i, :3, :3] == np.eye(3)).all()) for i, b in enumerate(bodies)]
        self.thin = [float(meshes[b.mesh_key].extents.min()) for b in bodies]
        self.radius = (np.array(self._sphere_r) + np.linalg.norm(np.array([local[b.mesh_key][1] for b in bodies]),
                                                                 axis=1)).tolist()

    def frame_gap(self, a: int, b: int, rows: list) -> float:
        """Lower bound (m) of the distance of ``a`` and ``b`` (transforms ``rows[a]``, ``rows[b]``):
        in the frame of each rotated body not smaller than the other, the gap between its local
        AABB and the box bounding the other's local AABB there (centre ``M c + p``, half
        extents ``|M| h``); the larger of the two. Both boxes contain their body."""
        best = -math.inf
        radius = self._sphere_r
        for f, o in ((a, b), (b, a)):
            if radius[o] > radius[f] or self._unrotated[f]:
                continue  # a larger body's box in a smaller one's frame is rarely tighter
            F, O = rows[f], rows[o]
            (f00, f01, f02, ftx), (f10, f11, f12, fty), (f20, f21, f22, ftz) = F[0], F[1], F[2]
            if (self._is_dyn[f] and f00 == 1.0 and f11 == 1.0 and f22 == 1.0 and f01 == 0.0 and f02 == 0.0
                    and f10 == 0.0 and f12 == 0.0 and f20 == 0.0 and f21 == 0.0):
                continue  # in the world axes its frame box is its world AABB: nothing to gain
            (o00, o01, o02, otx), (o10, o11, o12, oty), (o20, o21, o22, otz) = O[0], O[1], O[2]
            dx, dy, dz = otx - ftx, oty - fty, otz - ftz
            # M = R_f^T R_o, p = R_f^T (t_o - t_f): o's frame in f's
            m00, m01, m02 = f00 * o00 + f10 * o10 + f20 * o20, f00 * o01 + f10 * o11 + f20 * o21, f00 * o02 + f10 * o12 + f20 * o22
            m10, m11, m12 = f01 * o00 + f11 * o10 + f21 * o20, f01 * o01 + f11 * o11 + f21 * o21, f01 * o02 + f11 * o12 + f21 * o22
            m20, m21, m22 = f02 * o00 + f12 * o10 + f22 * o20, f02 * o01 + f12 * o11 + f22 * o21, f02 * o02 + f12 * o12 + f22 * o22
            lo, hi = self._box_lists[f][0], self._box_lists[f][1]
            (cx, cy, cz), (ex, ey, ez) = self._box_lists[o][2], self._box_lists[o][3]
            g = 0.0
            for (r0, r1, r2), t, l, h in (((m00, m01, m02), f00 * dx + f10 * dy + f20 * dz, lo[0], hi[0]),
                                          ((m10, m11, m12), f01 * dx + f11 * dy + f21 * dz, lo[1], hi[1]),
                                          ((m20, m21, m22), f02 * dx + f12 * dy + f22 * dz, lo[2], hi[2])):
                c = r0 * cx + r1 * cy + r2 * cz + t
                e = abs(r0) * ex + abs(r1) * ey + abs(r2) * ez
                sep = max(l - (c + e), (c - e) - h, 0.0)
                g += sep * sep
            best = max(best, math.sqrt(g))
        return best
