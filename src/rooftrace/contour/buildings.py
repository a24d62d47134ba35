"""Which points form which building, when the outline stage runs without the detection.

``rooftrace run`` outlines the buildings its detection found.  Points that
were classified elsewhere (a LAS file with class 6, with or without a
``building_id`` dimension) are grouped here: by their ``building_id`` when
there is one, else by connected components in plan view at twice the mean
point spacing (the thesis' L_Dxy, §3.3).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np

from rooftrace.contour.outline import RoofOutline, connected_buildings
from rooftrace.contour.spacing import building_mean_spacing
from rooftrace.errors import GeometryError

__all__ = ["BUILDING", "classified_buildings", "median_building_spacing", "outline_statuses", "warn_failed_outlines"]

log = logging.getLogger(__name__)

#: the ASPRS class of building points
BUILDING = 6


def classified_buildings(xyz: np.ndarray, classification: np.ndarray,
                         building_id: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The building (class 6) points of a classified cloud and a building id for each.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), float64
        Points (m).
    classification : ndarray of shape (N,)
        ASPRS classes; class 6 points are kept.
    building_id : ndarray of shape (N,), optional
        Building of each point (0 = none), as ``rooftrace detect`` writes
        it.  Without it the building points are split into connected
        components in plan view, linked within twice their mean spacing.

    Returns
    -------
    xyz : ndarray of shape (M, 3), float64
        The class 6 points, in input order.
    ids : ndarray of shape (M,), int64
        Building id per point (> 0; 0 = a component too small to be one).
        Too few or collinear points for a spacing make one building, whose
        outline then says why it failed.

    Examples
    --------
    >>> xy = np.stack(np.meshgrid(np.arange(4.0), np.arange(4.0)), -1).reshape(-1, 2)
    >>> xyz = np.column_stack([np.vstack([xy, xy + 50]), np.full(32, 10.0)])
    >>> pts, ids = classified_buildings(xyz, np.full(32, 6))
    >>> np.unique(ids).tolist()
    [1, 2]
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    building = np.asarray(classification) == BUILDING
    xyz = xyz[building]
    if building_id is not None:
        return xyz, np.asarray(building_id)[building].astype(np.int64)
    try:
        return xyz, connected_buildings(xyz[:, :2], 2.0 * building_mean_spacing(xyz[:, :2]))
    except GeometryError:
        return xyz, np.ones(len(xyz), np.int64)


def median_building_spacing(xyz: np.ndarray, ids: np.ndarray) -> float | None:
    """The cloud's mean spacing s_avg for the global alpha (S1) when only building points are known.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), float64
        Building points (m).
    ids : ndarray of shape (N,), int
        Building id per point (0 = none).

    Returns
    -------
    float or None
        The median over the buildings of :func:`building_mean_spacing` (m);
        None without a building or when one has too few points for it.

    Examples
    --------
    >>> xy = np.stack(np.meshgrid(np.arange(5.0), np.arange(5.0)), -1).reshape(-1, 2)
    >>> round(median_building_spacing(np.column_stack([xy, np.zeros(25)]), np.ones(25, int)), 3)
    1.118
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    ids = np.asarray(ids)
    try:
        per = [building_mean_spacing(xyz[ids == i, :2]) for i in np.unique(ids[ids > 0])]
    except GeometryError:
        return None
    return float(np.median(per)) if per else None


def outline_statuses(outlines: Sequence[RoofOutline]) -> dict[str, int]:
    """How many outlines have each ``status``, in order of first appearance.

    Examples
    --------
    >>> outline_statuses([RoofOutline(1, None, status="too_few_points"), RoofOutline(2, None, status="ok")])
    {'too_few_points': 1, 'ok': 1}
    """
    statuses: dict[str, int] = {}
    for o in outlines:
        statuses[o.status] = statuses.get(o.status, 0) + 1
    return statuses


def warn_failed_outlines(outlines: Sequence[RoofOutline]) -> list[int]:
    """Log one warning naming the buildings without an outline (at most 20 ids); return all their ids."""
    failed = [o.building_id for o in outlines if o.polygon is None]
    if failed:
        log.warning("%d of %d buildings have no outline (see their 'status' attribute): ids %s", len(failed),
                    len(outlines), ", ".join(map(str, failed[:20])) + (" ..." if len(failed) > 20 else ""))
    return failed
