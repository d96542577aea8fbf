"""Small array helpers of the network model."""
from __future__ import annotations

import numpy as np


def _run_starts(s: np.ndarray) -> np.ndarray:
    """Mask (n,) of the first element of each run of equal values in the sorted, non-empty ``s``."""
    new = np.empty(len(s), bool)
    new[0] = True
    np.not_equal(s[1:], s[:-1], out=new[1:])
    return new


def sorted_unique(a: np.ndarray):
    """``np.unique(a, return_index=True, return_inverse=True)`` for int arrays, by a stable sort.

    The same three results (sorted unique values, index of each value's first occurrence,
    inverse indices), from a stable (timsort) argsort, which is cheap on the nearly sorted keys
    the model passes (``np.unique`` sorts them from scratch).
    """
    n = len(a)
    if n == 0:
        return a[:0], np.zeros(0, np.int64), np.zeros(0, np.int64)
    perm = np.argsort(a, kind="stable")
    s = a[perm]
    new = _run_starts(s)
    inv = np.empty(n, np.int64)
    inv[perm] = np.cumsum(new) - 1
    return s[new], perm[new], inv


def unique_values(a: np.ndarray) -> np.ndarray:
    """``np.unique(a)`` for int arrays: sorted unique values, by a stable sort."""
    if len(a) == 0:
        return a[:0]
    s = np.sort(a, kind="stable")
    return s[_run_starts(s)]


def sum_by_key(keys: np.ndarray, w: np.ndarray):
    """Unique ``keys`` (sorted), the index of each one's first occurrence, and the sum of the
    weights ``w`` per key (``np.unique`` + ``np.bincount`` without the inverse indices)."""
    if len(keys) == 0:
        return keys[:0], np.zeros(0, np.int64), w[:0]
    perm = np.argsort(keys, kind="stable")
    s = keys[perm]
    starts = np.flatnonzero(_run_starts(s))
    return s[starts], perm[starts], np.add.reduceat(w[perm], starts)


def concat_ranges(lo: np.ndarray, n: np.ndarray) -> np.ndarray:
    """``lo[0] .. lo[0] + n[0] - 1, lo[1] .. lo[1] + n[1] - 1, ...`` as one int array."""
    return np.arange(int(n.sum())) + np.repeat(lo - (np.cumsum(n) - n), n)


PAIRWISE_BLOCK = 128   # numpy's PW_BLOCKSIZE


def pairwise_sum(a: list) -> float:
    """``float(np.add.reduce(np.array(a)))`` of a list of floats, in Python: numpy's pairwise
    summation (eight running sums over blocks of at most ``PAIRWISE_BLOCK`` values, combined
    as ``((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))``, then the rest in order; halves
    at multiples of 8 above the block size), the same additions in the same order."""
    n = len(a)
    if n < 8:
        res = 0.0
        for x in a:
            res += x
        return res
    if n <= PAIRWISE_BLOCK:
        r0, r1, r2, r3, r4, r5, r6, r7 = a[:8]
        m = n - n % 8
        for i in range(8, m, 8):
            r0 += a[i]
            r1 += a[i + 1]
            r2 += a[i + 2]
            r3 += a[i + 3]
            r4 += a[i + 4]
            r5 += a[i + 5]
            r6 += a[i + 6]
            r7 += a[i + 7]
        res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
        for i in range(m, n):
            res += a[i]
        return res
    h = n // 2
    h -= h % 8
    return pairwise_sum(a[:h]) + pairwise_sum(a[h:])
