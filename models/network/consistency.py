"""Consistency control of ch. 3: scene grid (§3.3), ownership (§3.6.2), dead reckoning (§3.6.3).

The cached master/slave rendering of §3.5.2 lives in the frame phases (:mod:`.delivery`,
:mod:`.history`; it needs the event timing); here are the pure, vectorised pieces.
"""
from __future__ import annotations

import math
from functools import lru_cache
from typing import Tuple

import numpy as np

from .arrays import concat_ranges
from .paths import Paths

_DEFAULT = Paths()


# -- scene grid §3.3 -------------------------------------------------------------------------
CELL_LIMIT = 2.0 ** 62   # cell quotients below this in magnitude: int() is the int64 cast
class SceneGrid:
    """``C x C`` grid over a square scene of side ``size``; 9-cell neighbourhoods (fig. 3-5a).

    Cell ``(i, j)`` has index ``i * C + j`` with ``i`` along x. Its neighbourhood is
    ``S_{i+di, j+dj}`` for ``di, dj in {-1, 0, 1}`` inside the grid. Up to ``scalar_pairs``
    candidates or view pairs, :meth:`view_pairs` and :meth:`not_in_view` run in Python.
    """

    def __init__(self, size: float, cells: int = 10, enabled: bool = True,
                 scalar_pairs: int = _DEFAULT.scalar_grid) -> None:
        self.size, self.C, self.enabled = float(size), int(cells), enabled
        self.scalar_pairs = scalar_pairs
        C = self.C
        i, j = np.divmod(np.arange(C * C), C)
        nb = []
        for di in (-1, 0, 1):
            for dj in (-1, 0, 1):
                ii, jj = i + di, j + dj
                ok = (ii >= 0) & (ii < C) & (jj >= 0) & (jj < C)
                nb.append(np.where(ok, ii * C + jj, -1))
        self.neigh = np.stack(nb, axis=1)  # (C*C, 9), -1 outside
        self._neigh_list = None            # its cells inside the grid per row, as lists (built on first use)

    def cell(self, pos: np.ndarray, pos_list=None) -> np.ndarray:
        """Cell index of each position (n, 2) -> (n,) int. ``pos_list``: the same positions as
        a list of ``[x, y]`` when the caller has it (a few positions: the cells in Python)."""
        if pos_list is not None:
            out = self._cell_scalar(pos_list)
            if out is not None:
                return np.array(out, np.int64)
        q = pos / self.size
        q *= self.C
        ij = q.astype(np.int64)
        np.maximum(ij, 0, out=ij)
        np.minimum(ij, self.C - 1, out=ij)
        out = ij[:, 0] * self.C
        out += ij[:, 1]
        return out

    def _cell_scalar(self, pos: list):
        """:meth:`cell` of positions given as a list of ``[x, y]`` (m), in Python: the same
        quotient ``x / size * C`` truncated toward zero and clipped to the grid. None when a
        quotient is not finite or too large for an exact int64 cast (the array code then)."""
        size, C = self.size, self.C
        Cf = float(C)     # (the same products and comparisons as with the int, without converting it each time)
        # every position inside the grid (the common case): one comprehension
        out = [int(u) * C + int(v) if 0.0 <= (u := x / size * Cf) < Cf and 0.0 <= (v := y / size * Cf) < Cf
               else -1 for x, y in pos]
        if -1 not in out:
            return out
        hi = C - 1
        out = []
        for x, y in pos:
            u = x / size * Cf
            v = y / size * Cf
            if 0.0 <= u < Cf and 0.0 <= v < Cf:     # inside the grid: no clipping
                out.append(int(u) * C + int(v))
                continue
            if not (-CELL_LIMIT < u < CELL_LIMIT and -CELL_LIMIT < v < CELL_LIMIT):
                return None
            i, j = int(u), int(v)
            out.append((0 if i < 0 else hi if i > hi else i) * C + (0 if j < 0 else hi if j > hi else j))
        return out

    def adjacent(self, a, b):
        """Cell ``b`` is in the 9-cell neighbourhood of cell ``a`` (symmetric), elementwise."""
        ia, ja = np.divmod(a, self.C)
        ib, jb = np.divmod(b, self.C)
        return (np.abs(ia - ib) <= 1) & (np.abs(ja - jb) <= 1)

    def not_in_view(self, old_cells: np.ndarray, old_online: np.ndarray, cells: np.ndarray,
                    vg: np.ndarray, vo: np.ndarray) -> np.ndarray:
        """Indices of the view pairs (viewer group ``vg``, object ``vo``) of cells ``cells``
        that were not in view with the cells ``old_cells`` (objects) and online groups
        ``old_online`` (G,) bool of another frame: pairs that entered the view since then (or,
        with the frames swapped, pairs that left it).

        A pair is in view iff its viewer is online and the object's cell is in the 9-cell
        neighbourhood of the viewer avatar's cell (§3.3; every online viewer sees every object
        without the grid). Only pairs whose object or viewer changed cell, or whose viewer was
        offline, can differ, so the neighbourhood test runs on those alone.
        """
        if not self.enabled:
            return np.flatnonzero(~np.take(old_online, vg))
        if len(vg) <= self.scalar_pairs:
            return self._not_in_view_scalar(old_cells.tolist(), old_online.tolist(), cells.tolist(), vg.tolist(),
                                            vo.tolist())
        moved = cells != old_cells
        changed_v = moved[:len(old_online)] | ~old_online
        cand = np.flatnonzero(np.take(moved, vo) | np.take(changed_v, vg))
        if len(cand):
            g, o = vg[cand], vo[cand]
            was = np.take(old_online, g) & self.adjacent(np.take(old_cells, o), np.take(old_cells, g))
            cand = cand[~was]
        return cand

    def view_pairs(self, viewer_cells: np.ndarray, object_cells: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """All (viewer, object) pairs with the object in the viewer's 9-cell neighbourhood.

        With the grid disabled every viewer sees every object. Returns index arrays, sorted
        by viewer. The relation is symmetric: the viewers of an object are the viewers in the
        object's neighbourhood.
        """
        M, O = len(viewer_cells), len(object_cells)
        if not self.enabled:
            return np.repeat(np.arange(M), O), np.tile(np.arange(O), M)
        if M * O <= self.scalar_pairs:
            return self._view_pairs_scalar(viewer_cells.tolist(), object_cells.tolist())
        order = np.argsort(object_cells, kind="stable")
        counts = np.bincount(object_cells, minlength=self.C * self.C)
        starts = np.cumsum(counts) - counts
        cells = self.neigh[viewer_cells].ravel()          # (M*9,)
        owner = np.repeat(np.arange(M), 9)
        valid = cells >= 0
        cells, owner = cells[valid], owner[valid]
        lens = counts[cells]
        return np.repeat(owner, lens), order[concat_ranges(starts[cells], lens)]


    def _not_in_view_scalar(self, old_cells: list, old_online: list, cells: list, vg: list, vo: list) -> np.ndarray:
        """:meth:`not_in_view` of a few pairs in Python (the same test: a pair whose object and
        viewer kept their cells and whose viewer was online is still in view; else it was in
        view iff its viewer was online and the cells were adjacent)."""
        C = self.C
        out = []
        for p, (g, o) in enumerate(zip(vg, vo)):
            og, oo = old_cells[g], old_cells[o]
            if oo == cells[o] and og == cells[g] and old_online[g]:
                continue
            if old_online[g]:
                ia, ja = divmod(oo, C)
                ib, jb = divmod(og, C)
                if -1 <= ia - ib <= 1 and -1 <= ja - jb <= 1:
                    continue
            out.append(p)
        return np.array(out, np.int64)

    def _view_pairs_scalar(self, viewer_cells: list, object_cells: list) -> Tuple[np.ndarray, np.ndarray]:
        """:meth:`view_pairs` of a few viewers and objects in Python: the same pairs in the same
        order (viewer by viewer, its neighbourhood's cells in ``neigh`` order, the objects of a
        cell in index order)."""
        if self._neigh_list is None:
            self._neigh_list = [[c for c in row if c >= 0] for row in self.neigh.tolist()]
        by_cell = {}
        for o, c in enumerate(object_cells):
            by_cell.setdefault(c, []).append(o)
        vl, vo = [], []
        for v, c in enumerate(viewer_cells):
            for nc in self._neigh_list[c]:
                objs = by_cell.get(nc)
                if objs:
                    vo += objs
                    vl += [v] * len(objs)
        return np.array(vl, np.int64), np.array(vo, np.int64)



class PointIndex:
    """Points (n, 2) sorted by x, for box queries around a few query points each frame.

    Sorting ``n`` values costs less than building a k-d tree; the tree (:attr:`tree`, for
    the exact pair order of :meth:`scipy.spatial.cKDTree.sparse_distance_matrix`) is built
    only when a caller needs it, e.g. on the rare frames with a contact.
    """

    def __init__(self, pts: np.ndarray) -> None:
        self.pts = pts
        self.order = np.argsort(pts[:, 0], kind="stable")
        self.xs = pts[self.order, 0]
        self._tree = None

    @property
    def tree(self):
        """k-d tree of the points (built on first use)."""
        if self._tree is None:
            from scipy.spatial import cKDTree

            self._tree = cKDTree(self.pts)
        return self._tree

    def near(self, q: np.ndarray, rad: np.ndarray):
        """Candidate pairs (query index, point index) with ``|x_p - x_q| <= rad_q`` and
        ``|y_p - y_q| <= rad_q``: a superset of the points within distance ``rad_q``."""
        lo = np.searchsorted(self.xs, q[:, 0] - rad, side="left")
        hi = np.searchsorted(self.xs, q[:, 0] + rad, side="right")
        n = hi - lo
        qi = np.repeat(np.arange(len(q)), n)
        pi = self.order[concat_ranges(lo, n)]
        ok = np.abs(self.pts[pi, 1] - q[qi, 1]) <= rad[qi]
        return qi[ok], pi[ok]


# -- ownership §3.6.2 ----------------------------------------------------------------------------
def ellipsoid_axes(vel: np.ndarray, frame_s: float, scale: float, min_axis: float, foci: str = "frame"):
    """Control ellipsoid of each avatar, eq. 3-11/3-12.

    The avatar moves ``D = |v| T`` per frame; the long semi-axis is ``a = D * Scale`` (eq. 3-11)
    along the velocity, floored at ``min_axis`` so a resting avatar keeps a sphere. The two
    foci are the current position ``A(t0)`` and the dead-reckoned next position
    ``A(t1) = A(t0) + v T``, so the focal half-distance is ``D/2`` and the short semi-axes are
    ``b = c = sqrt(a^2 - (D/2)^2)`` (eq. 3-12, reading the seed's ``c/2`` as half the focal
    distance). The centre is ``A(t0) + v T / 2``. Since ``a = 30 D >> D/2`` this ellipsoid is
    nearly a sphere. ``foci='reach'`` is the other reading: the foci are ``A(t0)`` and the
    position ``Scale`` frames ahead, ``A(t0) + v T Scale``, so the focal distance is ``a`` itself,
    ``b = c = sqrt(a^2 - (a/2)^2)`` and the centre is ``A(t0) + a u / 2``: a region stretched
    ahead of the avatar ("nearest arrival" rather than nearest distance).

    Parameters
    ----------
    vel : (n, d) m/s
    Returns
    -------
    a, b : (n,) m;  u : (n, d) unit long-axis direction (x axis for a resting avatar);
    shift : (n, d) m, centre minus position.
    """
    speed = np.sqrt(np.add.reduce(vel * vel, axis=1))     # np.linalg.norm(vel, axis=1), without its checks
    D = speed * frame_s
    a = np.maximum(D * scale, min_axis)
    focal = D * scale if foci == "reach" else D
    b = np.sqrt(a ** 2 - (0.5 * focal) ** 2)
    moving = speed > 0
    u = np.divide(vel, speed[:, None], out=np.zeros_like(vel), where=moving[:, None])
    if not moving.all():
        u[~moving, 0] = 1.0
    return a, b, u, 0.5 * focal[:, None] * u


def heading_distance(r: np.ndarray, u: np.ndarray, ecc: np.ndarray) -> np.ndarray:
    """Arrival distance (m) of points ``r`` (k, d) from an avatar (relative positions) heading
    along ``u`` (k, d) with ownership-ellipse eccentricity ``ecc`` (k,): ``L = |r| - ecc r.u =
    |r| (1 - ecc cos theta)``.

    The control ellipse has a focus at the avatar (its centre is ``A + f u``, ``ecc = f / a``),
    so its boundary in polar form about the avatar is ``|r| (1 - ecc cos theta) = a (1 - ecc^2)``:
    ``L`` is the ellipse's own radial measure, in metres, hence comparable between avatars of
    different region sizes (the Mahalanobis ``d`` of eq. 3-6 is relative to each region's
    size). Straight ahead ``L = (1 - ecc)|r|``, behind ``(1 + ecc)|r|``, a parked avatar
    (``ecc = 0``) ``|r|``: an avatar driving toward an entity wins it from a parked one up to
    ``1 / (1 - ecc)`` times nearer (2 in the ``reach`` reading, ``ecc = 1/2``); one driving away
    never wins it from a nearer parked one.
    """
    along = np.einsum("...i,...i->...", r, u)
    return np.sqrt(np.einsum("...i,...i->...", r, r)) - ecc * along


def mahalanobis_ellipsoid(x: np.ndarray, centre: np.ndarray, u: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Mahalanobis distance of eq. 3-6 with ``Sigma = R diag(a^2, b^2, b^2) R^T`` (long axis ``u``).

    ``d^2 = ((x - c).u)^2 / a^2 + (|x - c|^2 - ((x - c).u)^2) / b^2``; ``d <= 1`` inside the
    control ellipsoid of eq. 3-10. Arrays broadcast over the leading axis.
    """
    r = x - centre
    along = np.einsum("...i,...i->...", r, u)
    perp2 = np.maximum(np.einsum("...i,...i->...", r, r) - along ** 2, 0.0)
    return np.sqrt(along ** 2 / a ** 2 + perp2 / b ** 2)


def covariance(u: np.ndarray, a: float, b: float) -> np.ndarray:
    """The ellipsoid's covariance ``Sigma`` (3, 3) for long axis ``u`` (3,), for cross-checks."""
    u = np.asarray(u, float) / np.linalg.norm(u)
    return b ** 2 * np.eye(3) + (a ** 2 - b ** 2) * np.outer(u, u)


@lru_cache(maxsize=16)
def _all_pairs(n: int, m: int):
    """Every (i, j) for i < n, j < m, i-major (read-only index arrays, shared)."""
    gi, ei = np.divmod(np.arange(n * m), m)
    gi.flags.writeable = ei.flags.writeable = False
    return gi, ei


def assign_owners(rule: str, avatar_pos: np.ndarray, avatar_vel: np.ndarray, entity_pos: np.ndarray,
                  current: np.ndarray, frame_s: float, scale: float, min_axis: float,
                  foci: str = "reach", etree=None, lists=None, scalar_pairs: int = _DEFAULT.scalar_owners,
                  brute_pairs: int = _DEFAULT.brute_owners) -> np.ndarray:
    """Owning avatar (group index) of every entity, or the current one where nobody claims it.

    ``'mahalanobis'``: the avatar whose control ellipsoid (eq. 3-11/3-12) holds the entity with
    the smallest Mahalanobis distance. ``'euclidean'``: the nearest avatar (eq. 3-3) among those
    within a sphere of radius ``a`` (the same reach, no direction). ``'none'``: no change.
    Ties go to the lower index. Candidate pairs come from a k-d tree (``etree``: a
    ``cKDTree`` or a :class:`PointIndex` of ``entity_pos``), so the cost is linear; with a
    :class:`PointIndex` the Mahalanobis candidates are the entities in the box of half-width
    ``a`` around each centre (``d <= 1`` implies ``|x - c| <= a``: the same owners).
    The result may be ``current`` itself when no entity changes owner (small scenes).
    ``lists``: ``avatar_pos``, ``avatar_vel`` and ``entity_pos`` as lists of ``[x, y]`` when the
    caller has them (small scenes read them instead of the arrays). Up to ``scalar_pairs``
    (avatar, entity) pairs the owners are found in Python floats; below ``brute_pairs`` pairs
    without ``etree`` every pair is tested (brute force beats building a k-d tree every frame).
    """
    if rule == "none" or len(avatar_pos) == 0 or len(entity_pos) == 0:
        return current
    if etree is None and len(avatar_pos) * len(entity_pos) <= scalar_pairs and avatar_pos.shape[1] == 2:
        if lists is None:
            lists = (avatar_pos.tolist(), avatar_vel.tolist(), entity_pos.tolist())
        out = _assign_owners_scalar(rule, *lists, current, frame_s, scale, min_axis, foci)
        if out is not None:
            return out
    if avatar_vel is None:   # (given as a list only)
        avatar_vel = np.array(lists[1])
    a, b, u, shift = ellipsoid_axes(avatar_vel, frame_s, scale, min_axis, foci)
    centre = avatar_pos + shift if rule == "mahalanobis" else avatar_pos
    if etree is None and len(centre) * len(entity_pos) <= brute_pairs:
        # small scenes: every (avatar, entity) pair, no k-d tree (same result: the winner is
        # chosen by (entity, distance, avatar) below, whatever order the candidates come in)
        gi, ei = _all_pairs(len(centre), len(entity_pos))
        if rule == "euclidean":
            r = entity_pos[ei] - centre[gi]
            sd = {"v": np.sqrt(np.einsum("ij,ij->i", r, r))}
    elif rule == "mahalanobis" and isinstance(etree, PointIndex):
        gi, ei = etree.near(centre, a)
    else:
        from scipy.spatial import cKDTree

        etree = etree.tree if isinstance(etree, PointIndex) else etree
        etree = etree if etree is not None else cKDTree(entity_pos)
        sd = cKDTree(centre).sparse_distance_matrix(etree, float(a.max()), output_type="ndarray")
        gi, ei = sd["i"].astype(np.int64), sd["j"].astype(np.int64)
    if rule == "mahalanobis":
        d = mahalanobis_ellipsoid(entity_pos[ei], centre[gi], u[gi], a[gi], b[gi])
        keep = d <= 1.0
        gi, ei = gi[keep], ei[keep]
        # among the regions that hold it: the smallest arrival distance (heading_distance)
        r = entity_pos[ei] - avatar_pos[gi]
        ecc = np.sqrt(np.einsum("ij,ij->i", shift, shift)) / a
        d = heading_distance(r, u[gi], ecc[gi])
    else:  # nearest distance (eq. 3-3) among the avatars within reach a
        d = sd["v"]
        keep = d <= a[gi]
        gi, ei, d = gi[keep], ei[keep], d[keep]
    out = current.copy()
    if len(ei):
        order = np.lexsort((gi, d, ei))
        ei, gi = ei[order], gi[order]
        first = np.ones(len(ei), bool)
        first[1:] = ei[1:] != ei[:-1]
        out[ei[first]] = gi[first]
    return out



def _assign_owners_scalar(rule, avatar_pos, avatar_vel, entity_pos, current, frame_s, scale, min_axis, foci):
    """:func:`assign_owners` for a few 2-D avatars and entities in Python floats (eq. 3-6,
    3-11/3-12, 3-3): the same operations in the same order as :func:`ellipsoid_axes` and
    :func:`mahalanobis_ellipsoid` (IEEE double either way: squares as products, square roots
    correctly rounded), the winner of each entity the lowest (distance, avatar). None for a
    degenerate ellipsoid (``a = 0`` or ``b = 0``: the array code's NaN/inf semantics);
    ``current`` itself when no entity changes owner. Positions and velocities are lists of
    ``[x, y]``."""
    maha = rule == "mahalanobis"
    av = []      # per avatar: index, centre, the culling bound, long axis, a^2, b^2, reach a
    for i, ((axi, ayi), (vxi, vyi)) in enumerate(zip(avatar_pos, avatar_vel)):
        speed = math.sqrt(vxi * vxi + vyi * vyi)
        D = speed * frame_s
        a = max(D * scale, min_axis)
        focal = D * scale if foci == "reach" else D
        hf = 0.5 * focal
        b2_i = a * a - hf * hf
        if not (a > 0.0 and b2_i > 0.0 and math.isfinite(a)):   # degenerate ellipsoid: the array code
            return None
        b = math.sqrt(b2_i)
        if speed > 0:
            u0, u1 = vxi / speed, vyi / speed
        else:
            u0, u1 = 1.0, 0.0
        if maha:
            cxi, cyi = axi + hf * u0, ayi + hf * u1
        else:
            cxi, cyi = axi, ayi
        # b <= a: the ellipsoid (and the reach sphere) lie in the sphere of radius a, so a pair
        # with |r|^2 > a^2 (1 + 1e-9) has d > 1 (d > a) whatever the rounding: skipped
        a2 = a * a
        ecc = math.sqrt((hf * u0) * (hf * u0) + (hf * u1) * (hf * u1)) / a
        av.append((i, cxi, cyi, a2 * (1.0 + 1e-9), u0, u1, a2, b * b, a, axi, ayi, ecc))
    # avatar by avatar over the entities (the same winner: avatars in index order, a later one
    # wins only with a strictly smaller distance)
    ents = entity_pos
    best = [None] * len(ents)
    who = [-1] * len(ents)
    for i, cxi, cyi, far, u0, u1, a2, b2, reach, axi, ayi, ecc in av:
        # |r|^2 >= rx^2 > a^2 (with margin): outside the sphere of radius a (NaN: never claimed either way)
        for j in [j for j, (x, _) in enumerate(ents) if (x - cxi) * (x - cxi) <= far]:
            x, y = ents[j]
            rx = x - cxi
            ry = y - cyi
            rr = rx * rx + ry * ry
            if rr > far:      # |r| > a (with margin): outside the sphere that holds the ellipsoid
                continue
            if maha:
                along = rx * u0 + ry * u1
                al2 = along * along
                perp2 = rr - al2
                if perp2 < 0.0:
                    perp2 = 0.0
                d = math.sqrt(al2 / a2 + perp2 / b2)
                if not d <= 1.0:     # (NaN too, like the array test)
                    continue
                qx, qy = x - axi, y - ayi     # the arrival distance (heading_distance)
                d = math.sqrt(qx * qx + qy * qy) - ecc * (qx * u0 + qy * u1)
            else:
                d = math.sqrt(rr)
                if not d <= reach:
                    continue
            b = best[j]
            if b is None or d < b:
                best[j], who[j] = d, i
    moved = [(j, w) for j, (w, cur) in enumerate(zip(who, current.tolist())) if w >= 0 and w != cur]
    if not moved:
        return current
    out = current.copy()
    for j, who in moved:
        out[j] = who
    return out


# -- dead reckoning §3.6.3 -----------------------------------------------------------------------
def dead_reckon(pos: np.ndarray, vel, acc, dt, order: int) -> np.ndarray:
    """Extrapolate positions (n, 2) by ``dt`` (n,) s: order 0 ``p``, 1 ``p + v dt`` (the thesis's
    ``A(t1) = A(t0) + v (t1 - t0)``), 2 ``p + v dt + a dt^2 / 2``. ``vel``/``acc`` may be
    None when the order does not use them."""
    if order == 0:
        return pos.copy()
    dt = np.asarray(dt)[..., None]
    if order == 1:
        return pos + vel * dt
    return pos + dt * (vel + (0.5 * dt) * acc)


def free_motion(pos: np.ndarray, vel: np.ndarray, turn: np.ndarray, drag: float, dt: np.ndarray, size: float,
                h_max: float):
    """Positions and velocities (k, 2) of free entities ``dt`` (k,) s after the states ``pos``,
    ``vel`` (k, 2; m, m/s): the scene's entity law, which every node runs itself for an entity no
    avatar owns (§3.6.3), the world's law (:meth:`world.World.advance_to`).

    Each of ``n = ceil(dt / h_max)`` sub-steps ``h = dt / n`` turns the velocity by ``turn h``
    (``turn`` (k,) rad/s, the entity's constant turn rate from the scene file) and decays it by
    ``exp(-drag h)`` (``drag`` 1/s); the position moves by the trapezoid of the two velocities,
    and a wall of the square scene ``[0, size]^2`` reflects the position and that velocity
    component. Rows with ``dt <= 0`` are returned as they are.
    """
    dt = np.asarray(dt, float)
    n = np.where(dt > 0, np.maximum(1, np.ceil(dt / h_max - 1e-9)), 0).astype(np.int64)
    x, y = np.array(pos[:, 0], float), np.array(pos[:, 1], float)
    vx, vy = np.array(vel[:, 0], float), np.array(vel[:, 1], float)
    if not len(n) or n.max() == 0:
        return np.stack([x, y], axis=1), np.stack([vx, vy], axis=1)
    h = dt / np.maximum(n, 1)
    decay = np.exp(-drag * h)
    ct, st = np.cos(turn * h) * decay, np.sin(turn * h) * decay
    hh = 0.5 * h
    if len(n) <= SCALAR_FREE:
        return _free_motion_scalar(n.tolist(), x.tolist(), y.tolist(), vx.tolist(), vy.tolist(), ct.tolist(),
                                   st.tolist(), hh.tolist(), size)
    n_max = int(n.max())
    same = bool((n == n_max).all())       # (the usual case: every row one frame on)
    for i in range(n_max):
        a = slice(None) if same else np.flatnonzero(n > i)
        ax, ay = vx[a], vy[a]
        c, s_, k = ct[a], st[a], hh[a]
        bx = c * ax - s_ * ay
        by = s_ * ax + c * ay
        px = x[a] + k * (ax + bx)
        py = y[a] + k * (ay + by)
        for q, b in ((px, bx), (py, by)):     # walls: reflect the position and that velocity component
            lo, hi = q < 0.0, q > size
            if lo.any() or hi.any():
                q[lo] = -q[lo]
                q[hi] = 2.0 * size - q[hi]
                b[lo | hi] *= -1.0
        x[a], y[a], vx[a], vy[a] = px, py, bx, by
    return np.stack([x, y], axis=1), np.stack([vx, vy], axis=1)


#: up to this many rows :func:`free_motion` steps in Python floats (the same operations)
SCALAR_FREE = 16


def _free_motion_scalar(n, x, y, vx, vy, ct, st, hh, size):
    """:func:`free_motion`'s sub-steps for a few rows in Python floats: per row ``n`` sub-steps of
    the same products, sums and wall reflections as the array code, so the same results bit for
    bit; returns positions and velocities (k, 2)."""
    S2 = 2.0 * size
    pos, vel = [], []
    for k, px, py, ax, ay, c, s, h in zip(n, x, y, vx, vy, ct, st, hh):
        for _ in range(k):
            bx = c * ax - s * ay
            by = s * ax + c * ay
            px = px + h * (ax + bx)
            py = py + h * (ay + by)
            if px < 0.0:
                px, bx = -px, bx * -1.0
            elif px > size:
                px, bx = S2 - px, bx * -1.0
            if py < 0.0:
                py, by = -py, by * -1.0
            elif py > size:
                py, by = S2 - py, by * -1.0
            ax, ay = bx, by
        pos.append((px, py))
        vel.append((ax, ay))
    return np.array(pos, float).reshape(-1, 2), np.array(vel, float).reshape(-1, 2)
