"""A 3D view in the MCAP log for Foxglove: ``foxglove.FrameTransforms`` and ``foxglove.SceneUpdate``.

A scenario lists the bodies to draw (their keys are declared in
:class:`~immersim.orchestrator.schema.BodyTable`); each body's pose comes from logged signals
(or constants)::

    [[foxglove.bodies]]
    name = "platform"                      # frame id and entity id
    parent = "world"                       # default "world"
    position = ["plat.pose.x", "plat.pose.y", "plat.pose.z"]   # signal refs or numbers [m]
    euler = ["plat.pose.gamma", "plat.pose.beta", "plat.pose.alpha"]  # rad (default 0, 0, 0)
    order = "xyz"                          # A = A_x(e1) A_y(e2) A_z(e3) (the platform's, eq. 6-8);
                                           # "zyx": roll, pitch, yaw with R = R_z(e3) R_y(e2) R_x(e1)
    offset = [0.0, 0.0, 1.2]               # added to the position [m]
    shape = "cube"                         # cube | sphere | cylinder
    size = [0.76, 0.70, 0.04]              # [m]
    color = [0.2, 0.5, 0.9, 1.0]           # RGBA in 0..1

Every macro step the observer writes one ``/tf`` message (all frames), and once per
simulated second one ``/scene`` message (one entity per body, frame-locked to its frame, never
expiring), JSON-encoded under Foxglove's schema names, so opening the log in Foxglove's 3D panel shows the platform, the avatars and
the scene moving. It only reads values. In a log with ``[log] encoding = "ros1"`` the ``/tf``
messages are ROS 1 ``tf2_msgs/TFMessage`` (what ROS 1 tools and Foxglove read as ``/tf``), packed
with one ``struct`` call per step (:class:`Ros1Transforms`); ``/scene`` stays JSON.
"""
from __future__ import annotations

import json
import math
import struct

import orjson
from dataclasses import dataclass
from typing import Any, Callable, Dict, List, Sequence, Tuple, Union


Ref = Union[str, float]
SHAPES = {"cube": "cubes", "sphere": "spheres", "cylinder": "cylinders"}

FRAME_TRANSFORMS_SCHEMA = {
    "title": "foxglove.FrameTransforms", "type": "object",
    "properties": {"transforms": {"type": "array", "items": {"type": "object", "properties": {
        "timestamp": {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}},
        "parent_frame_id": {"type": "string"}, "child_frame_id": {"type": "string"},
        "translation": {"type": "object", "properties": {k: {"type": "number"} for k in "xyz"}},
        "rotation": {"type": "object", "properties": {k: {"type": "number"} for k in "xyzw"}}}}}},
}



def _obj(**properties: Any) -> Dict[str, Any]:
    return {"type": "object", "properties": properties}


def _array(items: Dict[str, Any]) -> Dict[str, Any]:
    return {"type": "array", "items": items}


_NUM, _INT, _STR, _BOOL = ({"type": t} for t in ("number", "integer", "string", "boolean"))
_VEC3, _COLOR = _obj(x=_NUM, y=_NUM, z=_NUM), _obj(r=_NUM, g=_NUM, b=_NUM, a=_NUM)
_POSE, _TIME = _obj(position=_VEC3, orientation=_obj(x=_NUM, y=_NUM, z=_NUM, w=_NUM)), _obj(sec=_INT, nsec=_INT)
#: the fields of each primitive a SceneUpdate of this view may hold (``/scene``, ``/scene/meshes``
#: and the parts redrawn every step)
_SHAPE = _obj(pose=_POSE, size=_VEC3, color=_COLOR)
_PRIMITIVES = {
    "cubes": _SHAPE, "spheres": _SHAPE, "cylinders": _SHAPE,
    "lines": _obj(type=_INT, pose=_POSE, thickness=_NUM, scale_invariant=_BOOL, points=_array(_VEC3),
                  color=_COLOR, colors=_array(_COLOR), indices=_array(_INT)),
    "models": _obj(pose=_POSE, scale=_VEC3, color=_COLOR, override_color=_BOOL, url=_STR, media_type=_STR,
                   data={"type": "string", "contentEncoding": "base64"}),
}


