"""Nodes (control platforms, render nodes, supernode) and the forwarding rules of §3.5.1.

Render node ``i`` belongs to group ``i // R`` (``R`` render nodes per group); control
platform ``g`` has node index ``G R + g``; the supernode is ``G R + G``. Every node has an
identity string, IPv4 address, port and a 128-bit ID (MD5 of ``ip:port``, §2.3.1).

:func:`build_messages` turns one frame's traffic into aggregated messages, one per
(sender, receiver) and PDU type, following the topology:

``hybrid_p2p`` (thesis, §3.5.1)
    (2) control commands reach only the master (via the supernode, see
    :meth:`NetworkModel.set_input`); the master forwards the next frame to its slaves (FRAME,
    LAN); (3) slaves report their view's dynamic entities and collisions to the master
    (REPORT, LAN); (4) each master sends the objects it owns to the other masters of its
    cluster, restricted to those whose 9-cell neighbourhood holds the object when the grid is
    on (STATE, WAN).
``client_server``
    every message is relayed by the supernode: owners send their updates to it, it forwards to
    each receiver one aggregated batch once the inputs of that batch have arrived.
``full_mesh``
    every render node broadcasts its updates to every other render node (no grid, no
    hierarchy); a master's broadcast to its own slaves doubles as their frame.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import List, Optional

import numpy as np

from . import links as lk
from .arrays import sorted_unique, unique_values
from .config import NetworkConfig
from .ids import node_id
from .paths import Paths
from .pdu import HEADER, PduType, controller_bytes, record_bytes, report_bytes

H = HEADER.size
PDU_NAMES = {int(t): t.name for t in PduType}
LAN, WAN = lk.CLASS_INDEX["lan"], lk.CLASS_INDEX["wan"]


class NodeRegistry:
    """Static identities of every node of a configuration."""

    def __init__(self, cfg: NetworkConfig) -> None:
        G, R = cfg.groups, cfg.render_nodes
        self.G, self.R = G, R
        self.n_render = G * R
        self.controller0 = G * R
        self.supernode = G * R + G
        self.n = G * R + G + 1
        self.group = np.r_[np.arange(G * R) // R, np.arange(G), -1]
        self.group_list = self.group.tolist()    # the same, as Python ints
        self.rank = np.r_[np.arange(G * R) % R, np.full(G, -1), -1]
        self.identify = [f"Render-{g:04d}" for g in range(G)]
        self.ip: List[str] = []
        self.port: List[int] = []
        for i in range(self.n):
            g = int(self.group[i])
            if i == self.supernode:
                self.ip.append("10.255.255.1"), self.port.append(20001)
            elif i >= self.controller0:
                self.ip.append(f"10.{g // 250}.{g % 250}.200"), self.port.append(20010)
            else:
                self.ip.append(f"10.{g // 250}.{g % 250}.{10 + int(self.rank[i])}"), self.port.append(20014)
        self.nid = [node_id(f"{ip}:{port}") for ip, port in zip(self.ip, self.port)]

    def render_nodes(self, g: int) -> np.ndarray:
        return np.arange(g * self.R, (g + 1) * self.R)

    def controller(self, g: int) -> int:
        return self.controller0 + g


@dataclass
class Traffic:
    """Messages of one frame plus the record and frame deliveries they carry.

    Message arrays are parallel (``send_t`` s, ``sender``/``receiver`` node, ``link`` class,
    ``nbytes``, ``ptype``, ``hop_of``: index of the first-hop message a relayed message waits
    for, -1 if none, -2 if it waits for the first hops of its records, ``rec_hop1``). Record deliveries: ``rec_msg`` (message), ``rec_viewer`` (group),
    ``rec_obj``. Frame deliveries: ``frame_msg``, ``frame_slave`` (node).
    """

    send_t: np.ndarray
    sender: np.ndarray
    receiver: np.ndarray
    link: np.ndarray
    nbytes: np.ndarray
    ptype: np.ndarray
    hop_of: np.ndarray
    rec_msg: np.ndarray
    rec_viewer: np.ndarray
    rec_obj: np.ndarray
    frame_msg: np.ndarray
    frame_slave: np.ndarray
    rec_hop1: np.ndarray
    #: the :class:`TrafficPlan` of these messages, once built (shared by copies with other send times)
    plan: Optional["TrafficPlan"] = None
    #: the send times as a list when a reuse left ``send_t`` None (a batch timed in Python floats)
    send_list: Optional[list] = None


class TrafficPlan:
    """What sending a :class:`Traffic` needs that does not depend on its send times or draws.

    Totals (messages, bytes, bytes per PDU type), the first hops (``hop_of == -1``) and the
    relayed second hops, and one :class:`links.TransmitPlan` for each (``paths``: their
    merged draws and Python-float timing, :class:`paths.Paths`).
    """

    def __init__(self, tr: Traffic, links, paths: Paths = Paths()) -> None:
        self.n = len(tr.send_t)
        self.nbytes = int(tr.nbytes.sum())
        per_type = np.bincount(tr.ptype, weights=tr.nbytes, minlength=64)
        self.by_type = [(PDU_NAMES[p], int(per_type[p])) for p in per_type.nonzero()[0].tolist()]
        first = tr.hop_of == -1
        self.first = first
        self.hop1 = lk.TransmitPlan(links, tr.sender[first], tr.link[first], tr.nbytes[first], paths.merge_draws,
                                    paths.float_batch)
        second = ~first
        self.second = second if second.any() else None
        self.wait = None     # (first hops, records' messages) of records relayed once their first hop arrived
        if self.second is not None:
            direct = second & (tr.hop_of >= 0)
            self.direct, self.direct_src = direct, tr.hop_of[direct]
            wait = tr.rec_hop1 >= 0
            self.wait = (tr.rec_hop1[wait], tr.rec_msg[wait]) if wait.any() else None
            self.hop2 = lk.TransmitPlan(links, tr.sender[second], tr.link[second], tr.nbytes[second],
                                        paths.merge_draws, paths.float_batch)
        self._deliveries = (tr.rec_msg, tr.frame_msg, tr.frame_slave)
        self._lists: Optional[tuple] = None

    def lists(self) -> tuple:
        """The records' messages, the (message, slave) pairs of the frame deliveries and the
        messages that carry records (sorted) as Python lists (built on first use, for the
        small-batch path of the model)."""
        if self._lists is None:
            rec_msg, frame_msg, frame_slave = self._deliveries
            rec = rec_msg.tolist()
            self._lists = (rec, list(zip(frame_msg.tolist(), frame_slave.tolist())), sorted(set(rec)))
        return self._lists


class _Builder:
    """Collects message columns; scalars are expanded only once, in :meth:`arrays`."""

    NAMES = ("send_t", "sender", "receiver", "link", "nbytes", "ptype", "hop_of")

    def __init__(self) -> None:
        self.parts: List[tuple] = []
        self.n = 0

    def add(self, send_t, sender, receiver, link, nbytes, ptype, hop_of=-1) -> np.ndarray:
        k = len(sender)
        self.parts.append((k, (send_t, sender, receiver, link, nbytes, ptype, -1 if hop_of is None else hop_of)))
        idx = np.arange(self.n, self.n + k)
        self.n += k
        return idx

    def arrays(self):
        out = {}
        for j, name in enumerate(self.NAMES):
            dtype = float if name == "send_t" else np.int64
            col = np.empty(self.n, dtype)
            at = 0
            for k, vals in self.parts:
                col[at:at + k] = vals[j]
                at += k
            out[name] = col
        return out


def _group_pairs(a: np.ndarray, b: np.ndarray, nb: int):
    """Unique (a, b) keys: returns unique a, unique b, counts, inverse index of each pair."""
    key = a * nb + b
    counts = np.bincount(key, minlength=nb * nb)
    uk = np.flatnonzero(counts)
    lookup = np.zeros(nb * nb, np.int64)
    lookup[uk] = np.arange(len(uk))
    return uk // nb, uk % nb, counts[uk], lookup[key]


def _cat(parts) -> np.ndarray:
    """The parts as one int64 array (no copy for a single int64 part)."""
    if not parts:
        return np.zeros(0, np.int64)
    if len(parts) == 1:
        return np.asarray(parts[0], np.int64)
    return np.concatenate(parts).astype(np.int64, copy=False)


def build_messages(cfg: NetworkConfig, reg: NodeRegistry, t: float, master: np.ndarray, slaves: List[np.ndarray],
                   pub_obj: np.ndarray, owner: np.ndarray, view_g: np.ndarray, view_o: np.ndarray,
                   frame_size: np.ndarray, send_pair: np.ndarray, view_owner=None,
                   scalar_pairs: int = Paths().scalar_messages) -> Traffic:
    """Aggregated messages of one frame at time ``t``.

    Parameters
    ----------
    master : (G,) node index of each group's master, -1 if the group is offline
    slaves : per group, node indices of its online slaves
    pub_obj : objects published this frame
    owner : (n_obj,) owning group of each object
    view_g, view_o : (viewer group, object) pairs of the grid neighbourhoods (viewers online)
    frame_size : (G,) objects in each group's frame
    send_pair : (len(view_g),) bool, the pair's object is sent to the viewer this frame (it was
        published, or it has just entered the viewer's neighbourhood)
    scalar_pairs : int, up to this many view pairs the hybrid_p2p messages are built in Python
    """
    G = reg.G
    rec = record_bytes(cfg.consistency.prediction_order)
    rep = report_bytes()
    b = _Builder()
    compose = t + cfg.scene.compose_ms * 1e-3
    published = np.zeros(len(owner), bool)
    published[pub_obj] = True
    rec_msg, rec_view, rec_obj, fr_msg, fr_slave, rec_hop1 = [], [], [], [], [], []
    online_g = np.flatnonzero(master >= 0)
    if cfg.net.topology == "full_mesh":
        everyone = np.concatenate([master[online_g]] + [s for s in slaves if len(s)]).astype(np.int64)
        n_pub = np.bincount(owner[pub_obj], minlength=G)
        # masters: all their published objects to every other render node
        for g in online_g:
            m = master[g]
            others = everyone[everyone != m]
            same = reg.group[others] == g
            idx = b.add(t, np.full(len(others), m), others, np.where(same, LAN, WAN), H + n_pub[g] * rec, PduType.STATE)
            mine = pub_obj[owner[pub_obj] == g]
            viewers = reg.group[others[~same & (others == master[reg.group[others]])]]
            vidx = idx[~same & (others == master[reg.group[others]])]
            if len(mine) and len(viewers):
                rec_msg.append(np.repeat(vidx, len(mine)))
                rec_view.append(np.repeat(viewers, len(mine)))
                rec_obj.append(np.tile(mine, len(viewers)))
            if len(slaves[g]):
                sl_mask = np.isin(others, slaves[g])
                fr_msg.append(idx[sl_mask])
                fr_slave.append(others[sl_mask])
        for g in online_g:
            for s in slaves[g]:
                others = everyone[everyone != s]
                same = reg.group[others] == g
                b.add(t, np.full(len(others), s), others, np.where(same, LAN, WAN), H + rep, PduType.REPORT)
    else:
        # STATE: owner's master -> viewer's master for published objects in the viewer's neighbourhood
        vown = owner[view_o] if view_owner is None else view_owner
        if cfg.net.topology == "hybrid_p2p" and len(view_g) <= scalar_pairs:
            return _hybrid_messages_scalar(cfg, reg, t, master, slaves, view_g, view_o, vown, frame_size, send_pair)
        if send_pair.all():                        # every frame published: no filtering copy
            vg, vo, og = view_g, view_o, vown
        else:
            cand = np.flatnonzero(send_pair)       # few pairs in DIS mode: filter them first
            vg, vo, og = view_g[cand], view_o[cand], vown[cand]
        keep = (og != vg) & (np.take(master, og) >= 0)
        if not keep.all():
            vg, vo, og = vg[keep], vo[keep], og[keep]
        if cfg.net.topology == "hybrid_p2p":
            sg, rg, cnt, inv = _group_pairs(og, vg, G)
            idx = b.add(t, master[sg], master[rg], WAN, H + cnt * rec, PduType.STATE)
            rec_msg.append(idx[inv]), rec_view.append(vg), rec_obj.append(vo)
        else:  # client_server: owner -> server, server -> viewer
            srv = reg.supernode
            sent = unique_values(vo)
            n_pub = np.bincount(owner[sent], minlength=G)
            senders = np.flatnonzero((n_pub > 0) & (master >= 0))
            hop1 = np.full(G, -1)
            hop1[senders] = b.add(t, master[senders], srv, WAN, H + n_pub[senders] * rec, PduType.STATE)
            # second hop (-2: leaves when the last first-hop message feeding it has arrived)
            rg_u, _, inv = sorted_unique(vg)
            cnt = np.bincount(inv, minlength=len(rg_u))
            idx = b.add(t, np.full(len(rg_u), srv), master[rg_u], WAN, H + cnt * rec, PduType.RELAY, -2)
            rec_msg.append(idx[inv]), rec_view.append(vg), rec_obj.append(vo)
            rec_hop1.append(hop1[og])
        # FRAME and REPORT inside each group, all groups at once
        sl = np.concatenate([slaves[g] for g in online_g]).astype(np.int64) if len(online_g) else np.zeros(0, np.int64)
        if len(sl):
            sg = reg.group[sl]
            fb = H + frame_size[sg] * rec
            if cfg.net.topology == "hybrid_p2p":
                idx = b.add(compose, master[sg], sl, LAN, fb, PduType.FRAME)
                b.add(t, sl, master[sg], LAN, H + rep, PduType.REPORT)
            else:
                gs = unique_values(sg)
                h1 = np.full(G, -1)
                h1[gs] = b.add(compose, master[gs], reg.supernode, WAN, H + frame_size[gs] * rec, PduType.FRAME)
                idx = b.add(compose, np.full(len(sl), reg.supernode), sl, WAN, fb, PduType.RELAY, h1[sg])
                b.add(t, sl, reg.supernode, WAN, H + rep, PduType.REPORT)
            fr_msg.append(idx), fr_slave.append(sl)
    arr = b.arrays()
    cat = _cat
    hop1 = cat(rec_hop1)
    rmsg = cat(rec_msg)
    if len(hop1) != len(rmsg):
        hop1 = np.full(len(rmsg), -1, np.int64)
    return Traffic(arr["send_t"], arr["sender"], arr["receiver"], arr["link"], arr["nbytes"], arr["ptype"],
                   arr["hop_of"], rmsg, cat(rec_view), cat(rec_obj), cat(fr_msg), cat(fr_slave), hop1)


def _hybrid_messages_scalar(cfg: NetworkConfig, reg: NodeRegistry, t: float, master: np.ndarray,
                            slaves: List[np.ndarray], view_g: np.ndarray, view_o: np.ndarray, vown: np.ndarray,
                            frame_size: np.ndarray, send_pair: np.ndarray) -> Traffic:
    """The ``hybrid_p2p`` messages of :func:`build_messages` for a few view pairs, built in
    Python: the same messages in the same order (STATE per (owner, viewer) group pair in key
    order ``owner * G + viewer``, then FRAME and REPORT per slave of the online groups) and
    the same record and frame deliveries."""
    G = reg.G
    rec = record_bytes(cfg.consistency.prediction_order)
    ml = master.tolist()
    rv, ro, rk = [], [], []      # records: viewer, object, (owner, viewer) key
    for g, o, w, sent in zip(view_g.tolist(), view_o.tolist(), vown.tolist(), send_pair.tolist()):
        if sent and w != g and ml[w] >= 0:
            rv.append(g)
            ro.append(o)
            rk.append(w * G + g)
    cnt: dict = {}
    for k in rk:
        cnt[k] = cnt.get(k, 0) + 1
    keys = sorted(cnt)
    at = {k: i for i, k in enumerate(keys)}
    send_t = [t] * len(keys)
    sender = [ml[k // G] for k in keys]
    receiver = [ml[k % G] for k in keys]
    link = [WAN] * len(keys)
    nbytes = [H + cnt[k] * rec for k in keys]
    ptype = [int(PduType.STATE)] * len(keys)
    # FRAME and REPORT inside each group
    sl = [node for g in range(G) if ml[g] >= 0 for node in slaves[g].tolist()]
    n0 = len(keys)
    if sl:
        grp, fs = reg.group_list, frame_size.tolist()
        m = [ml[grp[node]] for node in sl]
        send_t += [t + cfg.scene.compose_ms * 1e-3] * len(sl) + [t] * len(sl)
        sender += m + sl
        receiver += sl + m
        link += [LAN] * (2 * len(sl))
        nbytes += [H + fs[grp[node]] * rec for node in sl] + [H + report_bytes()] * len(sl)
        ptype += [int(PduType.FRAME)] * len(sl) + [int(PduType.REPORT)] * len(sl)
    n = len(send_t)
    i64 = np.int64
    return Traffic(np.array(send_t, float), np.array(sender, i64), np.array(receiver, i64), np.array(link, i64),
                   np.array(nbytes, i64), np.array(ptype, i64), np.full(n, -1, i64), np.array([at[k] for k in rk], i64),
                   np.array(rv, i64), np.array(ro, i64), np.arange(n0, n0 + len(sl), dtype=i64), np.array(sl, i64),
                   np.full(len(rk), -1, i64))


def control_bytes() -> int:
    """Bytes of one CONTROL PDU carrying a ControllerPacket."""
    return H + controller_bytes()
