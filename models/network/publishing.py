"""Frame phase 3: which objects their owners publish this frame.

Every object with an online owner (none without one, ``cfg.consistency.ownerless``) every frame, or with a
DIS threshold (``dis_threshold > 0``) only when the owner's dead reckoning of what it last published has drifted beyond the
threshold or ``dis_heartbeat_s`` has passed since (IEEE 1278 DIS, §3.6.3).
"""
from __future__ import annotations

from typing import Optional

import numpy as np

from .consistency import dead_reckon


class Publisher:
    """What each owner last published (read by the DIS test only).

    Attributes
    ----------
    t : (G + E,) s, time of the last publication; ``p``, ``v``, ``a`` (G + E, 2) its state
    exact : (positions array, first frame time it was used) or None: how long the scene has
        held these positions (a resting scene, see the display phase)
    """

    def __init__(self, n_obj: int) -> None:
        self.t = np.full(n_obj, -np.inf)
        self.p = np.zeros((n_obj, 2))
        self.v = np.zeros((n_obj, 2))
        self.a = np.zeros((n_obj, 2))
        self.exact: Optional[tuple] = None
        self._memo: Optional[tuple] = None   # ((group version, epoch), published mask, objects)

    def initial(self, net) -> None:
        """Frame 0: every node starts from the same scene file (the shared initial state)."""
        P, V, A = net.world.state()
        rc = net.records
        rc.uid = 0
        rec = rc.table(np.arange(net.n_obj), 0.0, P, V, A)
        n = rc.rid_col + 1
        rc.cache[:, :n] = np.repeat(rec[:, :n], net.cfg.groups, axis=0)
        self.t[:] = 0.0
        self.p, self.v, self.a = P.copy(), V.copy(), A.copy()

    def publish(self, net, fr) -> None:
        """Phase 3: ``fr.pub`` (G + E,) bool and ``fr.pub_obj`` (k,), the objects published at
        frame time ``fr.t`` from state ``fr.P``, ``fr.V``, ``fr.A``."""
        cfg, t, P = net.cfg, fr.t, fr.P
        online_g, owner = fr.online_g, net.own.owner
        if cfg.consistency.dis_threshold > 0:
            pred = dead_reckon(self.p, self.v, self.a, t - self.t, cfg.consistency.prediction_order)
            err = np.hypot(*(pred - P).T)
            owned = self._owned(cfg, online_g, owner)
            pub = owned & ((err > cfg.consistency.dis_threshold) | (t - self.t >= cfg.consistency.dis_heartbeat_s))
            if cfg.consistency.ownerless:   # an entity's last record before its release (ownership.py)
                pub[cfg.groups:] |= net.own.leaving & owned[cfg.groups:]
            pub_obj = np.flatnonzero(pub)
            self.t[pub_obj] = t
            self.p[pub_obj], self.v[pub_obj], self.a[pub_obj] = P[pub_obj], fr.V[pub_obj], fr.A[pub_obj]
        else:   # every object with an online owner (kept while groups and owners stay)
            memo = self._memo
            key = (net.groups.version, net.own.epoch)
            if memo is None or memo[0] != key:
                pub = self._owned(cfg, online_g, owner)
                memo = self._memo = (key, pub, np.flatnonzero(pub))
            pub, pub_obj = memo[1], memo[2]
        fr.pub, fr.pub_obj = pub, pub_obj
        net.metrics.published += len(pub_obj)
        if self.exact is None or self.exact[0] is not P:   # a new position array: a new streak
            self.exact = (P, t)

    @staticmethod
    def _owned(cfg, online_g: np.ndarray, owner: np.ndarray) -> np.ndarray:
        """Objects (G + E,) bool whose owner is online (an ownerless one, -1, has none)."""
        if not cfg.consistency.ownerless:
            return online_g[owner]
        return online_g[np.maximum(owner, 0)] & (owner >= 0)
