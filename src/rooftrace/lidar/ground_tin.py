"""A 2D Delaunay TIN with vectorised point location, for the ground filter.

Why not ``scipy.spatial.Delaunay``: the ground filter re-triangulates its
TIN every densification round and locates ~10⁵ candidates in it, then every
point of the cloud in the final one.  Measured on one 1.2 M-point synthetic
scene (96 k candidates, 2-core machine): Qhull takes 0.7 s per
triangulation and ``find_simplex`` first builds the barycentric transforms
(one LAPACK call per facet, 1.9 s more), so the ground stage took 47 s, 75 %
of it in Qhull.  Shewchuk's Triangle (the ``triangle`` package, exact
predicates, divide and conquer) triangulates the same points in 0.07 s.  It
has no point location, so this module adds one: a visibility walk in numba
over Triangle's neighbour table, from the previous query's triangle (the
queries come in a serpentine strip order, so the walks are short).
``startinpy`` (incremental insertion, 0.23 s for the same points, but one
Python call per located point) and scipy's incremental Qhull were measured
too and lose (see docs/design-notes.md, "City scale").

Tiles must equal the whole cloud, so nothing here may depend on vertex or
triangle numbering, which differs between a tile and the whole:

* the side of an edge a query lies on is computed with the edge's end points
  in lexicographic (x, y) order, so the two triangles sharing an edge agree
  on it exactly and a query lies in one triangle only;
* a query exactly on an edge goes to the triangle left of the edge (in that
  order), whichever triangle the walk came from;
* each triangle is listed starting from its lexicographically smallest
  vertex, so a facet's plane is computed from the same vertex order.
"""

from __future__ import annotations

import numpy as np
import triangle as _triangle
from numba import njit

from rooftrace.errors import GeometryError
from rooftrace.lidar._kernels import rotate_to_smallest, sort_by_bucket

__all__ = ["triangulate", "locate", "serpentine_order"]


def serpentine_order(xy: np.ndarray, width: float, start: float | None = None) -> np.ndarray:
    """Serpentine strip order: consecutive points are neighbours, so walks between them are short.

    Parameters
    ----------
    xy : ndarray of shape (N, 2), float64
        Positions (m).
    width : float
        Strip width (m), strips run along y.
    start : float, optional
        x (m) where the first strip starts (default: the lowest x); a fixed
        start gives a tile's points the same relative order as in the whole
        cloud.

    Returns
    -------
    ndarray of shape (N,), int64
        The permutation.
    """
    strip = np.floor((xy[:, 0] - (xy[:, 0].min() if start is None else start)) / width).astype(np.int64)
    y = np.where(strip % 2 == 0, xy[:, 1], -xy[:, 1])
    return sort_by_bucket(y, strip)


