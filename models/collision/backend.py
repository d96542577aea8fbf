"""The one interface of the collision backends: monitored pairs in, per-pair results out.

Every backend (``fcl``, ``basis_point``, ``honeycomb``) subclasses :class:`CollisionBackend`
and is driven through ``query(poses, dt) -> QueryResult``. The base class owns what is common:

* the poses and world transforms of all bodies, updated only for dynamic bodies that moved
  (per step as nested lists; the arrays ``poses`` / ``T`` / ``prev_T`` get a body's rows when
  a pair with the body is evaluated or the arrays are read);
* the skip rules: a pair none of whose bodies moved reuses its cached result (static-static
  pairs are evaluated once, at the first query, and never again); a step where no pose
  changed returns the previous result at once (``at_rest``);
* world AABBs and bounding spheres of the bodies (exact, from the transformed vertices);
* the closing speed of a pair from the pose change over the step;
* the far-pair skip of backends that declare ``FAR_SKIP`` (fcl): a pair whose last
  evaluation found every member's AABB at least ``max_distance`` away keeps its far result
  without any work while the AABB gaps cannot have closed to ``max_distance`` since (the
  gap bound of :meth:`CollisionBackend._far_holds`, else the backend's own gaps,
  :meth:`CollisionBackend._far_gap`), unless its first body is a fast mover that needs time
  of impact. The reported result and counters are exactly those of a full evaluation (which
  would find no candidate and no member within ``max_distance``).

Monitored pairs spec
--------------------
``"missile vs any tank; body_a vs body_b; avatar_1 vs scene"``: pairs separated by ``;`` (or
new lines), each ``A vs B`` where ``A`` is a body name and ``B`` is a body name, ``any G``
(every body whose group is ``G`` or whose name matches the glob ``G``, e.g. ``tank_1*``) or
``scene`` (every other body). An empty spec monitors each dynamic body against the scene.
A pair may end with options in parentheses: ``avatar_1 vs scene (horizontal)`` projects the
reported normal onto the horizontal plane (for ground vehicles and avatars).

Reported normal (all backends)
------------------------------
The unit normal points **from B to A**: the direction in which A has to move to separate
from its partner (``avatar_1 vs scene`` gives "from the obstacle to the avatar", what a
contact response needs). Separated: from B's nearest point to A's nearest point (fcl) or
the backend's separating axis. In contact: the separating direction of the pair's last
contact-free step with the same partner, kept while the contact holds; without such a
step (contact from the start, or the partner was beyond ``max_distance``) the backend's
contact normal (fcl: the deepest contact's), oriented from B to A. ``closing_speed`` > 0
when A and B approach along it. Beyond ``max_distance`` a pair reports ``distance =
max_distance``, no point, no normal and no partner; -1 is reserved for a pair without members.
"""
from __future__ import annotations

import fnmatch
import logging
import math
import struct
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from .exit import Footprints
from .geometry import pose_rows
from .scene import Scene, SceneError

log = logging.getLogger(__name__)

__all__ = ["BackendConfig", "PairSpec", "PairResult", "QueryResult", "CollisionBackend",
           "parse_pairs", "PairSpecError"]


class PairSpecError(SceneError):
    """The monitored-pairs spec names an unknown body or is malformed."""


@dataclass
class BackendConfig:
    """Options of the collision backends (each backend reads the ones it needs).

    Attributes
    ----------
    max_distance : float
        m; distances beyond it are not computed exactly (reported as ``max_distance``) and
        bodies farther apart never reach the narrow phase. ``inf``: always exact.
    ccd : bool
        fcl: time of impact for bodies that moved in the step.
    ccd_fast : float
        fcl: a body is a fast mover when its travel in the step (translation + angle x radius)
        exceeds ``ccd_fast`` times its thinnest extent; fast movers get conservative
        advancement over the swept volume (it cannot miss a tunnelling contact); slow movers,
        which cannot tunnel, get the time of impact from the distances at both ends of the step.
    max_contacts : int
        fcl: contacts requested per narrow-phase collision (deepest one is reported).
    chunk_faces : int
        fcl: exact distances against a mesh of at least ``CHUNK_MIN_FACES`` (1024) triangles
        are computed chunk by chunk (pieces of at most ``chunk_faces`` triangles, each its own
        BVH, visited in the order of a lower bound and pruned by it: exact, far fewer
        triangle pairs where large flat faces are nearest); 0: one whole-mesh BVH query
        (the mesh path).
    st : float
        basis_point: sampling threshold ST of eq. 5-8..5-11 (0.05 in the thesis).
    dn_rule : {'strict', 'floor'}
        basis_point: DN = largest integer strictly below 1/ST (text of §5.4.1) or floor(1/ST)
        (eq. 5-11 with equality, as table 5-5 lists DN = 20 for ST = 0.05).
    cells_n, cells_m : int
        honeycomb: n x m cells over the projection overlap (§4.4).
    shrink_ratio, shrink_step : float
        honeycomb: equal-ratio shrink start (5 %) and decrement (0.1 %), eq. 4-7.
    rays_per_cell : int
        honeycomb: k x k depth rays per cell (the ray-cast depth buffer of §4.2.2).
    honeycomb_axes : {'all', 'separating'}
        honeycomb: project on the three coordinate planes, or only across the most separating axis.
    """

    max_distance: float = math.inf
    ccd: bool = True
    ccd_fast: float = 0.5
    max_contacts: int = 32
    chunk_faces: int = 32
    st: float = 0.05
    dn_rule: str = "strict"
    cells_n: int = 8
    cells_m: int = 8
    shrink_ratio: float = 0.05
    shrink_step: float = 0.001
    rays_per_cell: int = 2
    honeycomb_axes: str = "all"

    def __post_init__(self) -> None:
        if not 0 < self.st < 1:
            raise ValueError(f"st = {self.st} must be in (0, 1)")
        if self.dn_rule not in ("strict", "floor"):
            raise ValueError(f"dn_rule = {self.dn_rule!r} must be 'strict' or 'floor'")
        if self.cells_n < 1 or self.cells_m < 1:
            raise ValueError(f"cells_n = {self.cells_n}, cells_m = {self.cells_m} must be >= 1")
        if not self.max_distance > 0:
            raise ValueError(f"max_distance = {self.max_distance} must be > 0")
        if not 0 < self.shrink_step <= self.shrink_ratio < 1:
            raise ValueError("need 0 < shrink_step <= shrink_ratio < 1")
        if self.honeycomb_axes not in ("all", "separating"):
            raise ValueError(f"honeycomb_axes = {self.honeycomb_axes!r} must be 'all' or 'separating'")
        if self.chunk_faces < 0:
            raise ValueError(f"chunk_faces = {self.chunk_faces} must be >= 0")
        if self.rays_per_cell < 1:
            raise ValueError(f"rays_per_cell = {self.rays_per_cell} must be >= 1")


