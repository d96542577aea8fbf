"""Backend ``honeycomb``: the thesis's ray-casting honeycomb space decomposition (ch. 4).

For a monitored pair, body ``a`` is the thesis's A and each member B:

1. **Depth direction**: the thesis projects on XOY with Z as depth (§4.3.1) and leaves the
   choice of plane open. A single plane misses contacts whose surfaces are parallel to the
   depth rays (a missile in a turret's top seen along Y), so by default
   (``honeycomb_axes='all'``) the detector runs on the three coordinate planes and reports a
   contact when any of them finds one; ``'separating'`` uses only the most separating axis of
   the two AABBs (largest gap or least overlap).
2. **Projection overlap** (§4.2.2, def. 1): the overlap of the projected AABBs; empty -> no
   collision (P(A) n P(B) = 0).
3. **Depth relation** (fig. 4-1) of the depth intervals [A_min, A_max], [B_min, B_max]:
   1 A before B, 2 B before A (disjoint), 3 B within A, 4 overlap with B first, 5 A within B,
   6 overlap with A first, 7 touching (A_max = B_min or B_max = A_min). Relations 3-6 (and 7)
   may collide, with D_max / D_min of §4.3.2: (B_max, B_min), (B_max, A_min), (A_max, A_min),
   (A_max, B_min). Because the detector predicts the next frame with the threshold d, 1 and 2
   stay candidates when the gap is <= d; the depth window is widened by d on both sides.
4. **Sub-boxes** BV(A), BV(B) (§4.3.2): the projection overlap x [D_min, D_max], split into
   ``cells_n x cells_m`` honeycomb cells (§4.4). In each cell ``rays_per_cell^2`` rays along the
   depth axis (the ray-cast depth buffer of §4.2.2) give the parts A_ij, B_ij inside the
   window; a cell without A_ij or B_ij has D_ij = -1 and cannot collide.
5. **Equal-ratio shrink** (§4.4.1, eq. 4-7): each cell's section starts on the sub-box face and
   moves towards the part, ``D_next = D_last (1 - ratio)`` with D measured to the far side of
   the part; no intersection -> continue (case 1); the section cut into the part (two or more
   intersections) -> step back and lower the ratio by 0.1 % (case 2); the section touches the
   part's extreme point within 0.1 % of the window depth -> stop (case 3).
6. **Threshold distance** (§4.4.2): d = the displacement of the moving body in the step. B's
   threshold line lies d in front of B_ij's section; D_ij(A) = distance from A_ij's section to
   it; collision when D_ij(A) <= 0, i.e. A_ij is within one step's travel of B_ij (the
   thesis's 0 <= D_ij(A)' <= d measured from the threshold line) or already overlaps it.

Outputs: ``distance`` = the smallest section gap over the cells (>= 0), ``depth`` = the
largest overlap of the sections along the depth axis, ``point`` = the centre of the nearest
cell between the sections, ``normal`` = +-depth axis from A to B.
"""
from __future__ import annotations

import logging
import math
from dataclasses import replace
from typing import Dict, Tuple

import numpy as np

from .backend import CollisionBackend, PairResult, PairSpec, aggregate
from .raycast import cast_rays

log = logging.getLogger(__name__)

__all__ = ["HoneycombBackend", "depth_relation", "equal_ratio_shrink"]


def depth_relation(a_min: float, a_max: float, b_min: float, b_max: float) -> int:
    """The depth relation 1..7 of fig. 4-1 (see the module docstring)."""
    if a_max == b_min or b_max == a_min:
        return 7
    if a_max < b_min:
        return 1
    if b_max < a_min:
        return 2
    if a_min <= b_min and b_max <= a_max:
        return 3
    if b_min <= a_min and a_max <= b_max:
        return 5
    if b_min < a_min:
        return 4
    return 6


def equal_ratio_shrink(start: np.ndarray, near: np.ndarray, far: np.ndarray, ratio: float = 0.05,
                       step: float = 0.001, tol: np.ndarray | float = 0.0, max_iter: int = 5000):
    """Equal-ratio shrink of eq. 4-7 for many cells at once.

    The section of each cell starts at ``start`` (the sub-box face) and approaches the part,
    whose extreme point (the side facing the section) is ``near`` and opposite side ``far``.
    Works for sections above (start >= near >= far) or below (start <= near <= far) the part.

    Returns
    -------
    section : ndarray
        Final section positions.
    iterations : int
    """
    sec = np.asarray(start, float).copy()
    near, far = np.broadcast_arrays(np.asarray(near, float), np.asarray(far, float))
    r = np.full(sec.shape, float(ratio))
    tol = np.broadcast_to(np.asarray(tol, float), sec.shape)
    sgn = np.sign(sec - far)
    active = (sgn != 0) & (np.abs(sec - near) > tol)
    it = 0
    while active.any() and it < max_iter:
        it += 1
        d_last = np.abs(sec - far)
        new = far + sgn * d_last * (1 - r)  # eq. 4-7
        gap = sgn * (new - near)  # > 0: still outside the part
        case1 = active & (gap > tol)
        case3 = active & (np.abs(gap) <= tol)
        case2 = active & (gap < -tol)
        sec = np.where(case1 | case3, new, sec)
        r = np.where(case2, r - step, r)
        done = case3 | (case2 & (r <= step / 2))
        active &= ~done
    return sec, it


