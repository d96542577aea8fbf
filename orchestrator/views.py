"""The 3D view of what the units describe: the collision unit's meshes, the platform's geometry.

With ``[foxglove] units = true`` a scenario gets, for every loaded instance of the built-in
``platform`` unit, its plate (a frame-locked cuboid, ``size_x`` x ``size_y`` x ``size_z``,
posed by ``pose.*`` with A = A_x(gamma) A_y(beta) A_z(alpha), eq. 6-8), its six slider rails
(static lines over the stroke range) and its six rods from the closed-form inverse kinematics
(eq. 6-14..6-19: ball joint B_i to slider C_i, redrawn every step on ``/scene/<unit>``); and
for every loaded instance of the built-in ``collision`` unit, the bodies of its scene drawn
with their own triangles, as glTF models (Foxglove ``ModelPrimitive``, :mod:`.glb`):

* a dynamic body (the FMU's ``body[j]``) is a frame of ``/tf`` posed by its inputs
  ``body[j].x, y, z, roll, pitch, yaw`` (R = Rz(yaw) Ry(pitch) Rx(roll), eq. 4-4), and its
  mesh, in the body's own coordinates, is frame-locked to that frame;
* the static bodies never move: one model in the ``world`` frame holds each distinct mesh
  once and every static body as a copy of it at the body's pose.

The meshes go into the log once, on ``/scene/meshes`` at the start time (Foxglove keeps the
last message of a topic, so a viewer that seeks still has them), never per step. Above
``mesh_triangles`` triangles of static bodies in a scene, the static bodies are drawn as their
oriented bounding boxes instead (a 5040-tank field would otherwise make a viewer draw 27
million triangles).
"""
from __future__ import annotations

import base64
from dataclasses import dataclass
from typing import Any, Dict, List, Sequence, Tuple

import numpy as np

from .glb import Placed, model_glb

#: colours (RGBA) by body group; other groups get the default
COLORS = {"tank": (0.35, 0.42, 0.3, 1.0), "missile": (0.85, 0.2, 0.15, 1.0)}
DEFAULT_COLOR = (0.55, 0.6, 0.7, 1.0)
COLLISION_MODEL = "collision"
PLATFORM_MODEL = "platform"
PLATE_COLOR = (0.2, 0.5, 0.9, 1.0)
RAIL_COLOR = (0.45, 0.45, 0.45, 1.0)
ROD_COLOR = (0.95, 0.75, 0.2, 1.0)
GLB_MEDIA_TYPE = "model/gltf-binary"


@dataclass(frozen=True)
class MeshEntity:
    """One entity of ``/scene/meshes`` in frame ``frame_id``: a glTF model (``model``: GLB
    bytes, :mod:`.glb`), a cube of size ``box`` (x, y, z, m) at the frame's origin, or the
    segments of ``lines``."""

    id: str
    frame_id: str
    color: Tuple[float, float, float, float] = DEFAULT_COLOR
    model: bytes = b""
    box: Any = None        # (3,) float: size, m
    lines: Any = None      # (2k, 3) float: k segments (a LINE_LIST)

    @property
    def kind(self) -> str:
        """The Foxglove primitive the entity is drawn with: ``lines``, ``cubes`` or ``models``."""
        return "lines" if self.lines is not None else "cubes" if self.box is not None else "models"

    def primitive(self) -> dict:
        """The entity's Foxglove primitive (``models``, ``cubes`` or ``lines``) as a JSON-ready
        dict; a model's bytes as base64 text (the schema's ``contentEncoding``)."""
        color = dict(zip("rgba", self.color))
        if self.lines is not None:
            return {"lines": [line_list(self.lines, self.color)]}
        if self.box is not None:
            size = dict(zip("xyz", map(float, self.box)))
            return {"cubes": [{"pose": _identity_pose(), "size": size, "color": color}]}
        return {"models": [{"pose": _identity_pose(), "scale": {"x": 1.0, "y": 1.0, "z": 1.0}, "color": color,
                            "override_color": False, "url": "", "media_type": GLB_MEDIA_TYPE,
                            "data": base64.b64encode(self.model).decode()}]}


