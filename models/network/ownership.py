"""Frame phase 2: ownership of the entities (§3.6.2) and hand-overs.

Avatars belong to their group; an entity to the group whose ownership region claims it
(:func:`consistency.assign_owners`, eq. 3-6, 3-11/3-12), initially the nearest avatar. A hand-over
is held for ``handover_hold_s``; the old owner knew the exact state when it let go, so its
cache starts from it. Every change bumps ``epoch``: records in flight sent before it have
their senders checked on delivery (§3.6.1).

With ``cfg.consistency.ownerless`` an entity that no region claims has no owner (-1, §3.6.3): its
owner publishes its state of that frame and then lets it go; from then nobody publishes it and
every node shows its own prediction (the scene's entity law from its last record,
:class:`display.FreePrediction`); a region (or an avatar touching it, :mod:`.contacts`) claims it
again. Releases and claims are decided by every node from the same rule and state, so they send
no message of their own; only a hand-over between two owners does.
"""
from __future__ import annotations

from typing import Optional

import numpy as np

from .consistency import PointIndex, assign_owners
from .nodes import H
from .pdu import PduType, record_bytes


def initial_owners(cfg, world) -> np.ndarray:
    """Owning group (G + E,) of every object at the start: avatars their group, entities the
    nearest avatar (round robin without an ownership rule); with ``cfg.consistency.ownerless`` the region
    of a resting avatar holding the entity, else none (-1). The nearest avatar: every pair up to
    ``world.paths.brute_owners`` pairs, else a k-d tree (the same squared distances, the same
    owners; of two avatars at exactly the same distance the brute force takes the first)."""
    G, E = cfg.groups, cfg.entities
    if cfg.consistency.ownership == "none" or E == 0:
        ent = np.arange(E) % G
    elif cfg.consistency.ownerless:
        ent = assign_owners(cfg.consistency.ownership, world.apos, np.zeros((G, 2)), world.epos, np.full(E, -1, np.int64),
                            cfg.scene.frame_s, cfg.consistency.ownership_scale, cfg.consistency.ownership_min_axis, cfg.consistency.ownership_foci)
    elif G * E <= world.paths.brute_owners:
        ent = nearest(world.epos, world.apos)
    else:
        from scipy.spatial import cKDTree

        ent = cKDTree(world.apos).query(world.epos)[1].astype(np.int64)
    return np.r_[np.arange(G), ent]