def scene_schema(kinds: Sequence[str]) -> bytes:
    """The JSON schema (compact text) of a SceneUpdate whose entities hold the primitives
    ``kinds`` (``cubes``, ``spheres``, ``cylinders``, ``lines``, ``models``). Every field is
    declared: Foxglove's JSON reader needs each object's properties and each array's items, and
    a model's ``data`` as base64 text (``contentEncoding``) to hand the GLB bytes to its model
    loader."""
    entity = _obj(timestamp=_TIME, frame_id=_STR, id=_STR, lifetime=_TIME, frame_locked=_BOOL,
                  **{k: _array(_PRIMITIVES[k]) for k in sorted(set(kinds))})
    schema = {"title": "foxglove.SceneUpdate", **_obj(deletions=_array(_obj()), entities=_array(entity))}
    return json.dumps(schema, separators=(",", ":")).encode()


@dataclass
class Body:
    name: str
    parent: str
    position: Tuple[Ref, Ref, Ref]
    euler: Tuple[Ref, Ref, Ref]
    order: str
    offset: Tuple[float, float, float]
    shape: str
    size: Tuple[float, float, float]
    color: Tuple[float, float, float, float]

    def refs(self) -> List[str]:
        return [r for r in (*self.position, *self.euler) if isinstance(r, str)]


def time_stamp(t_ns: int) -> Dict[str, int]:
    """A Foxglove ``Time`` of ``t_ns`` nanoseconds: ``{"sec": ..., "nsec": ...}``."""
    sec, nsec = divmod(t_ns, 1_000_000_000)
    return {"sec": sec, "nsec": nsec}


def _axis_quat(axis: int, angle: float) -> Tuple[float, float, float, float]:
    s, c = math.sin(angle / 2), math.cos(angle / 2)
    q = [0.0, 0.0, 0.0, c]
    q[axis] = s
    return tuple(q)  # (x, y, z, w)


def _qmul(a, b):
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz)


def euler_quaternion(e1: float, e2: float, e3: float, order: str = "xyz") -> Tuple[float, float, float, float]:
    """Quaternion (x, y, z, w) of ``A_x(e1) A_y(e2) A_z(e3)`` (``xyz``, eq. 6-8/6-9) or of
    ``R_z(e3) R_y(e2) R_x(e1)`` (``zyx``: roll e1, pitch e2, yaw e3)."""
    qx, qy, qz = _axis_quat(0, e1), _axis_quat(1, e2), _axis_quat(2, e3)
    return _qmul(_qmul(qx, qy), qz) if order == "xyz" else _qmul(_qmul(qz, qy), qx)


#: ROS 1 message definition of ``tf2_msgs/TFMessage`` with its dependencies (the text a ROS 1
#: bag stores; ``mcap_ros1`` and Foxglove parse it)
TF_MESSAGE_DEFINITION = "\n".join([
    "geometry_msgs/TransformStamped[] transforms", "",
    "=" * 80, "MSG: geometry_msgs/TransformStamped",
    "std_msgs/Header header", "string child_frame_id", "geometry_msgs/Transform transform", "",
    "=" * 80, "MSG: std_msgs/Header", "uint32 seq", "time stamp", "string frame_id", "",
    "=" * 80, "MSG: geometry_msgs/Transform",
    "geometry_msgs/Vector3 translation", "geometry_msgs/Quaternion rotation", "",
    "=" * 80, "MSG: geometry_msgs/Vector3", "float64 x", "float64 y", "float64 z", "",
    "=" * 80, "MSG: geometry_msgs/Quaternion", "float64 x", "float64 y", "float64 z", "float64 w", ""])


