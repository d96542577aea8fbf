"""The network model's shortcuts change no output: each is checked against the plain computation.

* subscription (view entry) times from cell changes vs a dense per-pair "last frame in view" table;
* messages reused from the last frame (small scenes) vs built every frame;
* view pairs reused when no object changed cell vs recomputed;
* per-object maxima of eq. 3-1/3-2 as segment reductions vs ``np.maximum.at``;
* a transmit plan reused over batches vs a fresh one per batch;
* the queued-event counter behind ``at_rest`` vs a scan of the event heap.
"""
import copy
from dataclasses import replace

import numpy as np
import pytest

from immersim.models.network import LinkClass, NetworkConfig, NetworkModel
from immersim.models.network import model as model_mod
from immersim.models.network.links import TransmitPlan, transmit
from immersim.models.network.metrics import inconsistency_sq

T = 0.033
LOSSY = {"lan": LinkClass(0.3, 0.2, 0.05, 1000.0), "wan": LinkClass(20.0, 8.0, 0.1, 50.0)}


def _trace(cfg, steps, drive=False):
    m = NetworkModel(cfg)
    out = []
    for k in range(steps):
        if drive:
            for g in range(cfg.driven_groups):
                m.set_input(g, 0.8 if k < steps // 2 else -0.6, 0.2 * (g - 1))
        out.append(m.step(T).as_dict())
    return m, out


def _same(a, b):
    (ma, oa), (mb, ob) = a, b
    assert oa == ob
    assert np.array_equal(ma.cache, mb.cache) and np.array_equal(ma.owner, mb.owner)
    assert np.array_equal(ma.per_object_max, mb.per_object_max) and np.array_equal(ma.per_object_rms, mb.per_object_rms)
    assert np.array_equal(ma.hist, mb.hist) and np.array_equal(ma.shown_frame, mb.shown_frame)
    assert ma.totals.by_type == mb.totals.by_type


@pytest.mark.parametrize("topology", ["hybrid_p2p", "client_server", "full_mesh"])
def test_reused_messages_and_views_change_nothing(monkeypatch, topology):
    cfg = NetworkConfig(groups=3, render_nodes=3, entities=8, driven_groups=3, seed=2, topology=topology,
                        links=LOSSY)
    fast = _trace(cfg, 50, drive=True)
    monkeypatch.setattr(model_mod, "MEMO_PAIRS", -1)                      # never reuse messages
    orig = NetworkModel._view

    def fresh_view(self, cells, online_g):
        self._view_memo = None                                            # never reuse view pairs
        return orig(self, cells, online_g)

    monkeypatch.setattr(NetworkModel, "_view", fresh_view)
    _same(fast, _trace(cfg, 50, drive=True))


def test_subscription_times_match_a_dense_view_table():
    """A pair's subscription time is the start of its current stay in the viewer's neighbourhood."""
    cfg = NetworkConfig(groups=6, render_nodes=2, entities=150, scene_size=80.0, avatar_start="uniform",
                        entity_speed=12.0, seed=7)
    m = NetworkModel(cfg)
    G, n = cfg.groups, m.n_obj
    last_in_view = np.zeros((n, G), np.int64)       # the former per-pair table: frame 0 = scene file
    enter = np.zeros((n, G))
    entered = 0
    for _ in range(60):
        m.step(T)
        cells = m.grid.cell(m.world.positions())
        online = np.flatnonzero(m.master >= 0)
        vo, vl = m.grid.view_pairs(cells, cells[online])
        vg = online[vl]
        new = last_in_view[vo, vg] != m.k - 1
        enter[vo[new], vg[new]] = m.k * cfg.frame_s
        last_in_view[vo, vg] = m.k
        entered += int(new.sum())
        assert np.array_equal(m.cache[m.index(vg, vo), m.enter_col], enter[vo, vg])
        assert all(m.in_view(int(g), int(o)) for g, o in zip(vg[:50], vo[:50]))
    assert entered > 50   # the check saw many entries


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


def test_transmit_plan_reused_over_batches_equals_fresh_batches():
    links = LOSSY
    rng_a, rng_b = np.random.default_rng(3), np.random.default_rng(3)
    sender = np.array([0, 2, 0, 1, 2, 2, 0])
    link = np.array([1, 0, 1, 1, 0, 1, 0])
    nbytes = np.array([100, 1500, 40, 9000, 64, 700, 3000])
    busy_a, busy_b = np.zeros(3), np.zeros(3)
    plan = TransmitPlan(links, sender, link, nbytes)
    for k in range(5):
        send = np.full(7, k * T) + np.where(np.arange(7) % 2, 0.002, 0.0)
        a = plan.run(rng_a, send, busy_a, 1.5)
        b = transmit(rng_b, links, send, sender, link, nbytes, busy_b, 1.5)
        assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1]) and np.array_equal(busy_a, busy_b)


