"""The ground truth (:mod:`world`): avatar and entity kinematics, resting fleets, contacts;
the Python-float forms of tiny scenes against the array code, bit for bit.
"""
import copy

import numpy as np

from immersim.models.network import NetworkConfig, NetworkModel
from immersim.models.network import world as world_mod
from immersim.models.network.paths import Paths
from immersim.models.network.world import World


T = 0.033


def test_resting_avatars_skip_repeated_substeps_exactly():
    """A resting fleet stops sub-stepping once a sub-step changes nothing: the same state as
    sub-stepping one by one (headings near +-pi and below -pi/2 included)."""
    cfg = NetworkConfig.from_flat(groups=6, render_nodes=1, entities=0)
    a, b = World(cfg, np.random.default_rng(1)), World(cfg, np.random.default_rng(1))
    for w in (a, b):
        w.yaw[:] = [-3.14159, -2.0, -1.6, 0.3, 3.1415926, 1e-17]
        w.steer[:] = [0.2, -0.4, 0.0, 0.1, -0.1, 0.3]
    h = cfg.scene.frame_s / cfg.world.substeps
    for k in range(1, 4):
        a.advance_to(k * cfg.scene.frame_s)                  # one call, 4 sub-steps (shortcut)
        for j in range(cfg.world.substeps):                  # one sub-step per call
            b.advance_to((k - 1) * cfg.scene.frame_s + (j + 1) * h if j < cfg.world.substeps - 1 else k * cfg.scene.frame_s)
        for name in ("apos", "yaw", "speed", "accel", "yaw_rate"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name


def test_scalar_kinematics_equal_the_array_code(monkeypatch):
    """Few avatars and entities run in Python floats: the same trajectories (walls, reversing,
    steering, entity reflections) as the numpy code."""
    cfg = NetworkConfig.from_flat(groups=4, render_nodes=2, entities=20, driven_groups=4, scene_size=12.0, seed=3,
                                  avatar_start="uniform", entity_speed=6.0, avatar_mass=float("inf"))  # (the walls it hits)

    def trace(paths=None):
        m = NetworkModel(cfg, paths)
        out = []
        for k in range(120):
            for g in range(4):
                m.set_input(g, 1.0 if k < 70 else -1.0, 0.3 * np.sin(0.05 * k + g))
            m.step(T)
            w = m.world
            out.append(np.r_[w.apos.ravel(), w.yaw, w.speed, w.accel, w.yaw_rate, w.epos.ravel(), w.evel.ravel()])
        return np.array(out), m

    fast, mf = trace()
    ref, mr = trace(Paths(scalar_avatars=0, scalar_entities=0))
    assert np.array_equal(fast, ref)
    S = cfg.scene.scene_size
    hits = {"n": 0}
    orig = world_mod.World._avatar_walls

    def counting(self):
        hits["n"] += bool(((self.apos < 0.0) | (self.apos > S)).any())
        return orig(self)

    monkeypatch.setattr(world_mod.World, "_avatar_walls", counting)
    trace(Paths(scalar_avatars=0, scalar_entities=0))
    assert hits["n"] > 3                                                     # walls were hit
    assert (np.diff(np.sign(ref[:, 24::2]), axis=0) != 0).sum() > 20        # entities reflected
    assert ref[:, :8].min() >= 0.0 and ref[:, :8].max() <= S


def test_avatars_one_by_one_equal_the_array_code():
    """Resting (with -0.0 speeds), driving into the walls and reversing: the same arrays and
    the same fixed-point decision as the array code's sub-step loop."""
    cfg = NetworkConfig.from_flat(groups=5, render_nodes=1, entities=0, scene_size=15.0, avatar_start="uniform", seed=2)

    def trace(paths=Paths()):
        w = World(cfg, np.random.default_rng(2), paths)
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
    plain, _ = trace(Paths(scalar_avatars=0))
    assert np.array_equal(fast, plain)
    S = cfg.scene.scene_size
    xy = plain[:, :10]
    assert ((xy == 0.0) | (xy == S)).any()                 # the walls were hit
    assert fast_fixed[1:19] == [True] * 18                 # resting at first: a fixed point (after the
    assert not any(fast_fixed[20:110])                     # first advance normalised the headings)


def test_point_index_contacts_equal_kd_tree_contacts():
    cfg = NetworkConfig.from_flat(groups=40, render_nodes=1, entities=600, scene_size=60.0, seed=8)
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
