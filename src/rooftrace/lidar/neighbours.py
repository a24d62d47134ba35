"""Exact k nearest neighbours of points among themselves, on a plan grid: :class:`GridKnn`.

The neighbours, and their order, of ``cKDTree(xyz).query(xyz, k)``,
about twice as fast on airborne points (which lie in plan rather than in
3D); the rows whose order a tie of distances leaves to the tree's
traversal are flagged for the tree.  Used by the detection's eigen
features and by the roof plane segmentation.
"""

from __future__ import annotations

import numba
import numpy as np
from numba import njit

from rooftrace.lidar._kernels import cell_gap2, column_max, column_min, dense_cells

__all__ = ["GridKnn", "insert_sorted"]

# cKDTree.query spends most of a k = 60 query in its heap of neighbours.
# Here the points sit in plan cells, sorted by height within a cell; a query
# visits the rings of cells around its own until the ring is farther than
# its (k+1)-th neighbour, and skips the part of a cell out of reach in z.
# The rows are visited cell by cell, so the previous row's (k+1)-th distance
# bounds the candidates worth sorting, and a counting sort on the distance
# orders them.  The k + 1 nearest distances decide the neighbours and their
# order uniquely unless two of them tie; such rows are flagged for the
# KD-tree (its tie order follows its traversal; about 1 row in 5000), and
# their order here is not the tree's.

#: two squared distances closer than this (relative) count as a tie
_TIE = 1e-12


@njit(cache=True)
def _knn_build(xyz, x0, y0, side, nx, ny):  # pragma: no cover - compiled
    """Cell of each point and the points sorted by (cell, z): (cell, start, perm, X, Y, Z)."""
    n = xyz.shape[0]
    cell = np.empty(n, np.int64)
    for i in range(n):
        ix = min(max(int(np.floor((xyz[i, 0] - x0) / side)), 0), nx - 1)
        iy = min(max(int(np.floor((xyz[i, 1] - y0) / side)), 0), ny - 1)
        cell[i] = ix * ny + iy
    by_z = np.argsort(xyz[:, 2], kind="mergesort")
    start = np.zeros(nx * ny + 1, np.int64)
    for i in range(n):
        start[cell[i] + 1] += 1
    for c in range(nx * ny):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    perm = np.empty(n, np.int64)
    for t in range(n):
        i = by_z[t]
        perm[fill[cell[i]]] = i
        fill[cell[i]] += 1
    xs, ys, zs = np.empty(n), np.empty(n), np.empty(n)
    for s in range(n):
        xs[s] = xyz[perm[s], 0]
        ys[s] = xyz[perm[s], 1]
        zs[s] = xyz[perm[s], 2]
    return cell, start, perm, xs, ys, zs


@njit(cache=True, inline="always")
def insert_sorted(bd, bi, p, d, index):  # pragma: no cover - compiled
    """Put distance ``d`` of point ``index`` into slot ``p`` of the ascending
    buffers ``bd`` / ``bi``, shifting the larger ones up (a stable insertion:
    ties keep their order).  A k-nearest search keeps its best k with it
    (``p`` = the count so far, or k - 1 once full).  Compiled, inlined."""
    while p > 0 and bd[p - 1] > d:
        bd[p] = bd[p - 1]
        bi[p] = bi[p - 1]
        p -= 1
    bd[p] = d
    bi[p] = index