def test_pending_event_counter_matches_the_heap():
    m = NetworkModel(NetworkConfig(groups=3, render_nodes=2, entities=5, driven_groups=2, seed=1))
    m.schedule_leave(0.2, 1)
    m.schedule_join(0.5, 1)
    for k in range(30):
        m.set_input(k % 2, 0.1 * k, 0.0)
        m.step(T)
        assert m._pending == sum(kind in model_mod.PENDING for _, _, kind, _ in m._heap)


def test_measure_off_changes_no_network_output_at_scale_like_density():
    """Same network with and without the display metric, in a dense scene with DIS updates."""
    base = NetworkConfig(groups=20, render_nodes=2, entities=400, scene_size=300.0, avatar_start="uniform",
                         dis_threshold=0.1, seed=4)
    a, oa = _trace(base, 25)
    b, ob = _trace(replace(base, measure=False), 25)
    keys = ("messages", "bytes", "dropped_frames", "handovers", "published", "rejected_updates")
    assert [[s[k] for k in keys] for s in oa] == [[s[k] for k in keys] for s in ob]
    assert np.array_equal(a.cache, b.cache)
    assert max(s["inconsistency_max"] for s in oa) > 0.0 == max(s["inconsistency_max"] for s in ob)


@pytest.mark.parametrize("foci", ["frame", "reach"])
def test_point_index_owners_equal_kd_tree_and_brute_force(foci):
    from scipy.spatial import cKDTree

    from immersim.models.network.consistency import PointIndex, assign_owners

    rng = np.random.default_rng(5)
    apos, avel = rng.uniform(0, 200, (30, 2)), rng.normal(0, 10, (30, 2))
    epos = rng.uniform(0, 200, (2000, 2))
    cur = rng.integers(0, 30, 2000)
    args = ("mahalanobis", apos, avel, epos, cur, 0.033, 30.0, 4.0, foci)
    via_index = assign_owners(*args, etree=PointIndex(epos))
    via_tree = assign_owners(*args, etree=cKDTree(epos))
    brute = cur.copy()
    from immersim.models.network.consistency import ellipsoid_axes, mahalanobis_ellipsoid
    a, b, u, shift = ellipsoid_axes(avel, 0.033, 30.0, 4.0, foci)
    d = mahalanobis_ellipsoid(epos[:, None, :], (apos + shift)[None], u[None], a[None], b[None])   # (E, G)
    inside = d <= 1.0
    # among the regions holding an entity the smallest arrival distance |r| - ecc r.u wins
    r = epos[:, None, :] - apos[None]
    ecc = np.hypot(*shift.T) / a
    L = np.hypot(r[..., 0], r[..., 1]) - ecc[None] * np.einsum("egi,gi->eg", r, u)
    brute[inside.any(1)] = np.where(inside, L, np.inf).argmin(1)[inside.any(1)]
    assert np.array_equal(via_index, via_tree) and np.array_equal(via_index, brute)
    assert (via_index != cur).sum() > 20


def test_point_index_contacts_equal_kd_tree_contacts():
    cfg = NetworkConfig(groups=40, render_nodes=1, entities=600, scene_size=60.0, seed=8)
    m = NetworkModel(cfg)
    w = m.world
    w.speed[:] = 5.0
    w2 = copy.deepcopy(w)               # (contacts separate overlaps: each path on its own copy)
    a = w.contacts(w.entity_index())
    b = w2.contacts(w2.entity_tree())
    assert len(a[0]) > 5
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    assert np.array_equal(w.epos, w2.epos) and w.separated == w2.separated > 0
    w.epos[:] = 1e4                     # nobody near: the index answers without a tree
    idx = w.entity_index()
    assert len(w.contacts(idx)[0]) == 0 and idx._tree is None


