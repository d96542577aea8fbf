"""Distance triangulations (models/collision/fans.py): a cylinder cap's fan re-triangulated."""
import fcl
import numpy as np
import pytest
import trimesh

from immersim.models.collision import BackendConfig, make_backend, parse_scene
from immersim.models.collision.fans import FAN_INNER, distance_faces, fan_centres, halving_cap
from immersim.models.collision.fcl_backend import bvh_model, fcl_transform
from immersim.models.collision.geometry import point_triangle_distance, pose_matrix
from immersim.models.collision.scene import TANK_TRIS, make_missile, make_tank


@pytest.mark.parametrize("tris", sorted(TANK_TRIS.values()))
def test_tank_distance_faces_are_the_same_closed_surface(tris):
    tank = make_tank(tris)
    F = distance_faces(tank.vertices, tank.faces)
    assert F.shape == tank.faces.shape  # exactly the same number of triangles
    turret_caps = fan_centres(tank.vertices, tank.faces)
    assert len(turret_caps) == 2
    changed = (F != tank.faces).any(axis=1)
    assert changed.sum() > 0 and np.all((tank.faces[changed, :, None] == np.array(turret_caps)).any(axis=(1, 2)))
    mesh = trimesh.Trimesh(tank.vertices, F, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume == pytest.approx(tank.volume, rel=1e-12)
    assert mesh.area == pytest.approx(tank.area, rel=1e-12)
    # no vertex is shared by more than a handful of cap triangles any more
    for c in turret_caps:
        assert int((F == c).any(axis=1).sum()) <= FAN_INNER
    assert np.bincount(F.ravel()).max() < 64
    assert mesh.area_faces.min() > 1e-12 * mesh.scale ** 2  # no degenerate triangle


@pytest.mark.parametrize("sections", [5, 6, 7, 8, 13, 64, 100, 581])
def test_halving_cap_keeps_every_cap_triangle_count(sections):
    cyl = trimesh.creation.cylinder(radius=1.2, height=0.8, sections=sections)
    faces = cyl.faces
    for c in np.flatnonzero((cyl.vertices[:, 0] == 0) & (cyl.vertices[:, 1] == 0)):
        faces = halving_cap(faces, int(c), cyl.vertices)
    mesh = trimesh.Trimesh(cyl.vertices, faces, process=False)
    assert len(faces) == 4 * sections
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume == pytest.approx(cyl.volume, rel=1e-12)
    assert np.allclose(mesh.face_normals[:, 2][np.abs(mesh.face_normals[:, 2]) > 0.5],
                       cyl.face_normals[:, 2][np.abs(cyl.face_normals[:, 2]) > 0.5])


def test_halving_cap_leaves_a_non_convex_fan_alone():
    # a star-shaped (non-convex) plane fan: ears would leave the polygon
    k = 12
    ang = np.arange(k) * 2 * np.pi / k
    r = np.where(np.arange(k) % 2 == 0, 1.0, 0.3)
    V = np.vstack([[0, 0, 0], np.c_[r * np.cos(ang), r * np.sin(ang), np.zeros(k)]])
    F = np.array([[0, 1 + j, 1 + (j + 1) % k] for j in range(k)])
    np.testing.assert_array_equal(halving_cap(F, 0, V, inner=4), F)
    assert distance_faces(V, F) is None  # fewer than FAN_MIN_TRIANGLES anyway
    m = make_missile()  # 32-section caps: left as they are
    assert distance_faces(m.vertices, m.faces) is None


def test_points_above_the_cap_have_the_fan_distances():
    """Exact point-triangle distances (brute force over every triangle) to the fan and to the
    distance triangulation agree to round-off, for points above the turret's top cap (near
    its centre, where the fan's slivers meet) and around the turret."""
    tank = make_tank(5442)
    F = distance_faces(tank.vertices, tank.faces)
    rng = np.random.default_rng(3)
    centre = np.array([-0.3, 0.0, 2.4])
    pts = np.vstack([centre + np.c_[rng.normal(0, 0.05, (40, 2)), rng.uniform(1e-3, 0.5, 40)],
                     centre + np.c_[rng.uniform(-1.6, 1.6, (60, 2)), rng.uniform(-0.9, 0.6, 60)]])
    for tri_faces in (tank.faces, F):
        T = np.asarray(tank.vertices, float)[tri_faces]
        d = np.array([point_triangle_distance(np.broadcast_to(p, (len(T), 3)), T)[0].min() for p in pts])
        if tri_faces is tank.faces:
            ref = d
    np.testing.assert_allclose(d, ref, rtol=0, atol=1e-12)
    assert np.all(ref[:40] > 0)


def test_backend_distances_equal_raw_fcl_on_the_mesh_itself():
    """The fcl backend's distances (distance triangulation, chunks) equal raw python-fcl's on
    the tank's own triangles to round-off, for the missile diving onto the turret cap's centre
    and for an avatar box around the tank; contacts are the mesh's own (same depth)."""
    spec = "tank:name=t,tris=5.4k;missile:name=m,x=0,z=10;box:name=av,sx=4,sy=2,sz=4.4,dynamic=1,x=30"
    scene = parse_scene(spec)
    be = make_backend("fcl", scene, "m vs t; av vs t", BackendConfig(max_distance=float("inf")))
    tank = scene.meshes[scene.bodies[0].mesh_key]
    raw_t = fcl.CollisionObject(bvh_model(tank.vertices, tank.faces), fcl.Transform())
    raw = [fcl.CollisionObject(bvh_model(scene.mesh(i).vertices, scene.mesh(i).faces), fcl.Transform()) for i in (1, 2)]
    rng = np.random.default_rng(5)
    checked = 0
    for k in range(30):
        nose = [-0.3 - 1.27 + rng.normal(0, 0.03), rng.normal(0, 0.03), 2.4 + 0.8 + rng.uniform(-0.05, 0.4), 0, 0.564, 0]
        box = [rng.uniform(-6, 6), rng.choice([-3.5, 3.5]) + rng.normal(0, 0.5), 2.5, 0, 0, rng.uniform(-np.pi, np.pi)]
        res = be.query(np.array([nose, box]), 0.033)
        for p, obj, pose in zip(res.pairs, raw, (nose, box)):
            obj.setTransform(fcl_transform(pose_matrix(pose)))
            cres = fcl.CollisionResult()
            fcl.collide(raw_t, obj, fcl.CollisionRequest(num_max_contacts=be.config.max_contacts, enable_contact=True),
                        cres)
            assert p.in_contact == cres.is_collision
            if p.in_contact:
                deepest = max(c.penetration_depth for c in cres.contacts)
                assert p.depth == deepest
            else:
                d = fcl.distance(raw_t, obj, fcl.DistanceRequest(), fcl.DistanceResult())
                assert abs(p.distance - d) <= 1e-12
                checked += 1
    assert checked > 30
