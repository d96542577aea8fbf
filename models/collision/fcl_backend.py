"""Backend ``fcl``: python-fcl BVHs, a dynamic AABB tree broad phase, exact distances.

Per monitored pair ``a vs members`` (shared BVHs and the static bodies' tree:
:mod:`.fcl_objects`):

* broad phase: the tree lists the static members whose AABB overlaps ``a``'s; dynamic members
  (and small static groups) are checked directly by their AABB gaps;
* each candidate gets ``fcl.collide`` with contacts (depth = the deepest contact's
  ``penetration_depth``), unless a lower bound of its distance (:mod:`.pair_cache`, the
  body-frame box gap) proves it apart; it then counts as tested without contact;
* without contact, the nearest member: the tree's pruned distance traversal, each exact
  ``fcl.distance`` on the distance triangulation (:mod:`.fans`) skipped when the AABB gap or
  a lower bound reaches the best so far (at first ``max_distance``); a body of at most
  ``CHUNK_OTHER_MAX_FACES`` triangles against a large mesh goes chunk by chunk (:mod:`.chunks`);
* time of impact for a body that moved (:mod:`.toi`): a contact that held from the start
  gets 0; a fast mover conservative advancement; a slow mover entering contact
  ``toi = h d0 / (d0 + depth)`` from the distance before and the depth after the step.

Far pairs are skipped by the base class's far-pair skip (:mod:`.far`).
"""
from __future__ import annotations

import logging
import math
from typing import List, Tuple

import fcl
import numpy as np

from .backend import CollisionBackend, PairResult, PairSpec, aggregate
from .chunks import chunked_distance
from .fcl_objects import BodyShapes, FclObjects, bvh_model, fcl_transform
from .geometry import norm3
from .pair_cache import PairDistances
from .toi import TimeOfImpact

log = logging.getLogger(__name__)

__all__ = ["FclBackend", "bvh_model", "fcl_transform"]