def nearest(q: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Index (k,) int64 of the point of ``pts`` (n, 2) m nearest each query point ``q`` (k, 2) m,
    by every pair's squared distance ``dx dx + dy dy`` (a k-d tree's own sum); ties: the first."""
    dx = q[:, None, 0] - pts[None, :, 0]
    dy = q[:, None, 1] - pts[None, :, 1]
    return np.argmin(dx * dx + dy * dy, axis=1).astype(np.int64)


def _touching_scalar(free: list, ep: list, cand: list, ap: list, r2: float, new: np.ndarray) -> np.ndarray:
    """:meth:`Ownership._touching` for a few pairs in Python floats: the same squared distances
    ``dx dx + dy dy``, the nearest avatar within ``r2`` (m^2), ties to the lower group."""
    out = None
    for e, (ex, ey) in zip(free, ep):
        best, who = r2, -1
        for g, (ax, ay) in zip(cand, ap):
            dx = ex - ax
            dy = ey - ay
            d2 = dx * dx + dy * dy
            if d2 < best or (who < 0 and d2 == best):
                best, who = d2, g
        if who >= 0:
            if out is None:
                out = new.copy()
            out[e] = who
    return new if out is None else out


class Ownership:
    """Who owns each object.

    Attributes
    ----------
    owner : (G + E,) int, owning group of every object (avatars first)
    hold : (G + E,) s, no hand-over of an object before this time
    claimed_t : (G + E,) s, when each object was last claimed from no owner (-inf: never)
    last : (G + E,) int, the group that let go of each ownerless object (its records in flight count)
    leaving : (E,) bool, entities no region claims, released after this frame's messages
    epoch : int, bumped at every ownership change
    """

    def __init__(self, cfg, world) -> None:
        self.owner = initial_owners(cfg, world)
        self.hold = np.full(len(self.owner), -np.inf)
        self.epoch = 0
        self.entity_ids = np.arange(cfg.groups, len(self.owner))
        self.claimed_t = np.full(len(self.owner), -np.inf)   # s, last claim of each object from no owner
        self.last = self.owner.copy()                         # the last owner of each object (ownerless: who let go)
        self.leaving = np.zeros(cfg.entities, bool)   # entities released after this frame's messages (ownerless)
        self._snap: Optional[tuple] = None   # (epoch, copy of the owners, as a list or None)

    def snapshot(self) -> tuple:
        """``(epoch, copy of the owners, None)`` taken once per epoch: the senders of filed records."""
        snap = self._snap
        if snap is None or snap[0] != self.epoch:
            snap = self._snap = (self.epoch, self.owner.copy(), None)
        return snap

    def snapshot_list(self, snap: tuple) -> list:
        """The owners of ``snap`` as a list (kept in the snapshot)."""
        if snap[2] is None:
            snap = self._snap = (snap[0], snap[1], snap[1].tolist())
        return snap[2]

    def handover(self, net, objs: np.ndarray, new: np.ndarray) -> None:
        """Give objects ``objs`` to groups ``new`` where the owner differs and no hold is on."""
        cfg = net.cfg
        if cfg.consistency.ownership == "none":
            return
        t = net.t
        changed = (self.owner[objs] != new) & (self.hold[objs] <= t + 1e-9)   # (hysteresis)
        if not changed.any():
            return
        o, old = objs[changed], self.owner[objs[changed]]
        if cfg.consistency.ownerless:
            return self._change_ownerless(net, o, old, new[changed])
        n = len(o)
        # the old owner knew the exact state when it let go: its cache starts from it
        P, V, A = (x[o] for x in net.world.state())
        rec = net.records.table(o, t, P, V, A)
        net.write_records(net.records.index(old, o), rec, np.arange(len(o)))
        net.errors.clean = None
        net.records.newest = max(net.records.newest, t)
        self.epoch += 1
        self.owner[o] = new[changed]
        self.hold[o] = t + cfg.consistency.handover_hold_s
        net.errors.touch(net.records.index(self.owner[o], o))   # the new owner's copy is no longer remote
        net.metrics.handovers += n
        net.count(n, n * (H + record_bytes(cfg.consistency.prediction_order)), PduType.HANDOVER)

    def _change_ownerless(self, net, o: np.ndarray, old: np.ndarray, new: np.ndarray) -> None:
        """Owner changes of objects ``o`` from ``old`` to ``new`` (-1: none) under ``ownerless``:
        an old owner's cache starts from the exact state it let go of (its copy now counts);
        hand-overs between two owners are sent (HANDOVER), releases and claims are not."""
        cfg, t, rc = net.cfg, net.t, net.records
        let_go = old >= 0
        if let_go.any():
            lo = o[let_go]
            P, V, A = (x[lo] for x in net.world.state())
            net.write_records(rc.index(old[let_go], lo), rc.table(lo, t, P, V, A), np.arange(len(lo)))
            rc.newest = max(rc.newest, t)
        net.errors.clean = None
        self.epoch += 1
        self.owner[o] = new
        self.hold[o] = t + cfg.consistency.handover_hold_s
        taken = new >= 0
        self.claimed_t[o[~let_go]] = t
        self.last[o[let_go & ~taken]] = old[let_go & ~taken]
        net.errors.touch(rc.index(new[taken], o[taken]))   # a new owner's copy is no longer remote
        n = int(np.count_nonzero(let_go & taken))
        net.metrics.handovers += n
        net.metrics.released += int(np.count_nonzero(~taken))
        net.metrics.claimed += int(np.count_nonzero(~let_go))
        if n:
            net.count(n, n * (H + record_bytes(cfg.consistency.prediction_order)), PduType.HANDOVER)

    def assign(self, net, fr) -> None:
        """Phase 2: the regions' claims on the entities this frame (``fr``: positions, velocities,
        the online groups ``fr.cand``, the entity index), handed over."""
        cfg, w, paths = net.cfg, net.world, net.paths
        if cfg.consistency.ownership == "none" or not cfg.entities:
            return
        G = cfg.groups
        cur = self.owner[G:]
        # ownerless: every entity must be claimed by a region anew, else it has no owner
        held = np.full(len(cur), -1, np.int64) if cfg.consistency.ownerless else cur
        cand = fr.cand
        if len(cand) == G:   # every group online: local indices are the groups (V[:G] is avel)
            lazy = fr.lazy
            fr.vl = w.avatar_velocities() if lazy else None
            new = assign_owners(cfg.consistency.ownership, w.apos, None if lazy else fr.V[:G], w.epos, held, cfg.scene.frame_s,
                                cfg.consistency.ownership_scale, cfg.consistency.ownership_min_axis, cfg.consistency.ownership_foci, fr.etree,
                                (fr.pl[:G], fr.vl, fr.pl[G:]) if lazy else None, paths.scalar_owners,
                                paths.brute_owners)
        else:
            cur_local = (np.minimum(np.searchsorted(cand, cur), max(len(cand) - 1, 0)) if not cfg.consistency.ownerless
                         else held)
            new_local = assign_owners(cfg.consistency.ownership, w.apos[cand], w.avel[cand], w.epos, cur_local,
                                      cfg.scene.frame_s, cfg.consistency.ownership_scale, cfg.consistency.ownership_min_axis,
                                      cfg.consistency.ownership_foci, fr.etree, None, paths.scalar_owners, paths.brute_owners)
            claimed = new_local != cur_local
            new = held.copy()
            new[claimed] = cand[new_local[claimed]]
        if cfg.consistency.ownerless:
            new = self._last_word(cur, self._touching(net, cand, new))
        if new is not cur:   # (assign_owners may return cur itself: nobody changed owner)
            self.handover(net, self.entity_ids, new)

    @staticmethod
    def _touching(net, cand: np.ndarray, new: np.ndarray) -> np.ndarray:
        """The claims ``new`` (E,) with every entity no region claims but the avatar of an online
        group ``cand`` touches (centres within ``avatar_radius + entity_radius``, the contact
        distance; a contact's separation leaves them there) given to the nearest such avatar."""
        free = np.flatnonzero(new < 0)
        if not len(free) or not len(cand):
            return new
        w, cw = net.world, net.cfg.world
        r = (cw.avatar_radius + cw.entity_radius) * (1.0 + 1e-9)
        ep, ap = w.epos[free], w.apos[cand]
        if len(free) * len(cand) <= net.paths.scalar_owners:   # a few pairs: in Python floats
            return _touching_scalar(free.tolist(), ep.tolist(), cand.tolist(), ap.tolist(), r * r, new)
        if len(free) * len(cand) <= net.paths.brute_owners:   # every pair (cheaper than an index)
            ei, gi = np.divmod(np.arange(len(free) * len(cand)), len(cand))
        else:
            ei, gi = PointIndex(ap).near(ep, np.full(len(free), r))
        d = ep[ei] - ap[gi]
        d2 = np.einsum("ij,ij->i", d, d)
        ok = d2 <= r * r
        if not ok.any():
            return new
        ei, gi, d2 = ei[ok], gi[ok], d2[ok]
        order = np.lexsort((gi, d2, ei))            # per entity the nearest avatar (ties: lower group)
        first = order[np.r_[True, np.diff(ei[order]) != 0]]
        new = new.copy()
        new[free[ei[first]]] = cand[gi[first]]
        return new

    def _last_word(self, cur: np.ndarray, new: np.ndarray) -> np.ndarray:
        """The claims ``new`` (E,) without this frame's releases: an owner whose entity no region
        claims keeps it until its state of this frame (contact responses included) is published,
        even under DIS (:mod:`.publishing`); :meth:`release` then lets it go after the frame's
        messages, so every node's own prediction starts from that record (§3.6.3).
        ``leaving`` marks them."""
        self.leaving = (new < 0) & (cur >= 0)
        if self.leaving.any():
            new = new.copy()
            new[self.leaving] = cur[self.leaving]
        return new

    def release(self, net) -> bool:
        """The entities marked ``leaving`` this frame lose their owner (after the frame's
        messages, :meth:`delivery.Inflight.post`); whether any did."""
        if not self.leaving.any():
            return False
        objs = self.entity_ids[self.leaving]
        self.leaving = np.zeros(len(self.leaving), bool)
        epoch = self.epoch
        self.handover(net, objs, np.full(len(objs), -1, np.int64))
        return self.epoch != epoch

    def claim(self, net, ents: np.ndarray, groups: np.ndarray) -> None:
        """Ownerless entities ``ents`` touched by the avatars of ``groups`` become theirs (the
        first contact of an entity wins)."""
        ents, first = np.unique(ents, return_index=True)
        objs = net.cfg.groups + ents
        self.hold[objs] = -np.inf   # (a release's hold does not stop a claim: the toucher answered it)
        self.handover(net, objs, groups[first])
