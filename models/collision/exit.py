"""Horizontal exit of a deep contact: the shortest move out of a union of convex parts (2-D).

fcl's contacts are triangle-pair contacts: depth and normal of the deepest one describe two
triangles, not how far or which way the first body must move to leave its partner. For a
``(horizontal)`` pair (a ground vehicle whose box spans the obstacles' height):

* each body is the union of its convex parts (connected components of its mesh, each taken
  as its convex hull), projected on the ground plane: convex polygons (world frame);
* the first body's polygon ``A`` overlaps part ``B_j`` after a move ``d`` iff ``d`` lies in
  the convex polygon ``M_j = B_j (+) (-A)`` (Minkowski difference); the exit is the shortest
  ``d`` outside every ``M_j``: the point of the boundary of their union nearest the origin
  (the translational penetration depth of the non-convex union, e.g. Kim et al., "Fast
  penetration depth computation for physically-based animation", SCA 2002). ``depth = |d|``,
  ``normal = d / |d|``: for one convex part the nearest face's normal, in a concave corner
  (a box against a hull's front face and a barrel's side) the diagonal out of both.
"""
from __future__ import annotations

from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

__all__ = ["convex_parts", "polygon", "edge_normals", "overlaps", "minkowski_difference", "exit_2d", "Footprints"]

#: m; overlaps of at most this along some axis count as touching, not overlapping
TOUCH = 1e-9


def convex_parts(mesh) -> List[np.ndarray]:
    """Vertices (body frame, (k, 3) m) of the convex hull of each connected component of a
    trimesh ``mesh`` (a component that qhull cannot hull, e.g. a flat one, keeps its vertices)."""
    out = []
    for part in mesh.split(only_watertight=False) or [mesh]:
        v = np.asarray(part.vertices, float)
        try:
            v = np.asarray(part.convex_hull.vertices, float)
        except Exception:   # degenerate component
            pass
        out.append(v)
    return out


#: relative tolerance of :func:`polygon`: a point within this times the largest coordinate of
#: the line through its neighbours is no vertex (qhull's merging of nearly collinear edges)
COLLINEAR = 1e-12


def polygon(points: np.ndarray) -> np.ndarray:
    """Convex hull (counter-clockwise vertices, (m, 2)) of 2-D ``points`` (k, 2); fewer than
    three points or collinear ones: the points themselves.

    Andrew's monotone chain over the points sorted by x, then y: the lower and the upper chain,
    a point dropped while it is not left of the line from the one before to the next by more
    than :data:`COLLINEAR` (duplicates and nearly collinear points are no vertices, as in
    qhull's hull); the vertices are input points, the first the leftmost (then lowest).
    """
    P = np.asarray(points, float)
    if len(P) < 3:
        return P
    pts = P[np.lexsort((P[:, 1], P[:, 0]))].tolist()
    tol = COLLINEAR * (float(np.abs(P).max()) or 1.0)
    hull = _chain(pts, tol)[:-1] + _chain(pts[::-1], tol)[:-1]
    return np.array(hull) if len(hull) >= 3 else P


def _chain(pts: list, tol: float) -> list:
    """One half of the monotone chain: the points of ``pts`` (sorted) that turn left."""
    out: list = []
    for p in pts:
        while len(out) >= 2:
            (ox, oy), (ax, ay) = out[-2], out[-1]
            ex, ey = p[0] - ox, p[1] - oy
            if (ax - ox) * ey - (ay - oy) * ex > tol * (abs(ex) + abs(ey)):
                break
            out.pop()
        out.append(p)
    return out


def edge_normals(poly: np.ndarray) -> np.ndarray:
    """Unit outward normals (m, 2) of the edges of a counter-clockwise convex polygon (m, 2)
    (degenerate edges dropped)."""
    return _edges(poly)[0]


def _edges(poly: np.ndarray):
    """Outward unit normals (m, 2) of a counter-clockwise convex polygon's edges and their
    offsets ``max(P . n) = P_k . n_k`` (m,) (the edge's own vertex: no product with the rest)."""
    e = np.roll(poly, -1, axis=0) - poly
    n = np.c_[e[:, 1], -e[:, 0]]
    L = np.hypot(n[:, 0], n[:, 1])
    keep = L > 1e-12
    n = n[keep] / L[keep, None]
    return n, np.einsum("ij,ij->i", poly[keep], n)


def _part(p) -> tuple:
    """A part as (polygon, normals, offsets) (offsets computed when given as (polygon, normals))."""
    return p if len(p) == 3 else (p[0], p[1], (p[0] @ p[1].T).max(0))


