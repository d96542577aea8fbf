"""The 3D view of what the units describe: the collision unit's meshes, the platform's geometry.

With ``[foxglove] units = true`` a scenario gets, for every loaded instance of the built-in
``platform`` unit, its plate (a frame-locked cuboid, ``size_x`` x ``size_y`` x ``size_z``,
posed by ``pose.*`` with A = A_x(gamma) A_y(beta) A_z(alpha), eq. 6-8), its six slider rails
(static lines over the stroke range) and its six rods from the closed-form inverse kinematics
(eq. 6-14..6-19: ball joint B_i to slider C_i, redrawn every step on ``/scene/<unit>``); and
for every loaded instance of the built-in ``collision`` unit, the bodies of its scene drawn
with their own triangles:

* a dynamic body (the FMU's ``body[j]``) is a frame of ``/tf`` posed by its inputs
  ``body[j].x, y, z, roll, pitch, yaw`` (R = Rz(yaw) Ry(pitch) Rx(roll), eq. 4-4), and its
  mesh, in the body's own coordinates, is frame-locked to that frame;
* a static body never moves: its triangles are placed in the ``world`` frame once.

The meshes go into the log once, on ``/scene/meshes`` at the start time (Foxglove keeps the
last message of a topic, so a viewer that seeks still has them), never per step. Above
``mesh_triangles`` triangles of static bodies in a scene, the static bodies are drawn as their
oriented bounding boxes instead (a 5040-tank field would otherwise put 27 million triangles
into the log).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, List, Sequence, Tuple

import numpy as np

#: colours (RGBA) by body group; other groups get the default
COLORS = {"tank": (0.35, 0.42, 0.3, 1.0), "missile": (0.85, 0.2, 0.15, 1.0)}
DEFAULT_COLOR = (0.55, 0.6, 0.7, 1.0)
COLLISION_MODEL = "collision"
PLATFORM_MODEL = "platform"
PLATE_COLOR = (0.2, 0.5, 0.9, 1.0)
RAIL_COLOR = (0.45, 0.45, 0.45, 1.0)
ROD_COLOR = (0.95, 0.75, 0.2, 1.0)


@dataclass(frozen=True)
class MeshEntity:
    """One entity of ``/scene/meshes``: triangles (``vertices[faces]``) in frame ``frame_id``,
    or, with ``box`` set, a cube of size ``box[0]`` posed by ``box[1]`` (4x4) in that frame."""

    id: str
    frame_id: str
    vertices: Any = None   # (n, 3) float
    faces: Any = None      # (m, 3) int
    color: Tuple[float, float, float, float] = DEFAULT_COLOR
    box: Any = None
    lines: Any = None      # (2k, 3) float: k segments (a LINE_LIST)

    def primitive(self) -> dict:
        """The entity's Foxglove primitive (``triangles``, ``cubes`` or ``lines``) as a JSON-ready dict."""
        color = dict(zip("rgba", self.color))
        if self.lines is not None:
            return {"lines": [line_list(self.lines, self.color)]}
        if self.box is not None:
            size, T = self.box
            return {"cubes": [{"pose": _pose(T), "size": dict(zip("xyz", map(float, size))), "color": color}]}
        pts = np.asarray(self.vertices, dtype=float)
        return {"triangles": [{"pose": _identity_pose(), "points": [dict(zip("xyz", p)) for p in pts.tolist()],
                               "color": color, "colors": [],
                               "indices": np.asarray(self.faces, dtype=np.int64).ravel().tolist()}]}


def line_list(points: Any, color: Sequence[float], thickness: float = 0.02) -> dict:
    """A Foxglove LinePrimitive of type LINE_LIST (segments between points 0-1, 2-3, ...)."""
    return {"type": 2, "pose": _identity_pose(), "thickness": thickness, "scale_invariant": False,
            "points": [dict(zip("xyz", p)) for p in np.asarray(points, dtype=float).tolist()],
            "color": dict(zip("rgba", color)), "colors": [], "indices": []}


