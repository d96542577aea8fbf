"""Pose transforms and motion bounds of the collision models against independent forms."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from immersim.models.collision.poses import face_shift as _face_shift
from immersim.models.collision.geometry import pose_matrix, pose_rows


def _random_poses(n, seed):
    rng = np.random.default_rng(seed)
    return np.c_[rng.uniform(-5, 5, (n, 3)), rng.uniform(-np.pi, np.pi, (n, 3))]


def test_pose_transform_is_yaw_pitch_roll_about_fixed_axes():
    """eq. 4-6: R = R_z(yaw) R_y(pitch) R_x(roll) (scipy's extrinsic 'xyz'), translation last column."""
    for pose in _random_poses(30, 2):
        T = pose_matrix(pose)
        np.testing.assert_allclose(T[:3, :3], Rotation.from_euler("xyz", pose[3:]).as_matrix(), atol=1e-14)
        np.testing.assert_array_equal(T[:3, 3], pose[:3])
        np.testing.assert_array_equal(T[3], [0, 0, 0, 1])
        assert pose_rows(pose) == T.tolist()


def test_face_shift_terms_are_the_translation_and_frobenius_rotation_change():
    """|t1 - t0| and ||R1 - R0||_F; with them every point of radius <= r moves at most t + f r."""
    poses = _random_poses(40, 3)
    rng = np.random.default_rng(4)
    for p0, p1 in zip(poses[:-1], poses[1:]):
        T0, T1 = pose_matrix(p0), pose_matrix(p1)
        t, f = _face_shift(T0.tolist(), T1.tolist())
        assert t == pytest.approx(np.linalg.norm(T1[:3, 3] - T0[:3, 3]), rel=1e-14)
        assert f == pytest.approx(np.linalg.norm(T1[:3, :3] - T0[:3, :3], "fro"), rel=1e-14)
        v = rng.normal(size=(50, 3))
        v *= 0.7 / np.linalg.norm(v, axis=1)[:, None]
        moved = np.linalg.norm(v @ T1[:3, :3].T + T1[:3, 3] - v @ T0[:3, :3].T - T0[:3, 3], axis=1)
        assert moved.max() <= t + f * 0.7 + 1e-12


@pytest.mark.parametrize("n_rays", [1, 3])
def test_rays_through_a_posed_cube_hit_its_faces_where_the_pose_puts_them(n_rays):
    """Rays along +x through a unit cube at x = 2 (rotated 90 deg about z: the same faces) enter
    at x = 1.5 and leave at x = 2.5, in world coordinates (a single ray too); a ray that misses
    gives no hit."""
    import trimesh

    from immersim.models.collision.raycast import cast_rays

    T = pose_matrix([2.0, 0.0, 0.0, 0.0, 0.0, np.pi / 2])
    origins = np.array([[-3.0, 0.1 * k, 0.2] for k in range(n_rays)] + [[-3.0, 5.0, 0.0]] * (n_rays > 1))
    loc, idx = cast_rays(trimesh.creation.box((1, 1, 1)), T, origins, np.tile([1.0, 0.0, 0.0], (len(origins), 1)))
    assert sorted(set(idx.tolist())) == list(range(n_rays))
    for k in range(n_rays):
        xs = np.sort(loc[idx == k, 0])
        np.testing.assert_allclose(xs, [1.5, 2.5], atol=1e-12)
        np.testing.assert_allclose(loc[idx == k, 1:], [[0.1 * k, 0.2]] * 2, atol=1e-12)
