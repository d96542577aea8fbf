"""Collision responses (frame phase 1): an entity touching its owner's avatar takes the impulse
in the same frame; a contact with another group's avatar is reported to the owner and acts
when the report arrives, one WAN latency later (§3.5.1 rule 3). Closed form: equal masses,
restitution 0.5, an entity at 1 m/s into a parked avatar leaves at 0.25 m/s."""
import numpy as np
import pytest

from immersim.models.network import LinkClass, NetworkConfig, NetworkModel

T = 0.033
WAN_S = 0.020


def _touching(avatar: int) -> NetworkModel:
    """Two parked avatars 60 m apart; the one entity (owned by group 0) 2.9 m right of
    ``avatar`` (contact distance 3 m), moving at 1 m/s toward it, no drag or turning."""
    cfg = NetworkConfig.from_flat(groups=2, render_nodes=1, entities=1, driven_groups=2, seed=0, ownership="none",
                                  entity_drag=0.0, links={"lan": LinkClass(0.3, 0.0, 0.0, 0.0),
                                                          "wan": LinkClass(1e3 * WAN_S, 0.0, 0.0, 0.0)})
    m = NetworkModel(cfg)
    w = m.world
    w.apos[:] = [[20.0, 50.0], [80.0, 50.0]]
    w.epos[0] = w.apos[avatar] + [2.9, 0.0]
    w.evel[0] = [-1.0, 0.0]
    w.eturn[:] = 0.0
    assert m.owner[2] == 0
    return m


def test_a_contact_with_the_owners_avatar_acts_in_the_same_frame():
    m = _touching(0)
    m.step(T)
    assert m.metrics.contacts == 1 and m.metrics.remote_contacts == 0
    assert m.world.evel[0] == pytest.approx([-0.25, 0.0], abs=1e-12)
    assert not m.contacts.pending.any()


def test_a_contact_with_another_groups_avatar_acts_one_report_latency_later():
    m = _touching(1)
    m.step(T)                                   # the contact is found at the frame, t = 33 ms
    assert m.metrics.contacts == 1 and m.metrics.remote_contacts == 1
    assert m.contacts.pending[0]
    assert np.array_equal(m.world.evel[0], [-1.0, 0.0])     # not yet: the report is on its way
    assert any(kind == "impulse" and t == pytest.approx(T + WAN_S, abs=1e-12)
               for t, _, kind, _ in m.events.heap)
    m.step(T)                                   # the report arrives at 53 ms, within this step
    assert m.world.evel[0] == pytest.approx([-0.25, 0.0], abs=1e-12)
    assert not m.contacts.pending.any() and m.metrics.remote_contacts == 0
