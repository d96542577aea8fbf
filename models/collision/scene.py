"""Scenes of rigid bodies for the collision unit: meshes, poses and the thesis's workloads.

A scene is a list of :class:`Body` (name, mesh, static or dynamic, pose). Identical meshes are
stored once (``Scene.meshes`` keyed by ``Body.mesh_key``) so that a field of 5040 tanks holds
one tank mesh, not 5040.

Scene spec strings
------------------
``parse_scene(spec)`` accepts three forms:

1. **Generator spec**: items separated by ``;``, each ``kind[:key=value,key=value,...]``::

       tanks:n=100,tris=5442,spacing=10;missile:x=0,y=0,z=3,pitch=1.5708

   kinds and their keys (all items also take ``name``, ``x y z roll pitch yaw`` in m / rad and
   ``dynamic`` = 0/1):

   ============  =====================================================================
   ``tanks``      field of ``n`` (1..5040) static tanks on a square grid: ``tris``,
                  ``spacing`` (m, 10), ``name`` is the prefix (``tank`` -> tank_0 ...);
                  the pose keys offset the whole field.
   ``tank``       one tank: ``tris`` (triangles; ``5.4k 8.7k 10.1k 26.4k`` name the
                  thesis's models, 5442 / 8676 / 10114 / 26432), static by default.
   ``missile``    ``length`` (m, 3.0), ``radius`` (m, 0.15); dynamic by default.
   ``box``        ``sx sy sz`` (m); ``sphere``: ``r``, ``subdiv``; ``cylinder``: ``r h``.
   ``mesh``       ``file`` = OBJ/STL/PLY/GLB path (relative to the spec file, if any).
   ============  =====================================================================

2. **JSON** (a ``.json`` file path, or text starting with ``{``)::

       {"bodies": [{"kind": "tank", "name": "t1", "tris": 5442, "x": 10},
                   {"kind": "mesh", "file": "rock.stl", "dynamic": true}]}

   Each entry takes the same keys as a generator item.

3. **A mesh file path** (``.obj .stl .ply .glb .gltf .off``): one dynamic body named after
   the file stem.

A missing or unreadable mesh raises :class:`MeshError` naming the file; a degenerate or
non-watertight mesh only warns (distances stay exact: FCL works on triangle soups).
"""
from __future__ import annotations

import json
import logging
import math
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Dict, List, Optional, Tuple

import numpy as np

from .geometry import pose_matrix
from .meshcache import generated

if TYPE_CHECKING:  # trimesh (~0.5 s to import) is imported where a mesh is built or loaded
    import trimesh

log = logging.getLogger(__name__)

__all__ = ["Body", "Scene", "SceneError", "MeshError", "MeshWarning", "parse_scene", "load_mesh",
           "make_tank", "make_missile", "TANK_TRIS", "MESH_EXTENSIONS", "MAX_TANKS"]

MESH_EXTENSIONS = (".obj", ".stl", ".ply", ".glb", ".gltf", ".off")
MAX_TANKS = 5040
#: the thesis's tank models (§5.7.1 / table 5-1; 10113 is odd, a closed mesh needs an even count)
TANK_TRIS = {"5.4k": 5442, "8.7k": 8676, "10.1k": 10114, "26.4k": 26432}
POSE_KEYS = ("x", "y", "z", "roll", "pitch", "yaw")
#: bound on every scene coordinate, m: a body's position plus its mesh's extent (FCL's
#: broad phase squares coordinates; 1e200 overflows to inf and crashes it)
MAX_COORD = 1e6


class SceneError(ValueError):
    """A scene spec is malformed: the message names the spec item (or file) and key."""


class MeshError(SceneError, OSError):
    """A mesh file is missing, unreadable or empty: the message names the file."""


class MeshWarning(UserWarning):
    """A mesh is degenerate or not watertight (it is still used)."""


@dataclass
class Body:
    """A rigid body of the scene.

    Attributes
    ----------
    name : str
    mesh_key : str
        Key into :attr:`Scene.meshes`; bodies with the same key share one mesh (and one BVH).
    dynamic : bool
        Dynamic bodies take poses as inputs; static bodies never move.
    pose : ndarray, shape (6,)
        ``(x, y, z, roll, pitch, yaw)`` in m and rad (initial pose for dynamic bodies).
    group : str
        Kind of body (``tank``, ``missile``, ``mesh`` ...) used by ``any <group>`` pair specs.
    """

    name: str
    mesh_key: str
    dynamic: bool
    pose: np.ndarray
    group: str = ""