def line_list(points: Any, color: Sequence[float], thickness: float = 0.02) -> dict:
    """A Foxglove LinePrimitive of type LINE_LIST (segments between points 0-1, 2-3, ...)."""
    return {"type": 2, "pose": _identity_pose(), "thickness": thickness, "scale_invariant": False,
            "points": [dict(zip("xyz", p)) for p in np.asarray(points, dtype=float).tolist()],
            "color": dict(zip("rgba", color)), "colors": [], "indices": []}


def _identity_pose() -> dict:
    """The identity pose (a platform's rods are redrawn every step: no rotation call)."""
    return {"position": {"x": 0.0, "y": 0.0, "z": 0.0}, "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}


def _box_mesh(bounds: Any) -> Tuple[np.ndarray, np.ndarray]:
    """Vertices (8, 3) and faces (12, 3) of the axis-aligned box ``bounds`` = (lo, hi)."""
    import trimesh

    box = trimesh.creation.box(bounds=np.asarray(bounds, dtype=float))
    return np.asarray(box.vertices), np.asarray(box.faces)


def collision_view(unit: str, scene_spec: str, mesh_triangles: int) -> Tuple[List[Any], List[MeshEntity]]:
    """Bodies (for ``/tf``) and mesh entities of one collision unit instance.

    Parameters
    ----------
    unit : str
        Instance name (frames are ``<unit>/<body name>``; the static bodies are the entity
        ``<unit>/static`` in ``world``).
    scene_spec : str
        The instance's ``scene`` parameter (the collision unit's scene language).
    mesh_triangles : int
        Budget of static triangles; beyond it static bodies are drawn as bounding boxes.
    """
    from ..models.collision.scene import parse_scene
    from .foxglove import Body, euler_quaternion

    scene = parse_scene(scene_spec)
    bodies, meshes = [], []
    static = scene.static
    boxes = sum(len(scene.mesh(i).faces) for i in static) > mesh_triangles
    for j, i in enumerate(scene.dynamic, 1):
        b = scene.bodies[i]
        frame, color = f"{unit}/{b.name}", COLORS.get(b.group, DEFAULT_COLOR)
        refs = [f"{unit}.body[{j}].{axis}" for axis in ("x", "y", "z", "roll", "pitch", "yaw")]
        bodies.append(Body(frame, "world", tuple(refs[:3]), tuple(refs[3:]), "zyx", (0.0, 0.0, 0.0), "mesh",
                           (1.0, 1.0, 1.0), color))
        mesh = scene.mesh(i)
        meshes.append(MeshEntity(frame, frame, color, model_glb([Placed(mesh.vertices, mesh.faces, color,
                                                                        [[0.0, 0.0, 0.0]], [[0.0, 0.0, 0.0, 1.0]])])))
    copies: Dict[Tuple[str, tuple], List[int]] = {}   # (mesh, colour) -> its static bodies
    for i in static:
        b = scene.bodies[i]
        copies.setdefault((b.mesh_key, COLORS.get(b.group, DEFAULT_COLOR)), []).append(i)
    parts = []
    for (_, color), members in copies.items():
        mesh = scene.mesh(members[0])
        vertices, faces = _box_mesh(mesh.bounds) if boxes else (mesh.vertices, mesh.faces)
        poses = np.array([scene.bodies[i].pose for i in members], dtype=float)
        parts.append(Placed(vertices, faces, color, poses[:, :3],
                            [euler_quaternion(*p[3:], "zyx") for p in poses.tolist()]))
    if parts:
        meshes.append(MeshEntity(f"{unit}/static", "world", DEFAULT_COLOR, model_glb(parts)))
    return bodies, meshes


class PlatformRods:
    """The per-step part of a platform's view: its six rods B_i -> C_i from the pose (eq. 6-14..6-19).

    ``refs`` are the pose signals it reads, ``entities(values, stamp)`` the SceneUpdate entities
    of one step (``values`` in the order of ``refs``), ``kinds`` the primitives they hold.
    """

    kinds = ("lines",)

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
    meshes = [MeshEntity(plate, plate, color=PLATE_COLOR, box=(p.size_x, p.size_y, p.size_z)),
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
