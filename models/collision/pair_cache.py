"""Bounds of a pair's distance from its last exact distance and the motion since.

The distance of two rigid bodies changes by at most the sum of the largest displacements of
their surface points; a body's points move by at most ``|t1 - t0| + ||R1 - R0||_F r`` from
transform 0 to 1 (``r`` its radius about the body origin, :func:`.poses.face_shift`). A pure
speed-up cache: a member is skipped only when it cannot beat the best distance so far, so
results are the same with or without it (it is not part of the FMU state).
"""
from __future__ import annotations

import math
from typing import Dict, Optional, Tuple

from .poses import Poses, face_shift

__all__ = ["PairDistances"]


class PairDistances:
    """Per ordered pair (a, b): at its last exact distance a lower bound of it, both bodies'
    transforms (rows) and an upper bound (inf unless that distance was found)."""

    #: m; added to an upper bound from an earlier distance plus the motion since (rounding)
    UPPER_MARGIN = 1e-9

    def __init__(self, frames: Poses, radius: list) -> None:
        self._frames, self._radius = frames, radius
        self._last: Dict[Tuple[int, int], tuple] = {}

    def store(self, a: int, b: int, lower: float, upper: float) -> None:
        rows = self._frames.rows  # (rows are replaced on a move, never modified)
        self._last[(a, b)] = (lower, rows[a], rows[b], upper)

    def since(self, a: int, b: int) -> Optional[Tuple[float, float]]:
        """``(lower - mu, upper + mu + UPPER_MARGIN)`` (m), ``mu`` the motion bound since the
        last exact distance of (a, b); None before the first."""
        last = self._last.get((a, b))
        if last is None:
            return None
        d, A0, B0, up = last
        mu = self.motion(a, b, A0, B0)
        return d - mu, up + mu + self.UPPER_MARGIN

    def bound(self, a: int, b: int) -> float:
        """Lower bound (m) of the distance of ``a`` and ``b`` (-inf before the first)."""
        since = self.since(a, b)
        return -math.inf if since is None else since[0]

    def motion(self, a: int, b: int, A0: list, B0: list) -> float:
        """Bound (m) on the travel of any surface point of ``a`` and ``b`` from ``A0``, ``B0``
        (rows) to their current transforms."""
        mu = 0.0
        rows, radius = self._frames.rows, self._radius
        for X0, i in ((A0, a), (B0, b)):
            X1 = rows[i]
            if X1 is X0:
                continue  # not moved since
            t, f = face_shift(X0, X1)
            if t or f:
                mu += t + f * radius[i]
        return mu
