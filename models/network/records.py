"""The receivers' record cache: one row of floats per (object, viewer group) (§3.6.3).

Flat index ``object * G + viewer`` (object-major: a frame's pairs are sorted by object, so
gathers and scatters walk memory forward). Row: record time t (s), position p (2, m), velocity
v (2, m/s, orders >= 1), acceleration a (2, m/s^2, order 2), the record's id (``rid_col``: records
with the same id have the same content) and the time the pair last entered the viewer's
neighbourhood (``enter_col``, subscription). One 64-byte row per pair (128 for order 2): the
display error of a pair reads one cache line.
"""
from __future__ import annotations

from typing import Dict, Optional

import numpy as np

RID_OBJECT = float(2 ** 32)  # record id = object * 2^32 + record-table id (sorted by object, then table)
T_COL = 0                    # cache row: record time, then p, v, a as the prediction order uses them


def aligned_rows(n: int, w: int) -> np.ndarray:
    """Zeroed C-contiguous (n, w) float64 array whose rows start on 64-byte boundaries."""
    buf = np.zeros(n * w + 8)
    off = (-buf.ctypes.data % 64) // 8
    return buf[off:off + n * w].reshape(n, w)


_PREFIX_DTYPES: Dict[int, np.dtype] = {}


def row_prefix(a: np.ndarray, ncol: int) -> np.ndarray:
    """The first ``ncol`` floats of every row of the C-contiguous (n, w) array ``a`` as one
    ``ncol * 8``-byte opaque item per row (a view: whole-record gathers and scatters)."""
    dt = _PREFIX_DTYPES.get(ncol)
    if dt is None:
        dt = _PREFIX_DTYPES[ncol] = np.dtype((np.void, 8 * ncol))
    return np.ndarray((a.shape[0],), dt, a, 0, (a.strides[0],))


class _Views:
    """Views into the cache kept between frames. A copy (``deepcopy``, pickle) starts empty: a
    copied view would be an array of its own, no longer a view of the copied array.

    Attributes
    ----------
    cache_rows : (cache, the record-prefix view of its rows, :func:`row_prefix`) or None
    """

    def __init__(self) -> None:
        self.cache_rows: Optional[tuple] = None

    def __deepcopy__(self, memo) -> "_Views":
        return _Views()

    def __reduce__(self):
        return _Views, ()


class RecordCache:
    """Records held by every viewer group, and the record tables written into them.

    Parameters
    ----------
    groups, n_obj : int, viewer groups G and objects (avatars first)
    order : int, prediction order (0-2): the record columns kept

    Attributes
    ----------
    cache : (n_obj * G, 8 or 16) rows as in the module docstring
    ncol, rid_col, enter_col : int, record columns, record-id column, subscription-time column
    uid : int, the next record-table id (0: the scene file)
    newest : float, s, newest record time written so far
    """

    def __init__(self, groups: int, n_obj: int, order: int) -> None:
        self.groups = groups
        self.ncol = 1 + 2 * (1 + min(order, 2))
        self.rid_col = self.ncol
        width = 8 if self.ncol + 2 <= 8 else 16
        self.enter_col = width - 1
        self.cache = aligned_rows(groups * n_obj, width)
        self.cache[:, T_COL] = -np.inf
        self.views = _Views()     # views into the cache, not part of the state
        self.obj_ids = np.arange(n_obj)
        self.obj_rid = self.obj_ids * RID_OBJECT
        self.uid = 1
        self.newest = -np.inf

    def index(self, viewer, obj):
        """Flat cache index of (viewer group, object)."""
        return np.asarray(obj) * self.groups + np.asarray(viewer)

    def table(self, objs: np.ndarray, t, P: np.ndarray, V: np.ndarray, A: np.ndarray) -> np.ndarray:
        """A new record table (len(objs), cache width): rows ``t, p, v, a`` (the columns the
        prediction order uses) of objects ``objs`` and their record ids under a fresh table id."""
        tab = np.empty((len(objs), self.cache.shape[1]))
        tab[:, T_COL] = t
        tab[:, 1:3] = P
        if self.ncol >= 5:
            tab[:, 3:5] = V
        if self.ncol >= 7:
            tab[:, 5:7] = A
        if objs is self.obj_ids:   # a frame's table: every object, ids object * 2^32 kept
            np.add(self.obj_rid, self.uid, out=tab[:, self.rid_col])
        else:
            tab[:, self.rid_col] = objs * RID_OBJECT + self.uid     # exact in float64 (< 2^53)
        self.uid += 1
        return tab

    def scatter(self, fi: np.ndarray, table: np.ndarray, ridx: np.ndarray) -> None:
        """Write records ``table[ridx]`` into the cache rows ``fi`` (the columns the prediction
        order uses and the record id, as one block per row; the subscription time is left alone)."""
        n = self.rid_col + 1
        view = self.views.cache_rows
        if view is None or view[0] is not self.cache:
            view = self.views.cache_rows = (self.cache, row_prefix(self.cache, n))
        view[1][fi] = row_prefix(table, n)[ridx]

    def record(self, viewer: int, obj: int) -> np.ndarray:
        """Cached record (7,) of ``obj`` at group ``viewer``: t (s), p (2, m), v (2, m/s), a (2, m/s^2)."""
        out = np.zeros(7)
        out[:self.ncol] = self.cache[int(self.index(viewer, obj)), :self.ncol]
        return out
