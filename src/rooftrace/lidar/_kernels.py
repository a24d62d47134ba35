"""Compiled kernels of the detection stages (numba).

Each replaces a sort or a Python loop over points by one pass, with the
same result to the bit (ties are broken as the numpy code they replace
breaks them).
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["dense_unique", "lowest_per_group", "lowest_point_per_group", "pair_pull", "rotate_to_smallest"]


@njit(cache=True)
def lowest_point_per_group(xyz: np.ndarray, rows: np.ndarray, group: np.ndarray, n_groups: int) -> np.ndarray:  # pragma: no cover
    """Row of the lexicographically smallest (x, y, z) point of each group.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), float64
        Points (m).
    rows : ndarray of shape (M,), int64
        The points taking part (indices into ``xyz``).
    group : ndarray of shape (M,), int64
        Group (0..G-1) of each of them.
    n_groups : int
        G; every group has a point.

    Returns
    -------
    ndarray of shape (G,), int64
        Position in ``rows`` of each group's smallest point; of equal points
        the first, as a stable ``np.lexsort((z, y, x))`` gives.
    """
    first = np.full(n_groups, -1, np.int64)
    for m in range(len(rows)):
        g = group[m]
        b = first[g]
        if b < 0:
            first[g] = m
            continue
        p, q = rows[m], rows[b]
        if xyz[p, 0] < xyz[q, 0] or (xyz[p, 0] == xyz[q, 0] and (
                xyz[p, 1] < xyz[q, 1] or (xyz[p, 1] == xyz[q, 1] and xyz[p, 2] < xyz[q, 2]))):
            first[g] = m
    return first


@njit(cache=True)
def lowest_per_group(z: np.ndarray, group: np.ndarray, n_groups: int) -> np.ndarray:  # pragma: no cover
    """Index of the lowest ``z`` of each group (0..G-1, each non-empty); of equal heights the first.

    The same as the first of each group after ``np.lexsort((arange, z, group))``.
    """
    best = np.full(n_groups, -1, np.int64)
    for i in range(len(z)):
        g = group[i]
        if best[g] < 0 or z[i] < z[best[g]]:
            best[g] = i
    return best


def dense_unique(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(values, return_inverse=True)`` of integers, by counting when they are dense.

    Parameters
    ----------
    values : ndarray of shape (N,), int
        N >= 1.

    Returns
    -------
    uniq : ndarray of shape (U,)
        The distinct values, ascending (``values.dtype``).
    inverse : ndarray of shape (N,), int64
        Position of each value in ``uniq``.
    """
    lo, hi = int(values.min()), int(values.max())
    if hi - lo > 4 * len(values) + 1024:
        uniq, inv = np.unique(values, return_inverse=True)
        return uniq, inv.ravel().astype(np.int64, copy=False)
    # a count over the range instead of a sort
    shifted = values - lo if lo else values
    present = np.bincount(shifted, minlength=hi - lo + 1) > 0
    uniq = np.flatnonzero(present)
    lookup = np.cumsum(present) - 1
    return (uniq + lo).astype(values.dtype, copy=False), lookup[shifted]


@njit(cache=True)
def rotate_to_smallest(tris: np.ndarray, nbrs: np.ndarray) -> tuple:  # pragma: no cover
    """Each triangle (and its neighbours with it) rotated to start at its smallest vertex, as int64.

    The same as ``tris[rows, (argmin(tris, 1)[:, None] + arange(3)) % 3]``
    (and ``nbrs`` likewise) in one pass.
    """
    n = tris.shape[0]
    t_out = np.empty((n, 3), np.int64)
    n_out = np.empty((n, 3), np.int64)
    for i in range(n):
        s = 0
        if tris[i, 1] < tris[i, s]:
            s = 1
        if tris[i, 2] < tris[i, s]:
            s = 2
        for j in range(3):
            c = (s + j) % 3
            t_out[i, j] = tris[i, c]
            n_out[i, j] = nbrs[i, c]
    return t_out, n_out


@njit(cache=True)
def pair_pull(xy: np.ndarray, labels: np.ndarray, pairs: np.ndarray) -> tuple:  # pragma: no cover
    """Neighbour count and summed offsets of each point over the ``pairs`` within one label.

    Returns ``count`` (N,) int64 and ``pull`` (N, 2) float64: for a pair
    (i, j), ``d = xy[j] - xy[i]`` is added to i and subtracted from j.  The
    sums run in pair order, as ``np.bincount(..., weights)`` adds, so the
    result is the same to the bit as the bincounts of the same pairs.
    """
    n = len(xy)
    count = np.zeros(n, np.int64)
    plus = np.zeros((n, 2))
    minus = np.zeros((n, 2))
    for p in range(len(pairs)):
        i, j = pairs[p, 0], pairs[p, 1]
        if labels[i] != labels[j]:
            continue
        count[i] += 1
        count[j] += 1
        for c in range(2):
            d = xy[j, c] - xy[i, c]
            plus[i, c] += d
            minus[j, c] += d
    return count, plus - minus
