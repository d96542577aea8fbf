"""Frame clocks with their own phase (``NetworkConfig.scene.frame_phase``, the default): every node
has its own seeded phase, a group runs on its master's (the slaves locked to it, §3.5.2), so
group ``g`` shows its frame ``k`` at ``k T + phi_g``; a record sent at the owner's frame ``k`` arrives after its latency ``L``
and is shown at the viewer's first frame ``m`` with ``m T + phi_v >= k T + phi_o + L``, so
``m - k = ceil((L + phi_o - phi_v) / T)`` (at least 0). Closed form: order 0, one entity in
straight motion at 1 m/s, no jitter: the viewer's copy is ``(m - k) T`` seconds old, its error
``(m - k) T`` m. Regression: the mean RMS display error of parked avatars and 40 moving entities
(order 0, no jitter) is a step function of ``ceil(L / T)`` with every clock in phase, and grows
with every latency step with the clocks' phases."""
import math

import numpy as np
import pytest

from immersim.models.network import LinkClass, NetworkConfig, NetworkModel

T = 0.033


def _links(L_ms: float) -> dict:
    return {"lan": LinkClass(0.3, 0.0, 0.0, 0.0), "wan": LinkClass(L_ms, 0.0, 0.0, 0.0)}


def test_every_node_has_its_own_clock_and_a_group_runs_on_its_masters():
    """Default: a seeded phase per node (render nodes, controllers, supernode); a group's clock is
    its master's, the slaves locked to it (§3.5.2); when the master leaves, the slave taking
    over brings its own clock. ``frame_phase=False``: every clock in phase."""
    assert NetworkConfig().scene.frame_phase is True
    assert NetworkModel(NetworkConfig.from_flat(groups=2, entities=0, frame_phase=False)).phase is None
    m = NetworkModel(NetworkConfig.from_flat(groups=5, render_nodes=2, entities=0, seed=4))
    ph = m.node_phase
    assert ph.shape == (m.reg.n,) and np.all((ph >= 0) & (ph < T)) and len(np.unique(ph)) == m.reg.n
    assert np.array_equal(m.phase, ph[m.master]) and m.master.tolist() == [0, 2, 4, 6, 8]
    again = NetworkModel(NetworkConfig.from_flat(groups=5, render_nodes=2, entities=0, seed=4))
    assert np.array_equal(ph, again.node_phase)      # seeded
    m.schedule_leave(m.t + 0.01, 2)                  # group 1's master leaves, node 3 takes over
    m.step(T)
    assert m.master[1] == 3 and m.phase[1] == ph[3] and m.phase[0] == ph[0]


def test_model_draws_do_not_depend_on_the_phases():
    """The phases come from a stream of their own: the ground truth (autopilots, entities'
    turns) and the links' draws are those of the run without phases."""
    a = NetworkModel(NetworkConfig.from_flat(groups=3, entities=10, seed=1, frame_phase=False))
    b = NetworkModel(NetworkConfig.from_flat(groups=3, entities=10, seed=1, frame_phase=True))
    for _ in range(40):
        a.step(T)
        b.step(T)
    assert np.array_equal(a.world.epos, b.world.epos) and np.array_equal(a.world.apos, b.world.apos)


@pytest.mark.parametrize("phi_o,phi_v,L_ms", [(0.0, 0.0, 0.0), (0.0, 0.0, 10.0), (0.030, 0.005, 0.0),
                                              (0.005, 0.030, 20.0), (0.005, 0.030, 30.0), (0.020, 0.001, 40.0)])
def test_a_record_is_shown_at_the_viewers_first_frame_after_its_arrival(phi_o, phi_v, L_ms):
    """Avatar 0 owns an entity moving at 1 m/s that only group 1 views (the state_traffic
    scene); the viewer's order-0 copy is ``n = max(0, ceil((L + phi_o - phi_v) / T))`` frames
    old, its error ``n T`` m at every frame once the first record has arrived."""
    cfg = NetworkConfig.from_flat(groups=2, render_nodes=1, entities=1, driven_groups=2, seed=0, entity_drag=0.0,
                                  links=_links(L_ms), prediction_order=0, frame_phase=True, ownerless=False,
                                  state_traffic="object_view")
    m = NetworkModel(cfg)
    m.node_phase[m.master] = [phi_o, phi_v]
    w = m.world
    w.apos[:] = [[5.0, 5.0], [35.0, 5.0]]
    w.epos[0] = [25.0, 1.0]
    w.evel[0] = [0.0, 1.0]
    w.eturn[:] = 0.0
    m.own.owner[2] = 0
    n = max(0, math.ceil((L_ms * 1e-3 + phi_o - phi_v) / T - 1e-9))
    for k in range(1, 41):
        m.step(T)
        if k > n + 1:
            assert m.per_object_max[2] == pytest.approx(n * T, abs=1e-9), k


def _mean_rms(L_ms: float, phase: bool, groups: int, seed: int, steps: int = 100, jitter_ms: float = 0.0) -> float:
    links = {"lan": LinkClass(0.3, 0.0, 0.0, 0.0), "wan": LinkClass(L_ms, jitter_ms, 0.0, 0.0)}
    cfg = NetworkConfig.from_flat(groups=groups, entities=40, driven_groups=groups, seed=seed, prediction_order=0,
                                  frame_phase=phase, links=links, ownerless=False, state_traffic="object_view")
    m = NetworkModel(cfg)
    return float(np.mean([m.step(T).inconsistency_rms for _ in range(steps)][5:]))


LATENCIES = (0.0, 5.0, 10.0, 20.0, 30.0, 40.0)


def test_in_phase_clocks_resolve_latency_to_whole_frames():
    """Parked avatars, 40 entities, order 0, no jitter, every clock in phase: 0 at L = 0, one
    value for every L in (0, T] and a larger one above (the step function of ``ceil(L / T)``)."""
    e = [_mean_rms(L, False, 4, 2) for L in LATENCIES]
    assert e[0] == 0.0 and e[1] == e[2] == e[3] == e[4] > 0 and e[5] > e[4]


def test_phased_clocks_make_the_display_error_grow_with_every_latency_step():
    """The same scene with 8 groups' frame clocks at their seeded phases (seed 0): strictly
    increasing over L = 0, 5, 10, 20, 30, 40 ms. (With 4 groups the few clock offsets between
    the owners and the viewers can leave a step between two of these latencies:
    results/network/latency_phase.md.)"""
    e = [_mean_rms(L, True, 8, 0) for L in LATENCIES]
    assert all(b > a for a, b in zip(e, e[1:])), e


@pytest.mark.parametrize("seed", [2, 5])
def test_with_the_default_jitter_four_groups_grow_with_every_latency_step(seed):
    """4 groups, the default WAN jitter (exponential, mean 5 ms; the same draws at every latency),
    frame clocks per node: strictly increasing over L = 0, 5, 10, 20, 30, 40 ms (8 of 8 seeds in
    results/network/latency_phase.md; without jitter 4 master clocks leave too few offsets)."""
    e = [_mean_rms(L, True, 4, seed, jitter_ms=5.0) for L in LATENCIES]
    assert all(b > a for a, b in zip(e, e[1:])), e
