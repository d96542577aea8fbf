"""The far-pair skip: a pair whose members were all at least ``max_distance`` away keeps its
far result without any work while their AABB gaps cannot have closed to ``max_distance``.

Each face of a body's world AABB moves by at most ``t + f rmax`` in a move (``(t, f)`` =
:func:`.poses.face_shift`, ``rmax`` the largest hull-vertex distance from the body origin);
an axis separation of two boxes by at most the sum over both, the Euclidean gap by at most
``sqrt(3)`` times that. Per body the running sum of these bounds is kept; a pair's record is
(smallest member gap, that sum over its bodies) at its last full evaluation.
"""
from __future__ import annotations

import math
from typing import List, Optional, Tuple

import numpy as np

__all__ = ["FarSkip"]

_SQRT3 = math.sqrt(3.0)


class FarSkip:
    """Records and test of the far-pair skip (module docstring).

    Parameters
    ----------
    local : dict
        Per mesh key ``(hull vertices, centre, radius)`` (:func:`.bounds.local_shapes`).
    keys : list of str
        Per body its mesh key.
    pair_bodies : list of list of int
        Per pair its dynamic bodies.
    max_distance, margin : float
        m; a far pair's member gaps are at least ``max_distance`` when recorded and ``limit =
        max_distance + margin`` when the record is kept (the margin covers AABB rounding).
    on : bool
        The skip is used.
    """

    def __init__(self, local, keys, pair_bodies, max_distance: float, margin: float, on: bool) -> None:
        self.on, self.max_distance, self.limit = on, max_distance, max_distance + margin
        self._rmax = [float(np.linalg.norm(local[k][0], axis=1).max()) if len(local[k][0]) else 0.0 for k in keys]
        self._shift = [0.0] * len(keys)
        self._pair_bodies = pair_bodies
        self.records: List[Optional[Tuple[float, float]]] = [None] * len(pair_bodies)

    def moved(self, bodies, motion) -> None:
        """Add the face-shift bounds of this query's moves (``motion[i] = (t, f)``)."""
        shift, rmax = self._shift, self._rmax
        for i in bodies:
            t, f = motion[i]
            shift[i] += t + f * rmax[i]

    def record(self, k: int, gap: Optional[float], plain_far: bool) -> None:
        """After a full evaluation of pair ``k``: keep (gap, shift sum) when its result is the
        plain far one (``plain_far``: no contact, partner, time of impact or candidate) and its
        smallest member gap ``gap`` is at least ``max_distance``, else forget the pair."""
        if gap is None or not plain_far or not gap >= self.max_distance:
            self.records[k] = None
            return
        shift = self._shift
        self.records[k] = (float(gap), sum(shift[i] for i in self._pair_bodies[k]))

    def closing(self, k: int) -> Tuple[bool, float]:
        """Whether pair ``k``'s gap may have closed to the limit since its record (by the face
        shifts), and the current shift sum of its bodies."""
        gap, shift0 = self.records[k]
        now = sum(map(self._shift.__getitem__, self._pair_bodies[k]))
        return gap - _SQRT3 * (now - shift0) < self.limit, now

    def confirm(self, k: int, exact: Optional[float], now: float) -> bool:
        """The exact gap ``exact`` (m, None: unknown) of pair ``k`` is still at least the limit:
        it becomes the record."""
        if exact is None or not exact >= self.limit:
            return False
        self.records[k] = (exact, now)
        return True

    def reset(self) -> None:
        self.records = [None] * len(self.records)
