"""Ground truth of the shared scene: avatars with simple vehicle kinematics, free entities.

Avatars (one per control platform) follow a kinematic bicycle model driven by the
ControllerPacket quantities (seed line ~711): ``throttle`` in [-1, 1] scales the acceleration
``mAcceleration = throttle * max_accel`` and ``steer`` in [-1, 1] the steering angle, which
gives the small orientation change ``mTinyOrient = yaw_rate * dt``::

    dv/dt   = max_accel * throttle - drag * v,    |v| <= max_speed
    dyaw/dt = v * tan(steer * max_steer) / wheelbase
    dx/dt   = v cos(yaw),  dy/dt = v sin(yaw)

Body-frame specific force (x forward, y left, z up) ``f = (dv/dt, v * dyaw/dt, g)`` and angular
rate ``w = (0, 0, dyaw/dt)`` feed the motion platform's washout. Free entities move on the
ground with a constant turn rate and linear drag (``dv/dt = w_e J v - drag_e v``) so that
their motion is smooth but curved (dead reckoning of order 2 has something to gain). Everyone
reflects off the scene's walls. Collision responses (inputs) move an avatar out of the obstacle
by the penetration depth along the normal and bounce or stop it: ``v <- v - (1 + e) (v.n) n``
for ``v.n < 0``. Avatar-entity contacts: the entity leaves the overlap, the impulse is split by
inverse mass (:mod:`.response`; the avatar's share along its heading).
"""
from __future__ import annotations

import math

import numpy as np

from .config import NetworkConfig
from .consistency import PointIndex
from .paths import Paths
from .response import impulse, inverse_mass, separation

G_ACC = 9.81
#: at most this many sub-step lengths keep the entities' per-sub-step turn (see _advance_entities)
TURN_MEMO = 64


def _clip_unit(x) -> float:
    """``float(np.clip(x, -1.0, 1.0))`` of a number, in Python (NaN stays NaN)."""
    x = float(x)
    return -1.0 if x < -1.0 else 1.0 if x > 1.0 else x


def _any_within(a: list, b: list, r2: float) -> bool:
    """Some point of ``a`` and some point of ``b`` (lists of ``[x, y]``) are at most
    ``sqrt(r2)`` apart: ``(bx - ax)^2 + (by - ay)^2 <= r2`` (the differences squared as products)."""
    for ax, ay in a:
        for bx, by in b:
            dx = bx - ax
            dx2 = dx * dx
            if dx2 <= r2:     # else dx^2 + dy^2 >= dx^2 > r2 (a rounded sum does not drop below a term)
                dy = by - ay
                if dx2 + dy * dy <= r2:
                    return True
    return False


def half_extent(a: float, b: float, yaw: float, n) -> float:
    """Half-extent (m) along the unit vector ``n`` (2,) of a box of half-length ``a`` (along
    the heading ``yaw``, rad) and half-width ``b``: ``a |cos(yaw - phi)| + b |sin(yaw - phi)|``."""
    c, s = math.cos(yaw), math.sin(yaw)
    return a * abs(c * n[0] + s * n[1]) + b * abs(-s * n[0] + c * n[1])


def ball_pairs(a: np.ndarray, b: np.ndarray, r: float):
    """Every pair (i, j) of points ``a[i]`` (n, 2), ``b[j]`` (m, 2) m at most ``r`` m apart,
    ``dx dx + dy dy <= r r``, by ``i`` then ``j``: the pairs and order of a k-d tree's
    ``query_ball_tree`` (its lists are sorted), from the same squared distances."""
    dx = b[:, 0] - a[:, 0, None]
    dy = b[:, 1] - a[:, 1, None]
    return np.nonzero(dx * dx + dy * dy <= r * r)


def _frozen(a: np.ndarray) -> np.ndarray:
    """``a`` made read-only (a shared constant)."""
    a.flags.writeable = False
    return a


#: the result of :meth:`World.contacts` without a contact (shared, read-only)
_NO_CONTACTS = (_frozen(np.zeros(0, int)), _frozen(np.zeros(0, int)), _frozen(np.zeros((0, 2))))


