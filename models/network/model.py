"""The discrete-event network model (ch. 2-3): events on a heap, frames every 33 ms.

Time advances through a ``heapq`` of events, each at its own time: controller inputs
reaching a master, autopilot input changes, delayed collision responses, heartbeats,
time-out checks, joins and leaves. Render frames are ticks at ``k * frame_s`` (``k`` an
integer). The world (ground truth) is advanced exactly to each event's time before the event
is applied, so an input arriving 7.3 ms into a frame changes the avatar's motion from 7.3 ms.

Messages are sampled per (sender, receiver, PDU type) per frame with their own arrival
times (latency + jitter + serialisation on the sender's uplink); a receiver's cache takes a
record as soon as it has arrived, and what a node shows at tick ``k`` is its cache at
``k * frame_s`` dead-reckoned to that instant (§3.5.2, §3.6.3). A slave shows frame ``k`` only
if its FRAME packet arrived by ``k * frame_s``; a late packet is dropped (§3.5.2).

Order of work at a tick ``t_k``: collision responses, ownership (§3.6.2), publishing
(every frame, or DIS threshold), message building by topology and link sampling, delivery
of everything that has arrived by ``t_k``, slave frame flips, display and metrics.
"""
from __future__ import annotations

import copy
import heapq
import logging
import math
from typing import Dict, List, Optional

import numpy as np

from . import links as lk
from .arrays import pairwise_sum
from .config import NetworkConfig
from .consistency import SceneGrid, assign_owners, dead_reckon
from .display import DisplayGroups, squared_dr_error
from .ids import PastryOverlay
from .metrics import StepMetrics, Totals, inconsistency_sq, object_runs
from .nodes import H, PDU_NAMES, NodeRegistry, Traffic, TrafficPlan, build_messages, control_bytes
from .pdu import PduType, record_bytes
from .supernode import CONTROLLER, RENDER, Supernode
from .world import World

log = logging.getLogger(__name__)

HIST = 16  # frames of displayed-avatar history kept for slaves that lag
RID_OBJECT = float(2 ** 32)  # record id = object * 2^32 + record-table id (sorted by object, then table)
T_COL = 0  # cache row: record time, then p, v, a as the prediction order uses them (see NetworkModel)
#: queued events that change what the nodes show (heartbeats and time-out checks do not)
PENDING = frozenset(("input", "impulse", "join", "leave"))
MEMO_PAIRS = 4096  # at most this many view pairs: a frame's messages may be reused (see _messages)
MEASURE_CHUNK = 16384   # copies per chunk of the per-copy display error (fits a core's cache)
#: a resting scene whose displayed copies all hold records of the resting state skips the
#: display error (all zeros, see _display)
REST_DISPLAY = True
SCALAR_VIEW = 64        # at most this many view pairs: the display error in Python floats
GROUPS_MIN_PAIRS = 4096  # more view pairs than this: the display metric keeps record groups (see _measure)
#: at most this many records in a frame's small lossless batch: filed as lists (see _file_rows);
#: campus_drive's frames carry 3-6 STATE records (each of 3 masters to its 2 peers), where
#: the lists cost less than a record table (its fixed cost of state(), _table and _file)
FEW_RECORDS = 8


def _due_frames(arrivals: list, T: float, k: int) -> list:
    """For each arrival (s), the first frame (>= ``k``) whose time (frame ``T`` s) is >= it, or -1
    for an arrival that is not finite or beyond any int64 frame: :meth:`NetworkModel._due`
    in Python (``max(ceil(a / T - 1e-9), k)`` per arrival)."""
    out = []
    for a in arrivals:
        x = a / T - 1e-9
        if not x < 4611686018427387904.0:    # 2^62 (False for NaN too)
            out.append(-1)
        else:
            out.append(k if x <= k else math.ceil(x))
    return out


def _aligned_rows(n: int, w: int) -> np.ndarray:
    """Zeroed C-contiguous (n, w) float64 array whose rows start on 64-byte boundaries."""
    buf = np.zeros(n * w + 8)
    off = (-buf.ctypes.data % 64) // 8
    return buf[off:off + n * w].reshape(n, w)


_PREFIX_DTYPES: Dict[int, np.dtype] = {}


def _row_prefix(a: np.ndarray, ncol: int) -> np.ndarray:
    """The first ``ncol`` floats of every row of the C-contiguous (n, w) array ``a`` as one
    ``ncol * 8``-byte opaque item per row (a view: whole-record gathers and scatters)."""
    dt = _PREFIX_DTYPES.get(ncol)
    if dt is None:
        dt = _PREFIX_DTYPES[ncol] = np.dtype((np.void, 8 * ncol))
    return np.ndarray((a.shape[0],), dt, a, 0, (a.strides[0],))


class _Views:
    """Views into the model's arrays kept between frames. A copy (``deepcopy``, pickle) starts
    empty: a copied view would be an array of its own, no longer a view of the copied array.

    Attributes
    ----------
    cache_rows : (cache, the record-prefix view of its rows, :func:`_row_prefix`) or None
    """

    def __init__(self) -> None:
        self.cache_rows: Optional[tuple] = None

    def __deepcopy__(self, memo) -> "_Views":
        return _Views()

    def __reduce__(self):
        return _Views, ()