@dataclass
class Scene:
    """Bodies and their (shared) meshes."""

    bodies: List[Body] = field(default_factory=list)
    meshes: Dict[str, trimesh.Trimesh] = field(default_factory=dict)
    source: str = ""
    _names: set = field(default_factory=set, repr=False)

    @property
    def dynamic(self) -> List[int]:
        """Indices of the dynamic bodies, in scene order (``body[i]`` of the FMU)."""
        return [i for i, b in enumerate(self.bodies) if b.dynamic]

    @property
    def static(self) -> List[int]:
        return [i for i, b in enumerate(self.bodies) if not b.dynamic]

    def index(self, name: str) -> int:
        for i, b in enumerate(self.bodies):
            if b.name == name:
                return i
        raise SceneError(f"scene {self.source!r}: no body named {name!r}")

    def mesh(self, i: int) -> trimesh.Trimesh:
        return self.meshes[self.bodies[i].mesh_key]

    def poses(self) -> np.ndarray:
        """Poses of all bodies, shape (n, 6)."""
        return np.array([b.pose for b in self.bodies], dtype=float).reshape(-1, 6)

    def transforms(self, poses: Optional[np.ndarray] = None) -> np.ndarray:
        """World transforms of all bodies, shape (n, 4, 4)."""
        poses = self.poses() if poses is None else poses
        return np.array([pose_matrix(p) for p in poses]).reshape(-1, 4, 4)

    def n_triangles(self) -> int:
        return int(sum(len(self.mesh(i).faces) for i in range(len(self.bodies))))

    def add(self, body: Body, mesh: trimesh.Trimesh) -> None:
        """Add a body; raises SceneError for a name used twice or a body reaching beyond
        :data:`MAX_COORD` (m) from the origin."""
        if body.name in self._names:
            raise SceneError(f"scene {self.source!r}: body name {body.name!r} used twice")
        reach = float(np.max(np.abs(body.pose[:3]))) + float(np.max(np.abs(mesh.bounds))) if len(mesh.vertices) else 0.0
        if not reach <= MAX_COORD:   # (also NaN)
            raise SceneError(f"scene {self.source!r}: body {body.name!r} at ({', '.join(f'{c:g}' for c in body.pose[:3])}) "
                             f"m reaches {reach:g} m from the origin, beyond {MAX_COORD:g} m")
        self._names.add(body.name)
        self.meshes.setdefault(body.mesh_key, mesh)
        self.bodies.append(body)


# -- meshes -----------------------------------------------------------------------------
def load_mesh(path: str | os.PathLike) -> trimesh.Trimesh:
    """Load a triangle mesh (OBJ/STL/PLY/GLB...) as one :class:`trimesh.Trimesh`.

    Raises
    ------
    MeshError
        The file is missing, unreadable, or holds no triangles (message names the file).
    """
    import trimesh

    path = Path(path)
    if not path.is_file():
        raise MeshError(f"mesh file {str(path)!r} does not exist")
    try:
        mesh = trimesh.load(str(path), force="mesh", process=True)
    except Exception as exc:  # trimesh raises many types for corrupt files
        raise MeshError(f"mesh file {str(path)!r} cannot be read: {type(exc).__name__}: {exc}") from exc
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise MeshError(f"mesh file {str(path)!r} holds no triangles")
    if not np.all(np.isfinite(mesh.vertices)):
        raise MeshError(f"mesh file {str(path)!r} has non-finite vertex coordinates")
    check_mesh(mesh, str(path))
    return mesh


def check_mesh(mesh: trimesh.Trimesh, label: str) -> None:
    """Warn (:class:`MeshWarning`) about degenerate triangles or a non-watertight mesh."""
    n_degenerate = int(np.sum(mesh.area_faces <= 1e-12 * max(mesh.scale, 1e-12) ** 2))
    if n_degenerate:
        warnings.warn(f"mesh {label}: {n_degenerate} degenerate (zero-area) triangles", MeshWarning,
                      stacklevel=3)
    if not mesh.is_watertight:
        warnings.warn(f"mesh {label}: not watertight; distances stay exact but inside/outside "
                      f"(penetration) tests of the ray-casting backends may be wrong", MeshWarning,
                      stacklevel=3)


