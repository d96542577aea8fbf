"""Ray casting against posed meshes through trimesh (shared by the thesis's two backends).

Rays are cast in the mesh's own frame (one ray accelerator per distinct mesh, built once) and
hits are mapped back to the world frame.
"""
from __future__ import annotations

import numpy as np
import trimesh

__all__ = ["cast_rays", "first_last_along"]


def cast_rays(mesh: trimesh.Trimesh, T: np.ndarray, origins: np.ndarray, directions: np.ndarray):
    """All hits of world rays with a mesh posed by ``T``.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Mesh in its body frame.
    T : ndarray, shape (4, 4)
        Body-to-world transform.
    origins, directions : ndarray, shape (r, 3)
        World-frame rays.

    Returns
    -------
    locations : ndarray, shape (h, 3)
        World hit points.
    index_ray : ndarray, shape (h,)
        Ray of each hit.
    """
    if len(origins) == 0:
        return np.zeros((0, 3)), np.zeros(0, int)
    R, t = T[:3, :3], T[:3, 3]
    o_loc = (origins - t) @ R
    d_loc = directions @ R
    loc, idx_ray, _ = mesh.ray.intersects_location(o_loc, d_loc, multiple_hits=True)
    if len(loc) == 0:
        return np.zeros((0, 3)), np.zeros(0, int)
    return loc @ R.T + t, np.asarray(idx_ray, int)


def first_last_along(locations: np.ndarray, index_ray: np.ndarray, axis: int, n_rays: int,
                     lo: float, hi: float):
    """First and last hit of each ray along ``axis`` inside ``[lo, hi]``.

    Returns
    -------
    has : ndarray of bool, shape (n_rays,)
    first, last : ndarray, shape (n_rays, 3)
        Hit with the smallest / largest coordinate along ``axis`` (one hit: both the same).
    """
    first = np.full((n_rays, 3), np.nan)
    last = np.full((n_rays, 3), np.nan)
    keep = (locations[:, axis] >= lo) & (locations[:, axis] <= hi)
    loc, idx = locations[keep], index_ray[keep]
    has = np.zeros(n_rays, bool)
    if len(loc) == 0:
        return has, first, last
    order = np.lexsort((loc[:, axis], idx))
    loc, idx = loc[order], idx[order]
    starts = np.flatnonzero(np.r_[True, idx[1:] != idx[:-1]])
    ends = np.r_[starts[1:], len(idx)] - 1
    rays = idx[starts]
    has[rays] = True
    first[rays] = loc[starts]
    last[rays] = loc[ends]
    return has, first, last
