"""The per-frame shortcuts of small scenes change no output: each is checked against the code
it replaces, bit for bit.

* a small lossless batch timed in Python floats (:meth:`TransmitPlan.run_floats`) vs the
  array code (:meth:`TransmitPlan.run`): arrivals, uplinks and the generator's state;
* due frames and control-packet latencies in Python vs :meth:`NetworkModel._due` and
  :func:`links.sample_latency` (lost, huge and late arrivals included);
* numpy's pairwise summation in Python (:func:`arrays.pairwise_sum`) vs ``np.add.reduce``;
* the grid's cells, view pairs and view entries of a few objects, and the hybrid_p2p messages
  of a few view pairs, in Python vs the array code;
* avatars sub-stepped one by one (resting, reversing, at the walls) vs the array code;
* whole runs with every such shortcut vs the array paths (campus size, lossy links, order 2,
  client-server), with joins, graceful leaves and crashes (the online-node count included);
* a frame's few records filed and delivered as lists vs a record table per frame.
"""
import math
from dataclasses import replace

import numpy as np
import pytest

from immersim.models.network import LinkClass, NetworkConfig, NetworkModel
from immersim.models.network import consistency as cons
from immersim.models.network import links as links_mod
from immersim.models.network import model as model_mod
from immersim.models.network import nodes as nodes_mod
from immersim.models.network import world as world_mod
from immersim.models.network.arrays import pairwise_sum
from immersim.models.network.links import TransmitPlan

T = 0.033
LINKS = {"lan": LinkClass(0.3, 0.1, 0.0, 1000.0), "wan": LinkClass(20.0, 5.0, 0.0, 100.0)}


@pytest.mark.parametrize("bandwidth", [100.0, 0.0, 0.05])
def test_float_batches_equal_the_array_code(bandwidth):
    links = {"lan": LinkClass(0.3, 0.1, 0.0, 1000.0), "wan": LinkClass(20.0, 5.0, 0.0, bandwidth)}
    gen = np.random.default_rng(7)
    for trial in range(60):
        n = int(gen.integers(1, links_mod.FLOAT_BATCH + 1))
        sender = gen.integers(0, 5, n)
        link = gen.integers(0, 2, n) if trial % 5 else np.ones(n, np.int64)   # some one-class batches
        nbytes = gen.integers(20, 3000, n)
        plan = TransmitPlan(links, sender, link, nbytes)
        if plan.floats is None:          # one class: not merged, the array code only
            assert not (link == 0).any() or not (link == 1).any()
            continue
        rng_a, rng_b = np.random.default_rng(trial), np.random.default_rng(trial)
        busy_a = gen.uniform(0.0, 0.01, 5) * (gen.random(5) < 0.5)
        busy_b = busy_a.copy()
        for k in range(4):
            send = k * T + np.where(gen.random(n) < 0.4, 0.002, 0.0)
            scale = float(gen.choice([1.0, 0.0, 2.5]))
            arrival, lost = plan.run(rng_a, send, busy_a, scale)
            floats = plan.run_floats(rng_b, send.tolist(), busy_b, scale)
            assert floats == arrival.tolist() and not lost.any()
            assert np.array_equal(busy_a, busy_b)
        assert rng_a.bit_generator.state == rng_b.bit_generator.state


def test_due_frames_equal_the_array_code():
    m = NetworkModel(NetworkConfig(groups=2, render_nodes=1, entities=0))
    gen = np.random.default_rng(1)
    for k in (0, 3, 1000):
        m.k = k
        arr = np.r_[gen.uniform(0.0, 40.0, 200), k * T, (k + 1) * T, k * T - 1e-12, (k + 2) * T + 1e-15,
                    np.inf, np.nan, 1e300, -np.inf, 0.0]
        assert model_mod._due_frames(arr.tolist(), T, k) == m._due(arr).tolist()


@pytest.mark.parametrize("n", [0, 1, 7, 8, 9, 16, 33, 64, 127, 128, 129, 300])
def test_pairwise_sum_equals_numpy(n):
    gen = np.random.default_rng(n)
    for _ in range(50):
        a = gen.random(n) ** 3 * 10.0 ** gen.uniform(-8, 4, n)
        a[gen.random(n) < 0.3] = 0.0
        assert pairwise_sum(a.tolist()) == float(np.add.reduce(a))


