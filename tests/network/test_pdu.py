"""PDUs of ch. 2: packing and unpacking round trips and the sizes the traffic model counts."""
import pytest

from immersim.models.network.ids import node_id
from immersim.models.network.pdu import (HEADER, ControllerPacket, Pdu, PduType, RenderPacket, controller_bytes,
                                         record_bytes)


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
