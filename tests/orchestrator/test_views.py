"""The 3D view of what the units describe: the collision unit's meshes, once, posed by its inputs."""
from __future__ import annotations

import base64
import json

import numpy as np
import pytest
from mcap.reader import make_reader
from scipy.spatial.transform import Rotation

from immersim.models.collision.geometry import pose_matrix
from immersim.models.collision.scene import parse_scene
from immersim.orchestrator.execution import Execution

SCENE = "tanks:n=3,tris=5.4k,spacing=10;missile:x=-30,y=0,z=15,pitch=0.41"


def _scenario(tmp_path, fmu, extra=""):
    path = tmp_path / "view.toml"
    path.write_text(f'''
[simulation]
stop = 0.33
[[units]]
name = "coll"
fmu = "{fmu}"
[units.parameters]
scene = "{SCENE}"
pairs = "missile vs any tank"
[[inputs]]
target = "coll.body[1].x"
kind = "ramp"
at = 0.0
slope = 5.0
initial = -30.0
[[inputs]]
target = "coll.body[1].pitch"
kind = "constant"
value = 0.41
[foxglove]
units = true
{extra}
''')
    return path


def _messages(path):
    with open(path, "rb") as f:
        return [(c.topic, m.log_time, json.loads(m.data)) for _, c, m in make_reader(f).iter_messages()
                if c.topic in ("/tf", "/scene/meshes", "coll")]


def _accessor(gltf, binary, i):
    """An accessor's values as read by the glTF 2.0 specification (tightly packed views)."""
    acc = gltf["accessors"][i]
    view = gltf["bufferViews"][acc["bufferView"]]
    dtype = {5121: np.uint8, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}[acc["componentType"]]
    width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}[acc["type"]]
    data = np.frombuffer(binary, dtype, acc["count"] * width, view.get("byteOffset", 0) + acc.get("byteOffset", 0))
    return data.reshape(acc["count"], width).astype(float)


def _trs(node):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(node.get("rotation", [0, 0, 0, 1])).as_matrix()
    T[:3, 3] = node.get("translation", [0, 0, 0])
    return T


def _drawn(model):
    """Every copy of every mesh of a ``ModelPrimitive``'s GLB as Foxglove places it: the node
    chain, each GPU instance (EXT_mesh_gpu_instancing) and Foxglove's +90 degrees about x of a
    glTF model (y-up) into its z-up world. Returns a list of (vertices (n, 3), faces (m, 3))."""
    import io
    import struct

    import trimesh

    assert model["media_type"] == "model/gltf-binary" and model["url"] == ""
    data = base64.b64decode(model["data"])   # the schema's contentEncoding
    magic, version, total = struct.unpack_from("<4sII", data)
    assert (magic, version, total) == (b"glTF", 2, len(data))
    n = struct.unpack_from("<I", data, 12)[0]
    gltf, binary = json.loads(data[20:20 + n]), data[28 + n:]
    scene = trimesh.load(io.BytesIO(data), file_type="glb", force="scene")   # a reference importer reads it
    assert len(scene.graph.nodes_geometry) == sum("mesh" in node for node in gltf["nodes"])
    turn = np.eye(4)
    turn[:3, :3] = Rotation.from_euler("x", 90, degrees=True).as_matrix()
    out = []

    def walk(i, parent):
        node = gltf["nodes"][i]
        T = parent @ _trs(node)
        if "mesh" in node:
            (prim,) = gltf["meshes"][node["mesh"]]["primitives"]
            vertices = _accessor(gltf, binary, prim["attributes"]["POSITION"])
            faces = _accessor(gltf, binary, prim["indices"]).astype(int).reshape(-1, 3)
            inst = node.get("extensions", {}).get("EXT_mesh_gpu_instancing", {}).get("attributes")
            copies = [np.eye(4)]
            if inst:
                t = _accessor(gltf, binary, inst["TRANSLATION"])
                q = _accessor(gltf, binary, inst["ROTATION"]) if "ROTATION" in inst else [[0, 0, 0, 1]] * len(t)
                copies = [_trs({"translation": a, "rotation": b}) for a, b in zip(t, q)]
            for C in copies:
                M = T @ C
                out.append((vertices @ M[:3, :3].T + M[:3, 3], faces))
        for child in node.get("children", []):
            walk(child, T)

    for root in gltf["scenes"][gltf.get("scene", 0)]["nodes"]:
        walk(root, turn)
    return out