class FclBackend(CollisionBackend):
    """Exact collision, distance, penetration depth and time of impact with python-fcl."""

    name = "fcl"
    FAR_SKIP = True
    #: m; a lower bound of a candidate's distance above this proves it is not in contact (far
    #: above the rounding of fcl's triangle tests at coordinates of 1e2..1e3 m)
    SEPARATED = 1e-6

    def _setup(self) -> None:
        scene = self.scene
        self.fclo = FclObjects(scene, self.frames, self.arrays, self.config.max_contacts)
        self.shapes = BodyShapes(scene, self.fclo, self.bounds.local, self.arrays.T(), self.config.chunk_faces)
        self.exact = PairDistances(self.frames, self.shapes.radius)
        self.toi = TimeOfImpact(self.config, self.frames, self.arrays, self.bounds, self.fclo, self.shapes, scene,
                                self.shortcuts.toi_pretests)
        n_static = len(self.fclo.static_idx)
        #: per pair: member mask, static members, dynamic members, whether the tree serves it,
        #: the members checked directly, the dynamic bodies whose fcl transform it needs
        self._pair_parts = {}
        for pair in self.pairs:
            mask = np.zeros(self.n, bool)
            mask[pair.members] = True
            mask[pair.a] = False
            members = pair.members[mask[pair.members]]
            stat = members[~self.is_dynamic[members]]
            # the tree serves groups that are all static bodies or larger than 8
            use_tree = len(stat) > 8 or (len(stat) > 0 and len(stat) == n_static)
            dyn = members[self.is_dynamic[members]]
            small = np.concatenate([dyn, [] if use_tree else stat]).astype(int).tolist()
            sync = ([int(pair.a)] if self.is_dynamic[pair.a] else []) + dyn.tolist()
            self._pair_parts[id(pair)] = (mask, stat, dyn, use_tree, small, sync)
        self._pair_now: List[int] = []  # the evaluated pair's bodies to sync before an fcl call
        self._a_first = False  # the nearest member's distance was computed with a first

    def _needs_toi(self, a: int) -> bool:
        return self.toi.needs(a)

    _far_gap_known = True

    def _far_gap(self, k: int, pair: PairSpec) -> float | None:
        """The smallest AABB gap of the members checked directly; None for a pair served by
        the tree (its distance traversal may count a candidate)."""
        parts = self._pair_parts[id(pair)]
        if parts[3]:
            return None
        return min(self.bounds.gap(pair.a, b) for b in parts[4])

    def _separated(self, a: int, b: int) -> bool:
        """A broad-phase candidate is provably not in contact: the pair cache's lower bound or
        the body-frame box gap exceeds ``SEPARATED`` (counted as a narrow-phase test)."""
        return (self.exact.bound(a, b) > self.SEPARATED
                or self.shapes.frame_gap(a, b, self.frames.rows) > self.SEPARATED)

    # -- narrow phase -------------------------------------------------------------------
    def _collide(self, a: int, b: int, obj_b=None) -> PairResult | None:
        # member first, as python-fcl's manager callbacks call it: fcl's BVH-BVH traversal
        # is far cheaper with the large tree first (tank vs missile)
        res = fcl.CollisionResult()
        fcl.collide(obj_b if obj_b is not None else self.fclo.objs[b], self.fclo.objs[a], self.fclo.creq, res)
        if not res.is_collision:
            return None
        c = max(res.contacts, key=lambda c: c.penetration_depth)
        n = -np.asarray(c.normal, float)  # fcl's normal points from its first object (b) to a
        return PairResult(True, 0.0, float(max(c.penetration_depth, 0.0)), np.asarray(c.pos, float).copy(),
                          n / (norm3(n) or 1.0))

    def _distance(self, a: int, b: int, res: "fcl.DistanceResult") -> bool:
        """Exact distance of (a, b) into a shared result (it keeps the smallest distance and its
        nearest points); True when ``b`` became the nearest. Skipped when the AABB gap, the
        pair cache's lower bound or the body-frame box gap reaches the best so far (checks
        left out when the pair cache's upper bound is below it: none could skip)."""
        before, fclo, shapes = res.min_distance, self.fclo, self.shapes
        bounds = self.shortcuts.distance_bounds
        since = self.exact.since(a, b) if bounds else None
        if since is None or since[1] >= before:  # (else it is nearer than the best: no bound can skip it)
            if self.bounds.gap(a, b) >= before:
                return False
            if bounds and ((since is not None and since[0] >= before)
                           or shapes.frame_gap(a, b, self.frames.rows) >= before + shapes.FRAME_GAP_MARGIN):
                return False
        # the larger BVH first: fcl's traversal is cheaper (member first otherwise, see _collide)
        fclo.sync(self._pair_now)
        faces = shapes.faces
        if faces[a] > faces[b]:
            a_first, big, small = True, a, b
        else:
            a_first, big, small = False, b, a
        chunks = shapes.chunks[big]
        if chunks is None or not shapes.chunk_partner[small]:
            d = up = fcl.distance(fclo.dobj(big), fclo.dobj(small), fclo.dreq, res)
            if not up >= 0:  # (fcl's -1: no distance, no bound)
                up = math.inf
        else:  # the same triangle pairs, chunk by chunk (module docstring of .chunks)
            tag, tf = fclo.chunk_tf(big)
            d = chunked_distance(chunks, tag, tf, self.arrays.T_of(big), self.arrays.T_of(small),
                                 (shapes.hull[small], shapes.box_c[small], shapes.box_h[small]), fclo.dobj(small), True,
                                 fclo.dreq, res, math.inf if since is None else since[1])
            # its distance when it became the nearest, else no bound above it
            up = res.min_distance if 0 <= res.min_distance < before else math.inf
        self.exact.store(a, b, d, up)
        if res.min_distance < before:
            self._a_first = a_first
            return True
        return False

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
        mask, stat, dyn, use_tree, small, self._pair_now = self._pair_parts[id(pair)]
        fclo = self.fclo
        # (the fcl transforms of the pair's moved bodies are set before the first fcl call)
        counts = [0, 0]  # candidates, narrow-phase tests
        results: List[Tuple[int, PairResult]] = []
        obj_a = fclo.objs[a]
        # broad phase (AABB overlap): static members through the tree, dynamic ones directly
        cands: List[int] = []
        if use_tree:
            fclo.sync(self._pair_now)
            fclo.manager.collide(obj_a, None, fclo.collector(cands, mask))  # (the callbacks take no data)
        # members checked directly (dynamic ones, and static ones outside the tree): one AABB
        # gap computation serves the broad phase and the nearest-member search (the gaps of
        # aabb_gap, computed per member in scalar code: the same numbers)
        gaps = None
        if small:
            gap = self.bounds.gap
            gaps = [gap(a, b) for b in small]
            cands += [b for b, g in zip(small, gaps) if g <= 0]
            if not use_tree:  # every member's gap is known: what the far-pair skip needs
                self._last_gap = min(gaps)
        if cands:
            fclo.sync(self._pair_now)
        seen = set()
        for b in cands:
            if b in seen:
                continue
            seen.add(b)
            counts[0] += 1
            counts[1] += 1
            if self.shortcuts.distance_bounds and self._separated(a, b):
                continue  # fcl.collide would find no intersecting triangles: no contact
            hit = self._collide(a, b)
            if hit is not None:
                results.append((b, hit))
        if not results:
            results = self._nearest(a, small, gaps, counts, mask, use_tree)
        # no member within max_distance: the base class reports distance = max_distance
        res = aggregate(results, self.config.max_distance)
        if self.config.ccd and self.frames.moved_now(a):
            prev = self._previous
            held = res.in_contact and prev is not None and prev.in_contact
            if held:  # the contact held from the start of the step
                res.toi = 0.0
            elif self._fast(a):  # a fast mover (.toi)
                res.toi = self.toi.first_contact(a, stat, dyn, mask, counts, dt, prev)
            elif res.in_contact:
                if prev is None or prev.distance < 0:
                    res.toi = 0.0
                else:  # signed distance linear over the step: d0 -> -depth
                    res.toi = dt * prev.distance / (prev.distance + max(res.depth, 1e-12))
        return res, counts[0], counts[1]

    def _nearest(self, a, small, gaps, counts, mask, use_tree) -> List[Tuple[int, PairResult]]:
        """Nearest member: pruned tree traversal for static members, direct (nearest AABB gap
        first, ``gaps`` of the members ``small``) for the others."""
        obj_a = self.fclo.objs[a]
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
        if use_tree:
            by_pose, key = self.fclo.by_pose, self.fclo.key

            def on_near(o1, o2, _data):
                for b in by_pose.get(key(o1), ()) or by_pose.get(key(o2), ()):
                    if mask[b]:
                        counts[0] += 1
                        counts[1] += 1
                        if self._distance(a, b, res):
                            best[0] = b
                d = res.min_distance
                return d <= 0, d

            self.fclo.manager.distance(obj_a, None, on_near)
        if best[0] < 0:
            return []
        return [(best[0], self._distance_result(res))]
