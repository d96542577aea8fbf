"""Display error of eq. 3-1/3-2 kept up to date by record groups (large scenes).

Every remote copy shown at frame time ``t`` is the viewer's cached record of the object,
dead-reckoned to ``t`` (§3.6.3): ``A_B(t) = p + v (t - t_r) (+ a (t - t_r)^2 / 2)``, and its
error is ``|A_B(t) - A(t)|`` against the owner's (true) state ``A(t)`` (eq. 3-1/3-2). Copies
of one object that hold the same record (same record id) show the same position, hence have
the same error. In a large scene most viewers of an object hold the same record (the owner's
last publication reached all of them), so the per-frame work is one evaluation per *record
group* ``(object, record id, number of counted copies)`` instead of one per copy.

A copy is *counted* when it is in view (the object is in the 9-cell neighbourhood of the
online viewer, §3.3), the viewer is not the owner, and its record is not older than its
subscription (``t_r >= t_enter``): exactly the copies of the plain per-copy evaluation. The
groups only change where a copy changed: a record written into it, the pair entering or
leaving the view, its object changing owner. The model reports written and re-owned pairs
(:meth:`DisplayGroups.touch`); entries and exits come from the cells that changed. A frame
that touched a large share of the copies (every object published every frame) is evaluated
per copy instead and the groups are rebuilt when they pay again.

The maxima (per object and overall) equal the per-copy ones exactly; the RMS values are
``sqrt(sum_g n_g e_g^2 / sum_g n_g)``, equal to the per-copy sums up to float round-off.
"""
from __future__ import annotations

from typing import List, Optional

import numpy as np

from .arrays import sum_by_key, unique_values
from .consistency import free_motion


def squared_dr_error(c: np.ndarray, ct: np.ndarray, x: np.ndarray, y: np.ndarray, t: float,
                     order: int) -> np.ndarray:
    """Squared position error (k,) m^2 of dead-reckoned records against the truth (eq. 3-1/3-2
    with §3.6.3): ``e = (p - truth) + v dt (+ a dt^2 / 2)``, ``dt = t - ct``.

    ``c`` (k, >= 7) holds rows ``t, px, py, vx, vy, ax, ay`` (the record cache's layout), ``ct``
    their record times (s), ``x, y`` (k,) the true positions (m). One sequence of in-place
    operations serves the per-copy and the per-record-group evaluations, so both give
    bit-identical errors.
    """
    ex = c[:, 1] - x
    ey = c[:, 2] - y
    if order >= 1:
        dt = t - ct
        ex += c[:, 3] * dt
        ey += c[:, 4] * dt
        if order >= 2:
            h = 0.5 * dt * dt
            ex += c[:, 5] * h
            ey += c[:, 6] * h
    ex *= ex
    ey *= ey
    ex += ey
    return ex

#: a frame that touched more than this share of the copies is evaluated per copy
TOUCHED_SHARE = 0.25