@dataclass
class PairSpec:
    """A monitored pair: body ``a`` against the bodies ``members``."""

    label: str
    a: int
    members: np.ndarray
    horizontal: bool = False


@dataclass
class PairResult:
    """Result of one monitored pair in one step.

    Attributes
    ----------
    in_contact : bool
    distance : float
        m; 0 in contact (fcl), -1 when the pair has no member.
    depth : float
        m; penetration depth (>= 0).
    point : ndarray, shape (3,)
        Contact point (in contact) or the closest point on ``a`` (world frame, m).
    normal : ndarray, shape (3,)
        Unit normal. Backends' ``_evaluate`` return it from ``a`` towards the partner;
        :meth:`CollisionBackend.query` reports it from the partner towards ``a`` (the
        separation direction of ``a``, module docstring).
    toi : float
        s from the start of the step to the first contact, -1 when none in the step.
    closing_speed : float
        m/s, relative speed of ``a`` towards the partner along ``normal``.
    partner : int
        Body index of the nearest / deepest member, -1 when none.
    """

    in_contact: bool = False
    distance: float = -1.0
    depth: float = 0.0
    point: np.ndarray = field(default_factory=lambda: np.zeros(3))
    normal: np.ndarray = field(default_factory=lambda: np.zeros(3))
    toi: float = -1.0
    closing_speed: float = 0.0
    partner: int = -1


@dataclass
class QueryResult:
    """All monitored pairs of one step plus work counters."""

    pairs: List[PairResult]
    n_bodies: int
    n_candidates: int
    n_narrow: int
    at_rest: bool


def parse_pairs(spec: str, scene: Scene) -> List[PairSpec]:
    """Parse a monitored-pairs spec (module docstring) against ``scene``."""
    names = {b.name: i for i, b in enumerate(scene.bodies)}
    groups: Dict[str, List[int]] = {}
    for i, b in enumerate(scene.bodies):
        groups.setdefault(b.group, []).append(i)
    text = (spec or "").replace("\n", ";")
    parts = [p.strip() for p in text.split(";") if p.strip()]
    if not parts:
        parts = [f"{scene.bodies[i].name} vs scene" for i in scene.dynamic]
    known = ", ".join(list(names)[:8]) + (" ..." if len(names) > 8 else "")
    pairs = []
    for part in parts:
        label = part
        horizontal = False
        if part.endswith(")") and "(" in part:
            part, _, opts = part[:-1].rpartition("(")
            for opt in (o.strip() for o in opts.split(",")):
                if opt == "horizontal":
                    horizontal = True
                elif opt:
                    raise PairSpecError(f"pairs spec {label!r}: unknown option {opt!r} (options: horizontal)")
            part = part.strip()
        left, sep, right = part.partition(" vs ")
        if not sep:
            raise PairSpecError(f"pairs spec {label!r}: expected 'A vs B'")
        left, right = left.strip(), right.strip()
        if left not in names:
            raise PairSpecError(f"pairs spec {part!r}: no body named {left!r} (bodies: {known})")
        a = names[left]
        if right == "scene":
            members = [i for i in range(len(scene.bodies)) if i != a]
        elif right.startswith("any "):
            pattern = right[4:].strip()
            members = groups.get(pattern) or [i for n, i in names.items() if fnmatch.fnmatchcase(n, pattern)]
            members = [i for i in members if i != a]
            if not members:
                raise PairSpecError(f"pairs spec {part!r}: no body matches group or name {pattern!r}")
        elif right in names:
            if names[right] == a:
                raise PairSpecError(f"pairs spec {part!r}: a body cannot be paired with itself")
            members = [names[right]]
        else:
            raise PairSpecError(f"pairs spec {part!r}: no body named {right!r} (bodies: {known})")
        pairs.append(PairSpec(label, a, np.asarray(sorted(members), dtype=int), horizontal))
    return pairs


