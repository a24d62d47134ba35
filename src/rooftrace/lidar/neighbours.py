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

from rooftrace.lidar._kernels import dense_cells

__all__ = ["GridKnn", "insert_sorted"]

# cKDTree.query spends most of a k = 60 query in its heap of neighbours.
# Here the points sit in plan cells, sorted by height within a cell; a query
# visits the rings of cells around its own until the ring is farther than
# its (k+1)-th neighbour, and skips the part of a cell out of reach in z.
# The k + 1 nearest distances decide the neighbours and their order
# uniquely unless two of them tie; such rows are flagged for the KD-tree
# (its tie order follows its traversal; about 1 row in 5000).

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


@njit(cache=True)
def _select_smallest(cd, ci, m, kk):  # pragma: no cover - compiled
    """Reorder ``cd[:m]`` (and ``ci``) so that ``cd[:kk]`` holds its kk smallest values (quickselect)."""
    lo, hi = 0, m - 1
    target = kk - 1
    while lo < hi:
        mid = (lo + hi) // 2
        a, b, c = cd[lo], cd[mid], cd[hi]
        pivot = max(min(a, b), min(max(a, b), c))
        i, j = lo, hi
        while i <= j:
            while cd[i] < pivot:
                i += 1
            while cd[j] > pivot:
                j -= 1
            if i <= j:
                cd[i], cd[j] = cd[j], cd[i]
                ci[i], ci[j] = ci[j], ci[i]
                i += 1
                j -= 1
        if target <= j:
            hi = j
        elif target >= i:
            lo = i
        else:
            break


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


@njit(cache=True)
def _knn_one(i, xyz, cell, start, perm, xs, ys, zs, x0, y0, side, nx, ny, k, bd, bi, cd, ci):  # pragma: no cover
    """The k + 1 nearest points of point i into ``bd`` (squared distances, ascending), ``bi``; True on a tie.

    ``cd``, ``ci``: room for the points of any 3 x 3 cells.
    """
    px, py, pz = xyz[i, 0], xyz[i, 1], xyz[i, 2]
    cx = cell[i] // ny
    cy = cell[i] - cx * ny
    margin = 1e-9 * side  # a point may sit an ulp outside its cell
    kk = k + 1
    # the cell and the ring around it hold the neighbours of nearly every
    # point (a cell holds ~k/pi points): all their distances, the k + 1
    # smallest selected and sorted, instead of an insertion each
    m = 0
    for gx in range(max(cx - 1, 0), min(cx + 1, nx - 1) + 1):
        for gy in range(max(cy - 1, 0), min(cy + 1, ny - 1) + 1):
            c = gx * ny + gy
            for s in range(start[c], start[c + 1]):
                dx = xs[s] - px
                dy = ys[s] - py
                dz = zs[s] - pz
                # the same sum order as cKDTree's squared distance
                cd[m] = dx * dx + dy * dy + dz * dz
                ci[m] = perm[s]
                m += 1
    if m > kk:
        _select_smallest(cd, ci, m, kk)
    cnt = min(m, kk)
    for s in range(cnt):
        insert_sorted(bd, bi, s, cd[s], ci[s])
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
                # cells on the grid's border also hold the points clipped into them
                if 0 < gx < nx - 1 and 0 < gy < ny - 1:
                    bx = x0 + gx * side
                    by = y0 + gy * side
                    ddx = max(max(bx - px, px - (bx + side)) - margin, 0.0)
                    ddy = max(max(by - py, py - (by + side)) - margin, 0.0)
                    if ddx * ddx + ddy * ddy >= worst:
                        continue
                c = gx * ny + gy
                a, b = start[c], start[c + 1]
                if a < b and worst < np.inf:
                    zlo = pz - np.sqrt(worst) * (1.0 + 1e-9)
                    lo, hi = a, b
                    while lo < hi:
                        mid = (lo + hi) // 2
                        if zs[mid] < zlo:
                            lo = mid + 1
                        else:
                            hi = mid
                    a = lo
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
            return True
    return False


@njit(cache=True, parallel=True)
def _knn_query(rows, xyz, cell, start, perm, xs, ys, zs, x0, y0, side, nx, ny, k, out, tie):  # pragma: no cover
    n = len(rows)
    # the most points any 3 x 3 cells hold
    block = 0
    for cx in range(nx):
        for cy in range(ny):
            block_n = 0
            for gx in range(max(cx - 1, 0), min(cx + 1, nx - 1) + 1):
                block_n += start[gx * ny + min(cy + 1, ny - 1) + 1] - start[gx * ny + max(cy - 1, 0)]
            block = max(block, block_n)
    for b in numba.prange((n + 255) // 256):
        bd = np.empty(k + 1)
        bi = np.empty(k + 1, np.int64)
        cd = np.empty(block)
        ci = np.empty(block, np.int64)
        for r in range(b * 256, min(n, (b + 1) * 256)):
            tie[r] = _knn_one(rows[r], xyz, cell, start, perm, xs, ys, zs, x0, y0, side, nx, ny, k, bd, bi, cd, ci)
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
    side, about 1.4 times the distance of the k-th neighbour from the density of the
    occupied 2 m cells, changes the speed only.
    """

    def __init__(self, xyz: np.ndarray, k: int) -> None:
        self.xyz = np.ascontiguousarray(xyz, dtype=np.float64)
        n = len(self.xyz)
        if not n > k >= 1:
            raise ValueError(f"GridKnn needs more than k = {k} >= 1 points, got {n}")
        self.k = int(k)
        lo = self.xyz[:, :2].min(axis=0)
        span = self.xyz[:, :2].max(axis=0) - lo
        ij = np.floor((self.xyz[:, :2] - lo) / 2.0).astype(np.int64)
        occupied = int(dense_cells(ij).max()) + 1
        # cells about 1.4 times the k-th neighbour's distance: the 3 x 3 cells around a point
        # hold ~2.9 k points (at twice that distance, ~11 k: Delft's search 20 % slower)
        side = float(np.sqrt(self.k * occupied * 2.0 / (np.pi * n)))
        # at most ~4 cells a point: a sparse, wide cloud gets coarser cells
        # and along a line (one span near 0) not more cells than ~4 a point either: a few points kilometres
        # apart made billions of cells
        side = max(side, float(np.sqrt(span[0] * span[1] / (4.0 * n))), float(span.max()) / (4.0 * n), 1e-6)
        self.side = side
        self.x0, self.y0 = float(lo[0]), float(lo[1])
        self.nx = int(span[0] // side) + 1
        self.ny = int(span[1] // side) + 1
        self._grid = _knn_build(self.xyz, self.x0, self.y0, side, self.nx, self.ny)

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
        _knn_query(rows, self.xyz, *self._grid, self.x0, self.y0, self.side, self.nx, self.ny, self.k, out, tie)
        return out, tie