class NetworkModel:
    """Hybrid-P2P distributed VR network with consistency control.

    Parameters
    ----------
    cfg : NetworkConfig

    Attributes
    ----------
    world : World, ground truth
    owner : (G + E,) owning group of every object (avatars first)
    metrics : StepMetrics of the last :meth:`step`; ``totals`` accumulates over the run
    per_object_max, per_object_rms : (G + E,) m, eq. 3-1/3-2 errors at the last frame
    """

    def __init__(self, cfg: NetworkConfig) -> None:
        self.cfg = cfg
        self.rng = np.random.default_rng(cfg.seed)
        self.world = World(cfg, self.rng)
        self.reg = NodeRegistry(cfg)
        self.grid = SceneGrid(cfg.scene_size, cfg.grid_cells, cfg.grid)
        self.supernode = Supernode(cfg.heartbeat_timeout_s)
        G, E = cfg.groups, cfg.entities
        self.n_obj = G + E
        if self.n_obj >= 2 ** 21:
            raise ValueError(f"network model: {self.n_obj} objects, at most 2^21 - 1 (record ids object * 2^32 + table)")
        self.t = 0.0
        self.k = 0
        self.latency_scale = 1.0
        self._heap: List[tuple] = []
        self._pending = 0          # events of a kind in PENDING on the heap (see at_rest)
        self._seq = 0
        self.alive = np.zeros(self.reg.n, bool)       # node process running (sends heartbeats)
        self.online = np.zeros(self.reg.n, bool)      # listed in the supernode's table (see _set_online)
        self._n_online = 0                             # its number of True entries
        self.busy = np.zeros(self.reg.n)              # uplink busy-until (s)
        self.master = np.full(G, -1, np.int64)
        self.slaves: List[np.ndarray] = [np.zeros(0, np.int64) for _ in range(G)]
        self.shown_frame = np.zeros(self.reg.n, np.int64)
        self.inputs = np.zeros((G, 2))
        self.inputs_changed = False
        # what at_rest() needs of the last step: an input changed in it (the flag above is
        # cleared at the end of every step), and the frame traffic of the step before
        self._step_inputs_changed = False
        self._prev_frame_traffic: Optional[tuple] = None
        self._traffic_steady = False
        # ownership: avatars by their group; entities initially by the nearest avatar
        self.owner = np.r_[np.arange(G), self._initial_entity_owners()]
        self.pending_contact = np.zeros(E, bool)
        self._hold = np.full(self.n_obj, -np.inf)   # per object: no hand-over before this time (s)
        # receivers' caches (viewer group x object): one row of floats per (object, viewer),
        # flat index object * G + viewer (object-major: the pairs of a frame are sorted by
        # object, so gathers and scatters walk memory forward). Row: record time t, position
        # p (2), velocity v (2, orders >= 1), acceleration a (2, order 2), the record's id
        # (``rid_col``: records with the same id have the same content), and the time the
        # pair last entered the viewer's neighbourhood (``enter_col``, subscription). One
        # 64-byte row per pair (128 for order 2): the display error of a pair reads one cache
        # line instead of one per column.
        self._ncol = 1 + 2 * (1 + min(cfg.prediction_order, 2))   # record columns the order uses
        self.rid_col = self._ncol
        width = 8 if self._ncol + 2 <= 8 else 16
        self.enter_col = width - 1
        self.cache = _aligned_rows(G * self.n_obj, width)
        self.cache[:, T_COL] = -np.inf
        self._views = _Views()     # views into the cache, not part of the state
        self._obj_ids = np.arange(self.n_obj)
        self._obj_rid = self._obj_ids * RID_OBJECT
        self._uid = 1              # next record-table id (0: the scene file); rid = object * 2^32 + uid
        # owner's knowledge of what it last published (DIS; not kept up to date without DIS)
        self.pub_t = np.full(self.n_obj, -np.inf)
        self.pub_p = np.zeros((self.n_obj, 2))
        self.pub_v = np.zeros((self.n_obj, 2))
        self.pub_a = np.zeros((self.n_obj, 2))
        # records in flight, bucketed by the frame at which they are due: k -> chunks in send order
        self._inflight: Dict[int, List[tuple]] = {}
        self._epoch = 0            # bumped at every ownership change: older chunks are re-checked
        self._newest = -np.inf     # newest record time written into the cache so far
        #: FRAME packets on their way to slaves: (arrival s (inf: lost), slave node, frame k)
        self._frames: List[tuple] = []
        self._hist = np.zeros((HIST, G, G, 2))
        self._hist_rows: Dict[int, list] = {}   # history slots of small scenes not yet in the array (see hist)
        # subscription: object cells and online viewers of the last frame (a pair is in view
        # when the object's cell is in the 9-cell neighbourhood of the viewer avatar's cell);
        # None before the first frame: every pair counts as in view at frame 0 (scene file)
        self._view_prev: Optional[tuple] = None
        self._per_raw: Optional[tuple] = None   # per-object errors not yet made arrays (see per_object_max)
        self.per_object_max = np.zeros(self.n_obj)
        self.per_object_rms = np.zeros(self.n_obj)
        self.metrics = StepMetrics()
        self._last_display = (0.0, 0.0, 0)
        self.totals = Totals()
        self.overlay: Optional[PastryOverlay] = None
        self.join_hops: List[int] = []
        self._iv = [0, 0]                # messages, bytes since the last frame (heartbeats excluded)
        self._msg_memo: Optional[dict] = None    # the last small frame's messages (see _messages)
        self._og_memo: Optional[tuple] = None    # (epoch, view, owner of each view pair)
        self._owner_snap: Optional[tuple] = None  # (epoch, copy of the owners): senders of filed records
        self._group_version = 0                  # bumped whenever a group's master or slaves are set
        self._slaves_memo: Optional[tuple] = None  # (group version, slave nodes, arange(G), slave list)
        self._online_memo: Optional[tuple] = None  # (group version, groups with a master, their indices)
        self._hist_dest: Optional[tuple] = None    # slot positions of the avatar cache rows (_shown_avatars_scalar)
        self._pos_memo: Optional[tuple] = None     # (positions array, as a list)
        self._scalar_view_memo: Optional[tuple] = None  # (view owners, objects, flat indices, remote copies)
        self._cells_memo: Optional[tuple] = None   # (positions array, their cells, the cells as a list or None)
        self._exact: Optional[tuple] = None        # (positions array, first frame time it was used)
        self._display_clean: Optional[tuple] = None  # (P, view objects, view owners): errors all 0
        self._pub_memo: Optional[tuple] = None     # ((group version, epoch), published mask, objects)
        self._entity_ids = np.arange(G, self.n_obj)
        self._view_memo: Optional[tuple] = None  # (cells, online groups, view pairs, group version) of the last frame
        self._segments: Optional[tuple] = None   # (vo, per-object runs of vo)
        self._view_hit = False
        self._groups: Optional[DisplayGroups] = None  # record groups of the display metric (large views)
        self._frame_traffic = (0, 0)     # the same for the interval that ended at the last frame
        self._bootstrap()
        self._iv = [0, 0]                # the bootstrap JOINs belong to no frame interval
        self.metrics.online_nodes = self._n_online

    # -- set-up ---------------------------------------------------------------------------
    def _initial_entity_owners(self) -> np.ndarray:
        cfg, w = self.cfg, self.world
        E = cfg.entities
        if cfg.ownership == "none" or E == 0:
            return np.arange(E) % cfg.groups
        from scipy.spatial import cKDTree

        return cKDTree(w.apos).query(w.epos)[1].astype(np.int64)

    def _bootstrap(self) -> None:
        cfg, reg = self.cfg, self.reg
        for g in range(cfg.groups):
            self._join(0.0, reg.controller(g))
            for i in reg.render_nodes(g):
                self._join(0.0, int(i))
        self._rebuild_overlay()
        phase = self.rng.uniform(0.0, cfg.heartbeat_s, reg.n - 1)
        for i in range(reg.n - 1):
            self._push(float(phase[i]), "heartbeat", i)
        self._push(cfg.heartbeat_s, "expire")
        for g in range(cfg.driven_groups, cfg.groups):
            self._autopilot(0.0, g)
        self._publish_initial()
        # frame 1 comes from the scene file every node has loaded (no packet needed)
        sl = np.concatenate(self.slaves) if self.slaves else np.zeros(0, np.int64)
        self._frames = [(0.0, node, 1) for node in sl.tolist()]
        self._display()

    def _publish_initial(self) -> None:
        """Frame 0: every node starts from the same scene file (the shared initial state)."""
        P, V, A = self.world.state()
        self._uid = 0
        rec = self._table(np.arange(self.n_obj), 0.0, P, V, A)
        n = self.rid_col + 1
        self.cache[:, :n] = np.repeat(rec[:, :n], self.cfg.groups, axis=0)
        self.pub_t[:] = 0.0
        self.pub_p, self.pub_v, self.pub_a = P.copy(), V.copy(), A.copy()

    def _table(self, objs: np.ndarray, t, P: np.ndarray, V: np.ndarray, A: np.ndarray) -> np.ndarray:
        """A new record table (len(objs), cache width): rows ``t, p, v, a`` (the columns the
        prediction order uses) of objects ``objs`` and their record ids under a fresh table id."""
        tab = np.empty((len(objs), self.cache.shape[1]))
        tab[:, T_COL] = t
        tab[:, 1:3] = P
        if self._ncol >= 5:
            tab[:, 3:5] = V
        if self._ncol >= 7:
            tab[:, 5:7] = A
        if objs is self._obj_ids:   # a frame's table: every object, ids object * 2^32 kept
            np.add(self._obj_rid, self._uid, out=tab[:, self.rid_col])
        else:
            tab[:, self.rid_col] = objs * RID_OBJECT + self._uid     # exact in float64 (< 2^53)
        self._uid += 1
        return tab

    def _push(self, t: float, kind: str, *data) -> None:
        self._seq += 1
        self._pending += kind in PENDING
        heapq.heappush(self._heap, (t, self._seq, kind, data))

    # -- membership -------------------------------------------------------------------------
    def _join(self, t: float, node: int) -> None:
        reg = self.reg
        g = int(reg.group[node])
        kind = CONTROLLER if node >= reg.controller0 else RENDER
        self.supernode.join(t, node, reg.identify[g], kind, reg.ip[node], reg.port[node], self.cfg.scene_id)
        self.alive[node] = True
        self._set_online(node, True)
        if kind == RENDER:
            self._refresh_group(g)

    def _set_online(self, node: int, on: bool) -> None:
        """Mark ``node`` listed (or not) in the supernode's table, keeping the count of
        online nodes (``StepMetrics.online_nodes``)."""
        if bool(self.online[node]) != on:
            self._n_online += 1 if on else -1
            self.online[node] = on

    def _leave(self, node: int, timed_out: bool) -> None:
        if not self.online[node]:
            return
        self.supernode.leave(node, timed_out)
        self._set_online(node, False)
        g = int(self.reg.group[node])
        if node < self.reg.controller0:
            self._refresh_group(g)

    def _refresh_group(self, g: int) -> None:
        """Master = first online render node of the group (§3.5.1 rule 1); the rest are slaves."""
        rows = self.supernode.group(self.reg.identify[g])
        nodes = np.array([r.node for r in rows], np.int64)
        old = self.master[g]
        self._group_version += 1
        self.master[g] = nodes[0] if len(nodes) else -1
        self.slaves[g] = nodes[1:]
        self.shown_frame[nodes[1:]] = np.minimum(self.shown_frame[nodes[1:]], self.k) if len(nodes) > 1 else 0
        if old != self.master[g] and self.overlay is not None:
            self._rebuild_overlay(new_master=int(self.master[g]) if self.master[g] >= 0 else None)

    def _rebuild_overlay(self, new_master: Optional[int] = None) -> None:
        """Pastry overlay of the cluster's masters; a new master routes a JOIN to its own ID."""
        ids = [self.reg.nid[m] for m in self.master if m >= 0]
        if not ids:
            self.overlay = None
            return
        cfg = self.cfg
        if len(ids) > 512:  # routing tables of very large clusters are built lazily (cost O(N^2))
            self.overlay = None
            return
        self.overlay = PastryOverlay(ids, cfg.pastry_b, cfg.pastry_L, cfg.pastry_M)
        if new_master is not None and len(ids) > 1:
            me = self.reg.nid[new_master]
            boot = min((i for i in ids if i != me))
            hops = len(self.overlay.route(boot, me)) - 1
            self.join_hops.append(hops)
            self._count(hops, hops * H, PduType.JOIN)

    def schedule_leave(self, t: float, node: int, graceful: bool = True) -> None:
        """Node ``node`` leaves at ``t`` (graceful: LEAVE PDU; else it crashes and times out)."""
        self._push(t, "leave", node, graceful)

    def schedule_join(self, t: float, node: int) -> None:
        self._push(t, "join", node)

    # -- inputs ------------------------------------------------------------------------------
    def set_input(self, g: int, throttle: float, steer: float, t: Optional[float] = None) -> None:
        """Driver input of group ``g`` at time ``t`` (default: now).

        A change travels as a ControllerPacket controller -> supernode -> master (hybrid and
        client-server; direct over the LAN in full mesh) and acts when it arrives.
        """
        t = self.t if t is None else t
        if self.inputs[g, 0] == throttle and self.inputs[g, 1] == steer:
            return
        self.inputs[g] = throttle, steer
        self.inputs_changed = True
        delay = self._control_delay()
        self._push(t + delay, "input", g, float(throttle), float(steer))

    def _control_delay(self) -> float:
        links = self.cfg.links
        if self.cfg.topology == "full_mesh":
            self._count(1, control_bytes(), PduType.CONTROL)
            return float(self.latency_scale * lk.sample_latency(self.rng, links["lan"], 1)[0])
        self._count(2, 2 * control_bytes(), PduType.CONTROL)
        return float(self.latency_scale * lk.latency_sum(self.rng, links["wan"], 2))

    def _autopilot(self, t: float, g: int) -> None:
        thr = float(self.rng.uniform(0.1, 0.6))
        steer = float(self.rng.uniform(-0.3, 0.3))
        self._push(t + self._control_delay(), "input", g, thr, steer)
        self._push(t + float(self.rng.exponential(self.cfg.autopilot_change_s)), "autopilot", g)

    def bounce(self, g: int, normal, restitution: Optional[float] = None, depth: float = 0.0) -> float:
        """Collision response input for avatar ``g`` against a static obstacle: contact normal
        (from the obstacle to the avatar), penetration ``depth`` (m) removed along it, velocity
        reflected when approaching (stop if restitution 0); returns |dv| (m/s)."""
        e = self.cfg.restitution if restitution is None else restitution
        return self.world.bounce_avatar(g, normal, e, depth)

    def inject_update(self, sender_group: int, viewer_group: int, obj: int, pos, vel=(0.0, 0.0),
                      arrival: Optional[float] = None) -> None:
        """Put a STATE record from ``sender_group`` for ``obj`` in flight (e.g. a forged one)."""
        t = self.t if arrival is None else arrival
        rec = self._table(np.array([obj]), self.t, np.asarray(pos, float)[None], np.asarray(vel, float)[None],
                          np.zeros((1, 2)))
        self._add_inflight(np.array([t]), np.array([self.index(viewer_group, obj)]), np.array([sender_group]),
                           rec, np.zeros(1, np.int64), epoch=-1)

    # -- stepping ------------------------------------------------------------------------------
    def step(self, h: float) -> StepMetrics:
        """Advance the model by ``h`` seconds; returns the step's metrics."""
        T = self.cfg.frame_s
        eps = 1e-9
        t_end = self.t + h
        k_end = round(t_end / T)
        if abs(t_end - k_end * T) < eps:  # masters differ in the last ulp of t + h: snap to the frame grid
            t_end = k_end * T
        self.metrics = StepMetrics()
        while True:
            t_tick = (self.k + 1) * T
            t_ev = self._heap[0][0] if self._heap else math.inf
            t_next = t_ev if t_ev < t_tick else t_tick      # min(t_tick, t_ev)
            if t_next > t_end + eps:
                break
            if t_next > self.t:                              # self.t = max(self.t, t_next)
                self.t = t_next
            if t_ev <= t_tick:
                _, _, kind, data = heapq.heappop(self._heap)
                self._pending -= kind in PENDING
                self._handle(kind, data)
            else:
                self.k += 1
                self.world.advance_to(self.t)
                self._tick()
        self.world.advance_to(t_end)
        self.t = t_end
        m = self.metrics
        if m.frames == 0:  # no frame in a short step: the display (and its error) is unchanged
            m.inconsistency_max, m.inconsistency_rms, m.desync_frames = self._last_display
        self._last_display = (m.inconsistency_max, m.inconsistency_rms, m.desync_frames)
        m.online_nodes = self._n_online
        m.frame_messages, m.frame_bytes = self._frame_traffic
        self.totals.add(m)
        self._step_inputs_changed = self.inputs_changed
        self._traffic_steady = self._frame_traffic == self._prev_frame_traffic
        self._prev_frame_traffic = self._frame_traffic
        self.inputs_changed = False
        return m

    def _handle(self, kind: str, data: tuple) -> None:
        t = self.t
        if kind == "input":
            g, thr, steer = data
            if self.master[g] >= 0:
                self.world.advance_to(t, entities=False)
                self.world.set_input(g, thr, steer)
        elif kind == "autopilot":
            self._autopilot(t, data[0])
        elif kind == "impulse":
            e, dv, g = data
            self.world.advance_to(t, avatars=False)
            self.world.push_entity(e, np.asarray(dv))
            self.pending_contact[e] = False
            self._handover(np.array([self.cfg.groups + e]), np.array([g]))
        elif kind == "heartbeat":
            node = data[0]
            if self.alive[node]:
                self.supernode.heartbeat(t, node)
                self._count(1, H, PduType.HEARTBEAT)
                self._push(t + self.cfg.heartbeat_s, "heartbeat", node)
        elif kind == "expire":
            for node in self.supernode.expire(t):
                self._set_online(node, False)
                self._refresh_group(int(self.reg.group[node]))
            self._push(t + self.cfg.heartbeat_s, "expire")
        elif kind == "leave":
            node, graceful = data
            self.alive[node] = False
            if graceful:
                self._count(1, H, PduType.LEAVE)
                self._leave(node, timed_out=False)
        elif kind == "join":
            node = data[0]
            if not self.online[node]:
                self._count(1, H, PduType.JOIN)
                self._join(t, node)
                self._push(t + self.cfg.heartbeat_s, "heartbeat", node)
        else:  # pragma: no cover
            raise ValueError(f"network model: unknown event {kind!r} at t = {t}")

    def _count(self, messages: int, nbytes: int, ptype: int) -> None:
        self.metrics.messages += int(messages)
        self.metrics.bytes += int(nbytes)
        if ptype != PduType.HEARTBEAT:
            self._iv[0] += int(messages)
            self._iv[1] += int(nbytes)
        bt = self.totals.by_type
        name = PDU_NAMES[int(ptype)]
        bt[name] = bt.get(name, 0) + int(nbytes)

    def _handover(self, objs: np.ndarray, new: np.ndarray) -> None:
        if self.cfg.ownership == "none":
            return
        changed = (self.owner[objs] != new) & (self._hold[objs] <= self.t + 1e-9)   # (hysteresis)
        if changed.any():
            n = int(changed.sum())
            o, old = objs[changed], self.owner[objs[changed]]
            # the old owner knew the exact state when it let go: its cache starts from it
            w = self.world
            P, V, A = (x[o] for x in w.state())
            rec = self._table(o, self.t, P, V, A)
            self._scatter(self.index(old, o), rec, np.arange(len(o)))
            self._display_clean = None
            self._newest = max(self._newest, self.t)
            self._epoch += 1
            self.owner[o] = new[changed]
            self._hold[o] = self.t + self.cfg.handover_hold_s
            if self._groups is not None:          # the new owner's copy is no longer a remote one
                self._groups.touch(self.index(self.owner[o], o))
            self.metrics.handovers += n
            self._count(n, n * (H + record_bytes(self.cfg.prediction_order)), PduType.HANDOVER)

    # -- a frame --------------------------------------------------------------------------------
    def _tick(self) -> None:
        cfg, w = self.cfg, self.world
        t = self.k * cfg.frame_s
        G = cfg.groups
        self.metrics.frames += 1
        online_g, cand = self._online_groups()
        # 1. collision responses between avatars and entities (the owner responds)
        # one k-d tree of the entities shared by contacts and ownership (large scenes only:
        # small ones use brute force, cheaper than a tree built every frame)
        etree = w.entity_index() if cfg.entities and cfg.groups * cfg.entities > 4096 else None
        # a small scene without DIS below order 2 takes its positions first as a list too (again
        # when a contact's separation moved them), and its velocities only where read (lazy)
        lazy = (cfg.dis_threshold <= 0 and cfg.prediction_order < 2 and self.n_obj <= SCALAR_VIEW
                and (cfg.entities or w._fixed_key is None))    # (a resting scene: state()'s kept arrays)
        pl = vl = None     # (positions list; avatar velocities list when ownership computed them)
        if lazy:
            P = w.positions()
            pl = self._positions_list(P)
        moved = w.separated
        ai, ei, dv = w.contacts(etree, pl, online_g)
        if w.separated != moved:   # overlaps were removed: positions (and their index) changed
            etree = w.entity_index() if etree is not None else None
            if lazy:
                P = w.positions()
                pl = self._positions_list(P)
        if len(ai):
            self.metrics.contacts += len(ai)
            local = self.owner[G + ei] == ai
            for e, d in zip(ei[local], dv[local]):
                w.push_entity(e, d)
            remote = ~local & ~self.pending_contact[ei]
            if remote.any():
                # the contact is reported to the owner (slave/master report, §3.5.1 rule 3)
                lat = self.latency_scale * lk.sample_latency(self.rng, cfg.links["wan"], int(remote.sum()))
                for e, d, g, L in zip(ei[remote], dv[remote], ai[remote], lat):
                    self.pending_contact[e] = True
                    self._push(t + float(L), "impulse", int(e), d.copy(), int(g))
                self.metrics.remote_contacts += int(remote.sum())
        # 2. ownership (§3.6.2)
        # accelerations only where read: order-2 records, the DIS test's last published state
        if lazy:
            V = A = None
        else:
            P, V, A = w.state(acc=cfg.prediction_order >= 2 or cfg.dis_threshold > 0)
        if cfg.ownership != "none" and cfg.entities:
            cur = self.owner[G:]
            if len(cand) == G:   # every group online: local indices are the groups (V[:G] is avel)
                vl = w.avatar_velocities() if lazy else None
                new = assign_owners(cfg.ownership, w.apos, None if lazy else V[:G], w.epos, cur, cfg.frame_s,
                                    cfg.ownership_scale, cfg.ownership_min_axis, cfg.ownership_foci, etree,
                                    (pl[:G], vl, pl[G:]) if lazy else None)
            else:
                cur_local = np.minimum(np.searchsorted(cand, cur), max(len(cand) - 1, 0))
                new_local = assign_owners(cfg.ownership, w.apos[cand], w.avel[cand], w.epos, cur_local,
                                          cfg.frame_s, cfg.ownership_scale, cfg.ownership_min_axis,
                                          cfg.ownership_foci, etree)
                claimed = new_local != cur_local
                new = cur.copy()
                new[claimed] = cand[new_local[claimed]]
            if new is not cur:   # (assign_owners may return cur itself: nobody changed owner)
                self._handover(self._entity_ids, new)
        # 3. publishing: every frame, or DIS threshold / heartbeat
        if cfg.dis_threshold > 0:
            has_owner = online_g[self.owner]
            pred = dead_reckon(self.pub_p, self.pub_v, self.pub_a, t - self.pub_t, cfg.prediction_order)
            err = np.hypot(*(pred - P).T)
            pub = has_owner & ((err > cfg.dis_threshold) | (t - self.pub_t >= cfg.dis_heartbeat_s))
            pub_obj = np.flatnonzero(pub)
        else:   # every object with an online owner (kept while groups and owners stay)
            memo = self._pub_memo
            if memo is None or memo[0] != (self._group_version, self._epoch):
                pub = online_g[self.owner]
                memo = self._pub_memo = ((self._group_version, self._epoch), pub, np.flatnonzero(pub))
            pub, pub_obj = memo[1], memo[2]
        if cfg.dis_threshold > 0:   # what the owner last published: read by the DIS test only
            self.pub_t[pub_obj] = t
            self.pub_p[pub_obj], self.pub_v[pub_obj], self.pub_a[pub_obj] = P[pub_obj], V[pub_obj], A[pub_obj]
        self.metrics.published += len(pub_obj)
        if self._exact is None or self._exact[0] is not P:   # a new position array: a new streak
            self._exact = (P, t)
        # 4. messages by topology, link sampling
        cm = self._cells_memo
        if cm is not None and cm[0] is P:   # the same position array (a scene at rest): the same cells
            cells = cm[1]
        else:
            cl = self.grid._cell_scalar(self._positions_list(P)) if len(P) <= SCALAR_VIEW else None
            if cl is not None and cm is not None and cm[2] == cl:   # nobody changed cell: the same array
                cells = cm[1]
            else:
                cells = self.grid.cell(P) if cl is None else np.array(cl, np.int64)
            self._cells_memo = (P, cells, cl)
        view = self._view(cells, online_g)
        vo, vg, fi, frame_size = view
        og = self._view_owners(view)
        newly = None                     # None: nobody entered a view this frame
        if cfg.topology == "full_mesh":  # a broadcast subscribes everyone to everything
            pass
        elif self._view_hit:             # same cells and viewers as the last frame: nobody entered
            self._view_prev = (cells, online_g)
        else:
            newly = self._entered(cells, online_g, vg, vo)
            if newly.any():
                self.cache[fi[newly], self.enter_col] = t
                self._display_clean = None
            else:
                newly = None
            self._view_prev = (cells, online_g)
        tr, memo = self._messages(t, pub, pub_obj, view, newly, og)
        arr_l = self._transmit_floats(tr)    # a small lossless batch in Python floats (or None)
        if arr_l is None:
            arrival, lost = self._transmit(tr)
        due = None
        if len(tr.rec_msg):
            # the frame at which each record is due is its message's (-1: the message, or the
            # first hop a relayed record waits for, was lost)
            if arr_l is not None:
                rec_msg, _, carriers = tr.plan.lists()
                due_c = _due_frames([arr_l[i] for i in carriers], cfg.frame_s, self.k)
                if due_c.count(due_c[0]) == len(due_c):   # every record due at one frame
                    due = due_c[0]
                else:
                    at = dict(zip(carriers, due_c))
                    due = [at[i] for i in rec_msg]
            else:
                due_msg = self._due(arrival)
                due_msg[lost] = -1
                due = np.take(due_msg, tr.rec_msg)
                if tr.plan.wait is not None:
                    hop = tr.rec_hop1
                    due[(hop >= 0) & np.take(lost, np.maximum(hop, 0))] = -1
            snap = self._owner_snap
            if snap is None or snap[0] != self._epoch:
                snap = self._owner_snap = (self._epoch, self.owner.copy(), None)
            if arr_l is not None and len(tr.rec_msg) <= FEW_RECORDS and memo is not None:
                self._file_rows(due, memo, tr, snap, t, P, V, A, vl)
                due = None
        if due is not None:
            # one record table per frame (objects x cache width, rows like the cache's); pairs
            # refer to it by object; the senders are the owners now (one snapshot per epoch)
            if V is None:
                V = w.state(acc=False)[1]
            table = self._table(self._obj_ids, t, P, V, A)
            if memo is None or memo.get("rec_fi") is None:
                rec_fi = self.index(tr.rec_viewer, tr.rec_obj)
                if memo is not None:
                    memo["rec_fi"] = rec_fi
            else:
                rec_fi = memo["rec_fi"]
            self._file(due, rec_fi, snap[1], table, tr.rec_obj, t_send=float(t))
        if len(tr.frame_msg):
            nxt = self.k + 1
            if arr_l is not None:   # nothing lost
                self._frames += [(arr_l[i], node, nxt) for i, node in tr.plan.lists()[1]]
            else:
                arr_l, lost_l = arrival.tolist(), lost.tolist()
                self._frames += [(math.inf if lost_l[i] else arr_l[i], node, nxt)
                                 for i, node in zip(tr.frame_msg.tolist(), tr.frame_slave.tolist())]
        # 5. deliveries up to now, slave frame flips (§3.5.2)
        self._deliver(t)
        self._flip_frames(t)
        # 6. display and metrics (eq. 3-1/3-2)
        self._display(vg, vo, fi, og, cells, online_g, P)
        self._frame_traffic = (self._iv[0], self._iv[1])
        self._iv = [0, 0]

    def _online_groups(self):
        """Groups with a master (G,) bool (read-only) and their indices, kept while the groups
        stay (the masters change only in :meth:`_refresh_group`, which bumps the version)."""
        memo = self._online_memo
        if memo is None or memo[0] != self._group_version:
            online_g = self.master >= 0
            online_g.flags.writeable = False
            memo = self._online_memo = (self._group_version, online_g, np.flatnonzero(online_g))
        return memo[1], memo[2]

    def _messages(self, t: float, pub: np.ndarray, pub_obj: np.ndarray, view: tuple, newly: Optional[np.ndarray],
                  og: np.ndarray):
        """This frame's messages (:func:`nodes.build_messages`) with their :class:`TrafficPlan`,
        and the memo entry (a dict, or None) they came from.

        In small scenes (at most ``MEMO_PAIRS`` view pairs) the messages of the last frame are
        reused when every input but the time is the same (groups, owners, publications,
        view pairs): only the send times, ``t`` or ``t`` plus the composition time, differ.
        Without DIS and with nobody entering a view, those inputs are functions of the
        groups (``_group_version``), the owners (``_epoch``) and the view pairs (the object
        ``view``), so the memo is found without comparing arrays.
        """
        cfg = self.cfg
        vo, vg, fi, frame_size = view
        memo = self._msg_memo
        fast = None
        if len(vg) <= MEMO_PAIRS:
            if cfg.dis_threshold <= 0 and newly is None:
                fast = (self._group_version, self._epoch)
                if memo is not None and memo["fast"] == fast and memo["view"] is view:
                    return self._resend(memo, t), memo
            send_pair = pub[vo] if newly is None else pub[vo] | newly
            key = (self.master.tobytes(), tuple(s.tobytes() for s in self.slaves), pub_obj.tobytes(),
                   self.owner.tobytes(), vg.tobytes(), vo.tobytes(), send_pair.tobytes(), og.tobytes())
            if memo is not None and memo["key"] == key:
                memo["fast"], memo["view"] = fast, view
                return self._resend(memo, t), memo
        else:
            send_pair = pub[vo] if newly is None else pub[vo] | newly
        tr = build_messages(cfg, self.reg, t, self.master, self.slaves, pub_obj, self.owner, vg, vo, frame_size,
                            send_pair, og)
        tr.plan = TrafficPlan(tr, cfg.links)
        if fast is None and len(vg) > MEMO_PAIRS:
            return tr, None
        # send times of a reuse: t + (composition time or 0), the same sums as build_messages's
        delay = np.where(tr.send_t != t, cfg.compose_ms * 1e-3, 0.0)
        self._msg_memo = memo = {"key": key, "fast": fast, "view": view, "tr": tr, "delay": delay}
        return tr, memo

    @staticmethod
    def _resend(memo: dict, t: float) -> Traffic:
        """The memo's messages sent at ``t`` (the memo's Traffic, its send times replaced). A
        batch timed in Python floats (:meth:`_transmit_floats`) gets them as a list
        (``send_list``, the same sums) and no array (``send_t`` None until an array is made)."""
        tr = memo["tr"]
        plan = tr.plan
        if plan.second is None and plan.hop1.floats is not None:
            dl = memo.get("delay_l")
            if dl is None:
                dl = memo["delay_l"] = memo["delay"].tolist()
            tr.send_list = [t + d for d in dl]
            tr.send_t = None
        else:
            tr.send_t = t + memo["delay"]
        return tr

    def _view_owners(self, view: tuple) -> np.ndarray:
        """Owner of the object of each view pair (kept while the view and the owners stay)."""
        memo = self._og_memo
        if memo is not None and memo[0] == self._epoch and memo[1] is view:
            return memo[2]
        og = self.owner.take(view[0])    # (the method: no Python wrapper, as in _measure_scalar)
        self._og_memo = (self._epoch, view, og)
        return og

    def _view(self, cells: np.ndarray, online_g: np.ndarray):
        """(viewer, object) pairs of the 9-cell neighbourhoods of the online groups (§3.3): object
        (k,), viewer group (k,), flat cache index (k,), and the objects per viewer (G,).
        The last frame's pairs are reused when no object changed cell and the same groups are
        online (a scene at rest, or slow objects in large cells)."""
        memo = self._view_memo
        if (memo is not None and (memo[3] == self._group_version or np.array_equal(memo[1], online_g))
                and (memo[0] is cells or memo[0].tobytes() == cells.tobytes())):   # (the same int64 cells)
            self._view_hit = True
            return memo[2]
        self._view_hit = False
        viewers = online_g.nonzero()[0]
        vo, vg_local = self.grid.view_pairs(cells, cells[viewers])
        vg = viewers[vg_local]
        out = (vo, vg, self.index(vg, vo), np.bincount(vg, minlength=self.cfg.groups))
        self._view_memo = (cells, online_g, out, self._group_version)
        return out

    def _object_segments(self, vo: np.ndarray):
        """Copies per object (n_obj,), objects with copies, and where their runs start in the
        object-sorted view pairs ``vo`` (:func:`metrics.object_runs`, kept with the view)."""
        seg = self._segments
        if seg is None or seg[0] is not vo:
            seg = self._segments = (vo, object_runs(vo, self.n_obj))
        return seg[1]

    def _count_batch(self, plan: TrafficPlan) -> None:
        """Count a frame's messages (:meth:`_transmit`): step, interval and per-type totals."""
        n, nb = plan.n, plan.nbytes
        self.metrics.messages += n
        self.metrics.bytes += nb
        self._iv[0] += n
        self._iv[1] += nb
        bt = self.totals.by_type
        for name, b in plan.by_type:
            bt[name] = bt.get(name, 0) + b

    def _transmit_floats(self, tr: Traffic) -> Optional[list]:
        """:meth:`_transmit` of a small batch of first hops on lossless links
        (:meth:`links.TransmitPlan.run_floats`): the arrival times (n,) s as a list, nothing
        lost; None for any other batch."""
        plan = tr.plan
        if plan.second is not None or plan.hop1.floats is None:
            return None
        self._count_batch(plan)
        send = tr.send_list if tr.send_t is None else tr.send_t.tolist()
        return plan.hop1.run_floats(self.rng, send, self.busy, self.latency_scale)

    def _transmit(self, tr: Traffic):
        """Arrival times and losses of a frame's messages (first hops, then relayed hops)."""
        plan = tr.plan
        n = plan.n
        arrival, lost = np.zeros(n), np.zeros(n, bool)
        self._count_batch(plan)
        first = plan.first
        a1, l1 = plan.hop1.run(self.rng, tr.send_t[first], self.busy, self.latency_scale)
        arrival[first], lost[first] = a1, l1
        second = plan.second
        if second is not None:
            send2 = tr.send_t.copy()
            direct, src = plan.direct, plan.direct_src
            send2[direct] = np.maximum(send2[direct], arrival[src])
            lost[direct] |= lost[src]
            if plan.wait is not None:
                hop1, msg = plan.wait
                ok = ~lost[hop1]
                np.maximum.at(send2, msg[ok], arrival[hop1][ok])
            a2, l2 = plan.hop2.run(self.rng, send2[second], self.busy, self.latency_scale)
            arrival[second], lost[second] = a2, lost[second] | l2
        self.metrics.lost_messages += int(np.count_nonzero(lost))
        return arrival, lost

    # -- in-flight records ----------------------------------------------------------------------
    def _add_inflight(self, arr: np.ndarray, fi: np.ndarray, sender: np.ndarray, table: np.ndarray,
                      ridx: np.ndarray, epoch: Optional[int] = None) -> None:
        """Put records in flight: arrival (s), flat cache index, the record ``table[ridx]``
        (rows t, p, v, a) and its sending group ``sender[ridx]`` (``sender`` has one entry
        per table row: the owners when the table was sent). Each is filed under the first frame ``k`` with
        ``k T >= arrival``: it has arrived by that tick and not by the one before. ``epoch``
        is the ownership epoch the senders were checked against (-1: never checked)."""
        if len(arr):
            self._file(self._due(arr), fi, sender, table, ridx, epoch)

    def _due(self, arr: np.ndarray) -> np.ndarray:
        """First frame ``k`` (>= the current one) with ``k T >= arrival`` for arrivals ``arr`` (s).

        An arrival that is not finite (a lost message) or beyond any int64 frame (a link of
        almost no bandwidth) gives -1, "lost", as :meth:`_file` reads it, without casting NaN,
        inf or an overflowing value to an integer (which numpy warns of, and which gave the
        negative minimum int64: lost as well)."""
        k = np.maximum(np.ceil(arr / self.cfg.frame_s - 1e-9), self.k)
        ok = k < 2.0 ** 62   # False for NaN too
        if not ok.all():
            k = np.where(ok, k, -1.0)
        return k.astype(np.int64)

    def _file(self, due: np.ndarray, fi: np.ndarray, sender: np.ndarray, table: np.ndarray,
              ridx: np.ndarray, epoch: Optional[int] = None, t_send: Optional[float] = None) -> None:
        """File records under the frame they are due (``due`` (k,) array or list, or one frame for
        all of them; -1: lost, dropped), in send order; see :meth:`_add_inflight`. ``t_send``: the newest record time of
        ``table`` when the caller knows it (a frame's table: the frame time)."""
        if isinstance(due, int):   # every record due at frame ``due`` (-1: lost)
            if due >= 0 and len(fi):
                meta = (self._epoch if epoch is None else epoch,
                        float(table[:, T_COL].max()) if t_send is None else t_send)
                self._inflight.setdefault(due, []).append((fi, sender, table, ridx, meta))
            return
        if not len(due):
            return
        if isinstance(due, list) or len(due) <= 64:   # a few records: the extremes in Python
            dl = due if isinstance(due, list) else due.tolist()
            hi = max(dl)
            if hi < 0:
                return
            lo = min(dl)
            some_lost = lo < 0
            if some_lost:
                lo = min(d for d in dl if d >= 0)
        else:
            hi = int(due.max())
            if hi < 0:
                return
            lo = int(due.min())
            some_lost = lo < 0
            if some_lost:
                lo = int(due[due >= 0].min())
        meta = (self._epoch if epoch is None else epoch,
                float(table[:, T_COL].max()) if t_send is None else t_send)
        if lo == hi and not some_lost:
            self._inflight.setdefault(lo, []).append((fi, sender, table, ridx, meta))
            return
        if isinstance(due, list):
            due = np.array(due, np.int64)
        if hi - lo <= 3:
            for key in range(lo, hi + 1):
                sel = due == key
                if not sel.any():
                    continue
                self._inflight.setdefault(int(key), []).append((fi[sel], sender, table, ridx[sel], meta))
            return
        if some_lost:
            keep = due >= 0
            due, fi, ridx = due[keep], fi[keep], ridx[keep]
        order = np.argsort(due, kind="stable")
        due, fi, ridx = due[order], fi[order], ridx[order]
        cuts = np.flatnonzero(np.diff(due)) + 1
        for lo, hi in zip(np.r_[0, cuts], np.r_[cuts, len(due)]):
            self._inflight.setdefault(int(due[lo]), []).append((fi[lo:hi], sender, table, ridx[lo:hi], meta))

    def _file_rows(self, due, memo: dict, tr: Traffic, snap: tuple, t: float, P, V, A, vl=None) -> None:
        """File a frame's few records (at most ``FEW_RECORDS``, a small lossless batch) as Python
        lists: the rows of :meth:`_table` of the records' objects alone (the same values and
        record ids; the frame's table id is used up as by :meth:`_table`), their flat cache
        indices and senders (the owners now, ``snap``), under the frame each is due (``due``: one
        frame for all, or one per record; -1: never). :meth:`_deliver` writes them row by row.
        ``V`` None: the velocity rows from ``vl`` (the avatars', :meth:`World.avatar_velocities`,
        when the caller has them) and the entities' velocities."""
        rl = memo.get("rec_l")
        if rl is None:   # the records' flat indices and objects as lists (kept with the messages)
            rl = memo["rec_l"] = (self.index(tr.rec_viewer, tr.rec_obj).tolist(), tr.rec_obj.tolist())
        fi, objs = rl
        if snap[2] is None:
            snap = self._owner_snap = (snap[0], snap[1], snap[1].tolist())
        owners = snap[2]
        uid = self._uid
        self._uid += 1
        pos = self._positions_list(P)
        ncol = self._ncol
        if ncol >= 5 and V is None:   # V's rows: avatars' speed (cos, sin) yaw, the entities' velocities
            G = self.cfg.groups
            if vl is None:
                vl = self.world.avatar_velocities()
            ev = self.world.evel
        rows = []
        for o in objs:
            row = [t] + pos[o]
            if ncol >= 5:
                row += V[o].tolist() if V is not None else vl[o] if o < G else ev[o - G].tolist()
                if ncol >= 7:
                    row += A[o].tolist()
            row.append(o * RID_OBJECT + uid)    # (= _obj_rid[o] + uid, exact)
            rows.append(row)
        senders = [owners[o] for o in objs]
        meta = (self._epoch, float(t))
        if isinstance(due, int):
            if due >= 0:
                self._inflight.setdefault(due, []).append((fi, senders, rows, None, meta))
            return
        by_due: dict = {}
        for d, f, w, r in zip(due, fi, senders, rows):
            if d >= 0:
                part = by_due.get(d)
                if part is None:
                    part = by_due[d] = ([], [], [])
                part[0].append(f)
                part[1].append(w)
                part[2].append(r)
        for d, (f, w, r) in by_due.items():
            self._inflight.setdefault(d, []).append((f, w, r, None, meta))

    def _deliver_rows(self, fi: list, senders: list, rows: list, epoch: int, t_send: float) -> None:
        """:meth:`_deliver` of a chunk filed by :meth:`_file_rows`: the same sender check
        (§3.6.1), the same "newer than the cached record" test and the same cache writes, row by row."""
        G = self.cfg.groups
        if epoch != self._epoch:   # owners changed since it was sent: check the senders
            own = self.owner.tolist()
            keep = [i for i, (f, w) in enumerate(zip(fi, senders)) if w == own[f // G]]
            if len(keep) < len(fi):
                self.metrics.rejected_updates += len(fi) - len(keep)
                fi, rows = [fi[i] for i in keep], [rows[i] for i in keep]
        cache = self.cache
        if t_send < self._newest:   # possibly older than what the cache holds
            keep = [i for i, (f, r) in enumerate(zip(fi, rows)) if r[0] > cache[f, T_COL]]
            if len(keep) < len(fi):
                fi, rows = [fi[i] for i in keep], [rows[i] for i in keep]
        n = self.rid_col + 1
        for f, r in zip(fi, rows):
            cache[f, :n] = r
        if self._groups is not None:
            self._groups.touch(np.array(fi, np.int64))

    def _deliver(self, t: float) -> None:
        """Apply every record that has arrived by ``t``; reject records from non-owners (§3.6.1).

        Chunks are applied in send order and one chunk holds one record per (viewer, object),
        so a newer record overwrites an older one; a record older than the cached one
        (reordering) is ignored.
        """
        G = self.cfg.groups
        k = self.k
        due = [key for key in self._inflight if key <= k]
        if len(due) > 1:
            due.sort()
        for key in due:
            for fi, sender, table, ridx, (epoch, t_send) in self._inflight.pop(key):
                if ridx is None:   # a few records as lists (_file_rows)
                    self._deliver_rows(fi, sender, table, epoch, t_send)
                else:
                    if epoch != self._epoch:  # owners changed since it was sent: check the senders
                        valid = np.take(sender, ridx) == np.take(self.owner, fi // G)
                        if not valid.all():
                            self.metrics.rejected_updates += int((~valid).sum())
                            fi, ridx = fi[valid], ridx[valid]
                    if t_send < self._newest:  # possibly older than what the cache holds
                        newer = table[ridx, T_COL] > self.cache[fi, T_COL]
                        if not newer.all():
                            fi, ridx = fi[newer], ridx[newer]
                    self._scatter(fi, table, ridx)
                self._newest = max(self._newest, t_send)
                ex = self._exact
                if epoch == -1 or ex is None or t_send < ex[1]:   # not a record of the resting scene
                    self._display_clean = None

    def index(self, viewer, obj):
        """Flat cache index of (viewer group, object)."""
        return np.asarray(obj) * self.cfg.groups + np.asarray(viewer)

    def _scatter(self, fi: np.ndarray, table: np.ndarray, ridx: np.ndarray) -> None:
        """Write records ``table[ridx]`` into the cache rows ``fi`` (the columns the prediction
        order uses and the record id, as one block per row; the subscription time is left alone)."""
        n = self.rid_col + 1
        view = self._views.cache_rows
        if view is None or view[0] is not self.cache:
            view = self._views.cache_rows = (self.cache, _row_prefix(self.cache, n))
        view[1][fi] = _row_prefix(table, n)[ridx]
        if self._groups is not None:
            self._groups.touch(fi)

    def record(self, viewer: int, obj: int) -> np.ndarray:
        """Cached record (7,) of ``obj`` at group ``viewer``: t (s), p (2, m), v (2, m/s), a (2, m/s^2)."""
        out = np.zeros(7)
        out[:self._ncol] = self.cache[int(self.index(viewer, obj)), :self._ncol]
        return out

    def in_view(self, viewer: int, obj: int) -> bool:
        """``obj`` was in the 9-cell neighbourhood of online group ``viewer`` at the last frame."""
        if self._view_prev is None:
            return True
        cells, online = self._view_prev
        return bool(online[viewer]) and (not self.grid.enabled
                                         or bool(self.grid.adjacent(cells[obj], cells[viewer])))

    def _entered(self, cells: np.ndarray, online_g: np.ndarray, vg: np.ndarray, vo: np.ndarray) -> np.ndarray:
        """Which of this frame's view pairs (``vg``, ``vo``) were not in view at the last frame
        (:meth:`SceneGrid.not_in_view`), as a mask."""
        newly = np.zeros(len(vg), bool)
        if self._view_prev is not None:
            pc, pon = self._view_prev
            newly[self.grid.not_in_view(pc, pon, cells, vg, vo)] = True
        return newly

    def _flip_frames(self, t: float) -> None:
        """Slaves whose FRAME for this tick has arrived by ``t`` show it; late or lost ones are
        dropped (§3.5.2). Pending FRAMEs due later stay."""
        fr = self._frames
        if not fr:
            return
        k = self.k
        lim = t + 1e-12
        later = [x for x in fr if x[2] > k]
        if len(later) == len(fr):   # every FRAME is due later
            return
        show = [x[1] for x in fr if x[2] == k and x[0] <= lim]
        if len(show) <= SCALAR_VIEW:   # a few: element by element (cheaper than a fancy assignment)
            sf = self.shown_frame
            for node in show:
                sf[node] = k
        else:
            self.shown_frame[show] = k
        self.metrics.dropped_frames += len(fr) - len(later) - len(show)
        self._frames = later

    # -- display ----------------------------------------------------------------------------------
    def _display(self, vg: Optional[np.ndarray] = None, vo: Optional[np.ndarray] = None,
                 fi: Optional[np.ndarray] = None, og: Optional[np.ndarray] = None,
                 cells: Optional[np.ndarray] = None, online_g: Optional[np.ndarray] = None,
                 P: Optional[np.ndarray] = None) -> None:
        cfg, G = self.cfg, self.cfg.groups
        t = self.k * cfg.frame_s
        if P is None:
            P = self.world.positions()
        if vg is None:
            online_g = self.master >= 0
            online = np.flatnonzero(online_g)
            cells = self.grid.cell(P)
            vo, vl = self.grid.view_pairs(cells, cells[online])
            vg = online[vl]
        if cfg.measure:
            clean = self._display_clean
            if (clean is not None and clean[0] is P and clean[1] is vo and clean[2] is og
                    and self.world.at_fixed_point()):
                # a resting scene whose every counted copy holds a record of this state (p the
                # truth, v = a = 0) and which got no other record since: every error is 0 again
                m = self.metrics
                m.inconsistency_max = max(m.inconsistency_max, 0.0)
                m.inconsistency_rms = 0.0
            elif fi is not None and og is not None and len(fi) <= SCALAR_VIEW and self._groups is None:
                self._measure_scalar(t, P, vo, vg, fi, og)     # (what _measure does for a small view)
            else:
                self._measure(t, P, vg, vo, fi, og, cells, online_g)
        # displayed avatars at every master (for slaves showing an older frame)
        sl, diag, sl_list = self._slave_nodes()
        if G * G <= SCALAR_VIEW:   # (as a list, into the array when read: see hist)
            self._hist_rows[self.k % HIST] = self._shown_avatars_scalar(t, P)
        else:
            slot = self.hist[self.k % HIST]
            blk = self.cache[:G * G]                  # avatars are objects 0..G-1: object-major block
            av = dead_reckon(blk[:, 1:3], blk[:, 3:5], blk[:, 5:7], t - blk[:, T_COL], cfg.prediction_order)
            slot[...] = av.reshape(G, G, 2).transpose(1, 0, 2)
            slot[diag, diag] = P[:G]                  # a master shows its own avatar as it is
        if sl_list:
            if len(sl_list) > SCALAR_VIEW:
                oldest = int(self.shown_frame[sl].min())
            else:
                sf = self.shown_frame.tolist()
                oldest = min([sf[i] for i in sl_list])
            self.metrics.desync_frames = max(self.metrics.desync_frames, self.k - oldest)

    def _shown_avatars_scalar(self, t: float, P: np.ndarray) -> list:
        """The avatars every master shows at frame time ``t`` (s), as the flat (viewer, avatar,
        xy) list of a history slot (m): each master's cached avatar records dead-reckoned
        (:func:`consistency.dead_reckon`, the same operations in Python floats), its own avatar
        the truth ``P[g]``."""
        G, order = self.cfg.groups, self.cfg.prediction_order
        if self._hist_dest is None:   # where cache row i (object i // G, viewer i % G) goes in the slot
            self._hist_dest = ([(i, 2 * ((i % G) * G + i // G)) for i in range(G * G) if i % G != i // G],
                               [2 * (g * G + g) for g in range(G)])
        dest, diag = self._hist_dest     # (the rows of other groups' avatars; the diagonal is the truth)
        out = [0.0] * (2 * G * G)
        rows = self.cache[:G * G, :self._ncol].tolist()
        if order == 1:
            for i, j in dest:
                c = rows[i]
                dt = t - c[T_COL]
                out[j] = c[1] + c[3] * dt
                out[j + 1] = c[2] + c[4] * dt
        elif order == 0:
            for i, j in dest:
                c = rows[i]
                out[j] = c[1]
                out[j + 1] = c[2]
        else:
            for i, j in dest:
                c = rows[i]
                dt = t - c[T_COL]
                hd = 0.5 * dt
                out[j] = c[1] + dt * (c[3] + hd * c[5])
                out[j + 1] = c[2] + dt * (c[4] + hd * c[6])
        for j, (x, y) in zip(diag, self._positions_list(P)):   # a master shows its own avatar as it is
            out[j] = x
            out[j + 1] = y
        return out

    def _positions_list(self, P: np.ndarray) -> list:
        """``P.tolist()`` (objects' ``[x, y]``, m), kept for the array ``P`` of the frame."""
        memo = self._pos_memo
        if memo is None or memo[0] is not P:
            memo = self._pos_memo = (P, P.tolist())
        return memo[1]

    def _slave_nodes(self):
        """Every slave render node (k,), ``arange(G)`` and the slaves as a list, kept while the
        groups stay."""
        memo = self._slaves_memo
        if memo is None or memo[0] != self._group_version:
            sl = (np.concatenate([s for s in self.slaves if len(s)]) if any(len(s) for s in self.slaves)
                  else np.zeros(0, int))
            memo = self._slaves_memo = (self._group_version, sl, np.arange(self.cfg.groups), sl.tolist())
        return memo[1], memo[2], memo[3]

    def _measure(self, t, P, vg, vo, fi, og, cells, online_g) -> None:
        """Display error of every remote copy at frame time ``t`` (eq. 3-1/3-2).

        Views of more than ``GROUPS_MIN_PAIRS`` copies keep :class:`display.DisplayGroups` (one
        evaluation per distinct record instead of per copy: the same maxima, RMS equal up to
        round-off) unless the frame rewrote a large share of the copies; else every copy is
        evaluated here.
        """
        cfg = self.cfg
        order = cfg.prediction_order
        if fi is None:
            fi = self.index(vg, vo)
        if og is None:
            og = np.take(self.owner, vo)
        if len(fi) > GROUPS_MIN_PAIRS:
            if self._groups is None:
                self._groups = DisplayGroups(len(self.cache), self.n_obj, cfg.groups)
            if self._groups.update(self, cells, online_g, vo, vg, fi, og):
                pm, pr, mx, rms = self._groups.errors(t, P, order)
                self.per_object_max, self.per_object_rms = pm, pr
                self.metrics.inconsistency_max = max(self.metrics.inconsistency_max, mx)
                self.metrics.inconsistency_rms = rms
                return
        elif self._groups is not None:
            self._groups.invalidate()
        # copies shown by non-owners that have a record of the object; dead reckoning (§3.6.3)
        # evaluated column by column: e = p + v dt (+ a dt^2 / 2) - truth
        n = len(fi)
        if n <= SCALAR_VIEW:
            return self._measure_scalar(t, P, vo, vg, fi, og)
        px, py = P[:, 0], P[:, 1]
        if n <= MEASURE_CHUNK:
            err2, remote = self._copy_errors(t, fi, vo, vg, og, px, py)
        else:
            # in chunks that stay in the CPU cache: one row (cache line) gathered per copy,
            # then the column arithmetic on the chunk
            err2, remote = np.empty(n), np.empty(n, bool)
            px, py = np.ascontiguousarray(px), np.ascontiguousarray(py)
            for a in range(0, n, MEASURE_CHUNK):
                b = min(a + MEASURE_CHUNK, n)
                err2[a:b], remote[a:b] = self._copy_errors(t, fi[a:b], vo[a:b], vg[a:b], og[a:b], px, py)
        pm, pr, mx, rms = inconsistency_sq(vo, err2, self.n_obj, remote, sorted_obj=True,
                                          segments=self._object_segments(vo))
        self.per_object_max, self.per_object_rms = pm, pr
        self.metrics.inconsistency_max = max(self.metrics.inconsistency_max, mx)
        self.metrics.inconsistency_rms = rms

    def _measure_scalar(self, t, P, vo, vg, fi, og) -> None:
        """:meth:`_measure` of a view of a few copies in Python floats: eq. 3-1/3-2 with the
        dead reckoning of §3.6.3 (the operations of :meth:`_copy_errors` and
        :func:`metrics.inconsistency_sq` in the same order; the total is numpy's sum of the
        same squared errors)."""
        memo = self._scalar_view_memo
        if memo is None or memo[0] is not og or memo[1] is not vo or memo[2] is not fi:
            # the copies shown by non-owners (only they can count): position, object, flat index
            remote = (og != vg).nonzero()[0]
            memo = self._scalar_view_memo = (og, vo, fi, remote.tolist(), vo[remote].tolist(), fi[remote])
        order, enter = self.cfg.prediction_order, self.enter_col
        rows = self.cache.take(memo[5], axis=0).tolist() if memo[3] else []   # (the method: no wrapper)
        pos = self._positions_list(P) if memo[3] else None
        n_obj = self.n_obj
        per_max, s2, cnt = [0.0] * n_obj, [0.0] * n_obj, [0] * n_obj
        err2 = [0.0] * len(fi)    # the own copies (and remote ones without a record) count as 0
        first_order, second_order = order >= 1, order >= 2
        for i, o, c in zip(memo[3], memo[4], rows):
            ct = c[0]
            if not ct >= c[enter] - 1e-12:   # no record since it subscribed
                continue
            cnt[o] += 1
            p = pos[o]
            ex = c[1] - p[0]
            ey = c[2] - p[1]
            if first_order:
                dt = t - ct
                ex += c[3] * dt
                ey += c[4] * dt
                if second_order:
                    h = 0.5 * dt * dt
                    ex += c[5] * h
                    ey += c[6] * h
            e = ex * ex + ey * ey
            err2[i] = e
            s2[o] += e
            if e > per_max[o]:
                per_max[o] = e
        m = self.metrics
        ex = self._exact
        self._display_clean = None
        if (REST_DISPLAY and ex is not None and ex[0] is P and not any(err2) and self.world.at_fixed_point()
                and min((c[0] for c in rows if c[0] >= c[enter] - 1e-12), default=math.inf) >= ex[1]):
            # the oldest counted record is one of this resting state: so are the others
            self._display_clean = (P, vo, og)
        n_valid = sum(cnt)
        if n_valid == 0:
            self._per_raw = (per_max, s2, cnt)     # (all zeros)
            m.inconsistency_max = max(m.inconsistency_max, 0.0)
            m.inconsistency_rms = 0.0
            return
        sqrt = math.sqrt
        self._per_raw = (per_max, s2, cnt)     # the per-object arrays when read (see per_object_max)
        m.inconsistency_max = max(m.inconsistency_max, sqrt(max(err2)))
        m.inconsistency_rms = sqrt(pairwise_sum(err2) / n_valid)   # numpy's sum of the same values

    @property
    def per_object_max(self) -> np.ndarray:
        """Eq. 3-1 per object at the last frame (G + E,) m: the largest error of its displayed
        copies (0 without one). A small view keeps the squared maxima, sums and counts of
        :meth:`_measure_scalar` and makes both arrays on the first read."""
        if self._per_raw is not None:
            self._per_arrays()
        return self._per_max

    @per_object_max.setter
    def per_object_max(self, value: np.ndarray) -> None:
        self._per_arrays()
        self._per_max = value

    @property
    def per_object_rms(self) -> np.ndarray:
        """Eq. 3-2 per object at the last frame (G + E,) m: the RMS error of its counted copies."""
        if self._per_raw is not None:
            self._per_arrays()
        return self._per_rms

    @per_object_rms.setter
    def per_object_rms(self, value: np.ndarray) -> None:
        self._per_arrays()
        self._per_rms = value

    def _per_arrays(self) -> None:
        """The per-object arrays from :meth:`_measure_scalar`'s lists (squared maxima, sums of
        squares, counts): ``sqrt(max)`` and ``sqrt(sum / count)`` (0 without a count)."""
        raw, self._per_raw = self._per_raw, None
        if raw is None:
            return
        per_max, s2, cnt = raw
        sqrt = math.sqrt
        per = np.array([sqrt(x) for x in per_max] + [sqrt(a / k) if k > 0 else 0.0 for a, k in zip(s2, cnt)])
        n = len(per_max)
        self._per_max, self._per_rms = per[:n], per[n:]

    def _copy_errors(self, t, fi, vo, vg, og, px, py):
        """Squared display errors (k,) m^2 of copies ``fi`` at frame time ``t`` and whether each
        counts (a non-owner's copy with a record since it subscribed), eq. 3-1/3-2 with the
        dead reckoning of §3.6.3: ``e = (p - truth) + v dt (+ a dt^2 / 2)``."""
        order = self.cfg.prediction_order
        c = np.take(self.cache, fi, axis=0)       # one row (cache line) per copy
        ct = c[:, T_COL]
        remote = (og != vg) & (ct >= c[:, self.enter_col] - 1e-12)
        return squared_dr_error(c, ct, np.take(px, vo), np.take(py, vo), t, order), remote

    # -- queries ------------------------------------------------------------------------------------
    def _shown_row(self, node: int):
        """History slot and group of what render node ``node`` shows now: its master's current
        frame, or the frame the slave shows (at most ``HIST - 1`` frames old)."""
        grp = self.reg.group_list[node]
        frame = self.k if node == self.master[grp] else int(self.shown_frame[node])
        return max(frame, self.k - HIST + 1) % HIST, grp

    def perceived_avatar(self, node: int, g: int) -> np.ndarray:
        """Position (2,) of avatar ``g`` as shown by render node ``node`` now (m)."""
        slot, grp = self._shown_row(node)
        return self.hist[slot, grp, g].copy()

    def perceived_avatars(self, node: int) -> np.ndarray:
        """Positions (G, 2) of every avatar as shown by render node ``node`` now (m)."""
        slot, grp = self._shown_row(node)
        return self.hist[slot, grp].copy()

    def perceived_list(self, node: int) -> list:
        """:meth:`perceived_avatars` of ``node`` flattened to a list ``[x0, y0, x1, y1, ...]`` (m)."""
        slot, grp = self._shown_row(node)
        row = self._hist_rows.get(slot)
        if row is not None:    # a small scene's slot not yet in the array: its group's part
            n = 2 * self.cfg.groups
            return row[n * grp:n * (grp + 1)]
        return self.hist[slot, grp].ravel().tolist()

    @property
    def hist(self) -> np.ndarray:
        """Displayed avatars (HIST, viewer group, avatar, xy) m of the last ``HIST`` frames, slot
        ``k % HIST`` for frame ``k`` (for slaves that show an older frame). Small scenes keep a
        frame's slot as the flat list of :meth:`_shown_avatars_scalar` until the array is read."""
        rows = self._hist_rows
        if rows:
            h = self._hist
            for slot, row in rows.items():
                h[slot].flat = row
            rows.clear()
        return self._hist

    def perceived_key(self, node: int) -> tuple:
        """What :meth:`perceived_avatars` of ``node`` returns, as bytes (the history row it
        reads; equal keys, equal positions)."""
        slot, grp = self._shown_row(node)
        return self.hist[slot, grp].tobytes()

    def at_rest(self) -> bool:
        """Stepping on with unchanged inputs would change no per-frame output.

        True when no input changed in the step, the step's frame traffic equals the step
        before's (a control packet handled in the step, or forwarded by a master in it, changes
        a frame's traffic once), nothing moves, no input, collision, join or leave event is
        queued, every node shows the true state and updates go out every frame
        (``dis_threshold <= 0``; with DIS the 1 s re-publication changes a frame's traffic).
        The per-frame traffic of such a frame (``StepMetrics.frame_messages``/``frame_bytes``:
        STATE, FRAME, REPORT of a scene that does not move) is then the same every frame;
        heartbeats (and the supernode's time-out checks) go on but are not part of it.
        """
        return (not self._step_inputs_changed and self._traffic_steady and not self._pending
                and self.metrics.inconsistency_max == 0.0 and self.cfg.driven_groups == self.cfg.groups
                and self.cfg.dis_threshold <= 0 and not self.world.moving())

    def shown_position(self, viewer: int, obj: int) -> np.ndarray:
        """Position (2,) m of object ``obj`` as the master of group ``viewer`` shows it at the
        current frame (its cache dead-reckoned to the frame time; the truth for its own objects)."""
        if self.owner[obj] == viewer:
            return self.world.positions()[obj].copy()
        fi = int(self.index(viewer, obj))
        c = self.cache[fi]
        dt = np.array([self.k * self.cfg.frame_s - c[0]])
        return dead_reckon(c[None, 1:3], c[None, 3:5], c[None, 5:7], dt, self.cfg.prediction_order)[0]

    def heartbeat_table(self) -> List[dict]:
        return self.supernode.table()

    def get_state(self):
        """Deep copy of the whole model (events, RNG, caches, world) for FMU get/set state."""
        return copy.deepcopy(self.__dict__)

    def set_state(self, state) -> None:
        self.__dict__.update(copy.deepcopy(state))