class CollisionBackend(ABC):
    """Common state and skip logic of every backend; subclasses implement ``_evaluate``.

    Parameters
    ----------
    scene : Scene
    pairs : str or list of PairSpec
        Monitored pairs (spec string or parsed).
    config : BackendConfig, optional
    """

    name = "abstract"
    #: the backend reports a pair whose members' AABB gaps are all >= ``max_distance`` as far
    #: (distance = max_distance, no candidate, no narrow-phase test) and sets ``_last_gap``
    #: in ``_evaluate`` (the smallest member AABB gap, or None), enabling the far-pair skip
    FAR_SKIP = False
    #: m of slack in the far-pair skip (covers the rounding of computed AABBs)
    FAR_MARGIN = 1e-9

    def __init__(self, scene: Scene, pairs, config: Optional[BackendConfig] = None) -> None:
        self.scene = scene
        self.config = config or BackendConfig()
        self.pairs: List[PairSpec] = parse_pairs(pairs, scene) if isinstance(pairs, (str, type(None))) else list(pairs)
        self.n = len(scene.bodies)
        self.dyn = np.asarray(scene.dynamic, dtype=int)
        self.is_dynamic = np.zeros(self.n, bool)
        self.is_dynamic[self.dyn] = True
        # the arrays behind the properties poses / T / prev_T: their dynamic rows are written
        # from the list forms (_dyn_poses, _T_rows, _prev_rows) only when read (_sync_rows)
        self._poses = scene.poses()
        self._T = scene.transforms(self._poses)
        self._prev_T = self._T.copy()
        self._qn = 0  # queries so far (the clock of the lazy rows)
        self._row_at = [0] * self.n  # query at which a body's T / prev_T rows were last written
        self._moved_at = [-1] * self.n  # query in which a body last moved
        self._same_rotation_at = [-1] * self.n  # query in which it last moved keeping its rotation
        self._prev_is_T = True  # the current query is the first: prev_T = T (no motion)
        self._poses_pending = False
        # per mesh: local vertices, bounding-sphere centre and radius (eq. 5-1)
        self._footprints = Footprints(scene)  # ground-plane parts of (horizontal) contacts (.exit)
        self._local: Dict[str, Tuple[np.ndarray, np.ndarray, float]] = {}
        for key, mesh in scene.meshes.items():
            v = np.asarray(mesh.vertices, float)
            c = (v.min(0) + v.max(0)) / 2
            # the AABB of a rotated mesh is that of its convex hull's vertices (fewer to rotate)
            try:
                hull = np.asarray(mesh.convex_hull.vertices, float) if len(v) > 64 else v
            except Exception:  # degenerate (flat) meshes: qhull fails, keep every vertex
                hull = v
            self._local[key] = (hull, c, float(np.linalg.norm(v - c, axis=1).max()))
        self.aabb = np.zeros((self.n, 2, 3))
        self.sphere_c = np.zeros((self.n, 3))
        self.sphere_r = np.array([self._local[b.mesh_key][2] for b in scene.bodies])
        self._aabb_cache: Dict[tuple, np.ndarray] = {}
        #: per dynamic body its last rotated local box: (rotation key, box, box as lists)
        self._dyn_box: Dict[int, tuple] = {}
        self._static_lists: Dict[int, tuple] = {}  # static bodies' AABBs as (lo, hi) lists
        self._static_rows: Dict[int, list] = {}  # static bodies' transforms as nested lists
        self._stale = np.zeros(self.n, bool)
        self._sphere_stale = np.zeros(self.n, bool)  # AABB current, bounding-sphere centre not
        self._is_dyn_list = self.is_dynamic.tolist()
        self._rot_key: Dict[int, Optional[bytes]] = {}
        self._update_bounds(np.arange(self.n))
        # dynamic bodies each pair depends on (for the skip rule)
        self._pair_dyn = [np.flatnonzero(self.is_dynamic[np.append(p.members, p.a)]) for p in self.pairs]
        self._pair_dyn = [set(np.append(p.members, p.a)[idx].tolist()) for p, idx in zip(self.pairs, self._pair_dyn)]
        self._dyn_list = self.dyn.tolist()
        self._n6 = 6 * len(self._dyn_list)
        #: each dynamic body with the start of its pose in a flat tuple of poses
        self._dyn_six = list(zip(self._dyn_list, range(0, self._n6, 6)))
        self._dyn_poses = {i: tuple(self._poses[i].tolist()) for i in self._dyn_list}
        self._cache: List[Optional[PairResult]] = [None] * len(self.pairs)
        self._previous: Optional[PairResult] = None
        self._last: Optional[QueryResult] = None
        # far-pair skip (FAR_SKIP backends): per body the largest distance of a hull vertex
        # from the body origin, and the running sum of per-step bounds on how far any face of
        # its AABB moved; per pair (smallest member gap, that sum over its bodies) when far
        self._rmax = [float(np.linalg.norm(self._local[b.mesh_key][0], axis=1).max()) if len(self._local[b.mesh_key][0])
                      else 0.0 for b in scene.bodies]
        self._shift = [0.0] * self.n
        # the transforms of the dynamic bodies as nested lists (current, and before this
        # query's move for the bodies that moved in it): scalar code for the per-step bounds
        self._T_rows: Dict[int, list] = {i: self._T[i].tolist() for i in self._dyn_list}
        self._prev_rows: Dict[int, list] = {}
        #: per body that moved in this query: (|t1 - t0|, ||R1 - R0||_F) of its move (_move)
        self._step_motion: Dict[int, Tuple[float, float]] = {}
        # per dynamic body: the bits of the (roll, pitch, yaw) its _T_rows rotation was made of
        self._rot_key = {i: _PACK3(*self._poses[i, 3:].tolist()) for i in self._dyn_list}
        self._toi_need: Dict[int, bool] = {}  # _needs_toi's answers in the current query
        self._pair_bodies = [sorted(d) for d in self._pair_dyn]
        self._far: List[Optional[Tuple[float, float]]] = [None] * len(self.pairs)
        self._last_gap: Optional[float] = None
        self._setup()
        #: the far-pair skip is on (set after ``_setup``: a backend may decide FAR_SKIP there)
        self._far_skip = bool(self.FAR_SKIP and math.isfinite(self.config.max_distance))
        #: m; a far pair's members' AABB gaps are at least this (max_distance and the slack)
        self._far_limit = self.config.max_distance + self.FAR_MARGIN

    # -- to implement -------------------------------------------------------------------
    def _setup(self) -> None:
        """Build backend structures (called once at the end of ``__init__``)."""

    @abstractmethod
    def _evaluate(self, pair: PairSpec, dt: float) -> Tuple[PairResult, int, int]:
        """Evaluate one pair at the current transforms (``self.prev_T`` holds the start of the
        step). Returns the result, the number of candidate pairs and of narrow-phase tests.

        The rows of ``_T`` / ``_prev_T`` of the pair's dynamic bodies are current (the query
        has called :meth:`_sync_rows` for them); other bodies' rows are read through the
        properties ``T`` / ``prev_T``."""

    # -- transforms -----------------------------------------------------------------------
    @property
    def T(self) -> np.ndarray:
        """World transforms of all bodies, shape (n, 4, 4) (at the current query's poses)."""
        self._sync_rows(self._dyn_list)
        return self._T

    @property
    def prev_T(self) -> np.ndarray:
        """World transforms at the start of the current query's step, shape (n, 4, 4) (the
        first query's and a rest step's equal ``T``)."""
        self._sync_rows(self._dyn_list)
        return self._prev_T

    @property
    def poses(self) -> np.ndarray:
        """Poses ``(x, y, z, roll, pitch, yaw)`` of all bodies, shape (n, 6) (m, rad)."""
        if self._poses_pending:
            self._poses_pending = False
            dyn_poses = self._dyn_poses
            for i in self._dyn_list:
                self._poses[i] = dyn_poses[i]
        return self._poses

    def _sync_rows(self, bodies) -> None:
        """Write the rows of ``_T`` / ``_prev_T`` of ``bodies`` from the list forms where they
        lag behind: a body that moved since its rows were written, or moved in the query that
        wrote them (its ``prev_T`` row is its ``T`` row in every later query until it moves)."""
        qn, at, moved_at = self._qn, self._row_at, self._moved_at
        for i in bodies:
            s = at[i]
            if s == qn or s > moved_at[i]:
                continue
            rows = self._T_rows[i]
            self._T[i] = rows
            self._prev_T[i] = rows if self._prev_is_T else self._prev_rows.get(i, rows)
            at[i] = qn

    def _rows(self, i: int) -> list:
        """The transform of body ``i`` as nested lists (a static body's converted once)."""
        rows = self._T_rows.get(i)
        if rows is None:
            rows = self._static_rows.get(i)
            if rows is None:
                rows = self._static_rows[i] = self._T[i].tolist()
        return rows

    def _prev_rows_of(self, i: int) -> list:
        """The transform of body ``i`` at the start of the current query's step as nested
        lists: the numbers of its ``prev_T`` row (:meth:`_sync_rows`)."""
        rows = self._rows(i)
        return rows if self._prev_is_T else self._prev_rows.get(i, rows)

    def _move(self, changed: List[Tuple[int, tuple]]) -> List[int]:
        """The dynamic bodies of ``changed`` (body, new pose) move: returns the bodies moved.

        Each gets its new transform as nested lists in ``_T_rows`` (its old one in
        ``_prev_rows``; the rotation of the old one when roll, pitch and yaw are the same bits:
        the same numbers :func:`pose_rows` would compute), the move's translation and rotation
        change ``(|t1 - t0|, ||R1 - R0||_F)`` in ``_step_motion`` (a cheap bound for the
        fast-mover test, :meth:`_needs_toi`) and, with the far-pair skip, the face-shift bound
        (:func:`_face_shift`). One loop for all bodies: this runs every step for every body."""
        dyn_poses, T_rows, prev_rows, motion = self._dyn_poses, self._T_rows, self._prev_rows, self._step_motion
        rot_key, same_at, moved_at, stale, qn = self._rot_key, self._same_rotation_at, self._moved_at, self._stale, self._qn
        shift, rmax, far_skip = self._shift, self._rmax, self._far_skip
        moved = []
        for i, row in changed:
            dyn_poses[i] = row
            old = prev_rows[i] = T_rows[i]
            key = _PACK3(row[3], row[4], row[5])
            if key == rot_key[i]:
                r0, r1, r2 = old[0], old[1], old[2]
                x, y, z = float(row[0]), float(row[1]), float(row[2])
                T_rows[i] = [[r0[0], r0[1], r0[2], x], [r1[0], r1[1], r1[2], y], [r2[0], r2[1], r2[2], z],
                             [0.0, 0.0, 0.0, 1.0]]
                same_at[i] = qn
                # _face_shift's terms (its arithmetic): the rotation's is exactly 0
                dx, dy, dz = x - r0[3], y - r1[3], z - r2[3]
                t, f = math.sqrt(dx * dx + dy * dy + dz * dz), 0.0
            else:
                M = T_rows[i] = pose_rows(row)
                rot_key[i] = key
                t, f = _face_shift(old, M)
            motion[i] = (t, f)
            if far_skip:
                shift[i] += t + f * rmax[i]
            moved_at[i] = qn
            stale[i] = True
            moved.append(i)
        return moved

    # -- bounds ---------------------------------------------------------------------------
    def ensure_bounds(self, idx) -> None:
        """Bring ``aabb`` / ``sphere_c`` of bodies ``idx`` up to date (they are lazy)."""
        idx = np.asarray(idx, dtype=int).ravel()
        stale = idx[self._stale[idx] | self._sphere_stale[idx]]
        if len(stale):
            self._update_bounds(stale)

    def _update_bounds(self, idx, spheres: bool = True) -> None:
        """World AABBs (and, with ``spheres``, bounding-sphere centres) of bodies ``idx`` at
        their current transforms; without ``spheres`` the centres stay stale (``ensure_bounds``
        brings them up to date)."""
        self._stale[idx] = False
        self._sphere_stale[idx] = not spheres
        self._sync_rows(idx)
        dynamic, rot_key = self._is_dyn_list, self._rot_key
        for i in idx:
            key = self.scene.bodies[i].mesh_key
            v, c, _ = self._local[key]
            T = self._T[i]
            # static bodies share rotated boxes by rotation; a dynamic body keeps its last one
            # (a body that only translates never rotates its vertices again: its rotation is
            # named by the bits of its roll, pitch and yaw, or by its own bits after set_state)
            if dynamic[i]:
                rkey = rot_key.get(i) or T[:3, :3].tobytes()
                last = self._dyn_box.get(i)
                box = last[1] if last is not None and last[0] == rkey else None
            else:
                rkey = (key, T[:3, :3].round(12).tobytes())
                box = self._aabb_cache.get(rkey)
            if box is None:
                pts = v @ T[:3, :3].T
                box = np.empty((2, 3))  # (lo, hi): the reductions written in place
                np.minimum.reduce(pts, 0, out=box[0])
                np.maximum.reduce(pts, 0, out=box[1])
                if dynamic[i]:
                    self._dyn_box[i] = (rkey, box, box.tolist())
                else:
                    self._aabb_cache[rkey] = box
            self.aabb[i] = box + T[:3, 3]
            if spheres:
                self.sphere_c[i] = T[:3, :3] @ c + T[:3, 3]

    def _aabb_lists(self, i: int) -> Tuple[list, list]:
        """Body ``i``'s world AABB as ``(lo, hi)`` lists: the numbers of ``aabb[i]`` brought up
        to date. A dynamic body that moved keeping the rotation of its last box gets them in
        scalar code, ``box + t`` per coordinate (what :meth:`_update_bounds` computes; its
        ``aabb`` row stays stale, written when read); a static body's are listed once."""
        if not self._is_dyn_list[i]:
            box = self._static_lists.get(i)
            if box is None:
                box = self._static_lists[i] = tuple(self.aabb[i].tolist())
            return box
        if self._stale[i]:
            last = self._dyn_box.get(i)
            if last is not None and last[0] == self._rot_key.get(i):
                rows = self._T_rows[i]
                (l0, l1, l2), (h0, h1, h2) = last[2]
                t0, t1, t2 = rows[0][3], rows[1][3], rows[2][3]
                return [l0 + t0, l1 + t1, l2 + t2], [h0 + t0, h1 + t1, h2 + t2]
            self._update_bounds([i], spheres=False)
        return self.aabb[i].tolist()

    def aabb_gap(self, a: int, members: np.ndarray) -> np.ndarray:
        """Euclidean gap between the AABB of ``a`` and those of ``members`` (0 if overlapping)."""
        if self._stale[a]:
            self._update_bounds([a])
        if self._stale[members].any():
            self.ensure_bounds(members)
        lo = np.maximum(self.aabb[members, 0] - self.aabb[a, 1], 0)
        hi = np.maximum(self.aabb[a, 0] - self.aabb[members, 1], 0)
        return np.linalg.norm(np.maximum(lo, hi), axis=1)

    # -- the query ----------------------------------------------------------------------
    def _changed(self, poses) -> List[Tuple[int, tuple]]:
        """The dynamic bodies whose pose differs from their last one, with the new pose as a
        6-tuple (scene order); every pose checked finite.

        A flat tuple of ``6 n_dynamic`` numbers (what the FMU passes) is sliced as it is when
        its sum is finite (then every entry is: an infinite or NaN entry makes the sum infinite
        or NaN); anything else (other forms, or a sum that overflows) goes through numpy."""
        dyn_poses = self._dyn_poses
        if type(poses) is tuple and len(poses) == self._n6:
            try:
                fast = math.isfinite(sum(poses))
            except (TypeError, ValueError, OverflowError):
                fast = False
            if fast:
                return [(i, row) for i, k in self._dyn_six if (row := poses[k:k + 6]) != dyn_poses[i]]
        arr = np.asarray(poses, dtype=float).reshape(len(self.dyn), 6)
        if not math.isfinite(float(arr.sum())) and not np.isfinite(arr).all():  # (a finite sum: all are)
            i, k = np.argwhere(~np.isfinite(arr))[0]
            raise ValueError(f"pose of dynamic body {self.scene.bodies[self.dyn[i]].name!r} "
                             f"({'x y z roll pitch yaw'.split()[k]}) = {arr[i, k]} is not finite")
        return [(i, row) for i, row in zip(self._dyn_list, map(tuple, arr.tolist())) if row != dyn_poses[i]]

    def query(self, poses: Sequence[Sequence[float]], dt: float = 0.033) -> QueryResult:
        """Advance to new poses of the dynamic bodies and evaluate every monitored pair.

        Parameters
        ----------
        poses : array_like, shape (n_dynamic, 6)
            ``(x, y, z, roll, pitch, yaw)`` of each dynamic body, scene order (m, rad).
        dt : float
            Step length (s): time of impact and closing speed refer to it.
        """
        changed = self._changed(poses)
        self._qn += 1
        self._prev_rows = {}
        self._step_motion = {}
        if self._last is not None and not changed:
            # nothing moved: the last contacts hold, nothing was tested, nothing is closing
            # (prev_T = T: no body moved in this query)
            rest = [_at_rest(r) for r in self._last.pairs]
            self._last = QueryResult(rest, self.n, 0, 0, True)
            return self._last
        # the first query's poses are the initial poses: the move from the scene spec's
        # pose to them is no motion (no time of impact, closing speed or honeycomb threshold)
        self._prev_is_T = self._last is None
        self._toi_need = {}
        moved = self._move(changed)
        self._poses_pending = True
        far_skip = self._far_skip
        if not far_skip:  # every moved pair is evaluated: write the rows at once
            self._sync_rows(moved)
        moved_set = set(moved)
        out, n_cand, n_narrow = [], 0, 0
        cache, pair_dyn, far = self._cache, self._pair_dyn, self._far
        for k, pair in enumerate(self.pairs):
            cached = cache[k]
            self._previous = cached  # the pair's result at the start of the step (for _evaluate)
            if cached is not None and moved_set.isdisjoint(pair_dyn[k]):
                # its at-rest form becomes the cached result (the same in every field the next
                # evaluation reads: contact, distance, partner, normal): the steps at rest that
                # follow return that one object (no new result; the FMU skips a result it has written)
                rest = cache[k] = _at_rest(cached)
                out.append(rest)
                continue
            if far_skip and far[k] is not None and self._far_holds(k, pair, moved_set):
                out.append(cached)  # the far result: no candidate, no test (class docstring)
                continue
            self._last_gap = None
            self._sync_rows(self._pair_bodies[k])
            if len(pair.members) == 0:
                res, c, m = PairResult(), 0, 0
            else:
                res, c, m = self._evaluate(pair, dt)
                self._report_normal(pair, res, cached)
            res.closing_speed = self._closing_speed(pair.a, res, dt)
            self._cache[k] = res
            if far_skip:
                self._far[k] = self._far_record(k, res, c, m)
            out.append(res)
            n_cand += c
            n_narrow += m
        self._last = QueryResult(out, self.n, n_cand, n_narrow, False)
        return self._last

    # -- far-pair skip ------------------------------------------------------------------
    def _far_record(self, k: int, res: PairResult, n_cand: int, n_narrow: int) -> Optional[Tuple[float, float]]:
        """What the far-pair skip of pair ``k`` needs after a full evaluation: (smallest member
        AABB gap, sum of the face-shift bounds of the pair's bodies), or None when the result
        is not the plain far one (a contact, a partner, a time of impact, any candidate)."""
        gap = self._last_gap
        if (gap is None or n_cand or n_narrow or res.in_contact or res.partner >= 0 or res.toi >= 0
                or not gap >= self.config.max_distance):
            return None
        shift = self._shift
        return float(gap), sum(shift[i] for i in self._pair_bodies[k])

    def _far_holds(self, k: int, pair: PairSpec, moved: set) -> bool:
        """The far result of pair ``k`` still holds: every member's AABB gap is still at least
        ``max_distance``, and the first body does not need a time of impact (:meth:`_needs_toi`).

        The gap is known without any bounds when it shrank by less than the slack: by at most
        ``sqrt(3)`` times the sum of the face shifts of both boxes (each axis' separation moves
        by at most that sum). Otherwise the backend's :meth:`_far_gap` (the members' AABB gaps
        themselves, what the evaluation would compute) decides, and becomes the new record."""
        gap, shift0 = self._far[k]
        now = sum(map(self._shift.__getitem__, self._pair_bodies[k]))
        limit = self._far_limit
        close = gap - _SQRT3 * (now - shift0) < limit
        if close and not self._far_gap_known:
            return False
        a = pair.a
        if a in moved:
            need = self._toi_need.get(a)  # decided already in this query (a body in two pairs)
            if need is None:
                need = self._toi_need[a] = self._needs_toi(a)
            if need:
                return False
        if close:
            exact = self._far_gap(k, pair)
            if exact is None or not exact >= limit:
                return False
            self._far[k] = (exact, now)
        return True

    #: the backend implements :meth:`_far_gap`
    _far_gap_known = False

    def _far_gap(self, k: int, pair: PairSpec) -> Optional[float]:
        """The smallest AABB gap (m) of pair ``k``'s members to its first body, as ``_evaluate``
        would compute it at the current transforms, or None when the backend cannot tell
        without evaluating (the far-pair skip then evaluates)."""
        return None

    def _needs_toi(self, a: int) -> bool:
        """Whether the motion of ``a`` (moved in this query: ``_prev_rows[a]`` is its transform
        before, ``_T_rows[a]`` after) calls for a time of impact with no contact at either end
        (backends with continuous collision override it)."""
        return False

    def _report_normal(self, pair: PairSpec, res: PairResult, prev: Optional[PairResult]) -> None:
        """Turn a backend result into the reported one (module docstring): cap the distance
        at ``max_distance``, normal from the partner to ``a``, a contact keeps the separating
        direction of the last contact-free step, optional horizontal projection."""
        md = self.config.max_distance
        if not res.in_contact and (res.distance < 0 or res.distance >= md):
            if math.isfinite(md):
                res.distance, res.partner = float(md), -1
                res.point, res.normal = np.zeros(3), np.zeros(3)
            return
        # scalar code on the three components (the numbers of the array expressions)
        n = [-x for x in np.asarray(res.normal, float).tolist()]
        if (res.in_contact and prev is not None and prev.partner == res.partner
                and prev.normal.any()):
            n = prev.normal.tolist()  # last separating direction, or the one the contact began with
        if pair.horizontal and res.in_contact:   # the shortest way out in the ground plane (.exit)
            out = self._horizontal_exit(pair)
            if out is not None:
                res.depth, n = out[0], [float(out[1][0]), float(out[1][1]), 0.0]
        if pair.horizontal and n[2] != 0.0:
            n[2] = 0.0
            if math.hypot(n[0], n[1]) < 1e-9 and res.partner >= 0:  # (nearly) vertical: centre to centre
                self.ensure_bounds([pair.a, res.partner])
                n = (self.sphere_c[pair.a] - self.sphere_c[res.partner]).tolist()
                n[2] = 0.0
                if math.hypot(n[0], n[1]) < 1e-9:
                    n = [0.0, 0.0, 0.0]
        norm = math.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
        res.normal = np.array([n[0] / norm, n[1] / norm, n[2] / norm]) if norm > 0 else np.zeros(3)

    def _horizontal_exit(self, pair: PairSpec):
        """Depth (m) and unit normal (2,) of the shortest ground-plane exit of ``pair.a`` from
        the members whose AABB overlaps its own (:mod:`.exit`), or None without overlap."""
        a = pair.a
        near = pair.members[self.aabb_gap(a, pair.members) <= 0.0].tolist()
        # a static body's transform is its row of T as it is (its footprint is kept after the first use)
        members = [(b, np.array(self._rows(b)), False) if self._is_dyn_list[b] else (b, self._T[b], True)
                   for b in near]
        return self._footprints.exit(a, np.array(self._rows(a)), members) if members else None

    def _closing_speed(self, a: int, res: PairResult, dt: float) -> float:
        if res.partner < 0 or dt <= 0:
            return 0.0
        b = res.partner
        if not (self.is_dynamic[a] or self.is_dynamic[b]):
            return 0.0
        # scalar code on the list forms of the T / prev_T rows (the same numbers)
        A1, A0, B1, B0 = self._rows(a), self._prev_rows_of(a), self._rows(b), self._prev_rows_of(b)
        n = res.normal.tolist()  # from b to a: approaching when a moves against it
        r0 = (A1[0][3] - A0[0][3]) - (B1[0][3] - B0[0][3])
        r1 = (A1[1][3] - A0[1][3]) - (B1[1][3] - B0[1][3])
        r2 = (A1[2][3] - A0[2][3]) - (B1[2][3] - B0[2][3])
        return -(r0 * n[0] + r1 * n[1] + r2 * n[2]) / dt

    # -- state (FMI get/set FMU state) ----------------------------------------------------
    def get_state(self) -> dict:
        """Everything that changes from step to step (poses, caches, last result)."""
        import copy

        return copy.deepcopy({"poses": self.poses, "T": self.T, "prev_T": self.prev_T,
                              "aabb": self.aabb, "sphere_c": self.sphere_c,
                              "cache": self._cache, "last": self._last})

    def set_state(self, state: dict) -> None:
        import copy

        state = copy.deepcopy(state)
        self._poses, self._T, self._prev_T = state["poses"], state["T"], state["prev_T"]
        self._poses_pending = False
        self.aabb, self.sphere_c = state["aabb"], state["sphere_c"]
        self._stale[self.dyn] = True
        self._cache, self._last = state["cache"], state["last"]
        self._dyn_poses = {i: tuple(self._poses[i].tolist()) for i in self._dyn_list}
        self._T_rows = {i: self._T[i].tolist() for i in self._dyn_list}
        self._rot_key = {i: None for i in self._dyn_list}
        self._prev_rows = {}
        self._step_motion = {}
        # the arrays hold the state's rows now; the next query writes them again (as if the
        # bodies had moved now, in a query number of their own: prev_T = T unless they move;
        # a backend's structures tagged with the query of a body's last move are stale)
        self._qn += 1
        for i in self._dyn_list:
            self._row_at[i] = self._moved_at[i] = self._qn
        self._far = [None] * len(self.pairs)


