"""Distance triangulations: large fans of slivers re-triangulated for exact distance queries.

A cylinder cap as ``trimesh.creation.cylinder`` builds it is a fan of ``s`` slivers meeting at
its centre; a BVH distance query from a point near the centre finds all ``s`` within
round-off of the minimum and prunes none. The distance of two bodies depends on their
surfaces only: :func:`distance_faces` re-triangulates each fan (coplanar, closed, convex, at
least ``FAN_MIN_TRIANGLES``) by passes of ears halving the polygon (:func:`halving_cap`): the
same polygon, vertices, boundary edges and triangle count, ``FAN_INNER`` triangles at the
centre. Exact minima agree to the rounding of triangle-triangle distances (~1e-16 m); nearest
points may differ where not unique. Contact tests keep the mesh's own triangles (fcl's depth,
point and normal are per triangle pair). Measured effects: ``results/collision/README.md``.
"""
from __future__ import annotations

import logging
from typing import List, Optional

import numpy as np

log = logging.getLogger(__name__)

__all__ = ["FAN_MIN_TRIANGLES", "FAN_INNER", "halving_cap", "fan_centres", "distance_faces"]

#: a fan of fewer triangles is left alone (a missile's 32-section caps: a query near their
#: centre costs little)
FAN_MIN_TRIANGLES = 64
#: a re-triangulated fan keeps at most this many triangles at its centre
FAN_INNER = 4
#: fan triangles whose unit normals differ by more (in any component) are not a plane polygon
#: (left alone)
FAN_NORMAL_TOL = 1e-9
#: relative to the fan's scale (at least 1 m): ring vertices farther from the centre's plane
#: are not a plane polygon (left alone)
FAN_PLANE_TOL = 1e-12


def _fan_ring(faces: np.ndarray, rows: np.ndarray, centre: int) -> Optional[List[int]]:
    """The boundary ring of the fan (``faces[rows]`` all contain ``centre``) in the fan
    triangles' orientation, or None when they do not form one closed fan."""
    nxt = {}
    for f in faces[rows].tolist():
        k = f.index(centre)
        u, w = f[(k + 1) % 3], f[(k + 2) % 3]  # the boundary edge u -> w
        if u in nxt:
            return None
        nxt[u] = w
    start = min(nxt)
    ring = [start]
    while len(ring) < len(rows):
        nx = nxt.get(ring[-1])
        if nx is None or nx == start:
            return None
        ring.append(nx)
    if nxt.get(ring[-1]) != start or len(set(ring)) != len(ring):
        return None
    return ring


def _halving(ring: List[int], centre: int, inner: int) -> List[List[int]]:
    """Triangles of the convex polygon ``ring`` (vertex ids in order) with the interior vertex
    ``centre``: passes of ears cut off the current polygon, ``(v0, v1, v2), (v2, v3, v4), ...``
    (every second vertex dropped), until at most ``inner`` vertices are left, which are joined
    to the centre. Each triangle lists its vertices in the polygon's order (its orientation).
    A polygon of ``s`` vertices and one interior vertex takes ``s`` triangles."""
    tris: List[List[int]] = []
    poly = list(ring)
    while len(poly) > inner:
        m = len(poly)
        tris += [[poly[2 * j], poly[2 * j + 1], poly[(2 * j + 2) % m]] for j in range(m // 2)]
        poly = poly[::2]
    tris += [[centre, poly[j], poly[(j + 1) % len(poly)]] for j in range(len(poly))]
    return tris


def halving_cap(faces: np.ndarray, centre: int, vertices: np.ndarray, inner: int = FAN_INNER) -> np.ndarray:
    """Re-triangulate the plane fan of triangles around vertex ``centre`` (a cylinder's cap).

    The cap polygon (the fan's boundary ring) is cut by passes of ears, each pass dropping every
    second vertex of the current polygon (:func:`_halving`), and the last ``inner`` or fewer
    vertices are joined to the centre: small triangles along the rim, larger ones inwards, a
    few at the centre, so any point of the cap is within a small distance of O(log s)
    triangles, not of all ``s`` fan slivers. The cap keeps exactly its ``s`` triangles, its
    vertices, its boundary edges (a closed mesh stays closed) and its orientation; the surface
    is the same plane polygon.

    Parameters
    ----------
    faces : ndarray, shape (m, 3)
        Triangles of the mesh; the fan is the triangles that contain ``centre``.
    centre : int
        Index of the fan's centre vertex.
    vertices : ndarray, shape (n, 3)
        The mesh's vertices: every new triangle must turn as the fan does (the polygon is
        convex and the centre inside the last polygon), else the faces are returned unchanged.
    inner : int
        Vertices of the last polygon at most (>= 3).

    Returns
    -------
    ndarray, shape (m, 3)
        A copy of the faces with the fan's triangles replaced (at the fan's rows).
    """
    faces = np.array(faces, dtype=np.int64)
    rows = np.flatnonzero((faces == centre).any(axis=1))
    ring = _fan_ring(faces, rows, centre) if len(rows) > inner else None
    if ring is None:
        return faces
    new = np.array(_halving(ring, centre, inner), dtype=np.int64)
    V = np.asarray(vertices, float)
    n_old = _normals(V, faces[rows]).sum(axis=0)
    if not np.all(_normals(V, new) @ n_old > 0):
        return faces
    faces[rows] = new
    return faces


def _normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Area-weighted normals of the triangles ``F`` (twice the area), shape (k, 3)."""
    T = V[F]
    return np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])


def fan_centres(vertices: np.ndarray, faces: np.ndarray, min_triangles: int = FAN_MIN_TRIANGLES) -> List[int]:
    """Vertices at the centre of a plane fan of at least ``min_triangles`` triangles (every
    triangle that contains the vertex has the same unit normal within ``FAN_NORMAL_TOL``, and
    their vertices lie in the centre's plane within ``FAN_PLANE_TOL`` x the fan's scale)."""
    V, F = np.asarray(vertices, float), np.asarray(faces, np.int64)
    counts = np.bincount(F.ravel(), minlength=len(V))
    out = []
    for c in np.flatnonzero(counts >= min_triangles).tolist():
        fan = F[(F == c).any(axis=1)]
        tri = V[fan]
        n = _normals(V, fan)
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        scale = float(np.abs(tri - V[c]).max())
        if (np.abs(n - n[0]).max() <= FAN_NORMAL_TOL
                and np.abs((tri - V[c]) @ n[0]).max() <= FAN_PLANE_TOL * max(scale, 1.0)):
            out.append(int(c))
    return out


def distance_faces(vertices: np.ndarray, faces: np.ndarray) -> Optional[np.ndarray]:
    """The faces with every large plane convex fan re-triangulated (:func:`halving_cap`),
    for exact distance queries (module docstring); None when the mesh has no such fan."""
    centres = fan_centres(vertices, faces)
    if not centres:
        return None
    out = np.asarray(faces, np.int64)
    for c in centres:
        out = halving_cap(out, c, vertices)
    if np.array_equal(out, faces):
        return None
    log.debug("distance triangulation: %d fan(s) of >= %d triangles re-triangulated", len(centres), FAN_MIN_TRIANGLES)
    return out
