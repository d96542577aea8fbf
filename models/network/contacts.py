"""Frame phase 1: collision responses between avatars and entities (the owner responds).

An entity that touches its owner's avatar takes the impulse at once; a contact with another
group's avatar is reported to the owner (slave/master report, §3.5.1 rule 3) and acts when the
report arrives (an ``impulse`` event), handing the entity over to the avatar that touched it.
An entity without an owner (``cfg.consistency.ownerless``) is answered by the node of the avatar touching
it, which claims it.
"""
from __future__ import annotations

import numpy as np

from . import links as lk


class Contacts:
    """Contact reports on their way to an owner.

    Attributes
    ----------
    pending : (E,) bool, an entity's contact report is in flight (no second one is sent)
    """

    def __init__(self, cfg, paths) -> None:
        self.pending = np.zeros(cfg.entities, bool)
        n_obj = cfg.groups + cfg.entities
        # one k-d tree of the entities shared by contacts and ownership (large scenes only:
        # small ones use brute force, cheaper than a tree built every frame)
        self._tree = bool(cfg.entities) and cfg.groups * cfg.entities > 4096
        # a small scene without DIS below order 2 takes its positions first as a list too (again
        # when a contact's separation moved them), and its velocities only where read (lazy)
        self._lazy = cfg.consistency.dis_threshold <= 0 and cfg.consistency.prediction_order < 2 and n_obj <= paths.scalar_view

    def respond(self, net, fr) -> None:
        """Find this frame's contacts and respond (phase 1); fills ``fr.etree``, ``fr.lazy``
        and, for a lazy frame, ``fr.P`` and ``fr.pl`` (positions after overlaps are separated)."""
        cfg, w = net.cfg, net.world
        G = cfg.groups
        etree = w.entity_index() if self._tree else None
        lazy = self._lazy and (cfg.entities or w._fixed_key is None)    # (a resting scene: state()'s kept arrays)
        pl = None
        if lazy:
            fr.P = w.positions()
            pl = net.positions_list(fr.P)
        moved = w.separated
        ai, ei, dv = w.contacts(etree, pl, fr.online_g)
        if w.separated != moved:   # overlaps were removed: positions (and their index) changed
            etree = w.entity_index() if etree is not None else None
            if lazy:
                fr.P = w.positions()
                pl = net.positions_list(fr.P)
        fr.etree, fr.lazy, fr.pl = etree, lazy, pl
        if not len(ai):
            return
        net.metrics.contacts += len(ai)
        owner = net.own.owner[G + ei]
        free = owner < 0          # (ownerless entities only)
        local = (owner == ai) | free
        for e, d in zip(ei[local], dv[local]):
            w.push_entity(e, d)
        if free.any():
            net.own.claim(net, ei[free], ai[free])
        remote = ~local & ~self.pending[ei]
        if remote.any():
            lat = net.latency_scale * lk.sample_latency(net.rng, cfg.net.links["wan"], int(remote.sum()))
            for e, d, g, L in zip(ei[remote], dv[remote], ai[remote], lat):
                self.pending[e] = True
                net.events.push(fr.t + float(L), "impulse", int(e), d.copy(), int(g))
            net.metrics.remote_contacts += int(remote.sum())