@njit(cache=True, inline="always")
def _first_at_least(zs, lo, hi, z):  # pragma: no cover - compiled
    """The first index in ``[lo, hi)`` of the ascending ``zs`` whose value is at least ``z`` (``hi``: none)."""
    while lo < hi:
        mid = (lo + hi) // 2
        if zs[mid] < z:
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit(cache=True, inline="always")
def _first_above(zs, lo, hi, z):  # pragma: no cover - compiled
    """The first index in ``[lo, hi)`` of the ascending ``zs`` whose value is above ``z`` (``hi``: none)."""
    while lo < hi:
        mid = (lo + hi) // 2
        if zs[mid] <= z:
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit(cache=True, inline="always")
def _block_candidates(px, py, pz, cx, cy, start, perm, xs, ys, zs, x0, y0, side, nx, ny, bound, cd,
                      ci):  # pragma: no cover
    """Squared distances (and points) of the 3 x 3 cells around cell (cx, cy) below ``bound``, into ``cd``, ``ci``.

    Returns their count.  ``bound`` inf: every point of the cells.
    """
    margin = 1e-9 * side  # a point may sit an ulp outside its cell
    finite = bound < np.inf
    reach = np.sqrt(bound) * (1.0 + 1e-9) if finite else np.inf
    m = 0
    for gx in range(max(cx - 1, 0), min(cx + 1, nx - 1) + 1):
        for gy in range(max(cy - 1, 0), min(cy + 1, ny - 1) + 1):
            # cells on the grid's border also hold the points clipped into them
            if finite and 0 < gx < nx - 1 and 0 < gy < ny - 1 and cell_gap2(px, py, gx, gy, x0, y0, side,
                                                                          margin) >= bound:
                continue
            c = gx * ny + gy
            a, b = start[c], start[c + 1]
            if finite and a < b:
                # a cell is sorted by height: only its slice within reach in z
                a = _first_at_least(zs, a, b, pz - reach)
                b = _first_above(zs, a, b, pz + reach)
            for s in range(a, b):
                dx = xs[s] - px
                dy = ys[s] - py
                dz = zs[s] - pz
                # the same sum order as cKDTree's squared distance
                d = dx * dx + dy * dy + dz * dz
                cd[m] = d
                ci[m] = perm[s]
                m += d < bound
    return m


@njit(cache=True, inline="always")
def _smallest_sorted(cd, ci, m, bound, kk, hist, bd, bi):  # pragma: no cover - compiled
    """The min(m, kk) smallest of ``cd[:m]`` (all below ``bound``), ascending, into ``bd`` / ``bi``; their count.

    A counting sort on ``len(hist) - 1`` equal bins of [0, bound) (the
    squared distances of points on a surface spread evenly over them),
    then insertion within the bins; ``cd`` / ``ci`` need room for 2 m.
    """
    nb = len(hist) - 1
    scale = nb / bound if bound > 0.0 else 0.0
    hist[:] = 0
    for s in range(m):
        hist[min(int(cd[s] * scale), nb - 1) + 1] += 1
    # the first bins holding kk values: the rest cannot be among the kk smallest
    last = nb - 1
    acc = 0
    for b in range(nb):
        acc += hist[b + 1]
        hist[b + 1] = acc
        if acc >= kk:
            last = b
            break
    taken = hist[last + 1]
    for s in range(m):
        b = min(int(cd[s] * scale), nb - 1)
        if b <= last:
            p = m + hist[b]
            hist[b] += 1
            cd[p] = cd[s]
            ci[p] = ci[s]
    cnt = min(taken, kk)
    for s in range(taken):
        d = cd[m + s]
        if s < kk:
            insert_sorted(bd, bi, s, d, ci[m + s])
        elif d < bd[kk - 1]:
            insert_sorted(bd, bi, kk - 1, d, ci[m + s])
    return cnt


