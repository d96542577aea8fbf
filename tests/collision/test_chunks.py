"""Chunked exact distances (models/collision/chunks.py) against the whole-mesh fcl query."""
import math

import fcl
import numpy as np
import pytest
import trimesh

from immersim.models.collision import BackendConfig, make_backend, parse_scene
import immersim.models.collision.chunks as chunks_mod
from immersim.models.collision.chunks import ChunkedMesh, chunk_lower_bounds, split_faces
from immersim.models.collision.fcl_backend import fcl_transform
from immersim.models.collision.geometry import pose_matrix
from immersim.models.collision.scene import make_tank

# a yawed 5.4k tank and three kinds of other body (the campus_drive avatar box, the missile, a ball)
SPEC = ("tank:name=t,tris=5.4k,yaw=2.2408;box:name=box,sx=4,sy=2,sz=4.4,dynamic=1,x=30;"
        "box:name=stick,sx=0.3,sy=0.5,sz=1.5,dynamic=1,x=-30;sphere:name=ball,r=1,dynamic=1,y=30")


def test_split_faces_partitions_every_triangle_once():
    tank = make_tank(5442)
    groups = split_faces(tank.vertices, tank.faces, 32)
    assert max(len(g) for g in groups) <= 32
    np.testing.assert_array_equal(np.sort(np.concatenate(groups)), np.arange(len(tank.faces)))
    # compact: the chunks' boxes are far smaller than the tank's
    chunks = ChunkedMesh(tank.vertices, tank.faces, 32)
    assert np.median(2 * chunks.half.max(1)) < 0.25 * tank.extents.max()


def test_chunk_parts_and_boxes_are_those_of_the_faces_they_hold():
    tank = make_tank(5442)
    chunks = ChunkedMesh(tank.vertices, tank.faces, 32)
    V, F = np.asarray(tank.vertices, float), np.asarray(tank.faces, np.int64)
    assert chunks.parts == [None] * len(chunks)   # made when first visited
    for i, idx in enumerate(chunks.faces):
        Vc, Fc = chunks.part(i)
        np.testing.assert_array_equal(Vc[Fc], V[F[idx]])     # the same triangles, local indices
        assert len(Vc) == len(np.unique(F[idx]))              # only the vertices they use
        lo, hi = Vc.min(0), Vc.max(0)
        assert chunks.centre[i].tobytes() == ((lo + hi) / 2).tobytes()
        assert chunks.half[i].tobytes() == ((hi - lo) / 2).tobytes()
    assert chunks.part(3) is chunks.part(3)


def test_chunk_bounds_are_lower_bounds_of_each_chunk_distance():
    rng = np.random.default_rng(7)
    tank = make_tank(5442)
    chunks = ChunkedMesh(tank.vertices, tank.faces, 32)
    other = trimesh.creation.box((4, 2, 4.4))
    obj = fcl.CollisionObject(_bvh(other), fcl.Transform())
    T_big = pose_matrix([1.0, -2.0, 0.0, 0.0, 0.0, 0.7])
    hull = np.asarray(other.vertices, float)
    centre, half = np.zeros(3), np.array([2.0, 1.0, 2.2])
    req = fcl.DistanceRequest()
    checked = 0
    for _ in range(20):
        T = pose_matrix([*rng.uniform(-8, 8, 2), rng.uniform(0, 4), *rng.uniform(-0.5, 0.5, 2), rng.uniform(-3, 3)])
        obj.setTransform(fcl_transform(T))
        lb, _, _ = chunk_lower_bounds(chunks, T_big, T, hull, centre, half)
        for i in np.argsort(lb)[:15]:
            chunks.obj(i).setTransform(fcl_transform(T_big))
            d = fcl.distance(chunks.obj(i), obj, req, fcl.DistanceResult())
            if d > 0:
                assert lb[i] <= d + 1e-12
                checked += 1
    assert checked > 100


def _bvh(mesh):
    g = fcl.BVHModel()
    g.beginModel(len(mesh.vertices), len(mesh.faces))
    g.addSubModel(np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64))
    g.endModel()
    return g