_SQRT3 = math.sqrt(3.0)
#: the bits of (roll, pitch, yaw): the key of a body's last rotation (``-0.0`` is not ``0.0``)
_PACK3 = struct.Struct("3d").pack


def _face_shift(T0: list, T1: list) -> Tuple[float, float]:
    """The two terms of a bound on how far any face of a body's world AABB moves from pose
    ``T0`` to ``T1`` (4x4 nested lists): ``|t1 - t0|`` and ``||R1 - R0||_F`` (m, 1); the bound
    is ``|t1 - t0| + ||R1 - R0||_F rmax``. A face coordinate is ``max_v (R v)_k + t_k`` over
    the hull vertices ``v`` (``|v| <= rmax``), and ``|((R1 - R0) v)_k| <= ||R1 - R0||_2 |v| <=
    ||R1 - R0||_F rmax``. (The fcl backend's pair distance cache bounds a body's motion with
    the same two terms.) Scalar code, the sums in row order, unrolled: this runs per moved body
    and step."""
    (a0, a1, a2, a3), (b0, b1, b2, b3), (c0, c1, c2, c3) = T0[0], T0[1], T0[2]
    (p0, p1, p2, p3), (q0, q1, q2, q3), (r0, r1, r2, r3) = T1[0], T1[1], T1[2]
    d3, e3, f3 = p3 - a3, q3 - b3, r3 - c3
    d0, d1, d2, e0, e1, e2, f0, f1, f2 = p0 - a0, p1 - a1, p2 - a2, q0 - b0, q1 - b1, q2 - b2, r0 - c0, r1 - c1, r2 - c2
    return (math.sqrt(d3 * d3 + e3 * e3 + f3 * f3),
            math.sqrt(d0 * d0 + d1 * d1 + d2 * d2 + e0 * e0 + e1 * e1 + e2 * e2 + f0 * f0 + f1 * f1 + f2 * f2))


