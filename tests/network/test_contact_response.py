"""Contact response that keeps bodies apart: closed forms of response.py, the avatar's
position correction and jolt, avatar-entity separation, and a full-throttle avatar driven into
a tank in closed loop with the collision unit's model (the network responds in the step the
collision model reports the contact, as benchmarks/bench_contact.py wires it)."""
import math
from functools import lru_cache

import numpy as np
import pytest

from immersim.models.collision import BackendConfig, make_backend, parse_scene
from immersim.models.network import NetworkConfig, NetworkModel
from immersim.models.network.response import impulse, inverse_mass, separation

H = 0.033


def _energy(m, v):
    return 0.5 * np.sum(np.where(np.isinf(m), 0.0, m)[:, None] * v * v)


def test_impulse_conserves_momentum_obeys_restitution_and_never_adds_energy():
    rng = np.random.default_rng(3)
    k = 400
    m1, m2 = rng.uniform(1, 2000, k), rng.uniform(1, 2000, k)
    m2[:50] = np.inf                                   # static partners
    v1, v2 = rng.normal(0, 10, (k, 2)), rng.normal(0, 10, (k, 2))
    v2[:50] = 0.0                                      # (a static body does not move)
    phi = rng.uniform(-np.pi, np.pi, k)
    n = np.c_[np.cos(phi), np.sin(phi)]
    for e in (0.0, 0.5, 1.0):
        dv1, dv2 = impulse(inverse_mass(m1), inverse_mass(m2), v1, v2, n, e)
        u0 = np.einsum("ij,ij->i", v1 - v2, n)
        u1 = np.einsum("ij,ij->i", v1 + dv1 - v2 - dv2, n)
        app = u0 < 0
        assert np.allclose(u1[app], -e * u0[app]) and np.array_equal(u1[~app], u0[~app])
        fin = np.isfinite(m2)
        p0 = m1[fin, None] * v1[fin] + m2[fin, None] * v2[fin]
        p1 = m1[fin, None] * (v1 + dv1)[fin] + m2[fin, None] * (v2 + dv2)[fin]
        assert np.allclose(p0, p1, rtol=0, atol=1e-8 * np.abs(p0).max())
        assert np.all(dv2[~fin] == 0.0)
        for i in range(k):   # kinetic energy: change (e^2 - 1) u^2 / (2 (w1 + w2)) <= 0
            ms = np.array([m1[i], m2[i]])
            before = _energy(ms, np.array([v1[i], v2[i]]))
            after = _energy(ms, np.array([v1[i] + dv1[i], v2[i] + dv2[i]]))
            w = 1 / m1[i] + (0.0 if np.isinf(m2[i]) else 1 / m2[i])
            expect = (e * e - 1) * min(u0[i], 0.0) ** 2 / (2 * w)
            assert after - before == pytest.approx(expect, abs=1e-6 * max(before, 1.0))
            assert after <= before + 1e-9 * max(before, 1.0)


def test_separation_removes_the_depth_keeps_the_mass_centre_and_spares_static_bodies():
    n = np.array([[0.6, 0.8], [1.0, 0.0]])
    dx1, dx2 = separation(inverse_mass([100.0, 100.0]), inverse_mass([300.0, np.inf]), n, [0.4, 0.25])
    assert np.allclose(dx1 - dx2, [[0.24, 0.32], [0.25, 0.0]])      # the gap opens by the depth
    assert np.allclose(100 * dx1[0] + 300 * dx2[0], 0.0)            # centre of mass stays
    assert np.allclose(dx1[0], 0.75 * 0.4 * n[0]) and np.all(dx2[1] == 0.0)


def _model(**kw):
    cfg = NetworkConfig.from_flat(groups=1, render_nodes=1, entities=0, driven_groups=1, seed=0, scene_size=200.0, **kw)
    return NetworkModel(cfg)


def test_bounce_corrects_the_position_and_the_jolt_is_the_velocity_change_only():
    m = _model()
    w = m.world
    w.apos[0] = (50.0, 50.0)
    w.yaw[0], w.speed[0] = 0.0, 10.0
    jolt = m.bounce(0, (-1.0, 0.0), restitution=0.5, depth=0.3)
    assert np.allclose(w.apos[0], (49.7, 50.0))
    assert np.allclose(w.avel[0], (-5.0, 0.0)) and jolt == pytest.approx(15.0)
    # receding, but still inside: moved out, no velocity change, no jolt
    jolt = m.bounce(0, (-1.0, 0.0), restitution=0.5, depth=0.2)
    assert jolt == 0.0 and np.allclose(w.apos[0], (49.5, 50.0)) and np.allclose(w.avel[0], (-5.0, 0.0))