def grid_box(extents, counts) -> trimesh.Trimesh:
    """Closed box centred at the origin whose faces are (nx, ny, nz) grids of quads.

    Triangle count ``4 (nx ny + ny nz + nz nx)``.
    """
    import trimesh

    ext = np.asarray(extents, float) / 2
    n = [int(c) for c in counts]
    verts, faces = [], []
    for axis in range(3):
        u, v = (axis + 1) % 3, (axis + 2) % 3
        gu = np.linspace(-ext[u], ext[u], n[u] + 1)
        gv = np.linspace(-ext[v], ext[v], n[v] + 1)
        U, V = np.meshgrid(gu, gv, indexing="ij")
        for sign in (-1.0, 1.0):
            P = np.zeros((U.size, 3))
            P[:, u], P[:, v], P[:, axis] = U.ravel(), V.ravel(), sign * ext[axis]
            base = sum(len(x) for x in verts)
            idx = np.arange(U.size).reshape(U.shape) + base
            a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
            c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
            tri = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
            if sign < 0:
                tri = tri[:, ::-1]
            verts.append(P)
            faces.append(tri)
    mesh = trimesh.Trimesh(np.concatenate(verts), np.concatenate(faces), process=True)
    mesh.fix_normals()
    return mesh


def _place(mesh: trimesh.Trimesh, pose) -> trimesh.Trimesh:
    mesh.apply_transform(pose_matrix(pose))
    return mesh


def make_tank(tris: int = 5442) -> trimesh.Trimesh:
    """A tank of exactly ``tris`` triangles (rounded up to even): grid-box hull, cylinder
    turret, cylinder barrel along +x and a cone antenna, all closed. Origin at the centre of
    the hull's bottom face; about 8.3 m x 3.4 m x 3.9 m.
    """
    import trimesh

    tris = int(tris)
    if tris < 400:
        raise SceneError(f"tank: tris = {tris} is below the minimum of 400 triangles")
    tris += tris % 2
    hull_ext = np.array([6.5, 3.4, 1.6])
    # hull takes ~55 % of the triangles: 4 (nx ny + ny nz + nz nx) = 0.55 T with n = ext / h
    coeff = 4 * (hull_ext[0] * hull_ext[1] + hull_ext[1] * hull_ext[2] + hull_ext[2] * hull_ext[0])
    h = math.sqrt(coeff / (0.55 * tris))
    counts = np.maximum(1, np.round(hull_ext / h)).astype(int)
    n_hull = 4 * (counts[0] * counts[1] + counts[1] * counts[2] + counts[2] * counts[0])
    s_barrel = 24
    rest = tris - n_hull - 4 * s_barrel
    s_ant = 3 if rest % 4 == 2 else 4
    s_turret = (rest - 2 * s_ant) // 4
    if s_turret < 8:
        raise SceneError(f"tank: cannot split {tris} triangles into hull, turret and barrel")
    hull = _place(grid_box(hull_ext, counts), (0, 0, 0.8, 0, 0, 0))
    turret = _place(trimesh.creation.cylinder(radius=1.2, height=0.8, sections=s_turret), (-0.3, 0, 2.0, 0, 0, 0))
    barrel = _place(trimesh.creation.cylinder(radius=0.1, height=4.0, sections=s_barrel),
                    (2.9, 0, 2.0, 0, math.pi / 2, 0))
    antenna = _place(trimesh.creation.cone(radius=0.05, height=1.5, sections=s_ant), (-1.2, 0.6, 2.4, 0, 0, 0))
    tank = trimesh.util.concatenate([hull, turret, barrel, antenna])
    assert len(tank.faces) == tris, (len(tank.faces), tris)
    return tank


def make_missile(length: float = 3.0, radius: float = 0.15, sections: int = 32) -> trimesh.Trimesh:
    """A missile along +x centred at the origin: cylinder body plus cone nose (closed parts)."""
    import trimesh

    body_len, nose_len = 0.85 * length, 0.15 * length
    body = _place(trimesh.creation.cylinder(radius=radius, height=body_len, sections=sections),
                  (-length / 2 + body_len / 2, 0, 0, 0, math.pi / 2, 0))
    nose = _place(trimesh.creation.cone(radius=radius, height=nose_len, sections=sections),
                  (-length / 2 + body_len, 0, 0, 0, math.pi / 2, 0))
    return trimesh.util.concatenate([body, nose])


def _creation():
    import trimesh.creation

    return trimesh.creation


