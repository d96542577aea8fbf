"""Small array helpers of the network model."""
from __future__ import annotations

import numpy as np


def sorted_unique(a: np.ndarray):
    """``np.unique(a, return_index=True, return_inverse=True)`` for int arrays, by a stable sort.

    The same three results (sorted unique values, index of each value's first occurrence,
    inverse indices); numpy 2.4's ``np.unique`` takes ~100 ms for 235,000 int64 values here,
    a stable (timsort) argsort of nearly sorted keys ~3 ms.
    """
    n = len(a)
    if n == 0:
        return a[:0], np.zeros(0, np.int64), np.zeros(0, np.int64)
    perm = np.argsort(a, kind="stable")
    s = a[perm]
    new = np.empty(n, bool)
    new[0] = True
    np.not_equal(s[1:], s[:-1], out=new[1:])
    inv = np.empty(n, np.int64)
    inv[perm] = np.cumsum(new) - 1
    return s[new], perm[new], inv


def unique_values(a: np.ndarray) -> np.ndarray:
    """``np.unique(a)`` for int arrays: sorted unique values, by a stable sort."""
    if len(a) == 0:
        return a[:0]
    s = np.sort(a, kind="stable")
    keep = np.empty(len(s), bool)
    keep[0] = True
    np.not_equal(s[1:], s[:-1], out=keep[1:])
    return s[keep]


def sum_by_key(keys: np.ndarray, w: np.ndarray):
    """Unique ``keys`` (sorted), the index of each one's first occurrence, and the sum of the
    weights ``w`` per key (``np.unique`` + ``np.bincount`` without the inverse indices)."""
    if len(keys) == 0:
        return keys[:0], np.zeros(0, np.int64), w[:0]
    perm = np.argsort(keys, kind="stable")
    s = keys[perm]
    new = np.empty(len(s), bool)
    new[0] = True
    np.not_equal(s[1:], s[:-1], out=new[1:])
    starts = np.flatnonzero(new)
    return s[starts], perm[starts], np.add.reduceat(w[perm], starts)
