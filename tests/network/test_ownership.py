"""Ownership (frame phase 2, §3.6.2, fig. 3-7): the region reaches ahead of the avatar, the
arrival distance |r| (1 - ecc cos theta) decides between avatars; eq. 3-12's two readings; the
small-scene forms (Python floats, positions given as lists, a sorted point index) against the
array code and brute force, bit for bit."""
import numpy as np
import pytest

from immersim.models.network import NetworkConfig
from immersim.models.network import consistency as cons
from immersim.models.network.consistency import assign_owners, ellipsoid_axes, heading_distance, mahalanobis_ellipsoid

T, SCALE, AMIN = 0.033, 30.0, 5.0


def _owner(apos, avel, epos, cur, foci="reach"):
    return assign_owners("mahalanobis", np.array(apos, float), np.array(avel, float), np.array(epos, float),
                         np.array(cur), T, SCALE, AMIN, foci)


def test_the_default_reading_reaches_ahead_and_the_literal_one_is_a_circle():
    assert NetworkConfig().consistency.ownership_foci == "reach"
    v = np.array([[10.0, 0.0]])
    a, b, u, shift = ellipsoid_axes(v, T, SCALE, AMIN, "reach")
    # a = 30 * 0.33 m; foci at the avatar and a ahead: ahead 1.5 a, behind 0.5 a, b = sqrt(3)/2 a
    assert a[0] == pytest.approx(9.9) and b[0] == pytest.approx(np.sqrt(0.75) * 9.9)
    for x, inside in ((1.5 * 9.9 - 1e-9, True), (1.5 * 9.9 + 1e-6, False), (-0.5 * 9.9 + 1e-9, True),
                      (-0.5 * 9.9 - 1e-6, False)):
        assert (mahalanobis_ellipsoid(np.array([x, 0.0]), shift[0], u[0], a[0], b[0]) <= 1.0) == inside
    a, b, u, shift = ellipsoid_axes(v, T, SCALE, AMIN, "frame")
    assert b[0] / a[0] == pytest.approx(np.sqrt(1 - (0.165 / 9.9) ** 2)) and b[0] / a[0] > 0.9998


def test_an_entity_behind_a_moving_avatar_goes_to_the_parked_one_nearby():
    """The reproduction: entity 8.9 m behind an avatar at 10 m/s, a parked avatar 4.6 m away."""
    args = ([[0, 0], [-13.5, 0]], [[10, 0], [0, 0]], [[-8.9, 0]], [1])
    assert _owner(*args)[0] == 1
    assert _owner(*args[:3], [0])[0] == 1           # whoever held it before
    # the mover's region: the 'reach' one ends 0.5 a = 4.95 m behind it; the literal 'frame'
    # one (a near circle of radius ~9.9 m) holds the entity, d = 0.90 (the parked one's 0.92 made
    # the mover the owner when the smallest d decided); the arrival distance 8.9 (1 + 1/60) m
    # > 4.6 m gives it to the parked avatar in both readings
    for foci, held in (("reach", False), ("frame", True)):
        a, b, u, shift = ellipsoid_axes(np.array([[10.0, 0.0]]), T, SCALE, AMIN, foci)
        d = mahalanobis_ellipsoid(np.array([-8.9, 0.0]), shift[0], u[0], a[0], b[0])
        assert (d <= 1.0) == held
        assert _owner(*args, foci=foci)[0] == 1


@pytest.mark.parametrize("ratio, winner", [(1.2, 0), (1.5, 0), (1.9, 0), (2.1, 1), (3.0, 1)])
def test_heading_toward_wins_from_a_parked_avatar_up_to_twice_nearer(ratio, winner):
    """Parked avatar r_p from the entity, a mover at 10 m/s heading straight at it from
    ratio * r_p: arrival distances (1 - 1/2) ratio r_p against r_p, so the mover wins for
    ratio < 2 (inside its region: ratio r_p <= 1.5 a = 14.85 m)."""
    r_p = 4.0
    apos = [[-ratio * r_p, 0.0], [0.0, r_p]]
    assert _owner(apos, [[10, 0], [0, 0]], [[0.0, 0.0]], [1 - winner])[0] == winner


def test_driving_away_never_wins_from_a_nearer_parked_avatar():
    rng = np.random.default_rng(11)
    n = 0
    for _ in range(400):
        e = rng.uniform(-20, 20, 2)
        r_p = rng.uniform(0.5, 4.9)
        phi = rng.uniform(-np.pi, np.pi)
        parked = e + r_p * np.array([np.cos(phi), np.sin(phi)])
        r_m = rng.uniform(r_p, 12.0)               # farther than the parked one
        psi = rng.uniform(-np.pi, np.pi)
        mover = e + r_m * np.array([np.cos(psi), np.sin(psi)])
        speed = rng.uniform(2, 20)
        heading = np.array([np.cos(psi), np.sin(psi)])   # away from the entity (mover - e direction)
        turn = rng.uniform(-1.2, 1.2)                     # up to ~70 degrees off straight away
        c, s = np.cos(turn), np.sin(turn)
        v = speed * np.array([c * heading[0] - s * heading[1], s * heading[0] + c * heading[1]])
        assert _owner([mover, parked], [v, [0, 0]], [e], [0])[0] == 1
        n += 1
    assert n == 400


def test_at_equal_distance_the_avatar_driving_toward_wins_over_the_one_driving_away():
    for cur in (0, 1):
        own = _owner([[-6.0, 0.0], [6.0, 0.0]], [[-8.0, 0.0], [-8.0, 0.0]], [[0.0, 0.0]], [cur])
        assert own[0] == 1      # avatar 1 drives toward x = 0, avatar 0 away from it


