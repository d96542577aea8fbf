"""Who is on line: joins, leaves and time-outs at the supernode, masters and slaves (§3.5.1).

A group's master is its first online render node (rule 1), the others its slaves; the
masters form a Pastry overlay (a new master routes a JOIN to its own ID).
"""
from __future__ import annotations

from typing import List, Optional

import numpy as np

from .ids import PastryOverlay
from .nodes import H
from .pdu import PduType
from .supernode import CONTROLLER, RENDER, Supernode


class Membership:
    """Node processes, the supernode's table and each group's master and slaves.

    Attributes
    ----------
    alive : (n,) bool, node process running (sends heartbeats)
    online : (n,) bool, listed in the supernode's table; ``n_online`` its count
    master : (G,) int, each group's master render node (-1: none)
    slaves : list of (k,) int, each group's slave render nodes
    shown_frame : (n,) int, the frame each slave shows
    version : int, bumped whenever a group's master or slaves are set
    overlay : PastryOverlay of the masters (None above 512 masters); ``join_hops`` per new master
    """

    def __init__(self, cfg, reg) -> None:
        G = cfg.groups
        self.supernode = Supernode(cfg.membership.heartbeat_timeout_s)
        self.alive = np.zeros(reg.n, bool)
        self.online = np.zeros(reg.n, bool)
        self.n_online = 0
        self.master = np.full(G, -1, np.int64)
        self.slaves: List[np.ndarray] = [np.zeros(0, np.int64) for _ in range(G)]
        self.shown_frame = np.zeros(reg.n, np.int64)
        self.version = 0
        self._slaves_memo: Optional[tuple] = None  # (version, slave nodes, arange(G), slave list)
        self._online_memo: Optional[tuple] = None  # (version, groups with a master, their indices)
        self.overlay: Optional[PastryOverlay] = None
        self.join_hops: List[int] = []

    def join(self, net, t: float, node: int) -> None:
        """Node ``node`` joins at ``t`` (s): listed at the supernode, its group's master re-chosen."""
        reg = net.reg
        g = int(reg.group[node])
        kind = CONTROLLER if node >= reg.controller0 else RENDER
        self.supernode.join(t, node, reg.identify[g], kind, reg.ip[node], reg.port[node], net.cfg.scene.scene_id)
        self.alive[node] = True
        self.set_online(node, True)
        if kind == RENDER:
            self.refresh_group(net, g)

    def set_online(self, node: int, on: bool) -> None:
        """Mark ``node`` listed (or not) in the supernode's table, keeping ``n_online``."""
        if bool(self.online[node]) != on:
            self.n_online += 1 if on else -1
            self.online[node] = on

    def leave(self, net, node: int, timed_out: bool) -> None:
        if not self.online[node]:
            return
        self.supernode.leave(node, timed_out)
        self.set_online(node, False)
        if node < net.reg.controller0:
            self.refresh_group(net, int(net.reg.group[node]))

    def expire(self, net, t: float) -> None:
        """The supernode's time-out check at ``t``: nodes without a heartbeat go off line."""
        for node in self.supernode.expire(t):
            self.set_online(node, False)
            self.refresh_group(net, int(net.reg.group[node]))

    def refresh_group(self, net, g: int) -> None:
        """Master = first online render node of the group (§3.5.1 rule 1); the rest are slaves."""
        rows = self.supernode.group(net.reg.identify[g])
        nodes = np.array([r.node for r in rows], np.int64)
        old = self.master[g]
        self.version += 1
        self.master[g] = nodes[0] if len(nodes) else -1
        self.slaves[g] = nodes[1:]
        self.shown_frame[nodes[1:]] = np.minimum(self.shown_frame[nodes[1:]], net.k) if len(nodes) > 1 else 0
        if old != self.master[g] and self.overlay is not None:
            self.rebuild_overlay(net, new_master=int(self.master[g]) if self.master[g] >= 0 else None)

    def rebuild_overlay(self, net, new_master: Optional[int] = None) -> None:
        """Pastry overlay of the cluster's masters; a new master routes a JOIN to its own ID."""
        ids = [net.reg.nid[m] for m in self.master if m >= 0]
        if not ids or len(ids) > 512:  # routing tables of very large clusters are built lazily (cost O(N^2))
            self.overlay = None
            return
        cfg = net.cfg
        self.overlay = PastryOverlay(ids, cfg.membership.pastry_b, cfg.membership.pastry_L, cfg.membership.pastry_M)
        if new_master is not None and len(ids) > 1:
            me = net.reg.nid[new_master]
            boot = min((i for i in ids if i != me))
            hops = len(self.overlay.route(boot, me)) - 1
            self.join_hops.append(hops)
            net.count(hops, hops * H, PduType.JOIN)

    def online_groups(self):
        """Groups with a master (G,) bool (read-only) and their indices, kept while the groups
        stay (the masters change only in :meth:`refresh_group`, which bumps the version)."""
        memo = self._online_memo
        if memo is None or memo[0] != self.version:
            online_g = self.master >= 0
            online_g.flags.writeable = False
            memo = self._online_memo = (self.version, online_g, np.flatnonzero(online_g))
        return memo[1], memo[2]

    def slave_nodes(self, groups: int):
        """Every slave render node (k,), ``arange(groups)`` and the slaves as a list, kept while
        the groups stay."""
        memo = self._slaves_memo
        if memo is None or memo[0] != self.version:
            sl = (np.concatenate([s for s in self.slaves if len(s)]) if any(len(s) for s in self.slaves)
                  else np.zeros(0, int))
            memo = self._slaves_memo = (self.version, sl, np.arange(groups), sl.tolist())
        return memo[1], memo[2], memo[3]