@pytest.mark.parametrize("body", ["box", "stick", "ball"])
def test_chunked_distances_equal_the_whole_mesh_path_on_random_poses(body):
    """Random poses around the tank (contacts, near misses, far): the chunked path reports the
    same contact flags, depths, contact points and partners, the same distances to 1e-9 m and
    normals to 1e-6; its nearest point is a true nearest point (at the reported distance from
    the tank, and ``p - d n`` on the tank) even where it is another one than the whole-mesh
    query's (parallel features: the nearest points are not unique). The ball (1280 triangles,
    more than CHUNK_OTHER_MAX_FACES) keeps the whole-mesh query: identical outputs."""
    rng = np.random.default_rng({"box": 1, "stick": 2, "ball": 3}[body])
    chunked = make_backend("fcl", parse_scene(SPEC), f"{body} vs t", BackendConfig(max_distance=2.0))
    mesh = make_backend("fcl", parse_scene(SPEC), f"{body} vs t", BackendConfig(max_distance=2.0, chunk_faces=0))
    tank = chunked.scene.mesh(0).copy()
    tank.apply_transform(chunked.T[0])
    dyn = [chunked.scene.bodies[i].name for i in chunked.scene.dynamic]
    k_body = dyn.index(body)
    rest = np.array([[30.0, 0, 0, 0, 0, 0], [-30.0, 0, 0, 0, 0, 0], [0, 30.0, 0, 0, 0, 0]])
    seen = {"contact": 0, "near": 0, "far": 0}
    for _ in range(60):
        poses = rest.copy()
        poses[k_body] = [*rng.uniform(-6.5, 6.5, 2), rng.uniform(-1, 6), *rng.uniform(-0.6, 0.6, 2),
                         rng.uniform(-math.pi, math.pi)]
        rc, rm = chunked.query(poses).pairs[0], mesh.query(poses).pairs[0]
        assert (rc.in_contact, rc.depth, rc.partner) == (rm.in_contact, rm.depth, rm.partner)
        assert abs(rc.distance - rm.distance) <= 1e-9
        np.testing.assert_allclose(rc.normal, rm.normal, atol=1e-6)
        np.testing.assert_allclose(rc.toi, rm.toi, atol=1e-9)
        if body == "ball":
            assert _same(rc, rm)
        if rc.in_contact:
            np.testing.assert_array_equal(rc.point, rm.point)
            seen["contact"] += 1
        elif rc.distance < 2.0:
            q = rc.point - rc.distance * rc.normal  # on the tank
            _, dq, _ = trimesh.proximity.closest_point(tank, [q])
            assert dq[0] < 1e-7
            _, dp, _ = trimesh.proximity.closest_point(tank, [rc.point])
            assert dp[0] >= rc.distance - 1e-7  # the point is on the body, at >= the distance
            seen["near"] += 1
        else:
            seen["far"] += 1
    assert seen["contact"] and seen["near"], seen


def test_chunked_distance_within_a_bound_equals_the_full_order():
    """``chunked_distance`` bounding only the chunks nearer than ``within`` (a bound above the
    distance) gives the same distance and nearest points as the full order bit for bit, and so
    does a ``within`` below the distance (not a bound: the full order is visited then); the
    backend's upper bounds from the last exact distance plus the motion since are bounds."""
    from immersim.models.collision.chunks import chunked_distance

    be = make_backend("fcl", parse_scene(SPEC), "box vs t", BackendConfig(max_distance=2.0))
    t, box = 0, 1
    chunks = be.shapes.chunks[t]
    tf_t = fcl_transform(be.T[t])
    obj = fcl.CollisionObject(be.fclo.dgeoms[be.scene.bodies[box].mesh_key], fcl.Transform())
    other_box = (be.shapes.hull[box], be.shapes.box_c[box], be.shapes.box_h[box])
    req = fcl.DistanceRequest(enable_nearest_points=True)
    rng = np.random.default_rng(8)
    subsets = 0
    for k in range(40):
        T = pose_matrix([*rng.uniform(-6.5, 6.5, 2), rng.uniform(0, 5), 0, 0, rng.uniform(-math.pi, math.pi)])
        obj.setTransform(fcl_transform(T))
        out = []
        for within in (math.inf, None, 0.5, 0.0):
            res = fcl.DistanceResult()
            if within is None:  # just above the distance, as the backend's upper bound would be
                within = out[0][0] + 1e-9
            n_bounded = []
            real = chunks_mod.chunk_lower_bounds
            chunks_mod.chunk_lower_bounds = lambda *a, **kw: (lambda r: n_bounded.append(len(r[0])) or r)(real(*a, **kw))
            try:
                chunked_distance(chunks, ("w", k, within), tf_t, be.T[t], T, other_box, obj, True, req, res, within)
            finally:
                chunks_mod.chunk_lower_bounds = real
            out.append((res.min_distance, [np.asarray(q).tolist() for q in res.nearest_points]))
            subsets += within < 1 and n_bounded[0] < len(chunks)
        assert all(o == out[0] for o in out), k
    assert subsets > 20
    # the backend's upper bound (last distance plus the motion since) along a walk towards the tank
    T0 = [9.0, 0.3, 2.5, 0, 0, 0.6]
    for k in range(25):
        pose = [[T0[0] - 0.12 * k, 0.3 + 0.01 * k, 2.5, 0, 0, 0.6 + 0.03 * k]] + [[30.0, 0, 0, 0, 0, 0], [0, 30.0, 0, 0, 0, 0]]
        before = be.exact.since(box, t)
        r = be.query(pose).pairs[0]
        if before is not None and 0 < r.distance < 2.0:
            assert r.distance <= before[1]


