"""Backend ``fcl``: python-fcl BVH models, a dynamic AABB tree broad phase, exact distances.

* One ``fcl.BVHModel`` (OBBRSS) per distinct mesh, shared by every body that uses the mesh
  (a field of 5040 tanks holds one tank BVH and 5040 ``CollisionObject`` transforms).
* Exact distances (narrow phase, chunks, conservative advancement) run on each mesh's
  distance triangulation (:func:`.fans.distance_faces`): large plane fans of slivers (a
  tank turret's caps, ~580 triangles meeting at the centre) re-triangulated, the same
  surface, so the same distances to round-off; a body whose mesh has one gets a second
  ``CollisionObject`` for it, made when first needed. Contact tests (``fcl.collide``: flag,
  depth, point, normal) and the broad phase use the mesh's own triangles.
* Static bodies live in one ``fcl.DynamicAABBTreeCollisionManager`` built once and never
  updated; dynamic bodies (at most a handful) are checked directly with an AABB cull. Only
  bodies that moved get a new transform.
* Per monitored pair ``a vs members``: broad phase ``manager.collide(a)`` lists the members
  whose AABB overlaps ``a``'s; each gets a narrow-phase ``fcl.collide`` with contacts
  (penetration depth = deepest contact's ``penetration_depth``), unless a lower bound of its
  distance (the last exact distance less the motion since, the body-frame box gap) proves
  it apart: it counts as tested and has no contact, what ``fcl.collide`` would say. Without contact,
  ``manager.distance(a)`` finds the nearest member: the tree prunes every member whose AABB is
  farther than the best distance so far (or than ``max_distance``). Before each exact
  ``fcl.distance`` the member's AABB gap and the lower bound from its last exact distance
  (minus the motion since) are checked against the best so far: a member at least
  ``max_distance`` away costs no mesh-mesh distance and the pair reports ``max_distance``.
  The same cache keeps an upper bound (the distance found, plus the motion since): a chunked
  query bounds only the chunks nearer than it (:func:`.chunks.chunked_distance`).
* Time of impact for bodies that moved. Slow movers (travel in the step below
  ``ccd_fast`` x their thinnest extent: they cannot tunnel) that enter contact get
  ``toi = h d0 / (d0 + depth)`` from the distance at the start and the depth at the end of
  the step (0 when the contact already held). For fast movers the swept AABB of ``a`` over
  the step is queried against the tree, and each candidate gets conservative advancement (Mirtich 1996) driven by
  ``fcl.distance``: ``s += d(s) / mu`` with ``mu`` a bound on the relative speed of any surface
  point (translation + angle x the largest distance of a hull vertex from the rotation axis,
  :meth:`FclBackend._speed`), until ``d <= toi_tol`` (contact at ``s``) or ``s > 1``.
  fcl's own ``continuousCollide`` is not used: its conservative-advancement solver rejects
  mesh-mesh requests in python-fcl 0.7 and the naive solver only samples 10 poses.
* Exact distances of a body of at most ``CHUNK_OTHER_MAX_FACES`` triangles (a box) to a
  mesh of at least ``CHUNK_MIN_FACES`` triangles go chunk by chunk
  (:mod:`.chunks`; ``BackendConfig.chunk_faces``, 0 for the whole-mesh query): the same
  distances (round-off), far fewer triangle pairs where a large flat face is nearest.
  A larger body (the missile) keeps the whole-mesh query, also in its conservative
  advancement: on the distance triangulation it is cheaper than the minimum over the
  chunks (1.6 ms instead of 2.5 ms for campus_drive's missile impact).
* Far pairs (every member's AABB at least ``max_distance`` away, no time of impact needed)
  are skipped by the base class's far-pair skip (``FAR_SKIP``); the fcl transform of a moved
  body is set only when a pair that involves it is evaluated.
"""
from __future__ import annotations

import logging
import math
from typing import Dict, List, Tuple

import fcl
import numpy as np

from .backend import CollisionBackend, PairResult, PairSpec, _face_shift, aggregate
from .chunks import CHUNK_MIN_FACES, CHUNK_OTHER_MAX_FACES, ChunkedMesh, chunked_distance
from .fans import distance_faces
from .geometry import _EYE3, Slerp, norm3, rotation_angle

log = logging.getLogger(__name__)

__all__ = ["FclBackend", "bvh_model", "fcl_transform"]


#: a rotation by theta <= pi has ||R1 - R0||_F = 2 sqrt(2) sin(theta / 2) >= 2 sqrt(2) theta / pi:
#: theta <= _ANGLE_PER_FRO ||R1 - R0||_F (rounded up)
_ANGLE_PER_FRO = math.pi / (2.0 * math.sqrt(2.0)) * (1.0 + 1e-12)


