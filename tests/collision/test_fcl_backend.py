"""Backend ``fcl``: distances against an independent brute force, contacts, skip rules, time of impact."""
import math

import numpy as np
import pytest
import trimesh

from immersim.models.collision import BackendConfig, Shortcuts, make_backend, parse_scene
from immersim.models.collision.geometry import point_triangle_distance, pose_matrix


def segment_distance(p1, q1, p2, q2):
    """Vectorised closest distance between segments p1q1 and p2q2 (Ericson 5.1.9)."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a = np.einsum("ij,ij->i", d1, d1)
    e = np.einsum("ij,ij->i", d2, d2)
    f = np.einsum("ij,ij->i", d2, r)
    c = np.einsum("ij,ij->i", d1, r)
    b = np.einsum("ij,ij->i", d1, d2)
    denom = a * e - b * b
    s = np.where(denom > 1e-15, np.clip((b * f - c * e) / np.where(denom > 1e-15, denom, 1), 0, 1), 0.0)
    t = (b * s + f) / e
    s = np.where(t < 0, np.clip(-c / a, 0, 1), np.where(t > 1, np.clip((b - c) / a, 0, 1), s))
    t = np.clip(t, 0, 1)
    return np.linalg.norm(p1 + d1 * s[:, None] - (p2 + d2 * t[:, None]), axis=1)


def brute_distance(ma: trimesh.Trimesh, mb: trimesh.Trimesh) -> float:
    """Exact distance of two disjoint triangle meshes: vertex-triangle and edge-edge minima."""
    best = math.inf
    for m1, m2 in ((ma, mb), (mb, ma)):
        V, F = m1.vertices, m2.triangles
        P = np.repeat(V, len(F), axis=0)
        Tr = np.tile(F, (len(V), 1, 1))
        best = min(best, point_triangle_distance(P, Tr)[0].min())
    ea, eb = ma.vertices[ma.edges_unique], mb.vertices[mb.edges_unique]
    A = np.repeat(ea, len(eb), axis=0)
    B = np.tile(eb, (len(ea), 1, 1))
    return min(best, segment_distance(A[:, 0], A[:, 1], B[:, 0], B[:, 1]).min())


def posed(scene, i, pose):
    m = scene.mesh(i).copy()
    m.apply_transform(pose_matrix(pose))
    return m


def test_point_triangle_distance_against_trimesh():
    rng = np.random.default_rng(1)
    tri = rng.normal(size=(300, 3, 3))
    p = rng.normal(size=(300, 3)) * 2
    d, c = point_triangle_distance(p, tri)
    for k in range(0, 300, 7):
        mesh = trimesh.Trimesh(tri[k], [[0, 1, 2]], process=False)
        _, dist, _ = trimesh.proximity.closest_point(mesh, p[k:k + 1])
        assert d[k] == pytest.approx(dist[0], abs=1e-9)


def test_distances_match_brute_force_on_random_poses():
    scene = parse_scene("box:name=block,sx=1.0,sy=0.6,sz=0.4;sphere:name=ball,r=0.3,subdiv=1,dynamic=1")
    be = make_backend("fcl", scene, "ball vs block")
    rng = np.random.default_rng(7)
    checked = 0
    for _ in range(40):
        pose = np.r_[rng.uniform(-1.5, 1.5, 3), rng.uniform(-np.pi, np.pi, 3)]
        r = be.query([pose]).pairs[0]
        ball, block = posed(scene, 1, pose), posed(scene, 0, np.zeros(6))
        if r.in_contact:
            assert trimesh.collision.CollisionManager is not None
            continue
        ref = brute_distance(ball, block)
        assert r.distance == pytest.approx(ref, abs=1e-7)
        # the reported point lies on the ball's surface, the normal points from the block to
        # the ball: stepping back along it by the distance lands on the block's surface
        _, dp, _ = trimesh.proximity.closest_point(ball, r.point[None])
        assert dp[0] < 1e-6
        assert np.linalg.norm(r.normal) == pytest.approx(1.0)
        _, db, _ = trimesh.proximity.closest_point(block, (r.point - r.distance * r.normal)[None])
        assert db[0] < 1e-6
        checked += 1
    assert checked >= 15


def test_contact_depth_and_normal_of_an_overlap():
    scene = parse_scene("box:name=floor,sx=10,sy=10,sz=1,z=-0.5;box:name=cube,sx=1,sy=1,sz=1,dynamic=1")
    be = make_backend("fcl", scene, "cube vs floor")
    r = be.query([[0, 0, 0.6, 0, 0, 0]]).pairs[0]
    assert not r.in_contact and r.distance == pytest.approx(0.1)
    assert r.normal == pytest.approx([0, 0, 1])  # from the floor (B) up to the cube (A)
    r = be.query([[0, 0, 0.4, 0, 0, 0]]).pairs[0]
    assert r.in_contact and r.distance == 0.0
    assert r.depth == pytest.approx(0.1, abs=1e-6)
    assert r.normal == pytest.approx([0, 0, 1], abs=1e-12)  # the last separating direction
    assert r.closing_speed == pytest.approx(0.2 / 0.033, rel=1e-6)


def test_contact_keeps_the_separating_direction_of_the_last_free_step():
    """A cube sinks into the corner of a step-shaped obstacle: fcl's deepest contact may be
    vertical, the reported normal stays the horizontal approach direction while the contact
    holds; without a free step the contact normal is oriented from B to A."""
    scene = parse_scene("box:name=wall,sx=1,sy=4,sz=4;box:name=cube,sx=1,sy=1,sz=1,dynamic=1,x=5")
    be = make_backend("fcl", scene, "cube vs wall")
    be.query([[1.2, 0, 0, 0, 0, 0]])
    r = be.query([[0.9, 0, 0, 0, 0, 0]]).pairs[0]
    assert r.in_contact and r.normal == pytest.approx([1, 0, 0])
    r = be.query([[0.9, 0, -1.9, 0, 0, 0]]).pairs[0]  # slides down, still in contact
    assert r.in_contact and r.normal == pytest.approx([1, 0, 0])
    fresh = make_backend("fcl", scene, "cube vs wall")
    r = fresh.query([[0.9, 0, 0, 0, 0, 0]]).pairs[0]  # in contact from the first query
    assert r.in_contact and r.normal @ np.array([1.0, 0, 0]) > 0.99


def test_horizontal_option_projects_the_normal():
    scene = parse_scene("box:name=wall,sx=1,sy=4,sz=4;box:name=cube,sx=1,sy=1,sz=1,dynamic=1,x=5")
    be = make_backend("fcl", scene, "cube vs wall; cube vs wall (horizontal)")
    full, flat = be.query([[1.5, 0, 3, 0, 0, 0]]).pairs  # the cube's bottom edge over the wall's top edge
    assert full.distance == flat.distance == pytest.approx(np.hypot(0.5, 0.5))
    assert full.normal == pytest.approx(np.array([1, 0, 1]) / np.sqrt(2))
    assert flat.normal == pytest.approx([1, 0, 0])
    # straight above: no horizontal direction (the centres are stacked too): zero normal
    assert not be.query([[0, 0, 3, 0, 0, 0]]).pairs[1].normal.any()
    # off-centre above: the vertical normal falls back to the horizontal centre-to-centre direction
    assert be.query([[0.2, 0, 3, 0, 0, 0]]).pairs[1].normal == pytest.approx([1, 0, 0])


def test_far_pairs_report_max_distance_without_an_exact_query(monkeypatch):
    from immersim.models.collision import fcl_backend

    calls = []
    real = fcl_backend.fcl.distance
    monkeypatch.setattr(fcl_backend.fcl, "distance", lambda *a: calls.append(1) or real(*a))
    scene = parse_scene("tank:name=t;tanks:n=50,spacing=10,x=200;box:name=av,sx=4,sy=2,sz=4.4,dynamic=1,x=30")
    be = make_backend("fcl", scene, "av vs t; av vs any tank_*", BackendConfig(max_distance=5.0))
    for x in (30.0, 29.0, 28.0):
        res = be.query([[x, 0, 2.5, 0, 0, 0]])
        for r in res.pairs:
            assert (r.in_contact, r.distance, r.partner, r.toi) == (False, 5.0, -1, -1.0)
            assert not r.normal.any()
    assert calls == []
    # inside max_distance the exact distance comes back
    r = be.query([[8.0, 0, 2.5, 0, 0, 0]]).pairs[0]
    assert 0 < r.distance < 5.0 and r.partner == 0 and calls


def test_closing_speed_is_positive_when_approaching():
    scene = parse_scene("box:name=wall,sx=1,sy=4,sz=4;box:name=cube,sx=1,sy=1,sz=1,dynamic=1,x=5")
    be = make_backend("fcl", scene, "cube vs wall")
    be.query([[5, 0, 0, 0, 0, 0]])
    r = be.query([[4, 0, 0, 0, 0, 0]], dt=0.1).pairs[0]
    assert r.normal == pytest.approx([1, 0, 0])  # from the wall to the cube
    assert r.closing_speed == pytest.approx(10.0)
    r = be.query([[4.5, 0, 0, 0, 0, 0]], dt=0.1).pairs[0]
    assert r.closing_speed == pytest.approx(-5.0)


def test_first_query_poses_are_the_initial_poses_not_a_motion():
    """The move from the scene spec's pose to the first input pose is no displacement."""
    scene = parse_scene("tank:name=t,tris=5.4k;box:name=av,sx=4,sy=2,sz=4.4,dynamic=1")
    for backend in ("fcl", "honeycomb"):
        r = make_backend(backend, scene, "av vs t").query([[16, 0, 2.5, 0, 0, 0]]).pairs[0]
        assert not r.in_contact, backend  # honeycomb's threshold d was 16 m
        assert r.toi == -1.0 and r.closing_speed == 0.0