def test_avatars_one_by_one_equal_the_array_code(monkeypatch):
    """Resting (with -0.0 speeds), driving into the walls and reversing: the same arrays and
    the same fixed-point decision as the array code's sub-step loop."""
    cfg = NetworkConfig(groups=5, render_nodes=1, entities=0, scene_size=15.0, avatar_start="uniform", seed=2)

    def trace():
        w = world_mod.World(cfg, np.random.default_rng(2))
        w.speed[:] = [0.0, -0.0, 0.0, -0.0, 0.0]
        w.steer[:] = [0.3, -0.2, 0.0, 0.1, -0.4]
        w.yaw[:] = [-3.14159, 3.1415926, 1e-17, -1.6, 2.0]
        out, fixed = [], []
        for k in range(1, 160):
            if k == 20:
                w.throttle[:] = [1.0, -1.0, 0.5, 1.0, -0.7]
            if k == 110:
                w.throttle[:] = 0.0
            w.advance_to(k * T - (0.011 if k % 3 == 0 else 0.0), entities=False)   # partial frames too
            w.advance_to(k * T, entities=False)
            out.append(np.r_[w.apos.ravel(), w.yaw, w.speed, w.accel, w.yaw_rate])
            fixed.append(w._fixed_key is not None)
        return np.array(out), fixed

    fast, fast_fixed = trace()
    monkeypatch.setattr(world_mod, "SCALAR_AVATARS", 0)
    plain, _ = trace()
    assert np.array_equal(fast, plain)
    S = cfg.scene_size
    xy = plain[:, :10]
    assert ((xy == 0.0) | (xy == S)).any()                 # the walls were hit
    assert fast_fixed[1:19] == [True] * 18                 # resting at first: a fixed point (after the
    assert not any(fast_fixed[20:110])                     # first advance normalised the headings)


def _run(cfg, steps=180):
    m = NetworkModel(cfg)
    m.schedule_leave(0.7, 1)                        # a graceful leave of a slave,
    m.schedule_leave(0.4, 3, graceful=False)        # a crashed master (times out after 3 s),
    m.schedule_join(2.4, 1)                         # and both rejoin
    m.schedule_join(5.2, 3)
    out = []
    for k in range(steps):
        for g in range(cfg.driven_groups):
            m.set_input(g, 0.0 if k < 10 else 0.9 - 0.4 * g, 0.25 * (g - 1) if k > 40 else 0.0)
        if k % 17 == 16:
            m.bounce(k % cfg.groups, (-1.0, 0.4))
        s = m.step(T).as_dict()
        assert s["online_nodes"] == int(np.count_nonzero(m.online))
        out.append((s, m.at_rest(), m.world.avatar_outputs(T), m.perceived_avatars(1).tolist(),
                    m.per_object_max.tolist(), m.per_object_rms.tolist()))
    return m, out


CASES = [
    dict(),                                                             # the campus_drive size
    dict(links={"lan": LinkClass(0.3, 0.2, 0.05, 1000.0), "wan": LinkClass(20.0, 8.0, 0.1, 50.0)}),
    dict(prediction_order=2, links={"lan": LinkClass(0.3, 0.1, 0.0, 0.0), "wan": LinkClass(30.0, 12.0, 0.0, 0.0)}),
    dict(prediction_order=0, topology="client_server"),
    dict(entities=20, scene_size=30.0, ownership="euclidean"),
]


