"""Frame phase 5: records in flight, their delivery into the receivers' caches, and the slaves'
frame flips (§3.5.2, §3.6.1).

A record is filed under the first frame ``k`` with ``k T >= arrival``: it has arrived by that
tick and not by the one before. At a tick every record due is applied in send order; records
from a group that no longer owns the object are rejected (§3.6.1), a record older than the
cached one (reordering) is ignored. A slave shows frame ``k`` only if its FRAME packet arrived
by ``k T``; a late packet is dropped. With frame clock phases (``cfg.scene.frame_phase``: every
node's clock has its own phase, a group's display runs on its master's clock, the slaves locked
to it, §3.5.2) a record is due at the viewer's first frame at or after its arrival on the
viewer's clock (:meth:`Inflight.phased`).
"""
from __future__ import annotations

import math
from typing import Dict, List, Optional

import numpy as np

from .records import RID_OBJECT, T_COL


def due_frames(arrivals: list, T: float, k: int) -> list:
    """For each arrival (s), the first frame (>= ``k``) whose time (frame ``T`` s) is >= it, or -1
    for an arrival that is not finite or beyond any int64 frame: :meth:`Inflight.due` in
    Python (``max(ceil(a / T - 1e-9), k)`` per arrival)."""
    out = []
    for a in arrivals:
        x = a / T - 1e-9
        if not x < 4611686018427387904.0:    # 2^62 (False for NaN too)
            out.append(-1)
        else:
            out.append(k if x <= k else math.ceil(x))
    return out