def overlaps(A: np.ndarray, nA: np.ndarray, B: np.ndarray, nB: np.ndarray, offB=None) -> bool:
    """Convex polygons ``A``, ``B`` (with their outward edge normals; ``offB`` the offsets
    ``max(B . nB)``) overlap by more than ``TOUCH``: no edge of either has the other polygon
    entirely outside it (separating-axis theorem for convex polygons; touching is apart)."""
    offB = (B @ nB.T).max(0) if offB is None else offB
    if np.any((A @ nB.T).min(0) >= offB - TOUCH):
        return False
    return not np.any((B @ nA.T).min(0) >= (A @ nA.T).max(0) - TOUCH)


def minkowski_difference(B: np.ndarray, A: np.ndarray) -> np.ndarray:
    """Counter-clockwise vertices of ``B (+) (-A)`` (convex polygons (m, 2), (k, 2), both
    counter-clockwise): the translations ``d`` at which ``A + d`` meets ``B``.

    The edges of both (those of ``-A`` are ``A``'s reversed) merged by angle and summed from
    the sum of the two lowest (then leftmost) vertices; edges shorter than 1e-12 m dropped.
    """
    out = []
    for P in (np.asarray(B, float), -np.asarray(A, float)):
        k = int(np.lexsort((P[:, 0], P[:, 1]))[0])        # lowest, then leftmost
        P = np.roll(P, -k, axis=0)
        out.append((P[0], np.roll(P, -1, axis=0) - P))
    e = np.concatenate([out[0][1], out[1][1]])
    e = e[np.hypot(e[:, 0], e[:, 1]) > 1e-12]
    ang = np.mod(np.arctan2(e[:, 1], e[:, 0]), 2.0 * np.pi)
    V = out[0][0] + out[1][0] + np.cumsum(e[np.argsort(ang, kind="stable")], axis=0)
    return np.roll(V, 1, axis=0)      # (the last partial sum closes the loop: the start)


