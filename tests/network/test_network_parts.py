"""Pastry routing, node ids and the supernode's heartbeat index table."""
import math

import numpy as np
import pytest

from immersim.models.network.ids import PastryOverlay, node_id, ring_distance, shared_prefix
from immersim.models.network.supernode import CONTROLLER, RENDER, Supernode


@pytest.mark.parametrize("b,n", [(4, 300), (2, 120)])
def test_pastry_routes_to_numerically_closest_within_log_hops(b, n):
    ids = [node_id(f"10.0.{i // 250}.{i % 250}:20014") for i in range(n)]
    ov = PastryOverlay(ids, b=b, L=2 ** b, M=2 ** b)
    rng = np.random.default_rng(0)
    bound = math.ceil(math.log(n, 2 ** b)) + 1          # prefix hops plus the leaf-set hop
    hops = []
    for _ in range(150):
        start = ids[rng.integers(n)]
        key = int.from_bytes(rng.bytes(16), "big")
        path = ov.route(start, key)
        assert path[-1] == ov.closest(key)
        hops.append(len(path) - 1)
    assert max(hops) <= bound, (max(hops), bound)
    # each prefix hop gains at least one digit
    assert shared_prefix(ids[0], ids[0], b) == 128 // b
    assert ring_distance(0, (1 << 128) - 1) == 1


def test_node_id_is_md5_128_bit():
    assert node_id("a") == int("0cc175b9c0f1b6a831c399e269772661", 16)


def test_supernode_heartbeat_table_and_master_election():
    sn = Supernode(timeout_s=3.0)
    sn.join(0.0, 1, "Render-01", RENDER, "10.0.0.10", 20014, 1)
    assert sn.table()[0]["heartbeat"] == "not started"        # no controller yet
    sn.join(0.1, 2, "Render-01", RENDER, "10.0.0.11", 20014, 1)
    sn.join(0.2, 9, "Render-01", CONTROLLER, "10.0.0.200", 20010, 1)
    assert all(r["heartbeat"] == "started" for r in sn.table())
    assert [r["online_order"] for r in sn.table()] == [1, 2, 3]
    assert sn.master("Render-01") == 1 and sn.cluster(1) == [1]
    sn.leave(1)
    assert sn.master("Render-01") == 2
    sn.heartbeat(2.0, 2)
    assert sn.expire(4.0) == [9] and sn.timeouts == 1        # controller silent since 0.2 s
    assert sn.table()[0]["heartbeat"] == "not started"
    with pytest.raises(ValueError, match="already online"):
        sn.join(5.0, 2, "Render-01", RENDER, "10.0.0.11", 20014, 1)
