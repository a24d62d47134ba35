"""Where the roof edge lies: beyond the last roof point, by at most one sampling step (beyond the thesis).

A boundary traced through the outermost roof points lies inside the true
edge by the depth of those points.  The edge cannot lie farther beyond the
last roof point than one sampling step across it (there would be another
roof point), nor beyond the first point that is not roof (ground, trees,
other buildings) straight out from it.  So the edge lies in
``[0, min(gap, step)]`` beyond each boundary point, and the estimate is the
middle of that interval, the median over a segment's points.

The first non-roof point alone is not enough: airborne LiDAR leaves the
ground beside a wall in the wall's scan shadow, so that point is often
metres out, and halfway to it overshot the edge (by about 4 cm on the
simulator's scenes, with their occlusion, at 12 pts/m²;
docs/design-notes.md, "Roof outlines").  The step across the edge is
``2 * fallback`` spacings, so that without any non-roof point near the
estimate is the ``fallback`` share of the spacing that is used when no
non-roof points are known at all.

A boundary point that is a point of the building's wall (below its roof,
lifted to it by :func:`rooftrace.contour.surface.outline_points`) lies on
the edge itself: a wall under an overhang lies inside the roof's outline,
so a wall point on the boundary is one flush with the edge (a flat roof with
a parapet, a gable end), or something lower at its foot.  Its interval is
``[0, 0]``.  Without this rule the estimate put flat roofs of Delft 0.2 m
beyond the BGT wall line and the simulator's outlines 1.4 cm outside on
average (docs/design-notes.md, "Wall points mark the edge").
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["EdgeContext", "edge_shift"]

#: neighbours looked at per boundary point
_K = 12
#: share of a segment's points that must see a non-roof point within one step for the shift to count as measured
_MIN_SHARE = 0.3


class EdgeContext:
    """The points around a building that are not its roof, for :func:`edge_shift`.

    Parameters
    ----------
    xy : ndarray of shape (C, 2) float64 or None
        Plan coordinates, metres, in the frame of the ring points.
    walls : ndarray of shape (W, 2) float64, optional
        Plan coordinates of the building's own points that lie below its
        roof (walls, points under eaves), in the same frame; a boundary point
        among them is on the edge.
    """

    def __init__(self, xy: np.ndarray | None, walls: np.ndarray | None = None):
        xy = None if xy is None else np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        self.xy = xy if xy is not None and len(xy) else None
        self.tree = cKDTree(self.xy) if self.xy is not None else None
        walls = None if walls is None else np.asarray(walls, dtype=np.float64).reshape(-1, 2)
        self.walls = cKDTree(walls) if walls is not None and len(walls) else None

    def on_wall(self, xy: np.ndarray) -> np.ndarray:
        """Which of ``xy`` (boundary points, metres) are the building's own points below its roof."""
        if self.walls is None:
            return np.zeros(len(xy), bool)
        return np.isfinite(self.walls.query(xy, distance_upper_bound=1e-9)[0])


def edge_shift(xy: np.ndarray, residual: np.ndarray, normal: np.ndarray, spacing: float,
               context: EdgeContext | None, fallback: float) -> tuple[float, bool]:
    """Outward shift (metres) that takes a fitted boundary to the roof edge.

    Parameters
    ----------
    xy : ndarray of shape (n, 2) float64
        The boundary points of one segment.
    residual : ndarray of shape (n,) float64
        Their signed distances to the fitted segment along ``normal`` (positive outwards), metres.
    normal : ndarray of shape (n, 2) or (2,) float64
        Unit outward normal(s) of the segment at the points.
    spacing : float
        Local mean point spacing, metres.
    context : EdgeContext or None
        Points that are not this roof, and the building's wall points.
    fallback : float
        Half the sampling step across the edge, in spacings: the depth of the
        outermost roof points when no non-roof point bounds it, and the
        shift when ``context`` holds no points at all.

    Returns
    -------
    shift : float
        Metres, positive outwards.
    measured : bool
        True when at least 30 % of the segment's points (and 3) see a
        non-roof point closer than one step, so that the shift comes from
        the context points.

    Examples
    --------
    A wall along y = 0, the roof at y > 0, 0.5 m spacing; ground points 0.6 m
    out bound the edge (half of 0.4 m: the step, 2 x 0.4 x 0.5 m, is nearer);
    ground 0.2 m out halves that:

    >>> xy = np.column_stack([np.arange(0, 10, 0.5), np.zeros(20)])
    >>> ground = xy - [0, 0.6]
    >>> edge_shift(xy, np.zeros(20), np.array([0.0, -1.0]), 0.5, EdgeContext(ground), fallback=0.4)
    (0.2, False)
    >>> edge_shift(xy, np.zeros(20), np.array([0.0, -1.0]), 0.5, EdgeContext(xy - [0, 0.2]), fallback=0.4)
    (0.1, True)

    When the boundary points are the tops of a flush wall, the edge is at them:

    >>> edge_shift(xy, np.zeros(20), np.array([0.0, -1.0]), 0.5, EdgeContext(ground, walls=xy), fallback=0.4)
    (0.0, True)
    """
    step = 2.0 * fallback * spacing
    # a wall point on the boundary is on the edge: the wall is flush with it (under an overhang it lies inside)
    wall = np.zeros(len(xy), bool) if context is None else context.on_wall(xy)
    if context is None or context.tree is None or len(xy) == 0:
        if not wall.any():
            return 0.5 * step, False
        return float(np.median(residual + np.where(wall, 0.0, 0.5 * step))), False
    normal = np.broadcast_to(np.asarray(normal, dtype=np.float64), (len(xy), 2))
    tangent = np.column_stack([-normal[:, 1], normal[:, 0]])
    k = min(_K, len(context.xy))
    # a point ahead within one step across and one spacing sideways lies within this radius
    dist, nb = context.tree.query(xy, k=k, distance_upper_bound=float(np.hypot(step, spacing)))
    dist, nb = dist.reshape(len(xy), k), nb.reshape(len(xy), k)
    found = np.isfinite(dist)
    rel = context.xy[np.where(found, nb, 0)] - xy[:, None, :]
    across = np.einsum("nkj,nj->nk", rel, normal)
    along = np.abs(np.einsum("nkj,nj->nk", rel, tangent))
    # the first non-roof point straight out: ahead of the boundary point, within one spacing sideways
    ok = found & (across > 0) & (along <= spacing)
    gap = np.minimum(np.where(ok, across, np.inf).min(axis=1), step)
    gap = np.where(wall, 0.0, gap)
    seen = gap < step
    measured = bool(seen.sum() >= max(3, _MIN_SHARE * len(xy)))
    return float(np.median(residual + 0.5 * gap)), measured