def triangulate(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Delaunay triangulation of distinct points with Shewchuk's Triangle.

    Parameters
    ----------
    xy : ndarray of shape (M, 2), float64
        Vertices (m), distinct, in a local frame.

    Returns
    -------
    order : ndarray of shape (M,), int64
        Lexicographic (x, y) order of the vertices; the other two arrays
        index ``xy[order]``.
    triangles : ndarray of shape (T, 3), int64
        Counter-clockwise triangles, each starting at its smallest vertex.
    neighbours : ndarray of shape (T, 3), int64
        ``neighbours[t, k]``: the triangle across the edge opposite vertex
        ``k`` of ``t``, -1 on the convex hull.

    Raises
    ------
    GeometryError
        Fewer than 3 points, or all of them on one line.

    Examples
    --------
    >>> order, tris, nbrs = triangulate(np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]]))
    >>> len(tris), sorted(nbrs.ravel().tolist())
    (2, [-1, -1, -1, -1, 0, 1])
    """
    xy = np.asarray(xy, np.float64)
    order = np.lexsort((xy[:, 1], xy[:, 0]))
    pts = np.ascontiguousarray(xy[order])
    out = _triangle.triangulate({"vertices": pts}, "Qzn") if len(pts) >= 3 else {}
    if "triangles" not in out or len(out["triangles"]) == 0:
        raise GeometryError(f"ground TIN: cannot triangulate {len(xy)} points (fewer than 3, or collinear)")
    # rotate each triangle (and its neighbours with it) to start at its smallest vertex: keeps it CCW
    tris, nbrs = rotate_to_smallest(np.ascontiguousarray(out["triangles"]), np.ascontiguousarray(out["neighbors"]))
    return order, tris, nbrs


def locate(pts: np.ndarray, triangles: np.ndarray, neighbours: np.ndarray, query: np.ndarray) -> np.ndarray:
    """Triangle of a TIN holding each query point.

    Parameters
    ----------
    pts : ndarray of shape (M, 2), float64
        TIN vertices in lexicographic (x, y) order (``xy[order]`` of
        :func:`triangulate`).
    triangles, neighbours : ndarray of shape (T, 3), int64
        From :func:`triangulate`.
    query : ndarray of shape (N, 2), float64
        Query positions; faster in a spatially coherent order
        (:func:`serpentine_order`).

    Returns
    -------
    ndarray of shape (N,), int64
        Triangle index, -1 outside the convex hull (or for a non-finite
        query).  A query on an edge gets the triangle left of the edge
        directed from its smaller to its larger vertex.

    Examples
    --------
    >>> xy = np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 2.0], [2.0, 2.0]])
    >>> order, tris, nbrs = triangulate(xy)
    >>> t = locate(xy[order], tris, nbrs, np.array([[0.5, 0.5], [3.0, 3.0]]))
    >>> bool(t[0] >= 0), int(t[1])
    (True, -1)
    """
    return _walk(np.ascontiguousarray(pts, np.float64), np.ascontiguousarray(triangles, np.int64),
                 np.ascontiguousarray(neighbours, np.int64), np.ascontiguousarray(query, np.float64))


@njit(cache=True)
def _side(pts, a, b, px, py):  # pragma: no cover - compiled
    """Orientation of p against edge (a, b), computed from the smaller vertex to the larger one.

    Positive when p is left of a → b.  Computing it in one direction only makes
    the two triangles of an edge agree exactly on the sign.
    """
    lo, hi = (a, b) if a < b else (b, a)
    ax, ay = pts[lo, 0], pts[lo, 1]
    d = (pts[hi, 0] - ax) * (py - ay) - (pts[hi, 1] - ay) * (px - ax)
    return d if a < b else -d


@njit(cache=True)
def _inside(pts, tris, t, px, py):  # pragma: no cover - compiled
    for e in range(3):
        if _side(pts, tris[t, (e + 1) % 3], tris[t, (e + 2) % 3], px, py) < 0.0:
            return False
    return True


@njit(cache=True)
def _walk(pts, tris, nbrs, query):  # pragma: no cover - compiled
    n = query.shape[0]
    nt = tris.shape[0]
    out = np.full(n, -1, np.int64)
    t = 0
    for k in range(n):
        px, py = query[k, 0], query[k, 1]
        if not (np.isfinite(px) and np.isfinite(py)):
            continue
        found = -1
        steps = 0
        # visibility walk: cross any edge that has p strictly on its far side;
        # it ends on a Delaunay triangulation (Edelsbrunner 1990), the step
        # cap only guards against rounding near degenerate configurations
        while steps <= nt:
            moved = False
            for e in range(3):
                a, b = tris[t, (e + 1) % 3], tris[t, (e + 2) % 3]
                if _side(pts, a, b, px, py) < 0.0:
                    if nbrs[t, e] < 0:
                        found = -2  # beyond a hull edge: outside the hull
                    else:
                        t = nbrs[t, e]
                        moved = True
                    break
            if found == -2 or not moved:
                break
            steps += 1
        if found == -2:
            continue
        if steps > nt:  # pragma: no cover - rounding fallback
            t = -1
            for s in range(nt):
                if _inside(pts, tris, s, px, py):
                    t = s
                    break
            if t < 0:
                t = 0
                continue
        # on an edge: the triangle left of the edge's canonical direction
        for e in range(3):
            a, b = tris[t, (e + 1) % 3], tris[t, (e + 2) % 3]
            if nbrs[t, e] >= 0 and _side(pts, a, b, px, py) == 0.0 and a > b:
                t = nbrs[t, e]
                break
        out[k] = t
    return out
