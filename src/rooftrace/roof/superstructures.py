"""Flat blocks for what stands on a roof but fits no plane: chimneys, vents, parapets, gable tops, roof clutter.

The segmentation and its second pass (:func:`rooftrace.roof.segmentation.detail_planes`)
leave points on no plane when they are too few, too rough or too narrow
for a plane: chains along a parapet or a gable wall rising above the roof,
chimneys and vents of one to a few points.  Under the faces of the planes
around them such points sit metres above the roof surface.  As LoD 1.3
models a roof by flat blocks, the top surface of what stands on the roof
is modelled by boxes: the points on no plane that stand more than ``rise``
above the roof under them, with no point within the spacing standing
``rise`` higher (the sides of a chimney, a wall under a higher roof's
edge), are linked into clusters; each cluster is cut from its top in
layers ``rise`` deep (a sloping coping, a gable's top in steps) and each
layer becomes a horizontal plane at its points' mean height (the
least-squares horizontal) when its points support it against the roof
under them (:func:`block_supported`).  The face partition gives each block
the plan region its points own (their nearest-point cells), kept whatever
its area (``partition_outline(kept_planes=...)``), with walls down to the
roof in the model: a box, however few its points.  A top point no block
holds (a vent pipe of one return) or whose block's face the partition lost
is named as one of the roof's top points; the model builds a box under it
when its faces leave it far under the roof, without a face of its own
(:func:`rooftrace.model.superstructures.with_boxes`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from rooftrace.graph import components
from rooftrace.roof.planes import PlaneFit, hull_area_test, plan_hull_area, plane_height, with_horizontal_planes

__all__ = ["block_planes", "block_supported", "superstructures", "Superstructures"]


@dataclass
class Superstructures:
    """What :func:`superstructures` finds on a roof.

    Attributes
    ----------
    labels : ndarray of shape (N,), int64
        Plane per point, the blocks numbered after the roof planes.
    fit : PlaneFit
        The planes with the blocks appended.
    tops : ndarray of shape (M,), int64
        The top points of what stands on the roof, sorted: the points of
        the blocks, and the points on no plane with none standing ``rise``
        higher within the spacing, at most ``box_height`` above the roof.
        The model puts a box under any of them the roof faces leave more
        than ``rise`` under it (:func:`rooftrace.model.superstructures.with_boxes`).
    """

    labels: np.ndarray
    fit: PlaneFit
    tops: np.ndarray


def block_planes(xyz: np.ndarray, labels: np.ndarray, fit: PlaneFit, spacing: float, *, min_points: int = 2,
                 rise: float = 0.5, link: float | None = None, min_density: float = 0.25, stray_points: int = 4,
                 k: int = 8, max_dz: float = 0.1):
    """The labels and planes of :func:`superstructures` (its blocks; no lone points)."""
    found = superstructures(xyz, labels, fit, spacing, min_points=min_points, rise=rise, link=link,
                            min_density=min_density, stray_points=stray_points, k=k, max_dz=max_dz)
    return found.labels, found.fit


def superstructures(xyz: np.ndarray, labels: np.ndarray, fit: PlaneFit, spacing: float, *, min_points: int = 2,
                    rise: float = 0.5, link: float | None = None, min_density: float = 0.25, stray_points: int = 4,
                    k: int = 8, max_dz: float = 0.1, box_height: float = 0.0) -> Superstructures:
    """Horizontal planes for the layers of the clusters of points on no plane that stand above the roof.

    First the points a plane holds apart from the rest of it (groups of
    fewer than ``stray_points`` linked within ``link``) are taken off it:
    they lie on the plane's extension, not on its surface, and join the
    points on no plane.

    Guarantee: every point on no plane that stands more than ``rise`` above
    the plane of its nearest labelled point and is not within ``rise``
    above (``max_dz`` under) another plane of its ``k`` nearest labelled
    points, with no point within ``spacing`` (plan) standing ``rise``
    higher, is in a block whose height
    is within ``rise`` of its own, unless its layer has fewer than
    ``min_points`` points, is scattered (``min_density``), or is not
    supported against the roof (:func:`block_supported`).  With
    ``box_height``, every point on no plane with no point within
    ``spacing`` standing ``rise`` higher (a top point) is one of ``tops``
    unless it stands more than ``box_height`` above the roof plane under it
    (a bird, a wire), and so is every block's point.

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
        Least height (m) of a block's point above the plane of its nearest
        labelled point (lower points on no plane are the roof's own rough
        strips, gutters and low parapets: the face partition takes them),
        and the depth of a layer.
    link : float, optional
        3D distance (m) linking points into clusters; default ``2.5 s``.
    min_density : float
        Fewest points per ``s²`` over the plan hull of a layer of three
        points or more: scattered returns (wires, birds, a tree branch) are
        not a block.
    stray_points : int
        A plane's points in groups of fewer than this are released.
    k, max_dz : int, float
        A point standing at most ``rise`` above, or ``max_dz`` (m) under, a
        plane of its ``k`` nearest labelled points is left to the face
        partition, which puts it with that plane
        (``partition_outline(rise=...)``, same ``k`` and ``max_dz``).
    box_height : float
        Highest a top point on no plane may stand above the roof plane
        under it (m) to be one of ``tops``; 0: no ``tops`` at all.

    Returns
    -------
    Superstructures
        ``labels`` with the blocks numbered after the planes of ``fit``, the
        stray points of a plane ``-1`` unless in a block; ``fit`` with the
        blocks appended (``p = q = 0``, ``r`` the mean height, ``sigma``
        with ``n - 1`` degrees of freedom and only ``var(r) = sigma² / n``);
        ``tops`` the blocks' points and the top points on no plane.

    Examples
    --------
    >>> from rooftrace.roof.planes import fit_planes
    >>> g = np.stack(np.meshgrid(np.arange(0, 6, 0.3), np.arange(0, 6, 0.3)), -1).reshape(-1, 2)
    >>> roof = np.column_stack([g, np.full(len(g), 5.0)])
    >>> chimney = np.array([[3.0, 3.0, 6.2], [3.3, 3.0, 6.25], [3.0, 3.3, 6.2], [3.3, 3.3, 6.15]])
    >>> vent = np.array([[1.5, 4.5, 5.9]])
    >>> xyz = np.vstack([roof[(np.hypot(*(g - 3.15).T) > 0.4) & (np.hypot(*(g - 1.5).T) > 0.1)], chimney, vent])
    >>> lab = np.r_[np.zeros(len(xyz) - 5, np.int64), -np.ones(5, np.int64)]
    >>> lab2, fit2 = block_planes(xyz, lab, fit_planes(xyz, lab), 0.3, min_points=1)
    >>> lab2[-5:].tolist(), fit2.planes[1:].round(2).tolist()
    ([1, 1, 1, 1, 2], [[0.0, 0.0, 1.0, -6.2], [0.0, 0.0, 1.0, -5.9]])
    >>> found = superstructures(xyz, lab, fit_planes(xyz, lab), 0.3, box_height=3.0)
    >>> found.labels[-5:].tolist(), (found.tops - len(xyz) + 5).tolist()
    ([1, 1, 1, 1, -1], [0, 1, 2, 3, 4])
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    labels = np.asarray(labels, dtype=np.int64)
    link = link or 2.5 * spacing
    labels = _stray_points_released(xyz, labels, link, stray_points)
    none = np.zeros(0, dtype=np.int64)
    un, on = np.flatnonzero(labels < 0), np.flatnonzero(labels >= 0)
    if len(un) < (1 if box_height > 0 else max(min_points, 1)) or not len(on):
        return Superstructures(labels, fit, none)
    # the roof under a leftover point: the plane of its nearest labelled point, as the face partition will put it;
    # one standing at most ``rise`` above (``max_dz`` under) a plane of its ``k`` nearest labelled points is that
    # plane's in the face partition (``faces._attached``: a coping, a gutter), not a block's
    _, nearest = cKDTree(xyz[on, :2]).query(xyz[un, :2], k=int(min(k, len(on))))
    nearest = nearest.reshape(len(un), -1)
    cand_planes = labels[on[nearest]]
    over = xyz[un, 2:3] - plane_height(fit.planes[cand_planes], xyz[un, None, :2])
    roof, above = cand_planes[:, 0], over[:, 0]
    high = (above > rise) & ~((over >= -max_dz) & (over <= rise)).any(axis=1)
    # a point with another standing ``rise`` higher beside it is a side or a wall, not a top surface
    test = np.ones(len(un), dtype=bool) if box_height > 0 else high
    surface = np.zeros(len(un), dtype=bool)
    if test.any():
        _, idx = cKDTree(xyz[:, :2]).query(xyz[un[test], :2], k=int(min(9, len(xyz))), distance_upper_bound=spacing)
        z = np.r_[xyz[:, 2], -np.inf][idx]
        surface[test] = ~(z > xyz[un[test], 2:3] + rise).any(axis=1)
    high &= surface
    cand = np.flatnonzero(high)
    blocks = []
    if len(cand) >= max(min_points, 1):
        comp = components(len(cand), cKDTree(xyz[un[cand]]).query_pairs(link, output_type="ndarray"))
        order = np.argsort(comp, kind="stable")
        starts = np.flatnonzero(np.r_[True, np.diff(comp[order]) != 0])
        blocks = _layers_as_blocks(xyz, un, np.split(cand[order], starts[1:]), above, fit.sigma[roof], spacing,
                                   min_points, rise, min_density)
    # the top points: the blocks', and those on no plane that stand at most ``box_height`` above the roof (a
    # higher lone return is a bird or a wire); the model boxes any of them its faces leave far under them
    tops = np.unique(np.concatenate([*blocks, un[surface & (above <= box_height)]])) if box_height > 0 else none
    if blocks:
        labels, fit = with_horizontal_planes(xyz, labels, fit, blocks)
    return Superstructures(labels, fit, tops.astype(np.int64))


