"""The one interface of the collision backends: monitored pairs in, per-pair results out.

Every backend (``fcl``, ``basis_point``, ``honeycomb``) subclasses :class:`CollisionBackend`
and is driven through ``query(poses, dt) -> QueryResult``. The base class owns the poses
(:mod:`.poses`), the bodies' bounds (:mod:`.bounds`), the reported normal and closing speed,
and the skip rules: a pair none of whose bodies moved keeps its result; a step where no pose
changed returns the last result (``at_rest``); with ``FAR_SKIP`` the far-pair skip
(:mod:`.far`). Every skip reports exactly what a full evaluation would.

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
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from .bounds import Bounds
from .exit import Footprints
from .far import FarSkip
from .poses import PoseArrays, Poses
from .scene import Scene, SceneError

log = logging.getLogger(__name__)

__all__ = ["BackendConfig", "Shortcuts", "PairSpec", "PairResult", "QueryResult", "CollisionBackend",
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


@dataclass(frozen=True)
class Shortcuts:
    """The speed mechanisms that change no output, one switch each: each is tested bit for bit
    against the backend without it; its A/B is in ``results/collision/ab.md``.

    far_pairs: the far-pair skip (:mod:`.far`). distance_bounds (fcl): lower bounds of a pair's
    distance (:mod:`.pair_cache`, body-frame box gaps) skip ``fcl.collide`` of candidates they
    prove apart and exact distances that cannot beat the best so far. flat_poses: the FMU's
    flat pose tuple is sliced as it is, not converted by numpy. rotation_reuse: a body keeping
    the bits of its roll, pitch and yaw keeps its rotation rows. toi_pretests (fcl): the
    fast-mover test settled by the move's face shift or a scalar estimate before the travel.
    """

    far_pairs: bool = True
    distance_bounds: bool = True
    flat_poses: bool = True
    rotation_reuse: bool = True
    toi_pretests: bool = True


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
    shortcuts : Shortcuts, optional
        Default: all on.
    """

    name = "abstract"
    #: the backend reports a pair whose members' AABB gaps are all >= ``max_distance`` as far
    #: and sets ``_last_gap`` in ``_evaluate`` (the smallest member AABB gap, or None)
    FAR_SKIP = False
    #: m of slack in the far-pair skip (covers the rounding of computed AABBs)
    FAR_MARGIN = 1e-9

    def __init__(self, scene: Scene, pairs, config: Optional[BackendConfig] = None,
                 shortcuts: Optional[Shortcuts] = None) -> None:
        self.scene = scene
        self.config = config or BackendConfig()
        self.shortcuts = shortcuts or Shortcuts()
        self.pairs: List[PairSpec] = parse_pairs(pairs, scene) if isinstance(pairs, (str, type(None))) else list(pairs)
        self.n = len(scene.bodies)
        self.dyn = np.asarray(scene.dynamic, dtype=int)
        self.is_dynamic = np.zeros(self.n, bool)
        self.is_dynamic[self.dyn] = True
        #: the poses and transforms (one representation), their array forms and the bounds
        self.frames = Poses(scene, self.shortcuts.flat_poses, self.shortcuts.rotation_reuse)
        self.arrays = PoseArrays(self.frames)
        self.bounds = Bounds(scene, self.frames, self.arrays)
        self._footprints = Footprints(scene)  # ground-plane parts of (horizontal) contacts (.exit)
        # the dynamic bodies of each pair (a pair none of them moved keeps its result)
        self._pair_dyn = [{int(i) for i in np.append(p.members, p.a) if self.is_dynamic[i]} for p in self.pairs]
        self._pair_bodies = [sorted(d) for d in self._pair_dyn]
        self._cache: List[Optional[PairResult]] = [None] * len(self.pairs)
        self._previous: Optional[PairResult] = None  # the evaluated pair's result of the last step
        self._last: Optional[QueryResult] = None
        self._toi_need: Dict[int, bool] = {}  # _needs_toi's answers in the current query
        self._last_gap: Optional[float] = None
        self._setup()
        # (after _setup: a backend may decide FAR_SKIP there)
        self.far = FarSkip(self.bounds.local, [b.mesh_key for b in scene.bodies], self._pair_bodies,
                           self.config.max_distance, self.FAR_MARGIN,
                           bool(self.FAR_SKIP and self.shortcuts.far_pairs and math.isfinite(self.config.max_distance)))

    # -- to implement -------------------------------------------------------------------
    def _setup(self) -> None:
        """Build backend structures (called once at the end of ``__init__``)."""

    @abstractmethod
    def _evaluate(self, pair: PairSpec, dt: float) -> Tuple[PairResult, int, int]:
        """Evaluate one pair at the current transforms (``prev_T`` holds the start of the
        step). Returns the result, the number of candidate pairs and of narrow-phase tests."""

    # -- poses, transforms, bounds (array forms) -------------------------------------------
    @property
    def T(self) -> np.ndarray:
        """World transforms of all bodies, shape (n, 4, 4) (at the current query's poses)."""
        return self.arrays.T()

    @property
    def prev_T(self) -> np.ndarray:
        """World transforms at the start of the current query's step, shape (n, 4, 4)."""
        return self.arrays.prev_T()

    @property
    def poses(self) -> np.ndarray:
        """Poses ``(x, y, z, roll, pitch, yaw)`` of all bodies, shape (n, 6) (m, rad)."""
        return self.arrays.poses()

    @property
    def aabb(self) -> np.ndarray:
        """World AABBs, shape (n, 2, 3) (lo, hi; m): rows current after :meth:`ensure_bounds`."""
        return self.bounds.aabb

    @property
    def sphere_c(self) -> np.ndarray:
        return self.bounds.sphere_c

    @property
    def sphere_r(self) -> np.ndarray:
        return self.bounds.sphere_r

    def ensure_bounds(self, idx) -> None:
        """Bring ``aabb`` / ``sphere_c`` of bodies ``idx`` up to date."""
        self.bounds.ensure(idx)

    def aabb_gap(self, a: int, members: np.ndarray) -> np.ndarray:
        """Euclidean gap between the AABB of ``a`` and those of ``members`` (0 if overlapping)."""
        return self.bounds.gaps(a, members)

    # -- the query ----------------------------------------------------------------------
    def query(self, poses: Sequence[Sequence[float]], dt: float = 0.033) -> QueryResult:
        """Advance to new poses of the dynamic bodies and evaluate every monitored pair.

        Parameters
        ----------
        poses : array_like, shape (n_dynamic, 6), or a flat tuple of 6 n_dynamic numbers
            ``(x, y, z, roll, pitch, yaw)`` of each dynamic body, scene order (m, rad).
        dt : float
            Step length (s): time of impact and closing speed refer to it.
        """
        frames = self.frames
        changed = frames.changed(poses)
        frames.begin()
        if self._last is not None and not changed:
            # nothing moved: the last contacts hold, nothing was tested, nothing is closing
            self._last = QueryResult([_at_rest(r) for r in self._last.pairs], self.n, 0, 0, True)
            return self._last
        # the first query's poses are the initial poses: no motion
        self._toi_need = {}
        moved = frames.move(changed, self._last is None)
        self.bounds.moved(moved)
        far = self.far
        if far.on:
            far.moved(moved, frames.motion)
        moved_set = set(moved)
        out, n_cand, n_narrow = [], 0, 0
        cache, pair_dyn = self._cache, self._pair_dyn
        for k, pair in enumerate(self.pairs):
            cached = cache[k]
            self._previous = cached
            if cached is not None and moved_set.isdisjoint(pair_dyn[k]):
                # its at-rest form becomes the cached result: later steps at rest return that
                # one object (the FMU skips a result it has written)
                rest = cache[k] = _at_rest(cached)
                out.append(rest)
                continue
            if far.on and far.records[k] is not None and self._far_holds(k, pair, moved_set):
                out.append(cached)  # the far result: no candidate, no test
                continue
            self._last_gap = None
            if len(pair.members) == 0:
                res, c, m = PairResult(), 0, 0
            else:
                res, c, m = self._evaluate(pair, dt)
                self._report_normal(pair, res, cached)
            res.closing_speed = self._closing_speed(pair.a, res, dt)
            cache[k] = res
            if far.on:
                far.record(k, self._last_gap, not (c or m or res.in_contact or res.partner >= 0 or res.toi >= 0))
            out.append(res)
            n_cand += c
            n_narrow += m
        self._last = QueryResult(out, self.n, n_cand, n_narrow, False)
        return self._last

    def _far_holds(self, k: int, pair: PairSpec, moved: set) -> bool:
        """Pair ``k``'s far record still holds (:mod:`.far`): its gap cannot have closed to the
        limit, or the backend's exact gap (:meth:`_far_gap`) is still beyond it; and its first
        body, if it moved, needs no time of impact."""
        far = self.far
        close, now = far.closing(k)
        if close and not self._far_gap_known:
            return False
        if pair.a in moved and self._fast(pair.a):
            return False
        return not close or far.confirm(k, self._far_gap(k, pair), now)

    #: the backend implements :meth:`_far_gap`
    _far_gap_known = False

    def _far_gap(self, k: int, pair: PairSpec) -> Optional[float]:
        """The smallest AABB gap (m) of pair ``k``'s members to its first body, as ``_evaluate``
        would compute it, or None when the backend cannot tell without evaluating."""
        return None

    def _fast(self, a: int) -> bool:
        """:meth:`_needs_toi` of ``a``, once per query."""
        need = self._toi_need.get(a)
        if need is None:
            need = self._toi_need[a] = self._needs_toi(a)
        return need

    def _needs_toi(self, a: int) -> bool:
        """Whether the move of ``a`` in this query calls for a time of impact with no contact
        at either end (backends with continuous collision override it)."""
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
        the members whose AABB overlaps its own (:mod:`.exit`), or None without overlap; the
        members within the exit's length (AABB gap below the depth) count too: the exit
        may not end inside one of them."""
        a, rows = pair.a, self.frames.rows
        gap = self.aabb_gap(a, pair.members)
        Ta = np.array(rows[a])
        reach, out = 0.0, None
        while True:
            near = pair.members[gap <= reach].tolist()
            # a static body's footprint is kept after its first use
            members = [(b, np.array(rows[b]), False) if self.is_dynamic[b] else (b, self.arrays.T_of(b), True)
                       for b in near]
            out = self._footprints.exit(a, Ta, members) if members else None
            if out is None or not np.any((gap > reach) & (gap < out[0])):
                return out
            reach = out[0]

    def _closing_speed(self, a: int, res: PairResult, dt: float) -> float:
        """m/s; minus the relative translation of ``a`` over the step along the normal, / dt."""
        if res.partner < 0 or dt <= 0:
            return 0.0
        b = res.partner
        if not (self.is_dynamic[a] or self.is_dynamic[b]):
            return 0.0
        rows, prev = self.frames.rows, self.frames.prev
        A1, A0, B1, B0 = rows[a], prev[a], rows[b], prev[b]
        n = res.normal.tolist()  # from b to a: approaching when a moves against it
        r0 = (A1[0][3] - A0[0][3]) - (B1[0][3] - B0[0][3])
        r1 = (A1[1][3] - A0[1][3]) - (B1[1][3] - B0[1][3])
        r2 = (A1[2][3] - A0[2][3]) - (B1[2][3] - B0[2][3])
        return -(r0 * n[0] + r1 * n[1] + r2 * n[2]) / dt

    # -- state (FMI get/set FMU state) ----------------------------------------------------
    def get_state(self) -> dict:
        """Everything that changes from step to step (poses, bounds, cached results)."""
        import copy

        return copy.deepcopy({"frames": self.frames.state(), "bounds": self.bounds.state(),
                              "cache": self._cache, "last": self._last})

    def set_state(self, state: dict) -> None:
        import copy

        state = copy.deepcopy(state)
        self.frames.restore(state["frames"])
        self.bounds.restore(state["bounds"])
        self._cache, self._last = state["cache"], state["last"]
        self.far.reset()


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
