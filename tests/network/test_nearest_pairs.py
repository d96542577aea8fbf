"""The nearest avatar and the avatar-entity pairs within reach, by every pair in numpy: the same
indices, pairs and pair order as scipy's k-d tree (``cKDTree.query``, ``query_ball_tree``),
which the model keeps only for scenes too large for every pair; and a small scene's run with
contacts imports no ``scipy.spatial``."""
import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial import cKDTree

from immersim.models.network import NetworkConfig, NetworkModel, Paths
from immersim.models.network.ownership import nearest
from immersim.models.network.world import ball_pairs


@pytest.mark.parametrize("seed", range(4))
def test_nearest_is_the_k_d_trees_nearest(seed):
    gen = np.random.default_rng(seed)
    for _ in range(50):
        pts = gen.uniform(0.0, 100.0, (int(gen.integers(1, 12)), 2))
        q = gen.uniform(-10.0, 110.0, (int(gen.integers(0, 60)), 2))
        assert np.array_equal(nearest(q, pts), cKDTree(pts).query(q)[1])


def _tree_pairs(a, b, r):
    lists = cKDTree(a).query_ball_tree(cKDTree(b), r)
    return [g for g, lst in enumerate(lists) for _ in lst], [e for lst in lists for e in lst]


@pytest.mark.parametrize("seed", range(4))
def test_ball_pairs_are_the_k_d_trees_pairs_in_its_order(seed):
    gen = np.random.default_rng(seed)
    for k in range(60):
        if k % 2:   # integer grid: many pairs exactly r apart (the bound is inclusive)
            a = gen.integers(0, 8, (int(gen.integers(1, 8)), 2)).astype(float)
            b = gen.integers(0, 8, (int(gen.integers(1, 80)), 2)).astype(float)
            r = float(gen.integers(1, 4))
        else:
            a = gen.uniform(0.0, 30.0, (int(gen.integers(1, 8)), 2))
            b = gen.uniform(0.0, 30.0, (int(gen.integers(1, 200)), 2))
            r = float(gen.uniform(0.5, 6.0))
        ai, ei = ball_pairs(a, b, r)
        assert (ai.tolist(), ei.tolist()) == _tree_pairs(a, b, r)


def test_initial_owners_by_every_pair_equal_the_k_d_trees():
    cfg = NetworkConfig.from_flat(groups=6, render_nodes=1, entities=300, scene_size=60.0, avatar_start="uniform",
                                  seed=3, ownerless=False)   # (the nearest avatar owns every entity)
    brute, tree = NetworkModel(cfg), NetworkModel(cfg, Paths(brute_owners=-1))
    assert np.array_equal(brute.owner, tree.owner)
    assert len(set(brute.owner[6:].tolist())) == 6


@pytest.mark.parametrize("groups", [3, 10])
def test_a_small_scene_with_contacts_imports_no_scipy_spatial(groups):
    """3 avatars, and 10 (campus_drive8's kind of scene: at most 4096 avatar-entity pairs)."""
    code = f"""
import sys
import numpy as np
from immersim.models.network import NetworkConfig, NetworkModel
m = NetworkModel(NetworkConfig.from_flat(groups={groups}, render_nodes=2, entities=16, driven_groups={groups}, seed=0))
w = m.world
for k in range(60):
    w.epos[k % 16] = w.apos[k % {groups}] + [2.5, 0.0]     # an entity inside an avatar's reach every frame
    m.step(0.033)
assert m.metrics.contacts + m.world.separated > 0
print("scipy.spatial" in sys.modules)
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False"]