@njit(cache=True)
def _knn_one(i, xyz, cell, start, perm, xs, ys, zs, x0, y0, side, nx, ny, k, guess, bd, bi, cd, ci,
             hist):  # pragma: no cover
    """The k + 1 nearest points of point i into ``bd`` (squared distances, ascending), ``bi``.

    Returns (tie, count): True when two of the k + 1 nearest distances
    (nearly) tie, and how many were found (k + 1 unless the cloud is
    smaller).  ``guess``: a squared distance likely to hold the k + 1
    nearest (inf: none); ``cd``, ``ci``: room for twice the points of any
    3 x 3 cells; ``hist``: the bins of :func:`_smallest_sorted`.
    """
    px, py, pz = xyz[i, 0], xyz[i, 1], xyz[i, 2]
    cx = cell[i] // ny
    cy = cell[i] - cx * ny
    margin = 1e-9 * side
    kk = k + 1
    # the cell and the ring around it hold the neighbours of nearly every
    # point.  Of their points only those nearer than the neighbours of
    # the previous point (a little farther) are sorted, when they are
    # enough; otherwise all of them
    m = _block_candidates(px, py, pz, cx, cy, start, perm, xs, ys, zs, x0, y0, side, nx, ny, guess, cd, ci)
    bound = guess
    if m < kk and guess < np.inf:
        bound = np.inf
        m = _block_candidates(px, py, pz, cx, cy, start, perm, xs, ys, zs, x0, y0, side, nx, ny, bound, cd, ci)
    if bound == np.inf:
        bound = 0.0
        for s in range(m):
            bound = max(bound, cd[s])
        bound = bound * (1.0 + 1e-9) + 1e-300
    cnt = _smallest_sorted(cd, ci, m, bound, kk, hist, bd, bi)
    worst = bd[kk - 1] if cnt == kk else np.inf
    ring = 2
    while True:
        gap = max((ring - 1) * side - margin, 0.0)
        if gap * gap >= worst:
            break
        if cx - ring < 0 and cy - ring < 0 and cx + ring >= nx and cy + ring >= ny:
            break
        for gx in range(max(cx - ring, 0), min(cx + ring, nx - 1) + 1):
            side_x = gx == cx - ring or gx == cx + ring
            for gy in range(max(cy - ring, 0), min(cy + ring, ny - 1) + 1):
                if not side_x and gy != cy - ring and gy != cy + ring:
                    continue  # inside the ring: visited already
                if 0 < gx < nx - 1 and 0 < gy < ny - 1 and cell_gap2(px, py, gx, gy, x0, y0, side, margin) >= worst:
                    continue
                c = gx * ny + gy
                a, b = start[c], start[c + 1]
                if a < b and worst < np.inf:
                    a = _first_at_least(zs, a, b, pz - np.sqrt(worst) * (1.0 + 1e-9))
                for s in range(a, b):
                    dz = zs[s] - pz
                    if dz > 0.0 and dz * dz >= worst:
                        break  # the rest of the cell is higher still
                    dx = xs[s] - px
                    dy = ys[s] - py
                    d = dx * dx + dy * dy + dz * dz
                    if d < worst:
                        if cnt < kk:
                            p = cnt
                            cnt += 1
                        else:
                            p = kk - 1
                        insert_sorted(bd, bi, p, d, perm[s])
                        if cnt == kk:
                            worst = bd[kk - 1]
        ring += 1
    for q in range(k):
        if bd[q + 1] - bd[q] <= _TIE * bd[q + 1]:
            return True, cnt
    return False, cnt


#: rows per thread's share of a query; each share starts without a guess
_SHARE = 256
#: the neighbours of the previous point, this much farther (in squared
#: distance), hold those of the next nearly always (Delft: 1 in 6 falls back)
_GUESS = 1.4
#: bins of the counting sort of the candidates
_BINS = 64