def _layers_as_blocks(xyz: np.ndarray, un: np.ndarray, clusters: list, above: np.ndarray, sigma: np.ndarray,
                      spacing: float, min_points: int, rise: float, min_density: float) -> list[np.ndarray]:
    """The points (indices into ``xyz``) of each block: the layers of ``clusters`` (indices into ``un``) that
    have ``min_points``, are dense and supported (:func:`superstructures`)."""
    blocks = []
    for cluster in clusters:
        # cut from the top, a layer of ``rise`` at a time: a sloping coping, a gable's top in steps
        while len(cluster) >= max(min_points, 1):
            z = xyz[un[cluster], 2]
            top = z >= z.max() - rise
            layer, cluster = cluster[top], cluster[~top]
            if len(layer) < min_points:
                continue
            pts, n = xyz[un[layer]], len(layer)
            # Qhull finds no hull for a chain of points (a parapet's coping seen by one scan line): area 0
            dense = n < 3 or hull_area_test(pts, plan_hull_area(pts), lambda a, n=n: n >= min_density * a / spacing**2,
                                            True)
            if dense and block_supported(above[layer], pts[:, 2], sigma[layer]):
                blocks.append(un[layer])
    return blocks


def block_supported(above: np.ndarray, z: np.ndarray, sigma: np.ndarray) -> bool:
    """Whether a layer's points are better explained by a flat block than by the roof under them (AIC).

    Without a block each point is a roof point off by its height ``above``
    the roof; with one, off by its height's deviation from the layer's mean.
    Both are weighed by the noise ``sigma`` of the roof plane under each
    point, and the block costs its one parameter (its height): it stands
    when ``Σ (above / σ)² - Σ ((z - mean) / σ)² > 2`` (over a flat roof of
    one noise: ``n mean(above)² / σ² > 2``).  A chimney top of one point
    half a metre above a roof of 5 cm noise scores 100; a layer whose height
    above the roof the roof's noise explains (a rough roof plane's strip)
    does not stand.

    Examples
    --------
    >>> block_supported([0.6], [6.0], [0.05])
    True
    >>> block_supported([0.06, -0.04, 0.05], [5.06, 4.96, 5.05], [0.05, 0.05, 0.05])
    False

    Parameters
    ----------
    above : ndarray of shape (n,)
        Each point's height above the roof plane under it (m).
    z : ndarray of shape (n,)
        The points' heights (m).
    sigma : ndarray of shape (n,)
        Height noise (m) of the roof plane under each point.

    Returns
    -------
    bool
    """
    sigma = np.asarray(sigma, dtype=np.float64)
    # a plane of exact points (synthetic) or of too few for a residual: millimetre noise
    w = 1.0 / np.maximum(np.where(np.isfinite(sigma), sigma, 0.0), 1e-3) ** 2
    z = np.asarray(z, dtype=np.float64)
    return bool(np.sum(w * np.asarray(above) ** 2) - np.sum(w * (z - z.mean()) ** 2) > 2.0)


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