class FreePrediction:
    """What every node shows of the entities no avatar owns (§3.6.3): each node runs the scene's
    entity law (:func:`consistency.free_motion`) from its last record of the entity, instead of
    dead reckoning it (prediction orders >= 1; order 0 predicts nothing).

    Copies holding the same record (record id) show the same prediction, so one state per record
    id is kept and advanced from frame to frame (``key`` sorted record ids, ``t`` s, ``p``, ``v``
    (k, 2) m, m/s): a record released long ago costs one frame of sub-steps per frame.
    """

    def __init__(self) -> None:
        self.key = np.zeros(0, np.int64)
        self.t = np.zeros(0)
        self.p = np.zeros((0, 2))
        self.v = np.zeros((0, 2))

    def positions(self, net, rows: np.ndarray, t: float) -> np.ndarray:
        """Shown positions (k, 2) m at frame time ``t`` of the cache ``rows`` (k, width) of
        ownerless entities (order >= 1); the states kept are those of these rows' records."""
        rid = rows[:, net.records.rid_col].astype(np.int64)
        uk, first, inv = np.unique(rid, return_index=True, return_inverse=True)
        r = rows[first]
        t0, p0, v0 = r[:, 0].copy(), r[:, 1:3].copy(), r[:, 3:5].copy()
        if len(self.key):   # records predicted at an earlier frame: on from there
            at = np.minimum(np.searchsorted(self.key, uk), len(self.key) - 1)
            kept = (self.key[at] == uk) & (self.t[at] <= t)
            at = at[kept]
            t0[kept], p0[kept], v0[kept] = self.t[at], self.p[at], self.v[at]
        cfg = net.cfg
        turn = net.world.eturn[(uk >> 32) - cfg.groups]
        p, v = free_motion(p0, v0, turn, cfg.world.entity_drag, t - t0, cfg.scene.scene_size,
                           cfg.scene.frame_s / cfg.world.substeps)
        self.key, self.t, self.p, self.v = uk, np.full(len(uk), t), p, v
        return p[inv.ravel()]

    def positions_floats(self, net, rows: list, t: float) -> list:
        """:meth:`positions` of a few cache rows given as lists of Python floats: the same record
        states (first row of each record id, the kept state where it is not newer than ``t``),
        the same :func:`consistency.free_motion` call and the same state kept, so the same
        positions bit for bit; returns ``[x, y]`` (m) per row."""
        rid_col = net.records.rid_col
        rids = [int(r[rid_col]) for r in rows]
        first = {}
        for j, u in enumerate(rids):
            first.setdefault(u, j)
        uk = sorted(first)
        kept = {k: i for i, k in enumerate(self.key.tolist())} if len(self.key) else {}
        t_kept = self.t.tolist() if kept else ()
        t0, p0, v0, at = [], [], [], []
        for u in uk:
            i = kept.get(u)
            if i is not None and t_kept[i] <= t:   # predicted at an earlier frame: on from there
                at.append(i)
                t0.append(t_kept[i])
                p0.append(None)
                v0.append(None)
            else:
                r = rows[first[u]]
                at.append(-1)
                t0.append(r[0])
                p0.append(r[1:3])
                v0.append(r[3:5])
        if kept:
            for j, i in enumerate(at):
                if i >= 0:
                    p0[j], v0[j] = self.p[i].tolist(), self.v[i].tolist()
        cfg = net.cfg
        G = cfg.groups
        turn = net.world.eturn[[(u >> 32) - G for u in uk]]
        p, v = free_motion(np.array(p0, float), np.array(v0, float), turn, cfg.world.entity_drag,
                           t - np.array(t0, float), cfg.scene.scene_size, cfg.scene.frame_s / cfg.world.substeps)
        self.key, self.t, self.p, self.v = np.array(uk, np.int64), np.full(len(uk), t), p, v
        where = {u: j for j, u in enumerate(uk)}
        shown = p.tolist()
        return [shown[where[u]] for u in rids]

    def errors(self, net, rows: np.ndarray, obj: np.ndarray, t: float, P: np.ndarray) -> np.ndarray:
        """Squared display errors (k,) m^2 of the ownerless copies ``rows`` of objects ``obj``
        at frame time ``t`` against the truth ``P`` (n_obj, 2)."""
        d = self.positions(net, rows, t) - np.take(P, obj, axis=0)
        return np.einsum("ij,ij->i", d, d)


