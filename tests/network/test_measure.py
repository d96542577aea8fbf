"""The display error (frame phase 6b, eq. 3-1/3-2): the metric's closed form, record groups vs
the per-copy error, the metric switched off, and the array helpers it uses."""

import numpy as np
import pytest

from immersim.models.network import NetworkConfig, NetworkModel
from immersim.models.network.arrays import pairwise_sum
from immersim.models.network.metrics import inconsistency, inconsistency_sq
from immersim.models.network.paths import Paths

from .helpers import LOSSY, T, trace


def test_inconsistency_is_the_max_and_rms_of_the_copies_position_errors():
    obj = np.array([0, 0, 1, 2, 2, 2])
    truth = np.array([[0.0, 0.0], [1.0, 1.0], [5.0, -2.0]])
    shown = truth[obj] + np.array([[3.0, 4.0], [0.0, 1.0], [0.0, 0.0], [1.0, 0.0], [0.0, -2.0], [0.6, 0.8]])
    per_max, per_rms, total_max, total_rms = inconsistency(obj, shown, truth, 4)
    np.testing.assert_allclose(per_max, [5.0, 0.0, 2.0, 0.0])
    np.testing.assert_allclose(per_rms, [np.sqrt((25 + 1) / 2), 0.0, np.sqrt((1 + 4 + 1) / 3), 0.0])
    assert total_max == pytest.approx(5.0)
    assert total_rms == pytest.approx(np.sqrt((25 + 1 + 0 + 1 + 4 + 1) / 6))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_sorted_segment_maxima_equal_scattered_maxima(seed):
    rng = np.random.default_rng(seed)
    obj = np.sort(rng.integers(0, 40, 500))
    err2 = rng.exponential(1.0, 500)
    mask = rng.random(500) < 0.7
    for msk in (mask, None):
        a = inconsistency_sq(obj, err2, 50, msk)
        b = inconsistency_sq(obj, err2, 50, msk, sorted_obj=True)
        assert all(np.array_equal(x, y) for x, y in zip(a, b))


def test_measure_off_changes_no_network_output_at_scale_like_density():
    """Same network with and without the display metric, in a dense scene with DIS updates."""
    base = NetworkConfig.from_flat(groups=20, render_nodes=2, entities=400, scene_size=300.0, avatar_start="uniform",
                                   dis_threshold=0.1, seed=4)
    a, oa = trace(base, 25)
    b, ob = trace(base.replace(measure=False), 25)
    keys = ("messages", "bytes", "dropped_frames", "handovers", "published", "rejected_updates")
    assert [[s[k] for k in keys] for s in oa] == [[s[k] for k in keys] for s in ob]
    assert np.array_equal(a.cache, b.cache)
    assert max(s["inconsistency_max"] for s in oa) > 0.0 == max(s["inconsistency_max"] for s in ob)


def _display_trace(cfg, steps, events=False, paths=None):
    m = NetworkModel(cfg, paths)
    out, per = [], []
    for k in range(steps):
        if events and k == 10:
            m.schedule_leave(m.t + 0.01, 2 * cfg.render_nodes)           # group 2's master leaves
            m.schedule_leave(m.t + 0.02, 5 * cfg.render_nodes, graceful=False)
        if events and k == 25:
            m.schedule_join(m.t + 0.005, 2 * cfg.render_nodes)
        out.append(m.step(T).as_dict())
        per.append((m.per_object_max.copy(), m.per_object_rms.copy()))
    return m, out, per


@pytest.mark.parametrize("kw", [
    dict(dis_threshold=0.05),
    dict(dis_threshold=0.05, prediction_order=2, ownership="euclidean"),
    dict(dis_threshold=0.2, prediction_order=0, links=LOSSY),
    dict(dis_threshold=0.05, grid=False, entities=150),
    dict(dis_threshold=0.05, topology="full_mesh", entities=150),
    dict(dis_threshold=0.05, topology="client_server", links=LOSSY),
    dict(dis_threshold=0.0),
])
def test_record_groups_equal_the_per_copy_display_error(monkeypatch, kw):
    """eq. 3-1/3-2 from record groups == per copy: maxima exact, RMS to round-off; the groups
    path really ran (contacts, hand-overs, masters leaving and joining, cells changing)."""
    from immersim.models.network import display

    cfg = NetworkConfig.from_flat(**{**dict(groups=16, render_nodes=2, entities=700, scene_size=90.0, avatar_start="uniform",
                                            entity_speed=6.0, seed=12), **kw})
    calls = {"groups": 0}
    orig = display.DisplayGroups.errors

    def counting(self, *a):
        calls["groups"] += 1
        return orig(self, *a)

    monkeypatch.setattr(display.DisplayGroups, "errors", counting)
    mg, og, pg = _display_trace(cfg, 45, events=True, paths=Paths(groups_min_pairs=0))   # record groups whenever they pay
    mc, oc, pc = _display_trace(cfg, 45, events=True, paths=Paths(groups_min_pairs=10 ** 12))   # every frame per copy
    for a, b in zip(og, oc):
        assert a["inconsistency_max"] == b["inconsistency_max"]
        assert a["inconsistency_rms"] == pytest.approx(b["inconsistency_rms"], rel=1e-12, abs=1e-15)
        assert {k: v for k, v in a.items() if not k.startswith("inconsistency")} == \
               {k: v for k, v in b.items() if not k.startswith("inconsistency")}
    for (amax, arms), (bmax, brms) in zip(pg, pc):
        assert np.array_equal(amax, bmax)
        np.testing.assert_allclose(arms, brms, rtol=1e-12, atol=1e-15)
    assert sum(s["handovers"] for s in og) > 0 and sum(s["contacts"] for s in og) > 0
    assert max(s["inconsistency_max"] for s in og) > 0
    assert calls["groups"] >= (5 if cfg.consistency.dis_threshold > 0 else 0)


@pytest.mark.parametrize("n", [0, 1, 7, 8, 9, 16, 33, 64, 127, 128, 129, 300])
def test_pairwise_sum_equals_numpy(n):
    gen = np.random.default_rng(n)
    for _ in range(50):
        a = gen.random(n) ** 3 * 10.0 ** gen.uniform(-8, 4, n)
        a[gen.random(n) < 0.3] = 0.0
        assert pairwise_sum(a.tolist()) == float(np.add.reduce(a))


@pytest.mark.parametrize("n", [0, 1, 7, 5000])
def test_sorted_unique_equals_np_unique(n):
    from immersim.models.network.arrays import sorted_unique

    a = np.random.default_rng(n).integers(-50, 300, n) * (2 ** 33)
    u, first, inv = sorted_unique(a)
    ru, rfirst, rinv = np.unique(a, return_index=True, return_inverse=True)
    assert np.array_equal(u, ru) and np.array_equal(first, rfirst) and np.array_equal(inv, rinv.ravel())


def test_unique_values_and_sum_by_key_equal_numpy():
    from immersim.models.network.arrays import sum_by_key, unique_values

    rng = np.random.default_rng(4)
    a = rng.integers(0, 400, 3000) * (2 ** 32) + rng.integers(0, 5, 3000)
    w = rng.choice([-1, 1], 3000)
    assert np.array_equal(unique_values(a), np.unique(a)) and len(unique_values(a[:0])) == 0
    u, first, dw = sum_by_key(a, w)
    ru, rfirst, rinv = np.unique(a, return_index=True, return_inverse=True)
    assert np.array_equal(u, ru) and np.array_equal(first, rfirst)
    assert np.array_equal(dw, np.bincount(rinv.ravel(), weights=w).astype(np.int64))