def test_time_of_impact_catches_tunnelling():
    """A missile crossing a 0.1 m plate in one step: no contact at either end, toi inside."""
    scene = parse_scene("box:name=plate,sx=0.1,sy=4,sz=4;missile:z=0,x=-3")
    be = make_backend("fcl", scene, "missile vs plate")
    be.query([[-3, 0, 0, 0, 0, 0]])
    r = be.query([[3, 0, 0, 0, 0, 0]], dt=0.033).pairs[0]
    assert not r.in_contact
    # the nose (x + 1.5) meets the plate face x = -0.05 after travelling 1.45 of 6 m
    assert r.toi == pytest.approx(1.45 / 6.0 * 0.033, abs=2e-4 * 0.033 / 6 + 1e-6)
    off = make_backend("fcl", scene, "missile vs plate", BackendConfig(ccd=False))
    off.query([[-3, 0, 0, 0, 0, 0]])
    assert off.query([[3, 0, 0, 0, 0, 0]]).pairs[0].toi == -1.0


def test_advancement_speed_bounds_every_surface_point_and_is_tighter_than_the_radius():
    """``_speed``: no hull vertex moves farther than speed x (s2 - s1) between two interpolated
    poses (Slerp), for random motions; for a box turning about the vertical it is the corner's
    distance from the axis (2.24 m for the 4 x 2 m avatar), below its radius about the origin."""
    from immersim.models.collision.geometry import Slerp

    scene = parse_scene("box:name=av,sx=4,sy=2,sz=4.4,dynamic=1;missile:name=m,x=10")
    be = make_backend("fcl", scene, "av vs m")
    rng = np.random.default_rng(2)
    for i in (0, 1):
        hull = be.shapes.hull[i]
        for _ in range(40):
            T0 = pose_matrix(np.r_[rng.normal(0, 3, 3), rng.uniform(-3, 3, 3)])
            T1 = pose_matrix(np.r_[rng.normal(0, 3, 3), rng.uniform(-3, 3, 3)])
            path = Slerp(T0, T1)
            mu = be.toi.speed(i, path, T0, T1)
            assert mu <= np.linalg.norm(T1[:3, 3] - T0[:3, 3]) + path.ang * be.shapes.radius[i] + 1e-12
            for s1, s2 in rng.uniform(0, 1, (5, 2)):
                P1 = hull @ path.at(s1)[:3, :3].T + path.at(s1)[:3, 3]
                P2 = hull @ path.at(s2)[:3, :3].T + path.at(s2)[:3, 3]
                assert np.linalg.norm(P2 - P1, axis=1).max() <= mu * abs(s2 - s1) * (1 + 1e-9) + 1e-12
    T0, T1 = pose_matrix([0, 0, 2.5, 0, 0, 0.67]), pose_matrix([0.1, 0, 2.5, 0, 0, 0.67 - math.pi / 2])
    assert be.toi.speed(0, Slerp(T0, T1), T0, T1) == pytest.approx(0.1 + math.pi / 2 * math.sqrt(5), rel=1e-12)
    assert math.sqrt(5) < be.shapes.radius[0]