def _identity_pose() -> dict:
    """The pose of :func:`_pose` for the identity (no rotation call: a platform's rods are
    redrawn every step)."""
    return {"position": {"x": 0.0, "y": 0.0, "z": 0.0}, "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}


def _pose(T: np.ndarray) -> dict:
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(np.asarray(T)[:3, :3]).as_quat()
    return {"position": dict(zip("xyz", map(float, np.asarray(T)[:3, 3]))),
            "orientation": {"x": float(x), "y": float(y), "z": float(z), "w": float(w)}}


def collision_view(unit: str, scene_spec: str, mesh_triangles: int) -> Tuple[List[Any], List[MeshEntity]]:
    """Bodies (for ``/tf``) and mesh entities of one collision unit instance.

    Parameters
    ----------
    unit : str
        Instance name (frames are ``<unit>/<body name>``).
    scene_spec : str
        The instance's ``scene`` parameter (the collision unit's scene language).
    mesh_triangles : int
        Budget of static triangles; beyond it static bodies are drawn as bounding boxes.
    """
    from ..models.collision.geometry import pose_matrix
    from ..models.collision.scene import parse_scene
    from .foxglove import Body

    scene = parse_scene(scene_spec)
    bodies, meshes = [], []
    static = scene.static
    boxes = sum(len(scene.mesh(i).faces) for i in static) > mesh_triangles
    for j, i in enumerate(scene.dynamic, 1):
        b = scene.bodies[i]
        frame = f"{unit}/{b.name}"
        refs = [f"{unit}.body[{j}].{axis}" for axis in ("x", "y", "z", "roll", "pitch", "yaw")]
        bodies.append(Body(frame, "world", tuple(refs[:3]), tuple(refs[3:]), "zyx", (0.0, 0.0, 0.0), "mesh",
                           (1.0, 1.0, 1.0), COLORS.get(b.group, DEFAULT_COLOR)))
        mesh = scene.mesh(i)
        meshes.append(MeshEntity(frame, frame, mesh.vertices, mesh.faces, COLORS.get(b.group, DEFAULT_COLOR)))
    for i in static:
        b = scene.bodies[i]
        mesh, T = scene.mesh(i), pose_matrix(b.pose)
        color = COLORS.get(b.group, DEFAULT_COLOR)
        if boxes:
            lo, hi = mesh.bounds
            centre = np.eye(4)
            centre[:3, 3] = (lo + hi) / 2
            meshes.append(MeshEntity(f"{unit}/{b.name}", "world", color=color, box=(hi - lo, T @ centre)))
        else:
            verts = np.asarray(mesh.vertices) @ T[:3, :3].T + T[:3, 3]
            meshes.append(MeshEntity(f"{unit}/{b.name}", "world", verts, mesh.faces, color))
    return bodies, meshes


class PlatformRods:
    """The per-step part of a platform's view: its six rods B_i -> C_i from the pose (eq. 6-14..6-19).

    ``refs`` are the pose signals it reads, ``entities(values, stamp)`` the SceneUpdate entities
    of one step (``values`` in the order of ``refs``).
    """

    def __init__(self, unit: str, params: Any) -> None:
        from ..models.platform.kinematics import ik_full

        self.unit, self.params, self._ik = unit, params, ik_full
        self.topic = f"/scene/{unit}"
        self.refs = [f"{unit}.pose.{ax}" for ax in ("x", "y", "z", "gamma", "beta", "alpha")]

    def points(self, pose: Sequence[float]) -> np.ndarray:
        """(12, 3): B_1, C_1, B_2, C_2, ... in the base frame, m."""
        ik = self._ik(np.asarray(pose, dtype=float)[None], self.params)
        B = ik.joints[0]
        C = B - ik.rods[0]
        return np.stack([B, C], axis=1).reshape(12, 3)

    def entities(self, values: Sequence[float], stamp: dict) -> List[dict]:
        return [{"timestamp": stamp, "frame_id": "world", "id": f"{self.unit}/rods", "frame_locked": False,
                 "lifetime": {"sec": 0, "nsec": 0}, "lines": [line_list(self.points(values), ROD_COLOR)]}]


def platform_view(unit: str, parameters: dict) -> Tuple[List[Any], List[MeshEntity], List[PlatformRods]]:
    """Bodies, meshes and per-step rods of one platform instance (its geometry parameters
    ``a, b, c, ...`` as the scenario sets them, the unit's defaults otherwise)."""
    from dataclasses import fields

    from ..models.platform.params import PlatformParams
    from .foxglove import Body

    p = PlatformParams(**{f.name: float(parameters[f.name]) for f in fields(PlatformParams) if f.name in parameters})
    plate = f"{unit}/plate"
    refs = PlatformRods(unit, p).refs
    body = Body(plate, "world", tuple(refs[:3]), tuple(refs[3:]), "xyz", (0.0, 0.0, 0.0), "mesh",
                (p.size_x, p.size_y, p.size_z), PLATE_COLOR)
    rails = np.concatenate([[c + p.stroke_min * e, c + p.stroke_max * e] for c, e in zip(p.sliders_home, p.axes)])
    meshes = [MeshEntity(plate, plate, color=PLATE_COLOR, box=((p.size_x, p.size_y, p.size_z), np.eye(4))),
              MeshEntity(f"{unit}/rails", "world", color=RAIL_COLOR, lines=rails)]
    return [body], meshes, [PlatformRods(unit, p)]


def unit_view(units: Sequence[Tuple[str, str, dict]], mesh_triangles: int, rods: bool = True
              ) -> Tuple[List[Any], List[MeshEntity], List[PlatformRods]]:
    """The view of every instance given as ``(instance name, model name, parameters)``
    (the parameters as the scenario sets them; the collision unit's ``scene`` with its
    default filled in); instances of models without a view are skipped. ``rods = False``
    leaves out the platforms' rods (the part redrawn every step)."""
    bodies: List[Any] = []
    meshes: List[MeshEntity] = []
    steps: List[PlatformRods] = []
    for name, model, params in units:
        if model == COLLISION_MODEL and params.get("scene"):
            b, m = collision_view(name, str(params["scene"]), mesh_triangles)
        elif model == PLATFORM_MODEL:
            b, m, r = platform_view(name, params)
            steps += r if rods else []
        else:
            continue
        bodies += b
        meshes += m
    return bodies, meshes, steps


def meshes_message(meshes: Sequence[MeshEntity], t_ns: int) -> dict:
    """The ``/scene/meshes`` SceneUpdate: one frame-locked entity per mesh, never expiring."""
    from .foxglove import time_stamp

    stamp = time_stamp(t_ns)
    return {"deletions": [], "entities": [
        {"timestamp": stamp, "frame_id": m.frame_id, "id": m.id, "frame_locked": True,
         "lifetime": {"sec": 0, "nsec": 0}, **m.primitive()} for m in meshes]}
