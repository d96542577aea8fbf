"""Importing the collision model (what building or loading the unit does) leaves the heavy
libraries alone; a scene imports trimesh when it builds a mesh (trimesh itself loads scipy's
spatial package and python-fcl), not when it reads the mesh back from the mesh cache."""
import os
import subprocess
import sys

HEAVY = ("trimesh", "scipy.spatial", "fcl")


def _loaded(code: str, **env) -> list:
    out = subprocess.run([sys.executable, "-c", f"import sys\n{code}\nprint(*[m for m in {HEAVY!r} if m in sys.modules])"],
                         capture_output=True, text=True, check=True, env={**os.environ, **env})
    return out.stdout.split()


def test_the_model_package_imports_no_heavy_library():
    assert _loaded("import immersim.models.collision") == []


def test_a_scene_of_primitives_brings_trimesh():
    code = "from immersim.models.collision import parse_scene\nparse_scene('box:sx=1,sy=1,sz=1')"
    assert "trimesh" in _loaded(code, IMMERSIM_MESH_CACHE="0")


def test_a_scene_read_from_the_mesh_cache_brings_no_heavy_library(tmp_path):
    code = "from immersim.models.collision import parse_scene\nparse_scene('box:sx=1,sy=1,sz=1;tank:tris=600')"
    assert "trimesh" in _loaded(code, IMMERSIM_MESH_CACHE=str(tmp_path))   # the first run builds and stores
    assert _loaded(code, IMMERSIM_MESH_CACHE=str(tmp_path)) == []
