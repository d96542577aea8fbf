"""Messages (frame phase 4): the grid's view and subscriptions, messages by topology, their reuse.

* subscription (view entry) times from cell changes vs a dense per-pair "last frame in view" table;
* messages and view pairs reused from the last frame (small scenes) vs built every frame.
"""
import numpy as np
import pytest

from immersim.models.network import LinkClass, NetworkConfig, NetworkModel
from immersim.models.network.paths import Paths


T = 0.033
LOSSY = {"lan": LinkClass(0.3, 0.2, 0.05, 1000.0), "wan": LinkClass(20.0, 8.0, 0.1, 50.0)}


def _trace(cfg, steps, drive=False, paths=None):
    m = NetworkModel(cfg, paths)
    out = []
    for k in range(steps):
        if drive:
            for g in range(cfg.driven_groups):
                m.set_input(g, 0.8 if k < steps // 2 else -0.6, 0.2 * (g - 1))
        out.append(m.step(T).as_dict())
    return m, out


def _same(a, b):
    (ma, oa), (mb, ob) = a, b
    assert oa == ob
    assert np.array_equal(ma.cache, mb.cache) and np.array_equal(ma.owner, mb.owner)
    assert np.array_equal(ma.per_object_max, mb.per_object_max) and np.array_equal(ma.per_object_rms, mb.per_object_rms)
    assert np.array_equal(ma.hist, mb.hist) and np.array_equal(ma.shown_frame, mb.shown_frame)
    assert ma.totals.by_type == mb.totals.by_type


@pytest.mark.parametrize("topology", ["hybrid_p2p", "client_server", "full_mesh"])
def test_reused_messages_and_views_change_nothing(topology):
    cfg = NetworkConfig(groups=3, render_nodes=3, entities=8, driven_groups=3, seed=2, topology=topology,
                        links=LOSSY)
    fast = _trace(cfg, 50, drive=True)
    _same(fast, _trace(cfg, 50, drive=True, paths=Paths(memo_pairs=-1, reuse_views=False)))   # never reused


def test_subscription_times_match_a_dense_view_table():
    """A pair's subscription time is the start of its current stay in the viewer's neighbourhood."""
    cfg = NetworkConfig(groups=6, render_nodes=2, entities=150, scene_size=80.0, avatar_start="uniform",
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
        enter[vo[new], vg[new]] = m.k * cfg.frame_s
        last_in_view[vo, vg] = m.k
        entered += int(new.sum())
        assert np.array_equal(m.cache[m.index(vg, vo), m.enter_col], enter[vo, vg])
        assert all(m.in_view(int(g), int(o)) for g, o in zip(vg[:50], vo[:50]))
    assert entered > 50   # the check saw many entries
