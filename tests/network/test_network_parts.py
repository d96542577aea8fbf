"""Pastry routing, PDU packing, the supernode's heartbeat index table, node membership."""
import math

import numpy as np
import pytest

from immersim.models.network import NetworkConfig, NetworkModel
from immersim.models.network.ids import PastryOverlay, node_id, ring_distance, shared_prefix
from immersim.models.network.pdu import (HEADER, ControllerPacket, Pdu, PduType, RenderPacket, controller_bytes,
                                         record_bytes)
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


def test_pdu_round_trip_and_sizes():
    rp = RenderPacket("E000001", (1.5, -2.0, 0.25), (1.0, 0.0, 0.0, 0.0), (3.0, 0.0, 0.0), {"acc": "xyz"}, {7: "go"})
    cp = ControllerPacket("Render-0001", 2.5, 0.01, {}, {1: "brake"})
    pdu = Pdu(42, PduType.STATE, node_id("n"), "10.0.0.7", 20014, 1.234, [rp, rp])
    raw = pdu.pack()
    back = Pdu.unpack(raw)
    assert back.pdu_id == 42 and back.pdu_type == PduType.STATE and back.identify == node_id("n")
    assert back.peer_ip == "10.0.0.7" and back.peer_port == 20014 and back.timestamp == 1.234
    assert back.packets[0].states == {"acc": "xyz"} and back.packets[1].commands == {7: "go"}
    assert back.packets[0].position == pytest.approx((1.5, -2.0, 0.25))
    # sizes: header 4+2+16+2+4+8+4+4; RenderPacket: str(2+7) + 10 float32 + maps (2+2+3+2+3) + (2+4+2+2)
    assert HEADER.size == 44
    assert len(rp.pack()) == 9 + 40 + 12 + 10
    assert len(raw) == 44 + 2 * len(rp.pack())
    c = Pdu.unpack(Pdu(1, PduType.CONTROL, 5, "10.0.0.1", 1, 0.0, [cp]).pack()).packets[0]
    assert (c.identify, c.commands) == ("Render-0001", {1: "brake"}) and c.acceleration == 2.5
    assert len(cp.pack()) == 13 + 8 + 2 + 2 + 4 + 2 + 5
    assert record_bytes(2) == record_bytes(1) + 2 + 3 + 2 + 12 and controller_bytes() == 7 + 8 + 4


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


def test_master_crash_times_out_and_first_slave_takes_over():
    cfg = NetworkConfig(groups=2, render_nodes=3, entities=5)
    m = NetworkModel(cfg)
    assert list(m.master) == [0, 3]
    m.schedule_leave(0.2, 0, graceful=False)                  # crash: no LEAVE, heartbeats stop
    for _ in range(int(1.0 / 0.033)):
        m.step(0.033)
    assert m.master[0] == 0                                   # not yet timed out
    for _ in range(int(3.5 / 0.033)):
        m.step(0.033)
    assert m.master[0] == 1 and list(m.slaves[0]) == [2]
    assert m.supernode.timeouts == 1 and m.metrics.online_nodes == 7   # 6 render + 2 controllers - 1
    m.schedule_join(m.t + 0.01, 0)
    m.step(0.033)
    assert m.master[0] == 1 and list(m.slaves[0]) == [2, 0]   # a rejoining node is a slave
