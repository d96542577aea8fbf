"""Backend ``basis_point``: the thesis's basis-point scan-line detector (ch. 5).

For a monitored pair, body ``a`` plays the thesis's collision node CN and each member a
potential node O_i:

1. **Bounding-sphere cull** (§5.2.1, eq. 5-1/5-2): O_i is kept when the centre distance
   ``d <= R1 + R2``.
2. **Intersection region IRS** (§5.2.2): the overlap of the two world AABBs; none -> no contact.
   SP_a and SCN are the parts of O_i and CN inside the IRS.
3. **Basis points** (§5.4): per axis, DN = the largest integer below 1/ST (``dn_rule='strict'``,
   the text) or floor(1/ST) (``'floor'``, eq. 5-11 with equality as table 5-5 lists),
   SD = IRS extent / DN (eq. 5-7). For the X direction, DN.y x DN.z scan lines parallel to X
   (at the centres of the SD.y x SD.z grid, "first horizontal then vertical") are cast through
   each body (trimesh ray casting); the first and last hit inside the IRS are the left/right
   basis points XL, XR (one hit: both). Likewise Y and Z.
4. **Related points** (§5.5.1, eq. 5-12): for each SCN basis point and each of SP_a's six
   basis-point sets, the points within the direction's radius R = max of the two sampling
   densities across the scan lines (X: max(SD.y, SD.z)).
5. **Feature pairs** (§5.5.2-5.5.3): 1 related point -> point-point, 2 -> point-line (foot of
   the perpendicular must fall on the segment), >= 3 -> point-face by the "threading"
   triangulation (§5.6): related points grouped into rows of the main axis (Z for X scans,
   Z for Y scans, Y for Z scans) and ordered along the secondary axis; N = 1 -> a point or a
   polyline; N >= 2 with one point per row -> a vertical polyline (the special point-line
   case); otherwise, for consecutive rows, a fan from the lower row's first point to the upper
   row's consecutive pairs ("bottom-up") and a fan from the upper row's last point to the lower
   row's pairs ("top-down"); two single-point rows give a segment (special case 1); a
   single-point row between wider rows is the common apex of both fans (special case 2).
6. **Point-triangle test** (§5.6.3): project the point on the triangle's plane; it is inside
   when the angles S_i P S_{i+1} (eq. 5-13) sum to 2 pi; then d = |p - P|.
7. **Contact** when a feature distance ``d <= eps`` with eps = the larger sampling density of
   the scan direction (§5.5.3).

Outputs: ``in_contact``; ``distance`` = the smallest feature distance (an estimate of the
surface distance at the scan resolution; without features, the distance between the nearest
basis points, or the sphere / AABB gap when culled); ``depth`` is not defined by the method
and is 0; ``point`` = the related point (or foot / projection) of the nearest feature.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Dict, List, Tuple

import numpy as np
from scipy.spatial import cKDTree

from .backend import CollisionBackend, PairResult, PairSpec, aggregate
from .raycast import cast_rays, first_last_along

log = logging.getLogger(__name__)

__all__ = ["BasisPointBackend", "scan_counts", "BasisPoints", "threading_features",
           "point_in_triangle_angles"]

#: (scan axis, secondary axis, main axis) of the X, Y and Z scan directions (§5.6.1)
AXES = ((0, 1, 2), (1, 0, 2), (2, 0, 1))


def scan_counts(st: float, rule: str = "strict") -> int:
    """DN of eq. 5-11: the largest integer below 1/ST (``strict``) or floor(1/ST)."""
    x = 1.0 / st
    if abs(x - round(x)) < 1e-9:
        x = float(round(x))
        return max(1, int(x) - 1) if rule == "strict" else max(1, int(x))
    return max(1, int(math.floor(x)))


@dataclass
class BasisPoints:
    """Basis points of one body in an IRS: per scan axis the L and R point sets.

    ``pts[k][side]`` is an (p, 3) array, ``grid[k]`` the (p, 2) secondary / main scan-line
    indices of those points (shared by L and R).
    """

    pts: List[Tuple[np.ndarray, np.ndarray]]
    grid: List[np.ndarray]

    def all_points(self) -> np.ndarray:
        arrs = [p for pair in self.pts for p in pair if len(p)]
        return np.concatenate(arrs) if arrs else np.zeros((0, 3))

    def count(self) -> int:
        return int(sum(len(p) for pair in self.pts for p in pair))


def point_in_triangle_angles(P: np.ndarray, tri: np.ndarray, tol: float = 1e-6) -> np.ndarray:
    """Angle-sum inside test of eq. 5-13: sum of angles S_i P S_{i+1} equals 2 pi.

    P : (t, 3) points in the triangles' planes; tri : (t, 3, 3). Returns (t,) bool.
    """
    total = np.zeros(len(P))
    for i in range(3):
        u = tri[:, i] - P
        v = tri[:, (i + 1) % 3] - P
        nu, nv = np.linalg.norm(u, axis=1), np.linalg.norm(v, axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            c = np.einsum("ij,ij->i", u, v) / (nu * nv)
        ang = np.arccos(np.clip(np.nan_to_num(c, nan=1.0), -1.0, 1.0))
        # P on a vertex: inside
        ang = np.where((nu < 1e-12) | (nv < 1e-12), np.pi, ang)
        total += ang
    return np.abs(total - 2 * np.pi) < tol * 2 * np.pi


def threading_features(grid: np.ndarray) -> Tuple[List[Tuple[int, int]], List[Tuple[int, int, int]], List[int]]:
    """Threading triangulation of related points (§5.6).

    Parameters
    ----------
    grid : ndarray, shape (q, 2)
        (secondary, main) scan-line indices of the q >= 1 related points.

    Returns
    -------
    segments, triangles, points : lists of indices into the related points
    """
    order = np.lexsort((grid[:, 0], grid[:, 1]))
    rows: List[List[int]] = []
    last_main = None
    for i in order:
        if grid[i, 1] != last_main:
            rows.append([])
            last_main = grid[i, 1]
        rows[-1].append(int(i))
    segments: List[Tuple[int, int]] = []
    triangles: List[Tuple[int, int, int]] = []
    points: List[int] = []
    if len(rows) == 1:  # N = 1
        row = rows[0]
        if len(row) == 1:
            points.append(row[0])
        else:
            segments += list(zip(row[:-1], row[1:]))
        return segments, triangles, points
    if all(len(r) == 1 for r in rows):  # special point-line case: a vertical chain (fig. 5-18)
        chain = [r[0] for r in rows]
        return list(zip(chain[:-1], chain[1:])), triangles, points
    for low, up in zip(rows[:-1], rows[1:]):
        if len(low) == 1 and len(up) == 1:  # special case 1 (fig. 5-24)
            segments.append((low[0], up[0]))
            continue
        apex = low[0]  # bottom-up fan (fig. 5-20)
        triangles += [(apex, up[m], up[m + 1]) for m in range(len(up) - 1)]
        apex = up[-1]  # top-down fan (fig. 5-21); a single-point row is the apex (case 2)
        triangles += [(apex, low[m], low[m + 1]) for m in range(len(low) - 1)]
        if len(up) == 1 and len(low) >= 2:
            pass  # covered by the top-down fan from the single upper point
    return segments, triangles, points


@lru_cache(maxsize=65536)
def _threading_cached(key: bytes, n: int):
    """Threading of a related-point pattern as index arrays (segments, triangles, points)."""
    grid = np.frombuffer(key, dtype=np.int64).reshape(n, 2)
    segs, tris, pts = threading_features(grid)
    return (np.asarray(segs, int).reshape(-1, 2), np.asarray(tris, int).reshape(-1, 3),
            np.asarray(pts, int))


class BasisPointBackend(CollisionBackend):
    """Basis-point scan-line collision detection (thesis ch. 5)."""

    name = "basis_point"

    def _setup(self) -> None:
        self.dn = scan_counts(self.config.st, self.config.dn_rule)
        self.last_stats: Dict[str, float] = {}

    # -- §5.4 -----------------------------------------------------------------------------
    def basis_points(self, body: int, lo: np.ndarray, hi: np.ndarray) -> BasisPoints:
        """Scan-line basis points of ``body`` inside the IRS ``[lo, hi]`` (§5.4.2)."""
        ext = np.maximum(hi - lo, 1e-9)
        sd = ext / self.dn
        mesh, T = self.scene.mesh(body), self.T[body]
        origins, dirs, meta = [], [], []
        for k, u, v in AXES:
            ju = np.arange(self.dn)
            gu = lo[u] + (ju + 0.5) * sd[u]
            gv = lo[v] + (ju + 0.5) * sd[v]
            U, V = np.meshgrid(np.arange(self.dn), np.arange(self.dn), indexing="xy")  # horizontal first
            o = np.zeros((U.size, 3))
            o[:, k] = lo[k] - 1e-6 * ext[k] - 1e-9
            o[:, u] = gu[U.ravel()]
            o[:, v] = gv[V.ravel()]
            d = np.zeros_like(o)
            d[:, k] = 1.0
            origins.append(o)
            dirs.append(d)
            meta.append(np.stack([U.ravel(), V.ravel()], 1))
        O, D = np.concatenate(origins), np.concatenate(dirs)
        loc, idx = cast_rays(mesh, T, O, D)
        pts, grid = [], []
        n = self.dn * self.dn
        for a, (k, _, _) in enumerate(AXES):
            sel = (idx >= a * n) & (idx < (a + 1) * n)
            has, first, last = first_last_along(loc[sel], idx[sel] - a * n, k, n, lo[k], hi[k])
            pts.append((first[has], last[has]))
            grid.append(meta[a][has])
        return BasisPoints(pts, grid)

    # -- §5.5-5.6 -------------------------------------------------------------------------
    def features(self, scn: np.ndarray, sp: BasisPoints, sd: np.ndarray):
        """Related points of every SCN basis point among SP_a's sets and the distance of each
        feature pair. Returns arrays (d, eps, p, q) of all evaluated features."""
        ds, eps_l, ps, qs = [], [], [], []
        if len(scn) == 0:
            return [np.zeros(0)] * 2 + [np.zeros((0, 3))] * 2
        for a, (k, u, v) in enumerate(AXES):
            radius = max(sd[u], sd[v])  # per-axis radius rule and offset eps (§5.5.1, §5.5.3)
            grid = sp.grid[a]
            for side in (0, 1):
                S = sp.pts[a][side]
                if len(S) == 0:
                    continue
                tree = cKDTree(S)
                related = tree.query_ball_point(scn, radius)
                pp_p, pp_q, seg_p, seg_ab, tri_p, tri = [], [], [], [], [], []
                for i, rel in enumerate(related):
                    n_rel = len(rel)
                    if n_rel == 0:
                        continue
                    if n_rel == 1:  # point-point
                        pp_p.append(i)
                        pp_q.append(rel[0])
                    elif n_rel == 2:  # point-line
                        seg_p.append(np.array([i]))
                        seg_ab.append(np.array([rel]))
                    else:  # point-face: threading (memoised on the related points' pattern)
                        rel = np.asarray(rel)
                        g = grid[rel]
                        segs, tris, pts = _threading_cached((g - g.min(0)).tobytes(), n_rel)
                        if len(segs):
                            seg_p.append(np.full(len(segs), i))
                            seg_ab.append(rel[segs])
                        if len(tris):
                            tri_p.append(np.full(len(tris), i))
                            tri.append(rel[tris])
                        if len(pts):
                            pp_p += [i] * len(pts)
                            pp_q += rel[pts].tolist()
                seg_p = np.concatenate(seg_p) if seg_p else []
                if len(seg_p):
                    seg_ab = np.concatenate(seg_ab)
                    seg_a, seg_b = seg_ab[:, 0], seg_ab[:, 1]
                tri_p = np.concatenate(tri_p) if tri_p else []
                if len(tri_p):
                    tri = np.concatenate(tri)
                if pp_p:
                    p, q = scn[pp_p], S[pp_q]
                    ds.append(np.linalg.norm(p - q, axis=1))
                    ps.append(p)
                    qs.append(q)
                if len(seg_p):
                    p, A, B = scn[seg_p], S[seg_a], S[seg_b]
                    AB = B - A
                    L2 = np.einsum("ij,ij->i", AB, AB)
                    with np.errstate(invalid="ignore", divide="ignore"):
                        t = np.einsum("ij,ij->i", p - A, AB) / L2
                    on = (L2 > 0) & (t >= 0) & (t <= 1)  # foot V on the segment, else no contact
                    V = A[on] + AB[on] * t[on, None]
                    ds.append(np.linalg.norm(p[on] - V, axis=1))
                    ps.append(p[on])
                    qs.append(V)
                if len(tri_p):
                    p, Tr = scn[tri_p], S[tri]
                    nrm = np.cross(Tr[:, 1] - Tr[:, 0], Tr[:, 2] - Tr[:, 0])
                    nn = np.linalg.norm(nrm, axis=1)
                    ok = nn > 1e-12
                    p, Tr, nrm = p[ok], Tr[ok], nrm[ok] / nn[ok, None]
                    h = np.einsum("ij,ij->i", p - Tr[:, 0], nrm)
                    P = p - h[:, None] * nrm  # projection on the plane
                    inside = point_in_triangle_angles(P, Tr)
                    ds.append(np.abs(h[inside]))
                    ps.append(p[inside])
                    qs.append(P[inside])
                n_new = sum(len(x) for x in ds) - sum(len(x) for x in eps_l)
                eps_l.append(np.full(n_new, radius))
        if not ds:
            return [np.zeros(0)] * 2 + [np.zeros((0, 3))] * 2
        return np.concatenate(ds), np.concatenate(eps_l), np.concatenate(ps), np.concatenate(qs)

    def _narrow(self, a: int, b: int, lo: np.ndarray, hi: np.ndarray) -> PairResult:
        sd = np.maximum(hi - lo, 1e-9) / self.dn
        bp_scn = self.basis_points(a, lo, hi)
        bp_sp = self.basis_points(b, lo, hi)
        scn = bp_scn.all_points()
        d, eps, p, q = self.features(scn, bp_sp, sd)
        self.last_stats = {"bp_scn": bp_scn.count(), "bp_sp": bp_sp.count(), "features": len(d),
                           "dn": self.dn}
        if len(d):
            hit = d <= eps
            k = int(np.argmin(np.where(hit, d - eps, d))) if hit.any() else int(np.argmin(d))
            dist = float(d.min())
            n = q[k] - p[k]
            nn = np.linalg.norm(n)
            normal = n / nn if nn > 1e-12 else self._centre_dir(a, b)
            return PairResult(bool(hit.any()), dist, 0.0, q[k].copy(), normal)
        sp_all = bp_sp.all_points()
        if len(scn) and len(sp_all):
            dd, j = cKDTree(sp_all).query(scn)
            i = int(np.argmin(dd))
            n = sp_all[j[i]] - scn[i]
            nn = np.linalg.norm(n)
            return PairResult(False, float(dd[i]), 0.0, scn[i].copy(),
                              n / nn if nn > 1e-12 else self._centre_dir(a, b))
        return PairResult(False, 0.0, 0.0, (lo + hi) / 2, self._centre_dir(a, b))

    def _centre_dir(self, a: int, b: int) -> np.ndarray:
        n = self.sphere_c[b] - self.sphere_c[a]
        nn = np.linalg.norm(n)
        return n / nn if nn > 0 else np.array([0.0, 0.0, 1.0])

    def _evaluate(self, pair: PairSpec, dt: float) -> Tuple[PairResult, int, int]:
        a, members = pair.a, pair.members
        self.ensure_bounds(np.append(members, a))
        # §5.2.1: bounding spheres, eq. 5-2
        dc = np.linalg.norm(self.sphere_c[members] - self.sphere_c[a], axis=1)
        near = dc <= self.sphere_r[a] + self.sphere_r[members]
        lower = math.inf
        if (~near).any():
            lower = float((dc[~near] - self.sphere_r[a] - self.sphere_r[members[~near]]).min())
        cands = members[near]
        # §5.2.2: AABBs and the IRS
        lo = np.maximum(self.aabb[cands, 0], self.aabb[a, 0])
        hi = np.minimum(self.aabb[cands, 1], self.aabb[a, 1])
        irs = np.all(lo <= hi, axis=1)
        if (~irs).any():
            lower = min(lower, float(self.aabb_gap(a, cands[~irs]).min()))
        results = []
        for j in np.flatnonzero(irs):
            results.append((int(cands[j]), self._narrow(a, int(cands[j]), lo[j], hi[j])))
        return aggregate(results, lower), len(cands), int(irs.sum())