@pytest.mark.parametrize("case", range(len(CASES)))
def test_frame_shortcuts_change_nothing(monkeypatch, case):
    cfg = replace(NetworkConfig(groups=3, render_nodes=3, entities=8, driven_groups=3, seed=5, scene_size=60.0,
                                entity_speed=3.0, links=LINKS), **CASES[case])
    fast, fo = _run(cfg)
    monkeypatch.setattr(links_mod, "FLOAT_BATCH", -1)           # batches planned and timed by the array code
    monkeypatch.setattr(cons, "SCALAR_VIEW_PAIRS", -1)          # view pairs in arrays
    monkeypatch.setattr(nodes_mod, "SCALAR_MESSAGES", -1)       # messages built in arrays
    monkeypatch.setattr(model_mod, "SCALAR_VIEW", -1)           # display in arrays
    monkeypatch.setattr(model_mod, "FEW_RECORDS", -1)           # every frame's records in a table
    monkeypatch.setattr(world_mod, "SCALAR_AVATARS", 0)         # kinematics in arrays
    monkeypatch.setattr(world_mod, "SCALAR_ENTITIES", 0)
    plain, po = _run(cfg)
    assert fo == po
    for name in ("cache", "owner", "hist", "shown_frame", "busy", "online"):
        assert np.array_equal(getattr(fast, name), getattr(plain, name)), name
    assert fast.totals.by_type == plain.totals.by_type and fast.totals.frames == plain.totals.frames
    assert fast.rng.bit_generator.state == plain.rng.bit_generator.state
    assert fast.supernode.timeouts == 1 and fast.supernode.leaves == 1
    assert any(s["handovers"] for s, *_ in fo) and max(s["inconsistency_max"] for s, *_ in fo) > 0.0
    assert not math.isnan(fo[-1][0]["inconsistency_rms"])


@pytest.mark.parametrize("cells", [1, 2, 5, 10])
def test_small_view_pairs_equal_the_array_code(monkeypatch, cells):
    grid = cons.SceneGrid(100.0, cells, True)
    gen = np.random.default_rng(cells)
    cases = [(gen.integers(0, cells * cells, gen.integers(0, 12)), gen.integers(0, cells * cells, gen.integers(0, 20)))
             for _ in range(200)]
    fast = [grid.view_pairs(v, o) for v, o in cases]
    monkeypatch.setattr(cons, "SCALAR_VIEW_PAIRS", -1)
    for (v, o), (a, b) in zip(cases, fast):
        ra, rb = grid.view_pairs(v, o)
        assert np.array_equal(a, ra) and np.array_equal(b, rb) and a.dtype == ra.dtype and b.dtype == rb.dtype


@pytest.mark.parametrize("cells", [1, 3, 10])
def test_small_view_entries_equal_the_array_code(monkeypatch, cells):
    grid = cons.SceneGrid(100.0, cells, True)
    gen = np.random.default_rng(cells)
    cases = []
    for _ in range(300):
        G, O = int(gen.integers(1, 5)), int(gen.integers(0, 10))
        old = gen.integers(0, cells * cells, G + O)
        new = np.where(gen.random(G + O) < 0.3, gen.integers(0, cells * cells, G + O), old)   # some moved
        k = int(gen.integers(0, 40))
        cases.append((old, gen.random(G) < 0.7, new, gen.integers(0, G, k), gen.integers(0, G + O, k)))
    fast = [grid.not_in_view(*c) for c in cases]
    monkeypatch.setattr(cons, "SCALAR_VIEW_PAIRS", -1)
    assert sum(len(f) for f in fast) > 100
    for c, f in zip(cases, fast):
        ref = grid.not_in_view(*c)
        assert np.array_equal(f, ref) and f.dtype == ref.dtype


@pytest.mark.parametrize("dist", ["exponential", "uniform", "normal"])
def test_latency_sum_equals_the_array_code(dist):
    for n in (1, 2, 3, 7, 8, 20):
        for link in (LinkClass(20.0, 5.0, 0.0, 100.0, dist), LinkClass(0.0, 3.0, 0.0, 0.0, dist),
                     LinkClass(20.0, 0.0, 0.0, 100.0, dist), LinkClass(5.0, 2.0, 0.1, 10.0, dist)):
            a, b = np.random.default_rng(n), np.random.default_rng(n)
            for _ in range(20):
                assert links_mod.latency_sum(a, link, n) == float(links_mod.sample_latency(b, link, n).sum())
            assert a.bit_generator.state == b.bit_generator.state


