"""Publishing (frame phase 3): every frame every object with an online owner; with a DIS
threshold only drifted objects and a heartbeat re-publication."""
import numpy as np

from immersim.models.network import NetworkConfig, NetworkModel


def test_dis_republishes_a_resting_object_at_the_first_frame_a_heartbeat_after_its_last():
    """DIS (dis_threshold > 0), nothing moving: an object is re-published at the first frame with
    t - t_last >= dis_heartbeat_s (1 s): frames of 33 ms give t = 1.023, 2.046, 3.069 s."""
    cfg = NetworkConfig.from_flat(groups=2, render_nodes=2, entities=0, driven_groups=2, seed=3, dis_threshold=0.1)
    m = NetworkModel(cfg)
    times, last, expected = [], 0.0, []
    for k in range(1, 100):
        m.step(cfg.scene.frame_s)
        t = k * cfg.scene.frame_s
        if t - last >= cfg.consistency.dis_heartbeat_s - 1e-9:
            expected.append(round(t, 6))
            last = t
        if m.metrics.published:
            assert m.metrics.published == cfg.groups
            times.append(round(t, 6))
    assert times == expected == [1.023, 2.046, 3.069]


def test_every_frame_publishes_every_object_whose_owner_is_online():
    """Without DIS a frame publishes the G + E objects; once group 1's only render node has left,
    the objects group 1 owns are no longer published (and nothing else changes owner at rest)."""
    cfg = NetworkConfig.from_flat(groups=3, render_nodes=1, entities=6, driven_groups=3, seed=2, ownership="none")
    m = NetworkModel(cfg)
    m.step(cfg.scene.frame_s)
    assert m.metrics.published == m.metrics.frames * (cfg.groups + cfg.entities)
    owned_by_1 = int(np.count_nonzero(m.owner == 1))
    m.schedule_leave(m.t + 0.001, 1)
    m.step(cfg.scene.frame_s)
    m.step(cfg.scene.frame_s)
    assert m.master[1] == -1
    assert m.metrics.published == cfg.groups + cfg.entities - owned_by_1 and owned_by_1 == 3
