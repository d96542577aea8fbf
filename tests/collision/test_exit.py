"""Ground-plane exit of a deep contact: depth and normal out of the nearest face (exit.py)."""
import math
from functools import lru_cache

import numpy as np
import pytest

from immersim.models.collision import BackendConfig, make_backend, parse_scene
from immersim.models.collision.exit import edge_normals, exit_2d, polygon

# tank footprint (hull box, body frame): x in [-3.25, 4.9] (barrel tip), hull y in [-1.7, 1.7]
SCENE = "box:name=av,sx=4,sy=2,sz=4.4,dynamic=1;tank:name=t,tris=5.4k,x=0,y=0,yaw=0"


@lru_cache(maxsize=1)
def _scene():
    return parse_scene(SCENE)     # (backends read the scene, never change it)


def _square(cx, cy, hx, hy, yaw=0.0):
    c, s = math.cos(yaw), math.sin(yaw)
    P = np.array([[cx + c * u - s * v, cy + s * u + c * v] for u, v in ((-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy))])
    return P, edge_normals(P)


def test_exit_of_two_rectangles_is_the_smallest_overlap_along_a_face_normal():
    B = _square(0.0, 0.0, 3.0, 1.0)
    A, nA = _square(0.5, 0.6, 1.0, 0.5)     # 0.9 m into B's top face, 3.5 m from its right end
    depth, n = exit_2d(A, nA, [B])
    assert depth == pytest.approx(0.9, abs=1e-12) and np.allclose(n, [0.0, 1.0])
    A, nA = _square(2.7, 0.0, 1.0, 0.5)     # 1.3 m into the right end, 1.5 m below the top
    depth, n = exit_2d(A, nA, [B])
    assert depth == pytest.approx(1.3, abs=1e-12) and np.allclose(n, [1.0, 0.0])
    assert exit_2d(*_square(5.0, 0.0, 1.0, 0.5), [B]) is None          # apart


def test_exit_of_a_rotated_box_matches_its_corner_depth():
    B = _square(0.0, 0.0, 3.0, 1.0)
    w = 0.3
    A, nA = _square(0.0, 2.0, 2.0, 1.0, w)
    depth, n = exit_2d(A, nA, [B])
    # the lowest corner of the rotated box is 2 sin w + cos w below its centre
    assert depth == pytest.approx(1.0 - (2.0 - 2.0 * math.sin(w) - math.cos(w)), abs=1e-12)
    assert np.allclose(n, [0.0, 1.0])


def test_exit_clears_every_overlapping_part():
    parts = [_square(0.0, 0.0, 1.0, 1.0), _square(0.0, 1.5, 0.5, 0.5)]  # a box with a knob on top
    A, nA = _square(0.0, 2.3, 1.0, 0.5)
    depth, n = exit_2d(A, nA, parts)
    assert np.allclose(n, [0.0, 1.0]) and depth == pytest.approx(0.2, abs=1e-12)   # 2.0 - 1.8


def test_polygon_is_counter_clockwise_convex_hull():
    P = polygon(np.array([[0, 0], [1, 0], [1, 1], [0, 1], [0.5, 0.5]], float))
    assert len(P) == 4
    area = 0.5 * np.sum(P[:, 0] * np.roll(P[:, 1], -1) - np.roll(P[:, 0], -1) * P[:, 1])
    assert area == pytest.approx(1.0)


@pytest.mark.parametrize("y, yaw, depth", [(2.6, 0.0, 0.1), (2.4, 0.0, 0.3), (1.5, 0.0, 1.2), (1.0, 0.0, 1.7),
                                           (2.0, 0.3, 1.7 - (2.0 - 2 * math.sin(0.3) - math.cos(0.3)))])
