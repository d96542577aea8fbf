"""The fcl backend's shortcuts give the outputs of the full computation, bit for bit.

Each ``Shortcuts`` switch is compared with the same backend without it over a trajectory that
approaches, touches and leaves a rotated tank while steering; the array forms of the poses
and transforms read as the poses say.
"""
import math
import struct

import numpy as np
import pytest

from immersim.models.collision import BackendConfig, Shortcuts, make_backend, parse_scene
from immersim.models.collision.geometry import pose_matrix

SCENE = ("box:name=av,sx=4,sy=2,sz=4.4,dynamic=1;sphere:name=e,r=1,dynamic=1;"
         "tank:name=t,tris=5.4k,x=12,y=1,yaw=2.2;tank:name=u,tris=5.4k,x=-12,y=0,yaw=0.4")
PAIRS = "av vs t (horizontal); av vs any e; e vs u"


def _trajectory(n=70):
    """The avatar drives into tank t and back out while steering; the ball rolls past u."""
    out = []
    for k in range(n):
        s = k / (n - 1)
        x = -2.0 + 16.0 * math.sin(math.pi * s)  # to x = 14 (through t's hull) and back
        out.append(((x, 0.3 * math.sin(5 * s), 2.5, 0.0, 0.0, 0.4 * s),
                    (-12.0 + 8 * math.cos(3 * s), 6.0 - 9 * s, 1.0, 0.0, 0.0, 0.0)))
    return out


def _bits(res):
    pairs = [(r.in_contact, struct.pack("d", r.distance), struct.pack("d", r.depth), r.point.tobytes(),
              r.normal.tobytes(), struct.pack("d", r.toi), struct.pack("d", r.closing_speed), r.partner)
             for r in res.pairs]
    return pairs, res.n_candidates, res.n_narrow, res.at_rest


def _run(be, traj):
    out = []
    for poses in traj:
        flat = tuple(x for p in poses for x in p)  # the FMU's flat tuple
        out.append(_bits(be.query(flat, 0.033)))
    return out


@pytest.fixture(scope="module")
def scene():
    return parse_scene(SCENE)