def bvh_model(vertices: np.ndarray, faces: np.ndarray) -> "fcl.BVHModel":
    """An fcl BVH (OBBRSS) of a triangle mesh."""
    g = fcl.BVHModel()
    g.beginModel(len(faces), len(vertices))  # (num_tris, num_vertices)
    g.addSubModel(np.asarray(vertices, float), np.asarray(faces, np.int64))
    g.endModel()
    return g


def fcl_transform(T: np.ndarray) -> "fcl.Transform":
    """The fcl transform of a 4x4 rigid transform (python-fcl copies the rotation and
    translation into arrays of its own)."""
    return fcl.Transform(T[:3, :3], T[:3, 3])


class FclBackend(CollisionBackend):
    """Exact collision, distance, penetration depth and time of impact with python-fcl."""

    name = "fcl"
    FAR_SKIP = True
    #: distance (m) below which conservative advancement reports contact
    toi_tol = 1e-4
    #: the motion bound between two iterations is inflated by this (relative) and this (m):
    #: covers the rounding of the interpolated pose and of fcl's distances (~1e-15 relative)
    CA_MOTION_REL = 1e-9
    CA_MOTION_ABS = 1e-9

    def _setup(self) -> None:
        self.geoms = {key: bvh_model(m.vertices, m.faces) for key, m in self.scene.meshes.items()}
        # exact distances run on each mesh's distance triangulation (.fans: large plane fans
        # re-triangulated; the same surface), contact tests on its own triangles
        dfaces = {key: distance_faces(m.vertices, m.faces) for key, m in self.scene.meshes.items()}
        self.dgeoms = {key: (self.geoms[key] if F is None else bvh_model(self.scene.meshes[key].vertices, F))
                       for key, F in dfaces.items()}
        #: per body its distance object when its mesh has a distance triangulation of its own
        #: (made when first needed), else None (its CollisionObject serves both)
        self._dist_own: List = [None] * self.n
        self._dist_distinct = [dfaces[b.mesh_key] is not None for b in self.scene.bodies]
        self.objs: List[fcl.CollisionObject] = [
            fcl.CollisionObject(self.geoms[b.mesh_key], fcl_transform(self.T[i]))
            for i, b in enumerate(self.scene.bodies)]
        self.static_idx = np.asarray(self.scene.static, dtype=int)
        self.manager = fcl.DynamicAABBTreeCollisionManager()
        if len(self.static_idx):
            self.manager.registerObjects([self.objs[i] for i in self.static_idx])
        self.manager.setup()
        # the callbacks receive fresh wrappers: identify static bodies by their translation
        self._by_pose: Dict[bytes, List[int]] = {}
        for i in self.static_idx:
            self._by_pose.setdefault(self._key(self.objs[i]), []).append(int(i))
        self._member_mask = np.zeros(self.n, bool)
        #: per body the query of the last move whose transform its fcl objects hold (the
        #: base class's _moved_at: a body moved since when they differ)
        self._fcl_at = list(self._moved_at)
        self._pair_now: List[int] = []
        self._pair_sync: Dict[int, List[int]] = {}
        self._pair_parts = {}
        self._small: Dict[int, np.ndarray] = {}
        self._small_list: Dict[int, List[int]] = {}
        for k, pair in enumerate(self.pairs):
            mask = np.zeros(self.n, bool)
            mask[pair.members] = True
            mask[pair.a] = False
            members = pair.members[mask[pair.members]]
            stat = members[~self.is_dynamic[members]]
            # the tree serves groups that are all static bodies or larger than 8; small subsets
            # of a larger scene are checked directly
            use_tree = len(stat) > 8 or (len(stat) > 0 and len(stat) == len(self.static_idx))
            dyn = members[self.is_dynamic[members]]
            self._pair_parts[id(pair)] = (mask, stat, dyn, use_tree)
            self._small[id(pair)] = np.concatenate([dyn, [] if use_tree else stat]).astype(int)
            self._small_list[id(pair)] = self._small[id(pair)].tolist()
            # dynamic bodies whose fcl transform must be current when the pair is evaluated
            self._pair_sync[id(pair)] = ([int(pair.a)] if self.is_dynamic[pair.a] else []) + dyn.tolist()
        self._creq = fcl.CollisionRequest(num_max_contacts=self.config.max_contacts, enable_contact=True)
        self._dreq = fcl.DistanceRequest(enable_nearest_points=True)
        self._faces = np.array([len(self.scene.meshes[b.mesh_key].faces) for b in self.scene.bodies])
        self._a_first = False
        # (a, b) -> at the last exact distance: a lower bound of it, T_a, T_b (rows), an upper bound
        self._exact: Dict[Tuple[int, int], tuple] = {}
        # each body's local AABB (its mesh's, in the body frame) for _frame_gap
        self._frame_box = [(np.asarray(self.scene.meshes[b.mesh_key].vertices, float).min(0),
                            np.asarray(self.scene.meshes[b.mesh_key].vertices, float).max(0))
                           for b in self.scene.bodies]
        # chunked exact distances (module docstring): the chunks of each large mesh, built once
        self._chunked: Dict[str, ChunkedMesh] = {}
        if self.config.chunk_faces > 0:
            for key, m in self.scene.meshes.items():
                if len(m.faces) >= CHUNK_MIN_FACES:
                    F = m.faces if dfaces[key] is None else dfaces[key]
                    self._chunked[key] = ChunkedMesh(m.vertices, F, self.config.chunk_faces, split_by=m.faces)
        self._body_chunks = [self._chunked.get(b.mesh_key) for b in self.scene.bodies]
        self._faces_list = self._faces.tolist()
        #: the body may be the other side of a chunked query (few triangles, module docstring)
        self._chunk_partner = [f <= CHUNK_OTHER_MAX_FACES for f in self._faces_list]
        # the other side of the chunk bound: each body's hull vertices and local AABB
        self._hull = [self._local[b.mesh_key][0] for b in self.scene.bodies]
        self._box_c = [(lo + hi) / 2 for lo, hi in self._frame_box]
        self._box_h = [(hi - lo) / 2 for lo, hi in self._frame_box]
        # the same boxes as lists (lo, hi, centre, half extents), one tuple per mesh, for _frame_gap
        boxes: Dict[str, tuple] = {}
        for b, (lo, hi), c, h in zip(self.scene.bodies, self._frame_box, self._box_c, self._box_h):
            boxes.setdefault(b.mesh_key, (lo.tolist(), hi.tolist(), c.tolist(), h.tolist()))
        self._box_lists = [boxes[b.mesh_key] for b in self.scene.bodies]
        self._sphere_r = self.sphere_r.tolist()
        self._is_dyn = self.is_dynamic.tolist()
        self._tf_cache: Dict[int, tuple] = {}
        self._unrotated = [not self.is_dynamic[i] and bool((self.T[i, :3, :3] == np.eye(3)).all())
                           for i in range(self.n)]
        self._thin = np.array([float(self.scene.meshes[b.mesh_key].extents.min()) for b in self.scene.bodies])
        self._radius = self.sphere_r + np.linalg.norm(
            np.array([self._local[b.mesh_key][1] for b in self.scene.bodies]), axis=1)
        # _needs_toi's estimate is within this of _travel (m): rounding of the translation
        # (relative), and of the rotation angle: the two traces of R1 R0^T differ by ~1e-14 at
        # most, acos near 1 turns that into up to ~1.4e-7 rad, times the radius
        self._radius_list = self._radius.tolist()
        self._toi_threshold = (self.config.ccd_fast * self._thin).tolist()
        self._toi_slack = [1e-9 * max(self.config.ccd_fast * t, 1e-300) + 1e-12 + 4e-7 * r
                           for t, r in zip(self._thin.tolist(), self._radius.tolist())]
        # _needs_toi's first test: a move whose bound from _step_motion is below this is no
        # fast mover's (the estimate is below the threshold by more than the slack)
        self._toi_clear = [t - 2.0 * s for t, s in zip(self._toi_threshold, self._toi_slack)]

    @staticmethod
    def _key(obj) -> bytes:
        return obj.getTranslation().tobytes()

    def _collector(self, found: List[int]):
        """Broad-phase callback: record the monitored members among the overlapping objects."""
        mask, by_pose, key = self._member_mask, self._by_pose, self._key

        def on_overlap(o1, o2, _data):
            for other in (o1, o2):
                for b in by_pose.get(key(other), ()):
                    if mask[b]:
                        found.append(b)
            return False
        return on_overlap

    def _chunk_tf(self, i: int) -> Tuple[tuple, "fcl.Transform"]:
        """The tag (body, transform version: the query in which it last moved) and fcl
        transform of body ``i`` for its chunks."""
        tag = (i, self._moved_at[i])
        cached = self._tf_cache.get(i)
        if cached is None or cached[0] != tag:
            cached = self._tf_cache[i] = (tag, fcl_transform(self._T[i]))
        return cached

    def _sync(self, bodies: List[int]) -> None:
        """Set the fcl transforms of ``bodies`` that moved since theirs was last set (the
        query of the last move differs from the one whose transform the object holds)."""
        moved_at, fcl_at, own = self._moved_at, self._fcl_at, self._dist_own
        for i in bodies:
            if fcl_at[i] != moved_at[i]:
                tf = fcl_transform(self._T[i])
                self.objs[i].setTransform(tf)
                if own[i] is not None:
                    own[i].setTransform(tf)
                fcl_at[i] = moved_at[i]

    def _dobj(self, i: int) -> "fcl.CollisionObject":
        """Body ``i``'s object for exact distances: on its mesh's distance triangulation
        (:func:`.fans.distance_faces`), or its collision object when that is the mesh itself.
        Its transform is the collision object's (call after :meth:`_sync`)."""
        if not self._dist_distinct[i]:
            return self.objs[i]
        obj = self._dist_own[i]
        if obj is None:
            obj = self._dist_own[i] = fcl.CollisionObject(self.dgeoms[self.scene.bodies[i].mesh_key],
                                                          fcl_transform(self._T[i]))
        return obj

    def _travel(self, a: int) -> float:
        """Bound (m) on the travel of any surface point of ``a`` over the step (translation +
        rotation angle x radius about the origin): what decides a fast mover. (Asked by the
        far-pair skip too, before the pair's rows are written: writes ``a``'s.)"""
        self._sync_rows((a,))
        T0, T1 = self._prev_T[a], self._T[a]
        return (norm3(T1[:3, 3] - T0[:3, 3])
                + rotation_angle(T1[:3, :3] @ T0[:3, :3].T) * self._radius[a])

    def _moved_now(self, a: int) -> bool:
        """``a`` has a new transform in this query (``prev_T[a] != T[a]``, on the list forms)."""
        if self._prev_is_T:
            return False
        before = self._prev_rows.get(a)
        return before is not None and before != self._T_rows[a]

    def _fast(self, a: int) -> bool:
        """``a`` (moved in this query) is a fast mover: :meth:`_needs_toi`, once per query."""
        need = self._toi_need.get(a)
        if need is None:
            need = self._toi_need[a] = self._needs_toi(a)
        return need

    def _needs_toi(self, a: int) -> bool:
        """A fast mover gets conservative advancement even without contact at either end.

        The answer of ``_travel(a) > ccd_fast * thin`` (what :meth:`_evaluate` asks, through
        :meth:`_fast`): a scalar estimate of the travel settles the clear cases and only one
        within its rounding of the threshold (``_toi_slack``) is decided by :meth:`_travel`
        itself. Before that, the move's translation ``t`` and ``f = ||R1 - R0||_F`` (recorded
        by :meth:`_move`) settle most slow moves: the rotation angle is at most
        ``pi f / (2 sqrt 2)`` (``f = 2 sqrt 2 sin(theta / 2)`` and ``sin(x) >= 2 x / pi`` on
        ``[0, pi / 2]``), so ``t + pi f / (2 sqrt 2) radius`` below the threshold by twice the
        slack puts the estimate below it by more than the slack (the estimate's rounding is
        within the slack): the answer the estimate gives, False."""
        if not self.config.ccd:
            return False
        motion = self._step_motion.get(a)
        if motion is not None and motion[0] + _ANGLE_PER_FRO * motion[1] * self._radius_list[a] < self._toi_clear[a]:
            return False
        T0, T1 = self._prev_rows[a], self._T_rows[a]  # before and after this query's move
        if T0 == T1:
            return False
        threshold = self._toi_threshold[a]
        (a0, a1, a2, ax), (b0, b1, b2, by), (c0, c1, c2, cz) = T0[0], T0[1], T0[2]
        (p0, p1, p2, px), (q0, q1, q2, qy), (r0, r1, r2, rz) = T1[0], T1[1], T1[2]
        dx, dy, dz = px - ax, qy - by, rz - cz
        estimate = math.sqrt(dx * dx + dy * dy + dz * dz)
        if self._same_rotation_at[a] != self._qn:  # (the same rotation: angle 0, within the slack)
            # trace(R1 R0^T) = sum of the element-wise products (rotation_angle's formula)
            c = p0 * a0 + p1 * a1 + p2 * a2 + q0 * b0 + q1 * b1 + q2 * b2 + r0 * c0 + r1 * c1 + r2 * c2
            estimate += math.acos(min(1.0, max(-1.0, (c - 1.0) / 2.0))) * self._radius_list[a]
        if abs(estimate - threshold) > self._toi_slack[a]:
            return estimate > threshold
        return bool(self._travel(a) > threshold)

    _far_gap_known = True

    def _far_gap(self, k: int, pair: PairSpec) -> float | None:
        """The smallest AABB gap of the members checked directly (a pair without the tree:
        :meth:`_evaluate` finds no candidate and no member nearer than ``max_distance`` when
        it is at least that); None for a pair served by the tree (the tree's distance
        traversal may count a candidate)."""
        if self._pair_parts[id(pair)][3]:
            return None
        a, small = pair.a, self._small_list[id(pair)]
        # first without any AABB update: a box around each moved body from its transform (its
        # local AABB rotated: it contains the exact AABB), less its rounding
        alo, ahi = self._loose_box(a)
        loose = math.inf
        for b in small:
            blo, bhi = self._loose_box(b)
            g = 0.0
            for k in range(3):
                d = max(blo[k] - ahi[k], alo[k] - bhi[k], 0.0)
                g += d * d
            loose = min(loose, math.sqrt(g) - self.LOOSE_ROUNDING)
        if loose >= self.config.max_distance + self.FAR_MARGIN:
            return loose
        return min(self._gap(a, b) for b in small)

    #: m; the rounding of _loose_box's corners (coordinates up to 1e4 m: ~1e-11 m)
    LOOSE_ROUNDING = 1e-9

    def _loose_box(self, i: int) -> tuple:
        """A world box (lo, hi lists) that contains body ``i``'s AABB: a static body's AABB
        itself, a dynamic body's local AABB rotated and moved by its current transform
        (centre ``R c + t``, half extents ``|R| h``), up to rounding."""
        if not self._is_dyn[i]:
            return self._aabb_lists(i)
        R = self._T_rows[i]
        (cx, cy, cz), (hx, hy, hz) = self._box_lists[i][2], self._box_lists[i][3]
        lo, hi = [], []
        for r0, r1, r2, t in R[:3]:
            c = r0 * cx + r1 * cy + r2 * cz + t
            e = abs(r0) * hx + abs(r1) * hy + abs(r2) * hz
            lo.append(c - e)
            hi.append(c + e)
        return lo, hi

    #: m; a lower bound of a candidate's distance above this proves it is not in contact (far
    #: above the rounding of fcl's triangle tests, coordinates of 1e2..1e3 m: ~1e-13 m)
    SEPARATED = 1e-6

    def _separated(self, a: int, b: int) -> bool:
        """A broad-phase candidate (overlapping AABBs) is provably not in contact: the lower
        bound from the pair's last exact distance (:meth:`_bound`) or the body-frame box gap
        (:meth:`_frame_gap`) exceeds ``SEPARATED``. The narrow-phase test would report no
        contact; it is counted all the same (``n_narrow`` counts the candidates tested)."""
        return self._bound(a, b) > self.SEPARATED or self._frame_gap(a, b) > self.SEPARATED

    # -- narrow phase -------------------------------------------------------------------
    def _collide(self, a: int, b: int, obj_b=None) -> PairResult | None:
        # member first, as python-fcl's manager callbacks call it: fcl's BVH-BVH traversal
        # is far cheaper with the large tree first (measured 0.1 ms vs 5-8 ms, tank vs missile)
        res = fcl.CollisionResult()
        fcl.collide(obj_b if obj_b is not None else self.objs[b], self.objs[a], self._creq, res)
        if not res.is_collision:
            return None
        c = max(res.contacts, key=lambda c: c.penetration_depth)
        n = -np.asarray(c.normal, float)  # fcl's normal points from its first object (b) to a
        return PairResult(True, 0.0, float(max(c.penetration_depth, 0.0)), np.asarray(c.pos, float).copy(),
                          n / (norm3(n) or 1.0))

    def _distance(self, a: int, b: int, res: "fcl.DistanceResult") -> bool:
        """Narrow-phase distance into a shared result (it keeps the smallest distance and its
        nearest points). True when ``b`` became the nearest.

        Skipped without a query when the AABB gap, or the lower bound from the pair's last
        exact distance (:meth:`_bound`), already reaches the best distance so far (at first
        ``max_distance``): a far pair costs no mesh-mesh distance. These checks are left out
        when the upper bound from the last exact distance is below the best (none could
        skip). (``fcl.distance`` itself does not prune with the result's current minimum: it
        always returns the exact distance, checked with python-fcl 0.7.)"""
        before = res.min_distance
        since = self._since(a, b)
        if since is None or since[1] >= before:  # (else it is nearer than the best: no bound can skip it)
            if self._gap(a, b) >= before:
                return False
            if (since is not None and since[0] >= before) or self._frame_gap(a, b) >= before + self.FRAME_GAP_MARGIN:
                return False
        # the larger BVH first: fcl's traversal is cheaper (member first otherwise, see _collide)
        self._sync(self._pair_now)
        faces = self._faces_list
        if faces[a] > faces[b]:
            a_first, big, small = True, a, b
        else:
            a_first, big, small = False, b, a
        chunks = self._body_chunks[big]
        if chunks is None or not self._chunk_partner[small]:
            d = up = fcl.distance(self._dobj(big), self._dobj(small), self._dreq, res)
            if not up >= 0:  # (fcl's -1: no distance, no bound)
                up = math.inf
        else:  # the same triangle pairs, chunk by chunk (module docstring of .chunks)
            tag, tf = self._chunk_tf(big)
            d = chunked_distance(chunks, tag, tf, self._T[big], self._T[small],
                                 (self._hull[small], self._box_c[small], self._box_h[small]), self._dobj(small), True,
                                 self._dreq, res, math.inf if since is None else since[1])
            # its distance when it became the nearest, else no bound above it
            up = res.min_distance if 0 <= res.min_distance < before else math.inf
        self._exact[(a, b)] = (d, self._rows(a), self._rows(b), up)  # (rows are replaced, never modified)
        if res.min_distance < before:
            self._a_first = a_first
            return True
        return False

    #: m; added to an upper bound of a pair's distance from an earlier one plus the motion since
    #: (the rounding of fcl's distances and of the motion bound, coordinates up to 1e4 m)
    UPPER_MARGIN = 1e-9

    def _since(self, a: int, b: int):
        """Bounds (m) of the distance of ``a`` and ``b`` from their last exact distance and the
        motion since (``mu``, :meth:`_bound`): ``(lower - mu, upper + mu + UPPER_MARGIN)``, or
        None before the first. The upper bound is inf unless that distance was found (a pair
        whose member was the nearest)."""
        last = self._exact.get((a, b))
        if last is None:
            return None
        d, A0, B0, up = last
        mu = self._motion(a, b, A0, B0)
        return d - mu, up + mu + self.UPPER_MARGIN

    def _bound(self, a: int, b: int) -> float:
        """Lower bound (m) of the distance of ``a`` and ``b`` from their last exact distance:
        ``d_last - mu``, ``mu`` bounding any surface point's travel since (:meth:`_motion`). A
        pure speed-up cache: a member is skipped only when it cannot beat the best distance so
        far, so the reported result is the same with or without it (not part of the FMU
        state). Valid because the distance of two rigid bodies changes by at most the sum of
        the largest displacements of their surface points."""
        since = self._since(a, b)
        return -math.inf if since is None else since[0]

    def _motion(self, a: int, b: int, A0: list, B0: list) -> float:
        """Bound (m) on the travel of any surface point of ``a`` and ``b`` from the transforms
        ``A0``, ``B0`` (rows) to their current ones: ``|t1 - t0| + ||R1 - R0||_F r`` per body,
        ``r`` its radius about the body origin."""
        mu = 0.0
        radius = self._radius_list
        for X0, i in ((A0, a), (B0, b)):
            X1 = self._rows(i)
            if X1 is X0:
                continue  # not moved since
            # |(R1 - R0) p + t1 - t0| <= |t1 - t0| + ||R1 - R0||_F |p|  (Frobenius >= spectral norm)
            t, f = _face_shift(X0, X1)
            if t or f:
                mu += t + f * radius[i]
        return mu

    #: m; the body-frame gap must beat the best distance by this much to skip a query (it can
    #: equal the exact distance, e.g. a box face parallel to a face that bounds the other mesh)
    FRAME_GAP_MARGIN = 1e-9

    def _frame_gap(self, a: int, b: int) -> float:
        """Lower bound (m) of the distance of ``a`` and ``b``: in the frame of each of the two
        bodies that is rotated and not smaller than the other (bounding spheres), the gap
        between its local AABB and the box that bounds the other body's local AABB there
        (centre ``M c + p``, half extents ``|M| h``: the box of its 8 corners; the larger of
        the two gaps). Both boxes contain their body, so the gap cannot exceed the distance;
        unlike the world-AABB gap it does not grow loose when a body is rotated (a tank at
        yaw 2.2 rad). Scalar code on the list forms of the transforms: a bound, compared with
        margins far above its rounding (``FRAME_GAP_MARGIN``, ``SEPARATED``)."""
        best = -math.inf
        radius, rows = self._sphere_r, self._rows
        for f, o in ((a, b), (b, a)):
            if radius[o] > radius[f] or self._unrotated[f]:
                continue  # a larger body's box in a smaller one's frame is rarely tighter
            F, O = rows(f), rows(o)
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

    def _gap(self, a: int, b: int) -> float:
        """AABB gap of two bodies (m, 0 if overlapping), scalar code for the per-candidate path."""
        (alo, ahi), (blo, bhi) = self._aabb_lists(a), self._aabb_lists(b)
        g = 0.0
        for k in range(3):
            d = max(blo[k] - ahi[k], alo[k] - bhi[k], 0.0)
            g += d * d
        return math.sqrt(g)

    def _distance_result(self, res: "fcl.DistanceResult") -> PairResult:
        pb, pa = (np.array(p, float) for p in res.nearest_points)  # computed as (member, a)
        if self._a_first:
            pa, pb = pb, pa
        n = pb - pa
        norm = norm3(n)
        return PairResult(False, float(max(res.min_distance, 0.0)), 0.0, pa, n / norm if norm > 0 else n)

    # -- one pair ------------------------------------------------------------------------
    def _evaluate(self, pair: PairSpec, dt: float) -> Tuple[PairResult, int, int]:
        a = pair.a
        mask, stat, dyn, use_tree = self._pair_parts[id(pair)]
        # the fcl transforms of the pair's moved bodies are set before the first fcl call
        # (a pair whose members all turn out far needs none)
        self._pair_now = self._pair_sync[id(pair)]
        self._member_mask = mask
        self._use_tree = use_tree
        counts = [0, 0]  # candidates, narrow-phase tests
        results: List[Tuple[int, PairResult]] = []
        obj_a = self.objs[a]
        # broad phase (AABB overlap): static members through the tree, dynamic ones directly
        cands: List[int] = []
        if use_tree:
            self._sync(self._pair_now)
            self.manager.collide(obj_a, None, self._collector(cands))  # (the callbacks take no data)
        # members checked directly (dynamic ones, and static ones outside the tree): one AABB
        # gap computation serves the broad phase and the nearest-member search (the gaps of
        # aabb_gap, computed per member in scalar code: the same numbers)
        small = self._small_list[id(pair)]
        gaps = None
        if small:
            gap = self._gap
            gaps = [gap(a, b) for b in small]
            cands += [b for b, g in zip(small, gaps) if g <= 0]
            if not use_tree:  # every member's gap is known: what the far-pair skip needs
                self._last_gap = min(gaps)
        if cands:
            self._sync(self._pair_now)
        seen = set()
        for b in cands:
            if b in seen:
                continue
            seen.add(b)
            counts[0] += 1
            counts[1] += 1
            if self._separated(a, b):
                continue  # fcl.collide would find no intersecting triangles: no contact
            hit = self._collide(a, b)
            if hit is not None:
                results.append((b, hit))
        if not results:
            results = self._nearest(a, small, gaps, counts)
        # no member within max_distance: the base class reports distance = max_distance
        res = aggregate(results, self.config.max_distance)
        if self.config.ccd and self._moved_now(a):
            prev = self._previous
            held = res.in_contact and prev is not None and prev.in_contact
            if held:  # the contact held from the start of the step
                res.toi = 0.0
            elif self._fast(a):  # _travel(a) > ccd_fast * thin
                res.toi = self._time_of_impact(a, stat, dyn, counts, dt)
            elif res.in_contact:
                if prev is None or prev.distance < 0:
                    res.toi = 0.0
                else:  # signed distance linear over the step: d0 -> -depth
                    res.toi = dt * prev.distance / (prev.distance + max(res.depth, 1e-12))
        return res, counts[0], counts[1]

    def _nearest(self, a, small, gaps, counts) -> List[Tuple[int, PairResult]]:
        """Nearest member: pruned tree traversal for static members, direct (nearest AABB gap
        first, ``gaps`` of the members ``small``) for the others."""
        mask, obj_a = self._member_mask, self.objs[a]
        res = fcl.DistanceResult(self.config.max_distance
                                 if math.isfinite(self.config.max_distance) else 1.7976931348623157e308)
        best = [-1]
        if gaps is not None and min(gaps) < res.min_distance:
            for b, gap in sorted(zip(small, gaps), key=lambda bg: bg[1]):
                if gap >= res.min_distance:
                    break
                counts[0] += 1
                counts[1] += 1
                if self._distance(a, b, res):
                    best[0] = b
        if self._use_tree:
            by_pose, key = self._by_pose, self._key

            def on_near(o1, o2, _data):
                for b in by_pose.get(key(o1), ()) or by_pose.get(key(o2), ()):
                    if mask[b]:
                        counts[0] += 1
                        counts[1] += 1
                        if self._distance(a, b, res):
                            best[0] = b
                d = res.min_distance
                return d <= 0, d

            self.manager.distance(obj_a, None, on_near)
        if best[0] < 0:
            return []
        return [(best[0], self._distance_result(res))]

    # -- time of impact -------------------------------------------------------------------
    def _time_of_impact(self, a, stat, dyn, counts, dt) -> float:
        T0, T1 = self._prev_T[a], self._T[a]
        # swept AABB of a over the step (padded by the rotation's chord at the bounding radius;
        # scalar code per coordinate, the numbers of the array expressions)
        ang = rotation_angle(T1[:3, :3] @ T0[:3, :3].T)
        pad = 2 * self._radius_list[a] * math.sin(min(ang, math.pi) / 2)
        box_lo, box_hi = self._aabb_lists(a)
        R0, R1 = self._prev_rows[a], self._T_rows[a]  # T0, T1 as lists (a moved in this query)
        lo, hi = [], []
        for k in range(3):
            shift = R0[k][3] - R1[k][3]
            lo.append(min(box_lo[k], box_lo[k] + shift) - pad)
            hi.append(max(box_hi[k], box_hi[k] + shift) + pad)
        cands = []
        for b in dyn.tolist():
            blo, bhi = self._aabb_lists(b)
            if all(blo[k] <= hi[k] and bhi[k] >= lo[k] for k in range(3)):
                cands.append(b)
        if len(stat):
            probe = fcl.CollisionObject(fcl.Box(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]),
                                        fcl.Transform(_EYE3, [(lo[k] + hi[k]) / 2 for k in range(3)]))
            found: List[int] = []
            self.manager.collide(probe, None, self._collector(found))
            cands += sorted(set(found))
        toi = math.inf
        prev = self._previous
        for b in cands:
            counts[0] += 1
            # the distance at the start of the step is known for the previous nearest member,
            # and is 0 for the previous contact's partner (it was in contact there: counted as
            # the narrow-phase test whose answer is known, as _separated's candidates are)
            d0 = None
            if prev is not None and prev.partner == b:
                if prev.in_contact:
                    d0 = 0.0
                    counts[1] += 1
                elif prev.distance >= 0:
                    d0 = prev.distance
            s = self._advance(a, b, counts, min(toi, 1.0), d0)
            if s is not None:
                toi = min(toi, s)
        return toi * dt if math.isfinite(toi) else -1.0

    def _speed(self, i: int, path: Slerp, T0: np.ndarray, T1: np.ndarray) -> float:
        """Bound (m per unit fraction of the step) on the displacement of any surface point of
        body ``i`` along its interpolated motion ``path`` from ``T0`` to ``T1``: ``|t1 - t0| +
        theta rho``, ``rho`` the largest distance of the body's hull vertices from the rotation
        axis through its origin (a point at distance ``rho`` from the axis, turned by
        ``dtheta``, moves by the chord ``2 rho sin(dtheta / 2) <= rho dtheta``; the hull
        contains the body and the distance from an axis is convex). For a body turning about
        one axis this is tighter than ``theta`` times its radius about the origin (an avatar
        box 4 x 2 x 4.4 m turning about the vertical: 2.24 m instead of 3.14 m), so conservative
        advancement takes longer steps."""
        trans = norm3(T1[:3, 3] - T0[:3, 3])
        if path.axis is None:
            return trans
        u = T0[:3, :3].T @ path.axis  # the axis in the body frame
        hull = self._hull[i]
        along = hull @ u
        rho2 = float(np.max(np.einsum("ij,ij->i", hull, hull) - along * along))
        return trans + path.ang * math.sqrt(max(rho2, 0.0))

    def _advance(self, a: int, b: int, counts, s_max: float, d0: float | None = None) -> float | None:
        """Conservative advancement of pair (a, b) over the step; first contact fraction.

        ``d0``: the distance at the start of the step when already known (saves a query)."""
        A0, A1, B0, B1 = self._prev_T[a], self._T[a], self._prev_T[b], self._T[b]
        path_a, path_b = Slerp(A0, A1), Slerp(B0, B1)  # the interpolated motions
        mu = self._speed(a, path_a, A0, A1) + self._speed(b, path_b, B0, B1)
        if d0 is not None:  # the first iteration of the loop below, before any fcl object is made
            if d0 <= self.toi_tol:
                return 0.0
            if mu <= 0 or 0.0 + d0 / mu > s_max:
                return None
        oa = fcl.CollisionObject(self.dgeoms[self.scene.bodies[a].mesh_key], fcl_transform(A0))
        ob = fcl.CollisionObject(self.dgeoms[self.scene.bodies[b].mesh_key], fcl_transform(B0))
        req = fcl.DistanceRequest()
        # a static chunked partner: its chunks at its (fixed) pose, a's pose interpolated; a
        # body that keeps the whole-mesh query (more than CHUNK_OTHER_MAX_FACES triangles)
        # keeps it here too (module docstring)
        chunks = self._body_chunks[b] if not self.is_dynamic[b] and self._chunk_partner[a] else None
        if chunks is not None:
            tag, tf = self._chunk_tf(b)
            hull, box_c, box_h = self._hull[a], self._box_c[a], self._box_h[a]
            path_b = None  # b at its static pose B1 (its chunks' transform)
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
                    # the distance is at most the last one plus the motion since (chunked_distance's
                    # within: only the chunks nearer than that are bounded)
                    res = fcl.DistanceResult()
                    chunked_distance(chunks, tag, tf, B1, TA, (hull, box_c, box_h), oa, False, req, res, within)
                    d = res.min_distance
            if d <= self.toi_tol:
                return s
            if mu <= 0:
                return None
            s_last = s
            s += d / mu
            if s > s_max:
                return None
            # no surface point of a or b moves farther than mu (s - s_last) between the two poses
            # (mu bounds both): the distance (each chunk's, the chunked query's within) changed
            # by at most that, plus the rounding margins
            motion = mu * (s - s_last) * (1.0 + self.CA_MOTION_REL) + self.CA_MOTION_ABS
            within = d + motion
            TA = path_a.at(s)
            oa.setTransform(fcl_transform(TA))
            if path_b is not None:
                ob.setTransform(fcl_transform(path_b.at(s)))
        return s