def test_time_of_impact_of_a_turning_box_is_the_first_contact():
    """An avatar box turning about the vertical by a quarter turn in one step next to a tank
    (campus_drive's bounce): no contact at either end, conservative advancement finds the
    first contact of the interpolated motion (checked on a fine sampling of it)."""
    from immersim.models.collision.geometry import Slerp

    scene = parse_scene("tank:name=t,tris=5.4k;box:name=av,sx=4,sy=2,sz=4.4,dynamic=1,y=6")
    be = make_backend("fcl", scene, "av vs t", BackendConfig(max_distance=2.0))
    p0, p1 = [1.0, 3.8, 2.5, 0, 0, 0.0], [1.0, 3.85, 2.5, 0, 0, -math.pi / 2]
    be.query([p0])
    r = be.query([p1], dt=0.033).pairs[0]
    assert not r.in_contact and r.toi > 0
    probe = make_backend("fcl", parse_scene("tank:name=t,tris=5.4k;box:name=av,sx=4,sy=2,sz=4.4,dynamic=1,y=6"),
                         "av vs t", BackendConfig(ccd=False))
    path = Slerp(pose_matrix(p0), pose_matrix(p1))
    first = None
    for s in np.linspace(0, 1, 2001):
        T = path.at(s)
        yaw = math.atan2(T[1, 0], T[0, 0])
        if probe.query([[*T[:3, 3], 0, 0, yaw]]).pairs[0].in_contact:
            first = s
            break
    assert first is not None
    # conservative: no contact before toi; converged: within the sampling (and 1e-4 m) of it
    assert r.toi / 0.033 <= first
    assert first - r.toi / 0.033 < 1e-3