def test_single_class_float_batches_equal_the_array_code():
    gen = np.random.default_rng(3)
    for trial in range(40):
        n = int(gen.integers(1, links_mod.FLOAT_BATCH + 1))
        sender, nbytes = gen.integers(0, 4, n), gen.integers(20, 3000, n)
        plan = TransmitPlan(LINKS, sender, np.full(n, trial % 2), nbytes)
        assert plan.floats is not None
        rng_a, rng_b = np.random.default_rng(trial), np.random.default_rng(trial)
        busy_a = gen.uniform(0.0, 0.01, 4)
        busy_b = busy_a.copy()
        for k in range(3):
            send = k * T + np.where(gen.random(n) < 0.4, 0.002, 0.0)
            arrival, lost = plan.run(rng_a, send, busy_a, 1.5)
            assert plan.run_floats(rng_b, send.tolist(), busy_b, 1.5) == arrival.tolist()
            assert np.array_equal(busy_a, busy_b) and not lost.any()
        assert rng_a.bit_generator.state == rng_b.bit_generator.state


def test_cells_from_a_positions_list_equal_the_array_code():
    gen = np.random.default_rng(9)
    for size, C in ((100.0, 10), (60.0, 7), (1.0, 1), (33.3, 3)):
        grid = cons.SceneGrid(size, C, True)
        pos = np.r_[gen.uniform(-0.1 * size, 1.1 * size, (200, 2)),
                    [[0.0, size], [size, 0.0], [-0.0, size * (1 - 1e-16)], [size / C, 2 * size / C], [1e30, -1e30]]]
        with np.errstate(invalid="ignore"):     # (1e30: beyond int64, the array code's cast)
            fast, ref = grid.cell(pos, pos.tolist()), grid.cell(pos)
        assert np.array_equal(fast, ref) and fast.dtype == ref.dtype
        assert np.array_equal(grid.cell(pos[:-1], pos[:-1].tolist()), ref[:-1])   # (all in Python)
    with np.errstate(invalid="ignore"):
        bad = np.array([[np.nan, 1.0], [np.inf, 2.0]])
        assert np.array_equal(grid.cell(bad, bad.tolist()), grid.cell(bad))   # not finite: the array code


def test_small_hybrid_messages_equal_the_array_code(monkeypatch):
    nodes = nodes_mod
    gen = np.random.default_rng(0)
    names = ("send_t", "sender", "receiver", "link", "nbytes", "ptype", "hop_of", "rec_msg", "rec_viewer", "rec_obj",
             "frame_msg", "frame_slave", "rec_hop1")
    cases = []
    for trial in range(300):
        G, R, E = int(gen.integers(1, 6)), int(gen.integers(1, 4)), int(gen.integers(0, 12))
        cfg = NetworkConfig(groups=G, render_nodes=R, entities=E, prediction_order=int(gen.integers(0, 3)))
        master = np.array([g * R if gen.random() < 0.8 else -1 for g in range(G)], np.int64)   # some offline
        slaves = [np.arange(g * R + 1, (g + 1) * R)[gen.random(R - 1) < 0.7] if master[g] >= 0 else np.zeros(0, np.int64)
                  for g in range(G)]
        owner = np.r_[np.arange(G), gen.integers(0, G, E)]
        k = int(gen.integers(0, 40))
        vo, vg = np.sort(gen.integers(0, G + E, k)), gen.integers(0, G, k)
        send = gen.random(k) < (0.5 if trial % 2 else 1.1)                     # DIS-like, or every pair
        cases.append((cfg, nodes.NodeRegistry(cfg), float(gen.uniform(0, 10)), master, slaves,
                      np.flatnonzero(gen.random(G + E) < 0.8), owner, vg, vo, np.bincount(vg, minlength=G), send,
                      owner[vo]))
    fast = [nodes.build_messages(*c) for c in cases]
    monkeypatch.setattr(nodes, "SCALAR_MESSAGES", -1)
    assert sum(len(f.rec_msg) for f in fast) > 1000 and sum(len(f.frame_msg) for f in fast) > 200
    for c, f in zip(cases, fast):
        ref = nodes.build_messages(*c)
        for name in names:
            a, b = getattr(f, name), getattr(ref, name)
            assert np.array_equal(a, b) and a.dtype == b.dtype, name


