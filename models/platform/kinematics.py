"""Kinematics of the PSS 3-2-1 platform: rotation, inverse and forward kinematics, Jacobian.

Pose ``q = (X_C, Y_C, Z_C, gamma, beta, alpha)`` (m, rad) as in eq. 6-48. The orientation is
``A = A_x(gamma) A_y(beta) A_z(alpha)`` (eq. 6-8/6-9). Everything here is vectorised over a
leading batch axis: a pose array of shape ``(N, 6)`` (or ``(6,)``) gives strokes ``(N, 6)``.

Inverse kinematics (eq. 6-13..6-19): with ``w_i = R_C + A r_Bi - C_i^0`` (``C_i^0`` the slider
point at zero stroke, eq. 6-6) and slider axis ``e_i``, the rod condition ``|B_i - C_i| = c``
gives ``dl_i = w_i . e_i - sqrt(c^2 - |w_i - (w_i . e_i) e_i|^2)``, which written out per
actuator is exactly eq. 6-14..6-19.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Callable

import numpy as np

from .params import PlatformParams

log = logging.getLogger(__name__)


class OutsideWorkspaceError(ValueError):
    """A pose or a stroke set is outside the platform's workspace (rod reach or stroke limit)."""


class SingularityError(ValueError):
    """The Euler-angle parametrisation is singular (cos beta = 0) or the actuator Jacobian is."""


def _batch(x: np.ndarray, n: int) -> tuple[np.ndarray, bool]:
    x = np.asarray(x, dtype=float)
    single = x.ndim == 1
    x = np.atleast_2d(x)
    if x.shape[-1] != n:
        raise ValueError(f"expected the last axis of length {n}, got shape {x.shape}")
    return x, single


def rotation(angles: np.ndarray) -> np.ndarray:
    """Rotation matrix A = A_x(gamma) A_y(beta) A_z(alpha), eq. 6-8/6-9.

    Parameters
    ----------
    angles : array (..., 3)
        (gamma, beta, alpha) in rad.

    Returns
    -------
    array (..., 3, 3)
        Maps platform-frame coordinates to base-frame coordinates.
    """
    angles = np.asarray(angles, float)
    g, b, a = angles[..., 0], angles[..., 1], angles[..., 2]
    cg, sg, cb, sb, ca, sa = np.cos(g), np.sin(g), np.cos(b), np.sin(b), np.cos(a), np.sin(a)
    A = np.empty(angles.shape[:-1] + (3, 3))
    A[..., 0, 0] = cb * ca
    A[..., 0, 1] = -cb * sa
    A[..., 0, 2] = sb
    A[..., 1, 0] = cg * sa + sg * sb * ca
    A[..., 1, 1] = cg * ca - sg * sb * sa
    A[..., 1, 2] = -sg * cb
    A[..., 2, 0] = sg * sa - cg * sb * ca
    A[..., 2, 1] = sg * ca + cg * sb * sa
    A[..., 2, 2] = cg * cb
    return A


def world_rate_matrix(angles: np.ndarray) -> np.ndarray:
    """E_w with Omega = E_w (gamma', beta', alpha'): angular velocity in OXYZ (thesis, after eq. 6-55).

    Returns array (..., 3, 3).
    """
    angles = np.asarray(angles, float)
    g, b = angles[..., 0], angles[..., 1]
    E = np.zeros(angles.shape[:-1] + (3, 3))
    E[..., 0, 0] = 1.0
    E[..., 0, 2] = np.sin(b)
    E[..., 1, 1] = np.cos(g)
    E[..., 1, 2] = -np.cos(b) * np.sin(g)
    E[..., 2, 1] = np.sin(g)
    E[..., 2, 2] = np.cos(b) * np.cos(g)
    return E


def body_rate_matrix(angles: np.ndarray) -> np.ndarray:
    """E_b with omega = E_b (gamma', beta', alpha'): body rates in Cxyz, eq. 6-11. Array (..., 3, 3)."""
    angles = np.asarray(angles, float)
    b, a = angles[..., 1], angles[..., 2]
    E = np.zeros(angles.shape[:-1] + (3, 3))
    E[..., 0, 0] = np.cos(b) * np.cos(a)
    E[..., 0, 1] = np.sin(a)
    E[..., 1, 0] = -np.cos(b) * np.sin(a)
    E[..., 1, 1] = np.cos(a)
    E[..., 2, 0] = np.sin(b)
    E[..., 2, 2] = 1.0
    return E


@dataclass
class IKResult:
    """Inverse kinematics of a batch of poses (all arrays have a leading batch axis N).

    Attributes
    ----------
    strokes : (N, 6) stroke dl_i, m (NaN where the rod cannot reach)
    rods : (N, 6, 3) rod vectors B_i - C_i in OXYZ, m
    joints : (N, 6, 3) ball joints B_i in OXYZ, m
    reach : (N, 6) (rod . slider axis) / c; 1 at home, 0 when the rod is perpendicular to its axis
    """

    strokes: np.ndarray
    rods: np.ndarray
    joints: np.ndarray
    reach: np.ndarray


