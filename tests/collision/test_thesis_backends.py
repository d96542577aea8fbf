"""The thesis's detectors: their building blocks (ch. 4-5) and their answers against FCL."""
import itertools

import numpy as np
import pytest
import trimesh

from immersim.models.collision import BackendConfig, make_backend, parse_scene
from immersim.models.collision.basis_point import (point_in_triangle_angles, scan_counts,
                                                   threading_features)
from immersim.models.collision.honeycomb import depth_relation, equal_ratio_shrink


@pytest.mark.parametrize("st,strict,floor", [(0.05, 19, 20), (0.1, 9, 10), (0.04, 24, 25), (0.07, 14, 14),
                                             (0.004, 249, 250), (0.01, 99, 100)])
def test_scan_counts_eq_5_11(st, strict, floor):
    assert scan_counts(st, "strict") == strict
    assert scan_counts(st, "floor") == floor  # the DN column of table 5-5 for SCN


def test_threading_special_cases():
    # N = 1, M = 1: a point; N = 1, M = 3: a polyline; N = 3, M = 1: the vertical chain (fig. 5-18)
    assert threading_features(np.array([[4, 2]])) == ([], [], [0])
    assert threading_features(np.array([[3, 1], [1, 1], [2, 1]])) == ([(1, 2), (2, 0)], [], [])
    assert threading_features(np.array([[0, 2], [0, 0], [0, 1]])) == ([(1, 2), (2, 0)], [], [])
    # special case 1 (fig. 5-24): two single-point rows between wider rows give a segment
    grid = np.array([[0, 0], [1, 0], [0, 1], [0, 2], [0, 3], [1, 3]])
    segs, tris, _ = threading_features(grid)
    assert (2, 3) in segs
    # special case 2 (fig. 5-26): a single-point row is the apex of both fans
    grid = np.array([[0, 0], [1, 0], [2, 0], [1, 1], [0, 2], [1, 2], [2, 2]])
    _, tris, _ = threading_features(grid)
    assert sorted(tris) == sorted([(3, 0, 1), (3, 1, 2), (3, 4, 5), (3, 5, 6)])


@pytest.mark.parametrize("rows,cols", [(2, 2), (2, 5), (4, 3), (6, 6)])
def test_threading_tiles_a_regular_grid_without_overlap(rows, cols):
    """On a planar grid the triangles cover the grid's rectangle exactly once."""
    grid = np.array(list(itertools.product(range(cols), range(rows))))
    segs, tris, pts = threading_features(grid)
    assert not segs and not pts
    P = np.c_[grid.astype(float), np.zeros(len(grid))]
    T = P[np.array(tris)]
    area = 0.5 * np.linalg.norm(np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]), axis=1)
    assert area.min() > 0
    assert area.sum() == pytest.approx((rows - 1) * (cols - 1))


def test_angle_sum_inside_test_matches_barycentric():
    rng = np.random.default_rng(0)
    tri = rng.normal(size=(2000, 3, 3))
    w = rng.uniform(-0.3, 1.0, size=(2000, 3))
    w /= w.sum(1, keepdims=True)
    P = np.einsum("ij,ijk->ik", w, tri)
    inside = np.all(w > 1e-3, axis=1)
    outside = np.any(w < -1e-3, axis=1)
    got = point_in_triangle_angles(P, tri)
    assert got[inside].all() and not got[outside].any()


@pytest.mark.parametrize("a,b,rel", [((0, 1), (2, 3), 1), ((2, 3), (0, 1), 2), ((0, 5), (1, 2), 3),
                                     ((1, 4), (0, 2), 4), ((1, 2), (0, 5), 5), ((0, 2), (1, 4), 6),
                                     ((0, 1), (1, 2), 7)])
def test_seven_depth_relations_of_fig_4_1(a, b, rel):
    assert depth_relation(a[0], a[1], b[0], b[1]) == rel


def test_equal_ratio_shrink_stops_on_the_part_from_either_side():
    far = np.array([0.0, 0.0, 5.0])
    near = np.array([1.0, 2.5, 4.0])
    start = np.array([3.0, 3.0, 1.0])  # two sections above their part, one below
    tol = 1e-3 * 3
    sec, it = equal_ratio_shrink(start, near, far, 0.05, 0.001, tol)
    assert np.all(np.abs(sec - near) <= tol + 1e-12)
    assert it > 5
    # D_next = D_last (1 - 0.05) (eq. 4-7): one unconstrained step from D = 3 gives 2.85
    one, _ = equal_ratio_shrink(np.array([3.0]), np.array([-10.0]), np.array([0.0]), max_iter=1)
    assert one[0] == pytest.approx(2.85)