FEW_CASES = [
    dict(),                                                              # the campus_drive size
    dict(prediction_order=2, entities=12, scene_size=40.0, entity_speed=5.0),   # order 2, hand-overs
    dict(prediction_order=0, links={"lan": LinkClass(0.3, 0.1, 0.0, 1000.0), "wan": LinkClass(15.0, 25.0, 0.0, 0.2)}),
    dict(groups=2, driven_groups=2, render_nodes=2, entities=1, grid=False),
]


@pytest.mark.parametrize("case", range(len(FEW_CASES)))
def test_few_records_as_lists_change_nothing(monkeypatch, case):
    """A frame's few records filed and delivered as lists (``FEW_RECORDS``) vs the record table
    of every frame: the same caches, owners, rejected and late records, RNG and outputs. The
    third case (a slow, jittery WAN) reorders records (the "newer than the cached one" test);
    latency bursts and bounces hand entities over with records in flight (the sender check)."""
    cfg = replace(NetworkConfig(groups=3, render_nodes=3, entities=8, driven_groups=3, seed=5, scene_size=60.0,
                                entity_speed=3.0, links=LINKS), **FEW_CASES[case])

    def trace():
        m = NetworkModel(cfg)
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
    deliver_rows = model_mod.NetworkModel._deliver_rows

    def counted(self, fi, senders, rows, epoch, t_send):
        calls["rows"] += 1
        calls["epoch"] += epoch != self._epoch       # owners changed while in flight: checked
        calls["older"] += t_send < self._newest      # possibly older than the cache: compared
        return deliver_rows(self, fi, senders, rows, epoch, t_send)

    monkeypatch.setattr(model_mod.NetworkModel, "_deliver_rows", counted)
    fast, fo = trace()
    assert calls["rows"] > 50 and (case == 3 or calls["epoch"] > 0) and (case != 2 or calls["older"] > 0)
    monkeypatch.setattr(model_mod, "FEW_RECORDS", -1)
    plain, po = trace()
    assert fo == po
    for name in ("cache", "owner", "hist", "shown_frame", "busy"):
        assert np.array_equal(getattr(fast, name), getattr(plain, name)), name
    assert fast.rng.bit_generator.state == plain.rng.bit_generator.state
    assert fast.totals.by_type == plain.totals.by_type and fast._uid == plain._uid
    assert case == 3 or sum(s["handovers"] for s, *_ in fo) > 0


def test_history_slots_kept_as_lists_read_as_the_array():
    """A small scene's history slots stay lists until the array is read: what every render node
    perceives from the lists equals the array's rows (slaves lagging behind included), and the
    array equals the one the array code writes."""
    cfg = NetworkConfig(groups=3, render_nodes=3, entities=8, driven_groups=3, seed=2,       # a slow LAN: late FRAMEs
                        links={"lan": LinkClass(22.0, 10.0, 0.0, 1000.0), "wan": LinkClass(25.0, 12.0, 0.0, 100.0)})

    def trace(read_lists):
        m = NetworkModel(cfg)
        seen = []
        for k in range(150):
            m.latency_scale = 3.0 if 40 <= k < 70 else 1.0        # a burst: slaves lag further
            for g in range(3):
                m.set_input(g, 0.8 - 0.2 * g, 0.2 * (g - 1))
            m.step(T)
            if read_lists:
                assert m.k % model_mod.HIST in m._hist_rows          # this frame's slot: a list
                lists = [m.perceived_list(node) for node in range(m.reg.n_render)]
                arrays = [m.perceived_avatars(node).ravel().tolist() for node in range(m.reg.n_render)]
                assert lists == arrays and not m._hist_rows
                seen.append(lists)
        return m, seen

    fast, seen = trace(True)
    assert any(s[1] != s[0] for s in seen)                  # a slave showed an older frame
    assert max(int(x) for x in fast.shown_frame) <= fast.k
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(model_mod, "SCALAR_VIEW", -1)              # history slots written by the array code
        plain, _ = trace(False)
    assert np.array_equal(fast.hist, plain.hist)