def test_an_entity_inside_an_avatar_is_pushed_out_whole():
    """The entity leaves the overlap; the avatar keeps its position whatever the masses (its
    contacts with the static scene are the collision unit's)."""
    cfg = dict(groups=1, render_nodes=1, entities=1, driven_groups=1, seed=0, scene_size=200.0)
    for m_a, share in ((math.inf, 1.0), (300.0, 1.0), (1000.0, 1.0)):
        m = NetworkModel(NetworkConfig.from_flat(avatar_mass=m_a, entity_mass=100.0, **cfg))
        w = m.world
        w.apos[0], w.epos[0] = (100.0, 100.0), (101.0, 100.0)     # 2 m overlap (radii 2 + 1)
        w.speed[0], w.evel[0] = 0.0, (0.0, 0.0)
        w.contacts()
        assert w.epos[0, 0] - w.apos[0, 0] == pytest.approx(3.0)
        assert w.epos[0, 0] == pytest.approx(101.0 + 2.0 * share)


def test_an_offline_avatar_neither_pushes_an_entity_nor_takes_an_impulse():
    """An avatar without a master (offline) takes no part in avatar-entity contacts: the entity
    it overlaps stays where it is, and neither body's velocity changes."""
    m = NetworkModel(NetworkConfig.from_flat(groups=1, render_nodes=1, entities=1, driven_groups=1, seed=0,
                                             scene_size=200.0, avatar_mass=300.0, entity_mass=100.0))
    w = m.world
    w.apos[0], w.epos[0] = (100.0, 100.0), (101.0, 100.0)     # 2 m overlap, approaching
    w.yaw[0], w.speed[0], w.evel[0] = 0.0, 8.0, (-2.0, 0.0)
    ai, ei, dv = w.contacts(online=np.array([False]))
    assert len(ai) == len(ei) == len(dv) == 0
    assert tuple(w.epos[0]) == (101.0, 100.0) and w.speed[0] == 8.0 and w.jolt[0] == 0.0
    ai, ei, dv = w.contacts(online=np.array([True]))   # the same pair online: pushed and bounced
    assert list(ai) == [0] and w.epos[0, 0] == pytest.approx(103.0) and w.speed[0] < 8.0


def test_entity_collision_with_finite_masses_gains_no_energy():
    m = NetworkModel(NetworkConfig.from_flat(groups=1, render_nodes=1, entities=1, driven_groups=1, seed=0,
                                             scene_size=200.0, avatar_mass=300.0, entity_mass=100.0))
    w = m.world
    w.apos[0], w.epos[0] = (100.0, 100.0), (102.9, 100.0)
    w.yaw[0], w.speed[0], w.evel[0] = 0.0, 8.0, (-2.0, 0.0)
    e0 = 0.5 * 300 * 8.0 ** 2 + 0.5 * 100 * 4.0
    p0 = 300 * 8.0 - 100 * 2.0
    ai, ei, dv = w.contacts()
    v_e = w.evel[0] + dv[0]
    v_a = w.avel[0]
    assert 300 * v_a[0] + 100 * v_e[0] == pytest.approx(p0)
    assert 0.5 * 300 * v_a @ v_a + 0.5 * 100 * v_e @ v_e <= e0
    assert v_e[0] - v_a[0] == pytest.approx(0.5 * 10.0)            # restitution 0.5 of the 10 m/s approach


# -- closed loop with the collision model -----------------------------------------------------------
TANK = "box:name=av,sx=4,sy=2,sz=4.4,dynamic=1;tank:name=t,tris=5.4k,x=100,y=100,yaw=0"


@lru_cache(maxsize=1)
def _scene():
    return parse_scene(TANK)


def _drive(throttle, steer, n_steps, start=(100.0, 80.0), yaw=math.pi / 2, v0=0.0, **cfg):
    """Avatar driven by ``throttle(k), steer(k)`` against a tank at (100, 100) (side face y = 98.3);
    the collision model sees the avatar's pose after each network step, the network responds to
    that report at the start of its next step. Returns per step (depth, contact, |v|, v.n, n)."""
    m = _model(**cfg)
    w = m.world
    w.apos[0], w.yaw[0], w.speed[0] = start, yaw, v0
    coll = make_backend("fcl", _scene(), "av vs t (horizontal)", BackendConfig(max_distance=2.0))
    out = []
    res = coll.query([*w.apos[0], 2.5, 0.0, 0.0, w.yaw[0]], H).pairs[0]
    for k in range(n_steps):
        v_before = float(np.hypot(*w.avel[0]))
        m.set_input(0, throttle(k), steer(k), m.t)
        if res.in_contact:
            m.bounce(0, res.normal[:2], depth=res.depth)
        m.step(H)
        res = coll.query([*w.apos[0], 2.5, 0.0, 0.0, w.yaw[0]], H).pairs[0]
        v = w.avel[0]
        out.append((res.depth if res.in_contact else 0.0, res.in_contact, max(v_before, float(np.hypot(*v))),
                    float(v @ res.normal[:2]), res.normal[:2].copy()))
    return out


