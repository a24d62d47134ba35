"""Delaunay edges and the spacings behind the three alpha strategies (thesis §4.2).

S1 takes the cloud's mean spacing s_avg (from the detection, or the median
of :func:`building_mean_spacing` over the buildings), S2 the
building's mean Delaunay edge length without the long edges
(:func:`building_alpha`, eq. 4.4), S3 a spacing per point from the edges
inside a 3 m circle (:func:`point_spacing`, eq. 4.5).  S3 is our own numba
kernel: no library gives per-point means over the Delaunay edges wholly inside
a ball, and listing the ball pairs with a KD-tree took gigabytes on AHN roofs.
"""

from __future__ import annotations

import numpy as np
import triangle as _triangle
from numba import njit
from scipy.spatial import Delaunay, QhullError

from rooftrace.errors import GeometryError

__all__ = ["delaunay_edges", "delaunay_mesh", "PlanMesh", "building_mean_spacing", "building_alpha", "point_spacing"]


def delaunay_edges(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unique edges of the 2D Delaunay triangulation.

    Parameters
    ----------
    xy : ndarray of shape (N, 2) float64
        Planimetric coordinates, without duplicates.

    Returns
    -------
    edges : ndarray of shape (E, 2) int64
        Point indices, ``edges[:, 0] < edges[:, 1]``.
    lengths : ndarray of shape (E,) float64
        Edge lengths in the units of ``xy``.

    Raises
    ------
    GeometryError
        Fewer than 3 points, or all collinear.
    """
    edges, lengths, _, _ = delaunay_mesh(xy)
    return edges, lengths


def delaunay_mesh(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The 2D Delaunay triangulation: unique edges (as :func:`delaunay_edges`) and triangles.

    Returns
    -------
    edges, lengths
        As :func:`delaunay_edges`.
    triangles : ndarray of shape (T, 3) int64
        Point indices, counter-clockwise.
    neighbours : ndarray of shape (T, 3) int64
        The triangle across the edge opposite each corner, -1 on the convex hull.

    Raises
    ------
    GeometryError
        Fewer than 3 points, or all collinear.
    """
    xy = np.asarray(xy, dtype=np.float64)
    if len(xy) < 3:
        raise GeometryError("too_few_points")
    mesh = _certified_triangle_mesh(xy)
    if mesh is None:
        triangles, neighbours = _qhull_mesh(xy)
    else:
        triangles, neighbours = mesh
    # each edge once: from the triangle with the lower index, or the only one (hull); the edge
    # between two corners is opposite the third, whose neighbour shares it
    own = np.arange(len(neighbours))[:, None]
    first = (neighbours < 0) | (neighbours > own)
    e = np.concatenate([triangles[first[:, 2]][:, [0, 1]], triangles[first[:, 0]][:, [1, 2]],
                        triangles[first[:, 1]][:, [2, 0]]])
    e = np.sort(e, axis=1).astype(np.int64)
    n = np.int64(len(xy))
    key = np.sort(e[:, 0] * n + e[:, 1])  # 1D keys: much faster than sorting rows
    if len(key) > 1 and not (key[1:] > key[:-1]).all():
        key = np.unique(key)  # a degenerate mesh that lists an edge twice
    e = np.column_stack([key // n, key % n])
    lengths = np.linalg.norm(xy[e[:, 1]] - xy[e[:, 0]], axis=1)
    return e, lengths, triangles, neighbours


def _qhull_mesh(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Qhull's triangles (counter-clockwise) and their neighbours."""
    try:
        tri = Delaunay(xy)
    except QhullError:
        raise GeometryError("collinear") from None
    if len(tri.simplices) == 0:
        raise GeometryError("collinear")
    triangles = tri.simplices.astype(np.int64)
    neighbours = tri.neighbors.astype(np.int64)
    a, b, c = xy[triangles[:, 0]], xy[triangles[:, 1]], xy[triangles[:, 2]]
    cw = (b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0] < 0
    # swapping corners 1 and 2 swaps the edges opposite them, so the neighbours swap too
    triangles[cw] = triangles[cw][:, [0, 2, 1]]
    neighbours[cw] = neighbours[cw][:, [0, 2, 1]]
    return triangles, neighbours


#: how far (in units of Qhull's round-off, :func:`_certified`) every quadrilateral of Triangle's mesh must be
#: from four points on a circle for Qhull to be sure to give the same triangles.  Building meshes shifted
#: by 10-400 km (where Qhull's round-off is large) differed from Triangle's up to about 11 such units and
#: never beyond; the buildings of Delft in the outline's frame are 19,000 or more units from a tie.
_QHULL_MARGIN = 1000.0


def _certified_triangle_mesh(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Shewchuk's Triangle's Delaunay mesh when it is certainly the one Qhull gives; None otherwise.

    Triangle (exact predicates, divide and conquer) triangulates a building
    five to ten times faster than Qhull.  Where no four points are nearly on
    one circle the Delaunay triangulation is unique, and Qhull finds it too;
    where some are (grids, ties, points closer than Qhull's round-off) Qhull
    may choose another diagonal or leave a point out, so the caller asks
    Qhull.  Each triangle's corners come in Triangle's order, not Qhull's,
    which only the order of sums over a triangle's corners sees.
    """
    if not _distinct_off_one_line(xy):
        return None  # Triangle crashes on some such sets (18 copies of one point); Qhull says why
    out = _triangle.triangulate({"vertices": np.ascontiguousarray(xy)}, "Qzn")
    if "triangles" not in out or len(out["triangles"]) == 0:
        return None
    triangles = np.ascontiguousarray(out["triangles"], dtype=np.int64)
    neighbours = np.ascontiguousarray(out["neighbors"], dtype=np.int64)
    if not (np.bincount(triangles.ravel(), minlength=len(xy)) > 0).all():
        return None  # a point left out (a duplicate)
    extent2 = float(np.abs(xy).max()) ** 2
    if not _certified(xy, triangles, neighbours, extent2, _QHULL_MARGIN):
        return None
    return triangles, neighbours


def _distinct_off_one_line(xy: np.ndarray) -> bool:
    """No point twice, and some point off the line through the first and the farthest from it."""
    ordered = xy[np.lexsort((xy[:, 1], xy[:, 0]))]
    if (ordered[1:] == ordered[:-1]).all(axis=1).any():
        return False
    d = xy - xy[0]
    far = d[np.argmax(np.einsum("ij,ij->i", d, d))]
    return bool((far[0] * d[:, 1] - far[1] * d[:, 0] != 0).any())


@njit(cache=True)
def _certified(xy, triangles, neighbours, extent2, margin):  # pragma: no cover - compiled
    # Every edge between two triangles: the far corner d of the neighbour must lie outside the
    # triangle's circumcircle by more than ``margin`` times Qhull's round-off.  Qhull lifts the points
    # to (x, y, x² + y²), so its error in the in-circle test, relative to the test's magnitude (the
    # permanent), is about eps * extent² / l², l the quadrilateral's size.  A triangle's corners must
    # be off one line by as much (a sliver on the hull).
    eps = 2.220446049250313e-16
    for t in range(len(triangles)):
        a0, a1, a2 = triangles[t, 0], triangles[t, 1], triangles[t, 2]
        ax, ay = xy[a0, 0], xy[a0, 1]
        bx, by = xy[a1, 0], xy[a1, 1]
        cx, cy = xy[a2, 0], xy[a2, 1]
        cross = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
        ab2 = (bx - ax) ** 2 + (by - ay) ** 2
        ac2 = (cx - ax) ** 2 + (cy - ay) ** 2
        if not cross > margin * eps * extent2 * np.sqrt(ab2 * ac2) / max(ab2, ac2):
            return False
        for k in range(3):
            u = neighbours[t, k]
            if u < t:  # the hull, or an edge met from the other side already
                continue
            d = -1
            for kk in range(3):
                if neighbours[u, kk] == t:
                    d = triangles[u, kk]
            if d < 0:
                return False
            px, py = xy[d, 0], xy[d, 1]
            adx, ady, bdx, bdy, cdx, cdy = ax - px, ay - py, bx - px, by - py, cx - px, cy - py
            al, bl, cl = adx * adx + ady * ady, bdx * bdx + bdy * bdy, cdx * cdx + cdy * cdy
            det = (al * (bdx * cdy - cdx * bdy) + bl * (cdx * ady - adx * cdy) + cl * (adx * bdy - bdx * ady))
            permanent = (al * (abs(bdx * cdy) + abs(cdx * bdy)) + bl * (abs(cdx * ady) + abs(adx * cdy))
                         + cl * (abs(adx * bdy) + abs(bdx * ady)))
            if not -det > margin * eps * extent2 / ((al + bl + cl) / 3.0) * permanent:
                return False
    return True


class PlanMesh:
    """One building's Delaunay mesh in plan and its points' spacings, for every alpha shape traced from it.

    A building's alpha shape is traced again with a larger alpha, another
    strategy, or without the seen-through cut (:func:`rooftrace.contour.outline.trace_outline`);
    the mesh and the ps_avg (a fifth of the outline stage on Delft) depend on
    the points alone, so they are computed once.

    Parameters
    ----------
    xy : ndarray of shape (N, 2) float64
        Planimetric coordinates (m), without duplicates.

    Attributes
    ----------
    xy, edges, lengths, triangles, neighbours
        As :func:`delaunay_mesh` returns them.

    Raises
    ------
    GeometryError
        As :func:`delaunay_mesh`.
    """

    def __init__(self, xy: np.ndarray):
        self.xy = np.asarray(xy, dtype=np.float64)
        self.edges, self.lengths, self.triangles, self.neighbours = delaunay_mesh(self.xy)
        self._spacing: dict[float, np.ndarray] = {}

    def point_spacing(self, radius: float) -> np.ndarray:
        """ps_avg of every point for a circle of ``radius`` metres (:func:`point_spacing`); read-only."""
        if radius not in self._spacing:
            ps = point_spacing(self.xy, self.edges, self.lengths, radius)
            ps.flags.writeable = False  # shared by every shape traced from the mesh
            self._spacing[radius] = ps
        return self._spacing[radius]


def building_mean_spacing(xy: np.ndarray) -> float:
    """Mean spacing of one building's points: the mean edge length of their whole Delaunay triangulation.

    The thesis' s_avg (§6.2) for a few thousand points: every edge, long
    edges (> mean + 3 std) removed.  A whole cloud's s_avg is
    :func:`rooftrace.lidar.spacing.mean_spacing`, which samples blocks so
    that its cost stays bounded.

    Parameters
    ----------
    xy : ndarray of shape (N, 2), float64
        Planimetric coordinates (m); duplicates are merged.

    Returns
    -------
    float
        Metres.

    Raises
    ------
    GeometryError
        Fewer than 3 distinct points, or all on one line.

    Examples
    --------
    >>> g = np.stack(np.meshgrid(np.arange(5.0), np.arange(5.0)), -1).reshape(-1, 2)
    >>> round(building_mean_spacing(g), 3)
    1.118
    """
    _, lengths = delaunay_edges(np.unique(np.asarray(xy, dtype=np.float64)[:, :2], axis=0))
    return building_alpha(lengths)


def building_alpha(lengths: np.ndarray, sigma: float = 3.0) -> float:
    """S2 alpha: mean edge length after dropping edges longer than mean + ``sigma`` * std (eq. 4.4)."""
    lengths = np.asarray(lengths, dtype=np.float64)
    keep = lengths <= lengths.mean() + sigma * lengths.std()
    return float(lengths[keep].mean())


def point_spacing(xy: np.ndarray, edges: np.ndarray, lengths: np.ndarray, radius: float = 3.0) -> np.ndarray:
    """ps_avg per point: mean length of the Delaunay edges wholly inside a circle of ``radius`` (eq. 4.5).

    An edge lies inside the (convex) circle when both its end points do.
    Points whose circle holds no whole edge get the mean of the edges they
    touch.
    """
    n = len(xy)
    # the balls are scanned on a grid of radius-sized cells instead of listing every pair: at AHN
    # densities a 3 m ball holds ~400 points, and the pair list of a 60 000-point roof took 2 GB
    cell = np.floor((xy - xy.min(axis=0)) / radius).astype(np.int64)
    nx, ny = int(cell[:, 0].max()) + 1, int(cell[:, 1].max()) + 1
    if nx * ny > 8 * n + 4096:
        # a few points kilometres apart (issue 10 fuzz: a dense grid of 65 GB): rank the occupied
        # columns and rows instead; neighbouring ranks are a superset of the neighbouring cells,
        # and the exact distance test below keeps only the ball
        cell = np.column_stack([np.unique(cell[:, k], return_inverse=True)[1].ravel() for k in (0, 1)])
        nx, ny = int(cell[:, 0].max()) + 1, int(cell[:, 1].max()) + 1
    key = cell[:, 0] * ny + cell[:, 1]
    order = np.argsort(key, kind="stable")
    cell_ptr = np.zeros(nx * ny + 1, dtype=np.int64)
    np.cumsum(np.bincount(key, minlength=nx * ny), out=cell_ptr[1:])
    # the kernel works on the points in cell order (a cell's points are
    # contiguous in memory, not scattered over the building); it visits them
    # in the same order as before, so every sum is the same.  Each edge is
    # stored once, at its lower end point, with the other end's coordinates
    # and its length beside it (read in order, not gathered)
    rank = np.empty(n, dtype=np.int64)
    rank[order] = np.arange(n)
    adj_ptr, adj_edge = _csr(rank[edges[:, 0]], np.arange(len(edges)), n)
    sorted_xy = np.ascontiguousarray(xy[order], dtype=np.float64)
    far_end = sorted_xy[rank[edges[adj_edge, 1]]]
    ps = np.empty(n)
    ps[order] = _ps_avg(sorted_xy, float(radius), np.ascontiguousarray(cell[order]), nx, ny, cell_ptr, adj_ptr,
                        np.ascontiguousarray(far_end[:, 0]), np.ascontiguousarray(far_end[:, 1]),
                        np.ascontiguousarray(lengths[adj_edge], dtype=np.float64))
    bad = ~np.isfinite(ps)
    if bad.any():
        touch = np.bincount(edges.ravel(), np.repeat(lengths, 2), n) / np.maximum(np.bincount(edges.ravel(), minlength=n), 1)
        ps[bad] = touch[bad]
    return ps


def _csr(rows: np.ndarray, cols: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    ptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(rows, minlength=n), out=ptr[1:])
    return ptr, _bucket(rows.astype(np.int64), cols.astype(np.int64), ptr)


@njit(cache=True)
def _bucket(rows, cols, ptr):  # pragma: no cover - compiled
    # counting sort of cols by rows (argsort of 1e5-1e6 pairs dominated S3)
    fill = ptr[:-1].copy()
    out = np.empty(len(cols), dtype=np.int64)
    for k in range(len(rows)):
        r = rows[k]
        out[fill[r]] = cols[k]
        fill[r] += 1
    return out


@njit(cache=True)
def _lengths_in_ball(i, xy, r2, cell, nx, ny, cell_ptr, adj_ptr, far_x, far_y, adj_length, ball,
                     out):  # pragma: no cover
    # the lengths of the edges wholly inside point i's ball, in the order the sum takes them: the
    # ball's points by cell (cx, then cy) and within a cell by rank, each point's edges in turn.  The
    # three cells of a column are consecutive in rank, so a column is one range.  Both tests write
    # unconditionally and advance the count by the test (no branch to mispredict).
    xi, yi = xy[i, 0], xy[i, 1]
    m = 0
    lo, hi = max(cell[i, 1] - 1, 0), min(cell[i, 1] + 2, ny)
    for cx in range(max(cell[i, 0] - 1, 0), min(cell[i, 0] + 2, nx)):
        for j in range(cell_ptr[cx * ny + lo], cell_ptr[cx * ny + hi]):
            dx = xy[j, 0] - xi
            dy = xy[j, 1] - yi
            ball[m] = j
            m += dx * dx + dy * dy <= r2
    count = 0
    for k in range(m):
        j = ball[k]
        for q in range(adj_ptr[j], adj_ptr[j + 1]):
            ex = far_x[q] - xi
            ey = far_y[q] - yi
            out[count] = adj_length[q]
            count += ex * ex + ey * ey <= r2
    return count


@njit(cache=True)
def _ps_avg(xy, radius, cell, nx, ny, cell_ptr, adj_ptr, far_x, far_y, adj_length):  # pragma: no cover
    # points in cell order (cell_ptr indexes xy directly).  Each point's mean
    # is one sequential sum, as it always was (another order changes ps_avg by
    # 1e-15, which flipped a building's outline); four points' sums run side
    # by side so that their additions overlap instead of waiting on each other
    n = len(xy)
    r2 = radius * radius
    out = np.empty(n, dtype=np.float64)
    ball = np.empty(n, dtype=np.int64)
    ne = len(adj_length)
    v0, v1, v2, v3 = np.empty(ne), np.empty(ne), np.empty(ne), np.empty(ne)
    for i0 in range(0, n - 3, 4):
        c0 = _lengths_in_ball(i0, xy, r2, cell, nx, ny, cell_ptr, adj_ptr, far_x, far_y, adj_length, ball, v0)
        c1 = _lengths_in_ball(i0 + 1, xy, r2, cell, nx, ny, cell_ptr, adj_ptr, far_x, far_y, adj_length, ball, v1)
        c2 = _lengths_in_ball(i0 + 2, xy, r2, cell, nx, ny, cell_ptr, adj_ptr, far_x, far_y, adj_length, ball, v2)
        c3 = _lengths_in_ball(i0 + 3, xy, r2, cell, nx, ny, cell_ptr, adj_ptr, far_x, far_y, adj_length, ball, v3)
        t0, t1, t2, t3 = 0.0, 0.0, 0.0, 0.0
        both = min(min(c0, c1), min(c2, c3))
        for k in range(both):
            t0 += v0[k]
            t1 += v1[k]
            t2 += v2[k]
            t3 += v3[k]
        for k in range(both, c0):
            t0 += v0[k]
        for k in range(both, c1):
            t1 += v1[k]
        for k in range(both, c2):
            t2 += v2[k]
        for k in range(both, c3):
            t3 += v3[k]
        out[i0] = t0 / c0 if c0 > 0 else np.nan
        out[i0 + 1] = t1 / c1 if c1 > 0 else np.nan
        out[i0 + 2] = t2 / c2 if c2 > 0 else np.nan
        out[i0 + 3] = t3 / c3 if c3 > 0 else np.nan
    for i in range(n - n % 4, n):
        c0 = _lengths_in_ball(i, xy, r2, cell, nx, ny, cell_ptr, adj_ptr, far_x, far_y, adj_length, ball, v0)
        t0 = 0.0
        for k in range(c0):
            t0 += v0[k]
        out[i] = t0 / c0 if c0 > 0 else np.nan
    return out
