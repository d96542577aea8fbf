"""Frame phase 6b: the spatio-temporal inconsistency of the displayed copies (eq. 3-1/3-2).

A copy is an (object, viewer group) pair in view whose viewer does not own the object and has a
record of it since it subscribed; its error is its record dead-reckoned to the frame time
(§3.6.3) minus the truth: ``e = (p - truth) + v dt (+ a dt^2 / 2)``. Eq. 3-1 is the largest error
of an object's copies, eq. 3-2 their RMS; the frame's figures are over every counted copy.
"""
from __future__ import annotations

import math
from typing import Optional

import numpy as np

from .arrays import pairwise_sum
from .display import DisplayGroups, FreePrediction, squared_dr_error
from .metrics import inconsistency_sq, object_runs
from .records import T_COL


class DisplayError:
    """The display error of the last frame and what it keeps between frames.

    Attributes
    ----------
    per_max, per_rms : (G + E,) m, eq. 3-1/3-2 per object at the last frame (0 without a copy)
    clean : (P, view objects, view owners) or None: a resting scene whose every counted copy
        holds a record of that state, errors all 0 while nothing else arrives
    groups : DisplayGroups or None, record groups of large views
    last : (max, rms, desync frames) shown by the last frame (a step without a frame repeats it)
    """

    def __init__(self, n_obj: int) -> None:
        self.n_obj = n_obj
        self._raw: Optional[tuple] = None       # a small view's squared maxima, sums and counts
        self._per_max = np.zeros(n_obj)
        self._per_rms = np.zeros(n_obj)
        self.clean: Optional[tuple] = None
        self.groups: Optional[DisplayGroups] = None
        self.last = (0.0, 0.0, 0)
        self._scalar: Optional[tuple] = None    # (view owners, objects, flat indices, remote copies)
        self._segments: Optional[tuple] = None  # (vo, per-object runs of vo)
        self.free = FreePrediction()             # every node's own prediction of ownerless entities

    @property
    def per_max(self) -> np.ndarray:
        if self._raw is not None:
            self._per_arrays()
        return self._per_max

    @property
    def per_rms(self) -> np.ndarray:
        if self._raw is not None:
            self._per_arrays()
        return self._per_rms

    def _set(self, pm: np.ndarray, pr: np.ndarray) -> None:
        self._raw = None
        self._per_max, self._per_rms = pm, pr

    def _per_arrays(self) -> None:
        """The per-object arrays from :meth:`measure_scalar`'s lists (squared maxima, sums of
        squares, counts): ``sqrt(max)`` and ``sqrt(sum / count)`` (0 without a count)."""
        raw, self._raw = self._raw, None
        if raw is None:
            return
        per_max, s2, cnt = raw
        sqrt = math.sqrt
        per = np.array([sqrt(x) for x in per_max] + [sqrt(a / k) if k > 0 else 0.0 for a, k in zip(s2, cnt)])
        n = len(per_max)
        self._per_max, self._per_rms = per[:n], per[n:]

    @staticmethod
    def ownerless(net) -> bool:
        """Some copy may be shown by the entity law (:class:`display.FreePrediction`): ``ownerless``
        with prediction order >= 1, and an entity without an owner now or claimed since the start."""
        cons, own = net.cfg.consistency, net.own
        return (cons.ownerless and cons.prediction_order >= 1
                and bool((own.owner < 0).any() or (own.claimed_t > -np.inf).any()))

    @staticmethod
    def free_copies(net, obj: np.ndarray, ct: np.ndarray) -> np.ndarray:
        """Copies (k,) bool of objects ``obj`` holding records of time ``ct`` (s) that their node
        shows by the entity law: the object has no owner, or was claimed after the record was
        sent (the node learns of the claim from the new owner's first record)."""
        own = net.own
        return (np.take(own.owner, obj) < 0) | (ct < np.take(own.claimed_t, obj))

    def touch(self, fi) -> None:
        """Cache rows ``fi`` were rewritten (the record groups re-check them)."""
        if self.groups is not None:
            self.groups.touch(fi)

    def display(self, net, t, P, vg, vo, fi, og, cells, online_g) -> None:
        """The display error at frame time ``t`` (s) of the view pairs (``vo``, ``vg``, ``fi``,
        owners ``og``; ``fi``/``og`` None: computed) into ``net.metrics``."""
        clean = self.clean
        if (clean is not None and clean[0] is P and clean[1] is vo and clean[2] is og
                and net.world.at_fixed_point()):
            # a resting scene whose every counted copy holds a record of this state (p the
            # truth, v = a = 0) and which got no other record since: every error is 0 again
            m = net.metrics
            m.inconsistency_max = max(m.inconsistency_max, 0.0)
            m.inconsistency_rms = 0.0
        elif fi is not None and og is not None and len(fi) <= net.paths.scalar_view and self.groups is None:
            self.measure_scalar(net, t, P, vo, vg, fi, og)     # (what measure does for a small view)
        else:
            self.measure(net, t, P, vg, vo, fi, og, cells, online_g)

    def measure(self, net, t, P, vg, vo, fi, og, cells, online_g) -> None:
        """Display error of every remote copy at frame time ``t`` (eq. 3-1/3-2).

        Views of more than ``paths.groups_min_pairs`` copies keep :class:`display.DisplayGroups`
        (one evaluation per distinct record instead of per copy: the same maxima, RMS equal up
        to round-off) unless the frame rewrote a large share of the copies; else every copy is
        evaluated here.
        """
        cfg, paths, rc = net.cfg, net.paths, net.records
        order = cfg.consistency.prediction_order
        if fi is None:
            fi = rc.index(vg, vo)
        if og is None:
            og = np.take(net.own.owner, vo)
        if len(fi) > paths.groups_min_pairs:
            if self.groups is None:
                self.groups = DisplayGroups(len(rc.cache), self.n_obj, cfg.groups)
            if self.groups.update(net, cells, online_g, vo, vg, fi, og):
                pm, pr, mx, rms = self.groups.errors(t, P, order, (self, net) if self.ownerless(net) else None)
                self._set(pm, pr)
                net.metrics.inconsistency_max = max(net.metrics.inconsistency_max, mx)
                net.metrics.inconsistency_rms = rms
                return
        elif self.groups is not None:
            self.groups.invalidate()
        n = len(fi)
        free = self.ownerless(net)
        if n <= paths.scalar_view:
            return self.measure_scalar(net, t, P, vo, vg, fi, og)
        px, py = P[:, 0], P[:, 1]
        chunk = paths.measure_chunk
        if n <= chunk:
            err2, remote = self._copy_errors(net, t, fi, vo, vg, og, px, py)
        else:
            # in chunks that stay in the CPU cache: one row (cache line) gathered per copy,
            # then the column arithmetic on the chunk
            err2, remote = np.empty(n), np.empty(n, bool)
            px, py = np.ascontiguousarray(px), np.ascontiguousarray(py)
            for a in range(0, n, chunk):
                b = min(a + chunk, n)
                err2[a:b], remote[a:b] = self._copy_errors(net, t, fi[a:b], vo[a:b], vg[a:b], og[a:b], px, py)
        if free:   # entities no avatar owns: every node's own prediction (§3.6.3)
            sel = np.flatnonzero(remote)
            rows = np.take(rc.cache, fi[sel], axis=0)
            law = self.free_copies(net, vo[sel], rows[:, T_COL])
            if law.any():
                err2[sel[law]] = self.free.errors(net, rows[law], vo[sel[law]], t, P)
        seg = self._segments
        if seg is None or seg[0] is not vo:
            seg = self._segments = (vo, object_runs(vo, self.n_obj))
        pm, pr, mx, rms = inconsistency_sq(vo, err2, self.n_obj, remote, sorted_obj=True, segments=seg[1])
        self._set(pm, pr)
        net.metrics.inconsistency_max = max(net.metrics.inconsistency_max, mx)
        net.metrics.inconsistency_rms = rms

    @staticmethod
    def _copy_errors(net, t, fi, vo, vg, og, px, py):
        """Squared display errors (k,) m^2 of copies ``fi`` at frame time ``t`` and whether each
        counts (a non-owner's copy with a record since it subscribed)."""
        rc = net.records
        c = np.take(rc.cache, fi, axis=0)       # one row (cache line) per copy
        ct = c[:, T_COL]
        remote = (og != vg) & (ct >= c[:, rc.enter_col] - 1e-12)
        return squared_dr_error(c, ct, np.take(px, vo), np.take(py, vo), t, net.cfg.consistency.prediction_order), remote

    def _free_scalar(self, net, t, objs: list, rows: list) -> dict:
        """For :meth:`measure_scalar`: the counted remote copies (their position in the lists
        ``objs``, ``rows``: objects and cache rows as Python floats) shown by the entity law, and
        their positions ``[x, y]`` (m) at ``t``, as :meth:`measure` selects (:meth:`free_copies`)
        and predicts them."""
        enter, own = net.records.enter_col, net.own
        owner, claimed = own.owner.tolist(), own.claimed_t.tolist()
        sel = [j for j, (o, c) in enumerate(zip(objs, rows))
               if c[T_COL] >= c[enter] - 1e-12 and (owner[o] < 0 or c[T_COL] < claimed[o])]
        if not sel:
            return {}
        return dict(zip(sel, self.free.positions_floats(net, [rows[j] for j in sel], t)))

    def measure_scalar(self, net, t, P, vo, vg, fi, og) -> None:
        """:meth:`measure` of a view of a few copies in Python floats (the operations of
        :meth:`_copy_errors` and :func:`metrics.inconsistency_sq` in the same order; the total
        is numpy's sum of the same squared errors)."""
        memo = self._scalar
        if memo is None or memo[0] is not og or memo[1] is not vo or memo[2] is not fi:
            # the copies shown by non-owners (only they can count): position, object, flat index
            remote = (og != vg).nonzero()[0]
            memo = self._scalar = (og, vo, fi, remote.tolist(), vo[remote].tolist(), fi[remote])
        rc = net.records
        order, enter = net.cfg.consistency.prediction_order, rc.enter_col
        rows = rc.cache.take(memo[5], axis=0).tolist() if memo[3] else []
        pos = net.positions_list(P) if memo[3] else None
        n_obj = self.n_obj
        per_max, s2, cnt = [0.0] * n_obj, [0.0] * n_obj, [0] * n_obj
        err2 = [0.0] * len(fi)    # the own copies (and remote ones without a record) count as 0
        first_order, second_order = order >= 1, order >= 2
        law = self._free_scalar(net, t, memo[4], rows) if memo[3] and self.ownerless(net) else {}
        for j, (i, o, c) in enumerate(zip(memo[3], memo[4], rows)):
            ct = c[0]
            if not ct >= c[enter] - 1e-12:   # no record since it subscribed
                continue
            cnt[o] += 1
            p = pos[o]
            q = law.get(j)
            if q is not None:      # an entity without an owner: the node's own prediction
                ex = q[0] - p[0]
                ey = q[1] - p[1]
            else:
                ex = c[1] - p[0]
                ey = c[2] - p[1]
            if first_order and q is None:
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
        m = net.metrics
        exact = net.pub.exact
        self.clean = None
        if (net.paths.rest_display and exact is not None and exact[0] is P and not any(err2)
                and net.world.at_fixed_point()
                and min((c[0] for c in rows if c[0] >= c[enter] - 1e-12), default=math.inf) >= exact[1]):
            # the oldest counted record is one of this resting state: so are the others
            self.clean = (P, vo, og)
        self._raw = (per_max, s2, cnt)     # the per-object arrays when read (see per_max)
        n_valid = sum(cnt)
        if n_valid == 0:
            m.inconsistency_max = max(m.inconsistency_max, 0.0)
            m.inconsistency_rms = 0.0
            return
        m.inconsistency_max = max(m.inconsistency_max, math.sqrt(max(err2)))
        m.inconsistency_rms = math.sqrt(pairwise_sum(err2) / n_valid)   # numpy's sum of the same values