class HoneycombBackend(CollisionBackend):
    """Honeycomb space-decomposition collision detection (thesis ch. 4)."""

    name = "honeycomb"
    #: fixed threshold d (m) instead of the step displacement (None: the thesis's rule)
    fixed_threshold: float | None = None

    def _setup(self) -> None:
        self.last_stats: Dict[str, float] = {}

    def _depth_axis(self, a: int, b: int) -> int:
        """The most separating world axis of the two AABBs (largest gap, or least overlap)."""
        ca, cb = self.aabb[a].mean(0), self.aabb[b].mean(0)
        half = (self.aabb[a, 1] - self.aabb[a, 0] + self.aabb[b, 1] - self.aabb[b, 0]) / 2
        return int(np.argmax(np.abs(cb - ca) - half))

    def threshold(self, a: int, b: int) -> float:
        """Threshold distance d (§4.4.2): the larger displacement of the two bodies in the step."""
        if self.fixed_threshold is not None:
            return float(self.fixed_threshold)
        da = np.linalg.norm(self.T[a, :3, 3] - self.prev_T[a, :3, 3])
        db = np.linalg.norm(self.T[b, :3, 3] - self.prev_T[b, :3, 3])
        return float(max(da, db))

    def _narrow(self, a: int, b: int) -> PairResult | None:
        """Run the detector with each configured depth axis; contact if any projection finds
        a colliding cell; distance = the smallest section gap (each is an upper bound)."""
        axes = [self._depth_axis(a, b)] if self.config.honeycomb_axes == "separating" else [0, 1, 2]
        best, stats = None, []
        for w in axes:
            r = self._narrow_axis(a, b, w)
            stats.append(dict(self.last_stats))
            if r is None:
                continue
            if best is None or (r.in_contact, r.depth, -r.distance) > (best.in_contact, best.depth, -best.distance):
                dist = min(best.distance, r.distance) if best is not None and not r.in_contact else r.distance
                best = replace(r, distance=dist)
            elif not best.in_contact:
                best.distance = min(best.distance, r.distance)
        self.last_stats = stats[0] if len(stats) == 1 else {
            "relation": [st["relation"] for st in stats], "axis": [st["axis"] for st in stats],
            "cells_full": sum(st["cells_full"] for st in stats), "threshold": stats[0]["threshold"],
            "rays": sum(st["rays"] for st in stats)}
        return best

    def _narrow_axis(self, a: int, b: int, w: int) -> PairResult | None:
        self.last_stats = {"relation": 0, "axis": w, "cells_full": 0, "threshold": 0.0, "rays": 0}
        u, v = [k for k in range(3) if k != w]
        A, B = self.aabb[a], self.aabb[b]
        # projection overlap (def. 1)
        lo_uv = np.maximum(A[0, [u, v]], B[0, [u, v]])
        hi_uv = np.minimum(A[1, [u, v]], B[1, [u, v]])
        if np.any(lo_uv > hi_uv):
            return None
        d = self.threshold(a, b)
        rel = depth_relation(A[0, w], A[1, w], B[0, w], B[1, w])
        d_min = max(A[0, w], B[0, w]) - d
        d_max = min(A[1, w], B[1, w]) + d
        gap0 = max(A[0, w], B[0, w]) - min(A[1, w], B[1, w])  # > 0: disjoint depth intervals
        self.last_stats = {"relation": rel, "axis": w, "cells_full": 0, "threshold": d, "rays": 0}
        if d_min > d_max:  # relations 1, 2 farther apart than the threshold
            return PairResult(False, float(gap0), 0.0, np.zeros(3), np.eye(3)[w])
        a_low = (A[0, w] + A[1, w]) < (B[0, w] + B[1, w])  # A below B along the depth axis
        n_, m_, k = self.config.cells_n, self.config.cells_m, self.config.rays_per_cell
        # ray grid: cells x k x k rays, parallel to the depth axis
        cu = (hi_uv[0] - lo_uv[0]) / n_
        cv = (hi_uv[1] - lo_uv[1]) / m_
        fu = (np.arange(n_ * k) + 0.5) / k
        fv = (np.arange(m_ * k) + 0.5) / k
        U, V = np.meshgrid(lo_uv[0] + fu * cu, lo_uv[1] + fv * cv, indexing="ij")
        cell = (np.arange(n_ * k)[:, None] // k) * m_ + (np.arange(m_ * k)[None, :] // k)
        n_rays = U.size
        O = np.zeros((n_rays, 3))
        O[:, u], O[:, v] = U.ravel(), V.ravel()
        O[:, w] = d_min - 1e-6 * max(d_max - d_min, 1.0) - 1e-9
        D = np.zeros((n_rays, 3))
        D[:, w] = 1.0
        cell = cell.ravel()
        part = {}
        for body in (a, b):
            loc, idx = cast_rays(self.scene.mesh(body), self.T[body], O, D)
            keep = (loc[:, w] >= d_min) & (loc[:, w] <= d_max) if len(loc) else np.zeros(0, bool)
            z, c = loc[keep, w], cell[idx[keep]]
            hi = np.full(n_ * m_, -np.inf)
            lo = np.full(n_ * m_, np.inf)
            np.maximum.at(hi, c, z)
            np.minimum.at(lo, c, z)
            part[body] = (lo, hi)
        (alo, ahi), (blo, bhi) = part[a], part[b]
        empty = ~(np.isfinite(ahi) & np.isfinite(bhi))
        depth_span = max(d_max - d_min, 1e-9)
        tol = 1e-3 * depth_span
        full = ~empty
        sec_a = np.full(n_ * m_, np.nan)
        sec_b = np.full(n_ * m_, np.nan)
        if full.any():
            # A's section starts on BV(A)'s face towards B and shrinks onto A_ij's facing extreme
            if a_low:
                sa, _ = equal_ratio_shrink(np.full(full.sum(), d_max), ahi[full], alo[full],
                                           self.config.shrink_ratio, self.config.shrink_step, tol)
                sb, _ = equal_ratio_shrink(np.full(full.sum(), d_min), blo[full], bhi[full],
                                           self.config.shrink_ratio, self.config.shrink_step, tol)
                gap = sb - sa
            else:
                sa, _ = equal_ratio_shrink(np.full(full.sum(), d_min), alo[full], ahi[full],
                                           self.config.shrink_ratio, self.config.shrink_step, tol)
                sb, _ = equal_ratio_shrink(np.full(full.sum(), d_max), bhi[full], blo[full],
                                           self.config.shrink_ratio, self.config.shrink_step, tol)
                gap = sa - sb
            sec_a[full], sec_b[full] = sa, sb
        D_ij = np.full(n_ * m_, -1.0)  # -1: empty cell (§4.4.2)
        if full.any():
            D_ij[full] = gap - d  # distance of A_ij's section to B's threshold line
        self.last_stats = {"relation": rel, "axis": w, "cells_full": int(full.sum()), "threshold": d,
                           "rays": 2 * n_rays}
        normal = np.eye(3)[w] * (1.0 if a_low else -1.0)
        if not full.any():
            return PairResult(False, float(max(gap0, 0.0)), 0.0, np.zeros(3), normal)
        gaps = np.full(n_ * m_, np.inf)
        gaps[full] = gap
        hit = full & (D_ij <= 0.0)
        j = int(np.argmin(gaps))
        iu, iv = divmod(j, m_)
        point = np.zeros(3)
        point[u] = lo_uv[0] + (iu + 0.5) * cu
        point[v] = lo_uv[1] + (iv + 0.5) * cv
        point[w] = (sec_a[j] + sec_b[j]) / 2
        return PairResult(bool(hit.any()), float(max(gaps[j], 0.0)), float(max(-gaps[j], 0.0)), point, normal)

    def _evaluate(self, pair: PairSpec, dt: float) -> Tuple[PairResult, int, int]:
        a, members = pair.a, pair.members
        self.ensure_bounds(np.append(members, a))
        gaps = self.aabb_gap(a, members)
        # candidates: AABBs within the threshold (projection overlap and depth relation follow)
        thr = np.array([self.threshold(a, int(b)) for b in members]) if len(members) <= 64 else \
            np.full(len(members), self.threshold(a, a))
        cand = members[gaps <= thr]
        lower = float(gaps[gaps > thr].min()) if (gaps > thr).any() else math.inf
        results, n_narrow = [], 0
        for b in cand:
            r = self._narrow(a, int(b))
            if r is None:
                lower = min(lower, float(self.aabb_gap(a, np.array([b]))[0]))
                continue
            n_narrow += 1
            results.append((int(b), r))
        return aggregate(results, lower), len(cand), n_narrow
