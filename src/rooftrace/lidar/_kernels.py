"""Compiled kernels of the detection stages (numba).

Each replaces a sort, a Python loop or a KD-tree query over points, with
the same result to the bit (ties are broken as the numpy or scipy code
they replace breaks them, or handed back to it).
"""

from __future__ import annotations

import numba
import numpy as np
from numba import njit

__all__ = ["cell_gap2", "column_max", "column_min", "count_within", "cross_pairs", "dense_cells", "dense_unique",
           "lowest_per_group", "lowest_point_per_group", "nearest_within", "normal_links", "pair_mask", "pair_pull",
           "rotate_to_smallest", "sort_by_bucket", "union_pairs", "unique_pairs"]


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


def column_min(a: np.ndarray) -> np.ndarray:
    """``a.min(axis=0)`` of an (N, C) array, one column at a time.

    numpy reduces a few columns along axis 0 row by row: 20-50 times
    slower (22 ms for a million points' x and y).  A minimum is exact, so
    the values are the same.
    """
    return np.array([a[:, j].min() for j in range(a.shape[1])], dtype=a.dtype)


def column_max(a: np.ndarray) -> np.ndarray:
    """``a.max(axis=0)`` of an (N, C) array, one column at a time (see :func:`column_min`)."""
    return np.array([a[:, j].max() for j in range(a.shape[1])], dtype=a.dtype)


@njit(cache=True)
def cross_pairs(labels: np.ndarray, pairs: np.ndarray, first: np.ndarray,
                second: np.ndarray) -> np.ndarray:  # pragma: no cover
    """Which pairs join a ``first`` cluster to another, ``second`` one.

    One pass over the pairs instead of numpy's label gathers and masks
    (five temporaries of Delft's 7.7 million pairs).

    Parameters
    ----------
    labels : ndarray of shape (N,), int
        Cluster of each point, negative for none.
    pairs : ndarray of shape (M, 2), int
        Point pairs.
    first, second : ndarray of shape (K,), bool
        Clusters allowed at the pair's first and second end.

    Returns
    -------
    ndarray of shape (M,), bool
        Both ends in a cluster, two different ones, the first a ``first``
        cluster, the second a ``second`` one.
    """
    keep = np.empty(len(pairs), np.bool_)
    for r in range(len(pairs)):
        a = labels[pairs[r, 0]]
        b = labels[pairs[r, 1]]
        keep[r] = a >= 0 and b >= 0 and a != b and first[a] and second[b]
    return keep


@njit(cache=True)
def pair_mask(flags: np.ndarray, pairs: np.ndarray, both: bool) -> np.ndarray:  # pragma: no cover
    """``flags[pairs[:, 0]] & flags[pairs[:, 1]]`` (``both``) or ``|`` (not ``both``), in one pass.

    Parameters
    ----------
    flags : ndarray of shape (N,), bool
        A flag per point.
    pairs : ndarray of shape (M, 2), int
        Point pairs.
    both : bool
        Both ends flagged, or at least one.

    Returns
    -------
    ndarray of shape (M,), bool
    """
    keep = np.empty(len(pairs), np.bool_)
    for r in range(len(pairs)):
        a = flags[pairs[r, 0]]
        b = flags[pairs[r, 1]]
        keep[r] = (a and b) if both else (a or b)
    return keep


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
def _sorted_rows(start, col, out, u):  # pragma: no cover - compiled
    """Each row r's values ``col[start[r]:start[r + 1]]`` sorted, the distinct ones written as (r, value).

    They go to ``out[u]`` on; returns the new u.
    """
    for r in range(len(start) - 1):
        lo, hi = start[r], start[r + 1]
        if hi - lo > 48:
            col[lo:hi] = np.sort(col[lo:hi])
        else:
            for s in range(lo + 1, hi):  # a plan neighbourhood: a few dozen at most
                v = col[s]
                t = s
                while t > lo and col[t - 1] > v:
                    col[t] = col[t - 1]
                    t -= 1
                col[t] = v
        for s in range(lo, hi):
            if s == lo or col[s] != col[s - 1]:
                out[u, 0] = r
                out[u, 1] = col[s]
                u += 1
    return u