def test_arrival_distance_closed_form_and_both_code_paths_agree():
    r = np.array([[3.0, 4.0], [-3.0, 0.0], [0.0, 2.0]])
    u = np.array([[1.0, 0.0]] * 3)
    assert np.allclose(heading_distance(r, u, np.full(3, 0.5)), [5.0 - 1.5, 3.0 + 1.5, 2.0])
    rng = np.random.default_rng(2)
    apos, avel = rng.uniform(0, 60, (6, 2)), rng.normal(0, 8, (6, 2))
    avel[0] = 0.0
    epos = rng.uniform(0, 60, (30, 2))      # 180 pairs: the Python-float path
    cur = rng.integers(0, 6, 30)
    small = assign_owners("mahalanobis", apos, avel, epos, cur, T, SCALE, AMIN, "reach")
    big = assign_owners("mahalanobis", apos, avel, epos, cur, T, SCALE, AMIN, "reach",
                        lists=None, etree=__import__("scipy.spatial", fromlist=["cKDTree"]).cKDTree(epos))
    assert np.array_equal(small, big) and (small != cur).sum() >= 3


@pytest.mark.parametrize("rule,foci", [("mahalanobis", "frame"), ("mahalanobis", "reach"), ("euclidean", "frame")])
def test_scalar_ownership_equals_the_array_code(rule, foci):
    rng = np.random.default_rng(5)
    for trial in range(300):
        G, E = rng.integers(1, 6), rng.integers(1, 30)
        apos = rng.uniform(0, 20, (G, 2))
        vel = rng.normal(0, 8, (G, 2)) * (rng.random((G, 1)) < 0.7)     # some avatars at rest
        if trial % 7 == 0:
            vel[:] = np.round(vel)                                       # exact ties of speed
        epos = np.r_[apos[rng.integers(0, G, E // 2)] + rng.normal(0, 3, (E // 2, 2)), rng.uniform(0, 20, (E - E // 2, 2))]
        cur = rng.integers(0, G, E)
        min_axis = 0.0 if trial % 11 == 0 else float(rng.choice([0.5, 2.0, 5.0]))   # 0: degenerate (array code)
        args = (rule, apos, vel, epos, cur, T, 30.0, min_axis, foci)
        with np.errstate(divide="ignore", invalid="ignore"):   # a = 0: the array code's inf/NaN
            fast = cons.assign_owners(*args)
            plain = cons.assign_owners(*args, scalar_pairs=-1)
        np.testing.assert_array_equal(fast, plain)


def test_ownership_from_lists_equals_the_arrays():
    """``assign_owners`` given the positions and velocities as lists (the small frame's; the
    velocity array left out) gives the array call's owners, degenerate ellipsoids included
    (``min_axis`` 0 and a resting avatar: the array code from the listed velocities)."""
    rng = np.random.default_rng(8)
    for trial in range(200):
        G, E = int(rng.integers(1, 5)), int(rng.integers(1, 12))
        apos = rng.uniform(0, 20, (G, 2))
        vel = rng.normal(0, 8, (G, 2)) * (rng.random((G, 1)) < 0.7)
        epos = rng.uniform(0, 20, (E, 2))
        cur = rng.integers(0, G, E)
        min_axis = 0.0 if trial % 5 == 0 else 5.0
        for rule in ("mahalanobis", "euclidean"):
            with np.errstate(divide="ignore", invalid="ignore"):
                ref = cons.assign_owners(rule, apos, vel, epos, cur, T, 30.0, min_axis)
                out = cons.assign_owners(rule, apos, None, epos, cur, T, 30.0, min_axis,
                                         lists=(apos.tolist(), vel.tolist(), epos.tolist()))
            np.testing.assert_array_equal(out, ref)


@pytest.mark.parametrize("foci", ["frame", "reach"])
def test_point_index_owners_equal_kd_tree_and_brute_force(foci):
    from scipy.spatial import cKDTree

    from immersim.models.network.consistency import PointIndex, assign_owners

    rng = np.random.default_rng(5)
    apos, avel = rng.uniform(0, 200, (30, 2)), rng.normal(0, 10, (30, 2))
    epos = rng.uniform(0, 200, (2000, 2))
    cur = rng.integers(0, 30, 2000)
    args = ("mahalanobis", apos, avel, epos, cur, 0.033, 30.0, 4.0, foci)
    via_index = assign_owners(*args, etree=PointIndex(epos))
    via_tree = assign_owners(*args, etree=cKDTree(epos))
    brute = cur.copy()
    from immersim.models.network.consistency import ellipsoid_axes, mahalanobis_ellipsoid
    a, b, u, shift = ellipsoid_axes(avel, 0.033, 30.0, 4.0, foci)
    d = mahalanobis_ellipsoid(epos[:, None, :], (apos + shift)[None], u[None], a[None], b[None])   # (E, G)
    inside = d <= 1.0
    # among the regions holding an entity the smallest arrival distance |r| - ecc r.u wins
    r = epos[:, None, :] - apos[None]
    ecc = np.hypot(*shift.T) / a
    L = np.hypot(r[..., 0], r[..., 1]) - ecc[None] * np.einsum("egi,gi->eg", r, u)
    brute[inside.any(1)] = np.where(inside, L, np.inf).argmin(1)[inside.any(1)]
    assert np.array_equal(via_index, via_tree) and np.array_equal(via_index, brute)
    assert (via_index != cur).sum() > 20