class DisplayGroups:
    """Record groups of the counted copies and the bookkeeping to update them.

    Parameters
    ----------
    n_pairs : int, number of (object, viewer) cache rows (``n_obj * G``)
    n_obj, groups : int
    """

    def __init__(self, n_pairs: int, n_obj: int, groups: int) -> None:
        self.n_obj, self.G = n_obj, groups
        self.crid = np.full(n_pairs, -1, np.int64)   # record id each copy is counted under, -1: not counted
        self.valid = False                           # groups reflect ``prev``'s frame
        self.key = np.zeros(0, np.int64)             # sorted record ids of the groups
        self.cnt = np.zeros(0, np.int64)             # counted copies per group
        self.rows = np.zeros((0, 0))                 # the groups' records (cache rows)
        self.prev: Optional[tuple] = None            # (cells, online, vo, vg, fi) of the last frame measured
        self.touched: List[np.ndarray] = []          # pairs written / re-owned since then
        self.n_touched = 0                           # their number (kept while invalid too)

    def touch(self, fi: np.ndarray) -> None:
        """Pairs ``fi`` (flat cache indices) whose record or owner changed."""
        self.n_touched += len(fi)
        if self.valid:
            self.touched.append(np.asarray(fi, np.int64))

    def invalidate(self) -> None:
        self.valid = False
        self.touched = []
        self.n_touched = 0

    # -- the frame ------------------------------------------------------------------------
    def update(self, model, cells: np.ndarray, online: np.ndarray, vo: np.ndarray, vg: np.ndarray,
               fi: np.ndarray, og: np.ndarray) -> bool:
        """Bring the groups to this frame's view (``vo``, ``vg``, ``fi``, owners ``og`` of the
        objects; ``cells`` (n_obj,), ``online`` (G,) bool). Returns False (groups invalid) when
        the frame touched too many copies: the caller then evaluates per copy."""
        prev, self.prev = self.prev, (cells, online, vo, vg, fi)
        limit = TOUCHED_SHARE * max(len(fi), 1)
        n_touched, self.n_touched = self.n_touched, 0
        if not self.valid or prev is None:
            if n_touched > limit:     # records changed almost everywhere: stay per copy
                return False
            return self._rebuild(model, vg, fi, og)
        parts = self.touched
        self.touched = []
        pc, pon, pvo, pvg, pfi = prev
        if pvo is not vo:   # the view changed: pairs that entered or left it
            parts = parts + self._view_changes(model.grid, pc, pon, pvo, pvg, pfi, cells, online, vo, vg, fi)
        n = sum(len(p) for p in parts)
        if n > limit:
            self.invalidate()
            return False
        if n:
            self._apply(model, unique_values(np.concatenate(parts)), cells, online)
        return True

    def _rebuild(self, model, vg, fi, og) -> bool:
        """Groups from scratch over this frame's view: its copies are all in view, so a copy
        counts when it is not the owner's and holds a record since it subscribed."""
        self.crid.fill(-1)
        rows = np.take(model.cache, fi, axis=0)
        sel = np.flatnonzero((og != vg) & (rows[:, 0] >= rows[:, model.enter_col] - 1e-12))
        keys = np.take(rows[:, model.rid_col], sel).astype(np.int64)
        self.crid[fi[sel]] = keys
        self.key, first, self.cnt = sum_by_key(keys, np.ones(len(keys), np.int64))
        self.rows = np.take(rows, sel[first], axis=0)
        self.valid = True
        self.touched = []
        return True

    def _view_changes(self, grid, pc, pon, pvo, pvg, pfi, cells, online, vo, vg, fi) -> List[np.ndarray]:
        """Flat indices of the pairs that entered the view (in ``fi``) and left it (in ``pfi``)."""
        return [fi[grid.not_in_view(pc, pon, cells, vg, vo)], pfi[grid.not_in_view(cells, online, pc, pvg, pvo)]]

    def _apply(self, model, T: np.ndarray, cells: np.ndarray, online: np.ndarray) -> None:
        """Recount the copies ``T`` (unique flat indices) and move them between groups."""
        G = self.G
        o, g = np.divmod(T, G)
        rows = np.take(model.cache, T, axis=0)
        inview = np.take(online, g)
        if model.grid.enabled:
            inview &= model.grid.adjacent(np.take(cells, o), np.take(cells, g))
        counted = inview & (np.take(model.owner, o) != g) & (rows[:, 0] >= rows[:, model.enter_col] - 1e-12)
        new = np.where(counted, rows[:, model.rid_col].astype(np.int64), -1)
        old = self.crid[T]
        chg = old != new
        if not chg.any():
            return
        self.crid[T] = new
        dec = old[chg & (old >= 0)]
        inc_sel = np.flatnonzero(chg & (new >= 0))
        keys = np.concatenate([dec, new[inc_sel]])
        if not len(keys):
            return
        w = np.concatenate([np.full(len(dec), -1, np.int64), np.ones(len(inc_sel), np.int64)])
        uk, first, dw = sum_by_key(keys, w)
        pos = np.searchsorted(self.key, uk)
        found = pos < len(self.key)
        found[found] = self.key[pos[found]] == uk[found]
        np.add.at(self.cnt, pos[found], dw[found])
        fresh = np.flatnonzero(~found)
        if (dw[fresh] <= 0).any() or (self.cnt < 0).any():
            raise RuntimeError("network display groups: a copy left a group it was not counted in")
        if len(fresh):
            # a new group's record: the row of one of its copies (all of them hold the same record)
            rep = inc_sel[first[fresh] - len(dec)]
            self.key = np.insert(self.key, pos[fresh], uk[fresh])
            self.cnt = np.insert(self.cnt, pos[fresh], dw[fresh])
            self.rows = np.insert(self.rows, pos[fresh], rows[rep], axis=0)
        empty = self.cnt == 0
        if empty.any():
            keep = ~empty
            self.key, self.cnt, self.rows = self.key[keep], self.cnt[keep], self.rows[keep]

    # -- the metric ------------------------------------------------------------------------
    def errors(self, t: float, P: np.ndarray, order: int, free=None):
        """Eq. 3-1/3-2 at frame time ``t`` from the groups, truth ``P`` (n_obj, 2); ``free``:
        (the model's :class:`measure.DisplayError`, the model) when copies of entities without
        an owner are shown by the entity law (:class:`FreePrediction`), else None.

        Returns per-object max and RMS (n_obj,) m and the overall max and RMS (m), as
        :func:`metrics.inconsistency_sq` does over the copies.
        """
        n_obj = self.n_obj
        w = self.cnt
        n_valid = int(w.sum())
        if n_valid == 0:
            z = np.zeros(n_obj)
            return z, z.copy(), 0.0, 0.0
        o = self.key >> 32                 # record id = object * 2^32 + table id
        c = self.rows
        ct = c[:, 0]
        # the same arithmetic as the per-copy evaluation, so each group's error is bit-identical
        ex = squared_dr_error(c, ct, np.take(P[:, 0], o), np.take(P[:, 1], o), t, order)
        if free is not None:   # entities no avatar owns: every node's own prediction (§3.6.3)
            shown, net = free
            sel = np.flatnonzero(shown.free_copies(net, o, ct))
            if len(sel):
                ex[sel] = shown.free.errors(net, c[sel], o[sel], t, P)
        per_max = np.zeros(n_obj)
        np.maximum.at(per_max, o, ex)
        wf = w.astype(float)
        s2 = np.bincount(o, weights=ex * wf, minlength=n_obj)
        cnt = np.bincount(o, weights=wf, minlength=n_obj)
        per_rms = np.sqrt(np.divide(s2, cnt, out=np.zeros(n_obj), where=cnt > 0))
        return np.sqrt(per_max), per_rms, float(np.sqrt(ex.max())), float(np.sqrt(s2.sum() / n_valid))