class Ros1Transforms:
    """A ``tf2_msgs/TFMessage`` of a fixed list of frames, packed by one ``struct`` (the
    frame ids are fixed, so the message has a fixed layout).

    Per transform: header (seq, stamp sec and nsec, parent frame id), child frame id,
    translation (x, y, z) and rotation quaternion (x, y, z, w), little-endian as ROS 1
    serializes them; the frame ids are fixed, so the message has a fixed layout.

    Parameters
    ----------
    frames : list of (parent, child)
    """

    def __init__(self, frames: Sequence[Tuple[str, str]]) -> None:
        fmt, self._n = ["<I"], len(frames)
        #: the arguments of the message's one struct: per frame 11 (sequence, sec, nsec, its frame
        #: ids as bytes, 7 pose numbers); only the stamps and the poses change
        self._args: List[Any] = [len(frames)]
        for parent, child in frames:
            p, c = parent.encode(), child.encode()
            ids = struct.pack("<I", len(p)) + p + struct.pack("<I", len(c)) + c
            fmt.append(f"III{len(ids)}s7d")
            self._args += [0, 0, 0, ids] + [0.0] * 7
        self._struct = struct.Struct("".join(fmt))

    def pack(self, seq: int, t_ns: int, poses: Sequence[float]) -> bytes:
        """The message at ``t_ns``; ``poses``: 7 numbers per frame (translation, quaternion).
        The frames' stamps and poses go into the arguments by strided slices (no loop)."""
        a, n = self._args, self._n
        sec, nsec = divmod(t_ns, 1_000_000_000)
        a[1::11], a[2::11], a[3::11] = [seq] * n, [sec] * n, [nsec] * n
        for j in range(7):
            a[5 + j::11] = poses[j::7]
        return self._struct.pack(*a)

    @staticmethod
    def decode(data: bytes) -> List[Dict[str, Any]]:
        """The transforms of a packed message, as the JSON ``/tf`` messages hold them."""
        (n,), off, out = struct.unpack_from("<I", data), 4, []
        for _ in range(n):
            _, sec, nsec, lp = struct.unpack_from("<4I", data, off)
            off += 16
            parent = data[off:off + lp].decode()
            (lc,) = struct.unpack_from("<I", data, off + lp)
            off += lp + 4
            child = data[off:off + lc].decode()
            v = struct.unpack_from("<7d", data, off + lc)
            off += lc + 56
            out.append({"timestamp": {"sec": sec, "nsec": nsec}, "parent_frame_id": parent, "child_frame_id": child,
                        "translation": dict(zip("xyz", v[:3])), "rotation": dict(zip("xyzw", v[3:]))})
        return out


def read_transforms(path) -> List[Tuple[int, List[Dict[str, Any]]]]:
    """``(log time ns, transforms)`` of every ``/tf`` message of a log, JSON or ROS 1."""
    from mcap.reader import make_reader

    with open(path, "rb") as fh:
        return [(m.log_time, Ros1Transforms.decode(m.data) if c.message_encoding == "ros1"
                 else json.loads(m.data)["transforms"])
                for _, c, m in make_reader(fh).iter_messages(topics=["/tf"])]