def _at_rest(r: PairResult) -> PairResult:
    """``r`` with no time of impact and no closing speed (``r`` itself when it has neither:
    stored results are never modified, so they can be shared)."""
    if r.toi == -1.0 and r.closing_speed == 0.0 and math.copysign(1.0, r.closing_speed) > 0:
        return r
    return PairResult(r.in_contact, r.distance, r.depth, r.point, r.normal, -1.0, 0.0, r.partner)


def aggregate(results: List[Tuple[int, PairResult]], lower_bound: float) -> PairResult:
    """Combine per-member results: deepest contact if any, else the nearest member.

    ``lower_bound`` is the distance bound of the members that never reached the narrow phase.
    """
    if not results:
        return PairResult(distance=float(lower_bound) if math.isfinite(lower_bound) else -1.0)
    if len(results) == 1:  # (one member examined, the usual case: no search)
        b, best = results[0]
        toi = best.toi if best.toi >= 0 else -1.0
    else:
        contacts = [(b, r) for b, r in results if r.in_contact]
        if contacts:
            b, best = max(contacts, key=lambda br: br[1].depth)
        else:
            b, best = min(results, key=lambda br: br[1].distance)
        tois = [r.toi for _, r in results if r.toi >= 0]
        toi = min(tois) if tois else -1.0
    distance = best.distance
    if not best.in_contact and distance > lower_bound:  # an unexamined member may be nearer: report the bound
        distance = float(lower_bound)
    # (the constructor, not dataclasses.replace: the same fields, a few microseconds less)
    return PairResult(best.in_contact, distance, best.depth, best.point, best.normal, toi, best.closing_speed, b)
