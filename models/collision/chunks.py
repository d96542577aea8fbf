"""Exact mesh distances chunk by chunk: a large mesh split into small BVHs, visited by a bound.

A mesh of at least ``CHUNK_MIN_FACES`` triangles, queried against a body of at most
``CHUNK_OTHER_MAX_FACES``, is split once into chunks of at most ``max_faces`` triangles
(median cuts of the centroids along the longest extent), each its own ``fcl.BVHModel`` in the
mesh's frame, built (with the chunk's own vertex list) when a query first visits the chunk. A query visits the chunks by
increasing lower bound and stops at the first whose bound reaches the best distance so far
less ``CHUNK_TIE``.

The bound of a chunk (local AABB centre ``c``, half extents ``h``) and the other body (local
AABB ``c_o``, ``e``; ``M = R_b^T R_o``, ``p = R_b^T (t_o - t_b)`` in the chunked body's frame)
is the larger of two box gaps (eq. 5-1's bounding-volume cull with boxes in both frames):

``g_1 = || max(|c - c_1| - h - e_1, 0) ||``  (``c_1``, ``e_1``: the box of the other's hull
vertices ``p + M v``)

``g_2 = || max(|M^T (c - p) - c_o| - |M|^T h - e, 0) ||``  (the chunk's box in the other's frame)

Given a bound above the pair's distance (``within``), only chunks whose ``g_1`` is below it
are bounded and sorted: the visit, its stop and the result are those of the full order.
A mesh's chunks may split another triangulation row for row (``split_by``, :mod:`.fans`).
Each triangle pair's distance is fcl's arithmetic of the whole-mesh query, so the minimum is
the same number (within ``CHUNK_TIE`` = 1e-12 m); where several pairs are nearest within
round-off, the nearest points are one of them.
"""
from __future__ import annotations

import logging
import math
from typing import List, Optional

import fcl
import numpy as np

log = logging.getLogger(__name__)

__all__ = ["CHUNK_MIN_FACES", "CHUNK_OTHER_MAX_FACES", "CHUNK_TIE", "ChunkedMesh", "split_faces", "chunk_lower_bounds",
           "chunked_distance"]

#: meshes with fewer triangles keep the whole-mesh query (their traversal is cheap)
CHUNK_MIN_FACES = 1024
#: m; a chunk whose lower bound is within this of the best distance so far is not visited
CHUNK_TIE = 1e-12
#: the other body of a chunked query has at most this many triangles (boxes, low-poly
#: proxies): each chunk query pairs the chunk's triangles with all of the other body's that
#: its BVH cannot prune, and a body of long triangles (the missile's 2.5 m side strips,
#: 192 triangles) is never pruned: chunk by chunk it costs more than the whole-mesh query
CHUNK_OTHER_MAX_FACES = 64


def split_faces(vertices: np.ndarray, faces: np.ndarray, max_faces: int) -> List[np.ndarray]:
    """Split the triangles into spatially compact groups of at most ``max_faces``.

    Median cut of the centroids along their longest extent, recursively (deterministic:
    stable sort). Returns the face indices of each group, shape (k,) each."""
    centroids = np.asarray(vertices, float)[np.asarray(faces)].mean(axis=1)
    out: List[np.ndarray] = []
    stack = [np.arange(len(faces))]
    while stack:
        idx = stack.pop()
        if len(idx) <= max_faces:
            out.append(idx)
            continue
        c = centroids[idx]
        axis = int(np.argmax(c.max(0) - c.min(0)))
        order = np.argsort(c[:, axis], kind="stable")
        half = len(idx) // 2
        stack.append(idx[order[half:]])
        stack.append(idx[order[:half]])
    return out