def test_chunked_time_of_impact_equals_the_whole_mesh_path():
    """A thin box diving fast onto a tank (conservative advancement on chunk distances; the
    missile, 192 triangles, keeps the whole-mesh query): the same time of impact to 1e-9 s
    and the same contacts, step by step."""
    spec = "tank:name=t,tris=5.4k,yaw=0.3;box:name=s,sx=0.3,sy=0.5,sz=1.5,dynamic=1,x=-6,z=9"
    chunked = make_backend("fcl", parse_scene(spec), "s vs t", BackendConfig(max_distance=2.0))
    mesh = make_backend("fcl", parse_scene(spec), "s vs t", BackendConfig(max_distance=2.0, chunk_faces=0))
    tois = []
    for k in range(40):
        pose = [[-6 + 0.18 * k, 0.3, max(9 - 0.35 * k, 2.5), 0.1, 0.564, 0.02 * k]]
        rc, rm = chunked.query(pose).pairs[0], mesh.query(pose).pairs[0]
        assert (rc.in_contact, rc.partner) == (rm.in_contact, rm.partner)
        assert abs(rc.toi - rm.toi) <= 1e-9
        assert abs(rc.distance - rm.distance) <= 1e-9
        tois.append(rc.toi)
    assert max(tois) > 0  # an impact inside a step was found


def test_a_missile_keeps_the_whole_mesh_query():
    spec = "tanks:n=4,tris=5.4k,spacing=12;missile:x=0,y=0,z=9,pitch=0.564"
    chunked = make_backend("fcl", parse_scene(spec), "missile vs any tank", BackendConfig(max_distance=2.0))
    mesh = make_backend("fcl", parse_scene(spec), "missile vs any tank",
                        BackendConfig(max_distance=2.0, chunk_faces=0))
    for k in range(30):
        pose = [[0.2 * k, 0.3, max(9 - 0.25 * k, 2.0), 0, 0.564, 0]]
        assert _same(chunked.query(pose).pairs[0], mesh.query(pose).pairs[0])


def _same(p, q):
    """Exact equality of two PairResults."""
    return ((p.in_contact, p.distance, p.depth, p.toi, p.closing_speed, p.partner, p.point.tolist(), p.normal.tolist())
            == (q.in_contact, q.distance, q.depth, q.toi, q.closing_speed, q.partner, q.point.tolist(), q.normal.tolist()))


def test_chunk_transform_cache_and_state_roll_back_change_no_output():
    """A moving chunked tank and a box: the chunks' cached transforms (set only when they hold
    another body's or an older pose) give the same outputs as setting them before every query,
    and rolling the model state back and replaying gives the same outputs again."""
    spec = "tank:name=t,tris=5.4k,dynamic=1;box:name=box,sx=4,sy=2,sz=4.4,dynamic=1,x=9"
    cached = make_backend("fcl", parse_scene(spec), "box vs t", BackendConfig(max_distance=2.0))
    fresh = make_backend("fcl", parse_scene(spec), "box vs t", BackendConfig(max_distance=2.0))

    def poses(k):
        return [[0.05 * k, 0.02 * k, 0, 0, 0, 0.01 * k], [9 - 0.12 * k, 0.3, 2.5, 0, 0, 0.6 + 0.02 * k]]

    out, snapshot = [], None
    for k in range(40):
        for chunks in fresh.shapes.chunked.values():
            chunks.tag = [None] * len(chunks)
        rc, rf = cached.query(poses(k)).pairs[0], fresh.query(poses(k)).pairs[0]
        assert _same(rc, rf)
        out.append(rc)
        if k == 19:
            snapshot = cached.get_state()
    assert any(r.in_contact for r in out) and any(0 < r.distance < 2 for r in out)
    cached.set_state(snapshot)
    for k in range(20, 40):
        assert _same(cached.query(poses(k)).pairs[0], out[k])



def test_chunk_bvhs_built_when_first_visited_give_the_outputs_of_all_built_up_front():
    """A chunk's BVH is built when a query first visits it: a new backend has built none, a
    walk past the tank builds only the chunks it visits, and every output is the same bit for
    bit as a backend whose chunks were all built before the first query."""
    lazy = make_backend("fcl", parse_scene(SPEC), "box vs t", BackendConfig(max_distance=2.0))
    eager = make_backend("fcl", parse_scene(SPEC), "box vs t", BackendConfig(max_distance=2.0))
    chunks = lazy.shapes.chunks[0]
    assert chunks._objs.count(None) == len(chunks) > 100
    built_up_front = eager.shapes.chunks[0]
    assert all(built_up_front.obj(i) is not None for i in range(len(built_up_front)))
    assert built_up_front._objs.count(None) == 0
    rest = [[-30.0, 0, 0, 0, 0, 0], [0, 30.0, 0, 0, 0, 0]]
    for k in range(40):
        pose = [[9.0 - 0.3 * k, 0.3 + 0.02 * k, 2.5 - 0.03 * k, 0, 0, 0.6 + 0.03 * k]] + rest
        assert _same(lazy.query(pose).pairs[0], eager.query(pose).pairs[0]), k
    built = len(chunks) - chunks._objs.count(None)
    assert 0 < built < len(chunks) // 2
