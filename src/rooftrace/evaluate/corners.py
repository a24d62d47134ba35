"""Corners of roof outlines and their one-to-one matching (shape quality).

What counts as a corner
-----------------------
A corner is a vertex where the ring turns, after two kinds of vertices that
do not make the shape have been set aside:

1. **Collinear vertices.** A vertex lying within ``collinear_tolerance``
   (2 cm) of the segment joining its neighbours is dropped, smallest
   deviation first, until none is left: vertices left along a straight wall
   by a union, a digitiser or an outline tracer are not corners.
2. **Vertices along a curve.** A curved wall (a round tower, a bay, a
   facade following a bent street) is stored as many vertices each turning a
   little, in the same sense. Its interior has no corner: the tangent turns
   continuously there. So a run of three or more successive vertices that
   all turn in the same sense, each by at most ``curve_turn`` (25°), is a
   curve and none of its vertices is a corner. Where a curve meets a wall at
   an angle (a semicircular bay on a straight facade) the tangent jumps;
   that vertex turns by more than ``curve_turn`` and is a corner. A circle
   has no corner at all.

Every other vertex is a corner, however small its turn beyond the 2 cm: a
wall that zig-zags (turns alternating in sense) has a corner at every zig,
and a right angle rounded off into two or three facets of 30–45° counts two
or three corners. Both are shape defects this measure is meant to show;
the reference digitised with clean corners has one there.

All rings count (outer rings and holes, every part of a MultiPolygon); only
x and y are used (the two vertices of a vertical step of a 3D outline are
one corner in plan).
"""

from __future__ import annotations

import numpy as np
import shapely
from scipy.optimize import linear_sum_assignment
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from rooftrace.evaluate.geometry import polygonal

__all__ = ["outline_corners", "match_corners", "COLLINEAR_TOLERANCE", "CURVE_TURN"]

#: metres; the tolerance of the collinear-vertex removal
COLLINEAR_TOLERANCE = 0.02
#: degrees; the largest turn of a vertex that can lie on a curve
CURVE_TURN = 25.0

# plan coincidence of successive vertices (a vertical step, a repeated point), metres
_SAME_POINT = 1e-6


def _deviation(xy: np.ndarray) -> np.ndarray:
    """Distance of each vertex of a closed ring (open array) to the segment joining its neighbours."""
    prev, nxt = np.roll(xy, 1, axis=0), np.roll(xy, -1, axis=0)
    d = nxt - prev
    dd = np.einsum("ij,ij->i", d, d)
    t = np.clip(np.einsum("ij,ij->i", xy - prev, d) / np.where(dd > 0, dd, 1.0), 0.0, 1.0)
    return np.linalg.norm(xy - (prev + t[:, None] * d), axis=1)


def _drop_collinear(xy: np.ndarray, tolerance: float) -> np.ndarray:
    """The ring without vertices within ``tolerance`` of their neighbours' segment.

    Each pass drops, smallest deviation first, candidates none of whose
    neighbours is dropped in the same pass (a neighbour's deviation changes
    when a vertex goes), so the result is that of dropping one at a time
    up to the order of equal deviations.
    """
    while len(xy) > 3:
        dev = _deviation(xy)
        cand = np.flatnonzero(dev < tolerance)
        if len(cand) == 0:
            break
        n = len(xy)
        drop = np.zeros(n, dtype=bool)
        blocked = np.zeros(n, dtype=bool)
        for i in cand[np.argsort(dev[cand], kind="stable")]:
            if blocked[i] or n - drop.sum() <= 3:
                continue
            drop[i] = True
            blocked[(i - 1) % n] = blocked[(i + 1) % n] = True
        xy = xy[~drop]
    return xy


def _turns(xy: np.ndarray) -> np.ndarray:
    """Signed turn (degrees, counter-clockwise positive) at each vertex of a closed ring."""
    e_in = xy - np.roll(xy, 1, axis=0)
    e_out = np.roll(xy, -1, axis=0) - xy
    cross = e_in[:, 0] * e_out[:, 1] - e_in[:, 1] * e_out[:, 0]
    return np.degrees(np.arctan2(cross, np.einsum("ij,ij->i", e_in, e_out)))


def _on_curve(turn: np.ndarray, curve_turn: float) -> np.ndarray:
    """Vertices in a cyclic run of >= 3 gentle turns of one sense."""
    n = len(turn)
    # run key: +1 / -1 for a gentle turn to the left / right, 0 for a sharp one
    key = np.where(np.abs(turn) <= curve_turn, np.sign(turn), 0).astype(np.int8)
    starts = np.flatnonzero((key != np.roll(key, 1)) | (key == 0))
    if len(starts) == 0:  # one gentle run all round: a circle, an ellipse
        return np.ones(n, dtype=bool) if key[0] != 0 else np.zeros(n, dtype=bool)
    out = np.zeros(n, dtype=bool)
    ends = np.append(starts[1:], starts[0] + n)
    for s, e in zip(starts, ends):
        if key[s] != 0 and e - s >= 3:
            out[np.arange(s, e) % n] = True
    return out


