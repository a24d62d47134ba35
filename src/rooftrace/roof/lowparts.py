"""Flat blocks for the lower roof parts no plane took: terraces, balconies, low annexes, mixed clutter.

The segmentation and its second pass leave points on no plane when they
are too rough, too mixed in height or too few for a plane: a roof terrace
with planters and railings, a balcony, a lower roof part seen by a few
scan lines, the far slope of a neighbour's roof reaching into the
footprint.  The face partition then carries the plane of the nearest
labelled points over them, and they lie metres under its face.  The flat
blocks of :func:`rooftrace.roof.superstructures.block_planes` peel what
stands *above* the roof from its top; this is their mirror for what lies
*under* it: each cluster of such points that the sky sees (no point of
the building stands over it) is peeled from its bottom in layers ``rise``
deep while a layer lies more than ``rise`` under the roof, and each layer
becomes a horizontal plane at its points' mean height, as LoD 1.3 models
a roof by flat blocks; the face partition gives it its face like any plane.

Invariant (with ``rise = step_height``): after :func:`low_blocks` no
cluster of at least ``min_points`` points on no plane, linked within
``link``, seen from above and dense enough to be a surface, lies with its
bottom layer's median more than ``rise`` under the plane of its nearest
labelled points; what is left under the roof is either sparse (scattered
returns), or under another point of the building (a wall under the eaves,
a floor under a canopy), or fewer than ``min_points`` points.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from rooftrace.graph import components
from rooftrace.roof.planes import PlaneFit, hull_area_test, plan_hull_area, plane_height, with_horizontal_planes

__all__ = ["low_blocks", "open_to_sky", "depth_under_roof"]


def open_to_sky(xyz: np.ndarray, which: np.ndarray, radius: float, rise: float, *,
                by: np.ndarray | None = None) -> np.ndarray:
    """Which of the points ``which`` have no point of ``xyz`` within ``radius`` in plan more than ``rise`` above.

    A wall point under the eaves, or a floor under a canopy, has the roof
    over it within the point spacing; a terrace or a lower roof has not
    (but along the foot of the wall that rises over it).

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), float64
        The building's points (m).
    which : ndarray of int
        Indices into ``xyz`` of the points to judge.
    radius : float
        Plan radius (m).
    rise : float
        Height (m) above a point that makes a neighbour stand over it.
    by : ndarray of bool, shape (N,), optional
        The points that may stand over another; default all.

    Returns
    -------
    ndarray of shape (len(which),), bool
    """
    if not len(which):
        return np.zeros(0, bool)
    over_them = None if by is None else np.flatnonzero(by)
    others = xyz[:, :2] if over_them is None else xyz[over_them, :2]
    pairs = cKDTree(xyz[which, :2]).sparse_distance_matrix(cKDTree(others), radius, output_type="ndarray")
    over = np.zeros(len(which), bool)
    i, j = pairs["i"], (pairs["j"] if over_them is None else over_them[pairs["j"]])
    high = xyz[j, 2] > xyz[which[i], 2] + rise
    over[i[high]] = True
    return ~over


def depth_under_roof(xyz: np.ndarray, labels: np.ndarray, planes: np.ndarray, which: np.ndarray) -> np.ndarray:
    """How deep (m) each of the points ``which`` lies under the plane of its nearest labelled point in plan.

    The face partition gives a point's cell the plane of its nearest
    labelled points: this is how far under that face the point will lie
    (negative: above it).
    """
    on = np.flatnonzero(labels >= 0)
    _, nearest = cKDTree(xyz[on, :2]).query(xyz[which, :2])
    return plane_height(planes[labels[on[nearest]]], xyz[which, :2]) - xyz[which, 2]


def low_blocks(xyz: np.ndarray, labels: np.ndarray, fit: PlaneFit, spacing: float, *, min_points: int = 4,
               rise: float = 0.5, link: float | None = None, min_density: float = 0.25):
    """Horizontal planes for the layers of the clusters of points on no plane that lie under the roof.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), float64
        One building's roof points (m).
    labels : ndarray of shape (N,), int
        Plane per point, ``-1`` for none.
    fit : PlaneFit
        The planes of ``labels``.
    spacing : float
        Mean point spacing ``s`` (m); also the plan radius within which a
        point of the building more than ``rise`` higher puts a point under
        cover (:func:`open_to_sky`).
    min_points : int
        Fewest points of a block.
    rise : float
        Depth (m) of a layer, and how far a layer's median must lie under
        the plane of its points' nearest labelled points to be a block;
        higher layers (the rough strip of the roof itself, a gutter) stay
        on no plane.
    link : float, optional
        3D distance (m) linking points into clusters; default ``2.5 s``.
    min_density : float
        Fewest points per ``s²`` over a layer's plan hull: scattered
        returns (through a skylight, off a railing) are not a block.

    Returns
    -------
    labels : ndarray of shape (N,), int64
        With the blocks numbered after the planes of ``fit``.
    fit : PlaneFit
        ``fit`` with the blocks appended (``p = q = 0``, ``r`` the mean
        height, ``sigma`` with ``n - 1`` degrees of freedom and only
        ``var(r) = sigma² / n``).

    Examples
    --------
    A flat roof at 9 m with a sunken terrace on two levels (6 and 6.9 m);
    the points at the foot of a wall rising over them stay on none:

    >>> from rooftrace.roof.planes import fit_planes
    >>> g = np.stack(np.meshgrid(np.arange(0, 8, 0.3), np.arange(0, 8, 0.3)), -1).reshape(-1, 2)
    >>> low = (g[:, 0] > 5) & (g[:, 1] > 5)
    >>> z = np.where(low, 6.0 + 0.9 * (g[:, 0] > 6.5), 9.0)
    >>> xyz = np.column_stack([g, z])
    >>> lab = np.where(low, -1, 0)
    >>> lab2, fit2 = low_blocks(xyz, lab, fit_planes(xyz, lab), 0.3)
    >>> np.unique(lab2[low], return_counts=True)[1].tolist(), fit2.planes[1:, 3].round(2).tolist()
    ([28, 27, 45], [-6.0, -6.9])
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    labels = np.asarray(labels, dtype=np.int64)
    link = link or 2.5 * spacing
    un = np.flatnonzero(labels < 0)
    if len(un) < min_points or not (labels >= 0).any():
        return labels, fit
    depth = depth_under_roof(xyz, labels, fit.planes, un)
    # only what lies under the roof and is seen from above can be a lower roof part
    cand = depth > rise
    cand[cand] = open_to_sky(xyz, un[cand], spacing, rise)
    un, depth = un[cand], depth[cand]
    if len(un) < min_points:
        return labels, fit
    comp = components(len(un), cKDTree(xyz[un]).query_pairs(link, output_type="ndarray"))
    order = np.argsort(comp, kind="stable")
    starts = np.flatnonzero(np.r_[True, np.diff(comp[order]) != 0])
    blocks = []
    for cluster in np.split(order, starts[1:]):
        # peeled from the bottom, a layer of ``rise`` at a time: a terrace's floor, then what stands on it
        while len(cluster) >= min_points:
            z = xyz[un[cluster], 2]
            bottom = z <= z.min() + rise
            layer = cluster[bottom]
            if not np.median(depth[layer]) > rise:
                break
            cluster = cluster[~bottom]
            pts, n = xyz[un[layer]], len(layer)
            # a layer of too few points (a stray return under the terrace) is skipped, not a stop
            if n >= min_points and hull_area_test(pts, plan_hull_area(pts),
                                                  lambda a, n=n: n >= min_density * a / spacing**2, True):
                blocks.append(un[layer])
    if not blocks:
        return labels, fit
    return with_horizontal_planes(xyz, labels, fit, blocks)

