"""Heading-aware ownership (§3.6.2, fig. 3-7): the region reaches ahead of the avatar, the
arrival distance |r| (1 - ecc cos theta) decides between avatars; eq. 3-12's two readings."""
import numpy as np
import pytest

from immersim.models.network import NetworkConfig
from immersim.models.network.consistency import assign_owners, ellipsoid_axes, heading_distance, mahalanobis_ellipsoid

T, SCALE, AMIN = 0.033, 30.0, 5.0


def _owner(apos, avel, epos, cur, foci="reach"):
    return assign_owners("mahalanobis", np.array(apos, float), np.array(avel, float), np.array(epos, float),
                         np.array(cur), T, SCALE, AMIN, foci)


def test_the_default_reading_reaches_ahead_and_the_literal_one_is_a_circle():
    assert NetworkConfig().ownership_foci == "reach"
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
