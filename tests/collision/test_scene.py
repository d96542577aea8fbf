"""Scenes: generated workloads, spec formats, mesh files and their errors, pair specs."""
import json
import warnings

import numpy as np
import pytest
import trimesh

from immersim.models.collision import (MeshError, MeshWarning, PairSpecError, SceneError, TANK_TRIS, make_tank,
                                       parse_pairs, parse_scene)


@pytest.mark.parametrize("label,count", sorted(TANK_TRIS.items()))
def test_thesis_tanks_have_their_triangle_counts_and_are_closed(label, count):
    tank = make_tank(count)
    assert len(tank.faces) == count
    assert tank.is_watertight and tank.is_winding_consistent
    assert parse_scene(f"tank:tris={label}").n_triangles() == count


def test_odd_triangle_count_is_rounded_up_to_even():
    assert len(make_tank(10113).faces) == 10114


def test_tank_field_shares_one_mesh_and_lies_on_a_grid():
    scene = parse_scene("tanks:n=10,tris=5442,spacing=12;missile:z=6")
    assert len(scene.bodies) == 11 and len(scene.meshes) == 2
    assert scene.dynamic == [10]
    xy = scene.poses()[:10, :2]
    assert set(np.round(xy[:, 0], 9)) == {0.0, 12.0, 24.0, 36.0}  # ceil(sqrt(10)) = 4 columns
    assert scene.bodies[3].name == "tank_3" and scene.bodies[3].group == "tank"


def test_json_scene_and_mesh_files(tmp_path):
    box = trimesh.creation.box((1, 2, 3))
    for ext in ("stl", "obj", "ply", "glb"):
        box.export(tmp_path / f"b.{ext}")
    spec = {"bodies": [{"kind": "mesh", "file": f"b.{ext}", "name": f"b_{ext}", "x": 3 * k}
                       for k, ext in enumerate(("stl", "obj", "ply", "glb"))]}
    (tmp_path / "scene.json").write_text(json.dumps(spec))
    scene = parse_scene(str(tmp_path / "scene.json"))
    assert [b.name for b in scene.bodies] == ["b_stl", "b_obj", "b_ply", "b_glb"]
    for i in range(4):
        np.testing.assert_allclose(scene.mesh(i).extents, [1, 2, 3], atol=1e-9)
    single = parse_scene(str(tmp_path / "b.stl"))
    assert single.bodies[0].name == "b" and single.bodies[0].dynamic


def test_missing_and_corrupt_mesh_files_name_the_file(tmp_path):
    with pytest.raises(MeshError, match=r"nowhere\.obj.*does not exist"):
        parse_scene(f"mesh:file={tmp_path / 'nowhere.obj'}")
    bad = tmp_path / "broken.stl"
    bad.write_bytes(b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0\n")
    with pytest.raises(MeshError, match=r"broken\.stl"):
        parse_scene(f"mesh:file={bad}")


def test_non_watertight_mesh_warns(tmp_path):
    box = trimesh.creation.box((1, 1, 1))
    open_box = trimesh.Trimesh(box.vertices, box.faces[:-2], process=False)
    open_box.export(tmp_path / "open.stl")
    with pytest.warns(MeshWarning, match="not watertight"):
        parse_scene(f"mesh:file={tmp_path / 'open.stl'}")


@pytest.mark.parametrize("spec,match", [
    ("tanks:n=0", r"n = 0 tanks is outside 1\.\.5040"),
    ("tanks:n=5041", "outside"),
    ("tank:tris=lots", r"tris = 'lots'"),
    ("missile:z=up", r"z = 'up' is not a number"),
    ("missile:colour=red", r"unknown key\(s\) colour"),
    ("teapot:r=1", r"unknown kind 'teapot'"),
    ("box:sx=1;box:sx=2,name=box", r"body name 'box' used twice"),
    ("box:sx", r"'sx' is not key=value"),
    ("{\"bodies\": 3}", "list 'bodies'"),
])
def test_bad_specs_name_item_and_key(spec, match):
    with pytest.raises(SceneError, match=match):
        parse_scene(spec)


def test_pair_specs():
    scene = parse_scene("tanks:n=3;missile:z=5;box:name=rock,x=50")
    pairs = parse_pairs("missile vs any tank; missile vs rock; tank_0 vs scene; missile vs any tank_[12]", scene)
    assert [list(p.members) for p in pairs] == [[0, 1, 2], [4], [1, 2, 3, 4], [1, 2]]
    default = parse_pairs("", scene)
    assert len(default) == 1 and default[0].a == 3 and len(default[0].members) == 4
    with pytest.raises(PairSpecError, match="no body named 'rocket'"):
        parse_pairs("rocket vs scene", scene)
    with pytest.raises(PairSpecError, match="expected 'A vs B'"):
        parse_pairs("missile against rock", scene)
    with pytest.raises(PairSpecError, match="no body matches group or name 'plane'"):
        parse_pairs("missile vs any plane", scene)
