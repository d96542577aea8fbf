"""Contact response of two bodies along a contact normal: impulse and separation.

Both act along the unit normal ``n`` (pointing from body 2 to body 1, body 1's separation
direction), with inverse masses ``w = 1 / m`` (``m = inf``: a static body, ``w = 0``):

* impulse (Newton's restitution law, momentum conserved): with the approach speed
  ``u = (v1 - v2) . n < 0``, ``j = -(1 + e) u / (w1 + w2)``, ``dv1 = j w1 n``,
  ``dv2 = -j w2 n``; after it ``(v1' - v2') . n = -e u``. Kinetic energy changes by
  ``(e^2 - 1) u^2 / (2 (w1 + w2))``: never a gain for ``0 <= e <= 1``. Not approaching
  (``u >= 0``): no impulse.
* separation (position correction, removes the penetration ``depth``): ``dx1 = depth w1 /
  (w1 + w2) n``, ``dx2 = -depth w2 / (w1 + w2) n``; the centre of mass stays where it was, a
  static body takes none of it.

The position correction is not felt: a collision jolt is the velocity change ``|dv1|`` only.
"""
from __future__ import annotations

import numpy as np

__all__ = ["inverse_mass", "impulse", "separation"]


def inverse_mass(m) -> np.ndarray:
    """``1 / m`` (1/kg) elementwise, 0 for an infinite (static) mass."""
    m = np.asarray(m, float)
    return np.where(np.isinf(m), 0.0, 1.0 / m)


def impulse(w1, w2, v1, v2, n, e: float):
    """Velocity changes ``dv1, dv2`` (k, 2) m/s of a restitution-``e`` contact (module docstring).

    Parameters
    ----------
    w1, w2 : array_like, shape (k,)
        Inverse masses (1/kg); ``w1 + w2 > 0``.
    v1, v2 : array_like, shape (k, 2)
        Velocities (m/s).
    n : array_like, shape (k, 2)
        Unit normals from body 2 to body 1.
    e : float
        Coefficient of restitution in [0, 1].
    """
    w1, w2 = np.asarray(w1, float), np.asarray(w2, float)
    n = np.asarray(n, float)
    u = np.einsum("ij,ij->i", np.asarray(v1, float) - np.asarray(v2, float), n)
    j = np.where(u < 0.0, -(1.0 + e) * u / (w1 + w2), 0.0)
    return (j * w1)[:, None] * n, -(j * w2)[:, None] * n


def separation(w1, w2, n, depth):
    """Position corrections ``dx1, dx2`` (k, 2) m that remove a penetration ``depth`` (k,) m
    along the unit normals ``n`` (k, 2) (from body 2 to body 1), split by inverse mass."""
    w1, w2 = np.asarray(w1, float), np.asarray(w2, float)
    s = np.maximum(np.asarray(depth, float), 0.0) / (w1 + w2)
    n = np.asarray(n, float)
    return (s * w1)[:, None] * n, -(s * w2)[:, None] * n
