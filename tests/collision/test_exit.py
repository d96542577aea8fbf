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