class ChunkedMesh:
    """The chunks of one mesh: BVHs and local AABBs (centres and half extents).

    Parameters
    ----------
    vertices : ndarray, shape (n, 3)
    faces : ndarray, shape (m, 3)
    max_faces : int
        Triangles per chunk at most.
    split_by : ndarray, shape (m, 3), optional
        Faces (row for row another triangulation of the same mesh) whose centroids decide the
        split: a distance triangulation (:mod:`.fans`) is chunked as the mesh itself is, so
        the chunks of the triangles the two share are the same. Default: ``faces``.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, max_faces: int,
                 split_by: Optional[np.ndarray] = None) -> None:
        V, F = np.asarray(vertices, float), np.asarray(faces, np.int64)
        self._V, self._F = V, F
        #: per chunk the indices of its faces
        self.faces = split_faces(V, F if split_by is None else np.asarray(split_by, np.int64), max_faces)
        #: per chunk its vertices and faces (local indices), made when first visited (:meth:`part`)
        self.parts: List[Optional[tuple]] = [None] * len(self.faces)
        # each chunk's box: the smallest and largest coordinates of its faces' vertices
        tri = V[F[np.concatenate(self.faces)]]            # (m, 3, 3), chunk after chunk
        starts = np.cumsum([0] + [len(idx) for idx in self.faces[:-1]])
        lo = np.minimum.reduceat(tri.min(axis=1), starts)
        hi = np.maximum.reduceat(tri.max(axis=1), starts)
        self.centre = (lo + hi) / 2
        self.half = (hi - lo) / 2
        self._objs: List[Optional[fcl.CollisionObject]] = [None] * len(self.parts)
        #: per chunk object: the (body, transform version) whose transform it holds
        self.tag: List[Optional[tuple]] = [None] * len(self.parts)

    def part(self, i: int) -> tuple:
        """Chunk ``i``'s vertices (k, 3) and faces (local indices, (f, 3)): the vertices its
        faces use, in the mesh's order (made the first time)."""
        p = self.parts[i]
        if p is None:
            used, local = np.unique(self._F[self.faces[i]], return_inverse=True)
            p = self.parts[i] = (self._V[used], local.reshape(-1, 3))
        return p

    def obj(self, i: int) -> "fcl.CollisionObject":
        """Chunk ``i``'s collision object (identity transform when new): its BVH is built here
        the first time (a run visits few of a mesh's chunks)."""
        o = self._objs[i]
        if o is None:
            from .fcl_backend import bvh_model

            o = self._objs[i] = fcl.CollisionObject(bvh_model(*self.part(i)), fcl.Transform())
        return o

    def __len__(self) -> int:
        return len(self.parts)


def chunk_lower_bounds(chunks: ChunkedMesh, T_big: np.ndarray, T_other: np.ndarray, other_hull: np.ndarray,
                       other_centre: np.ndarray, other_half: np.ndarray, within: float = math.inf) -> tuple:
    """Lower bounds (m) of the distance of each chunk to the other body (module docstring).

    Parameters
    ----------
    chunks : ChunkedMesh
    T_big, T_other : ndarray, shape (4, 4)
        World transforms of the chunked body and of the other body.
    other_hull : ndarray, shape (k, 3)
        Vertices of the other body whose convex hull contains it (local frame): their AABB
        in the chunked body's frame is the other body's tight box there.
    other_centre, other_half : ndarray, shape (3,)
        The other body's local AABB.
    within : float, optional
        m; only the chunks whose first gap ``g_1`` is below this get their bounds (both
        gaps); the others' bounds are at least ``within`` (default: every chunk). Each
        chunk's numbers are the same either way (row by row the same arithmetic).

    Returns
    -------
    lb : ndarray, shape (k,)
        The bounds of the chunks ``idx``.
    order : ndarray, shape (k,)
        Sum of the squared gaps in both frames: orders chunks of equal bound (a flat face
        under a rotated body's box: many chunks share the box's gap, the other frame's gap
        tells them apart).
    idx : ndarray of int, shape (k,), or None
        The chunks bounded, None for all of them (``k = n_chunks``, in order).
    """
    # (the expressions of the module docstring, evaluated in place where a temporary would be
    # made: the same operations in the same order, so the same numbers, with fewer arrays;
    # this runs once per chunked distance)
    Rb = T_big[:3, :3]
    M = Rb.T @ T_other[:3, :3]
    p = Rb.T @ (T_other[:3, 3] - T_big[:3, 3])
    pts = other_hull @ M.T  # the other body's hull in the chunked body's frame
    pts += p
    lo, hi = np.minimum.reduce(pts, 0), np.maximum.reduce(pts, 0)
    c, h = chunks.centre, chunks.half
    g1 = c - (lo + hi) / 2  # |c - c_1| - h - e_1
    np.abs(g1, out=g1)
    g1 -= h
    g1 -= (hi - lo) / 2
    np.maximum(g1, 0.0, out=g1)
    b1 = np.einsum("ij,ij->i", g1, g1)
    idx = None
    if within < math.inf:
        idx = (np.sqrt(b1) < within).nonzero()[0]
        c, h, b1 = c.take(idx, 0), h.take(idx, 0), b1.take(idx)
    g2 = (c - p) @ M  # |M^T (c - p) - c_o| - |M|^T h - e
    g2 -= other_centre
    np.abs(g2, out=g2)
    g2 -= h @ np.abs(M)
    g2 -= other_half
    np.maximum(g2, 0.0, out=g2)
    b2 = np.einsum("ij,ij->i", g2, g2)
    return np.sqrt(np.maximum(b1, b2)), b1 + b2, idx


