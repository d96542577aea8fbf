"""Membership and events: joins, leaves and time-outs at the supernode, masters and slaves
(§3.5.1), the queued-event counter behind ``at_rest``."""
from immersim.models.network import NetworkConfig, NetworkModel
from immersim.models.network import events as events_mod

T = 0.033


def test_master_crash_times_out_and_first_slave_takes_over():
    cfg = NetworkConfig.from_flat(groups=2, render_nodes=3, entities=5)
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


def test_pending_event_counter_matches_the_heap():
    m = NetworkModel(NetworkConfig.from_flat(groups=3, render_nodes=2, entities=5, driven_groups=2, seed=1))
    m.schedule_leave(0.2, 1)
    m.schedule_join(0.5, 1)
    for k in range(30):
        m.set_input(k % 2, 0.1 * k, 0.0)
        m.step(T)
        assert m.events.pending == sum(kind in events_mod.PENDING for _, _, kind, _ in m.events.heap)


def test_the_first_online_render_node_is_the_master_and_a_graceful_leave_hands_over_at_once():
    """Rule 1 of §3.5.1: the master is the group's first online render node; after a graceful
    LEAVE the next one is master in the same step (no time-out), and the LEAVE is counted."""
    cfg = NetworkConfig.from_flat(groups=2, render_nodes=3, entities=0, driven_groups=2)
    m = NetworkModel(cfg)
    assert list(m.master) == [0, 3] and [list(s) for s in m.slaves] == [[1, 2], [4, 5]]
    m.schedule_leave(0.01, 3)
    m.step(0.033)
    assert list(m.master) == [0, 4] and list(m.slaves[1]) == [5]
    assert m.supernode.leaves == 1 and m.supernode.timeouts == 0 and m.totals.by_type["LEAVE"] > 0


def test_a_node_coming_back_on_line_sends_one_join():
    """A render node that left gracefully and joins again sends one LEAVE, then one JOIN PDU
    (H bytes each), counted where every message is counted."""
    from immersim.models.network.nodes import H
    from immersim.models.network.pdu import PduType

    m = NetworkModel(NetworkConfig.from_flat(groups=2, render_nodes=3, entities=0, driven_groups=2))
    sent = []
    real = m.count
    m.count = lambda n, nbytes, ptype: sent.append((int(n), int(nbytes), int(ptype))) or real(n, nbytes, ptype)
    m.schedule_leave(0.01, 4)
    m.schedule_join(0.05, 4)
    for _ in range(3):
        m.step(T)
    control = [s for s in sent if s[2] in (PduType.LEAVE, PduType.JOIN)]
    assert control == [(1, H, PduType.LEAVE), (1, H, PduType.JOIN)]
