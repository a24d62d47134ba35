"""Flat blocks for what stands on a roof but fits no plane: parapets, chimneys, gable tops, roof clutter.

The segmentation and its second pass (:func:`rooftrace.roof.segmentation.detail_planes`)
leave points on no plane when they are too few, too rough or too narrow
for a plane: chains along a parapet or a gable wall rising above the roof,
chimneys of a few points, vents.  Under the faces of the planes around them
such points sit metres above the roof surface.  As LoD 1.3 models a roof
by flat blocks, each cluster of such points is peeled from its top in
layers ``rise`` deep, as seen from above, while a layer stands more than
``rise`` above the roof: each such layer becomes a horizontal plane at its
points' mean height (the least-squares horizontal), a parapet's coping on
its wall, a gable's sloping top in steps, a chimney's top without its
sides; the face partition gives each its face like any plane.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from rooftrace.graph import components
from rooftrace.roof.planes import PlaneFit, hull_area_test, plan_hull_area, plane_height, with_horizontal_planes

__all__ = ["block_planes"]


def block_planes(xyz: np.ndarray, labels: np.ndarray, fit: PlaneFit, spacing: float, *, min_points: int = 4,
                 rise: float = 0.5, link: float | None = None, min_density: float = 0.25):
    """Horizontal planes for the layers of the clusters of points on no plane that stand above the roof.

    First the points a plane holds apart from the rest of it (groups of
    fewer than ``min_points`` linked within ``link``) are taken off it: they
    lie on the plane's extension, not on its surface, and join the points
    on no plane.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), float64
        One building's roof points (m).
    labels : ndarray of shape (N,), int
        Plane per point, ``-1`` for none.
    fit : PlaneFit
        The planes of ``labels``.
    spacing : float
        Mean point spacing ``s`` (m).
    min_points : int
        Fewest points of a block.
    rise : float
        Depth (m) of a layer, and the median height of a layer's points
        above the plane of their nearest labelled point that makes it a
        block; lower layers (wall points under the eaves, a rough strip of
        the roof itself) stay on no plane.
    link : float, optional
        3D distance (m) linking points into clusters; default ``2.5 s``.
    min_density : float
        Fewest points per ``s²`` over a layer's plan hull: scattered
        returns (wires, birds, a tree branch) are not a block.

    Returns
    -------
    labels : ndarray of shape (N,), int64
        With the blocks numbered after the planes of ``fit``, the stray
        points of a plane ``-1`` unless in a block.
    fit : PlaneFit
        ``fit`` with the blocks appended (``p = q = 0``, ``r`` the mean
        height, ``sigma`` with ``n - 1`` degrees of freedom and only
        ``var(r) = sigma² / n``).

    Examples
    --------
    >>> from rooftrace.roof.planes import fit_planes
    >>> g = np.stack(np.meshgrid(np.arange(0, 6, 0.3), np.arange(0, 6, 0.3)), -1).reshape(-1, 2)
    >>> roof = np.column_stack([g, np.full(len(g), 5.0)])
    >>> chimney = np.array([[3.0, 3.0, 6.2], [3.3, 3.0, 6.25], [3.0, 3.3, 6.2], [3.3, 3.3, 6.15]])
    >>> xyz = np.vstack([roof[np.hypot(*(g - 3.15).T) > 0.4], chimney])
    >>> lab = np.r_[np.zeros(len(xyz) - 4, np.int64), -np.ones(4, np.int64)]
    >>> lab2, fit2 = block_planes(xyz, lab, fit_planes(xyz, lab), 0.3)
    >>> lab2[-4:].tolist(), fit2.planes[1].round(2).tolist()
    ([1, 1, 1, 1], [0.0, 0.0, 1.0, -6.2])
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    labels = np.asarray(labels, dtype=np.int64)
    link = link or 2.5 * spacing
    labels = _stray_points_released(xyz, labels, link, min_points)
    un, on = np.flatnonzero(labels < 0), np.flatnonzero(labels >= 0)
    if len(un) < min_points or not len(on):
        return labels, fit
    comp = components(len(un), cKDTree(xyz[un]).query_pairs(link, output_type="ndarray"))
    # the roof under a leftover point: the plane of its nearest labelled point, as the face partition will put it
    _, nearest = cKDTree(xyz[on, :2]).query(xyz[un, :2])
    above = xyz[un, 2] - plane_height(fit.planes[labels[on[nearest]]], xyz[un, :2])
    order = np.argsort(comp, kind="stable")
    starts = np.flatnonzero(np.r_[True, np.diff(comp[order]) != 0])
    blocks = []
    for cluster in np.split(order, starts[1:]):
        # peeled from the top, a layer of ``rise`` at a time, as seen from above: a parapet on its wall, a
        # gable's sloping top in steps; the layers under the roof's own height are walls and stay on none
        while len(cluster) >= min_points:
            z = xyz[un[cluster], 2]
            top = z >= z.max() - rise
            layer = cluster[top]
            if len(layer) < min_points or not np.median(above[layer]) > rise:
                break
            cluster = cluster[~top]
            # Qhull finds no hull for a chain of points (a parapet's coping seen by one scan line): area 0
            pts, n = xyz[un[layer]], len(layer)
            if hull_area_test(pts, plan_hull_area(pts), lambda a, n=n: n >= min_density * a / spacing**2, True):
                blocks.append(un[layer])
    if not blocks:
        return labels, fit
    return with_horizontal_planes(xyz, labels, fit, blocks)


def _stray_points_released(xyz: np.ndarray, labels: np.ndarray, link: float, min_points: int) -> np.ndarray:
    """``labels`` with the points of a plane that lie apart from the rest of it taken off it (``-1``).

    A plane holds a point by its equation: a point of a chimney, a parapet or
    a lower roof that happens to lie on the extension of a plane elsewhere on
    the roof is labelled with it, alone or with one or two others, metres
    from the plane's own points.  The face partition gives such a point a
    region of a cell or two, which merges into the face around it, and the
    point ends up metres off that face.  The groups of a plane's points
    linked within ``link`` (m, 3D) that have fewer than ``min_points``
    points are released, to be judged with the other leftovers.
    """
    on = np.flatnonzero(labels >= 0)
    if len(on) < 2:
        return labels
    pairs = cKDTree(xyz[on]).query_pairs(link, output_type="ndarray")
    pairs = pairs[labels[on[pairs[:, 0]]] == labels[on[pairs[:, 1]]]]
    comp = components(len(on), pairs)
    small = np.bincount(comp)[comp] < min_points
    if not small.any():
        return labels
    labels = labels.copy()
    labels[on[small]] = -1
    return labels