def test_basis_points_lie_on_the_surface_and_cover_the_scan_grid():
    scene = parse_scene("box:name=block,sx=1.0,sy=0.6,sz=0.4;sphere:name=ball,r=0.3,subdiv=2,dynamic=1")
    be = make_backend("basis_point", scene, "ball vs block")
    lo, hi = np.array([-0.5, -0.3, -0.2]), np.array([0.5, 0.3, 0.2])
    bp = be.basis_points(0, lo, hi)
    pts = bp.all_points()
    assert len(pts) == 2 * 3 * be.dn ** 2  # every scan line crosses the box twice
    _, d, _ = trimesh.proximity.closest_point(scene.mesh(0), pts)
    assert d.max() < 1e-9
    # X scans: XL on the face x = -0.5, XR on x = +0.5
    assert np.allclose(bp.pts[0][0][:, 0], -0.5) and np.allclose(bp.pts[0][1][:, 0], 0.5)


def _agreement(backend, n=25, seed=5, **attrs):
    scene = parse_scene("box:name=block,sx=1.0,sy=0.6,sz=0.4;sphere:name=ball,r=0.3,subdiv=2,dynamic=1")
    ref = make_backend("fcl", scene, "ball vs block")
    be = make_backend(backend, scene, "ball vs block")
    for k, v in attrs.items():
        setattr(be, k, v)
    rng = np.random.default_rng(seed)
    fp = fn = tp = 0
    for _ in range(n):
        pose = np.r_[rng.uniform(-0.9, 0.9, 3), rng.uniform(-np.pi, np.pi, 3)]
        exact = ref.query([pose]).pairs[0].in_contact
        got = be.query([pose]).pairs[0].in_contact
        fp += got and not exact
        fn += exact and not got
        tp += got and exact
    return tp, fp, fn


def test_basis_point_agrees_with_fcl_on_contact():
    tp, fp, fn = _agreement("basis_point")
    assert tp >= 3 and fp + fn <= 2


def test_honeycomb_at_rest_agrees_with_fcl_on_contact():
    tp, fp, fn = _agreement("honeycomb", fixed_threshold=0.0)
    assert tp >= 3 and fp + fn <= 2


def test_honeycomb_threshold_predicts_the_next_step():
    """A cube 0.3 m from a wall moving 0.4 m per step is flagged one step early (d = 0.4)."""
    scene = parse_scene("box:name=wall,sx=1,sy=4,sz=4;box:name=cube,sx=1,sy=1,sz=1,dynamic=1,x=3")
    hc = make_backend("honeycomb", scene, "cube vs wall", BackendConfig(honeycomb_axes="separating"))
    fc = make_backend("fcl", scene, "cube vs wall")
    for be in (hc, fc):
        be.query([[3.0, 0, 0, 0, 0, 0]])
        be.query([[2.6, 0, 0, 0, 0, 0]])
    h, f = hc.query([[1.3, 0, 0, 0, 0, 0]]), fc.query([[1.3, 0, 0, 0, 0, 0]])
    assert not f.pairs[0].in_contact and f.pairs[0].distance == pytest.approx(0.3)
    assert h.pairs[0].in_contact  # within one step's travel (d = 1.3 m in this jump)
    assert h.pairs[0].distance == pytest.approx(0.3, abs=0.01)
    assert hc.last_stats["axis"] == 0 and hc.last_stats["cells_full"] == 64
    hc.fixed_threshold = 0.0
    hc.query([[1.31, 0, 0, 0, 0, 0]])
    assert not hc.query([[1.3, 0, 0, 0, 0, 0]]).pairs[0].in_contact


def test_honeycomb_empty_cells_cannot_collide():
    """A ball sunk 5 cm into a plate: only the central cells hold a part of the ball inside
    the depth window; the others have D_ij = -1 and are never tested."""
    scene = parse_scene("box:name=plate,sx=4,sy=4,sz=0.2;sphere:name=ball,r=0.5,subdiv=3,dynamic=1,z=2")
    hc = make_backend("honeycomb", scene, "ball vs plate", BackendConfig(honeycomb_axes="separating"))
    fc = make_backend("fcl", scene, "ball vs plate")
    hc.fixed_threshold = 0.0
    q = hc.query([[1.0, 1.0, 0.65, 0, 0, 0]])  # ball bottom about 0.05 m above the plate
    assert not q.pairs[0].in_contact and q.n_narrow == 0  # AABBs apart: culled
    pose = [1.0, 1.0, 0.55, 0, 0, 0]
    r, exact = hc.query([pose]).pairs[0], fc.query([pose]).pairs[0]
    assert r.in_contact and exact.in_contact
    assert r.depth == pytest.approx(0.05, abs=0.01)
    assert hc.last_stats["relation"] == 4 and 0 < hc.last_stats["cells_full"] < 64