def _conforms(schema, value, path="message"):
    """``value`` holds only fields ``schema`` declares, of their types, in the shape Foxglove's
    JSON reader needs (every object with its properties, every array with typed items)."""
    kind = schema["type"]
    if kind == "object":
        assert isinstance(value, dict) and "properties" in schema, path
        for k, v in value.items():
            assert k in schema["properties"], f"{path}.{k} is not in the schema"
            _conforms(schema["properties"][k], v, f"{path}.{k}")
    elif kind == "array":
        assert isinstance(value, list) and "type" in schema["items"], path
        for v in value:
            _conforms(schema["items"], v, path + "[]")
    else:
        types = {"number": (int, float), "integer": int, "string": str, "boolean": bool}[kind]
        assert isinstance(value, types), path


def _foxglove(key, value):
    """A decoded ``/scene/meshes`` value rebuilt with foxglove-sdk's own message classes (a
    field Foxglove's SceneUpdate does not have, or of another type, raises); ``key`` names it."""
    import foxglove.messages as fm

    classes = {"entities": fm.SceneEntity, "deletions": fm.SceneEntityDeletion, "timestamp": fm.Timestamp,
               "lifetime": fm.Duration, "cubes": fm.CubePrimitive, "spheres": fm.SpherePrimitive,
               "cylinders": fm.CylinderPrimitive, "lines": fm.LinePrimitive,
               "models": fm.ModelPrimitive, "pose": fm.Pose, "position": fm.Vector3, "orientation": fm.Quaternion,
               "size": fm.Vector3, "scale": fm.Vector3, "color": fm.Color, "colors": fm.Color, "points": fm.Point3}
    if isinstance(value, list):
        return [_foxglove(key, v) for v in value]
    if key == "data":
        return base64.b64decode(value)
    if key == "type":
        return {t.value: t for t in (fm.LinePrimitiveLineType.LineStrip, fm.LinePrimitiveLineType.LineLoop,
                                     fm.LinePrimitiveLineType.LineList)}[value]
    if isinstance(value, dict):
        return classes[key](**{k: _foxglove(k, v) for k, v in value.items()})
    return value


def test_meshes_are_logged_once_with_their_own_triangles(tmp_path, built_fmus):
    """Each body drawn with its own triangles: the dynamic ones in their own frame, every static
    one a copy of its mesh at its pose (trimesh's own transform as the reference)."""
    out = tmp_path / "view.mcap"
    Execution(_scenario(tmp_path, built_fmus["collision"]), out).run()
    msgs = _messages(out)
    meshes = [m for t, _, m in msgs if t == "/scene/meshes"]
    assert len(meshes) == 1   # once, not per step
    with open(out, "rb") as f:
        summary = make_reader(f).get_summary()
    (channel,) = [c for c in summary.channels.values() if c.topic == "/scene/meshes"]
    _conforms(json.loads(summary.schemas[channel.schema_id].data), meshes[0])
    import foxglove.messages as fm

    assert fm.SceneUpdate(**{k: _foxglove(k, v) for k, v in meshes[0].items()}).encode()
    scene = parse_scene(SCENE)
    entities = {e["id"]: e for e in meshes[0]["entities"]}
    assert set(entities) == {"coll/missile", "coll/static"}
    (missile,) = _drawn(entities["coll/missile"]["models"][0])
    assert entities["coll/missile"]["frame_id"] == "coll/missile"   # frame-locked to its /tf frame
    mesh = scene.mesh(scene.index("missile"))
    np.testing.assert_allclose(missile[0], mesh.vertices, atol=1e-6)
    np.testing.assert_array_equal(missile[1], mesh.faces)
    assert entities["coll/static"]["frame_id"] == "world"
    drawn = _drawn(entities["coll/static"]["models"][0])
    static = [i for i, b in enumerate(scene.bodies) if not b.dynamic]
    assert len(drawn) == len(static) == 3
    for i in static:
        want = scene.mesh(i).copy().apply_transform(pose_matrix(scene.bodies[i].pose))
        assert sum(np.allclose(v, want.vertices, atol=1e-5) and np.array_equal(f, want.faces) for v, f in drawn) == 1


