"""Messages (frame phase 4): the grid's view and subscriptions, messages by topology, their reuse.

* subscription (view entry) times from cell changes vs a dense per-pair "last frame in view" table;
* messages and view pairs reused from the last frame (small scenes) vs built every frame;
* the hybrid_p2p messages of a few view pairs in Python vs the array code.
"""
import numpy as np
import pytest

from immersim.models.network import NetworkConfig, NetworkModel
from immersim.models.network import nodes
from immersim.models.network.paths import Paths

from .helpers import LOSSY, T, trace


def _same(a, b):
    (ma, oa), (mb, ob) = a, b
    assert oa == ob
    assert np.array_equal(ma.cache, mb.cache) and np.array_equal(ma.owner, mb.owner)
    assert np.array_equal(ma.per_object_max, mb.per_object_max) and np.array_equal(ma.per_object_rms, mb.per_object_rms)
    assert np.array_equal(ma.hist, mb.hist) and np.array_equal(ma.shown_frame, mb.shown_frame)
    assert ma.totals.by_type == mb.totals.by_type


@pytest.mark.parametrize("topology", ["hybrid_p2p", "client_server", "full_mesh"])
def test_reused_messages_and_views_change_nothing(topology):
    cfg = NetworkConfig.from_flat(groups=3, render_nodes=3, entities=8, driven_groups=3, seed=2, topology=topology,
                                  links=LOSSY)
    fast = trace(cfg, 50, drive=True)
    _same(fast, trace(cfg, 50, drive=True, paths=Paths(memo_pairs=-1, reuse_views=False)))   # never reused


def test_subscription_times_match_a_dense_view_table():
    """A pair's subscription time is the start of its current stay in the viewer's neighbourhood."""
    cfg = NetworkConfig.from_flat(groups=6, render_nodes=2, entities=150, scene_size=80.0, avatar_start="uniform",
                                  entity_speed=12.0, seed=7)
    m = NetworkModel(cfg)
    G, n = cfg.groups, m.n_obj
    last_in_view = np.zeros((n, G), np.int64)       # the former per-pair table: frame 0 = scene file
    enter = np.zeros((n, G))
    entered = 0
    for _ in range(60):
        m.step(T)
        cells = m.grid.cell(m.world.positions())
        online = np.flatnonzero(m.master >= 0)
        vo, vl = m.grid.view_pairs(cells, cells[online])
        vg = online[vl]
        new = last_in_view[vo, vg] != m.k - 1
        enter[vo[new], vg[new]] = m.k * cfg.scene.frame_s
        last_in_view[vo, vg] = m.k
        entered += int(new.sum())
        assert np.array_equal(m.cache[m.index(vg, vo), m.enter_col], enter[vo, vg])
        assert all(m.in_view(int(g), int(o)) for g, o in zip(vg[:50], vo[:50]))
    assert entered > 50   # the check saw many entries


def test_small_hybrid_messages_equal_the_array_code():
    gen = np.random.default_rng(0)
    names = ("send_t", "sender", "receiver", "link", "nbytes", "ptype", "hop_of", "rec_msg", "rec_viewer", "rec_obj",
             "frame_msg", "frame_slave", "rec_hop1")
    cases = []
    for trial in range(300):
        G, R, E = int(gen.integers(1, 6)), int(gen.integers(1, 4)), int(gen.integers(0, 12))
        cfg = NetworkConfig.from_flat(groups=G, render_nodes=R, entities=E, prediction_order=int(gen.integers(0, 3)))
        master = np.array([g * R if gen.random() < 0.8 else -1 for g in range(G)], np.int64)   # some offline
        slaves = [np.arange(g * R + 1, (g + 1) * R)[gen.random(R - 1) < 0.7] if master[g] >= 0 else np.zeros(0, np.int64)
                  for g in range(G)]
        owner = np.r_[np.arange(G), gen.integers(0, G, E)]
        k = int(gen.integers(0, 40))
        vo, vg = np.sort(gen.integers(0, G + E, k)), gen.integers(0, G, k)
        send = gen.random(k) < (0.5 if trial % 2 else 1.1)                     # DIS-like, or every pair
        cases.append((cfg, nodes.NodeRegistry(cfg), float(gen.uniform(0, 10)), master, slaves,
                      np.flatnonzero(gen.random(G + E) < 0.8), owner, vg, vo, np.bincount(vg, minlength=G), send,
                      owner[vo]))
    fast = [nodes.build_messages(*c) for c in cases]
    assert sum(len(f.rec_msg) for f in fast) > 1000 and sum(len(f.frame_msg) for f in fast) > 200
    for c, f in zip(cases, fast):
        ref = nodes.build_messages(*c, scalar_pairs=-1)
        for name in names:
            a, b = getattr(f, name), getattr(ref, name)
            assert np.array_equal(a, b) and a.dtype == b.dtype, name