def test_skip_rules_and_rest():
    scene = parse_scene("tanks:n=100,tris=5.4k;missile:z=30;sphere:name=drone,r=0.5,dynamic=1,z=40")
    be = make_backend("fcl", scene, "missile vs any tank; tank_0 vs tank_1; drone vs scene")
    assert len(be.fclo.geoms) == 3  # one BVH for all 100 tanks
    r0 = be.query([[0, 0, 30, 0, 0, 0], [0, 0, 40, 0, 0, 0]])
    assert r0.n_bodies == 102
    # the far missile: the tree hands out only the nearest tanks, not all 100
    r1 = be.query([[45, 45, 30, 0, 0, 0], [0, 0, 40, 0, 0, 0]])
    assert 1 <= r1.n_candidates <= 8 and not r1.at_rest  # over all three pairs
    # nothing moves: cached answer, nothing tested
    r2 = be.query([[45, 45, 30, 0, 0, 0], [0, 0, 40, 0, 0, 0]])
    assert r2.at_rest and r2.n_candidates == 0 and r2.n_narrow == 0
    assert [p.distance for p in r2.pairs] == [p.distance for p in r1.pairs]
    # only the drone moves: the missile pair and the static-static pair are not re-tested
    calls = []
    orig = be._evaluate
    be._evaluate = lambda pair, dt: calls.append(pair.label) or orig(pair, dt)
    be.query([[45, 45, 30, 0, 0, 0], [0, 0, 41, 0, 0, 0]])
    assert calls == ["drone vs scene"]