class Inflight:
    """Records and FRAME packets on their way.

    Attributes
    ----------
    chunks : dict, frame k -> chunks ``(fi, sender, table, ridx, (epoch, t_send))`` due then, in
        send order (``ridx`` None: a few records as lists, :meth:`file_rows`)
    frames : list of (arrival s (inf: lost), slave node, frame k), FRAME packets to slaves
    """

    def __init__(self) -> None:
        self.chunks: Dict[int, List[tuple]] = {}
        self.frames: List[tuple] = []

    def due(self, net, arr: np.ndarray) -> np.ndarray:
        """First frame ``k`` (>= the current one) with ``k T >= arrival`` for arrivals ``arr`` (s).

        An arrival that is not finite (a lost message) or beyond any int64 frame (a link of
        almost no bandwidth) gives -1, "lost", as :meth:`file` reads it, without casting NaN,
        inf or an overflowing value to an integer."""
        k = np.maximum(np.ceil(arr / net.cfg.scene.frame_s - 1e-9), net.k)
        ok = k < 2.0 ** 62   # False for NaN too
        if not ok.all():
            k = np.where(ok, k, -1.0)
        return k.astype(np.int64)

    def _put(self, key: int, chunk: tuple) -> None:
        self.chunks.setdefault(key, []).append(chunk)

    def file(self, net, due, fi: np.ndarray, sender: np.ndarray, table: np.ndarray, ridx: np.ndarray,
             epoch: Optional[int] = None, t_send: Optional[float] = None) -> None:
        """File records ``table[ridx]`` for cache rows ``fi`` from senders ``sender[ridx]`` (the
        owners when the table was sent) under the frame they are due (``due`` (k,) array or
        list, or one int frame for all; -1: lost, dropped). ``epoch``: the ownership epoch the
        senders were checked against (-1: never; None: now); ``t_send``: the newest record time
        of ``table`` when the caller knows it (a frame's table: the frame time)."""
        if isinstance(due, int):   # every record due at frame ``due`` (-1: lost)
            if due >= 0 and len(fi):
                meta = (net.own.epoch if epoch is None else epoch,
                        float(table[:, T_COL].max()) if t_send is None else t_send)
                self._put(due, (fi, sender, table, ridx, meta))
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
        meta = (net.own.epoch if epoch is None else epoch,
                float(table[:, T_COL].max()) if t_send is None else t_send)
        if lo == hi and not some_lost:
            self._put(lo, (fi, sender, table, ridx, meta))
            return
        if isinstance(due, list):
            due = np.array(due, np.int64)
        if hi - lo <= 3:
            for key in range(lo, hi + 1):
                sel = due == key
                if sel.any():
                    self._put(int(key), (fi[sel], sender, table, ridx[sel], meta))
            return
        if some_lost:
            keep = due >= 0
            due, fi, ridx = due[keep], fi[keep], ridx[keep]
        order = np.argsort(due, kind="stable")
        due, fi, ridx = due[order], fi[order], ridx[order]
        cuts = np.flatnonzero(np.diff(due)) + 1
        for lo, hi in zip(np.r_[0, cuts], np.r_[cuts, len(due)]):
            self._put(int(due[lo]), (fi[lo:hi], sender, table, ridx[lo:hi], meta))

    def file_rows(self, net, fr, due, snap: tuple) -> None:
        """File a frame's few records (at most ``paths.few_records``, a small lossless batch) as
        Python lists: the rows of the frame's record table for the records' objects alone (the
        same values and record ids; the frame's table id is used up as by
        :meth:`RecordCache.table`), their flat cache indices and senders (the owners now,
        ``snap``), under the frame each is due (``due``: one frame for all, or one per record;
        -1: never). :meth:`deliver_rows` writes them row by row. ``fr.V`` None: the velocity rows
        from ``fr.vl`` (the avatars') and the entities' velocities."""
        memo, tr, t, V, A = fr.memo, fr.tr, fr.t, fr.V, fr.A
        rc = net.records
        rl = memo.get("rec_l")
        if rl is None:   # the records' flat indices and objects as lists (kept with the messages)
            rl = memo["rec_l"] = (rc.index(tr.rec_viewer, tr.rec_obj).tolist(), tr.rec_obj.tolist())
        fi, objs = rl
        owners = net.own.snapshot_list(snap)
        uid = rc.uid
        rc.uid += 1
        pos = net.positions_list(fr.P)
        ncol = rc.ncol
        if ncol >= 5 and V is None:   # V's rows: avatars' speed (cos, sin) yaw, the entities' velocities
            G = net.cfg.groups
            vl = fr.vl if fr.vl is not None else net.world.avatar_velocities()
            ev = net.world.evel
        rows = []
        for o in objs:
            row = [t] + pos[o]
            if ncol >= 5:
                row += V[o].tolist() if V is not None else vl[o] if o < G else ev[o - G].tolist()
                if ncol >= 7:
                    row += A[o].tolist()
            row.append(o * RID_OBJECT + uid)    # (= obj_rid[o] + uid, exact)
            rows.append(row)
        senders = [owners[o] for o in objs]
        meta = (net.own.epoch, float(t))
        if isinstance(due, int):
            if due >= 0:
                self._put(due, (fi, senders, rows, None, meta))
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
            self._put(d, (f, w, r, None, meta))

    def post(self, net, fr) -> None:
        """File this frame's records (phase 4's messages ``fr.tr`` and their timing) and FRAME
        packets: a record is due at its message's frame (-1: the message, or the first hop a
        relayed record waits for, was lost); the senders are the owners now."""
        cfg, tr, arr_l = net.cfg, fr.tr, fr.arr_l
        due = None
        small = arr_l is not None     # a small lossless batch timed in Python floats
        if len(tr.rec_msg):
            snap = net.own.snapshot()
            if arr_l is not None and net.phase is not None:   # the frame clocks' phases (:meth:`phased`)
                due = self.phased_floats(net, fr, net.own.snapshot_list(snap))
            elif arr_l is not None:
                rec_msg, _, carriers = tr.plan.lists()
                due_c = due_frames([arr_l[i] for i in carriers], cfg.scene.frame_s, net.k)
                if due_c.count(due_c[0]) == len(due_c):   # every record due at one frame
                    due = due_c[0]
                else:
                    at = dict(zip(carriers, due_c))
                    due = [at[i] for i in rec_msg]
            else:
                due_msg = self.due(net, fr.arrival)
                due_msg[fr.lost] = -1
                due = np.take(due_msg, tr.rec_msg)
                if tr.plan.wait is not None:
                    hop = tr.rec_hop1
                    due[(hop >= 0) & np.take(fr.lost, np.maximum(hop, 0))] = -1
            if net.phase is not None and arr_l is None:
                due = self.phased(net, fr, due, snap[1])
            if small and len(tr.rec_msg) <= net.paths.few_records and fr.memo is not None:
                self.file_rows(net, fr, due.tolist() if isinstance(due, np.ndarray) else due, snap)
                due = None
        if due is not None:
            # one record table per frame (objects x cache width, rows like the cache's); pairs
            # refer to it by object; the senders are the owners now (one snapshot per epoch)
            if fr.V is None:
                fr.V = net.world.state(acc=False)[1]
            rc = net.records
            table = rc.table(rc.obj_ids, fr.t, fr.P, fr.V, fr.A)
            memo = fr.memo
            if memo is None or memo.get("rec_fi") is None:
                rec_fi = rc.index(tr.rec_viewer, tr.rec_obj)
                if memo is not None:
                    memo["rec_fi"] = rec_fi
            else:
                rec_fi = memo["rec_fi"]
            self.file(net, due, rec_fi, snap[1], table, tr.rec_obj, t_send=float(fr.t))
        if len(tr.frame_msg):
            nxt = net.k + 1
            if arr_l is not None:   # nothing lost
                self.frames += [(arr_l[i], node, nxt) for i, node in tr.plan.lists()[1]]
            else:
                arr, lost = fr.arrival.tolist(), fr.lost.tolist()
                self.frames += [(math.inf if lost[i] else arr[i], node, nxt)
                                for i, node in zip(tr.frame_msg.tolist(), tr.frame_slave.tolist())]
        if net.own.release(net):   # entities no region claims, their state of this frame sent (ownership.py)
            fr.og = net.msgs.view_owners(net, fr.view)    # (the display counts the former owners' copies)

    def phased(self, net, fr, due: np.ndarray, owners: np.ndarray) -> np.ndarray:
        """Frames (k,) at which this frame's records are shown with the groups' frame clocks
        (``cfg.scene.frame_phase``, :attr:`NetworkModel.phase`: each group's master's clock): the
        owner sends at its frame, ``t_k + phi_owner``; a record
        arriving ``a - t_k`` later is shown at the viewer's first frame ``m`` with
        ``t_m + phi_viewer >= a + phi_owner`` (at least this one), -1 where ``due`` is (lost)."""
        tr, ph = fr.tr, net.phase
        arr = np.take(fr.arrival, tr.rec_msg) + ph.take(owners.take(tr.rec_obj)) - ph.take(tr.rec_viewer)
        return np.where(due >= 0, self.due(net, arr), -1)

    def phased_floats(self, net, fr, owners: list) -> list:
        """:meth:`phased` of a small lossless batch in Python floats (``fr.arr_l``; ``owners`` the
        owners' snapshot as a list): the same sums ``arrival + phi_owner - phi_viewer`` and
        frames (:func:`due_frames`)."""
        tr, ph, arr = fr.tr, net.phase.tolist(), fr.arr_l
        msg = tr.plan.lists()[0]
        return due_frames([arr[m] + ph[owners[o]] - ph[v] for m, o, v in zip(msg, tr.rec_obj.tolist(),
                                                                               tr.rec_viewer.tolist())],
                          net.cfg.scene.frame_s, net.k)

    def deliver_rows(self, net, fi: list, senders: list, rows: list, epoch: int, t_send: float) -> None:
        """:meth:`deliver` of a chunk filed by :meth:`file_rows`: the same sender check
        (§3.6.1), the same "newer than the cached record" test and the same cache writes, row by row."""
        G = net.cfg.groups
        if epoch != net.own.epoch:   # owners changed since it was sent: check the senders
            own = net.own.owner.tolist()
            last = net.own.last
            keep = [i for i, (f, w) in enumerate(zip(fi, senders))
                    if w == own[f // G] or (own[f // G] < 0 and w == last[f // G])]
            if len(keep) < len(fi):
                net.metrics.rejected_updates += len(fi) - len(keep)
                fi, rows = [fi[i] for i in keep], [rows[i] for i in keep]
        rc = net.records
        cache = rc.cache
        if t_send < rc.newest:   # possibly older than what the cache holds
            keep = [i for i, (f, r) in enumerate(zip(fi, rows)) if r[0] > cache[f, T_COL]]
            if len(keep) < len(fi):
                fi, rows = [fi[i] for i in keep], [rows[i] for i in keep]
        n = rc.rid_col + 1
        for f, r in zip(fi, rows):
            cache[f, :n] = r
        if net.errors.groups is not None:
            net.errors.touch(np.array(fi, np.int64))

    def deliver(self, net) -> None:
        """Apply every record due by the current frame; reject records from non-owners (§3.6.1).

        Chunks are applied in send order and one chunk holds one record per (viewer, object),
        so a newer record overwrites an older one; a record older than the cached one
        (reordering) is ignored.
        """
        G = net.cfg.groups
        k = net.k
        rc, own, shown = net.records, net.own, net.errors
        due = [key for key in self.chunks if key <= k]
        if len(due) > 1:
            due.sort()
        for key in due:
            for fi, sender, table, ridx, (epoch, t_send) in self.chunks.pop(key):
                if ridx is None:   # a few records as lists (file_rows)
                    self.deliver_rows(net, fi, sender, table, epoch, t_send)
                else:
                    if epoch != own.epoch:  # owners changed since it was sent: check the senders
                        now = np.take(own.owner, fi // G)   # (an entity released since: its last owner's record)
                        who = np.take(sender, ridx)
                        valid = (who == now) | ((now < 0) & (who == np.take(own.last, fi // G)))
                        if not valid.all():
                            net.metrics.rejected_updates += int((~valid).sum())
                            fi, ridx = fi[valid], ridx[valid]
                    if t_send < rc.newest:  # possibly older than what the cache holds
                        newer = table[ridx, T_COL] > rc.cache[fi, T_COL]
                        if not newer.all():
                            fi, ridx = fi[newer], ridx[newer]
                    net.write_records(fi, table, ridx)
                rc.newest = max(rc.newest, t_send)
                ex = net.pub.exact
                if epoch == -1 or ex is None or t_send < ex[1]:   # not a record of the resting scene
                    shown.clean = None

    def flip_frames(self, net, t: float) -> None:
        """Slaves whose FRAME for this tick has arrived by ``t`` show it; late or lost ones are
        dropped (§3.5.2). Pending FRAMEs due later stay."""
        fr = self.frames
        if not fr:
            return
        k = net.k
        lim = t + 1e-12
        later = [x for x in fr if x[2] > k]
        if len(later) == len(fr):   # every FRAME is due later
            return
        show = [x[1] for x in fr if x[2] == k and x[0] <= lim]
        sf = net.groups.shown_frame
        if len(show) <= net.paths.scalar_view:   # a few: element by element (cheaper than a fancy assignment)
            for node in show:
                sf[node] = k
        else:
            sf[show] = k
        net.metrics.dropped_frames += len(fr) - len(later) - len(show)
        self.frames = later
