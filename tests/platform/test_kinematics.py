"""Kinematics of the platform: eq. 6-14..6-19 against independent derivations."""
import numpy as np
import pytest
from hypothesis import assume, given, settings, strategies as st

from immersim.models.platform.kinematics import (
    OutsideWorkspaceError, actuator_jacobian, body_rate_matrix, clamp_to_workspace, forward_kinematics,
    inverse_kinematics, near_singular, rotation, workspace_check, world_rate_matrix)
from immersim.models.platform.params import PlatformParams

P = PlatformParams()


def _axis_rot(axis, t):
    c, s = np.cos(t), np.sin(t)
    return {"x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
            "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]


def test_rotation_is_product_of_axis_rotations_eq_6_8():
    g, b, a = 0.3, -0.2, 0.7
    A = rotation(np.array([g, b, a]))
    np.testing.assert_allclose(A, _axis_rot("x", g) @ _axis_rot("y", b) @ _axis_rot("z", a), atol=1e-15)
    np.testing.assert_allclose(A @ A.T, np.eye(3), atol=1e-15)


def test_rate_matrices_consistent_eq_6_11():
    ang = np.array([0.2, -0.4, 0.9])
    np.testing.assert_allclose(rotation(ang) @ body_rate_matrix(ang), world_rate_matrix(ang), atol=1e-15)
    # Omega from the derivative of A: [Omega]_x = A' A^T
    rate, eps = np.array([0.3, -0.5, 0.2]), 1e-6
    dA = (rotation(ang + eps * rate) - rotation(ang - eps * rate)) / (2 * eps)
    W = dA @ rotation(ang).T
    np.testing.assert_allclose([W[2, 1], W[0, 2], W[1, 0]], world_rate_matrix(ang) @ rate, atol=1e-9)


def test_home_is_zero_stroke():
    np.testing.assert_allclose(inverse_kinematics(np.zeros(6)), 0.0, atol=1e-15)


@pytest.mark.parametrize("z_c", [0.0, 0.02, -0.03])
def test_single_axis_y_motion_eq_6_75_to_6_80(z_c):
    c = P.c
    y = 0.05 * np.sin(np.linspace(0, 2 * np.pi, 50))
    poses = np.zeros((50, 6))
    poses[:, 1], poses[:, 2] = y, z_c
    L = inverse_kinematics(poses)
    expected = np.column_stack([
        c - np.sqrt(c**2 - y**2 - z_c**2),                # 6-75
        y + c - np.sqrt(c**2 - z_c**2),                   # 6-76
        y + c - np.sqrt(c**2 - z_c**2),                   # 6-77
        z_c + c - np.sqrt(c**2 - y**2),                   # 6-78
        z_c + c - np.sqrt(c**2 - y**2),                   # 6-79
        z_c + c - np.sqrt(c**2 - y**2)])                  # 6-80
    np.testing.assert_allclose(L, expected, atol=1e-15)


def _thesis_ik(q):
    """Eq. 6-14..6-19 transcribed term by term from the seed."""
    X, Y, Z = q[:3]
    a, b, c, d, e, h, m, n = P.a, P.b, P.c, P.d, P.e, P.h, P.m, P.n
    A = rotation(q[3:])
    a11, a12, a13, a21, a22, a23, a31, a32, a33 = A.ravel()
    r = np.sqrt
    return np.array([
        X - a * a11 + a + c - r(c**2 - (Y - a * a21) ** 2 - (Z - a * a31) ** 2),
        Y - e * a21 - b * a22 + b + c - r(c**2 - (X - e * a11 - b * a12 + e) ** 2 - (Z - e * a31 - b * a32) ** 2),
        Y + e * a21 - b * a22 + b + c - r(c**2 - (X + e * a11 - b * a12 - e) ** 2 - (Z + e * a31 - b * a32) ** 2),
        Z + d * a31 + m * a32 - h * a33 + h + c - r(c**2 - (X + d * a11 + m * a12 - h * a13 - d) ** 2
                                                   - (Y + d * a21 + m * a22 - h * a23 - m) ** 2),
        Z - d * a31 + m * a32 - h * a33 + h + c - r(c**2 - (X - d * a11 + m * a12 - h * a13 + d) ** 2
                                                   - (Y - d * a21 + m * a22 - h * a23 - m) ** 2),
        Z - n * a32 - h * a33 + h + c - r(c**2 - (X - n * a12 - h * a13) ** 2 - (Y - n * a22 - h * a23 + n) ** 2),
    ])


def _sphere_line_ik(q):
    """Independent derivation: slider point C_i = C_i^0 + t e_i on the sphere |C - B_i| = c,
    solved as a quadratic in t with numpy.roots; the root with B_i beyond C_i along e_i."""
    A = rotation(q[3:])
    out = []
    for r_b, e, c0 in zip(P.joints, P.axes, P.sliders_home):
        B = q[:3] + A @ r_b
        d = c0 - B
        roots = np.roots([1.0, 2 * d @ e, d @ d - P.c**2]).real
        out.append(min(roots))  # B - C has a positive component along e: the smaller t
    return np.array(out)


poses_st = st.tuples(*[st.floats(-0.06, 0.06)] * 3, *[st.floats(-0.15, 0.15)] * 3).map(np.array)


@settings(max_examples=60, deadline=None)
@given(poses_st)
def test_ik_matches_thesis_closed_form_and_sphere_line_intersection(q):
    L = inverse_kinematics(q, check=False)
    assume(np.isfinite(L).all())
    np.testing.assert_allclose(L, _thesis_ik(q), atol=1e-13)
    np.testing.assert_allclose(L, _sphere_line_ik(q), atol=1e-10)


def test_ik_vectorised_matches_single():
    rng = np.random.default_rng(1)
    q = rng.uniform(-1, 1, (200, 6)) * [0.04, 0.04, 0.04, 0.1, 0.1, 0.1]
    L = inverse_kinematics(q)
    assert L.shape == (200, 6)
    np.testing.assert_allclose(L[17], inverse_kinematics(q[17]), atol=0)


@settings(max_examples=100, deadline=None)
@given(poses_st)
def test_ik_fk_round_trip_1e_10(q):
    assume(workspace_check(q).inside[0])
    res = forward_kinematics(inverse_kinematics(q))
    assert res.converged.all()
    np.testing.assert_allclose(res.poses[0], q, atol=1e-10)


def test_jacobian_matches_finite_differences():
    q = np.array([0.01, -0.02, 0.015, 0.08, -0.05, 0.1])
    J = actuator_jacobian(q)
    eps = 1e-6
    Jn = np.column_stack([(inverse_kinematics(q + eps * d) - inverse_kinematics(q - eps * d)) / (2 * eps)
                          for d in np.eye(6)])
    np.testing.assert_allclose(J, Jn, atol=1e-8)


def test_fk_outside_workspace_raises_with_residual():
    with pytest.raises(OutsideWorkspaceError, match="strokes outside the limits"):
        forward_kinematics(np.array([0.5, 0, 0, 0, 0, 0]))
    res = forward_kinematics(np.array([0.5, 0, 0, 0, 0, 0]), raise_on_failure=False)
    assert not res.converged[0]


def test_ik_out_of_reach_raises():
    with pytest.raises(OutsideWorkspaceError, match="out of the rods' reach"):
        inverse_kinematics(np.array([0, 0.5, 0, 0, 0, 0]))


def test_workspace_clamp_and_singularity_flags():
    far = np.array([0.0, 0.4, 0.3, 0, 0, 0])
    inside, clamped = clamp_to_workspace(far)
    assert clamped and workspace_check(inside).inside[0]
    assert np.allclose(inside / np.linalg.norm(inside), far / np.linalg.norm(far))
    betas = np.linspace(0, np.pi / 2, 50)
    poses = np.zeros((50, 6))
    poses[:, 4] = betas
    flags = near_singular(poses)
    assert not flags[0] and flags[-1]
    # flagged well before cos(beta) vanishes
    assert betas[np.argmax(flags)] < np.deg2rad(80)