def _ring_corners(xy: np.ndarray, collinear_tolerance: float, curve_turn: float) -> np.ndarray:
    if len(xy) > 1 and np.all(np.abs(xy[0] - xy[-1]) <= _SAME_POINT):
        xy = xy[:-1]
    if len(xy) > 1:
        step = np.linalg.norm(np.diff(xy, axis=0, append=xy[:1]), axis=1)
        xy = xy[step > _SAME_POINT]
    if len(xy) < 3:
        return np.empty((0, 2))
    xy = _drop_collinear(xy, collinear_tolerance)
    turn = _turns(xy)
    return xy[~_on_curve(turn, curve_turn) & (turn != 0)]


def outline_corners(geom, *, collinear_tolerance: float = COLLINEAR_TOLERANCE,
                    curve_turn: float = CURVE_TURN) -> np.ndarray:
    """The corners of an outline (see the module docstring for the definition).

    Parameters
    ----------
    geom : Polygon, MultiPolygon, a sequence of them (unioned), or None
    collinear_tolerance : float, default 0.02
        A vertex closer than this to the segment joining its neighbours is
        no corner (CRS units, m).
    curve_turn : float, default 25.0
        Largest turn (degrees) of a vertex on a curve: runs of three or more
        successive turns of one sense, each at most this, are curves and
        have no corner.

    Returns
    -------
    ndarray of shape (N, 2) float64
        x, y of the corners, ring by ring in the order of
        ``shapely.get_rings``; empty for None or an empty geometry.

    Examples
    --------
    >>> from shapely import Point, box
    >>> len(outline_corners(box(0, 0, 10, 5)))
    4
    >>> len(outline_corners(Point(0, 0).buffer(5)))  # a circle
    0
    """
    if not collinear_tolerance >= 0:
        raise ValueError(f"collinear_tolerance must be >= 0, not {collinear_tolerance}")
    if not 0 <= curve_turn < 180:
        raise ValueError(f"curve_turn must be in [0, 180) degrees, not {curve_turn}")
    geom = polygonal(geom, "geom")
    if geom is None:
        return np.empty((0, 2))
    rings = shapely.get_rings(shapely.get_parts(geom))
    corners = [_ring_corners(shapely.get_coordinates(r), collinear_tolerance, curve_turn)
               for r in rings if not r.is_empty]
    return np.concatenate(corners) if corners else np.empty((0, 2))


def match_corners(extracted: np.ndarray, reference: np.ndarray, tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """One-to-one matching of corners within ``tolerance``.

    The most pairs closer than ``tolerance``, and among those the smallest
    total distance (an optimal assignment in each connected group of
    corners within reach of each other).

    Parameters
    ----------
    extracted, reference : ndarray of shape (N, 2) and (M, 2)
        Corner positions (CRS units, m).
    tolerance : float
        Largest distance of a matched pair (m).

    Returns
    -------
    pairs : ndarray of shape (K, 2) int64
        Indices (extracted, reference) of the matched pairs, sorted by the
        reference index.
    distance : ndarray of shape (K,) float64
        Their planimetric distances (m).
    """
    if not tolerance > 0:
        raise ValueError(f"tolerance must be > 0, not {tolerance}")
    ne, nr = len(extracted), len(reference)
    if ne == 0 or nr == 0:
        return np.empty((0, 2), dtype=np.int64), np.empty(0)
    near = cKDTree(extracted).query_ball_tree(cKDTree(reference), tolerance)
    ie = np.repeat(np.arange(ne), [len(j) for j in near])
    ir = np.fromiter((j for js in near for j in sorted(js)), dtype=np.int64, count=len(ie))
    if len(ie) == 0:
        return np.empty((0, 2), dtype=np.int64), np.empty(0)
    # groups of corners within reach of each other: extracted 0..ne-1, reference ne..ne+nr-1
    graph = coo_matrix((np.ones(len(ie)), (ie, ne + ir)), shape=(ne + nr, ne + nr))
    _, label = connected_components(graph, directed=False)
    dist = np.linalg.norm(extracted[ie] - reference[ir], axis=1)
    # a pair beyond reach costs more than any set of pairs within it, so the
    # assignment first maximises the number of pairs, then minimises their distance
    big = tolerance * (min(ne, nr) + 1)
    out_e, out_r = [], []
    for g in np.unique(label[ie]):
        sel = label[ie] == g
        ue, e_idx = np.unique(ie[sel], return_inverse=True)
        ur, r_idx = np.unique(ir[sel], return_inverse=True)
        cost = np.full((len(ue), len(ur)), big)
        cost[e_idx, r_idx] = dist[sel]
        rows, cols = linear_sum_assignment(cost)
        ok = cost[rows, cols] <= tolerance
        out_e.append(ue[rows[ok]])
        out_r.append(ur[cols[ok]])
    e, r = np.concatenate(out_e), np.concatenate(out_r)
    order = np.argsort(r, kind="stable")
    pairs = np.column_stack([e[order], r[order]]).astype(np.int64)
    return pairs, np.linalg.norm(extracted[pairs[:, 0]] - reference[pairs[:, 1]], axis=1)

