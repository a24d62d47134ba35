"""Adjacency of roof planes from their points, and how each adjacent pair meets.

Two planes are adjacent when enough of their points lie within ``radius`` of
each other in plan.  The midpoints of those close point pairs trace the
shared boundary; they clip the intersection line and tell a ridge from a step.

A pair is *convex* when each plane, extended, passes above the other plane's
points near the boundary (the roof is the lower of the two: ridges and hips)
and *concave* when it passes below (valleys).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from rooftrace.roof.planes import plane_height

__all__ = ["Adjacency", "plane_adjacency"]


@dataclass
class Adjacency:
    """Adjacent plane pairs.

    Attributes
    ----------
    pairs : ndarray of shape (P, 2), int64
        Plane indices ``(a, b)`` with ``a < b``.
    links : ndarray of shape (P,), int64
        Number of close point pairs joining them.
    midpoints : list of ndarray of shape (M_p, 2)
        Plan midpoints of the close point pairs: the shared boundary.
    convexity : ndarray of shape (P,)
        Median of "other plane's height minus the point's height" over the
        boundary points (m): positive for convex (ridge, hip), negative for
        concave (valley) meetings.
    gap : ndarray of shape (P,)
        Median ``|z_a - z_b|`` of the two planes at the midpoints (m).
    """

    pairs: np.ndarray
    links: np.ndarray
    midpoints: list
    convexity: np.ndarray
    gap: np.ndarray

    def __len__(self) -> int:
        return len(self.pairs)


def plane_adjacency(
    xyz: np.ndarray,
    labels: np.ndarray,
    planes: np.ndarray,
    radius: float,
    min_links: int = 3,
) -> Adjacency:
    """Find adjacent planes.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3)
    labels : ndarray of shape (N,), int
        Plane per point, ``-1`` unassigned.
    planes : ndarray of shape (K, 4)
    radius : float
        Largest plan distance (m) between two points of different planes for
        them to count as neighbours across a boundary.
    min_links : int
        Fewest close point pairs for an adjacency (one or two pairs are
        corners touching, not a shared edge).
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    sel = np.flatnonzero(labels >= 0)
    empty = Adjacency(np.zeros((0, 2), np.int64), np.zeros(0, np.int64), [], np.zeros(0), np.zeros(0))
    if len(sel) < 2:
        return empty
    P = xyz[sel]
    lab = labels[sel]
    ij = cKDTree(P[:, :2]).query_pairs(radius, output_type="ndarray")
    if len(ij) == 0:
        return empty
    ij = ij[lab[ij[:, 0]] != lab[ij[:, 1]]]
    if len(ij) == 0:
        return empty
    # Orient every link so that its first point is on the lower plane index.
    swap = lab[ij[:, 0]] > lab[ij[:, 1]]
    ij[swap] = ij[swap][:, ::-1]
    la, lb = lab[ij[:, 0]], lab[ij[:, 1]]
    K = len(planes)
    key = la * K + lb
    order = np.argsort(key, kind="stable")
    ij, la, lb, key = ij[order], la[order], lb[order], key[order]
    ukey, start, count = np.unique(key, return_index=True, return_counts=True)
    pa, pb = P[ij[:, 0]], P[ij[:, 1]]
    mid = (pa[:, :2] + pb[:, :2]) / 2
    # b's plane above a's point, a's plane above b's point: convex meeting.
    da = plane_height(planes[lb], pa[:, :2]) - pa[:, 2]
    db = plane_height(planes[la], pb[:, :2]) - pb[:, 2]
    zgap = np.abs(plane_height(planes[la], mid) - plane_height(planes[lb], mid))
    keep = count >= min_links
    if not keep.any():
        return empty
    link_pair = np.repeat(np.arange(len(ukey)), count)
    conv = _medians(np.concatenate([da, db]), np.concatenate([link_pair, link_pair]), len(ukey))[keep]
    gap = _medians(zgap, link_pair, len(ukey))[keep]
    pairs = np.column_stack([ukey[keep] // K, ukey[keep] % K]).astype(np.int64)
    mids = [mid[s : s + c] for s, c in zip(start[keep], count[keep])]
    return Adjacency(pairs, count[keep].astype(np.int64), mids, conv, gap)


def _medians(values: np.ndarray, group: np.ndarray, n_groups: int) -> np.ndarray:
    """``np.median`` of the values of each group (ids 0 .. n_groups - 1, none empty), for all groups at once.

    The same numbers as one ``np.median`` call per group (thousands of them
    on a large building): the middle value, or the mean of the two middle
    values as ``(a + b) / 2``; NaN for a group holding a NaN.
    """
    ordered = values[np.lexsort((values, group))]
    count = np.bincount(group, minlength=n_groups)
    start = np.cumsum(count) - count
    out = (ordered[start + (count - 1) // 2] + ordered[start + count // 2]) / 2
    out[np.bincount(group, weights=np.isnan(values), minlength=n_groups) > 0] = np.nan
    return out