@njit(cache=True)
def _unique_rows_of_pairs(a, b, n):  # pragma: no cover - compiled
    """The distinct (a, b) of :func:`unique_pairs`: a counting sort on ``a``, then each (short) row sorted."""
    start = _key_starts(a, n)
    # each b straight into its row (the rows are sorted next, so their order in it does not matter)
    fill = start[:-1].copy()
    col = np.empty(len(a), np.int64)
    for e in range(len(a)):
        col[fill[a[e]]] = b[e]
        fill[a[e]] += 1
    out = np.empty((len(a), 2), np.int64)
    u = _sorted_rows(start, col, out, 0)
    return out[:u].copy()


@njit(cache=True)
def _unique_rows_of_two(p, q, n):  # pragma: no cover - compiled
    """:func:`_unique_rows_of_pairs` of the rows of ``p`` and ``q`` together, without concatenating them."""
    start = np.zeros(n + 1, np.int64)
    for e in range(len(p)):
        start[p[e, 0] + 1] += 1
    for e in range(len(q)):
        start[q[e, 0] + 1] += 1
    for r in range(n):
        start[r + 1] += start[r]
    fill = start[:-1].copy()
    col = np.empty(len(p) + len(q), np.int64)
    for e in range(len(p)):
        col[fill[p[e, 0]]] = p[e, 1]
        fill[p[e, 0]] += 1
    for e in range(len(q)):
        col[fill[q[e, 0]]] = q[e, 1]
        fill[q[e, 0]] += 1
    out = np.empty((len(col), 2), np.int64)
    u = _sorted_rows(start, col, out, 0)
    return out[:u].copy()