def test_the_far_pair_skip_changes_no_output(scene):
    traj = _trajectory()
    fast = make_backend("fcl", scene, PAIRS, BackendConfig(max_distance=2.0))
    full = make_backend("fcl", scene, PAIRS, BackendConfig(max_distance=2.0), Shortcuts(far_pairs=False))
    assert fast.far.on and not full.far.on  # full: every pair whose bodies moved is evaluated
    evaluated = []
    real = fast._evaluate
    fast._evaluate = lambda pair, dt: evaluated.append(pair.label) or real(pair, dt)
    assert _run(fast, traj) == _run(full, traj)
    # the shortcut was taken: far steps of 'av vs any e' and 'e vs u' are not evaluated
    assert len(evaluated) < 0.7 * 3 * len(traj)
    assert any(r.in_contact for r in fast.query(tuple(x for p in traj[len(traj) // 2] for x in p)).pairs)


def test_skipped_contact_tests_change_no_output(scene):
    traj = _trajectory()
    fast = make_backend("fcl", scene, PAIRS, BackendConfig(max_distance=2.0))
    # every broad-phase candidate gets fcl.collide
    full = make_backend("fcl", scene, PAIRS, BackendConfig(max_distance=2.0), Shortcuts(distance_bounds=False))
    skipped = []
    real = fast._separated
    fast._separated = lambda a, b: real(a, b) and not skipped.append((a, b))
    assert _run(fast, traj) == _run(full, traj)
    assert skipped  # candidates overlapping t's world AABB but apart in its frame


def test_lazy_transforms_read_as_the_poses_say(scene):
    be = make_backend("fcl", scene, PAIRS, BackendConfig(max_distance=2.0))
    traj = _trajectory(12)
    dyn = list(scene.dynamic)
    for k, poses in enumerate(traj):
        be.query(tuple(x for p in poses for x in p))
        if k % 3:  # read the arrays only now and then (rows written lazily in between)
            continue
        T = np.array([pose_matrix(p) for p in poses])
        np.testing.assert_array_equal(be.T[dyn], T)
        np.testing.assert_array_equal(be.poses[dyn], np.array(poses))
    # prev_T: the transforms before the last query's move; equal to T at rest
    last = traj[-1]
    moved = ((last[0][0] + 1.0,) + last[0][1:], last[1])
    be.query(tuple(x for p in moved for x in p))
    np.testing.assert_array_equal(be.prev_T[dyn], np.array([pose_matrix(p) for p in last]))
    np.testing.assert_array_equal(be.T[dyn], np.array([pose_matrix(p) for p in moved]))
    be.query(tuple(x for p in moved for x in p))  # nothing moved
    np.testing.assert_array_equal(be.prev_T[dyn], be.T[dyn])


def test_a_non_finite_flat_pose_is_rejected_by_name(scene):
    be = make_backend("fcl", scene, PAIRS, BackendConfig(max_distance=2.0))
    with pytest.raises(ValueError, match=r"pose of dynamic body 'e' \(yaw\) = nan is not finite"):
        be.query((0.0, 0.0, 2.5, 0.0, 0.0, 0.0, 1.0, 2.0, 1.0, 0.0, 0.0, math.nan))


def test_the_travel_of_a_far_skipped_body_is_that_of_its_poses(scene):
    """The far-pair skip may ask for a body's travel before the pair's rows are written."""
    from immersim.models.collision.geometry import rotation_angle

    be = make_backend("fcl", scene, PAIRS, BackendConfig(max_distance=2.0))
    p0 = ((-30.0, 0.0, 2.5, 0.0, 0.0, 0.1), (40.0, 0.0, 1.0, 0.0, 0.0, 0.0))
    p1 = ((-29.8, 0.1, 2.5, 0.0, 0.0, 0.12), (40.0, 0.0, 1.0, 0.0, 0.0, 0.0))
    be.query(tuple(x for p in p0 for x in p))
    be.query(tuple(x for p in p1 for x in p))
    evaluated = []
    real = be._evaluate
    be._evaluate = lambda pair, dt: evaluated.append(pair.label) or real(pair, dt)
    p2 = ((-29.6, 0.2, 2.5, 0.0, 0.0, 0.14), p1[1])  # slow: no time of impact needed
    be.query(tuple(x for p in p2 for x in p))
    assert evaluated == []  # far: the rows of the avatar were not written by an evaluation
    T1, T2 = pose_matrix(p1[0]), pose_matrix(p2[0])
    expected = np.linalg.norm(T2[:3, 3] - T1[:3, 3]) + rotation_angle(T2[:3, :3] @ T1[:3, :3].T) * be.shapes.radius[0]
    assert be.toi.travel(0) == expected


def test_the_fast_mover_test_from_the_step_motion_is_that_of_the_travel(scene):
    """_needs_toi's first test (translation and ||R1 - R0||_F of the move, recorded by _move)
    answers as ``_travel(a) > ccd_fast * thin`` does, on moves around the threshold."""
    be = make_backend("fcl", scene, PAIRS, BackendConfig(max_distance=2.0))
    rng = np.random.default_rng(7)
    threshold = be.toi.threshold[0]  # the avatar box: 0.5 x its 2 m thinnest extent
    ball = (40.0, 0.0, 1.0, 0.0, 0.0, 0.0)
    decided = 0
    for _ in range(300):
        p0 = (-30.0, 0.0, 2.5, *rng.uniform(-0.3, 0.3, 3))
        step = rng.uniform(0.0, 1.2 * threshold)
        turn = rng.uniform(0.0, 0.4, 3) * rng.integers(0, 2)
        d = rng.normal(size=3)
        p1 = tuple(np.add(p0[:3], step * d / np.linalg.norm(d)).tolist()) + tuple(np.add(p0[3:], turn).tolist())
        be.query(p0 + ball)
        be.query(p1 + ball)
        t, f = be.frames.motion[0]
        decided += t + 1.111 * f * be.shapes.radius[0] < be.toi.clear[0]
        assert be.toi.needs(0) == bool(be.toi.travel(0) > threshold)
    assert 50 < decided < 300  # the first test settles part of the moves, not all


def test_norm3_is_numpys_norm_bit_for_bit():
    from immersim.models.collision.geometry import norm3

    rng = np.random.default_rng(3)
    for v in rng.normal(size=(20000, 3)) * rng.choice([1e-9, 1e-3, 1.0, 1e3], size=(20000, 1)):
        assert norm3(v) == np.linalg.norm(v)


def test_the_scalar_aabb_gap_is_the_array_gaps_bit_for_bit(scene):
    """``Bounds.gap`` (scalar, per pair: the fcl backend's narrow phase) and ``Bounds.gaps``
    (arrays, one body to many: the other backends) give the same numbers along the trajectory."""
    be = make_backend("fcl", scene, PAIRS, BackendConfig(max_distance=2.0))
    everyone = np.arange(len(scene.bodies))
    checked = 0
    for poses in _trajectory(30):
        be.query(tuple(x for p in poses for x in p), 0.033)
        for a in everyone:
            gaps = be.bounds.gaps(a, everyone)
            assert [struct.pack("d", be.bounds.gap(a, b)) for b in everyone] == [struct.pack("d", g) for g in gaps]
            checked += int((gaps > 0).sum())
    assert checked > 100  # separated boxes, not only overlapping ones (gap 0)


@pytest.mark.parametrize("off", sorted(Shortcuts.__dataclass_fields__))
def test_each_shortcut_changes_no_output(scene, off):
    """The backend without one shortcut gives the outputs of the backend with all, bit for bit,
    in both pose forms (the FMU's flat tuple and an array), also after a state restore."""
    traj = _trajectory(40)
    fast = make_backend("fcl", scene, PAIRS, BackendConfig(max_distance=2.0))
    plain = make_backend("fcl", scene, PAIRS, BackendConfig(max_distance=2.0), Shortcuts(**{off: False}))
    assert _run(fast, traj) == _run(plain, traj)
    state = fast.get_state(), plain.get_state()
    arrays = [np.array(p) for p in traj[::-1]]
    assert [_bits(fast.query(p)) for p in arrays] == [_bits(plain.query(p)) for p in arrays]
    fast.set_state(state[0])
    plain.set_state(state[1])
    assert _run(fast, traj[::3]) == _run(plain, traj[::3])


def test_slerp_at_is_the_array_formula():
    """Slerp.at's scalar translation and constant identity give the array expressions' bits."""
    from immersim.models.collision.geometry import Slerp

    rng = np.random.default_rng(5)
    for _ in range(200):
        T0, T1 = (pose_matrix(np.concatenate([rng.uniform(-50, 50, 3), rng.uniform(-3, 3, 3)])) for _ in range(2))
        path, s = Slerp(T0, T1), float(rng.uniform())
        T = np.eye(4)
        T[:3, 3] = (1 - s) * T0[:3, 3] + s * T1[:3, 3]
        K, a = path.K, s * path.ang
        T[:3, :3] = (np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K) @ T0[:3, :3]
        assert path.at(s).tobytes() == T.tobytes()


def test_a_pair_at_rest_reports_one_result_object(scene):
    """A pair whose bodies stopped reports its at-rest result (no time of impact, no closing
    speed) and, from the first step at rest on, the same object: the FMU skips writing it."""
    be = make_backend("fcl", scene, PAIRS, BackendConfig(max_distance=2.0))
    traj = _trajectory()
    k = len(traj) // 2  # the avatar in contact with t, moving
    for poses in traj[:k]:
        be.query(tuple(x for p in poses for x in p))
    moving = be.query(tuple(x for p in traj[k] for x in p)).pairs[0]
    assert moving.in_contact and moving.closing_speed != 0.0
    shown = []
    for j in range(k + 1, k + 4):  # the avatar stops there, the ball keeps rolling
        poses = (traj[k][0], traj[j][1])
        shown.append(be.query(tuple(x for p in poses for x in p)).pairs[0])
    assert shown[0] is shown[1] is shown[2]
    r = shown[0]
    assert (r.in_contact, r.distance, r.depth, r.partner, r.toi, r.closing_speed) == (
        moving.in_contact, moving.distance, moving.depth, moving.partner, -1.0, 0.0)
    assert r.point is moving.point and r.normal is moving.normal



def test_a_body_turning_in_place_toward_a_far_partner_is_evaluated_again():
    """The far-pair skip's bound counts rotation: the box, turning in place, brings its corner from
    2.2 m to 1.96 m of the ball (max_distance 2 m); the skip gives the full computation's outputs."""
    scene = parse_scene("box:name=av,sx=4,sy=2,sz=4.4,dynamic=1;sphere:name=e,r=1,dynamic=1")
    traj = [((0.0, 0.0, 2.5, 0.0, 0.0, 0.02 * k), (5.2, 0.0, 2.5, 0.0, 0.0, 0.0)) for k in range(24)]
    fast = make_backend("fcl", scene, "av vs e", BackendConfig(max_distance=2.0))
    full = make_backend("fcl", scene, "av vs e", BackendConfig(max_distance=2.0), Shortcuts(far_pairs=False))
    got = _run(fast, traj)
    assert got == _run(full, traj)
    first, last = (struct.unpack("d", got[k][0][0][1])[0] for k in (0, -1))
    assert first == 2.0   # far: reported at max_distance
    yaw = 0.02 * 23       # the corner's reach along x: 2 cos(yaw) + 1 sin(yaw)
    assert last == pytest.approx(5.2 - 1.0 - (2.0 * math.cos(yaw) + math.sin(yaw)), abs=1e-4)  # (a meshed ball)


@pytest.mark.parametrize("rel", [1e-12, -1e-12])
def test_a_move_within_rounding_of_the_fast_mover_threshold_is_decided_by_its_travel(rel):
    """A pure translation by ``ccd_fast * thin * (1 +- 1e-12)``: the scalar estimate lies within
    its slack of the threshold, so the exact travel decides; the backend without the pretests
    (travel alone) answers the same."""
    scene = parse_scene("box:name=av,sx=4,sy=2,sz=4.4,dynamic=1;sphere:name=e,r=1,dynamic=1")
    ball = (40.0, 0.0, 1.0, 0.0, 0.0, 0.0)
    answers = []
    for pretests in (True, False):
        be = make_backend("fcl", scene, "av vs e", BackendConfig(max_distance=2.0), Shortcuts(toi_pretests=pretests))
        threshold = be.toi.threshold[0]
        assert threshold == 0.5 * 2.0  # ccd_fast x the box's thinnest extent (sy = 2 m)
        be.query((0.0, 0.0, 2.5, 0.0, 0.0, 0.0) + ball)
        be.query((threshold * (1.0 + rel), 0.0, 2.5, 0.0, 0.0, 0.0) + ball)
        assert be.toi.travel(0) == threshold * (1.0 + rel)
        answers.append(be.toi.needs(0))
    assert answers == [rel > 0, rel > 0]


def test_a_far_pair_within_the_rounding_margin_below_max_distance_is_evaluated():
    """Two axis-aligned unit boxes (AABB gap = exact distance) recorded far at 2.1 m, then moved to
    5e-10 m below max_distance = 2 m: the far record's limit is max_distance + 1e-9, so the pair is
    evaluated and reports its exact distance and partner; 5e-10 m above it stays far. The skip
    gives the outputs of the backend without it, bit for bit."""
    scene = parse_scene("box:name=a,sx=1,sy=1,sz=1,dynamic=1;box:name=b,sx=1,sy=1,sz=1,dynamic=1")
    b = (3.0, 0.0, 0.5, 0.0, 0.0, 0.0)
    traj = [((x, 0.0, 0.5, 0.0, 0.0, 0.0), b) for x in (-0.1, 5e-10, -0.1, -5e-10)]
    fast = make_backend("fcl", scene, "a vs b", BackendConfig(max_distance=2.0))
    full = make_backend("fcl", scene, "a vs b", BackendConfig(max_distance=2.0), Shortcuts(far_pairs=False))
    got = _run(fast, traj)
    assert got == _run(full, traj)
    fast.query(tuple(x for p in traj[0] for x in p))
    assert fast.far.records[0] is not None  # recorded far
    near = fast.query(tuple(x for p in traj[1] for x in p)).pairs[0]
    exact = (3.0 - 0.5) - (5e-10 + 0.5)
    assert near.distance < 2.0 and near.distance == pytest.approx(exact, abs=1e-13) and near.partner == 1
    fast.query(tuple(x for p in traj[2] for x in p))
    above = fast.query(tuple(x for p in traj[3] for x in p)).pairs[0]
    assert (above.distance, above.partner) == (2.0, -1)  # beyond max_distance: the far result
