"""Consistency-control formulas (§3.3, §3.6.2, §3.6.3) against brute force and closed forms.

Grid: the 9-cell neighbourhood of every cell (corners and edges included) against the set of
cells ``(i + di, j + dj)`` inside the grid, through every code path. Ownership: nearest /
smallest Mahalanobis distance, ties at exactly equal distance to the lower avatar index.
"""
import math

import numpy as np
import pytest

from immersim.models.network import consistency as cons
from immersim.models.network.consistency import (PointIndex, SceneGrid, assign_owners, covariance, dead_reckon,
                                                 ellipsoid_axes, mahalanobis_ellipsoid)


def _brute_neighbourhood(c, C):
    i, j = divmod(c, C)
    return {(i + di) * C + (j + dj) for di in (-1, 0, 1) for dj in (-1, 0, 1)
            if 0 <= i + di < C and 0 <= j + dj < C}


@pytest.mark.parametrize("C", [1, 2, 5, 8])
def test_nine_cell_neighbourhood_of_every_cell_is_the_brute_force_set(C):
    g = SceneGrid(100.0, C)
    for c in range(C * C):
        got = {int(x) for x in g.neigh[c] if x >= 0}
        assert got == _brute_neighbourhood(c, C), c
        assert len(got) == (min(c // C + 1, C - 1) - max(c // C - 1, 0) + 1) * (min(c % C + 1, C - 1) - max(c % C - 1, 0) + 1)
    a, b = np.divmod(np.arange(C ** 4), C * C)
    adj = g.adjacent(a, b)
    np.testing.assert_array_equal(adj, [int(y) in _brute_neighbourhood(int(x), C) for x, y in zip(a, b)])


@pytest.mark.parametrize("scalar", [True, False])
def test_view_pairs_of_objects_in_every_cell_are_the_brute_force_pairs(scalar):
    """One viewer and two objects in every cell of a 6 x 6 grid: the view pairs are exactly the
    (viewer, object) pairs whose cells are neighbours, in the small (Python) and the array path."""
    C = 6
    g = SceneGrid(60.0, C, scalar_pairs=10 ** 9 if scalar else -1)
    viewers = np.arange(C * C)
    objects = np.repeat(np.arange(C * C), 2)
    v, o = g.view_pairs(viewers, objects)
    got = set(zip(v.tolist(), o.tolist()))
    expected = {(vi, oi) for vi in range(C * C) for oi in range(len(objects))
                if int(objects[oi]) in _brute_neighbourhood(vi, C)}
    assert got == expected and len(v) == len(expected)
    assert np.all(np.diff(v) >= 0)      # sorted by viewer


@pytest.mark.parametrize("scalar", [True, False])
def test_pairs_entering_the_view_are_those_not_adjacent_before(scalar):
    """Of the pairs in view now, those whose viewer was offline or whose cells were not
    neighbours before."""
    C = 5
    g = SceneGrid(50.0, C, scalar_pairs=10 ** 9 if scalar else -1)
    rng = np.random.default_rng(8)
    G, n = 4, 30
    old = rng.integers(0, C * C, n)
    new = np.where(rng.random(n) < 0.5, rng.integers(0, C * C, n), old)
    online = np.array([True, False, True, True])
    vg, vo = np.repeat(np.arange(G), n), np.tile(np.arange(n), G)
    now = np.array([int(new[b]) in _brute_neighbourhood(int(new[a]), C) for a, b in zip(vg, vo)])
    vg, vo = vg[now], vo[now]        # the pairs in view now (viewers are the first G objects)
    got = set(g.not_in_view(old, online, new, vg, vo).tolist())
    expected = {p for p, (a, b) in enumerate(zip(vg, vo))
                if not (online[a] and int(old[b]) in _brute_neighbourhood(int(old[a]), C))}
    assert got == expected


@pytest.mark.parametrize("use_list", [True, False])
def test_cell_index_is_the_truncated_quotient_clipped_to_the_grid(use_list):
    g = SceneGrid(10.0, 4)
    pos = np.array([[0.0, 0.0], [2.49, 2.51], [9.99, 0.1], [10.0, 10.0], [-3.0, 5.0], [5.0, 42.0], [7.5, 2.5]])
    got = g.cell(pos.copy(), pos.tolist() if use_list else None)
    ij = [(min(max(int(x / 10.0 * 4), 0), 3), min(max(int(y / 10.0 * 4), 0), 3)) for x, y in pos]
    np.testing.assert_array_equal(got, [i * 4 + j for i, j in ij])
    np.testing.assert_array_equal(got, [0, 1, 12, 15, 2, 11, 13])


# -- ownership ------------------------------------------------------------------------------
PATHS = ("scalar", "brute", "kdtree", "pointindex")


def _owners(path, rule, apos, avel, epos, current, **kw):
    kw = dict(frame_s=0.033, scale=30.0, min_axis=5.0, scalar_pairs=10 ** 9 if path == "scalar" else -1,
              brute_pairs=10 ** 9 if path == "brute" else -1) | kw
    etree = None
    if path == "kdtree":
        from scipy.spatial import cKDTree
        etree = cKDTree(epos)
    elif path == "pointindex":
        etree = PointIndex(epos)
    return assign_owners(rule, apos, avel, epos, current, etree=etree, **kw)


@pytest.mark.parametrize("path", PATHS)
@pytest.mark.parametrize("rule", ["euclidean", "mahalanobis"])
@pytest.mark.parametrize("flip", [False, True])
def test_ownership_tie_at_exactly_equal_distance_goes_to_the_lower_index(path, rule, flip):
    """Two resting avatars 2 m either side of an entity (distances exactly 2.0 each, in either
    rule): the lower avatar index owns it, whichever side it is on; a third entity nearer to
    avatar 1 goes to avatar 1; one out of reach keeps its current owner."""
    left, right = [3.0, 5.0], [7.0, 5.0]
    apos = np.array([right, left] if flip else [left, right])
    avel = np.zeros((2, 2))
    epos = np.array([[5.0, 5.0], [(7.5 if not flip else 2.5), 5.0], [40.0, 40.0]])
    current = np.array([-1, -1, 7])
    out = _owners(path, rule, apos, avel, epos, current)
    np.testing.assert_array_equal(out, [0, 1, 7])


@pytest.mark.parametrize("path", PATHS)
def test_ownership_is_the_nearest_avatar_within_reach_by_brute_force(path):
    rng = np.random.default_rng(21)
    apos = rng.uniform(0, 60, (6, 2))
    avel = rng.normal(scale=3.0, size=(6, 2))
    epos = rng.uniform(0, 60, (40, 2))
    current = np.full(40, -1)
    out = _owners(path, "euclidean", apos, avel, epos, current, min_axis=8.0)
    a = np.maximum(np.linalg.norm(avel, axis=1) * 0.033 * 30.0, 8.0)
    d = np.linalg.norm(epos[:, None, :] - apos[None, :, :], axis=2)
    d = np.where(d <= a[None, :], d, np.inf)
    expected = np.where(np.isfinite(d.min(axis=1)), d.argmin(axis=1), -1)
    np.testing.assert_array_equal(out, expected)
    assert len(set(expected.tolist())) > 2 and (expected == -1).any()


@pytest.mark.parametrize("foci", ["frame", "reach"])
def test_control_ellipsoid_axes_eq_3_11_3_12(foci):
    vel = np.array([[3.0, 4.0], [0.0, 0.0], [-0.1, 0.0]])
    a, b, u, shift = ellipsoid_axes(vel, 0.04, 30.0, 2.0, foci)
    D = np.array([5.0, 0.0, 0.1]) * 0.04
    np.testing.assert_allclose(a, np.maximum(D * 30.0, 2.0))
    focal = D * 30.0 if foci == "reach" else D
    np.testing.assert_allclose(b, np.sqrt(a ** 2 - (focal / 2) ** 2))
    np.testing.assert_allclose(u, [[0.6, 0.8], [1.0, 0.0], [-1.0, 0.0]])
    np.testing.assert_allclose(shift, focal[:, None] / 2 * u)


def test_mahalanobis_distance_is_r_sigma_inverse_r():
    rng = np.random.default_rng(4)
    for _ in range(20):
        u = rng.normal(size=3)
        u /= np.linalg.norm(u)
        a, b = 3.0 + rng.random(), 1.0 + rng.random()
        x, c = rng.normal(size=3) * 3, rng.normal(size=3)
        r = x - c
        expected = math.sqrt(r @ np.linalg.solve(covariance(u, a, b), r))
        assert mahalanobis_ellipsoid(x, c, u, np.array(a), np.array(b)) == pytest.approx(expected, rel=1e-12)
    S = covariance(np.array([0.0, 2.0, 0.0]), 3.0, 1.0)
    np.testing.assert_allclose(S, np.diag([1.0, 9.0, 1.0]))


@pytest.mark.parametrize("order", [0, 1, 2])
def test_dead_reckoning_orders(order):
    p = np.array([[1.0, 2.0], [-3.0, 0.5]])
    v = np.array([[0.5, -1.0], [2.0, 0.0]])
    a = np.array([[1.0, 4.0], [0.0, -2.0]])
    dt = np.array([0.1, 0.3])
    expected = p + (order >= 1) * v * dt[:, None] + (order >= 2) * 0.5 * a * dt[:, None] ** 2
    np.testing.assert_allclose(dead_reckon(p, v, a, dt, order), expected, rtol=1e-15)


@pytest.mark.parametrize("cells", [1, 2, 5, 10])
def test_small_view_pairs_equal_the_array_code(cells):
    grid, plain = cons.SceneGrid(100.0, cells, True), cons.SceneGrid(100.0, cells, True, scalar_pairs=-1)
    gen = np.random.default_rng(cells)
    cases = [(gen.integers(0, cells * cells, gen.integers(0, 12)), gen.integers(0, cells * cells, gen.integers(0, 20)))
             for _ in range(200)]
    fast = [grid.view_pairs(v, o) for v, o in cases]
    for (v, o), (a, b) in zip(cases, fast):
        ra, rb = plain.view_pairs(v, o)
        assert np.array_equal(a, ra) and np.array_equal(b, rb) and a.dtype == ra.dtype and b.dtype == rb.dtype


@pytest.mark.parametrize("cells", [1, 3, 10])
def test_small_view_entries_equal_the_array_code(cells):
    grid, plain = cons.SceneGrid(100.0, cells, True), cons.SceneGrid(100.0, cells, True, scalar_pairs=-1)
    gen = np.random.default_rng(cells)
    cases = []
    for _ in range(300):
        G, O = int(gen.integers(1, 5)), int(gen.integers(0, 10))
        old = gen.integers(0, cells * cells, G + O)
        new = np.where(gen.random(G + O) < 0.3, gen.integers(0, cells * cells, G + O), old)   # some moved
        k = int(gen.integers(0, 40))
        cases.append((old, gen.random(G) < 0.7, new, gen.integers(0, G, k), gen.integers(0, G + O, k)))
    fast = [grid.not_in_view(*c) for c in cases]
    assert sum(len(f) for f in fast) > 100
    for c, f in zip(cases, fast):
        ref = plain.not_in_view(*c)
        assert np.array_equal(f, ref) and f.dtype == ref.dtype


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