# -- spec parsing -------------------------------------------------------------------------
def _parse_tris(value, where: str) -> int:
    text = str(value).strip().lower()
    if text in TANK_TRIS:
        return TANK_TRIS[text]
    try:
        return int(float(text[:-1]) * 1000) if text.endswith("k") else int(text)
    except ValueError:
        raise SceneError(f"{where}: tris = {value!r} is not a triangle count") from None


class _Item:
    """One generator item with typed, checked access to its keys."""

    def __init__(self, kind: str, keys: dict, where: str, base_dir: Optional[Path]):
        self.kind, self.keys, self.where, self.base_dir = kind, dict(keys), where, base_dir
        self.used = {"kind"}

    def get(self, key, default=None):
        self.used.add(key)
        return self.keys.get(key, default)

    def num(self, key, default: float) -> float:
        value = self.get(key, default)
        try:
            out = float(value)
        except (TypeError, ValueError):
            raise SceneError(f"{self.where}: {key} = {value!r} is not a number") from None
        if not math.isfinite(out):
            raise SceneError(f"{self.where}: {key} = {value!r} is not finite")
        return out

    def flag(self, key, default: bool) -> bool:
        value = self.get(key, default)
        if isinstance(value, bool):
            return value
        text = str(value).strip().lower()
        if text in ("1", "true", "yes", "on"):
            return True
        if text in ("0", "false", "no", "off"):
            return False
        raise SceneError(f"{self.where}: {key} = {value!r} is not a flag (0/1)")

    def pose(self) -> np.ndarray:
        return np.array([self.num(k, 0.0) for k in POSE_KEYS])

    def check_unused(self) -> None:
        unknown = sorted(set(self.keys) - self.used)
        if unknown:
            raise SceneError(f"{self.where}: unknown key(s) {', '.join(unknown)} for kind {self.kind!r}")


