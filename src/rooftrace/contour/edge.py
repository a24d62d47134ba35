"""Where the roof edge lies: between the last roof point and the first point that is not roof (beyond the thesis).

A boundary traced through the outermost roof points lies inside the true
edge by the depth of those points, about half the gap to the next point
across the edge.  With the points that are not roof around the building
(ground, trees, other buildings), that gap is measured point by point: the
edge is taken halfway between each boundary point and the first non-roof
point straight out from it.  For a sampling of the same density on both
sides of the edge the two distances have the same distribution, so the
midpoint is unbiased whatever the density and scan pattern.  Without such
points a fixed share of the local spacing is the fallback.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["EdgeContext", "edge_shift"]

#: neighbours looked at per boundary point
_K = 12
#: a non-roof point counts only within this many spacings of the boundary point (farther: occlusion, water)
_REACH = 3.0
#: share of a segment's points that must see a non-roof point for the measured shift to be used
_MIN_SHARE = 0.3


class EdgeContext:
    """The points around a building that are not its roof, for :func:`edge_shift`.

    Parameters
    ----------
    xy : ndarray of shape (C, 2) float64 or None
        Plan coordinates, metres, in the frame of the ring points.
    """

    def __init__(self, xy: np.ndarray | None):
        xy = None if xy is None else np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        self.xy = xy if xy is not None and len(xy) else None
        self.tree = cKDTree(self.xy) if self.xy is not None else None


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
        Points that are not this roof.
    fallback : float
        Shift in spacings when the context does not say (no points, or fewer
        than 30 % of the segment's points see one within 3 spacings).

    Returns
    -------
    shift : float
        Metres, positive outwards.
    measured : bool
        True when it comes from the context points.
    """
    default = fallback * spacing
    if context is None or context.tree is None or len(xy) == 0:
        return default, False
    normal = np.broadcast_to(np.asarray(normal, dtype=np.float64), (len(xy), 2))
    tangent = np.column_stack([-normal[:, 1], normal[:, 0]])
    k = min(_K, len(context.xy))
    dist, nb = context.tree.query(xy, k=k, distance_upper_bound=_REACH * spacing)
    dist, nb = dist.reshape(len(xy), k), nb.reshape(len(xy), k)
    found = np.isfinite(dist)
    rel = context.xy[np.where(found, nb, 0)] - xy[:, None, :]
    across = np.einsum("nkj,nj->nk", rel, normal)
    along = np.abs(np.einsum("nkj,nj->nk", rel, tangent))
    # the first non-roof point straight out: ahead of the boundary point, within one spacing sideways
    ok = found & (across > 0) & (along <= spacing)
    gap = np.where(ok, across, np.inf).min(axis=1)
    seen = np.isfinite(gap)
    if seen.sum() < max(3, _MIN_SHARE * len(xy)):
        return default, False
    return float(np.median(residual[seen] + 0.5 * gap[seen])), True