def chunked_distance(chunks: ChunkedMesh, tag, tf_big: "fcl.Transform", T_big: np.ndarray, T_other: np.ndarray,
                     other_box: tuple, other: "fcl.CollisionObject", big_first: bool, req: "fcl.DistanceRequest",
                     res: "fcl.DistanceResult", within: float = math.inf) -> float:
    """Exact distance of the chunked body to ``other`` into ``res`` (keeps the smallest).

    Chunks are visited by increasing lower bound (:func:`chunk_lower_bounds`; ties by the sum
    of squared gaps, then index) until one's bound is within ``CHUNK_TIE`` of
    ``res.min_distance``. ``tag`` names the body and transform version of ``tf_big`` (fcl form
    of ``T_big``); ``big_first``: the chunk is fcl's first object. ``within`` (m): a bound
    above the distance; only chunks nearer are bounded (if the visit ends above it, the full
    order is visited). ``other_box``: ``(hull, centre, half)`` of the other body.

    Returns a lower bound of the pair's distance (m) for the pair cache: the smallest distance
    found, or when smaller the bound of the chunk where the visit stopped, or ``within`` when
    the visit of the chunks nearer than it ended.
    """
    within = min(within, res.min_distance)
    bounds, tie, idx = chunk_lower_bounds(chunks, T_big, T_other, *other_box, within=within)
    order = np.lexsort((tie, bounds)).tolist()  # (idx is sorted: ties by chunk index, as in the full order)
    listed = bounds.tolist()
    ids = idx.tolist() if idx is not None else None
    own = math.inf
    objs, tags, make = chunks._objs, chunks.tag, chunks.obj
    for j in order:
        bound = listed[j]
        if ids is not None and bound >= within:
            break  # unbounded chunks may come first in the full order
        if bound >= res.min_distance - CHUNK_TIE:
            return min(own, bound)
        i = j if ids is None else ids[j]
        obj = objs[i]
        if obj is None:
            obj = make(i)
        if tags[i] != tag:
            obj.setTransform(tf_big)
            tags[i] = tag
        if big_first:
            d = fcl.distance(obj, other, req, res)
        else:
            d = fcl.distance(other, obj, req, res)
        if d < own:
            own = d
    if ids is None:
        return own
    if res.min_distance - CHUNK_TIE <= within:  # the full order stops at a chunk bounded >= within
        return min(own, within)
    log.debug("chunked distance: %.6g m was not a bound (best %.6g m): the full order", within, res.min_distance)
    return min(own, chunked_distance(chunks, tag, tf_big, T_big, T_other, other_box, other, big_first, req, res))