def test_state_round_trip_restores_caches():
    scene = parse_scene("tanks:n=4;missile:z=8")
    be = make_backend("fcl", scene, "missile vs any tank")
    be.query([[0.3, 0, 6, 0, 0.5, 0]])
    state = be.get_state()
    a = be.query([[0.3, 0, 3, 0, 0.5, 0]]).pairs[0]
    be.query([[20, 0, 3, 0, 0, 0]])
    be.set_state(state)
    b = be.query([[0.3, 0, 3, 0, 0.5, 0]]).pairs[0]
    assert (a.in_contact, a.distance, a.depth, a.toi, a.closing_speed) == \
        (b.in_contact, b.distance, b.depth, b.toi, b.closing_speed)


def test_non_watertight_mesh_keeps_exact_distances(tmp_path):
    box = trimesh.creation.box((1, 1, 1))
    trimesh.Trimesh(box.vertices, box.faces[2:], process=False).export(tmp_path / "open.stl")
    with pytest.warns(Warning):
        scene = parse_scene(f"mesh:file={tmp_path / 'open.stl'},name=open;sphere:name=ball,r=0.2,subdiv=1,dynamic=1")
    be = make_backend("fcl", scene, "ball vs open")
    pose = [1.3, 0.2, 0.1, 0, 0, 0]
    r = be.query([pose]).pairs[0]
    assert r.distance == pytest.approx(brute_distance(posed(scene, 1, pose), scene.mesh(0)), abs=1e-7)


def test_nan_pose_is_rejected_naming_the_body():
    scene = parse_scene("tank;missile:z=8")
    be = make_backend("fcl", scene)
    with pytest.raises(ValueError, match=r"'missile' \(pitch\) = nan is not finite"):
        be.query([[0, 0, 8, 0, float("nan"), 0]])


@pytest.mark.parametrize("chunk_faces", [0, 32])
def test_distance_lower_bound_cache_changes_no_output(chunk_faces):
    """The skip rule 'last exact distance minus the travel since cannot beat the best so far'
    is a pure speed-up: the same trajectory without it gives identical results, and on the
    whole-mesh path (chunk_faces = 0) it does skip exact queries (a ball near the corner of
    the tank's AABB: gap 0.87 m, distance 3.4 m; with chunks the chunk bounds already prune
    these queries, and the cache keeps their lower bound; its upper bound limits the chunks
    bounded to those nearer than it, with the same results)."""
    from immersim.models.collision import fcl_backend

    scene = parse_scene("tank:name=t,tris=5.4k;sphere:name=ball,r=0.3,dynamic=1,x=20")
    cfg = BackendConfig(max_distance=2.0, chunk_faces=chunk_faces)
    cached = make_backend("fcl", scene, "ball vs t", cfg)
    # no bounds from the last exact distance (nor chunk subsets)
    plain = make_backend("fcl", scene, "ball vs t", cfg, Shortcuts(distance_bounds=False))
    calls = {"cached": 0, "plain": 0}
    real = fcl_backend.fcl.distance
    rng = np.random.default_rng(3)
    p = np.array([5.7, 2.5, 4.7])
    seen = []
    for k in range(60):  # a random walk from the corner towards the tank, in and out of range
        p = p + rng.uniform(-0.1, 0.04, 3)
        pose = [[*p, *rng.uniform(-0.2, 0.2, 3)]]
        out = {}
        for name, be in (("cached", cached), ("plain", plain)):
            fcl_backend.fcl.distance = lambda *a, _n=name: calls.__setitem__(_n, calls[_n] + 1) or real(*a)
            try:
                out[name] = be.query(pose).pairs[0]
            finally:
                fcl_backend.fcl.distance = real
        rc, r = out["cached"], out["plain"]
        seen.append(r.distance)
        assert (rc.in_contact, rc.distance, rc.partner) == (r.in_contact, r.distance, r.partner)
        np.testing.assert_array_equal(rc.normal, r.normal)
        np.testing.assert_array_equal(rc.point, r.point)
    assert calls["cached"] < calls["plain"] if chunk_faces == 0 else calls["cached"] <= calls["plain"]
    assert min(seen) < 2.0 and max(seen) == 2.0  # the walk was in and out of range


