"""Binary glTF 2.0 (GLB) of triangle meshes and their copies, for Foxglove's ``ModelPrimitive``.

Each distinct mesh is stored once (float32 positions, indices of the smallest unsigned type,
one material of its colour); its copies are GPU instances (``EXT_mesh_gpu_instancing``, read
by three.js's ``GLTFLoader``, which Foxglove's 3D panel uses). Copies that share a row (the
same ``y`` and ``z`` and the same rotations and ``x`` steps along it, e.g. the rows of a field
of tanks) share one instance table: a node per row, placed at the row's first copy, points to
it. A single copy is a plain node posed by its translation and rotation.

Coordinates are z-up (ROS, Foxglove's world); glTF is y-up and Foxglove turns a model by
+90 degrees about x on loading it, so the root node turns the model by -90 degrees about x.
"""
from __future__ import annotations

import json
import struct
from dataclasses import dataclass
from typing import Any, Dict, List, Sequence, Tuple

import numpy as np

INSTANCING = "EXT_mesh_gpu_instancing"
#: the root node's rotation (x, y, z, w): -90 degrees about x, z-up -> glTF's y-up
Z_UP = [-float(np.sqrt(0.5)), 0.0, 0.0, float(np.sqrt(0.5))]
_FLOAT, _U8, _U16, _U32 = 5126, 5121, 5123, 5125
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963


@dataclass(frozen=True)
class Placed:
    """A mesh and its copies.

    ``vertices`` (n, 3) and ``faces`` (m, 3) in the mesh's own frame, m; ``color`` RGBA in
    0..1; copy i is the mesh turned by the unit quaternion ``rotations[i]`` (x, y, z, w) and
    then moved by ``translations[i]`` (k, 3), m, in the model's frame.
    """

    vertices: Any
    faces: Any
    color: Tuple[float, float, float, float]
    translations: Any
    rotations: Any


class _Builder:
    """The JSON and binary chunks of one GLB under construction."""

    def __init__(self) -> None:
        self.bin = bytearray()
        self.gltf: Dict[str, Any] = {"asset": {"version": "2.0", "generator": "immersim"}, "scene": 0,
                                     "scenes": [{"nodes": [0]}], "nodes": [{"rotation": Z_UP, "children": []}],
                                     "meshes": [], "materials": [], "accessors": [], "bufferViews": []}

    def accessor(self, array: np.ndarray, kind: str, component: int, target: int | None = None,
                 bounds: bool = False) -> int:
        """Append ``array``'s bytes (4-byte aligned) as a buffer view and an accessor; its index."""
        self.bin += b"\0" * (-len(self.bin) % 4)
        view: Dict[str, Any] = {"buffer": 0, "byteOffset": len(self.bin), "byteLength": array.nbytes}
        if target is not None:
            view["target"] = target
        self.bin += array.tobytes()
        self.gltf["bufferViews"].append(view)
        acc: Dict[str, Any] = {"bufferView": len(self.gltf["bufferViews"]) - 1, "componentType": component,
                               "count": len(array) if kind != "SCALAR" else array.size, "type": kind}
        if bounds:   # required for POSITION
            acc["min"], acc["max"] = array.min(axis=0).tolist(), array.max(axis=0).tolist()
        self.gltf["accessors"].append(acc)
        return len(self.gltf["accessors"]) - 1

    def mesh(self, part: Placed) -> int:
        vertices = np.asarray(part.vertices, dtype=np.float32).reshape(-1, 3)
        faces = np.asarray(part.faces).reshape(-1)
        index_type = next((t, c) for t, c in ((np.uint8, _U8), (np.uint16, _U16), (np.uint32, _U32))
                          if len(vertices) <= np.iinfo(t).max)
        position = self.accessor(vertices, "VEC3", _FLOAT, _ARRAY_BUFFER, bounds=True)
        indices = self.accessor(faces.astype(index_type[0]), "SCALAR", index_type[1], _ELEMENT_ARRAY_BUFFER)
        self.gltf["materials"].append({"pbrMetallicRoughness": {"baseColorFactor": [float(c) for c in part.color],
                                                                "metallicFactor": 0.0, "roughnessFactor": 1.0}})
        self.gltf["meshes"].append({"primitives": [{"attributes": {"POSITION": position}, "indices": indices,
                                                    "material": len(self.gltf["materials"]) - 1}]})
        return len(self.gltf["meshes"]) - 1

    def copies(self, mesh: int, part: Placed) -> None:
        """A node per row of copies (a single copy: a node posed by its own pose)."""
        t = np.asarray(part.translations, dtype=float).reshape(-1, 3)
        q = np.asarray(part.rotations, dtype=float).reshape(-1, 4)
        rows: Dict[Tuple[float, float], List[int]] = {}
        for i, (y, z) in enumerate(t[:, 1:].tolist()):
            rows.setdefault((y, z), []).append(i)
        turned = bool(np.any(q[:, :3]))
        tables: Dict[bytes, Dict[str, int]] = {}   # a row's instance data -> its accessors
        children = self.gltf["nodes"][0]["children"]
        for members in rows.values():
            first = members[0]
            node: Dict[str, Any] = {"mesh": mesh, "translation": t[first].tolist()}
            if len(members) == 1:
                if turned:
                    node["rotation"] = q[first].tolist()
            else:
                steps = np.zeros((len(members), 3), dtype=np.float32)
                steps[:, 0] = t[members, 0] - t[first, 0]
                rot = q[members].astype(np.float32)
                key = steps.tobytes() + (rot.tobytes() if turned else b"")
                if key not in tables:
                    tables[key] = {"TRANSLATION": self.accessor(steps, "VEC3", _FLOAT)}
                    if turned:
                        tables[key]["ROTATION"] = self.accessor(rot, "VEC4", _FLOAT)
                node["extensions"] = {INSTANCING: {"attributes": tables[key]}}
            self.gltf["nodes"].append(node)
            children.append(len(self.gltf["nodes"]) - 1)

    def glb(self) -> bytes:
        gltf = self.gltf
        if any("extensions" in n for n in gltf["nodes"]):
            gltf["extensionsUsed"] = gltf["extensionsRequired"] = [INSTANCING]
        self.bin += b"\0" * (-len(self.bin) % 4)
        gltf["buffers"] = [{"byteLength": len(self.bin)}]
        text = json.dumps(gltf, separators=(",", ":")).encode()
        text += b" " * (-len(text) % 4)
        total = 12 + 8 + len(text) + 8 + len(self.bin)
        return b"".join([struct.pack("<4sII", b"glTF", 2, total), struct.pack("<I4s", len(text), b"JSON"), text,
                         struct.pack("<I4s", len(self.bin), b"BIN\0"), bytes(self.bin)])


def model_glb(parts: Sequence[Placed]) -> bytes:
    """The GLB of ``parts``: each mesh once, its copies as instances (see the module's notes)."""
    b = _Builder()
    for part in parts:
        b.copies(b.mesh(part), part)
    return b.glb()

