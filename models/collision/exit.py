"""Horizontal exit of a deep contact: depth and normal out of the nearest face (2-D SAT).

fcl's contacts are triangle-pair contacts: depth and normal of the deepest one describe two
triangles, not how far or which way the first body must move to leave its partner. For a
``(horizontal)`` pair (a ground vehicle whose box spans the obstacles' height):

* each body is the union of its convex parts (connected components of its mesh, each taken
  as its convex hull), projected on the ground plane: convex polygons (world frame);
* the partners' parts overlapping the first body's polygon ``A`` (separating-axis test) must
  all be left: along a unit ``n`` after ``push(n) = max_j (max(B_j . n) - min(A . n))``;
* the exit is the shortest over both signs of every edge normal of ``A`` and of the
  overlapping parts: ``depth = min_n push(n)``, ``normal = argmin`` (the exact penetration
  depth of two convex polygons; for several parts the shortest face-normal move clearing all).
"""
from __future__ import annotations

from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

__all__ = ["convex_parts", "polygon", "edge_normals", "overlaps", "exit_2d", "Footprints"]

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


def polygon(points: np.ndarray) -> np.ndarray:
    """Convex hull (counter-clockwise vertices, (m, 2)) of 2-D ``points`` (k, 2); fewer than
    three points or collinear ones: the points themselves."""
    from scipy.spatial import ConvexHull, QhullError  # (scipy.spatial: ~0.3 s to import, only on a contact)

    try:
        h = ConvexHull(points)
    except (QhullError, ValueError):
        return np.asarray(points, float)
    return np.asarray(points, float)[h.vertices]


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


def exit_2d(A: np.ndarray, nA: np.ndarray, parts: Sequence[tuple]) -> Optional[Tuple[float, np.ndarray]]:
    """Shortest exit of the convex polygon ``A`` from the convex polygons ``parts``
    (module docstring): ``(depth m, unit normal (2,))`` along which ``A`` moves, or None when
    no part overlaps ``A``.

    Candidate directions: both signs of ``A``'s edge normals and the outward edge normals of
    the overlapping parts (leaving a part through one of its faces); a part's support along
    its own normals is its edge offsets (no product of its vertices with its own normals).

    Parameters
    ----------
    A : ndarray, shape (k, 2)
        The moving body's polygon (counter-clockwise), ``nA`` its edge normals.
    parts : sequence of (polygon (m, 2), edge normals (m, 2)[, offsets (m,)])
        The obstacles' convex parts.
    """
    hit = [q for q in map(_part, parts) if overlaps(A, nA, q[0], q[1], q[2])]
    if not hit:
        return None
    blocks = [np.concatenate([nA, -nA])] + [nB for _, nB, _ in hit]
    support = [np.full(len(b), -np.inf) for b in blocks]
    for j, (B, _, offB) in enumerate(hit):
        for k, axes in enumerate(blocks):
            s_k = offB if k == j + 1 else (B @ axes.T).max(0)
            np.maximum(support[k], s_k, out=support[k])
    axes = np.concatenate(blocks)
    push = np.concatenate(support) - (A @ axes.T).min(0)
    k = int(np.argmin(push))
    return max(float(push[k]), 0.0), axes[k].copy()


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