def test_cached_dynamic_boxes_equal_fresh_ones():
    scene = parse_scene("tank:name=t,tris=5.4k,dynamic=1;missile:z=8")
    be = make_backend("fcl", scene, "missile vs t")
    for pose in ([[0, 0, 0, 0, 0, 0.3], [1, 0, 8, 0, 1.2, 0]], [[2, 1, 0, 0, 0, 0.3], [1, 0, 7, 0, 1.2, 0]]):
        be.query(pose)
        be.ensure_bounds([0, 1])
        for i in (0, 1):
            v = posed(scene, i, pose[i]).vertices
            np.testing.assert_allclose(be.aabb[i], [v.min(0), v.max(0)], atol=1e-12)


def test_far_pair_skip_changes_no_output_and_skips_evaluations():
    """The far-pair skip (a pair whose members' AABBs were all >= max_distance away keeps its
    far result while the gap bound holds) is a pure speed-up: a trajectory that drives a
    turning box from far away into a tank and back, two balls that close in on it, and a
    fast missile diving onto a second tank (time of impact) gives the same results and
    counters with and without it, and the skip does save evaluations."""
    from immersim.models.collision import fcl_backend

    spec = ("tank:name=t,tris=5.4k,x=20,yaw=0.7;tank:name=u,tris=5.4k,x=-40;box:name=av,sx=4,sy=2,sz=4.4,dynamic=1;"
            "sphere:name=b1,r=1,dynamic=1;sphere:name=b2,r=1,dynamic=1;missile:name=m,dynamic=1,x=-40,z=30")
    pairs = "av vs t; av vs any b*; m vs scene; b1 vs b2"
    fast = make_backend("fcl", parse_scene(spec), pairs, BackendConfig(max_distance=2.0))
    # the same backend without the far-pair skip
    plain = make_backend("fcl", parse_scene(spec), pairs, BackendConfig(max_distance=2.0), Shortcuts(far_pairs=False))
    evaluations = {"fast": 0, "plain": 0}
    real = fcl_backend.FclBackend._evaluate
    seen = {"contact": 0, "toi": 0, "near": 0}
    for k in range(150):
        x = -20 + 0.4 * k if k < 100 else 20 - 0.4 * (k - 100)  # into the tank (x ~ 13 m) and back
        yb = 30 - 0.25 * k  # the balls close in on the box's path
        poses = [[x, 0.5 * np.sin(k / 7), 2.5, 0, 0, 0.01 * k],
                 [x + 3, yb, 1, 0, 0, 0],
                 [x + 3, yb + 2.2 + 0.3 * np.sin(k / 3), 1, 0, 0, 0],
                 [-40 + 0.1 * k, 0, max(30 - 3.0 * k, 4.2), 0, 0.5, 0]]  # dives onto u at ~3 m/step
        out = {}
        for name, be in (("fast", fast), ("plain", plain)):
            def counted(self, pair, dt, _n=name):
                evaluations[_n] += 1
                return real(self, pair, dt)
            fcl_backend.FclBackend._evaluate = counted
            try:
                out[name] = be.query(poses, 0.033)
            finally:
                fcl_backend.FclBackend._evaluate = real
        f, p = out["fast"], out["plain"]
        assert (f.n_candidates, f.n_narrow, f.at_rest) == (p.n_candidates, p.n_narrow, p.at_rest)
        for rf, rp in zip(f.pairs, p.pairs):
            assert (rf.in_contact, rf.distance, rf.depth, rf.toi, rf.closing_speed, rf.partner) == \
                (rp.in_contact, rp.distance, rp.depth, rp.toi, rp.closing_speed, rp.partner)
            np.testing.assert_array_equal(rf.point, rp.point)
            np.testing.assert_array_equal(rf.normal, rp.normal)
            seen["contact"] += rp.in_contact
            seen["toi"] += rp.toi >= 0
            seen["near"] += 0 < rp.distance < 2.0
    assert evaluations["fast"] < 0.8 * evaluations["plain"]
    assert all(seen.values()), seen  # contacts, times of impact and near misses were all compared