class FoxgloveObserver:
    """Writes ``/tf`` and ``/scene`` into an open :class:`~immersim.orchestrator.observers.McapObserver`.

    ``/tf`` goes with every step, one transform per body (:meth:`transforms`: the log writer
    writes it with the step's other messages); ``/scene`` when due (:meth:`scene_due`). The message is built once and
    updated in place: a value given as a number is computed once, a body rotating about one
    axis only (the others 0, e.g. an avatar's yaw) gets its quaternion from one sine and one
    cosine. ``/scene`` holds frame-locked entities of a fixed shape, size and colour that never
    expire: it is written at the first step and then once per ``scene_period_s`` of simulated
    time (a viewer that seeks or joins late finds a recent one; Foxglove keeps the last one per
    topic); a view whose bodies are all drawn by ``/scene/meshes`` has no ``/scene``.

    Parameters
    ----------
    mcap : McapObserver
    bodies : list of Body
    lookup : callable
        ``lookup("unit.var")`` returns a function giving that signal's current value.
    scene_period_s : float
        Simulated seconds between two ``/scene`` messages.
    meshes : list of views.MeshEntity, optional
        Meshes the units describe (:mod:`~immersim.orchestrator.views`), written once on
        ``/scene/meshes`` with the first ``/scene``; their bodies (shape ``"mesh"``) get no primitive.
    steps : list, optional
        Parts of the view redrawn every step (``views.PlatformRods``: ``topic``, ``refs``,
        ``entities(values, stamp)``), each a SceneUpdate on its own topic.
    """

    def __init__(self, mcap, bodies: List[Body], lookup: Callable[[str], Callable[[], float]],
                 scene_period_s: float = 1.0, meshes: Sequence[Any] = (), steps: Sequence[Any] = ()) -> None:
        self.mcap, self.bodies = mcap, bodies
        self.meshes = list(meshes)
        self._steps = [(part, [lookup(r) for r in part.refs]) for part in steps]
        self._stamp = {"sec": 0, "nsec": 0}
        self._msg: Dict[str, Any] = {"transforms": []}
        #: per body with signal references: (translation dict, its getters and offsets or None,
        #: rotation dict, how its angles are read: None (fixed), (axis, getter), or 3 getters, order)
        self._moving: List[tuple] = []
        for b in bodies:
            pos = [lookup(r) if isinstance(r, str) else r for r in b.position]
            ang = [lookup(r) if isinstance(r, str) else r for r in b.euler]
            fixed = [r for r in (*pos, *ang) if not callable(r)]
            translation, rotation = self._pose(b, [0.0 if callable(r) else r for r in (*pos, *ang)])
            self._msg["transforms"].append({"timestamp": self._stamp, "parent_frame_id": b.parent,
                                            "child_frame_id": b.name, "translation": translation,
                                            "rotation": rotation})
            if len(fixed) == 6:
                continue
            moves = any(map(callable, pos))
            turning = [i for i, r in enumerate(ang) if callable(r) or r != 0.0]
            if not any(map(callable, ang)):
                spin = None                                   # fixed rotation, computed above
            elif len(turning) == 1:
                spin = (turning[0], ang[turning[0]])          # about one axis: q = (sin, cos) of half the angle
            else:
                spin = tuple(ang)
            self._moving.append((translation, (pos, b.offset) if moves else None, rotation, spin, b.order))
        self._period_ns = int(round(scene_period_s * 1e9))
        self._next_scene = None
        w = mcap.writer
        # every frame's translation and quaternion, 7 numbers each, in /tf's order; the moving
        # bodies' update (:meth:`_update`) rewrites theirs every step (both encodings)
        tfs = self._msg["transforms"]
        self._poses = [v for t in tfs for v in (*t["translation"].values(), *t["rotation"].values())]
        index = {id(t["translation"]): i for i, t in enumerate(tfs)}
        #: what :meth:`_update` writes: (pose index, getter, offset) of each moving coordinate,
        #: (sine index, cosine index, getter) of each one-axis rotation, (offset, angles, order)
        #: of each other rotation
        self._shifts, self._spins, self._turns = [], [], []
        for translation, moves, _, spin, order in self._moving:
            o = 7 * index[id(translation)]
            if moves is not None:
                self._shifts += [(o + j, g, off) for j, (g, off) in enumerate(zip(*moves)) if callable(g)]
            if spin is not None and len(spin) == 2:
                self._spins.append((o + 3 + spin[0], o + 6, spin[1]))
            elif spin is not None:
                self._turns.append((o, spin, order))
        #: the JSON message's dicts of the moving bodies, with their offset in the poses
        self._moved = [(translation, rotation, 7 * index[id(translation)])
                       for translation, _, rotation, _, _ in self._moving]
        self._ros1: Ros1Transforms | None = None
        if getattr(mcap, "encoding", "json") == "ros1":
            sid = w.register_schema(name="tf2_msgs/TFMessage", encoding="ros1msg",
                                    data=TF_MESSAGE_DEFINITION.encode())
            self._tf = w.register_channel(topic="/tf", message_encoding="ros1", schema_id=sid)
            self._ros1 = Ros1Transforms([(t["parent_frame_id"], t["child_frame_id"]) for t in tfs])
        else:
            sid = w.register_schema(name="foxglove.FrameTransforms", encoding="jsonschema",
                                    data=json.dumps(FRAME_TRANSFORMS_SCHEMA).encode())
            self._tf = w.register_channel(topic="/tf", message_encoding="json", schema_id=sid)
        # each SceneUpdate channel with the schema of the primitives it draws; /scene only when a
        # body is a primitive of it (the units' bodies are drawn by /scene/meshes)
        schemas: Dict[Tuple[str, ...], int] = {}

        def channel(topic: str, kinds) -> int:
            kinds = tuple(sorted(set(kinds)))
            if kinds not in schemas:
                schemas[kinds] = w.register_schema(name="foxglove.SceneUpdate", encoding="jsonschema",
                                                   data=scene_schema(kinds))
            return w.register_channel(topic=topic, message_encoding="json", schema_id=schemas[kinds])

        drawn = [SHAPES[b.shape] for b in bodies if b.shape != "mesh"]
        self._scene = channel("/scene", drawn) if drawn else None
        self._meshes = channel("/scene/meshes", [m.kind for m in self.meshes]) if self.meshes else None
        if self._meshes is not None and getattr(w, "tee", None) is not None:
            w.tee.latch(self._meshes)   # the live view: a viewer joining late gets them too
        self._step_channels = [channel(part.topic, part.kinds) for part, _ in self._steps]

    @staticmethod
    def _pose(body: Body, v: Sequence[float]) -> Tuple[Dict[str, float], Dict[str, float]]:
        """Translation (position + offset, m) and rotation quaternion of a body's frame."""
        qx, qy, qz, qw = euler_quaternion(v[3], v[4], v[5], body.order)
        return ({"x": v[0] + body.offset[0], "y": v[1] + body.offset[1], "z": v[2] + body.offset[2]},
                {"x": qx, "y": qy, "z": qz, "w": qw})

    def _update(self, poses: List[float]) -> None:
        """Write every moving body's translation (position + offset) and quaternion into
        ``poses``: about one axis the quaternion is the sine and cosine of half the angle, else
        :func:`euler_quaternion`; a constant position plus its offset is there from the start."""
        for i, get, off in self._shifts:
            poses[i] = get() + off
        sin, cos = math.sin, math.cos
        for i, j, get in self._spins:
            half = 0.5 * get()
            poses[i] = sin(half)
            poses[j] = cos(half)
        for o, angles, order in self._turns:
            poses[o + 3:o + 7] = euler_quaternion(*[a() if callable(a) else a for a in angles], order)

    def transforms(self, k: int, t_ns: int) -> Tuple[int, bytes]:
        """``(channel id, data)`` of step ``k``'s ``/tf`` message (the log writer puts it with the
        step's other messages)."""
        poses = self._poses
        self._update(poses)
        if self._ros1 is not None:
            return self._tf, self._ros1.pack(k, t_ns, poses)
        stamp = self._stamp   # shared by every transform of the message
        stamp["sec"], stamp["nsec"] = divmod(t_ns, 1_000_000_000)
        for translation, rotation, o in self._moved:
            translation["x"], translation["y"], translation["z"] = poses[o:o + 3]
            rotation["x"], rotation["y"], rotation["z"], rotation["w"] = poses[o + 3:o + 7]
        return self._tf, orjson.dumps(self._msg)

    def step_items(self, k: int, t_ns: int) -> List[Tuple[int, bytes]]:
        """``(channel id, data)`` of step ``k``'s view messages: ``/tf`` and the parts redrawn
        every step (the log writer writes them with the step's other messages)."""
        items = [self.transforms(k, t_ns)]
        if self._steps:
            stamp = time_stamp(t_ns)
            for cid, (part, getters) in zip(self._step_channels, self._steps):
                items.append((cid, orjson.dumps({"deletions": [],
                                                 "entities": part.entities([g() for g in getters], stamp)})))
        return items

    def scene_due(self, k: int, t_ns: int) -> None:
        """``/scene`` at the first step and then once per ``scene_period_s`` (with the meshes once)."""
        if self._next_scene is None and self._meshes is not None:   # the meshes: once, at the start
            from .views import meshes_message

            self.mcap.writer.add_message(self._meshes, log_time=t_ns, publish_time=t_ns, sequence=k,
                                         data=orjson.dumps(meshes_message(self.meshes, t_ns)))
        if self._next_scene is None or t_ns >= self._next_scene:
            self._next_scene = t_ns + self._period_ns
            if self._scene is None:
                return
            stamp = time_stamp(t_ns)
            self.mcap.writer.add_message(self._scene, log_time=t_ns, publish_time=t_ns, sequence=k,
                                         data=orjson.dumps({"deletions": [], "entities": self._entities(stamp)}))

    def _entities(self, stamp: Dict[str, int]) -> List[Dict[str, Any]]:
        entities = []
        for body in self.bodies:
            if body.shape == "mesh":   # drawn by /scene/meshes
                continue
            prim = {"pose": {"position": {"x": 0, "y": 0, "z": 0}, "orientation": {"x": 0, "y": 0, "z": 0, "w": 1}},
                    "size": dict(zip("xyz", body.size)), "color": dict(zip("rgba", body.color))}
            entities.append({"timestamp": stamp, "frame_id": body.name, "id": body.name, "frame_locked": True,
                             "lifetime": {"sec": 0, "nsec": 0}, SHAPES[body.shape]: [prim]})
        return entities
