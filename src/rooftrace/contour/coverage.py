"""How much of a building's points its outline covers: the outline stage's invariant.

An outline traced from a building's points must hold them: a point lies
inside the polygon (holes excluded) or within the local alpha of its
boundary, where the alpha shape may have cut in between points.  An outline
that covers much less has lost part of the building (a ring dropped, the
shape fallen apart) and must not pass as ``ok``.
"""

from __future__ import annotations

import numpy as np
import shapely

__all__ = ["outline_coverage", "MIN_COVERAGE"]

#: share of a building's points its outline must cover (the rest: isolated points, noise)
MIN_COVERAGE = 0.99


def outline_coverage(polygon, xy: np.ndarray, tolerance: float | np.ndarray = 0.0) -> float:
    """Share of points inside ``polygon`` (or on its boundary) or within ``tolerance`` of it.

    Parameters
    ----------
    polygon : shapely.Polygon or MultiPolygon or None
        The outline (Z ignored), holes excluded from it.
    xy : ndarray of shape (N, 2) or (N, 3) float64
        The building's points, metres (only x and y are used).
    tolerance : float or ndarray of shape (N,)
        Distance (m) a point may lie outside, per point or for all: the
        local alpha radius.

    Returns
    -------
    float
        In [0, 1]; 1 for no points, 0 without a polygon.

    Examples
    --------
    >>> import shapely
    >>> square = shapely.box(0, 0, 10, 10)
    >>> xy = np.array([[5.0, 5.0], [10.3, 5.0], [12.0, 5.0], [-0.1, -0.1]])
    >>> outline_coverage(square, xy), outline_coverage(square, xy, 0.5)
    (0.25, 0.75)
    """
    xy = np.asarray(xy, dtype=np.float64)
    if len(xy) == 0:
        return 1.0
    if polygon is None or polygon.is_empty:
        return 0.0
    flat = shapely.force_2d(polygon)
    shapely.prepare(flat)
    inside = shapely.intersects_xy(flat, xy[:, 0], xy[:, 1])  # the boundary counts: alpha-shape vertices lie on it
    tolerance = np.broadcast_to(np.asarray(tolerance, dtype=np.float64), (len(xy),))
    out = np.flatnonzero(~inside & (tolerance > 0))
    if len(out):
        # only the points outside are measured; most of a building is inside
        near = shapely.dwithin(flat, shapely.points(xy[out, 0], xy[out, 1]), tolerance[out])
        inside[out[near]] = True
    return float(inside.mean())