def ik_full(poses: np.ndarray, p: PlatformParams = PlatformParams()) -> IKResult:
    """Closed-form inverse kinematics, eq. 6-14..6-19, with rod vectors and reach ratios.

    Never raises: where a rod cannot reach its slider axis the stroke is NaN and reach < 0.
    """
    q, _ = _batch(poses, 6)
    A = rotation(q[:, 3:])
    B = q[:, None, :3] + np.einsum("nij,kj->nki", A, p.joints)  # eq. 6-12
    w = B - p.sliders_home[None]
    we = np.einsum("nki,ki->nk", w, p.axes)
    perp2 = np.einsum("nki,nki->nk", w, w) - we * we
    s2 = p.c * p.c - perp2
    s = np.sqrt(np.where(s2 >= 0, s2, np.nan))
    strokes = we - s
    rods = w - strokes[..., None] * p.axes[None]
    reach = np.where(s2 >= 0, s, -np.sqrt(np.abs(s2))) / p.c
    return IKResult(strokes, rods, B, reach)


def inverse_kinematics(poses: np.ndarray, p: PlatformParams = PlatformParams(), check: bool = True) -> np.ndarray:
    """Strokes dl_1..dl_6 of poses, eq. 6-14..6-19.

    Parameters
    ----------
    poses : array (N, 6) or (6,)
        (X_C, Y_C, Z_C, gamma, beta, alpha), m and rad.
    p : PlatformParams
    check : bool
        Raise :class:`OutsideWorkspaceError` when a rod cannot reach (else NaN is returned there).

    Returns
    -------
    array (N, 6) or (6,)
        Strokes in m.
    """
    q, single = _batch(poses, 6)
    res = ik_full(q, p)
    if check:
        bad = np.flatnonzero(~np.isfinite(res.strokes).all(axis=1))
        if bad.size:
            i = int(bad[0])
            raise OutsideWorkspaceError(
                f"pose {i} = {np.array2string(q[i], precision=4)} is out of the rods' reach "
                f"(reach ratio {np.nanmin(res.reach[i]):.3g} < 0)")
    return res.strokes[0] if single else res.strokes


def actuator_jacobian(poses: np.ndarray, p: PlatformParams = PlatformParams()) -> np.ndarray:
    """Exact Jacobian d(dl)/dq of the strokes with respect to the pose, shape (N, 6, 6).

    With rod vector u_i = B_i - C_i, d(dl_i)/dB_i = u_i / (u_i . e_i) and
    dB_i/dq = [I, -[A r_i]_x E_w]; the row is ``[g_i, (A r_i x g_i) E_w]``,
    ``g_i = u_i / (u_i . e_i)``. Its transpose maps actuator forces to generalized forces
    (virtual work, eq. 6-51/6-55): ``Q = J^T F``.
    """
    q, single = _batch(poses, 6)
    res = ik_full(q, p)
    ue = np.einsum("nki,ki->nk", res.rods, p.axes)
    gvec = res.rods / ue[..., None]
    r_world = res.joints - q[:, None, :3]
    Ew = world_rate_matrix(q[:, 3:])
    J = np.empty(q.shape[:1] + (6, 6))
    J[..., :3] = gvec
    J[..., 3:] = np.einsum("nki,nij->nkj", np.cross(r_world, gvec), Ew)
    return J[0] if single else J


@dataclass
class WorkspaceReport:
    """Workspace check of a batch of poses: masks of shape (N,) and the strokes (N, 6)."""

    inside: np.ndarray
    reach_ok: np.ndarray
    stroke_ok: np.ndarray
    strokes: np.ndarray
    min_reach: np.ndarray


def within_limits(strokes: np.ndarray, reach: np.ndarray, p: PlatformParams = PlatformParams()):
    """Workspace criteria from strokes and reach ratios (..., 6): ``(reach_ok, stroke_ok)`` (...,).

    Reach: every (rod . slider axis) / c >= ``p.reach_margin``; strokes within the limits. NaN
    (rod out of reach) fails both.
    """
    reach_ok = reach.min(axis=-1) >= p.reach_margin  # NaN compares False (no warning)
    stroke_ok = ((strokes >= p.stroke_min) & (strokes <= p.stroke_max)).all(axis=-1)
    return reach_ok, stroke_ok


def workspace_check(poses: np.ndarray, p: PlatformParams = PlatformParams()) -> WorkspaceReport:
    """Check rod reach (reach ratio >= p.reach_margin) and stroke limits for poses (N, 6)."""
    q, _ = _batch(poses, 6)
    res = ik_full(q, p)
    reach_ok, stroke_ok = within_limits(res.strokes, res.reach, p)
    return WorkspaceReport(reach_ok & stroke_ok, reach_ok, stroke_ok, res.strokes, np.min(res.reach, axis=1))


