"""Corner measures of an outline against a reference polygon (number, completeness, correctness, offset).

Corners are the vertices left after removing collinear ones within 2 cm
(``shapely.simplify``), on the outer ring and the holes.
"""

from __future__ import annotations

import numpy as np
import shapely
from scipy.spatial import cKDTree

__all__ = ["corner_points", "corner_scores"]


def corner_points(polygon, tolerance: float = 0.02) -> np.ndarray:
    """(K, 2) corners of a polygon's rings after dropping vertices within ``tolerance`` m of a straight line."""
    if polygon is None or polygon.is_empty:
        return np.zeros((0, 2))
    simple = shapely.simplify(shapely.force_2d(polygon), tolerance)
    parts = getattr(simple, "geoms", [simple])
    rings = [r for p in parts for r in (p.exterior, *p.interiors)]
    return np.concatenate([np.asarray(r.coords)[:-1, :2] for r in rings]) if rings else np.zeros((0, 2))


def corner_scores(polygon, reference, distance: float = 0.5) -> dict:
    """Corner count ratio, completeness and correctness within ``distance`` m, mean offset of matched corners."""
    mine, ref = corner_points(polygon), corner_points(reference)
    if len(mine) == 0 or len(ref) == 0:
        return dict(ratio=np.nan, completeness=0.0, correctness=0.0, offset=np.nan, n=len(mine), n_ref=len(ref))
    d_ref = cKDTree(mine).query(ref)[0]
    d_mine = cKDTree(ref).query(mine)[0]
    hit = d_ref <= distance
    return dict(ratio=len(mine) / len(ref), completeness=float(hit.mean()), correctness=float((d_mine <= distance).mean()),
                offset=float(d_ref[hit].mean()) if hit.any() else np.nan, n=len(mine), n_ref=len(ref))
