"""Compiled loops of :func:`rooftrace.roof.faces.partition_outline`: the plane each raster cell takes.

A cell whose k nearest labelled points disagree takes the candidate with
the fewest violations of the intersection lines near it, then (with
``vote``) the most votes, then the nearest.  In numpy this went through
(cells, k, k) arrays of candidate pairs, a third of the face partition on
Delft; here one pass per cell does the integer bookkeeping.  The float
work (distances of cells to lines, plane heights) stays in numpy, in
:mod:`~rooftrace.roof.faces`.

The kernels of :mod:`rooftrace.roof.faces`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["cell_lines", "cell_choice"]


@njit(cache=True)
def cell_lines(cand, segidx):  # pragma: no cover - compiled
    """Lines between the distinct candidate planes of each cell.

    Returns ``ptr`` (R+1,) and ``line`` (P,): the lines of cell r are
    ``line[ptr[r]:ptr[r+1]]`` (each once; ``segidx`` is symmetric with -1 on
    the diagonal, one line per plane pair).
    """
    n, k = cand.shape
    ptr = np.zeros(n + 1, dtype=np.int64)
    out = np.empty(16, dtype=np.int64)
    distinct = np.empty(k, dtype=np.int64)
    m = 0
    for r in range(n):
        nd = 0
        for i in range(k):
            new = True
            for a in range(nd):
                if distinct[a] == cand[r, i]:
                    new = False
                    break
            if new:
                distinct[nd] = cand[r, i]
                nd += 1
        for a in range(nd):
            for b in range(a + 1, nd):
                s = segidx[distinct[a], distinct[b]]
                if s >= 0:
                    if m == len(out):
                        bigger = np.empty(2 * len(out), dtype=np.int64)
                        bigger[:m] = out[:m]
                        out = bigger
                    out[m] = s
                    m += 1
        ptr[r + 1] = m
    return ptr, out[:m].copy()


@njit(cache=True)
def _n_lines(segidx):  # pragma: no cover - compiled
    return max(segidx.max() + 1, 1)


@njit(cache=True)
def cell_choice(cand, segidx, ptr, line, near, sign, z, vote=True):  # pragma: no cover - compiled
    """Index (0..k-1) of the candidate each cell takes.

    Score, lowest wins (first on ties): violations x (k+1)² - votes x (k+1)
    + rank (without ``vote``: violations x (k+1)² + rank), where a violation
    is a candidate pair across a line within the tolerance (``near`` per
    entry of ``line``) whose heights ``z`` (R, k) disagree with the line's
    convexity (``sign``: the lower plane across a convex line, the higher
    across a concave one).
    """
    n, k = cand.shape
    pos = np.full(_n_lines(segidx), -1, dtype=np.int64)
    choice = np.empty(n, dtype=np.int64)
    for r in range(n):
        for p in range(ptr[r], ptr[r + 1]):
            pos[line[p]] = p
        best, best_j = 0, 0
        for i in range(k):
            votes = 0
            viol = 0
            for j in range(k):
                if cand[r, j] == cand[r, i]:
                    votes += 1
                    continue  # one plane: same height, never a violation
                s = segidx[cand[r, i], cand[r, j]]
                if s >= 0 and near[pos[s]] and ((sign[s] > 0 and z[r, i] > z[r, j])
                                                 or (sign[s] < 0 and z[r, i] < z[r, j])):
                    viol += 1
            score = viol * (k + 1) * (k + 1) - (votes * (k + 1) if vote else 0) + i
            if i == 0 or score < best:
                best, best_j = score, i
        choice[r] = best_j
    return choice
