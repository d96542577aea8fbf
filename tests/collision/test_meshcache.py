"""The mesh cache gives back trimesh's generated meshes bit for bit (vertices, faces, bounds,
extents, convex hull, convex parts), cold and warm, and survives a damaged entry."""
import numpy as np
import pytest
import trimesh

from immersim.models.collision import meshcache, parse_scene
from immersim.models.collision.exit import convex_parts

SPEC = ("tank:name=t,tris=600;missile:name=m,length=2.5,radius=0.2;box:name=b,sx=1,sy=2,sz=3;"
        "sphere:name=s,r=0.7,subdiv=2;cylinder:name=c,r=0.4,h=1.5")


def _same(a, b):
    a, b = np.asarray(a), np.asarray(b)
    assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def _check(cached, made):
    assert isinstance(cached, meshcache.CachedMesh) and isinstance(made, trimesh.Trimesh)
    for attr in ("vertices", "faces", "bounds", "extents"):
        _same(getattr(cached, attr), getattr(made, attr))
    _same(cached.convex_hull.vertices, made.convex_hull.vertices)
    parts, want = convex_parts(cached), convex_parts(made)
    assert len(parts) == len(want) > 0
    for p, q in zip(parts, want):
        _same(p, q)


def test_cold_and_warm_cache_give_trimesh_meshes_bit_for_bit(tmp_path, monkeypatch):
    monkeypatch.setenv("IMMERSIM_MESH_CACHE", "0")
    plain = parse_scene(SPEC)
    monkeypatch.setenv("IMMERSIM_MESH_CACHE", str(tmp_path))
    cold = parse_scene(SPEC)
    assert len(list(tmp_path.glob("*.npz"))) == len(plain.meshes) == 5
    warm = parse_scene(SPEC)
    for key, made in plain.meshes.items():
        _check(cold.meshes[key], made)
        _check(warm.meshes[key], made)
    assert warm.meshes[plain.bodies[0].mesh_key].trimesh().faces.shape == (600, 3)


def test_a_damaged_entry_is_made_again(tmp_path, monkeypatch):
    monkeypatch.setenv("IMMERSIM_MESH_CACHE", str(tmp_path))
    parse_scene("box:sx=1,sy=2,sz=3")
    (entry,) = tmp_path.glob("*.npz")
    entry.write_bytes(entry.read_bytes()[:100])
    mesh = next(iter(parse_scene("box:sx=1,sy=2,sz=3").meshes.values()))
    _same(mesh.vertices, trimesh.creation.box((1.0, 2.0, 3.0)).vertices)
    assert not list(tmp_path.glob("*.tmp"))
    with np.load(entry) as z:
        assert z["faces"].shape == (12, 3)


def test_a_flat_mesh_has_no_hull(tmp_path, monkeypatch):
    monkeypatch.setenv("IMMERSIM_MESH_CACHE", str(tmp_path))
    flat = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], process=False)
    mesh = meshcache.generated("flat-test", lambda: flat)
    with pytest.raises(ValueError, match="convex hull of this mesh could not be made"):
        mesh.convex_hull
    _same(convex_parts(mesh)[0], flat.vertices)


def test_the_cache_keeps_the_entries_used_last(tmp_path, monkeypatch):
    import os

    monkeypatch.setenv("IMMERSIM_MESH_CACHE", str(tmp_path))
    monkeypatch.setattr(meshcache, "MAX_ENTRIES", 2)
    parse_scene("box:sx=1,sy=1,sz=1")
    (first,) = tmp_path.glob("*.npz")
    os.utime(first, ns=(1, 1))   # used long ago ...
    parse_scene("box:sx=1,sy=1,sz=1")   # ... and now again: the newest
    parse_scene("box:sx=2,sy=1,sz=1")
    os.utime(next(f for f in tmp_path.glob("*.npz") if f != first), ns=(2, 2))
    parse_scene("box:sx=3,sy=1,sz=1")   # the third entry removes the one used least recently
    assert len(list(tmp_path.glob("*.npz"))) == 2 and first.exists()
