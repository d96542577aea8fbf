"""The 3D view of what the units describe: the collision unit's meshes, once, posed by its inputs."""
from __future__ import annotations

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


def test_meshes_are_logged_once_with_their_own_triangles(tmp_path, built_fmus):
    out = tmp_path / "view.mcap"
    Execution(_scenario(tmp_path, built_fmus["collision"]), out).run()
    msgs = _messages(out)
    meshes = [m for t, _, m in msgs if t == "/scene/meshes"]
    assert len(meshes) == 1   # once, not per step
    scene = parse_scene(SCENE)
    entities = {e["id"]: e for e in meshes[0]["entities"]}
    assert set(entities) == {f"coll/{b.name}" for b in scene.bodies}
    for i, b in enumerate(scene.bodies):
        tri = entities[f"coll/{b.name}"]["triangles"][0]
        mesh = scene.mesh(i)
        assert len(tri["indices"]) == 3 * len(mesh.faces)
        pts = np.array([[p["x"], p["y"], p["z"]] for p in tri["points"]])
        if b.dynamic:   # in the body's own frame, frame-locked to its /tf frame
            assert entities[f"coll/{b.name}"]["frame_id"] == f"coll/{b.name}"
            np.testing.assert_array_equal(pts, mesh.vertices)
        else:           # static: placed in the world once (trimesh's own transform as the reference)
            assert entities[f"coll/{b.name}"]["frame_id"] == "world"
            np.testing.assert_allclose(pts, mesh.copy().apply_transform(pose_matrix(b.pose)).vertices, atol=1e-12)


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
    for e in meshes["entities"]:
        i = scene.index(e["id"].split("/", 1)[1])
        if scene.bodies[i].dynamic:
            assert "triangles" in e   # dynamic bodies keep their meshes
            continue
        (cube,) = e["cubes"]
        lo, hi = scene.mesh(i).bounds
        assert [cube["size"][k] for k in "xyz"] == pytest.approx(hi - lo)
        centre = pose_matrix(scene.bodies[i].pose) @ np.append((lo + hi) / 2, 1.0)
        assert [cube["pose"]["position"][k] for k in "xyz"] == pytest.approx(centre[:3])


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
