"""Connected components of an undirected graph given by its edges.

Written here instead of calling ``scipy.sparse.csgraph.connected_components``
because the callers label many small graphs (the plane segmentation: one per
region level, RANSAC candidate and merge round) where building the sparse
matrix costs more than the search, and large ones (region growing of a
tile's points) where a union-find is as fast.  The labels are scipy's, so
either can stand for the other.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["components"]


def components(n: int, pairs: np.ndarray) -> np.ndarray:
    """Connected component (0..C-1) of each of ``n`` nodes linked by ``pairs``.

    Parameters
    ----------
    n : int
        Nodes.
    pairs : ndarray of shape (P, 2), int
        Edges, either direction.

    Returns
    -------
    ndarray of shape (n,), int32
        The labels of ``scipy.sparse.csgraph.connected_components(..., directed=False)``:
        components numbered in the order of their smallest node.

    Examples
    --------
    >>> components(5, np.array([[3, 1], [4, 0]])).tolist()
    [0, 1, 2, 1, 0]
    """
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    return _union_find(int(n), np.ascontiguousarray(pairs[:, 0]), np.ascontiguousarray(pairs[:, 1]))


@njit(cache=True)
def _find(parent, v):  # pragma: no cover - compiled
    while parent[v] != v:
        parent[v] = parent[parent[v]]
        v = parent[v]
    return v


@njit(cache=True)
def _union_find(n, i, j):  # pragma: no cover - compiled
    # the smaller root wins, so a root is its component's smallest node
    parent = np.arange(n)
    for e in range(len(i)):
        a, b = _find(parent, i[e]), _find(parent, j[e])
        if a < b:
            parent[b] = a
        elif b < a:
            parent[a] = b
    labels = np.empty(n, dtype=np.int32)
    nxt = 0
    for v in range(n):
        r = _find(parent, v)
        if r == v:
            labels[v] = nxt
            nxt += 1
        else:
            labels[v] = labels[r]
    return labels
