"""Pastry routing-table locality, the inconsistency metric (eq. 3-1/3-2) and DIS heartbeats,
against brute force and closed forms."""
import numpy as np
import pytest

from immersim.models.network.config import NetworkConfig
from immersim.models.network.ids import PastryOverlay, digits, node_id, shared_prefix
from immersim.models.network.metrics import inconsistency
from immersim.models.network.model import NetworkModel


def test_routing_table_entry_is_the_proximity_nearest_node_with_that_prefix_and_digit():
    """Pastry's locality (§2.3.1): entry (l, d) of node n is, of all nodes sharing l digits with n
    and having digit d next, the one nearest to n in the proximity metric."""
    ids = [node_id(f"node-{k}") for k in range(60)]
    rng = np.random.default_rng(6)
    prox = {i: float(x) for i, x in zip(ids, rng.uniform(0, 100, len(ids)))}
    ov = PastryOverlay(ids, b=2, L=8, M=8, proximity=prox)
    checked = 0
    for n in ids[:12]:
        table = ov.nodes[n].table
        for other in ids:
            if other == n:
                continue
            l = shared_prefix(n, other, 2)
            d = digits(other, 2)[l]
            cands = [o for o in ids if o != n and shared_prefix(n, o, 2) == l and digits(o, 2)[l] == d]
            best = min(abs(prox[o] - prox[n]) for o in cands)
            assert abs(prox[table[l][d]] - prox[n]) == best
            checked += 1
    assert checked > 500


def test_inconsistency_is_the_max_and_rms_of_the_copies_position_errors():
    obj = np.array([0, 0, 1, 2, 2, 2])
    truth = np.array([[0.0, 0.0], [1.0, 1.0], [5.0, -2.0]])
    shown = truth[obj] + np.array([[3.0, 4.0], [0.0, 1.0], [0.0, 0.0], [1.0, 0.0], [0.0, -2.0], [0.6, 0.8]])
    per_max, per_rms, total_max, total_rms = inconsistency(obj, shown, truth, 4)
    np.testing.assert_allclose(per_max, [5.0, 0.0, 2.0, 0.0])
    np.testing.assert_allclose(per_rms, [np.sqrt((25 + 1) / 2), 0.0, np.sqrt((1 + 4 + 1) / 3), 0.0])
    assert total_max == pytest.approx(5.0)
    assert total_rms == pytest.approx(np.sqrt((25 + 1 + 0 + 1 + 4 + 1) / 6))


def test_dis_republishes_a_resting_object_at_the_first_frame_a_heartbeat_after_its_last():
    """DIS (dis_threshold > 0), nothing moving: an object is re-published at the first frame with
    t - t_last >= dis_heartbeat_s (1 s): frames of 33 ms give t = 1.023, 2.046, 3.069 s."""
    cfg = NetworkConfig(groups=2, render_nodes=2, entities=0, driven_groups=2, seed=3, dis_threshold=0.1)
    m = NetworkModel(cfg)
    times, last, expected = [], 0.0, []
    for k in range(1, 100):
        m.step(cfg.frame_s)
        t = k * cfg.frame_s
        if t - last >= cfg.dis_heartbeat_s - 1e-9:
            expected.append(round(t, 6))
            last = t
        if m.metrics.published:
            assert m.metrics.published == cfg.groups
            times.append(round(t, 6))
    assert times == expected == [1.023, 2.046, 3.069]


def test_cluster_holds_the_masters_of_the_render_groups_of_its_scene_only():
    from immersim.models.network.supernode import CONTROLLER, RENDER, Supernode

    sn = Supernode()
    sn.join(0.0, 1, "Render-01", RENDER, "10.0.0.10", 20014, 1)
    sn.join(0.1, 2, "Render-01", RENDER, "10.0.0.11", 20014, 1)
    sn.join(0.2, 3, "Render-02", RENDER, "10.0.0.12", 20014, 2)      # another scene
    sn.join(0.3, 4, "Render-03", RENDER, "10.0.0.13", 20014, 1)
    sn.join(0.4, 9, "Control-09", CONTROLLER, "10.0.0.200", 20010, 1)  # a controller, not a render group
    assert sn.cluster(1) == [1, 4]
    assert sn.cluster(2) == [3]