def _segments_cross(P: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """Intersection points (n, 2) of the edges of the closed polygons ``P`` and ``Q``."""
    a, r = P, np.roll(P, -1, axis=0) - P
    c, s = Q, np.roll(Q, -1, axis=0) - Q
    den = r[:, None, 0] * s[None, :, 1] - r[:, None, 1] * s[None, :, 0]
    ca = c[None, :, :] - a[:, None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (ca[..., 0] * s[None, :, 1] - ca[..., 1] * s[None, :, 0]) / den
        u = (ca[..., 0] * r[:, None, 1] - ca[..., 1] * r[:, None, 0]) / den
    i, j = np.nonzero((den != 0.0) & (t >= 0.0) & (t <= 1.0) & (u >= 0.0) & (u <= 1.0))
    return a[i] + t[i, j, None] * r[i]


def _closest_on_edges(P: np.ndarray) -> np.ndarray:
    """The point of each edge of the closed polygon ``P`` (m, 2) nearest the origin (m, 2)."""
    r = np.roll(P, -1, axis=0) - P
    rr = np.einsum("ij,ij->i", r, r)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.clip(-np.einsum("ij,ij->i", P, r) / rr, 0.0, 1.0)
    t[rr == 0.0] = 0.0
    return P + t[:, None] * r


def exit_2d(A: np.ndarray, nA: np.ndarray, parts: Sequence[tuple]) -> Optional[Tuple[float, np.ndarray]]:
    """Shortest exit of the convex polygon ``A`` from the union of the convex polygons
    ``parts`` (module docstring): ``(depth m, unit normal (2,))``, ``A`` moved by ``depth``
    along the normal touches the parts and overlaps none; None when no part overlaps ``A``.

    The translations that leave ``A`` overlapping part ``j`` form the convex polygon
    ``M_j = B_j (+) (-A)``; the origin lies in their union ``U`` and the exit is the point of
    the boundary of ``U`` nearest the origin: the nearest point of some edge of some ``M_j``,
    a vertex, or a crossing of two edges of different ``M_j``, that lies inside no ``M_k``
    (exact for one convex part: the nearest face, its move computed from the supports as the
    separating-axis test does; in a concave corner a diagonal move).

    Parameters
    ----------
    A : ndarray, shape (k, 2)
        The moving body's polygon (counter-clockwise), ``nA`` its edge normals.
    parts : sequence of (polygon (m, 2), edge normals (m, 2)[, offsets (m,)])
        The obstacles' convex parts (counter-clockwise); parts apart from ``A`` count too
        (an exit does not end inside one).
    """
    parts = [_part(p) for p in parts]
    hit = [overlaps(A, nA, q[0], q[1], q[2]) for q in parts]
    if not any(hit):
        return None
    # the faces of each overlapped M_j: along each of its normals (and +nA) the move
    # max(B_j . n) - min(A . n) (a part's support along its own normals: its edge offsets)
    axes_a = np.concatenate([nA, -nA])
    dist, normal = [], []
    for (B, nB, offB), h in zip(parts, hit):
        if h:
            axes = np.concatenate([axes_a, nB])
            dist.append(np.concatenate([(B @ axes_a.T).max(0), offB]) - (A @ axes.T).min(0))
            normal.append(axes)
    points = [d[:, None] * n for d, n in zip(dist, normal)]
    # the vertices, the nearest points of the edges and the crossings of the edges of every M_j
    M = [minkowski_difference(q[0], A) for q in parts]
    halves = [_edges(P) for P in M]       # outward normals, offsets: inside M_k iff q . n < offset
    pts = M + [_closest_on_edges(P) for P in M]
    lo, hi = [P.min(axis=0) for P in M], [P.max(axis=0) for P in M]
    for i in range(len(M)):
        for j in range(i + 1, len(M)):
            if np.all(lo[i] <= hi[j]) and np.all(lo[j] <= hi[i]):
                pts.append(_segments_cross(M[i], M[j]))
    p = np.concatenate(pts)
    r = np.hypot(p[:, 0], p[:, 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        u = p / r[:, None]
    face = _nearest_free(np.concatenate(points), np.concatenate(dist), np.concatenate(normal), halves)
    point = _nearest_free(p, r, u, halves)
    # a face's move is computed as the separating-axis test does; a point (from the vertices'
    # sums) wins only when shorter beyond rounding: in a corner, where no face move is free
    best = face if point is None or (face is not None and face[0] <= point[0] + TOUCH) else point
    if best is None:
        raise AssertionError("exit_2d: no boundary point of the union found")   # (the union is bounded)
    return best


def _nearest_free(q: np.ndarray, dist: np.ndarray, normal: np.ndarray, halves: list):
    """The candidate moves ``q`` (n, 2) (lengths ``dist``, directions ``normal``): the shortest
    one (> 0) inside none of the convex polygons ``halves`` (outward normals, offsets), as
    ``(length, direction)``, or None."""
    order = np.argsort(dist, kind="stable")
    for start in range(0, len(order), 64):   # nearest first: the first not inside any M_k
        k = order[start:start + 64]
        free = dist[k] > 0.0
        for n, off in halves:
            free &= ~np.all(q[k] @ n.T < off - TOUCH, axis=1)
        if free.any():
            best = k[int(np.argmax(free))]
            return float(dist[best]), normal[best].copy()
    return None


class Footprints:
    """Ground-plane convex parts of a scene's bodies (static bodies' polygons kept)."""

    def __init__(self, scene) -> None:
        self.scene = scene
        self._parts: Dict[str, List[np.ndarray]] = {}
        self._static: Dict[int, list] = {}

    def _local(self, i: int) -> List[np.ndarray]:
        """The body-frame convex parts of body ``i``'s mesh (kept per mesh)."""
        key = self.scene.bodies[i].mesh_key
        local = self._parts.get(key)
        if local is None:
            local = self._parts[key] = convex_parts(self.scene.meshes[key])
        return local

    def parts(self, i: int, T: np.ndarray, static: bool) -> list:
        """(polygon, edge normals, offsets) of each part of body ``i`` at the world transform
        ``T`` (4, 4)."""
        if static and i in self._static:
            return self._static[i]
        R, t = T[:2, :3], T[:2, 3]
        out = []
        for v in self._local(i):
            P = polygon(v @ R.T + t)
            out.append((P, *_edges(P)))
        if static:
            self._static[i] = out
        return out

    def exit(self, a: int, Ta: np.ndarray, members: Sequence[Tuple[int, np.ndarray, bool]]
             ) -> Optional[Tuple[float, np.ndarray]]:
        """Shortest horizontal exit of body ``a`` (its convex hull's footprint at ``Ta``) from
        every part of ``members`` (body, transform, static), see :func:`exit_2d`."""
        v = np.concatenate(self._local(a))
        A = polygon(v @ Ta[:2, :3].T + Ta[:2, 3])
        parts = [p for b, T, st in members for p in self.parts(b, T, st)]
        return exit_2d(A, edge_normals(A), parts)