def _display_trace(cfg, steps, events=False):
    m = NetworkModel(cfg)
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

    cfg = NetworkConfig(**{**dict(groups=16, render_nodes=2, entities=700, scene_size=90.0, avatar_start="uniform",
                                  entity_speed=6.0, seed=12), **kw})
    calls = {"groups": 0}
    orig = display.DisplayGroups.errors

    def counting(self, *a):
        calls["groups"] += 1
        return orig(self, *a)

    monkeypatch.setattr(display.DisplayGroups, "errors", counting)
    monkeypatch.setattr(model_mod, "GROUPS_MIN_PAIRS", 0)          # record groups whenever they pay
    mg, og, pg = _display_trace(cfg, 45, events=True)
    monkeypatch.setattr(model_mod, "GROUPS_MIN_PAIRS", 10 ** 12)   # every frame per copy
    mc, oc, pc = _display_trace(cfg, 45, events=True)
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
    assert calls["groups"] >= (5 if cfg.dis_threshold > 0 else 0)


def test_resting_avatars_skip_repeated_substeps_exactly():
    """A resting fleet stops sub-stepping once a sub-step changes nothing: the same state as
    sub-stepping one by one (headings near +-pi and below -pi/2 included)."""
    from immersim.models.network.world import World

    cfg = NetworkConfig(groups=6, render_nodes=1, entities=0)
    a, b = World(cfg, np.random.default_rng(1)), World(cfg, np.random.default_rng(1))
    for w in (a, b):
        w.yaw[:] = [-3.14159, -2.0, -1.6, 0.3, 3.1415926, 1e-17]
        w.steer[:] = [0.2, -0.4, 0.0, 0.1, -0.1, 0.3]
    h = cfg.frame_s / cfg.substeps
    for k in range(1, 4):
        a.advance_to(k * cfg.frame_s)                  # one call, 4 sub-steps (shortcut)
        for j in range(cfg.substeps):                  # one sub-step per call
            b.advance_to((k - 1) * cfg.frame_s + (j + 1) * h if j < cfg.substeps - 1 else k * cfg.frame_s)
        for name in ("apos", "yaw", "speed", "accel", "yaw_rate"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name


def test_scalar_kinematics_equal_the_array_code(monkeypatch):
    """Few avatars and entities run in Python floats: the same trajectories (walls, reversing,
    steering, entity reflections) as the numpy code."""
    from immersim.models.network import world as world_mod

    cfg = NetworkConfig(groups=4, render_nodes=2, entities=20, driven_groups=4, scene_size=12.0, seed=3,
                        avatar_start="uniform", entity_speed=6.0, avatar_mass=float("inf"))  # (the walls it hits)

    def trace():
        m = NetworkModel(cfg)
        out = []
        for k in range(120):
            for g in range(4):
                m.set_input(g, 1.0 if k < 70 else -1.0, 0.3 * np.sin(0.05 * k + g))
            m.step(T)
            w = m.world
            out.append(np.r_[w.apos.ravel(), w.yaw, w.speed, w.accel, w.yaw_rate, w.epos.ravel(), w.evel.ravel()])
        return np.array(out), m

    fast, mf = trace()
    monkeypatch.setattr(world_mod, "SCALAR_AVATARS", 0)
    monkeypatch.setattr(world_mod, "SCALAR_ENTITIES", 0)
    ref, mr = trace()
    assert np.array_equal(fast, ref)
    S = cfg.scene_size
    hits = {"n": 0}
    orig = world_mod.World._avatar_walls

    def counting(self):
        hits["n"] += bool(((self.apos < 0.0) | (self.apos > S)).any())
        return orig(self)

    monkeypatch.setattr(world_mod.World, "_avatar_walls", counting)
    trace()
    assert hits["n"] > 3                                                     # walls were hit
    assert (np.diff(np.sign(ref[:, 24::2]), axis=0) != 0).sum() > 20        # entities reflected
    assert ref[:, :8].min() >= 0.0 and ref[:, :8].max() <= S


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
