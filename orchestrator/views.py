"""The 3D view of what the units describe: the collision unit's real meshes.

With ``[foxglove] units = true`` a scenario gets, for every loaded instance of the built-in
``collision`` unit, the bodies of its scene drawn with their own triangles:

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

    def primitive(self) -> dict:
        """The entity's Foxglove primitive (``triangles`` or ``cubes``) as a JSON-ready dict."""
        color = dict(zip("rgba", self.color))
        if self.box is not None:
            size, T = self.box
            return {"cubes": [{"pose": _pose(T), "size": dict(zip("xyz", map(float, size))), "color": color}]}
        pts = np.asarray(self.vertices, dtype=float)
        return {"triangles": [{"pose": _pose(np.eye(4)), "points": [dict(zip("xyz", p)) for p in pts.tolist()],
                               "color": color, "colors": [],
                               "indices": np.asarray(self.faces, dtype=np.int64).ravel().tolist()}]}


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


def unit_view(units: Sequence[Tuple[str, str, Any]], mesh_triangles: int) -> Tuple[List[Any], List[MeshEntity]]:
    """The view of every instance given as ``(instance name, model name, scene parameter)``;
    instances of models without a view are skipped."""
    bodies: List[Any] = []
    meshes: List[MeshEntity] = []
    for name, model, scene in units:
        if model == COLLISION_MODEL and scene:
            b, m = collision_view(name, str(scene), mesh_triangles)
            bodies += b
            meshes += m
    return bodies, meshes


def meshes_message(meshes: Sequence[MeshEntity], t_ns: int) -> dict:
    """The ``/scene/meshes`` SceneUpdate: one frame-locked entity per mesh, never expiring."""
    stamp = dict(zip(("sec", "nsec"), divmod(t_ns, 1_000_000_000)))
    return {"deletions": [], "entities": [
        {"timestamp": stamp, "frame_id": m.frame_id, "id": m.id, "frame_locked": True,
         "lifetime": {"sec": 0, "nsec": 0}, **m.primitive()} for m in meshes]}
