"""What the render nodes show (frame phase 6a): masters their dead-reckoned cache, slaves the
frame their master sent in time; a small scene's history slots as lists vs the array code."""
import numpy as np

from immersim.models.network import LinkClass, NetworkConfig, NetworkModel
from immersim.models.network.history import HIST
from immersim.models.network.paths import Paths


T = 0.033


def test_a_master_shows_its_own_avatar_as_it_is_and_the_others_dead_reckoned():
    """Order 1: a master's row of the history holds its own avatar's true position and every
    other avatar's cached record p + v (t - t_record) at the frame time."""
    cfg = NetworkConfig.from_flat(groups=3, render_nodes=2, entities=0, driven_groups=3, seed=1, prediction_order=1)
    m = NetworkModel(cfg)
    for k in range(20):
        for g in range(3):
            m.set_input(g, 0.7, 0.1 * g)
        m.step(T)
    t, P = m.k * cfg.scene.frame_s, m.world.positions()
    for g in range(3):
        shown = m.perceived_avatars(int(m.master[g]))
        for a in range(3):
            r = m.record(g, a)
            expected = P[a] if a == g else r[1:3] + r[3:5] * (t - r[0])
            assert np.array_equal(shown[a], expected)
    assert not np.array_equal(m.perceived_avatars(int(m.master[0]))[1], P[1])   # a remote copy lags


def test_history_slots_kept_as_lists_read_as_the_array():
    """A small scene's history slots stay lists until the array is read: what every render node
    perceives from the lists equals the array's rows (slaves lagging behind included), and the
    array equals the one the array code writes."""
    cfg = NetworkConfig.from_flat(groups=3, render_nodes=3, entities=8, driven_groups=3, seed=2,       # a slow LAN: late FRAMEs
                                  links={"lan": LinkClass(22.0, 10.0, 0.0, 1000.0), "wan": LinkClass(25.0, 12.0, 0.0, 100.0)})

    def trace(read_lists, paths=None):
        m = NetworkModel(cfg, paths)
        seen = []
        for k in range(150):
            m.latency_scale = 3.0 if 40 <= k < 70 else 1.0        # a burst: slaves lag further
            for g in range(3):
                m.set_input(g, 0.8 - 0.2 * g, 0.2 * (g - 1))
            m.step(T)
            if read_lists:
                assert m.k % HIST in m.history.rows          # this frame's slot: a list
                lists = [m.perceived_list(node) for node in range(m.reg.n_render)]
                arrays = [m.perceived_avatars(node).ravel().tolist() for node in range(m.reg.n_render)]
                assert lists == arrays and not m.history.rows
                seen.append(lists)
        return m, seen

    fast, seen = trace(True)
    assert any(s[1] != s[0] for s in seen)                  # a slave showed an older frame
    assert max(int(x) for x in fast.shown_frame) <= fast.k
    plain, _ = trace(False, Paths(scalar_view=-1))          # history slots written by the array code
    assert np.array_equal(fast.hist, plain.hist)
