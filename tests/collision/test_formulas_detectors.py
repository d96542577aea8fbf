"""Collision formulas against geometry worked out here: time of impact of a slow mover, and the
detectors' distances against the exact (fcl) distance.
"""
import numpy as np
import pytest

from immersim.models.collision import make_backend, parse_scene

H = 0.033


@pytest.mark.parametrize("d0, depth", [(0.10, 0.05), (0.02, 0.12), (0.06, 0.06)])
def test_slow_mover_time_of_impact_is_h_d0_over_d0_plus_depth(d0, depth):
    """A 1 m cube slides along x into the 3 m face of a wall, from a gap d0 to an overlap depth
    within one step (travel well below half its thinnest extent: a slow mover). The signed
    distance is linear over the step, so contact comes at toi = h d0 / (d0 + depth); the closing
    speed is (d0 + depth) / h. Uneven approaches (d0 != depth) tell d0 from depth."""
    scene = parse_scene("box:name=wall,sx=1,sy=3,sz=3;box:name=cart,sx=1,sy=1,sz=1,dynamic=1")
    be = make_backend("fcl", scene, "cart vs wall")
    far, before, after = (be.query([[x, 0.3, -0.2, 0, 0, 0]], H).pairs[0] for x in (3.0, 1.0 + d0, 1.0 - depth))
    assert far.distance == pytest.approx(2.0, abs=1e-12)
    assert not before.in_contact and before.distance == pytest.approx(d0, abs=1e-12)
    assert after.in_contact and after.depth == pytest.approx(depth, abs=1e-9)
    assert after.toi == pytest.approx(H * d0 / (d0 + depth), rel=1e-7)
    assert after.closing_speed == pytest.approx((d0 + depth) / H, rel=1e-7)


def test_contact_that_held_from_the_start_of_the_step_has_time_of_impact_zero():
    scene = parse_scene("box:name=wall,sx=1,sy=3,sz=3;box:name=cart,sx=1,sy=1,sz=1,dynamic=1")
    be = make_backend("fcl", scene, "cart vs wall")
    r = [be.query([[x, 0.3, -0.2, 0, 0, 0]], H).pairs[0] for x in (3.0, 0.97, 0.95)]
    assert r[1].in_contact and r[2].in_contact and r[2].toi == 0.0


SCENE = "box:name=block,sx=1.0,sy=0.6,sz=0.4;sphere:name=ball,r=0.3,subdiv=1,dynamic=1"


def _poses(n, lo, hi, seed):
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < n:
        p = rng.uniform(-hi, hi, 3)
        if np.abs(p).max() >= lo:
            out.append(np.r_[p, rng.uniform(-np.pi, np.pi, 3)])
    return out


def test_basis_point_distance_never_exceeds_the_exact_distance_nor_goes_negative():
    """Near (narrow phase) and far (bounding-sphere and box lower bounds) poses alike."""
    scene = parse_scene(SCENE)
    exact, bp = make_backend("fcl", scene, "ball vs block"), make_backend("basis_point", scene, "ball vs block")
    checked = 0
    for pose in _poses(40, 0.0, 3.0, 3):
        e, b = exact.query([pose]).pairs[0], bp.query([pose]).pairs[0]
        if e.in_contact:
            continue
        assert 0.0 <= b.distance <= e.distance + 1e-9, (pose, b.distance, e.distance)
        checked += 1
    assert checked >= 30


@pytest.mark.parametrize("detector, gap", [("basis_point", 0.4), ("basis_point", 3.0), ("basis_point", 9.0),
                                           ("honeycomb", 3.0), ("honeycomb", 9.0)])
def test_far_lower_bound_is_at_most_the_gap(detector, gap):
    """A ball of radius 0.3 centred ``gap + 0.3`` m above the block's top face (z = 0.2): the exact
    distance is ``gap`` (up to the faceted sphere); the far bound must not exceed it and is >= 0.
    (The honeycomb's narrow phase flags contact within its threshold distance, the body's
    displacement in the step, so it is checked on far poses only.)"""
    scene = parse_scene(SCENE)
    exact, det = make_backend("fcl", scene, "ball vs block"), make_backend(detector, scene, "ball vs block")
    for dx in (0.0, 0.7, 1.9):
        pose = [dx, 0.1, 0.2 + 0.3 + gap, 0, 0, 0]
        e, d = exact.query([pose]).pairs[0], det.query([pose]).pairs[0]
        assert not d.in_contact
        assert 0.0 <= d.distance <= e.distance + 1e-9
        if dx == 0.0:
            assert e.distance == pytest.approx(gap, abs=0.02)
            assert d.distance >= 0.5 * gap - 0.3     # a bound, not a trivial zero


def test_basis_point_contact_flag_agrees_with_the_exact_test_away_from_touching():
    """Contact iff fcl finds one, for poses apart by more than 1 cm or overlapping by more than 5 cm
    (the tolerance of the features' contact test is a fraction of the sampling distance)."""
    scene = parse_scene(SCENE)
    exact, bp = make_backend("fcl", scene, "ball vs block"), make_backend("basis_point", scene, "ball vs block")
    rng = np.random.default_rng(3)
    seen = [0, 0]
    for _ in range(40):
        pose = np.r_[rng.uniform(-1.2, 1.2, 3), rng.uniform(-np.pi, np.pi, 3)]
        e, b = exact.query([pose]).pairs[0], bp.query([pose]).pairs[0]
        if (e.in_contact and e.depth > 0.05) or (not e.in_contact and e.distance > 0.01):
            assert b.in_contact == e.in_contact, (pose, e, b)
            seen[e.in_contact] += 1
    assert seen[0] >= 20 and seen[1] >= 2


@pytest.mark.parametrize("gap", [2.0, 5.0])
def test_fcl_far_pair_gap_is_a_lower_bound_of_the_exact_gap(gap):
    """Two moving axis-aligned cubes ``gap`` m apart along x beyond ``max_distance``: the far-pair
    skip's box gap never exceeds the exact gap (it is a lower bound, rounding included)."""
    from immersim.models.collision import BackendConfig

    scene = parse_scene("box:name=wall,sx=1,sy=1,sz=1,dynamic=1;box:name=cart,sx=1,sy=1,sz=1,dynamic=1")
    be = make_backend("fcl", scene, "cart vs wall", BackendConfig(max_distance=0.5))
    r = be.query([[0.0, 0.0, 0.0, 0, 0, 0], [1.0 + gap, 0.0, 0.0, 0, 0, 0]]).pairs[0]
    assert r.distance == 0.5 and not r.in_contact
    g = be._far_gap(0, be.pairs[0])
    assert g is not None and gap - 1e-6 <= g <= gap
