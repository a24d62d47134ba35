"""Compiled loops of :func:`rooftrace.roof.faces.partition_outline`: the plane each raster cell takes.

A cell whose k nearest labelled points disagree takes the candidate with
the fewest violations of the intersection lines near it, then (with
``vote``) the most votes, then the nearest.  In numpy this went through
(cells, k, k) arrays of candidate pairs, a third of the face partition on
Delft; here one pass per cell does the integer bookkeeping.  The float
work (distances of cells to lines, plane heights) stays in numpy, in
:mod:`~rooftrace.roof.faces`.  The k nearest labelled points of every
cell (a million cells on a large roof) come from a bucket search that
leaves only the cells with ties to ``cKDTree``.

The kernels of :mod:`rooftrace.roof.faces`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from rooftrace.lidar.neighbours import insert_sorted

__all__ = ["cell_lines", "cell_choice", "simplify_arcs", "points_in_boxes", "nearest_points"]


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


@njit(cache=True)
def _swept(V, i, j, pts, lo, hi, delta, foreign):  # pragma: no cover - compiled
    """Net misplacements (sum of ``delta``) of the points the chord ``V[i]-V[j]`` moves across the arc
    ``V[i..j]``, and whether any of them lies in a third face (``foreign``).

    The points moved are those inside the closed curve arc + chord by the
    even-odd rule: there the chord puts them on the arc's other side.
    """
    x0, y0 = V[i, 0], V[i, 1]
    x1, y1 = x0, y0
    for v in range(i, j + 1):
        x0, x1 = min(x0, V[v, 0]), max(x1, V[v, 0])
        y0, y1 = min(y0, V[v, 1]), max(y1, V[v, 1])
    net = 0
    for p in range(lo, hi):
        px, py = pts[p, 0], pts[p, 1]
        if px < x0 or px > x1 or py < y0 or py > y1:
            continue
        inside = False
        for e in range(i, j + 1):
            ax, ay = V[e, 0], V[e, 1]
            if e < j:
                bx, by = V[e + 1, 0], V[e + 1, 1]
            else:
                bx, by = V[i, 0], V[i, 1]
            if (ay > py) != (by > py) and px < ax + (py - ay) * (bx - ax) / (by - ay):
                inside = not inside
        if inside:
            if foreign[p]:
                return net, True
            net += delta[p]
    return net, False


@njit(cache=True)
def simplify_arcs(V, vptr, crease, pts, pptr, delta, foreign, free, floor, cap, few):  # pragma: no cover - compiled
    """Vertices kept of each face boundary (arc) by a Douglas-Peucker split judged on the points.

    Arc ``r`` is ``V[vptr[r]:vptr[r+1]]`` (its ends fixed; a closed arc is
    first split at its vertex farthest from its start), its points
    ``pts[pptr[r]:pptr[r+1]]``, with ``delta`` the misplacements (1 or 0)
    a move across the arc makes of each and ``foreign`` for points in a
    third face.  A chord replaces its stretch of arc when the stretch is
    within ``floor`` (m) of it (the raster's own staircase), or when it
    moves no point of a third face and either every vertex of the stretch
    is a ``crease`` (the two planes meet there: a ridge or valley, which a
    chord between crease points keeps within the crease tolerance) or it
    lies within ``cap`` (m) and the ``delta`` of the points it moves sum to
    at most ``few``.  Arcs not ``free``
    keep every vertex.  Returns a keep mask over ``V``.
    """
    keep = np.zeros(len(V), dtype=np.bool_)
    stack = np.empty((2 * len(V) + 4, 2), dtype=np.int64)
    for r in range(len(vptr) - 1):
        s, t = vptr[r], vptr[r + 1] - 1
        keep[s] = keep[t] = True
        if not free[r]:
            keep[s:t] = True
            continue
        top = 0
        if V[s, 0] == V[t, 0] and V[s, 1] == V[t, 1]:
            far, best = s, -1.0
            for v in range(s + 1, t):
                d = (V[v, 0] - V[s, 0]) ** 2 + (V[v, 1] - V[s, 1]) ** 2
                if d > best:
                    far, best = v, d
            keep[far] = True
            stack[0, 0], stack[0, 1], stack[1, 0], stack[1, 1] = s, far, far, t
            top = 2
        else:
            stack[0, 0], stack[0, 1] = s, t
            top = 1
        while top:
            top -= 1
            i, j = stack[top, 0], stack[top, 1]
            if j - i < 2:
                continue
            ax, ay = V[i, 0], V[i, 1]
            dx, dy = V[j, 0] - ax, V[j, 1] - ay
            L2 = max(dx * dx + dy * dy, 1e-24)
            dev, far = -1.0, i + 1
            for v in range(i + 1, j):
                u = min(max(((V[v, 0] - ax) * dx + (V[v, 1] - ay) * dy) / L2, 0.0), 1.0)
                d = np.hypot(V[v, 0] - ax - u * dx, V[v, 1] - ay - u * dy)
                if d > dev:
                    dev, far = d, v
            ok = dev <= floor
            if not ok:
                ridge = True
                for v in range(i, j + 1):
                    if not crease[v]:
                        ridge = False
                        break
                if ridge or dev <= cap:
                    net, third = _swept(V, i, j, pts, pptr[r], pptr[r + 1], delta, foreign)
                    ok = not third and (ridge or net <= few)
            if not ok:
                keep[far] = True
                stack[top, 0], stack[top, 1] = i, far
                stack[top + 1, 0], stack[top + 1, 1] = far, j
                top += 2
    return keep


@njit(cache=True)
def points_in_boxes(x, y, order, boxes):  # pragma: no cover - compiled
    """The points inside or on each box, as an STR tree of the boxes queried with the points finds them.

    ``order`` sorts ``x``; ``boxes`` (R, 4) are ``(xmin, ymin, xmax, ymax)``.
    Returns box pointers (R + 1,) and the points of each box in ascending
    index order.  Each box scans its strip of ``x``: no point geometries,
    no tree, the same inclusive comparisons of the same doubles as GEOS's
    envelope test.
    """
    n = len(order)
    xs = x[order]
    ptr = np.zeros(len(boxes) + 1, dtype=np.int64)
    lo = np.searchsorted(xs, boxes[:, 0], side="left")
    hi = np.searchsorted(xs, boxes[:, 2], side="right")
    for r in range(len(boxes)):
        c = 0
        for t in range(lo[r], min(hi[r], n)):
            yv = y[order[t]]
            if boxes[r, 1] <= yv <= boxes[r, 3]:
                c += 1
        ptr[r + 1] = ptr[r] + c
    out = np.empty(ptr[-1], dtype=np.int64)
    for r in range(len(boxes)):
        w = ptr[r]
        for t in range(lo[r], min(hi[r], n)):
            yv = y[order[t]]
            if boxes[r, 1] <= yv <= boxes[r, 3]:
                out[w] = order[t]
                w += 1
        out[ptr[r]:ptr[r + 1]].sort()
    return ptr, out


@njit(cache=True)
def nearest_points(px, py, lab, qx, qy, k, bucket, max_ring=4):  # pragma: no cover - compiled
    """The ``k`` labelled points nearest each query point, nearest first, and where that order is not certain.

    The points are bucketed on a square grid of ``bucket`` (m); each query
    scans rings of buckets outwards until no unscanned point can be nearer
    than its ``k + 1``-th, at most ``max_ring`` rings (a query farther from
    the points is flagged, a k-d tree finds those in logarithmic time).
    Distances are compared squared, as
    ``dx * dx + dy * dy`` (the sum ``cKDTree`` forms in 2D).  A query is
    flagged ``unsure`` where the order could depend on how ties are broken:
    its ``k``-th and ``k + 1``-th distances within a relative 1e-9, or two
    consecutive ones of different labels within it; those are left to
    ``cKDTree.query``.

    Returns
    -------
    idx : ndarray of shape (M, k), int64
    unsure : ndarray of shape (M,), bool
    """
    n, m = len(px), len(qx)
    idx = np.zeros((m, k), dtype=np.int64)
    unsure = np.zeros(m, dtype=np.bool_)
    xmin, ymin = px.min(), py.min()
    ncol = int((px.max() - xmin) / bucket) + 1
    nrow = int((py.max() - ymin) / bucket) + 1
    key = np.empty(n, dtype=np.int64)
    for p in range(n):
        key[p] = int((py[p] - ymin) / bucket) * ncol + int((px[p] - xmin) / bucket)
    order = np.argsort(key, kind="mergesort")
    start = np.zeros(nrow * ncol + 1, dtype=np.int64)
    for p in range(n):
        start[key[p] + 1] += 1
    for b in range(nrow * ncol):
        start[b + 1] += start[b]
    kk = min(k + 1, n)
    bd = np.empty(kk, dtype=np.float64)
    bi = np.empty(kk, dtype=np.int64)
    for q in range(m):
        x, y = qx[q], qy[q]
        cj = int(np.floor((x - xmin) / bucket))
        ci = int(np.floor((y - ymin) / bucket))
        found = 0
        r = 0
        while True:
            for i in range(ci - r, ci + r + 1):
                if i < 0 or i >= nrow:
                    continue
                edge_row = i == ci - r or i == ci + r
                j = cj - r
                while j <= cj + r:
                    if 0 <= j < ncol:
                        b = i * ncol + j
                        for t in range(start[b], start[b + 1]):
                            p = order[t]
                            dx, dy = x - px[p], y - py[p]
                            d = dx * dx + dy * dy
                            if found < kk or d < bd[kk - 1]:
                                insert_sorted(bd, bi, found if found < kk else kk - 1, d, p)
                                if found < kk:
                                    found += 1
                    # inside the ring only its first and last columns are new
                    j += 1 if edge_row or j == cj + r else 2 * r
            # every unscanned point lies outside the scanned square of buckets
            gap = min(x - (xmin + (cj - r) * bucket), xmin + (cj + r + 1) * bucket - x,
                      y - (ymin + (ci - r) * bucket), ymin + (ci + r + 1) * bucket - y)
            done = ci - r <= 0 and cj - r <= 0 and ci + r >= nrow - 1 and cj + r >= ncol - 1
            if done or (found == kk and gap > 0 and bd[kk - 1] * (1 + 1e-9) < gap * gap):
                break
            r += 1
            if r > max_ring:
                break
        if r > max_ring:
            unsure[q] = True
            continue
        for s in range(k):
            idx[q, s] = bi[s]
        if kk > k and bd[k] - bd[k - 1] <= 1e-9 * bd[k]:
            unsure[q] = True
        for s in range(k - 1):
            if bd[s + 1] - bd[s] <= 1e-9 * bd[s + 1] and lab[bi[s]] != lab[bi[s + 1]]:
                unsure[q] = True
    return idx, unsure
