"""The discrete-event network model (ch. 2-3): events on a heap, frames every 33 ms.

Time advances through the events of :mod:`.events`, each at its own time. Render frames
are ticks at ``k * frame_s`` (``k`` an integer). The world (ground truth) is advanced exactly
to each event's time before the event is applied.

A tick ``t_k`` runs the phases of the frame in order, each a module with its own state:
collision responses (:mod:`.contacts`), ownership (:mod:`.ownership`, §3.6.2), publishing
(:mod:`.publishing`, every frame or DIS threshold), messages by topology and link sampling
(:mod:`.messages`), delivery of everything that has arrived by ``t_k`` and slave frame flips
(:mod:`.delivery`, §3.5.2), what the nodes show (:mod:`.history`) and the display error
(:mod:`.measure`, eq. 3-1/3-2). Fast and plain forms of a step are chosen by one
:class:`paths.Paths`.
"""
from __future__ import annotations

import copy
import math
from typing import List, Optional

import numpy as np

from . import events as ev
from .config import NetworkConfig
from .consistency import SceneGrid, dead_reckon, free_motion
from .contacts import Contacts
from .delivery import Inflight
from .history import AvatarHistory
from .measure import DisplayError
from .membership import Membership
from .messages import Messaging
from .metrics import FrameTraffic, StepMetrics, Totals
from .nodes import PDU_NAMES, NodeRegistry
from .ownership import Ownership
from .paths import Paths
from .pdu import PduType
from .publishing import Publisher
from .records import RecordCache
from .world import World


class Frame:
    """What the phases of one tick hand each other (frame time ``t`` s; state ``P``, ``V``,
    ``A``; positions ``pl`` and avatar velocities ``vl`` as lists in a lazy small frame; the
    online groups, view, publications, messages and their timing)."""

    __slots__ = ("t", "P", "V", "A", "pl", "vl", "etree", "lazy", "online_g", "cand", "cells", "view", "og",
                 "newly", "pub", "pub_obj", "tr", "memo", "arr_l", "arrival", "lost")

    def __init__(self, t: float) -> None:
        self.t = t
        self.P = self.V = self.A = self.pl = self.vl = None


class DriverInputs:
    """Driver inputs (G, 2) throttle, steer as last set, whether one changed in the running
    step (``changed``) and in the last completed one (``step_changed``)."""

    def __init__(self, groups: int) -> None:
        self.values = np.zeros((groups, 2))
        self.changed = False
        self.step_changed = False