def unique_pairs(a: np.ndarray, b: np.ndarray, n: int) -> np.ndarray:
    """``np.unique(np.column_stack([a, b]), axis=0)`` of integers in [0, n).

    Returns the distinct (a, b) pairs as (U, 2) int64, in (a, b) order.
    """
    # columns of a pair array stay views: copying Delft's 7 million took a third of the count
    a = np.asarray(a, dtype=np.int64)
    b = np.asarray(b, dtype=np.int64)
    if n <= 4 * len(a) + 1024:
        # counting on a: np.sort of the 7 million int64 keys of Delft's plan pairs took 0.6-1.0 s
        return _unique_rows_of_pairs(a, b, int(n))
    # a sort, not np.unique: its hash path took 30 s on the 5 million pairs of an AHN3 tile
    key = np.sort(a * n + b)
    key = key[np.r_[True, key[1:] != key[:-1]]] if len(key) else key
    return np.column_stack([key // n, key % n])


def union_pairs(p: np.ndarray, q: np.ndarray, n: int) -> np.ndarray:
    """``unique_pairs`` of the rows of two (M, 2) pair arrays of integers in [0, n) together.

    The same (U, 2) int64 as ``unique_pairs`` of their concatenation,
    without the concatenation (123 MB for Delft's 7.7 million pairs).
    """
    p = np.asarray(p, dtype=np.int64).reshape(-1, 2)
    q = np.asarray(q, dtype=np.int64).reshape(-1, 2)
    if n <= 4 * (len(p) + len(q)) + 1024:
        return _unique_rows_of_two(p, q, int(n))
    both = np.concatenate([p, q])
    return unique_pairs(both[:, 0], both[:, 1], n)


def dense_cells(ij: np.ndarray) -> np.ndarray:
    """Index (0..C-1) of each row's integer cell (i, j), cells numbered in (i, j) order, by counting.

    ``np.unique(ij, axis=0, return_inverse=True)[1]``: the grids of the
    outlier filter, the ground blocks and the spacing estimates.
    """
    ij = ij - column_min(ij)
    return dense_unique(ij[:, 0] * (int(ij[:, 1].max()) + 1) + ij[:, 1])[1]


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


@njit(cache=True)
def _bucket_then_sort(key: np.ndarray, lo: int, span: int, values: np.ndarray) -> np.ndarray:  # pragma: no cover
    count = np.zeros(span + 1, np.int64)
    for i in range(len(key)):
        count[key[i] - lo + 1] += 1
    for b in range(span):
        count[b + 1] += count[b]
    fill = count[:-1].copy()
    order = np.empty(len(key), np.int64)
    for i in range(len(key)):
        b = key[i] - lo
        order[fill[b]] = i
        fill[b] += 1
    for b in range(span):
        if count[b + 1] - count[b] > 1:
            run = order[count[b]:count[b + 1]].copy()
            order[count[b]:count[b + 1]] = run[np.argsort(values[run], kind="mergesort")]
    return order


def sort_by_bucket(values: np.ndarray, key: np.ndarray) -> np.ndarray:
    """``np.lexsort((values, key))`` for integer ``key`` of a small range (strips, cells): a counting sort, then each bucket.

    Parameters
    ----------
    values : ndarray of shape (N,), float64
        Finite secondary key.
    key : ndarray of shape (N,), int
        Primary key.

    Returns
    -------
    ndarray of shape (N,), int64
        The permutation; ties by index, as ``np.lexsort``.
    """
    if len(key) == 0:
        return np.empty(0, np.int64)
    lo, hi = int(key.min()), int(key.max())
    if hi - lo > 4 * len(key) + 1024:
        return np.lexsort((values, key))
    return _bucket_then_sort(np.ascontiguousarray(key, np.int64), lo, hi - lo + 1,
                             np.ascontiguousarray(values, np.float64))


@njit(cache=True)
def _octant(dx, dy):  # pragma: no cover - compiled
    """Sector (of 8, the first starting at -x) of the direction (dx, dy) from its signs, -1 near a border.

    The sector of ``int((arctan2(dy, dx) + pi) / (pi / 4))`` without the
    arctangent; where the direction lies within 1e-9 (relative) of an axis
    or a diagonal the rounding of that formula decides, so -1 asks for it.
    """
    ax, ay = abs(dx), abs(dy)
    if ax == 0.0 or ay == 0.0:
        return -1
    if ay <= 1e-9 * ax or ax <= 1e-9 * ay or abs(ax - ay) <= 1e-9 * (ax + ay):
        return -1
    steep = ay > ax
    if dy < 0.0:
        if dx < 0.0:
            return 1 if steep else 0
        return 2 if steep else 3
    if dx > 0.0:
        return 5 if steep else 4
    return 6 if steep else 7


@njit(cache=True, inline="always")
def _cell_of(px, py, x0, y0, side, nx, ny):  # pragma: no cover
    """Column and row of the plan grid cell holding (px, py), clamped to the grid (a query may lie outside it)."""
    cx = min(max(int(np.floor((px - x0) / side)), 0), nx - 1)
    cy = min(max(int(np.floor((py - y0) / side)), 0), ny - 1)
    return cx, cy


@njit(cache=True, inline="always")
def cell_gap2(px, py, gx, gy, x0, y0, side, margin):  # pragma: no cover - compiled
    """Squared plan distance from (px, py) to grid cell (gx, gy), less ``margin`` per axis (a point may sit an ulp
    outside its cell): a cell this far or farther holds nothing nearer.  Compiled, inlined."""
    bx = x0 + gx * side
    by = y0 + gy * side
    ddx = max(max(bx - px, px - (bx + side)) - margin, 0.0)
    ddy = max(max(by - py, py - (by + side)) - margin, 0.0)
    return ddx * ddx + ddy * ddy


#: rows per thread's share of :func:`_sector_scan`
_SECTOR_SHARE = 256


@njit(cache=True, parallel=True)
def _sector_scan(xy, order, xs, ys, start, nx, ny, x0, y0, side, rows, radius, n_sectors, out):  # pragma: no cover
    """Nearest point per angular sector of each row within ``radius``; ties go to the lower index.

    ``xs``, ``ys`` are the coordinates in cell order (``order``), read in
    sequence.  The cells may be smaller than ``radius``: those wholly
    beyond it are skipped (the result does not depend on the cells).
    """
    r2 = radius * radius
    width = 2.0 * np.pi / n_sectors
    reach = int(np.ceil(radius / side))
    margin = 1e-9 * side  # a point may sit an ulp outside its cell
    for share in numba.prange((len(rows) + _SECTOR_SHARE - 1) // _SECTOR_SHARE):
        best = np.empty(n_sectors)
        for r in range(share * _SECTOR_SHARE, min(len(rows), (share + 1) * _SECTOR_SHARE)):
            best[:] = np.inf
            i = rows[r]
            px, py = xy[i, 0], xy[i, 1]
            cx, cy = _cell_of(px, py, x0, y0, side, nx, ny)
            for gx in range(max(cx - reach, 0), min(cx + reach, nx - 1) + 1):
                for gy in range(max(cy - reach, 0), min(cy + reach, ny - 1) + 1):
                    # cells on the grid's border also hold the points clipped into them
                    if 0 < gx < nx - 1 and 0 < gy < ny - 1 and cell_gap2(px, py, gx, gy, x0, y0, side, margin) > r2:
                        continue
                    c = gx * ny + gy
                    for s in range(start[c], start[c + 1]):
                        dx = xs[s] - px
                        dy = ys[s] - py
                        d = dx * dx + dy * dy
                        if d > r2 or d == 0.0:
                            continue
                        j = order[s]
                        k = _octant(dx, dy) if n_sectors == 8 else -1
                        if k < 0:
                            a = np.arctan2(dy, dx) + np.pi
                            k = min(int(a / width), n_sectors - 1)
                        if d < best[k] or (d == best[k] and j < out[r, k]):
                            best[k] = d
                            out[r, k] = j


def sector_nearest(xy: np.ndarray, rows: np.ndarray, radius: float, n_sectors: int = 8) -> np.ndarray:
    """Nearest point in each of ``n_sectors`` equal angular sectors around each of ``rows``, within ``radius`` in plan.

    Parameters
    ----------
    xy : ndarray of shape (N, 2), float64
        Plan coordinates (m).
    rows : ndarray of shape (R,), int
        Points whose neighbours are wanted.
    radius : float
        Search radius (m).
    n_sectors : int, default 8
        Sectors, the first starting at the direction -x.

    Returns
    -------
    ndarray of shape (R, n_sectors), int64
        Index into ``xy`` of the nearest point per sector, -1 where the
        sector holds none within ``radius`` (points at the same plan
        position are skipped).
    """
    xy = np.ascontiguousarray(np.asarray(xy, dtype=np.float64)[:, :2])
    rows = np.ascontiguousarray(rows, dtype=np.int64)
    out = np.full((len(rows), n_sectors), -1, np.int64)
    if len(xy) < 2 or len(rows) == 0:
        return out
    # cells of half the radius: the 5 x 5 cells around a point, less the
    # corners beyond the radius, cover less than the 3 x 3 of a radius's width
    order, xs, ys, start, nx, ny, x0, y0, side = _plan_grid(xy, 0.5 * float(radius))
    _sector_scan(xy, order, xs, ys, start, nx, ny, x0, y0, side, rows, float(radius), int(n_sectors), out)
    return out


def _plan_grid(xy: np.ndarray, radius: float) -> tuple:
    """Plan cells at least ``radius`` wide (and ~4 points a cell at most), the points in cell order.

    Returns (order, xs, ys, start, nx, ny, x0, y0, side): the points of cell
    c are ``order[start[c]:start[c + 1]]`` (ascending), ``xs``, ``ys`` their
    coordinates in that order, so that a scan of a cell reads them in sequence.
    """
    lo = column_min(xy)
    span = column_max(xy) - lo
    side = max(float(radius), float(np.sqrt(span[0] * span[1] / (4.0 * len(xy)))), 1e-6)
    nx, ny = int(span[0] // side) + 1, int(span[1] // side) + 1
    ij = np.minimum(np.floor((xy - lo) / side).astype(np.int64), [nx - 1, ny - 1])
    order, start = _counting_order(ij[:, 0] * ny + ij[:, 1], nx * ny)
    xs, ys = np.ascontiguousarray(xy[order, 0]), np.ascontiguousarray(xy[order, 1])
    return order, xs, ys, start, nx, ny, float(lo[0]), float(lo[1]), side


@njit(cache=True)
def _key_starts(key, n_keys):  # pragma: no cover - compiled
    """Where each key of [0, n_keys) starts in ``key`` sorted (n_keys + 1 offsets), by counting."""
    start = np.zeros(n_keys + 1, np.int64)
    for i in range(len(key)):
        start[key[i] + 1] += 1
    for c in range(n_keys):
        start[c + 1] += start[c]
    return start


@njit(cache=True)
def _counting_order(key, n_keys):  # pragma: no cover - compiled
    """``np.argsort(key, kind="stable")`` of keys in [0, n_keys) and where each key starts in it, by counting."""
    start = _key_starts(key, n_keys)
    fill = start[:-1].copy()
    order = np.empty(len(key), np.int64)
    for i in range(len(key)):
        order[fill[key[i]]] = i
        fill[key[i]] += 1
    return order, start


@njit(cache=True, parallel=True)
def _count_within(xy, label, flag, order, xs, ys, start, nx, ny, x0, y0, side, r2, count, flagged):  # pragma: no cover
    for i in numba.prange(len(xy)):
        px, py = xy[i, 0], xy[i, 1]
        cx, cy = _cell_of(px, py, x0, y0, side, nx, ny)
        c = 0
        f = 0
        for gx in range(max(cx - 1, 0), min(cx + 1, nx - 1) + 1):
            for gy in range(max(cy - 1, 0), min(cy + 1, ny - 1) + 1):
                g = gx * ny + gy
                for s in range(start[g], start[g + 1]):
                    j = order[s]
                    if label[j] != label[i]:
                        continue
                    dx = xs[s] - px
                    dy = ys[s] - py
                    # cKDTree's squared distance and its ball test (d <= r²)
                    if dx * dx + dy * dy <= r2:
                        c += 1
                        f += flag[j]
        count[i] = c
        flagged[i] = f


def count_within(xy: np.ndarray, label: np.ndarray, flag: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Points of the same label within ``radius`` in plan of each point (itself included), and the flagged ones.

    Parameters
    ----------
    xy : ndarray of shape (N, 2), float64
        Plan coordinates (m).
    label : ndarray of shape (N,), int
        Label of each point.
    flag : ndarray of shape (N,), bool
    radius : float
        Plan radius (m), included.

    Returns
    -------
    count, flagged : ndarray of shape (N,), int64
        The counts of ``cKDTree.query_ball_point(..., return_length=True)``
        of the points of each label apart, without a tree per label.
    """
    xy = np.ascontiguousarray(np.asarray(xy, dtype=np.float64)[:, :2])
    count = np.zeros(len(xy), np.int64)
    flagged = np.zeros(len(xy), np.int64)
    if len(xy) == 0:
        return count, flagged
    # cells a little wider than the radius: a pair at exactly the radius
    # never lies two cells apart by the rounding of the cell index
    grid = _plan_grid(xy, float(radius) * (1.0 + 1e-9))
    _count_within(xy, np.ascontiguousarray(label, np.int64), np.ascontiguousarray(flag, np.int64), *grid,
                  float(radius) ** 2, count, flagged)
    return count, flagged


@njit(cache=True, parallel=True)
def _nearest_scan(queries, order, xs, ys, zs, start, nx, ny, x0, y0, side, r2, out, tie):  # pragma: no cover
    for q in numba.prange(len(queries)):
        px, py = queries[q, 0], queries[q, 1]
        pz = queries[q, 2] if len(zs) else 0.0
        cx, cy = _cell_of(px, py, x0, y0, side, nx, ny)
        best = r2
        bj = -1
        t = False
        for gx in range(max(cx - 1, 0), min(cx + 1, nx - 1) + 1):
            for gy in range(max(cy - 1, 0), min(cy + 1, ny - 1) + 1):
                g = gx * ny + gy
                for s in range(start[g], start[g + 1]):
                    dx = xs[s] - px
                    dy = ys[s] - py
                    # cKDTree's squared distance, and its bound (d < r²)
                    d = dx * dx + dy * dy
                    if len(zs):
                        dz = zs[s] - pz
                        d = d + dz * dz
                    if d < best:
                        best = d
                        bj = order[s]
                        t = False
                    elif d == best and bj >= 0:
                        t = True
        out[q] = bj
        tie[q] = t


def nearest_within(data: np.ndarray, queries: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Nearest point of ``data`` closer than ``radius`` to each query, as ``cKDTree.query(..., distance_upper_bound)``.

    Parameters
    ----------
    data : ndarray of shape (N, D), float64
        Points (m), D = 2 (plan) or 3.
    queries : ndarray of shape (M, D), float64
    radius : float
        Distances must be shorter than this (m).

    Returns
    -------
    nearest : ndarray of shape (M,), int64
        Index into ``data``, -1 where none is closer than ``radius``.
    tie : ndarray of shape (M,), bool
        Queries with two nearest points at the same distance: which one the
        KD-tree returns follows its traversal; ask it.
    """
    data = np.asarray(data, dtype=np.float64)
    queries = np.ascontiguousarray(queries, dtype=np.float64)
    out = np.full(len(queries), -1, np.int64)
    tie = np.zeros(len(queries), bool)
    if len(data) == 0 or len(queries) == 0:
        return out, tie
    xy = np.ascontiguousarray(data[:, :2])
    # cells a little wider than the radius: a point at the radius never lies
    # two cells away by the rounding of the cell index
    order, xs, ys, start, nx, ny, x0, y0, side = _plan_grid(xy, float(radius) * (1.0 + 1e-9))
    zs = np.ascontiguousarray(data[order, 2]) if data.shape[1] > 2 else np.empty(0)
    _nearest_scan(queries, order, xs, ys, zs, start, nx, ny, x0, y0, side, float(radius) ** 2, out, tie)
    return out, tie


@njit(cache=True)
def _dot3(a0, a1, a2, b0, b1, b2):  # pragma: no cover - compiled
    # numpy's einsum("ij,ij->i") adds the three products in this order
    return (a0 * b0 + a2 * b2) + a1 * b1


@njit(cache=True, parallel=True)
def normal_links(xyz, normals, pairs, link_height, min_cos):  # pragma: no cover - compiled
    """The normal test of region growing for each pair, without numpy's (M, 3) temporaries.

    ``|n_i·(p_i − p_j)| < link_height`` and ``|n_j·(p_i − p_j)| < link_height``,
    and, when ``min_cos`` > -1, ``|n_i·n_j| >= min_cos``.  The products are
    summed in einsum's order, so the dot products are numpy's to the bit.
    """
    keep = np.empty(len(pairs), np.bool_)
    for e in numba.prange(len(pairs)):
        i, j = pairs[e, 0], pairs[e, 1]
        dx = xyz[i, 0] - xyz[j, 0]
        dy = xyz[i, 1] - xyz[j, 1]
        dz = xyz[i, 2] - xyz[j, 2]
        ok = (abs(_dot3(normals[i, 0], normals[i, 1], normals[i, 2], dx, dy, dz)) < link_height
              and abs(_dot3(normals[j, 0], normals[j, 1], normals[j, 2], dx, dy, dz)) < link_height)
        if ok and min_cos > -1.0:
            ok = abs(_dot3(normals[i, 0], normals[i, 1], normals[i, 2],
                           normals[j, 0], normals[j, 1], normals[j, 2])) >= min_cos
        keep[e] = ok
    return keep