@pytest.mark.parametrize("y0", [92.0, 85.0, 75.0])
def test_full_throttle_into_a_tank_never_sinks_deeper_than_one_step_of_travel(y0):
    rows = _drive(lambda k: 1.0, lambda k: 0.0, 150, start=(100.0, y0))
    assert any(r[1] for r in rows)
    for depth, c, sp, vn, n in rows:
        assert depth <= sp * H + 0.05
        if c:
            assert np.allclose(n, [0.0, -1.0], atol=1e-9)   # out of the side face, the short way


def test_one_step_after_the_response_the_depth_is_below_1_cm_unless_pushed_in_again():
    rows = _drive(lambda k: 1.0 if k < 40 else 0.0, lambda k: 0.0, 120, start=(100.0, 92.0))
    seen = 0
    for k in range(len(rows) - 1):
        if rows[k][1]:                               # reported: the response acts in step k + 1
            depth, c, sp, vn, n = rows[k + 1]
            if vn >= 0.0:                            # not driven back in
                assert depth < 0.01
                seen += 1
    assert seen >= 1


def test_the_avatar_leaves_the_contact_when_steered_away():
    """Pressed against the side face (heading 30 degrees into it, full throttle), then the driver
    steers away: the contact ends within 1 s."""
    turn = 60
    rows = _drive(lambda k: 1.0 if k < turn else 0.6, lambda k: 0.0 if k < turn else -1.0, 150,
                  start=(96.0, 93.0), yaw=math.radians(30.0), v0=3.0)
    assert any(r[1] for r in rows[:turn])
    after = [r[1] for r in rows[turn:]]
    last = max([i for i, c in enumerate(after) if c], default=-1)
    assert (last + 1) * H <= 1.0


def _corners(xy, yaw, a=2.0, b=1.0):
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[xy[0] + c * u - s * v, xy[1] + s * u + c * v] for u in (-a, a) for v in (-b, b)])


@pytest.mark.parametrize("deg", [-80.0, -60.0, -30.0])
def test_a_turning_bounce_leaves_the_box_touching_the_face(deg):
    """A 4 x 2 m box 0.25 m into the face y = 0 (heading ``deg`` into it) bounces (e = 0.5): the
    reflected velocity turns the box; with its footprint known the response moves it out by the
    depth plus the turn's extra reach, so its lowest corner ends on the face (or above it, when
    the turn shortens its reach) and the jolt is the velocity change alone."""
    yaw, d = math.radians(deg), 0.25
    xy = np.array([50.0, 0.0])
    xy[1] -= _corners(xy, yaw)[:, 1].min() + d            # lowest corner 0.25 m below the face
    low = {}
    for box in ((0.0, 0.0), (4.0, 2.0)):
        m = _model(avatar_length=box[0], avatar_width=box[1])
        w = m.world
        w.apos[0], w.yaw[0], w.speed[0] = xy, yaw, 10.0
        v0 = w.avel[0].copy()
        jolt = m.bounce(0, (0.0, 1.0), restitution=0.5, depth=d)
        v1 = w.avel[0]
        assert v1[1] == pytest.approx(-0.5 * v0[1]) and v1[0] == pytest.approx(v0[0])
        assert jolt == pytest.approx(float(np.hypot(*(v1 - v0))), rel=1e-12)
        low[box] = _corners(w.apos[0], float(w.yaw[0]))[:, 1].min()
    # reach of the half-extents along y before and after: 2 |sin| + |cos|
    grow = 2 * abs(math.sin(math.atan2(-0.5 * math.sin(yaw), math.cos(yaw)))) + abs(math.cos(
        math.atan2(-0.5 * math.sin(yaw), math.cos(yaw)))) - (2 * abs(math.sin(yaw)) + abs(math.cos(yaw)))
    assert low[(0.0, 0.0)] == pytest.approx(-grow, abs=1e-9)    # without the box: the turn alone swings it
    assert low[(4.0, 2.0)] == pytest.approx(max(-grow, 0.0), abs=1e-9)    # touching (or clear)


@pytest.mark.parametrize("yaw_deg, start", [(-135.0, (109.0, 105.5)), (-150.0, (110.0, 104.0)), (-160.0, (110.0, 103.0))])
def test_into_the_corner_of_hull_and_barrel_at_full_throttle(yaw_deg, start):
    """Driven at full throttle, obliquely, into the tank's front (the concave corner of the
    hull's front face and the barrel's side): the depth never exceeds one step's travel plus
    5 cm, and one step after each response it is below 1 cm unless the avatar moves in again."""
    rows = _drive(lambda k: 1.0, lambda k: 0.0, 150, start=start, yaw=math.radians(yaw_deg), v0=5.0,
                  avatar_length=4.0, avatar_width=2.0)
    assert any(r[1] for r in rows)
    for k, (depth, c, sp, vn, n) in enumerate(rows):
        assert depth <= sp * H + 0.05
        if k and rows[k - 1][1] and vn >= 0.0:
            assert depth < 0.01
