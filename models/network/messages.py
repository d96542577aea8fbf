"""Frame phase 4: who sees what (the grid's view, §3.3), this frame's messages by topology
(:func:`nodes.build_messages`) and their timing on the links (:mod:`.links`).

A pair (viewer group, object) is in view when the object's cell is in the 9-cell neighbourhood
of the viewer avatar's cell; a pair entering the view is subscribed at the frame time (the
record cache's ``enter_col``) and gets the object's state this frame even without DIS
publication; with ``state_traffic = 'neighbour_nodes'`` only a viewer whose avatar is in the
9-cell neighbourhood of the owner's avatar gets it (:meth:`Messaging.neighbours`). Messages are sampled per (sender, receiver, PDU type) with their own arrival
times (latency + jitter + serialisation on the sender's uplink).
"""
from __future__ import annotations

from typing import Optional

import numpy as np

from .nodes import Traffic, TrafficPlan, build_messages


class Messaging:
    """The view and the messages of the last frame, and the senders' uplinks.

    Attributes
    ----------
    busy : (n,) s, each node's uplink is busy until then
    prev : (cells, online groups) of the last frame, or None before the first frame (every
        pair counts as in view at frame 0: the scene file)
    """

    def __init__(self, n_nodes: int) -> None:
        self.busy = np.zeros(n_nodes)
        self.prev: Optional[tuple] = None
        self._cells: Optional[tuple] = None     # (positions array, their cells, the cells as a list or None)
        self._view: Optional[tuple] = None      # (cells, online groups, view pairs, group version)
        self._view_hit = False
        self._owners: Optional[tuple] = None    # (epoch, view, owner of each view pair)
        self._msgs: Optional[dict] = None       # the last small frame's messages (see messages)

    # -- the view ------------------------------------------------------------------------------
    def cells(self, net, P: np.ndarray) -> np.ndarray:
        """Grid cell (n_obj,) of every object at positions ``P``, the same array while no object
        changes cell."""
        cm = self._cells
        if cm is not None and cm[0] is P:   # the same position array (a scene at rest): the same cells
            return cm[1]
        cl = net.grid._cell_scalar(net.positions_list(P)) if len(P) <= net.paths.scalar_view else None
        if cl is not None and cm is not None and cm[2] == cl:   # nobody changed cell: the same array
            cells = cm[1]
        else:
            cells = net.grid.cell(P) if cl is None else np.array(cl, np.int64)
        self._cells = (P, cells, cl)
        return cells

    def view(self, net, cells: np.ndarray, online_g: np.ndarray):
        """(viewer, object) pairs of the 9-cell neighbourhoods of the online groups (§3.3): object
        (k,), viewer group (k,), flat cache index (k,), and the objects per viewer (G,).
        The last frame's pairs are reused when no object changed cell and the same groups are
        online (a scene at rest, or slow objects in large cells)."""
        memo = self._view
        if (net.paths.reuse_views and memo is not None
                and (memo[3] == net.groups.version or np.array_equal(memo[1], online_g))
                and (memo[0] is cells or memo[0].tobytes() == cells.tobytes())):   # (the same int64 cells)
            self._view_hit = True
            return memo[2]
        self._view_hit = False
        viewers = online_g.nonzero()[0]
        vo, vg_local = net.grid.view_pairs(cells, cells[viewers])
        vg = viewers[vg_local]
        out = (vo, vg, net.records.index(vg, vo), np.bincount(vg, minlength=net.cfg.groups))
        self._view = (cells, online_g, out, net.groups.version)
        return out

    def view_owners(self, net, view: tuple) -> np.ndarray:
        """Owner of the object of each view pair (kept while the view and the owners stay)."""
        memo = self._owners
        epoch = net.own.epoch
        if memo is not None and memo[0] == epoch and memo[1] is view:
            return memo[2]
        og = net.own.owner.take(view[0])
        self._owners = (epoch, view, og)
        return og

    def subscribe(self, net, fr) -> None:
        """Pairs that entered a view this frame get the frame time as their subscription time;
        ``fr.newly`` their mask (None: nobody entered, or a full mesh broadcast to everyone)."""
        fr.newly = None
        if net.cfg.net.topology == "full_mesh":  # a broadcast subscribes everyone to everything
            return
        if not self._view_hit:
            vo, vg, fi, _ = fr.view
            newly = np.zeros(len(vg), bool)
            if self.prev is not None:
                pc, pon = self.prev
                newly[net.grid.not_in_view(pc, pon, fr.cells, vg, vo)] = True
            if newly.any():
                rc = net.records
                rc.cache[fi[newly], rc.enter_col] = fr.t
                net.errors.clean = None
                fr.newly = newly
        self.prev = (fr.cells, fr.online_g)

    def in_view(self, net, viewer: int, obj: int) -> bool:
        """``obj`` was in the 9-cell neighbourhood of online group ``viewer`` at the last frame."""
        if self.prev is None:
            return True
        cells, online = self.prev
        return bool(online[viewer]) and (not net.grid.enabled
                                         or bool(net.grid.adjacent(cells[obj], cells[viewer])))

    # -- the messages --------------------------------------------------------------------------
    def messages(self, net, fr):
        """This frame's messages (:func:`nodes.build_messages`) with their :class:`TrafficPlan`,
        and the memo entry (a dict, or None) they came from.

        In small scenes (at most ``paths.memo_pairs`` view pairs) the messages of the last frame
        are reused when every input but the time is the same (groups, owners, publications,
        view pairs): only the send times, ``t`` or ``t`` plus the composition time, differ.
        Without DIS and with nobody entering a view, those inputs are functions of the
        groups (version), the owners (epoch) and the view pairs (the object ``view``), so the
        memo is found without comparing arrays.
        """
        cfg, t, view, newly, og, pub = net.cfg, fr.t, fr.view, fr.newly, fr.og, fr.pub
        grp, owner = net.groups, net.own.owner
        vo, vg, fi, frame_size = view
        if newly is not None and cfg.consistency.ownerless:   # an ownerless object entering a view: nobody sends it
            newly = newly & (og >= 0)
        memo = self._msgs
        fast = None
        if len(vg) <= net.paths.memo_pairs:
            if cfg.consistency.dis_threshold <= 0 and newly is None:
                fast = (grp.version, net.own.epoch)
                if memo is not None and memo["fast"] == fast and memo["view"] is view:
                    return self._resend(memo, t), memo
            send_pair = self.neighbours(net, fr, pub[vo] if newly is None else pub[vo] | newly)
            key = (grp.master.tobytes(), tuple(s.tobytes() for s in grp.slaves), fr.pub_obj.tobytes(),
                   owner.tobytes(), vg.tobytes(), vo.tobytes(), send_pair.tobytes(), og.tobytes())
            if memo is not None and memo["key"] == key:
                memo["fast"], memo["view"] = fast, view
                return self._resend(memo, t), memo
        else:
            send_pair = self.neighbours(net, fr, pub[vo] if newly is None else pub[vo] | newly)
        tr = build_messages(cfg, net.reg, t, grp.master, grp.slaves, fr.pub_obj, owner, vg, vo, frame_size,
                            send_pair, og, net.paths.scalar_messages)
        tr.plan = TrafficPlan(tr, cfg.net.links, net.paths)
        if fast is None and len(vg) > net.paths.memo_pairs:
            return tr, None
        # send times of a reuse: t + (composition time or 0), the same sums as build_messages's
        delay = np.where(tr.send_t != t, cfg.scene.compose_ms * 1e-3, 0.0)
        self._msgs = memo = {"key": key, "fast": fast, "view": view, "tr": tr, "delay": delay}
        return tr, memo

    @staticmethod
    def neighbours(net, fr, send_pair: np.ndarray) -> np.ndarray:
        """``send_pair`` (one bool per view pair) as the ``state_traffic`` rule has it: with
        'neighbour_nodes' (§3.3) a pair is kept only when the viewer's avatar is in the 9-cell
        neighbourhood of the object's owner's avatar (the avatars are objects ``0..G-1``, so
        the owner group is its avatar's object); an ownerless object is sent by nobody anyway."""
        if net.cfg.net.state_traffic == "object_view" or not net.grid.enabled or net.cfg.net.topology == "full_mesh":
            return send_pair
        vg, og, cells = fr.view[1], fr.og, fr.cells
        near = net.grid.adjacent(cells.take(np.maximum(og, 0)), cells.take(vg))
        return send_pair & near

    @staticmethod
    def _resend(memo: dict, t: float) -> Traffic:
        """The memo's messages sent at ``t`` (the memo's Traffic, its send times replaced). A
        batch timed in Python floats (:meth:`transmit_floats`) gets them as a list
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

    # -- the links -----------------------------------------------------------------------------
    def transmit_floats(self, net, tr: Traffic) -> Optional[list]:
        """:meth:`transmit` of a small batch of first hops on lossless links
        (:meth:`links.TransmitPlan.run_floats`): the arrival times (n,) s as a list, nothing
        lost; None for any other batch."""
        plan = tr.plan
        if plan.second is not None or plan.hop1.floats is None:
            return None
        net.count_batch(plan)
        send = tr.send_list if tr.send_t is None else tr.send_t.tolist()
        return plan.hop1.run_floats(net.rng, send, self.busy, net.latency_scale)

    def transmit(self, net, tr: Traffic):
        """Arrival times (n,) s and losses (n,) bool of a frame's messages (first hops, then
        relayed hops)."""
        plan = tr.plan
        n = plan.n
        arrival, lost = np.zeros(n), np.zeros(n, bool)
        net.count_batch(plan)
        first = plan.first
        rng, busy, scale = net.rng, self.busy, net.latency_scale
        a1, l1 = plan.hop1.run(rng, tr.send_t[first], busy, scale)
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
            a2, l2 = plan.hop2.run(rng, send2[second], busy, scale)
            arrival[second], lost[second] = a2, lost[second] | l2
        net.metrics.lost_messages += int(np.count_nonzero(lost))
        return arrival, lost

    def send(self, net, fr) -> None:
        """Phase 4: cells, view, subscriptions, messages and their timing into ``fr`` (``cells``,
        ``view``, ``og``, ``newly``, ``tr``, ``memo``, and ``arr_l`` for a batch timed in Python
        floats, else ``arrival`` and ``lost``)."""
        fr.cells = self.cells(net, fr.P)
        fr.view = self.view(net, fr.cells, fr.online_g)
        fr.og = self.view_owners(net, fr.view)
        self.subscribe(net, fr)
        fr.tr, fr.memo = self.messages(net, fr)
        fr.arr_l = self.transmit_floats(net, fr.tr)    # a small lossless batch in Python floats (or None)
        if fr.arr_l is None:
            fr.arrival, fr.lost = self.transmit(net, fr.tr)