def _add_item(scene: Scene, item: _Item, counter: Dict[str, int]) -> None:
    kind = item.kind
    counter[kind] = counter.get(kind, 0) + 1
    default_name = kind if counter[kind] == 1 else f"{kind}_{counter[kind] - 1}"
    if kind == "tanks":
        n = int(item.num("n", 1))
        if not 1 <= n <= MAX_TANKS:
            raise SceneError(f"{item.where}: n = {n} tanks is outside 1..{MAX_TANKS}")
        tris = _parse_tris(item.get("tris", 5442), item.where)
        spacing = item.num("spacing", 10.0)
        prefix = str(item.get("name", "tank"))
        dynamic = item.flag("dynamic", False)
        offset = item.pose()
        key = f"tank:{tris + tris % 2}"
        mesh = scene.meshes.get(key) or generated(key, lambda: make_tank(tris))
        cols = int(math.ceil(math.sqrt(n)))
        for k in range(n):
            pose = offset.copy()
            pose[0] += (k % cols) * spacing
            pose[1] += (k // cols) * spacing
            scene.add(Body(f"{prefix}_{k}", key, dynamic, pose, "tank"), mesh)
    elif kind == "tank":
        tris = _parse_tris(item.get("tris", 5442), item.where)
        key = f"tank:{tris + tris % 2}"
        mesh = scene.meshes.get(key) or generated(key, lambda: make_tank(tris))
        scene.add(Body(str(item.get("name", default_name)), key, item.flag("dynamic", False), item.pose(), "tank"), mesh)
    elif kind == "missile":
        length, radius = item.num("length", 3.0), item.num("radius", 0.15)
        if length <= 0 or radius <= 0:
            raise SceneError(f"{item.where}: missile length and radius must be > 0")
        key = f"missile:{length:g}:{radius:g}"
        mesh = scene.meshes.get(key) or generated(key, lambda: make_missile(length, radius))
        scene.add(Body(str(item.get("name", default_name)), key, item.flag("dynamic", True), item.pose(), "missile"), mesh)
    elif kind in ("box", "sphere", "cylinder"):
        if kind == "box":
            size = (item.num("sx", 1.0), item.num("sy", 1.0), item.num("sz", 1.0))
            if min(size) <= 0:
                raise SceneError(f"{item.where}: box sizes must be > 0")
            key, make = f"box:{size}", lambda: _creation().box(size)
        elif kind == "sphere":
            r, sub = item.num("r", 0.5), int(item.num("subdiv", 3))
            if r <= 0:
                raise SceneError(f"{item.where}: sphere r must be > 0")
            key, make = f"sphere:{r}:{sub}", lambda: _creation().icosphere(subdivisions=sub, radius=r)
        else:
            r, hh = item.num("r", 0.5), item.num("h", 1.0)
            if r <= 0 or hh <= 0:
                raise SceneError(f"{item.where}: cylinder r and h must be > 0")
            key, make = f"cylinder:{r}:{hh}", lambda: _creation().cylinder(radius=r, height=hh, sections=32)
        mesh = scene.meshes.get(key) or generated(key, make)
        scene.add(Body(str(item.get("name", default_name)), key, item.flag("dynamic", False), item.pose(), kind), mesh)
    elif kind == "mesh":
        file = item.get("file")
        if not file:
            raise SceneError(f"{item.where}: kind 'mesh' needs a file key")
        path = Path(str(file))
        if not path.is_absolute() and item.base_dir is not None:
            path = item.base_dir / path
        key = f"file:{path.resolve()}"
        mesh = scene.meshes.get(key) or load_mesh(path)
        scene.add(Body(str(item.get("name", path.stem)), key, item.flag("dynamic", False), item.pose(),
                       str(item.get("group", "mesh"))), mesh)
    else:
        raise SceneError(f"{item.where}: unknown kind {kind!r} (tanks, tank, missile, box, sphere, "
                         f"cylinder, mesh)")
    item.check_unused()


def _items_from_generator(spec: str) -> List[Tuple[str, dict, str]]:
    items = []
    for k, raw in enumerate(part.strip() for part in spec.split(";")):
        if not raw:
            continue
        kind, _, rest = raw.partition(":")
        kind = kind.strip().lower()
        keys: dict = {}
        where = f"scene spec item {k + 1} {raw!r}"
        for kv in filter(None, (s.strip() for s in rest.split(","))):
            key, eq, value = kv.partition("=")
            if not eq or not key.strip():
                raise SceneError(f"{where}: {kv!r} is not key=value")
            keys[key.strip().lower()] = value.strip()
        items.append((kind, keys, where))
    return items


def _items_from_json(text: str, label: str) -> List[Tuple[str, dict, str]]:
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise SceneError(f"scene {label}: invalid JSON: {exc}") from None
    bodies = data.get("bodies") if isinstance(data, dict) else None
    if not isinstance(bodies, list):
        raise SceneError(f"scene {label}: expected an object with a list 'bodies'")
    items = []
    for k, entry in enumerate(bodies):
        where = f"scene {label} bodies[{k}]"
        if not isinstance(entry, dict) or "kind" not in entry:
            raise SceneError(f"{where}: each body needs a 'kind'")
        items.append((str(entry["kind"]).lower(), {str(a).lower(): v for a, v in entry.items()}, where))
    return items


def parse_scene(spec: str, base_dir: str | os.PathLike | None = None) -> Scene:
    """Build a :class:`Scene` from a generator spec, a JSON scene or a mesh file path.

    See the module docstring for the format. Raises :class:`SceneError` (or
    :class:`MeshError`) naming the item, key or file at fault.
    """
    if not isinstance(spec, str) or not spec.strip():
        raise SceneError("scene spec is empty")
    text = spec.strip()
    base = Path(base_dir) if base_dir is not None else None
    lower = text.lower()
    if lower.endswith(".json"):
        path = Path(text)
        if not path.is_absolute() and base is not None:
            path = base / path
        if not path.is_file():
            raise SceneError(f"scene file {str(path)!r} does not exist")
        items = _items_from_json(path.read_text(), repr(str(path)))
        base = path.parent
    elif text.startswith("{"):
        items = _items_from_json(text, "JSON")
    elif lower.endswith(MESH_EXTENSIONS) and ":" not in text.split("/")[-1] and "=" not in text:
        items = [("mesh", {"file": text, "dynamic": True}, f"scene mesh {text!r}")]
    else:
        items = _items_from_generator(text)
    scene = Scene(source=text)
    counter: Dict[str, int] = {}
    for kind, keys, where in items:
        _add_item(scene, _Item(kind, keys, where, base), counter)
    if not scene.bodies:
        raise SceneError(f"scene spec {text!r} defines no bodies")
    log.info("scene %r: %d bodies (%d dynamic), %d mesh(es), %d triangles", text[:60], len(scene.bodies),
             len(scene.dynamic), len(scene.meshes), scene.n_triangles())
    return scene