def test_horizontal_pair_reports_the_exit_out_of_the_nearest_face(y, yaw, depth):
    """A fresh contact (no contact-free step before it) deep in the tank's side face: fcl's
    triangle contact has a depth of at most ~0.16 m (one grid triangle) and, rotated, a tilted
    normal; the pair reports the body's exit: the hull's side face normal and the full depth."""
    be = make_backend("fcl", _scene(), "av vs t (horizontal)", BackendConfig(max_distance=2.0))
    r = be.query([0.0, y, 2.5, 0.0, 0.0, yaw], 0.033).pairs[0]
    assert r.in_contact
    assert r.depth == pytest.approx(depth, abs=1e-9)
    assert np.allclose(r.normal, [0.0, 1.0, 0.0], atol=1e-12)


def test_fcl_alone_gives_triangle_depths_and_vertical_normals():
    """What the exit replaces (documents fcl's contact on this mesh): the deepest triangle
    contact of the same 1.7 m deep, 0.3 rad rotated box."""
    import fcl

    from immersim.models.collision.fcl_backend import bvh_model, fcl_transform
    from immersim.models.collision.geometry import pose_matrix

    scene = _scene()
    objs = [fcl.CollisionObject(bvh_model(np.asarray(scene.mesh(i).vertices), np.asarray(scene.mesh(i).faces)),
                                fcl_transform(T)) for i, T in enumerate(
        [pose_matrix((0.0, 2.0, 2.5, 0.0, 0.0, 0.3)), pose_matrix((0.0, 0.0, 0.0, 0.0, 0.0, 0.0))])]
    res = fcl.CollisionResult()
    fcl.collide(objs[1], objs[0], fcl.CollisionRequest(num_max_contacts=32, enable_contact=True), res)
    c = max(res.contacts, key=lambda c: c.penetration_depth)
    assert res.is_collision and c.penetration_depth < 0.2     # one grid triangle; the body is 1.25 m deep
    assert abs(c.normal[2]) == pytest.approx(1.0)             # a cap triangle's normal, not the side face's


def test_the_exit_goes_the_short_way_near_the_end_face():
    """A box entering the tank's rear end (x = -3.25) 0.4 m deep is pushed out along -x, not
    across the 3.4 m wide hull."""
    be = make_backend("fcl", _scene(), "av vs t (horizontal)", BackendConfig(max_distance=2.0))
    r = be.query([-3.25 - 2.0 + 0.4, 0.0, 2.5, 0.0, 0.0, 0.0], 0.033).pairs[0]
    assert r.in_contact and r.depth == pytest.approx(0.4, abs=1e-9)
    assert np.allclose(r.normal, [-1.0, 0.0, 0.0], atol=1e-12)


def _first_free(A, nA, parts, u, t_max=20.0):
    """Independent of exit_2d: the smallest t >= 0 at which ``A + t u`` overlaps no part, from
    the separating-axis test on the axes of ``A`` and each part (for each part the open
    interval of t where every axis's projections overlap)."""
    spans = []
    for B, nB in parts:
        lo, hi = -np.inf, np.inf
        for n in np.concatenate([nA, nB]):
            a, b, un = A @ n, B @ n, float(u @ n)
            # overlap along n: min(A.n) + t un < max(B.n) and max(A.n) + t un > min(B.n)
            if abs(un) < 1e-15:
                if not (a.min() < b.max() and a.max() > b.min()):
                    lo, hi = np.inf, -np.inf
                continue
            t1, t2 = (b.max() - a.min()) / un, (b.min() - a.max()) / un
            lo, hi = max(lo, min(t1, t2)), min(hi, max(t1, t2))
        if lo < hi:
            spans.append((lo, hi))
    t = 0.0
    for lo, hi in sorted(spans):
        if lo < t < hi:
            t = hi
    for lo, hi in sorted(spans):      # (a later span may start before the new t)
        if lo < t < hi:
            t = hi
    return t


