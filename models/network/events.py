"""Events between frames, each at its own time: controller inputs reaching a master, autopilot
input changes, delayed collision responses, heartbeats, time-out checks, joins and leaves.

The world is advanced exactly to an event's time before it is applied, so an input arriving
7.3 ms into a frame changes the avatar's motion from 7.3 ms.
"""
from __future__ import annotations

import heapq
from typing import List

import numpy as np

from . import links as lk
from .nodes import H, control_bytes
from .pdu import PduType

#: queued events that change what the nodes show (heartbeats and time-out checks do not)
PENDING = frozenset(("input", "impulse", "join", "leave"))


class EventQueue:
    """A heap of ``(t, seq, kind, data)`` events; ``pending`` counts those of a kind in
    :data:`PENDING` (see ``NetworkModel.at_rest``)."""

    def __init__(self) -> None:
        self.heap: List[tuple] = []
        self.pending = 0
        self.seq = 0

    def push(self, t: float, kind: str, *data) -> None:
        self.seq += 1
        self.pending += kind in PENDING
        heapq.heappush(self.heap, (t, self.seq, kind, data))

    def next_time(self, default: float) -> float:
        return self.heap[0][0] if self.heap else default

    def pop(self) -> tuple:
        """The earliest event's ``(kind, data)``."""
        _, _, kind, data = heapq.heappop(self.heap)
        self.pending -= kind in PENDING
        return kind, data


def control_delay(net) -> float:
    """Delay (s) of a ControllerPacket controller -> supernode -> master (hybrid and
    client-server; direct over the LAN in full mesh), counted as traffic."""
    links = net.cfg.net.links
    if net.cfg.net.topology == "full_mesh":
        net.count(1, control_bytes(), PduType.CONTROL)
        return float(net.latency_scale * lk.sample_latency(net.rng, links["lan"], 1)[0])
    net.count(2, 2 * control_bytes(), PduType.CONTROL)
    return float(net.latency_scale * lk.latency_sum(net.rng, links["wan"], 2))


def autopilot(net, t: float, g: int) -> None:
    """Group ``g`` (not driven) picks new random inputs; the next change after an exponential time."""
    thr = float(net.rng.uniform(0.1, 0.6))
    steer = float(net.rng.uniform(-0.3, 0.3))
    net.events.push(t + control_delay(net), "input", g, thr, steer)
    net.events.push(t + float(net.rng.exponential(net.cfg.world.autopilot_change_s)), "autopilot", g)


def handle(net, kind: str, data: tuple) -> None:
    """Apply event ``kind`` with ``data`` at the model's current time."""
    t, grp, ev = net.t, net.groups, net.events
    if kind == "input":
        g, thr, steer = data
        if grp.master[g] >= 0:
            net.world.advance_to(t, entities=False)
            net.world.set_input(g, thr, steer)
    elif kind == "autopilot":
        autopilot(net, t, data[0])
    elif kind == "impulse":
        e, dv, g = data
        net.world.advance_to(t, avatars=False)
        net.world.push_entity(e, np.asarray(dv))
        net.contacts.pending[e] = False
        net.own.handover(net, np.array([net.cfg.groups + e]), np.array([g]))
    elif kind == "heartbeat":
        node = data[0]
        if grp.alive[node]:
            grp.supernode.heartbeat(t, node)
            net.count(1, H, PduType.HEARTBEAT)
            ev.push(t + net.cfg.membership.heartbeat_s, "heartbeat", node)
    elif kind == "expire":
        grp.expire(net, t)
        ev.push(t + net.cfg.membership.heartbeat_s, "expire")
    elif kind == "leave":
        node, graceful = data
        grp.alive[node] = False
        if graceful:
            net.count(1, H, PduType.LEAVE)
            grp.leave(net, node, timed_out=False)
    elif kind == "join":
        node = data[0]
        if not grp.online[node]:
            net.count(1, H, PduType.JOIN)
            grp.join(net, t, node)
            ev.push(t + net.cfg.membership.heartbeat_s, "heartbeat", node)
    else:  # pragma: no cover
        raise ValueError(f"network model: unknown event {kind!r} at t = {t}")