@njit(cache=True, parallel=True)
def _knn_query(rows, order, xyz, cell, start, perm, xs, ys, zs, x0, y0, side, nx, ny, k, out, tie):  # pragma: no cover
    """The k nearest of each of ``rows`` into ``out`` (and ``tie``), visited in ``order`` (by cell, then height)."""
    n = len(rows)
    # the most points any 3 x 3 cells hold
    block = 0
    for cx in range(nx):
        for cy in range(ny):
            block_n = 0
            for gx in range(max(cx - 1, 0), min(cx + 1, nx - 1) + 1):
                block_n += start[gx * ny + min(cy + 1, ny - 1) + 1] - start[gx * ny + max(cy - 1, 0)]
            block = max(block, block_n)
    for b in numba.prange((n + _SHARE - 1) // _SHARE):
        bd = np.empty(k + 1)
        bi = np.empty(k + 1, np.int64)
        cd = np.empty(2 * block)
        ci = np.empty(2 * block, np.int64)
        hist = np.empty(_BINS + 1, np.int64)
        guess = np.inf
        for t in range(b * _SHARE, min(n, (b + 1) * _SHARE)):
            r = order[t]
            tie[r], cnt = _knn_one(rows[r], xyz, cell, start, perm, xs, ys, zs, x0, y0, side, nx, ny, k, guess,
                                   bd, bi, cd, ci, hist)
            # consecutive points lie in one cell, at nearly the same height
            guess = bd[k] * _GUESS if cnt == k + 1 else np.inf
            for q in range(k):
                out[r, q] = bi[q]


class GridKnn:
    """Exact k nearest neighbours of points among themselves, on a plan grid.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), float64
        Points (m), N > k.
    k : int
        Neighbours per point, the point itself included.

    Notes
    -----
    :meth:`query` returns the neighbours of ``cKDTree(xyz).query(xyz[rows],
    k)`` in the same order, except in the rows it flags as ties.  The cell
    side, about twice the distance of the k-th neighbour from the density of the
    occupied 2 m cells, changes the speed only.
    """

    def __init__(self, xyz: np.ndarray, k: int) -> None:
        self.xyz = np.ascontiguousarray(xyz, dtype=np.float64)
        n = len(self.xyz)
        if not n > k >= 1:
            raise ValueError(f"GridKnn needs more than k = {k} >= 1 points, got {n}")
        self.k = int(k)
        lo = column_min(self.xyz[:, :2])
        span = column_max(self.xyz[:, :2]) - lo
        ij = np.floor((self.xyz[:, :2] - lo) / 2.0).astype(np.int64)
        occupied = int(dense_cells(ij).max()) + 1
        # cells about twice the k-th neighbour's distance: the 3 x 3 cells around a point
        # hold ~11 k points, of which only those within the guessed reach are sorted, and
        # the ring beyond them is rarely visited (at 1.4 times, ~2.9 k: Delft's search 10 % slower)
        side = float(2.0 * np.sqrt(self.k * occupied / (np.pi * n)))
        # at most ~4 cells a point: a sparse, wide cloud gets coarser cells
        # and along a line (one span near 0) not more cells than ~4 a point either: a few points kilometres
        # apart made billions of cells
        side = max(side, float(np.sqrt(span[0] * span[1] / (4.0 * n))), float(span.max()) / (4.0 * n), 1e-6)
        self.side = side
        self.x0, self.y0 = float(lo[0]), float(lo[1])
        self.nx = int(span[0] // side) + 1
        self.ny = int(span[1] // side) + 1
        self._grid = _knn_build(self.xyz, self.x0, self.y0, side, self.nx, self.ny)
        # each point's place in the (cell, height) order: queries visit their rows in it
        self._rank = np.empty(n, np.int64)
        self._rank[self._grid[2]] = np.arange(n)

    def query(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The k nearest points of the points ``rows``, nearest first.

        Returns
        -------
        idx : ndarray of shape (R, k), int64
        tie : ndarray of shape (R,), bool
            Rows where two of the k + 1 nearest distances (nearly) tie:
            their order is not unique, ask ``cKDTree.query``.
        """
        rows = np.ascontiguousarray(rows, dtype=np.int64)
        out = np.empty((len(rows), self.k), np.int64)
        tie = np.empty(len(rows), np.bool_)
        # neighbouring rows one after the other: each row's neighbours bound the next one's search
        order = np.argsort(self._rank[rows], kind="stable")
        _knn_query(rows, order, self.xyz, *self._grid, self.x0, self.y0, self.side, self.nx, self.ny, self.k,
                   out, tie)
        return out, tie