def test_dynamic_bodies_follow_their_pose_inputs(tmp_path, built_fmus):
    out = tmp_path / "view.mcap"
    Execution(_scenario(tmp_path, built_fmus["collision"]), out).run()
    msgs = _messages(out)
    poses = {t: m for topic, t, m in msgs if topic == "coll"}
    tfs = [(t, m) for topic, t, m in msgs if topic == "/tf"]
    assert len(tfs) == len(poses) == 11
    for t, m in tfs:
        (tf,) = [x for x in m["transforms"] if x["child_frame_id"] == "coll/missile"]
        p = poses[t]
        assert [tf["translation"][k] for k in "xyz"] == pytest.approx([p["body[1].x"], p["body[1].y"], p["body[1].z"]])
        R = pose_matrix([0, 0, 0, p["body[1].roll"], p["body[1].pitch"], p["body[1].yaw"]])[:3, :3]
        q = [tf["rotation"][k] for k in "xyzw"]
        np.testing.assert_allclose(Rotation.from_quat(q).as_matrix(), R, atol=1e-12)


def test_static_bodies_beyond_the_budget_are_their_bounding_boxes(tmp_path, built_fmus):
    out = tmp_path / "view.mcap"
    Execution(_scenario(tmp_path, built_fmus["collision"], "mesh_triangles = 1000"), out).run()
    (meshes,) = [m for t, _, m in _messages(out) if t == "/scene/meshes"]
    scene = parse_scene(SCENE)
    entities = {e["id"]: e for e in meshes["entities"]}
    (missile,) = _drawn(entities["coll/missile"]["models"][0])   # dynamic bodies keep their meshes
    assert len(missile[1]) == len(scene.mesh(scene.index("missile")).faces)
    drawn = _drawn(entities["coll/static"]["models"][0])
    static = [i for i, b in enumerate(scene.bodies) if not b.dynamic]
    assert len(drawn) == len(static)
    for i in static:   # the 8 corners of the body's bounds, at its pose
        lo, hi = scene.mesh(i).bounds
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        T = pose_matrix(scene.bodies[i].pose)
        want = corners @ T[:3, :3].T + T[:3, 3]
        hits = [v for v, f in drawn if len(f) == 12 and np.allclose(np.sort(v, axis=0), np.sort(want, axis=0), atol=1e-5)]
        assert len(hits) == 1


def test_a_field_of_tanks_is_one_mesh_and_a_table_per_row():
    """5040 tanks on a 71 x 71 grid: one box mesh, rows sharing an instance table, every tank
    drawn once at its place; the model stays a few kilobytes."""
    from immersim.orchestrator.views import collision_view

    scene = parse_scene("tanks:n=5040,tris=5.4k,spacing=10")
    _, (static,) = collision_view("coll", "tanks:n=5040,tris=5.4k,spacing=10", 500_000)
    model = static.primitive()["models"][0]
    drawn = _drawn(model)
    assert len(drawn) == 5040
    lo, hi = scene.mesh(0).bounds
    centres = np.array(sorted(tuple(np.round(v.mean(axis=0) - (lo + hi) / 2, 6)) for v, _ in drawn))
    want = np.array(sorted(tuple(np.round(b.pose[:3], 6)) for b in scene.bodies))
    np.testing.assert_allclose(centres, want, atol=1e-4)
    assert len(base64.b64decode(model["data"])) < 16_000