def _reflect_avatars(apos: np.ndarray, yaw: np.ndarray, speed: np.ndarray, S: float):
    """Avatars (positions (n, 2) m, headings (n,) rad, speeds (n,) m/s) reflected off the walls
    of the scene ``[0, S]^2``: positions clipped, the velocity component across a wall reversed
    (heading and speed from the new velocity). Rows inside the scene are returned unchanged;
    ``yaw`` and ``speed`` are modified in place."""
    out = (apos < 0.0) | (apos > S)
    if not out.any():
        return apos, yaw, speed
    apos = np.clip(apos, 0.0, S)
    vel = np.empty((len(yaw), 2))
    np.cos(yaw, out=vel[:, 0])
    np.sin(yaw, out=vel[:, 1])
    vel *= speed[:, None]
    vel[out] *= -1.0
    rows = out.any(axis=1)
    yaw[rows] = np.arctan2(vel[rows, 1], vel[rows, 0])
    speed[rows] = np.abs(speed[rows])
    return apos, yaw, speed


class World:
    """Vectorised state of ``G`` avatars and ``E`` free entities (SI units, z up); ``paths``
    chooses the Python-float forms of tiny scenes and the resting shortcut (:class:`paths.Paths`)."""

    def __init__(self, cfg: NetworkConfig, rng: np.random.Generator, paths: Paths = Paths()) -> None:
        G, E, S = cfg.groups, cfg.entities, cfg.scene.scene_size
        self.cfg = cfg
        self.paths = paths
        self.t = self.ta = self.te = 0.0
        if cfg.world.avatar_start == "uniform":
            self.apos = rng.uniform(0.05 * S, 0.95 * S, (G, 2))
        else:  # a common start area: a disc around the scene centre
            ring = min(5.0 * np.sqrt(G), 0.4 * S) * np.sqrt(rng.uniform(0.05, 1.0, G))
            phi = rng.uniform(-np.pi, np.pi, G)
            self.apos = 0.5 * S + ring[:, None] * np.c_[np.cos(phi), np.sin(phi)]
        self.yaw = rng.uniform(-np.pi, np.pi, G)
        self.speed = np.zeros(G)
        self.throttle = np.zeros(G)
        self.steer = np.zeros(G)
        self.accel = np.zeros(G)        # dv/dt of the last sub-step (m/s^2)
        self.yaw_rate = np.zeros(G)     # rad/s
        self.jolt = np.zeros(G)         # |dv| from collision responses since last reset (m/s)
        self.epos = rng.uniform(0.0, S, (E, 2))
        ang = rng.uniform(-np.pi, np.pi, E)
        self.evel = cfg.world.entity_speed * np.c_[np.cos(ang), np.sin(ang)]
        self.eturn = rng.uniform(-0.2, 0.2, E)   # rad/s
        self.ez = np.full(E, cfg.world.entity_radius)
        self.separated = 0         # avatar-entity overlaps removed so far (see _separate)
        # inverse masses (1/kg) of the avatar-entity contacts (response.py), fixed by the config
        self._w_entity, self._w_avatar = float(inverse_mass(cfg.world.entity_mass)), float(inverse_mass(cfg.world.avatar_mass))
        self._fixed_key = None     # see at_fixed_point
        self._ksteer_memo = None   # (steering bytes, steering gains tan(steer max) / wheelbase)
        self._turn_memo = {}       # (sub-step h, turn rates) -> decay, cos and sin of the entities' turn per sub-step
        self._state_memo = None    # (avatar key, P, V, A) of a scene without entities at rest
        self._trig_memo = None     # (heading bytes, their cosines, sines)

    # -- views ----------------------------------------------------------------------------
    @property
    def avel(self) -> np.ndarray:
        """Avatar velocity (G, 2), m/s."""
        out = np.empty((len(self.yaw), 2))
        np.cos(self.yaw, out=out[:, 0])
        np.sin(self.yaw, out=out[:, 1])
        out *= self.speed[:, None]
        return out

    def positions(self) -> np.ndarray:
        """All objects (avatars then entities), (G + E, 2)."""
        return np.concatenate([self.apos, self.epos])

    def state(self, acc: bool = True):
        """Positions (m), velocities (m/s), accelerations (m/s^2), each (G + E, 2), of all
        objects, avatars first (P as :meth:`positions`, V of the avatars as :attr:`avel`).

        Avatars: ``v = speed (cos yaw, sin yaw)``, world-frame ``a = accel (cos, sin) + speed *
        yaw rate (-sin, cos)``; entities: ``a = eturn (-vy, vx) - drag v``. Written column by
        column into fresh arrays (one cos/sin of the headings). A scene without entities whose
        avatars rest at a fixed point gets the same arrays again (callers only read them).
        ``acc`` False: A is None (a caller that does not use it)."""
        if self.paths.rest_skip and not len(self.evel) and self._fixed_key is not None:   # at rest, no entities
            memo = self._state_memo
            if memo is not None and memo[0] == self._avatar_key() and (memo[3] is not None or not acc):
                return memo[1], memo[2], memo[3] if acc else None
        c, s = self._headings()
        G, E = len(c), len(self.evel)
        n = G + E
        P, V = np.concatenate((self.apos, self.epos)), np.empty((n, 2))
        sp = self.speed
        np.multiply(c, sp, out=V[:G, 0])
        np.multiply(s, sp, out=V[:G, 1])
        V[G:] = self.evel
        if not acc:
            if self._fixed_key is not None and not E:
                self._state_memo = (self._avatar_key(), P, V, None)
            return P, V, None
        A = np.empty((n, 2))
        lat = sp * self.yaw_rate
        acc = self.accel
        np.subtract(acc * c, lat * s, out=A[:G, 0])
        np.add(acc * s, lat * c, out=A[:G, 1])
        if E:
            v = self.evel
            vx, vy = v[:, 0], v[:, 1]
            drag = self.cfg.world.entity_drag
            # eturn * (-vy) - drag vx, eturn * vx - drag vy
            np.subtract(self.eturn * -vy, drag * vx, out=A[G:, 0])
            np.subtract(self.eturn * vx, drag * vy, out=A[G:, 1])
        elif self._fixed_key is not None:
            self._state_memo = (self._avatar_key(), P, V, A)
        return P, V, A

    def _headings(self, lists: bool = False):
        """``np.cos(yaw), np.sin(yaw)`` (G,) (not to be written), kept while the headings stay (the frame's
        :meth:`state` and the step's :meth:`avatar_outputs` read the same ones); ``lists``: the
        same values as two lists of Python floats."""
        key = self.yaw.tobytes()
        memo = self._trig_memo
        if memo is None or memo[0] != key:
            memo = self._trig_memo = [key, np.cos(self.yaw), np.sin(self.yaw), None]   # (callers only read them)
        if lists:
            if memo[3] is None:
                memo[3] = (memo[1].tolist(), memo[2].tolist())
            return memo[3]
        return memo[1], memo[2]

    def avatar_velocities(self) -> list:
        """Avatar velocities ``[[vx, vy], ...]`` (m/s) in Python floats: the rows of :attr:`avel`
        and of the avatars' V in :meth:`state` (the same products)."""
        c, s = self._headings(lists=True)
        return [[a * v, b * v] for a, b, v in zip(c, s, self.speed.tolist())]

    #: indices of the constant fields of :meth:`avatar_outputs` (z, f_z, w_x, w_y: flat ground)
    CONSTANT_OUTPUTS = (2, 8, 9, 10)

    def avatar_outputs(self, h=None, constants: bool = True) -> list:
        """Per avatar ``x, y, z, yaw, vx, vy``, the body-frame specific force (m/s^2, gravity
        included on z: ``accel, v * yaw rate, g``), the body-frame angular rate (rad/s:
        ``0, 0, yaw rate``), the jolt (m/s) and ``jolt / h`` (m/s^2, 0 without ``h``): 14
        Python floats per avatar in one flat list (the same products as :attr:`avel`).
        ``constants`` False: without the four that never change (:attr:`CONSTANT_OUTPUTS`), 10 per avatar."""
        c, s = self._headings(lists=True)
        out = []
        rows = zip(self.apos.tolist(), self.yaw.tolist(), self.speed.tolist(), c, s, self.accel.tolist(),
                   self.yaw_rate.tolist(), self.jolt.tolist())
        if constants:
            for (x, y), w, v, c, s, a, yr, j in rows:
                out += (x, y, 0.0, w, c * v, s * v, a, v * yr, G_ACC, 0.0, 0.0, yr, j, j / h if h else 0.0)
        else:
            for (x, y), w, v, c, s, a, yr, j in rows:
                out += (x, y, w, c * v, s * v, a, v * yr, yr, j, j / h if h else 0.0)
        return out

    def moving(self, eps: float = 1e-9) -> bool:
        """Some avatar or entity moves faster than ``eps`` (m/s), or some throttle is set."""
        if len(self.speed) <= self.paths.scalar_avatars and len(self.evel) <= self.paths.scalar_entities:   # tiny: plain Python
            return (any(abs(v) > eps for v in self.speed.tolist())
                    or any(abs(v) > eps for v in self.evel.ravel().tolist()) or any(self.throttle.tolist()))
        return bool(np.any(np.abs(self.speed) > eps) or np.any(np.abs(self.evel) > eps)
                    or np.any(self.throttle != 0.0))

    # -- dynamics ---------------------------------------------------------------------------
    def advance_to(self, t: float, avatars: bool = True, entities: bool = True) -> None:
        """Advance avatars and/or entities to time ``t`` (s). The two have their own clocks:
        entity motion does not depend on avatar inputs between frames, so an input event only
        needs the avatars brought up to its time."""
        if avatars and t > self.ta:
            self._advance_avatars(t - self.ta)
            self.ta = t
        if entities and t > self.te:
            self._advance_entities(t - self.te)
            self.te = t
        self.t = max(self.ta, self.te)

    def _substeps(self, dt: float):
        n = max(1, math.ceil(dt / (self.cfg.scene.frame_s / self.cfg.world.substeps) - 1e-9))
        return n, dt / n

    def _avatar_key(self) -> tuple:
        """Every avatar array a sub-step reads or writes, as bytes."""
        return (self.apos.tobytes(), self.yaw.tobytes(), self.speed.tobytes(), self.throttle.tobytes(),
                self.steer.tobytes(), self.accel.tobytes(), self.yaw_rate.tobytes())

    def at_fixed_point(self) -> bool:
        """The avatars rest at a fixed point of the sub-step (no throttle, no speed, and the
        last advance's first sub-step changed nothing) and nothing touched them since: a
        further advance would leave every avatar array as it is."""
        return self.paths.rest_skip and self._fixed_key is not None and self._fixed_key == self._avatar_key()

    def _advance_avatars(self, dt: float) -> None:
        if len(self.speed) <= self.paths.scalar_avatars and self.at_fixed_point():
            return
        cfg = self.cfg
        n, h = self._substeps(dt)
        if len(self.speed) <= self.paths.scalar_avatars:
            key = self.steer.tobytes()
            memo = self._ksteer_memo
            if memo is None or memo[0] != key:   # the steering gains, kept while the steering stays
                k = np.tan(self.steer * cfg.world.max_steer_rad) / cfg.world.wheelbase
                memo = self._ksteer_memo = (key, k.tolist())
            return self._advance_avatars_scalar(n, h, memo[1])
        k_steer = np.tan(self.steer * cfg.world.max_steer_rad) / cfg.world.wheelbase
        # no throttle and no speed: a sub-step leaves speed and position as they are; once it
        # also leaves the (normalised) heading unchanged, every further one repeats it exactly
        still = not self.throttle.any() and not self.speed.any()
        for _ in range(n):
            yaw0 = self.yaw
            v0 = self.speed
            a = cfg.world.max_accel * self.throttle - cfg.world.drag * v0
            v1 = np.minimum(np.maximum(v0 + a * h, -cfg.world.max_speed), cfg.world.max_speed)
            self.accel = (v1 - v0) / h
            vm = 0.5 * (v0 + v1)
            self.yaw_rate = vm * k_steer
            yaw_m = self.yaw + 0.5 * self.yaw_rate * h
            step = vm * h
            apos = np.empty_like(self.apos)
            np.multiply(step, np.cos(yaw_m), out=apos[:, 0])
            np.multiply(step, np.sin(yaw_m), out=apos[:, 1])
            apos += self.apos
            self.apos = apos
            self.yaw = np.mod(self.yaw + self.yaw_rate * h + np.pi, 2 * np.pi) - np.pi
            self.speed = v1
            self._avatar_walls()
            if still and np.array_equal(self.yaw, yaw0):
                break

    def _advance_avatars_scalar(self, n: int, h: float, ks: list) -> None:
        """:meth:`_advance_avatars` for a few avatars in Python floats: the same operations in
        the same order (IEEE double either way), without ~30 numpy calls per sub-step.

        Avatars do not interact within an advance, so each one runs its sub-steps in turn
        (the array code's sub-step loop outside, the avatars inside, gives the same values).
        A resting fleet stops where the array code does: at rest (no throttle, no speed) an
        avatar whose heading a sub-step leaves unchanged repeats that sub-step exactly, so it
        stops there by itself, and the fleet is at a fixed point when every avatar stopped
        after its first sub-step. A wall hit goes through the array code
        (:func:`_reflect_avatars`) for that avatar."""
        cfg = self.cfg
        S, ms, acc, drag = cfg.scene.scene_size, cfg.world.max_speed, cfg.world.max_accel, cfg.world.drag
        pi, two_pi = np.pi, 2 * np.pi
        thr = self.throttle.tolist()
        sp, yaw = self.speed.tolist(), self.yaw.tolist()
        xy = self.apos.tolist()
        still = not any(thr) and not any(sp)
        first = True
        cos, sin, nms = math.cos, math.sin, -ms
        G = len(sp)
        out = [0.0] * (6 * G)     # x, y per avatar, then yaw, speed, accel, yaw rate per avatar
        for i, (v0, th, k, yw, (xi, yi)) in enumerate(zip(sp, thr, ks, yaw, xy)):
            a0 = yr = 0.0
            push = acc * th     # max_accel * throttle (the same every sub-step)
            for j in range(n):
                a = push - drag * v0
                v1 = v0 + a * h     # clipped to [-ms, ms] (np.minimum(np.maximum(., -ms), ms))
                if v1 < nms:
                    v1 = nms
                elif v1 > ms:
                    v1 = ms
                a0 = (v1 - v0) / h
                vm = 0.5 * (v0 + v1)
                yr = vm * k
                yaw_m = yw + 0.5 * yr * h
                step = vm * h
                xn = step * cos(yaw_m) + xi
                yn = step * sin(yaw_m) + yi
                yw2 = (yw + yr * h + pi) % two_pi - pi
                if xn < 0.0 or yn < 0.0 or xn > S or yn > S:    # a wall: the array code
                    p, w, v = _reflect_avatars(np.array([[xn, yn]]), np.array([yw2]), np.array([v1]), S)
                    (xn, yn), = p.tolist()
                    yw2, v1 = float(w[0]), float(v[0])
                fixed = still and yw2 == yw
                xi, yi, yw, v0 = xn, yn, yw2, v1
                if fixed:
                    break
            else:
                j = n             # every sub-step ran
            if not (still and j == 0):
                first = False
            out[2 * i] = xi
            out[2 * i + 1] = yi
            out[2 * G + i] = yw
            out[3 * G + i] = v0
            out[4 * G + i] = a0
            out[5 * G + i] = yr
        arr = np.array(out)
        self.apos = arr[:2 * G].reshape(G, 2)
        self.yaw, self.speed = arr[2 * G:3 * G], arr[3 * G:4 * G]
        self.accel, self.yaw_rate = arr[4 * G:5 * G], arr[5 * G:]
        # a first sub-step that changed nothing is a fixed point: the next advance may be skipped
        # (its sub-steps would compute the same values; the step length does not enter them at rest)
        self._fixed_key = self._avatar_key() if still and first else None

    def _advance_entities(self, dt: float) -> None:
        """Exact rotation of the velocity by ``w h`` with decay; trapezoidal positions."""
        if not len(self.epos):
            return
        cfg = self.cfg
        n, h = self._substeps(dt)
        if len(self.epos) <= self.paths.scalar_entities:
            key = (h, self.eturn.tobytes())
            memo = self._turn_memo.get(key)
            if memo is None:   # per sub-step length (a few values: k T - (k - 1) T differ in the last bits)
                if len(self._turn_memo) >= TURN_MEMO:
                    self._turn_memo.clear()
                memo = self._turn_memo[key] = (float(np.exp(-cfg.world.entity_drag * h)), np.cos(self.eturn * h).tolist(),
                                               np.sin(self.eturn * h).tolist())
            return self._advance_entities_scalar(n, h, *memo)
        decay = np.exp(-cfg.world.entity_drag * h)
        ct, st = np.cos(self.eturn * h), np.sin(self.eturn * h)
        for _ in range(n):
            vx, vy = self.evel[:, 0], self.evel[:, 1]
            nv = np.empty_like(self.evel)
            nv[:, 0] = (ct * vx - st * vy) * decay
            nv[:, 1] = (st * vx + ct * vy) * decay
            self.epos += 0.5 * h * (self.evel + nv)
            self.evel = nv
            self._entity_walls()

    def _advance_entities_scalar(self, n: int, h: float, decay: float, ct: list, st: list) -> None:
        """:meth:`_advance_entities` for a few entities in Python floats (same operations in the
        same order, walls included; entities do not interact, so each runs its sub-steps in turn)."""
        S = self.cfg.scene.scene_size
        S2, hh = 2 * S, 0.5 * h
        pos, vel = [], []    # x, y (vx, vy) per entity
        for (x, y), (ax, ay), c, s in zip(self.epos.tolist(), self.evel.tolist(), ct, st):
            for _ in range(n):
                bx = (c * ax - s * ay) * decay
                by = (s * ax + c * ay) * decay
                x = x + hh * (ax + bx)
                y = y + hh * (ay + by)
                if x < 0.0:           # walls: reflect the position and that velocity component
                    x, bx = -x, bx * -1.0
                elif x > S:
                    x, bx = S2 - x, bx * -1.0
                if y < 0.0:
                    y, by = -y, by * -1.0
                elif y > S:
                    y, by = S2 - y, by * -1.0
                ax, ay = bx, by
            pos += (x, y)
            vel += (ax, ay)
        self.epos.flat = pos      # (in place, row by row)
        self.evel = np.array(vel).reshape(-1, 2)

    def _entity_walls(self) -> None:
        S = self.cfg.scene.scene_size
        p, v = self.epos, self.evel
        if len(p) == 0 or (p.min() >= 0.0 and p.max() <= S):
            return
        lo, hi = p < 0.0, p > S
        if lo.any() or hi.any():
            p[lo] = -p[lo]
            p[hi] = 2 * S - p[hi]
            v[lo | hi] *= -1.0

    def _avatar_walls(self) -> None:
        if len(self.apos) == 0 or (self.apos.min() >= 0.0 and self.apos.max() <= self.cfg.scene.scene_size):
            return
        self.apos, self.yaw, self.speed = _reflect_avatars(self.apos, self.yaw, self.speed, self.cfg.scene.scene_size)

    # -- inputs -----------------------------------------------------------------------------
    def set_input(self, g: int, throttle: float, steer: float) -> None:
        """ControllerPacket of avatar ``g`` takes effect (clipped to [-1, 1])."""
        self.throttle[g] = _clip_unit(throttle)
        self.steer[g] = _clip_unit(steer)

    def bounce_avatar(self, g: int, normal, restitution: float, depth: float = 0.0) -> float:
        """Collision response of avatar ``g`` against a static obstacle (:mod:`.response` with
        ``w2 = 0``): unit normal ``normal`` (2,) from the obstacle to the avatar, penetration
        ``depth`` (m). The avatar moves ``depth`` along the normal (out of the obstacle) and,
        when approaching (``v.n < 0``), its velocity is reflected: ``v <- v - (1 + e)(v.n) n``.

        The heading follows the new velocity; the footprint box (``avatar_length`` x
        ``avatar_width``) turned with it reaches ``sigma(yaw') - sigma(yaw)`` further towards the
        obstacle (``sigma`` its half-extent along ``n``, :func:`half_extent`), which the position
        correction adds: after the response the box touches a flat face instead of swinging a
        corner into it. Returns the velocity change |dv| (m/s, the jolt; the position
        correction is not felt); 0 when the avatar is not approaching.
        """
        n = np.asarray(normal, float)
        norm = np.hypot(*n)
        if norm == 0.0:
            return 0.0
        n = n / norm
        vn = float(self.avel[g] @ n)
        jolt, yaw0 = 0.0, float(self.yaw[g])
        if vn < 0.0:
            jolt = self._change_avatar_velocity(g, -(1.0 + restitution) * vn * n)
        wc = self.cfg.world
        move = max(float(depth), 0.0)
        if jolt and (wc.avatar_length or wc.avatar_width):
            a, b = 0.5 * wc.avatar_length, 0.5 * wc.avatar_width
            move += max(0.0, half_extent(a, b, float(self.yaw[g]), n) - half_extent(a, b, yaw0, n))
        if move > 0.0:
            apos = self.apos.copy()     # (a new array: the kept state keys compare bytes)
            apos[g] += move * n
            self.apos = apos
        return jolt

    def push_entity(self, e: int, dv) -> None:
        """Apply a velocity change ``dv`` (2,) m/s to entity ``e`` (collision response)."""
        self.evel[e] += dv

    def entity_tree(self):
        """k-d tree of the entity positions (built once per frame, shared by contacts and ownership)."""
        from scipy.spatial import cKDTree

        return cKDTree(self.epos)

    def entity_index(self) -> PointIndex:
        """x-sorted entity positions (once per frame, shared by contacts and ownership); its
        k-d tree is built only on a frame with a contact candidate."""
        return PointIndex(self.epos)

    def contacts(self, etree=None, pos_list=None, online=None):
        """Approaching avatar-entity pairs in contact: (avatar, entity, dv of entity (k, 2)).
        ``pos_list``: every position (avatars, then entities) as a list of ``[x, y]`` when the
        caller has it (the tiny scenes' pre-check reads it). ``online`` (G,) bool: only these
        avatars take part (an offline avatar neither pushes entities nor takes an impulse)."""
        G, E = len(self.speed), len(self.evel)
        if G == 0 or E == 0:
            return _NO_CONTACTS
        r = self.cfg.world.avatar_radius + self.cfg.world.entity_radius
        if isinstance(etree, PointIndex):
            # candidates in a box around each avatar; none within r and approaching (up to a
            # relative 1e-9, a superset of the exact test below): no contact, no tree needed
            ai, ei = etree.near(self.apos, np.full(G, r * (1.0 + 1e-9)))
            d = self.epos[ei] - self.apos[ai]
            d2 = np.einsum("ij,ij->i", d, d)
            close = np.flatnonzero(d2 <= r * r * (1.0 + 1e-9))
            if not len(close):   # (an overlap needs its separation even when not approaching)
                return _NO_CONTACTS
        elif etree is None and G * E <= self.paths.scalar_contacts:
            # tiny scenes: the same brute-force check in Python floats (the same differences,
            # squares and bound)
            a, b = (self.apos.tolist(), self.epos.tolist()) if pos_list is None else (pos_list[:G], pos_list[G:])
            if not _any_within(a, b, r * r * (1.0 + 1e-9)):
                return _NO_CONTACTS
        elif etree is None:
            # small scenes (no entity index: :class:`.contacts.Contacts` decides): a brute-force
            # distance check finds the (rare) frames with a contact
            dx = self.epos[:, 0] - self.apos[:, 0, None]
            dy = self.epos[:, 1] - self.apos[:, 1, None]
            if not ((dx * dx + dy * dy) <= r * r * (1.0 + 1e-9)).any():
                return _NO_CONTACTS
        if G < 8 or etree is None:   # every pair in numpy (no scipy.spatial to import), by avatar then entity
            ai, ei = ball_pairs(self.apos, self.epos, r)
        else:   # (the pair order of the k-d tree's sparse distance matrix)
            from scipy.spatial import cKDTree   # (here: a frame without a contact candidate needs no import)

            etree = etree.tree if isinstance(etree, PointIndex) else etree
            sd = cKDTree(self.apos).sparse_distance_matrix(etree, r, output_type="ndarray")
            ai, ei = sd["i"].astype(int), sd["j"].astype(int)
        if online is not None:
            on = online[ai]
            ai, ei = ai[on], ei[on]
        if len(ai) == 0:
            return ai, ei, np.zeros((0, 2))
        d = self.epos[ei] - self.apos[ai]
        dist = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)
        n = d / dist[:, None]     # from the avatar to the entity
        w_e, w_a = self._w_entity, self._w_avatar
        # the entity leaves the overlap (the avatar keeps its position: its contacts with the
        # static scene are the collision unit's, which this model does not know)
        self._separate(ei, n, r - dist)
        avel = self.avel
        rel = np.einsum("ij,ij->i", avel[ai] - self.evel[ei], n)
        keep = rel > 0
        ai, ei, n = ai[keep], ei[keep], n[keep]
        dv, dva = impulse(w_e, w_a, self.evel[ei], avel[ai], n, self.cfg.world.restitution)
        if w_a:     # a finite avatar mass: the avatar's share, at once (its master responds)
            c, s = np.cos(self.yaw[ai]), np.sin(self.yaw[ai])
            along = dva[:, 0] * c + dva[:, 1] * s
            for g, dsp in zip(ai.tolist(), along.tolist()):
                # along its heading only: the tyres hold the sideways part (the ground takes it;
                # the avatar's kinetic energy is at most the two-body result's), so the heading
                # of a vehicle does not jump when an entity hits it
                self.speed[g] += dsp
                self.jolt[g] += abs(dsp)
        return ai, ei, dv

    def _separate(self, ei, n, depth) -> None:
        """Move entities ``ei`` out of their avatar-entity overlaps ``depth`` (k,) m along the
        unit normals ``n`` (k, 2) (avatar to entity); the avatar stays (:func:`separation` with
        its inverse mass 0); ``separated`` counts the pairs moved."""
        over = depth > 0.0
        if not over.any():
            return
        dx_e, _ = separation(self._w_entity, 0.0, n[over], depth[over])
        S = self.cfg.scene.scene_size      # (a wall does not give way: nobody is pushed through it)
        self.epos = self.epos.copy()
        np.add.at(self.epos, ei[over], dx_e)
        np.clip(self.epos, 0.0, S, out=self.epos)
        self.separated += int(over.sum())

    def _change_avatar_velocity(self, g: int, dv) -> float:
        """``v <- v + dv`` for avatar ``g`` (heading and speed from the new velocity); adds
        ``|dv|`` to its jolt and returns it (m/s)."""
        v2 = self.avel[g] + dv
        sp = float(np.hypot(*v2))
        if sp > 1e-12:
            self.yaw[g] = np.arctan2(v2[1], v2[0])
        self.speed[g] = sp
        jolt = float(np.hypot(*dv))
        self.jolt[g] += jolt
        return jolt