def test_exit_from_a_concave_corner_is_the_diagonal_not_a_face():
    """A box 0.3 m into a hull's front face and 0.2 m into a barrel's side (an L-shaped
    union): leaving either face alone would end inside the other part (3.8 m or 1.9 m moves);
    the shortest exit is the corner diagonal, hypot(0.3, 0.2), pointing out of both."""
    hull, barrel = _square(0.0, 0.0, 3.25, 1.7), _square(4.9 - 2.0, 0.0, 2.0, 0.1)   # barrel x 2.9 .. 4.9
    A, nA = _square(3.25 + 1.0 - 0.3, 0.1 + 0.5 - 0.2, 1.0, 0.5)
    depth, n = exit_2d(A, nA, [hull, barrel])
    assert depth == pytest.approx(math.hypot(0.3, 0.2), abs=1e-12)
    assert np.allclose(n, np.array([0.3, 0.2]) / math.hypot(0.3, 0.2), atol=1e-12)
    assert exit_2d(A + depth * n, nA, [hull, barrel]) is None                     # touching: apart
    assert exit_2d(A + (depth - 1e-6) * n, nA, [hull, barrel]) is not None


def test_an_exit_never_ends_inside_a_part_it_did_not_overlap():
    """Two blocks 0.3 m apart, a 0.4 m wide box 0.3 m into the left one's right face: moving
    right 0.3 m would end 0.1 m inside the right block (a part apart from the box before the
    move); the exit goes up instead (0.4 m out of the top face)."""
    left, right = _square(0.0, 0.0, 2.0, 2.0), _square(2.3 + 2.0, 0.0, 2.0, 2.0)   # gap x 2.0 .. 2.3
    A, nA = _square(2.0 + 0.2 - 0.3, 2.0 + 0.5 - 0.4, 0.2, 0.5)                     # x 1.7 .. 2.1
    depth, n = exit_2d(A, nA, [left, right])
    assert depth == pytest.approx(0.4, abs=1e-12) and np.allclose(n, [0.0, 1.0], atol=1e-12)


@pytest.mark.parametrize("seed", range(4))
def test_exit_is_the_shortest_move_over_all_directions(seed):
    """Random boxes in random rotated parts: exit_2d's depth is the minimum over 3600
    directions of the first overlap-free distance along each (an independent separating-axis
    ray cast), up to the grid's angular resolution, and its own direction attains it."""
    rng = np.random.default_rng(seed)
    parts = [_square(*rng.uniform(-1.5, 1.5, 2), *rng.uniform(0.3, 1.5, 2), rng.uniform(-np.pi, np.pi))
             for _ in range(3)]
    A, nA = _square(*rng.uniform(-0.5, 0.5, 2), 1.0, 0.5, rng.uniform(-np.pi, np.pi))
    out = exit_2d(A, nA, parts)
    assert out is not None
    depth, n = out
    th = np.linspace(-np.pi, np.pi, 3600, endpoint=False)
    ray = min(_first_free(A, nA, parts, np.array([math.cos(a), math.sin(a)])) for a in th)
    assert depth <= ray + 1e-9 and ray <= depth + 3e-3
    assert _first_free(A, nA, parts, n) == pytest.approx(depth, abs=1e-9)


def test_one_convex_part_exit_is_the_separating_axis_minimum():
    """One overlapped convex part: the exit is the smallest separating-axis overlap over both
    signs of the box's edge normals and the part's, along that axis (a face, never a corner
    point of the Minkowski difference)."""
    rng = np.random.default_rng(11)
    seen = 0
    for _ in range(200):
        B, nB = _square(*rng.uniform(-1, 1, 2), *rng.uniform(0.5, 2.0, 2), rng.uniform(-np.pi, np.pi))
        A, nA = _square(*rng.uniform(-1, 1, 2), 1.0, 0.5, rng.uniform(-np.pi, np.pi))
        out = exit_2d(A, nA, [(B, nB)])
        if out is None:
            continue
        axes = np.concatenate([nA, -nA, nB])
        push = np.array([max(B @ n) - min(A @ n) for n in axes])
        k = int(np.argmin(push))
        assert out[0] == pytest.approx(push[k], rel=1e-12, abs=1e-12)
        assert np.min(np.hypot(*(axes - out[1]).T)) == 0.0         # one of the axes exactly
        seen += 1
    assert seen > 100