def test_the_platform_is_drawn_from_its_geometry_at_its_pose(tmp_path, built_fmus):
    """Plate frame = the unit's pose (A = Ax(gamma) Ay(beta) Az(alpha)); every step's rods run
    from the ball joint B_i on the plate to a slider point C_i that lies on its rail at the
    stroke the unit reports, one rod length c away (an independent check of the IK drawing)."""
    from immersim.models.platform.kinematics import rotation
    from immersim.models.platform.params import PlatformParams

    path = tmp_path / "plat.toml"
    path.write_text(f'''
[simulation]
stop = 0.66
[[units]]
name = "plat"
fmu = "{built_fmus["platform"]}"
[[inputs]]
target = "plat.cue.f_x"
kind = "step"
at = 0.1
value = 2.0
[[inputs]]
target = "plat.cue.w_z"
kind = "constant"
value = 0.3
[foxglove]
units = true
''')
    out = tmp_path / "plat.mcap"
    Execution(path, out).run()
    with open(out, "rb") as f:
        msgs = [(c.topic, m.log_time, json.loads(m.data)) for _, c, m in make_reader(f).iter_messages()]
    p = PlatformParams()
    unit = {t: m for topic, t, m in msgs if topic == "plat"}
    rods = {t: m for topic, t, m in msgs if topic == "/scene/plat"}
    tfs = {t: m for topic, t, m in msgs if topic == "/tf"}
    assert len(rods) == len(unit) == 21
    moved = 0.0
    for t, m in unit.items():
        pose = [m[f"pose.{a}"] for a in ("x", "y", "z", "gamma", "beta", "alpha")]
        A = rotation(np.array(pose[3:]))
        (tf,) = [x for x in tfs[t]["transforms"] if x["child_frame_id"] == "plat/plate"]
        np.testing.assert_allclose(Rotation.from_quat([tf["rotation"][k] for k in "xyzw"]).as_matrix(), A, atol=1e-12)
        assert [tf["translation"][k] for k in "xyz"] == pytest.approx(pose[:3])
        pts = np.array([[q["x"], q["y"], q["z"]] for q in rods[t]["entities"][0]["lines"][0]["points"]])
        B, C = pts[0::2], pts[1::2]
        np.testing.assert_allclose(B, np.array(pose[:3]) + p.joints @ A.T, atol=1e-12)
        strokes = np.array([m[f"stroke[{i}]"] for i in range(1, 7)])
        np.testing.assert_allclose(C, p.sliders_home + strokes[:, None] * p.axes, atol=1e-9)
        np.testing.assert_allclose(np.linalg.norm(B - C, axis=1), p.c, atol=1e-9)
        moved = max(moved, float(np.max(np.abs(strokes))))
    assert moved > 1e-3   # the cue moved the actuators: the check is not of the home pose only
    import foxglove.messages as fm

    (meshes,) = [m for topic, _, m in msgs if topic == "/scene/meshes"]   # the plate's cube, the rails' lines
    assert {k for e in meshes["entities"] for k in ("cubes", "lines") if k in e} == {"cubes", "lines"}
    assert fm.SceneUpdate(**{k: _foxglove(k, v) for k, v in meshes.items()}).encode()


@pytest.mark.parametrize("name, topics", [("demo", {"/scene"}), ("teleop", {"/scene/meshes", "/scene/plat"})])
def test_every_scene_channel_declares_what_its_messages_hold(tmp_path, name, topics):
    """Hand-written bodies (demo's ``/scene``) and the platform's rods redrawn each step
    (teleop's ``/scene/plat``) get a schema that declares every field, as ``/scene/meshes``
    does: Foxglove's JSON reader reads nothing from an object schema without its properties."""
    from immersim.orchestrator.cli import main

    root = __import__("pathlib").Path(__file__).resolve().parents[2]
    out = tmp_path / f"{name}.mcap"
    assert main(["run", str(root / "scenarios" / f"{name}.toml"), "-q", "-o", str(out),
                 "--set", "simulation.stop=0.099"]) == 0
    import foxglove.messages as fm

    seen = set()
    with open(out, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            if channel.topic.startswith("/scene"):
                seen.add(channel.topic)
                value = json.loads(message.data)
                _conforms(json.loads(schema.data), value, channel.topic)
                assert fm.SceneUpdate(**{k: _foxglove(k, v) for k, v in value.items()}).encode()
    assert seen == topics