class NetworkModel:
    """Hybrid-P2P distributed VR network with consistency control.

    Parameters
    ----------
    cfg : NetworkConfig
    paths : Paths, which form of each step runs (default: every shortcut where it pays;
        :meth:`Paths.plain`: the plain array code; the same outputs bit for bit)

    Attributes
    ----------
    world : World, ground truth
    owner : (G + E,) owning group of every object (avatars first)
    metrics : StepMetrics of the last :meth:`step`; ``totals`` accumulates over the run
    per_object_max, per_object_rms : (G + E,) m, eq. 3-1/3-2 errors at the last frame
    """

    def __init__(self, cfg: NetworkConfig, paths: Optional[Paths] = None) -> None:
        self.cfg = cfg
        self.paths = Paths() if paths is None else paths
        self.rng = np.random.default_rng(cfg.seed)
        self.world = World(cfg, self.rng, self.paths)
        self.reg = NodeRegistry(cfg)
        self.grid = SceneGrid(cfg.scene.scene_size, cfg.scene.grid_cells, cfg.scene.grid, self.paths.scalar_grid)
        G, n_obj = cfg.groups, cfg.groups + cfg.entities
        if n_obj >= 2 ** 21:
            raise ValueError(f"network model: {n_obj} objects, at most 2^21 - 1 (record ids object * 2^32 + table)")
        self.t = 0.0
        self.k = 0
        self.latency_scale = 1.0
        self.events = ev.EventQueue()
        self.groups = Membership(cfg, self.reg)
        self.inputs = DriverInputs(G)
        self.own = Ownership(cfg, self.world)
        self.contacts = Contacts(cfg, self.paths)
        self.records = RecordCache(G, n_obj, cfg.consistency.prediction_order)
        self.pub = Publisher(n_obj)
        self.msgs = Messaging(self.reg.n)
        self.flight = Inflight()
        # frame clock phase of every node (s), cfg.scene.frame_phase (see phase); its own stream leaves the model's draws as they are
        self.node_phase = (np.random.default_rng([cfg.seed, 5]).uniform(0.0, cfg.scene.frame_s, self.reg.n)
                           if cfg.scene.frame_phase else None)
        self.errors = DisplayError(n_obj)
        self.history = AvatarHistory(G)
        self.metrics = StepMetrics()
        self.totals = Totals()
        self.traffic = FrameTraffic()
        self._pos = None      # (positions array, as a list): see positions_list
        self._bootstrap()
        self.traffic.interval = [0, 0]      # the bootstrap JOINs belong to no frame interval
        self.metrics.online_nodes = self.groups.n_online

    @property
    def n_obj(self) -> int:
        """Objects: G avatars, then E entities."""
        return self.cfg.groups + self.cfg.entities

    # -- set-up ---------------------------------------------------------------------------
    def _bootstrap(self) -> None:
        cfg, reg, grp = self.cfg, self.reg, self.groups
        for g in range(cfg.groups):
            grp.join(self, 0.0, reg.controller(g))
            for i in reg.render_nodes(g):
                grp.join(self, 0.0, int(i))
        grp.rebuild_overlay(self)
        phase = self.rng.uniform(0.0, cfg.membership.heartbeat_s, reg.n - 1)
        for i in range(reg.n - 1):
            self.events.push(float(phase[i]), "heartbeat", i)
        self.events.push(cfg.membership.heartbeat_s, "expire")
        for g in range(cfg.driven_groups, cfg.groups):
            ev.autopilot(self, 0.0, g)
        self.pub.initial(self)
        # frame 1 comes from the scene file every node has loaded (no packet needed)
        sl = np.concatenate(grp.slaves) if grp.slaves else np.zeros(0, np.int64)
        self.flight.frames = [(0.0, node, 1) for node in sl.tolist()]
        self._display()

    # -- shared helpers of the phases -------------------------------------------------------
    def positions_list(self, P: np.ndarray) -> list:
        """``P.tolist()`` (objects' ``[x, y]``, m), kept for the array ``P`` of the frame."""
        memo = self._pos
        if memo is None or memo[0] is not P:
            memo = self._pos = (P, P.tolist())
        return memo[1]

    def write_records(self, fi: np.ndarray, table: np.ndarray, ridx: np.ndarray) -> None:
        """Records ``table[ridx]`` into cache rows ``fi`` (:meth:`RecordCache.scatter`)."""
        self.records.scatter(fi, table, ridx)
        self.errors.touch(fi)

    def count(self, messages: int, nbytes: int, ptype: int) -> None:
        """Count messages of one PDU type: step, frame interval (not heartbeats), per-type totals."""
        self.metrics.messages += int(messages)
        self.metrics.bytes += int(nbytes)
        if ptype != PduType.HEARTBEAT:
            self.traffic.add(int(messages), int(nbytes))
        bt = self.totals.by_type
        name = PDU_NAMES[int(ptype)]
        bt[name] = bt.get(name, 0) + int(nbytes)

    def count_batch(self, plan) -> None:
        """Count a frame's messages (a :class:`nodes.TrafficPlan`): step, interval and per-type totals."""
        n, nb = plan.n, plan.nbytes
        m = self.metrics
        m.messages += n
        m.bytes += nb
        self.traffic.add(n, nb)
        bt = self.totals.by_type
        for name, b in plan.by_type:
            bt[name] = bt.get(name, 0) + b

    # -- membership and inputs ------------------------------------------------------------
    def schedule_leave(self, t: float, node: int, graceful: bool = True) -> None:
        """Node ``node`` leaves at ``t`` (graceful: LEAVE PDU; else it crashes and times out)."""
        self.events.push(t, "leave", node, graceful)

    def schedule_join(self, t: float, node: int) -> None:
        self.events.push(t, "join", node)

    def set_input(self, g: int, throttle: float, steer: float, t: Optional[float] = None) -> None:
        """Driver input of group ``g`` at time ``t`` (default: now).

        A change travels as a ControllerPacket controller -> supernode -> master (hybrid and
        client-server; direct over the LAN in full mesh) and acts when it arrives.
        """
        t = self.t if t is None else t
        inp = self.inputs
        if inp.values[g, 0] == throttle and inp.values[g, 1] == steer:
            return
        inp.values[g] = throttle, steer
        inp.changed = True
        delay = ev.control_delay(self)
        self.events.push(t + delay, "input", g, float(throttle), float(steer))

    def bounce(self, g: int, normal, restitution: Optional[float] = None, depth: float = 0.0) -> float:
        """Collision response input for avatar ``g`` against a static obstacle: contact normal
        (from the obstacle to the avatar), penetration ``depth`` (m) removed along it, velocity
        reflected when approaching (stop if restitution 0); returns |dv| (m/s)."""
        e = self.cfg.world.restitution if restitution is None else restitution
        return self.world.bounce_avatar(g, normal, e, depth)

    def inject_update(self, sender_group: int, viewer_group: int, obj: int, pos, vel=(0.0, 0.0),
                      arrival: Optional[float] = None) -> None:
        """Put a STATE record from ``sender_group`` for ``obj`` in flight (e.g. a forged one)."""
        t = self.t if arrival is None else arrival
        rec = self.records.table(np.array([obj]), self.t, np.asarray(pos, float)[None],
                                 np.asarray(vel, float)[None], np.zeros((1, 2)))
        self.flight.file(self, self.flight.due(self, np.array([t])), np.array([self.index(viewer_group, obj)]),
                         np.array([sender_group]), rec, np.zeros(1, np.int64), epoch=-1)

    # -- stepping ------------------------------------------------------------------------------
    def step(self, h: float) -> StepMetrics:
        """Advance the model by ``h`` seconds; returns the step's metrics."""
        T = self.cfg.scene.frame_s
        eps = 1e-9
        t_end = self.t + h
        k_end = round(t_end / T)
        if abs(t_end - k_end * T) < eps:  # masters differ in the last ulp of t + h: snap to the frame grid
            t_end = k_end * T
        self.metrics = StepMetrics()
        events = self.events
        while True:
            t_tick = (self.k + 1) * T
            t_ev = events.heap[0][0] if events.heap else math.inf
            t_next = t_ev if t_ev < t_tick else t_tick      # min(t_tick, t_ev)
            if t_next > t_end + eps:
                break
            if t_next > self.t:                              # self.t = max(self.t, t_next)
                self.t = t_next
            if t_ev <= t_tick:
                ev.handle(self, *events.pop())
            else:
                self.k += 1
                self.world.advance_to(self.t)
                self._tick()
        self.world.advance_to(t_end)
        self.t = t_end
        m, shown = self.metrics, self.errors
        if m.frames == 0:  # no frame in a short step: the display (and its error) is unchanged
            m.inconsistency_max, m.inconsistency_rms, m.desync_frames = shown.last
        shown.last = (m.inconsistency_max, m.inconsistency_rms, m.desync_frames)
        m.online_nodes = self.groups.n_online
        m.frame_messages, m.frame_bytes = self.traffic.frame
        self.totals.add(m)
        self.inputs.step_changed = self.inputs.changed
        self.traffic.close_step()
        self.inputs.changed = False
        return m

    def _tick(self) -> None:
        """One frame: the phases in order (module docstring)."""
        cfg = self.cfg
        fr = Frame(self.k * cfg.scene.frame_s)
        self.metrics.frames += 1
        fr.online_g, fr.cand = self.groups.online_groups()
        self.contacts.respond(self, fr)                      # 1. collision responses
        if not fr.lazy:   # accelerations only where read: order-2 records, the DIS test
            fr.P, fr.V, fr.A = self.world.state(acc=cfg.consistency.prediction_order >= 2 or cfg.consistency.dis_threshold > 0)
        self.own.assign(self, fr)                            # 2. ownership (§3.6.2)
        self.pub.publish(self, fr)                           # 3. publishing
        self.msgs.send(self, fr)                             # 4. messages, link sampling
        self.flight.post(self, fr)
        self.flight.deliver(self)                            # 5. deliveries up to now, frame flips
        self.flight.flip_frames(self, fr.t)
        self._display(fr)                                    # 6. display and its error
        self.traffic.close_frame()

    def _display(self, fr: Optional[Frame] = None) -> None:
        """What the nodes show at the current frame and its error (eq. 3-1/3-2); without a
        frame (set-up) the view is computed here."""
        cfg = self.cfg
        t = self.k * cfg.scene.frame_s
        if fr is None:
            P = self.world.positions()
            online_g = self.groups.master >= 0
            online = np.flatnonzero(online_g)
            cells = self.grid.cell(P)
            vo, vl = self.grid.view_pairs(cells, cells[online])
            vg, fi, og = online[vl], None, None
        else:
            P, cells, online_g, og = fr.P, fr.cells, fr.online_g, fr.og
            vo, vg, fi, _ = fr.view
        if cfg.measure:
            self.errors.display(self, t, P, vg, vo, fi, og, cells, online_g)
        self.history.write(self, t, P)

    # -- queries ------------------------------------------------------------------------------------
    @property
    def phase(self) -> Optional[np.ndarray]:
        """Frame clock phase (G,) s of each group: its master's own (``node_phase``), the slaves
        locked to it (§3.5.2); None with every clock in phase."""
        if self.node_phase is None:
            return None
        return self.node_phase[np.maximum(self.groups.master, 0)]

    def index(self, viewer, obj):
        """Flat cache index of (viewer group, object)."""
        return self.records.index(viewer, obj)

    def record(self, viewer: int, obj: int) -> np.ndarray:
        """Cached record (7,) of ``obj`` at group ``viewer``: t (s), p (2, m), v (2, m/s), a (2, m/s^2)."""
        return self.records.record(viewer, obj)

    def in_view(self, viewer: int, obj: int) -> bool:
        """``obj`` was in the 9-cell neighbourhood of online group ``viewer`` at the last frame."""
        return self.msgs.in_view(self, viewer, obj)

    def perceived_avatar(self, node: int, g: int) -> np.ndarray:
        """Position (2,) of avatar ``g`` as shown by render node ``node`` now (m)."""
        slot, grp = self.history.shown_row(self, node)
        return self.hist[slot, grp, g].copy()

    def perceived_avatars(self, node: int) -> np.ndarray:
        """Positions (G, 2) of every avatar as shown by render node ``node`` now (m)."""
        slot, grp = self.history.shown_row(self, node)
        return self.hist[slot, grp].copy()

    def perceived_list(self, node: int) -> list:
        """:meth:`perceived_avatars` of ``node`` flattened to a list ``[x0, y0, x1, y1, ...]`` (m)."""
        return self.history.perceived_list(self, node)

    def perceived_key(self, node: int) -> tuple:
        """What :meth:`perceived_avatars` of ``node`` returns, as bytes (the history row it
        reads; equal keys, equal positions)."""
        slot, grp = self.history.shown_row(self, node)
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
        return (not self.inputs.step_changed and self.traffic.steady and not self.events.pending
                and self.metrics.inconsistency_max == 0.0 and self.cfg.driven_groups == self.cfg.groups
                and self.cfg.consistency.dis_threshold <= 0 and not self.world.moving())

    def shown_position(self, viewer: int, obj: int) -> np.ndarray:
        """Position (2,) m of object ``obj`` as the master of group ``viewer`` shows it at the
        current frame (its cache dead-reckoned to the frame time, or for an entity without an
        owner the scene's entity law run from it, :class:`display.FreePrediction`; the truth for
        its own objects)."""
        if self.owner[obj] == viewer:
            return self.world.positions()[obj].copy()
        c = self.cache[int(self.index(viewer, obj))]
        dt = np.array([self.k * self.cfg.scene.frame_s - c[0]])
        if self.errors.ownerless(self) and self.errors.free_copies(self, np.array([obj]), c[None, 0])[0]:
            scene, w = self.cfg.scene, self.cfg.world
            return free_motion(c[None, 1:3], c[None, 3:5], self.world.eturn[[obj - self.cfg.groups]], w.entity_drag,
                               dt, scene.scene_size, scene.frame_s / w.substeps)[0][0]
        return dead_reckon(c[None, 1:3], c[None, 3:5], c[None, 5:7], dt, self.cfg.consistency.prediction_order)[0]

    def heartbeat_table(self) -> List[dict]:
        return self.groups.supernode.table()

    # the phases' state, read by callers and tests
    cache = property(lambda self: self.records.cache, doc="receivers' record cache (records.RecordCache)")
    rid_col = property(lambda self: self.records.rid_col)
    enter_col = property(lambda self: self.records.enter_col)
    owner = property(lambda self: self.own.owner, doc="(G + E,) owning group of every object")
    per_object_max = property(lambda self: self.errors.per_max, doc="(G + E,) m, eq. 3-1 at the last frame")
    per_object_rms = property(lambda self: self.errors.per_rms, doc="(G + E,) m, eq. 3-2 at the last frame")
    hist = property(lambda self: self.history.hist, doc="(HIST, viewer group, avatar, xy) m, shown avatars")
    busy = property(lambda self: self.msgs.busy, doc="(n,) s, uplink busy-until")
    supernode = property(lambda self: self.groups.supernode)
    master = property(lambda self: self.groups.master)
    slaves = property(lambda self: self.groups.slaves)
    online = property(lambda self: self.groups.online)
    alive = property(lambda self: self.groups.alive)
    shown_frame = property(lambda self: self.groups.shown_frame)
    overlay = property(lambda self: self.groups.overlay)
    join_hops = property(lambda self: self.groups.join_hops)

    def get_state(self):
        """Deep copy of the whole model (events, RNG, caches, world) for FMU get/set state."""
        return copy.deepcopy(self.__dict__)

    def set_state(self, state) -> None:
        self.__dict__.update(copy.deepcopy(state))
