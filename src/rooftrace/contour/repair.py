"""Repair of invalid outline polygons (self-touching or crossing rings after regularisation).

``shapely.make_valid`` splits a ring pinched at a point into its wings; a
roof is one feature, so the wings are joined again by narrow bridges where
they touch instead of keeping only the largest.
"""

from __future__ import annotations

import numpy as np
import shapely
from scipy.spatial import cKDTree

__all__ = ["make_valid_outline"]


def make_valid_outline(polygon, rings: list[np.ndarray], corners: list[np.ndarray]):
    """Repair an invalid outline polygon and carry its corner indices over.

    Parameters
    ----------
    polygon : shapely.Polygon with Z
        Built from ``rings`` (outer first).
    rings : list of ndarray of shape (V, 3)
    corners : list of ndarray of int
        Corner indices per ring.

    Returns
    -------
    polygon : shapely.Polygon or None
        Valid, oriented; None when nothing polygonal is left.
    corners : list of ndarray of int
        Corner indices per ring of the result (vertices that were corners).
    """
    fixed = shapely.make_valid(polygon)
    parts = [g for g in getattr(fixed, "geoms", [fixed]) if isinstance(g, shapely.Polygon) and not g.is_empty]
    if not parts:
        return None, []
    best = max(parts, key=lambda g: g.area)
    if len(parts) > 1 and best.area < 0.95 * sum(g.area for g in parts):
        # a ring pinched at a point (two wings of one roof touching): join the wings rather than drop one
        best = _join_parts(parts, rings) or best
    best = shapely.orient_polygons(best) if hasattr(shapely, "orient_polygons") \
        else shapely.geometry.polygon.orient(best)
    corner_xy = np.concatenate([r[c, :2] for r, c in zip(rings, corners)]) if rings else np.empty((0, 2))
    new_corners = []
    for ring in [best.exterior, *best.interiors]:
        xy = np.asarray(ring.coords)[:-1, :2]
        hit = np.min(np.linalg.norm(xy[:, None] - corner_xy[None], axis=2), axis=1) < 1e-6
        new_corners.append(np.flatnonzero(hit))
    return best, new_corners


def _join_parts(parts: list, rings: list[np.ndarray], width: float = 0.1):
    """The parts of a pinched ring joined by bridges ``width`` metres wide where they touch, Z from the ring."""
    flat = [shapely.force_2d(p) for p in parts if p.area > 1e-6]
    grown = [p.buffer(width) for p in flat]
    bridges = [grown[a].intersection(grown[b]) for a in range(len(grown)) for b in range(a + 1, len(grown))]
    joined = shapely.union_all(flat + bridges)
    if not isinstance(joined, shapely.Polygon) or joined.is_empty:
        return None
    xyz = np.concatenate(rings)
    tree = cKDTree(xyz[:, :2])

    def lift(ring):
        xy = np.asarray(ring.coords)[:, :2]
        return np.column_stack([xy, xyz[tree.query(xy)[1], 2]])

    return shapely.Polygon(lift(joined.exterior), [lift(h) for h in joined.interiors])