@pytest.mark.parametrize("chunk_faces", [0, 32])
def test_body_frame_gap_changes_no_output_and_skips_exact_queries(chunk_faces):
    """The body-frame gap (the ball's box in the rotated tank's frame against the tank's own
    box) is a lower bound of the distance: skipping exact queries with it changes no result,
    and near the corner of the tank's loose world AABB it does skip them on the whole-mesh
    path (time of impact off: only the narrow-phase distances are counted; with chunks their
    own bounds, in both bodies' frames, already prune those queries)."""
    from immersim.models.collision import fcl_backend

    spec = "tank:name=t,tris=5.4k,yaw=0.785;sphere:name=ball,r=0.3,dynamic=1,x=20"
    config = BackendConfig(max_distance=2.0, ccd=False, chunk_faces=chunk_faces)
    with_gap = make_backend("fcl", parse_scene(spec), "ball vs t", config)
    plain = make_backend("fcl", parse_scene(spec), "ball vs t", config, Shortcuts(distance_bounds=False))
    calls = {"with_gap": 0, "plain": 0}
    real = fcl_backend.fcl.distance
    lo, hi = with_gap.aabb[0]
    seen = []
    # the corner of the world AABB on the tank's short axis is ~4 m from the tank itself
    corner = np.array([hi[0], lo[1], (lo[2] + hi[2]) / 2])
    for k in range(16):  # from outside that corner, through it, towards the tank, spinning
        p = corner + np.array([1.0, -1.0, 0.0]) * (1.0 - 3.8 * k / 15) / math.sqrt(2)
        out = {}
        for name, be in (("with_gap", with_gap), ("plain", plain)):
            fcl_backend.fcl.distance = lambda *a, _n=name: calls.__setitem__(_n, calls[_n] + 1) or real(*a)
            try:
                out[name] = be.query([[*p, 0, 0, 0.4 * k]])
            finally:
                fcl_backend.fcl.distance = real
        g, r = out["with_gap"], out["plain"]
        assert (g.n_candidates, g.n_narrow) == (r.n_candidates, r.n_narrow)
        rg, rp = g.pairs[0], r.pairs[0]
        assert (rg.in_contact, rg.distance, rg.depth, rg.partner) == (rp.in_contact, rp.distance, rp.depth, rp.partner)
        np.testing.assert_array_equal(rg.point, rp.point)
        np.testing.assert_array_equal(rg.normal, rp.normal)
        seen.append(rp.distance)
    assert calls["with_gap"] < calls["plain"] if chunk_faces == 0 else calls["with_gap"] <= calls["plain"]
    assert min(seen) < 2.0 and max(seen) == 2.0