def clamp_to_workspace(pose: np.ndarray, p: PlatformParams = PlatformParams(),
                       origin: np.ndarray | None = None, iters: int = 24,
                       inside: Callable[[np.ndarray], bool] | None = None) -> tuple[np.ndarray, bool]:
    """Pull ``pose`` (6,) back along the segment from ``origin`` (default home) into the workspace.

    Bisection on the segment parameter (the workspace is star-shaped about home in practice);
    ``inside(pose) -> bool`` may replace :func:`workspace_check` (e.g. a compiled IK).
    Returns ``(pose_inside, clamped)``.
    """
    if inside is None:
        def inside(x):
            return bool(workspace_check(x, p).inside[0])
    pose = np.asarray(pose, float)
    origin = np.zeros(6) if origin is None else np.asarray(origin, float)
    if inside(pose):
        return pose.copy(), False
    if not inside(origin):
        origin = np.zeros(6)
    lo, hi = 0.0, 1.0
    d = pose - origin
    for _ in range(iters):
        mid = 0.5 * (lo + hi)
        if inside(origin + mid * d):
            lo = mid
        else:
            hi = mid
    return origin + lo * d, True


def singular_flags(beta: np.ndarray, reach: np.ndarray, p: PlatformParams = PlatformParams(),
                   cos_beta_min: float = 0.17, reach_min: float | None = None) -> np.ndarray:
    """Near-singular criteria from beta (...,) and reach ratios (..., 6): boolean (...,).

    |cos beta| < cos_beta_min (Euler singularity at beta = +-90 deg, default about 80 deg) or some
    rod within ``reach_min`` (default 2 x reach_margin) of perpendicular to its slider (actuator
    Jacobian singular), NaN reach included.
    """
    reach_min = 2.0 * p.reach_margin if reach_min is None else reach_min
    rod_bad = ~(reach.min(axis=-1) >= reach_min)
    return (np.abs(np.cos(beta)) < cos_beta_min) | rod_bad


def near_singular(poses: np.ndarray, p: PlatformParams = PlatformParams(), cos_beta_min: float = 0.17,
                  reach_min: float | None = None) -> np.ndarray:
    """Boolean (N,): :func:`singular_flags` of poses (N, 6)."""
    q, _ = _batch(poses, 6)
    return singular_flags(q[:, 4], ik_full(q, p).reach, p, cos_beta_min, reach_min)


@dataclass
class FKResult:
    """Forward kinematics result for a batch (N, ...)."""

    poses: np.ndarray
    residual: np.ndarray
    iterations: int
    converged: np.ndarray


def forward_kinematics(strokes: np.ndarray, p: PlatformParams = PlatformParams(), guess: np.ndarray | None = None,
                       tol: float = 1e-13, max_iter: int = 30, raise_on_failure: bool = True) -> FKResult:
    """Pose from strokes by Newton iteration with the exact Jacobian :func:`actuator_jacobian`.

    Parameters
    ----------
    strokes : array (N, 6) or (6,), m
    guess : array like ``strokes``, optional
        Starting poses (default home).
    tol : float
        Convergence on max |IK(q) - strokes| in m.
    raise_on_failure : bool
        Raise :class:`OutsideWorkspaceError` (with the residual) when a stroke set is outside the
        stroke limits or Newton does not converge; else report it in ``converged``.
    """
    L, _ = _batch(strokes, 6)
    q = np.zeros_like(L) if guess is None else np.array(np.broadcast_to(np.atleast_2d(guess), L.shape), float)
    out_of_limits = ~np.all((L >= p.stroke_min) & (L <= p.stroke_max), axis=1)
    residual = np.full(L.shape[0], np.inf)
    it = 0
    for it in range(1, max_iter + 1):
        res = ik_full(q, p)
        r = res.strokes - L
        residual = np.max(np.abs(r), axis=1)
        residual = np.where(np.isfinite(residual), residual, np.inf)
        if np.all(residual < tol):
            break
        J = actuator_jacobian(q, p)
        ok = np.isfinite(r).all(axis=1) & np.isfinite(J).all(axis=(1, 2))
        step = np.zeros_like(q)
        if ok.any():
            try:
                step[ok] = np.linalg.solve(J[ok], r[ok][..., None])[..., 0]
            except np.linalg.LinAlgError:
                step[ok] = np.einsum("nij,nj->ni", np.linalg.pinv(J[ok]), r[ok])
        step[~ok] = 0.5 * q[~ok]  # rod lost: back off towards home
        q = q - step
    converged = (residual < max(tol, 1e-10)) & ~out_of_limits
    if raise_on_failure and not converged.all():
        i = int(np.flatnonzero(~converged)[0])
        why = "strokes outside the limits" if out_of_limits[i] else "Newton did not converge"
        raise OutsideWorkspaceError(
            f"forward kinematics of strokes {i} = {np.array2string(L[i], precision=4)} m failed: {why} "
            f"(residual {residual[i]:.3g} m after {it} iterations)")
    return FKResult(q, residual, it, converged)
