"""Network service platform (supernode) and its heartbeat index table (table 2-2, §2.3.1.2).

A row per control platform or render node: ``Identify`` (the group's identity, shared by a
controller and its render nodes), node type, IP, port, scene ID, online order (sequence
number of login) and the heartbeat flag. The flag of a row is "started" only when a control
platform and at least one render node with the same Identify are online (§2.3.1.2). The
first render node of an Identify to log in is the master (F-RP); when it leaves or times out
the earliest remaining one takes over (§3.5.1 rule 1).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, List, Optional

CONTROLLER, RENDER = "controller", "render"


@dataclass
class IndexRow:
    """One row of table 2-2 (plus the time of the last heartbeat, for time-outs)."""

    node: int
    identify: str
    node_type: str
    ip: str
    port: int
    scene_id: int
    online_order: int
    heartbeat_started: bool = False
    last_seen: float = 0.0


class Supernode:
    """Heartbeat index table with joins, leaves and time-outs.

    Parameters
    ----------
    timeout_s : float
        A node silent for longer than this is removed (crash detection).
    """

    def __init__(self, timeout_s: float = 3.0) -> None:
        self.timeout_s = timeout_s
        self.rows: Dict[int, IndexRow] = {}
        self._order = 0
        self.joins = 0
        self.leaves = 0
        self.timeouts = 0

    def join(self, t: float, node: int, identify: str, node_type: str, ip: str, port: int, scene_id: int) -> IndexRow:
        """Register ``node`` at time ``t``; returns its row."""
        if node in self.rows:
            raise ValueError(f"supernode: node {node} ({identify}) is already online")
        if node_type not in (CONTROLLER, RENDER):
            raise ValueError(f"supernode: node type {node_type!r} must be {CONTROLLER!r} or {RENDER!r}")
        self._order += 1
        row = IndexRow(node, identify, node_type, ip, port, scene_id, self._order, last_seen=t)
        self.rows[node] = row
        self.joins += 1
        self._update_flags(identify)
        return row

    def leave(self, node: int, timed_out: bool = False) -> Optional[IndexRow]:
        """Remove ``node`` (graceful leave, or time-out when ``timed_out``)."""
        row = self.rows.pop(node, None)
        if row is None:
            return None
        if timed_out:
            self.timeouts += 1
        else:
            self.leaves += 1
        self._update_flags(row.identify)
        return row

    def heartbeat(self, t: float, node: int) -> None:
        """Record a heartbeat of ``node`` at ``t`` (ignored for unknown nodes)."""
        row = self.rows.get(node)
        if row is not None:
            row.last_seen = t

    def expire(self, t: float) -> List[int]:
        """Remove every node silent since ``t - timeout_s``; returns their ids."""
        dead = [n for n, r in self.rows.items() if t - r.last_seen > self.timeout_s]
        for n in dead:
            self.leave(n, timed_out=True)
        return dead

    def _update_flags(self, identify: str) -> None:
        rows = [r for r in self.rows.values() if r.identify == identify]
        started = any(r.node_type == CONTROLLER for r in rows) and any(r.node_type == RENDER for r in rows)
        for r in rows:
            r.heartbeat_started = started

    def group(self, identify: str) -> List[IndexRow]:
        """Online render nodes of ``identify`` in login order; the first is the master (F-RP)."""
        return sorted((r for r in self.rows.values() if r.identify == identify and r.node_type == RENDER),
                      key=lambda r: r.online_order)

    def master(self, identify: str) -> Optional[int]:
        g = self.group(identify)
        return g[0].node if g else None

    def cluster(self, scene_id: int) -> List[int]:
        """Masters of every group in scene ``scene_id`` (the cluster, §3.2.2)."""
        idents = sorted({r.identify for r in self.rows.values() if r.scene_id == scene_id and r.node_type == RENDER})
        return [m for m in (self.master(i) for i in idents) if m is not None]

    def table(self) -> List[dict]:
        """The index table as a list of dicts (table 2-2 columns), in online order."""
        return [dict(Identify=r.identify, type=r.node_type, ip=r.ip, port=r.port, scene_id=r.scene_id,
                     online_order=r.online_order, heartbeat="started" if r.heartbeat_started else "not started")
                for r in sorted(self.rows.values(), key=lambda r: r.online_order)]
