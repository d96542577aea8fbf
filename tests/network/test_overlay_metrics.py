"""Pastry routing-table locality and the cluster of a scene,
against brute force and closed forms."""
import numpy as np

from immersim.models.network.ids import PastryOverlay, digits, node_id, shared_prefix


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
