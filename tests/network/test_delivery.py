"""Delivery (frame phase 5): records due at the first frame after their arrival, the sender
check (§3.6.1), reordering, FRAME packets and their deadline (§3.5.2); a frame's few records
filed as lists vs a record table per frame, bit for bit."""
import math

import numpy as np
import pytest

from immersim.models.network import LinkClass, NetworkConfig, NetworkModel
from immersim.models.network.delivery import Inflight, due_frames
from immersim.models.network.paths import Paths


T = 0.033
LINKS = {"lan": LinkClass(0.3, 0.1, 0.0, 1000.0), "wan": LinkClass(20.0, 5.0, 0.0, 100.0)}


def run(cfg, steps):
    m = NetworkModel(cfg)
    out = [m.step(T) for _ in range(steps)]
    return m, out


def test_forged_update_from_non_owner_is_rejected_and_counted():
    cfg = NetworkConfig.from_flat(groups=3, render_nodes=1, entities=10, ownerless=False).with_links(
        latency_ms=0.0, jitter_ms=0.0, bandwidth_mbps=0.0)
    m = NetworkModel(cfg)
    m.step(T)
    G = cfg.groups
    obj = G + 0
    owner = int(m.owner[obj])
    forger = (owner + 1) % G
    viewer = (owner + 2) % G
    before = m.record(viewer, obj)
    m.inject_update(forger, viewer, obj, pos=(1e4, 1e4))
    m.flight.deliver(m)
    assert m.metrics.rejected_updates == 1
    assert np.array_equal(m.record(viewer, obj), before)
    # the same record from the owner is accepted
    m.inject_update(owner, viewer, obj, pos=(5.0, 6.0))
    m.flight.deliver(m)
    assert m.metrics.rejected_updates == 1
    assert tuple(m.record(viewer, obj)[1:3]) == (5.0, 6.0)


def test_late_slave_packets_are_dropped_at_the_tick():
    # FRAME leaves compose_ms after the tick and must arrive by the next one
    def frac(lan):
        cfg = NetworkConfig.from_flat(groups=2, render_nodes=3, entities=5, compose_ms=2.0,
                                      links={"lan": lan, "wan": LinkClass(10.0)})
        m, out = run(cfg, 300)
        frames = sum(s.frames for s in out[1:]) * cfg.groups * (cfg.render_nodes - 1)
        return sum(s.dropped_frames for s in out[1:]) / frames, max(s.desync_frames for s in out)
    assert frac(LinkClass(10.0)) == (0.0, 0)
    f, desync = frac(LinkClass(40.0))
    assert f == 1.0 and desync > 100
    # exponential jitter: P(2 + 25 + X > 33 ms) = exp(-6/5); the deadline is exact, not rounded
    f, _ = frac(LinkClass(25.0, 5.0))
    n = 299 * 2 * 2
    assert abs(f - math.exp(-1.2)) < 4 * math.sqrt(0.3 * 0.7 / n)


def test_due_frames_equal_the_array_code():
    m = NetworkModel(NetworkConfig.from_flat(groups=2, render_nodes=1, entities=0))
    gen = np.random.default_rng(1)
    for k in (0, 3, 1000):
        m.k = k
        arr = np.r_[gen.uniform(0.0, 40.0, 200), k * T, (k + 1) * T, k * T - 1e-12, (k + 2) * T + 1e-15,
                    np.inf, np.nan, 1e300, -np.inf, 0.0]
        assert due_frames(arr.tolist(), T, k) == m.flight.due(m, arr).tolist()


FEW_CASES = [
    dict(),                                                              # the campus_drive size
    dict(prediction_order=2, entities=12, scene_size=40.0, entity_speed=5.0, ownerless=False),   # order 2, hand-overs
    dict(prediction_order=0, links={"lan": LinkClass(0.3, 0.1, 0.0, 1000.0), "wan": LinkClass(15.0, 25.0, 0.0, 0.2)},
         ownerless=False),
    dict(groups=2, driven_groups=2, render_nodes=2, entities=1, grid=False),
    dict(ownerless=False, frame_phase=False, state_traffic="object_view"),   # the former defaults
]


@pytest.mark.parametrize("case", range(len(FEW_CASES)))
def test_few_records_as_lists_change_nothing(monkeypatch, case):
    """A frame's few records filed and delivered as lists (``Paths.few_records``) vs the record table
    of every frame: the same caches, owners, rejected and late records, RNG and outputs. The
    third case (a slow, jittery WAN) reorders records (the "newer than the cached one" test);
    latency bursts and bounces hand entities over with records in flight (the sender check)."""
    cfg = NetworkConfig.from_flat(groups=3, render_nodes=3, entities=8, driven_groups=3, seed=5, scene_size=60.0,
                                  entity_speed=3.0, links=LINKS).replace(**FEW_CASES[case])

    def trace(paths=None):
        m = NetworkModel(cfg, paths)
        out = []
        for k in range(260):
            m.latency_scale = 4.0 if 60 <= k < 90 else 1.0
            for g in range(cfg.groups):
                m.set_input(g, 0.0 if k < 10 else 0.9 - 0.3 * g, 0.3 * (g - 1) if k > 40 else 0.0)
            if k % 13 == 12:
                m.bounce(k % cfg.groups, (-1.0, 0.4))
            out.append((m.step(T).as_dict(), m.perceived_avatars(1).tolist(), m.per_object_max.tolist(),
                        m.per_object_rms.tolist()))
        return m, out

    calls = {"rows": 0, "epoch": 0, "older": 0}
    deliver_rows = Inflight.deliver_rows

    def counted(self, net, fi, senders, rows, epoch, t_send):
        calls["rows"] += 1
        calls["epoch"] += epoch != net.own.epoch       # owners changed while in flight: checked
        calls["older"] += t_send < net.records.newest  # possibly older than the cache: compared
        return deliver_rows(self, net, fi, senders, rows, epoch, t_send)

    monkeypatch.setattr(Inflight, "deliver_rows", counted)
    fast, fo = trace()
    assert calls["rows"] > 50 and (case in (0, 3) or calls["epoch"] > 0) and (case != 2 or calls["older"] > 0)
    plain, po = trace(Paths(few_records=-1))
    assert fo == po
    for name in ("cache", "owner", "hist", "shown_frame", "busy"):
        assert np.array_equal(getattr(fast, name), getattr(plain, name)), name
    assert fast.rng.bit_generator.state == plain.rng.bit_generator.state
    assert fast.totals.by_type == plain.totals.by_type and fast.records.uid == plain.records.uid
    assert case == 3 or sum(s["handovers"] + s["released"] + s["claimed"] for s, *_ in fo) > 0
    assert case in (0, 3) or sum(s["handovers"] for s, *_ in fo) > 0
