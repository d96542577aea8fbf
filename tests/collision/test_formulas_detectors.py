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


@pytest.mark.parametrize("c, contact", [(1.6, False), (1.5, False), (1.45, True)])
def test_basis_point_contact_offset_is_the_sampling_distance_of_the_overlap_region(c, contact):
    """Two 2 m cubes turned 45 deg about z, the second at (c, c, 0): two faces face each other
    across the gap sqrt(2) c - 2 (0.263, 0.121, 0.051 m), and the world boxes overlap over
    [c - sqrt(2), sqrt(2)]^2 x [-1, 1]. Sampling distance SD = extent / DN (eq. 5-7), so the
    contact offset eps (the larger SD across a scan direction, §5.5.3) is at most 2 / DN.
    Contact iff the gap is within eps; the distance is the exact (fcl) gap."""
    import math

    from immersim.models.collision.basis_point import scan_counts

    scene = parse_scene("box:name=a,sx=2,sy=2,sz=2,dynamic=1;box:name=b,sx=2,sy=2,sz=2,dynamic=1")
    exact, bp = make_backend("fcl", scene, "b vs a"), make_backend("basis_point", scene, "b vs a")
    poses = [[0, 0, 0, 0, 0, math.pi / 4], [c, c, 0, 0, 0, math.pi / 4]]
    gap = math.sqrt(2) * c - 2
    eps = 2.0 / scan_counts(bp.config.st, bp.config.dn_rule)
    assert (gap <= eps) == contact                   # the cases straddle the offset
    e, b = exact.query(poses).pairs[0], bp.query(poses).pairs[0]
    assert e.distance == pytest.approx(gap, abs=1e-9)
    assert b.in_contact == contact
    assert b.distance == pytest.approx(gap, abs=1e-6)


@pytest.mark.parametrize("offset, axis", [((1.45, 1.3, 1.1), 0), ((1.3, 1.45, 1.1), 1), ((1.1, 1.3, 1.45), 2)])
def test_honeycomb_reports_the_normal_of_the_axis_with_the_smallest_gap(offset, axis):
    """Two unit balls apart by ``offset`` (|offset| - 2 = 0.237 m), their world boxes overlapping
    on every axis, so each of the three projections runs. Along axis w the balls' surfaces are
    at best min over the common disc of c_w - sqrt(1 - |p - c_uv|^2) - sqrt(1 - |p|^2) apart:
    0.40, 0.47 and 0.64 m across the largest, middle and smallest offset component (worked out
    here on a grid). The reported gap is the smallest section gap, between the exact 0.237 m
    and that 0.40 m, and the normal is the depth axis it was found on."""
    scene = parse_scene("sphere:name=a,r=1,subdiv=3,dynamic=1;sphere:name=b,r=1,subdiv=3,dynamic=1")
    c = np.array(offset)
    gaps = []
    for w in range(3):
        u, v = [k for k in range(3) if k != w]
        g = np.linspace(-1.0, 2.5, 701)
        U, V = np.meshgrid(g, g)
        ra, rb = 1 - U**2 - V**2, 1 - (U - c[u])**2 - (V - c[v])**2
        both = (ra >= 0) & (rb >= 0)
        gaps.append(float((c[w] - np.sqrt(rb[both]) - np.sqrt(ra[both])).min()))
    assert int(np.argmin(gaps)) == axis and sorted(gaps)[1] - min(gaps) > 0.05
    hc = make_backend("honeycomb", scene, "b vs a")
    poses = [[0, 0, 0, 0, 0, 0], [*offset, 0, 0, 0]]
    hc.query(poses)
    r = hc.query(poses).pairs[0]          # at rest: threshold distance 0
    assert not r.in_contact
    assert np.linalg.norm(c) - 2 - 0.01 <= r.distance <= min(gaps) + 0.01
    assert np.abs(r.normal) == pytest.approx(np.eye(3)[axis])
