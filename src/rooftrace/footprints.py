"""Cadastral footprints as buildings: which LiDAR points belong to which footprint.

A footprint (BGT/BAG ``pand``, a cadastre parcel building) is where the walls
meet the ground; the roof seen by the laser may stick out beyond it (eaves,
overhangs of 0.2–1 m).  Each footprint becomes one building made of

* the building points (class 6 of the detection) inside it,
* the building points in a band of ``overhang`` metres around it that belong
  to a detected building which also has points inside the footprint (so a
  neighbouring building without footprint is not taken in); a band point near
  several footprints goes to the nearest one, and
* the points inside it that the detection left unclassified and that stand
  ``min_height`` above the ground (chimneys, parapets, roof clutter too rough
  or too small for its roof test), when it has building points, and
* the other non-building points inside it or in its band, ``min_height / 2``
  above the ground, that touch its building's points (within ``2.5 s`` in
  3D, or of one that joined so, three links deep): clutter along the eaves,
  a chimney's top, a shed roof under ``min_height``, a roof under a tree's
  edge or a lower roof part the detection called vegetation.  They are roof
  points but not outline points (:attr:`FootprintAssignment.touching`):
  traced with them, an outline reached out over lower roofs beyond the
  building.

Neither of the last two takes a tree's points (:func:`tree_points`: the
detection's vegetation, or points amid vegetation or amid returns that went
on through, whose neighbourhood is no plane), except the grazed edges of a
chimney, a dormer or a parapet (:func:`chimney_edges`): a tree-like point
whose pulse ended on the building's points at most a box's height under it,
in a clump standing at one height, is a roof point too.  So every non-ground point over an
``"ok"`` footprint is either in its building or left out for a reason of
:data:`LEFT_OUT` (:attr:`FootprintAssignment.left_out`): near the ground, a
tree's, or detached from the building's points.

A detected building spanning several footprints (a terraced row) is thereby
split along the footprints: a point inside footprint A goes to A, a point in
the shared band goes to the nearest footprint.

Footprints that get too few building points keep a status and a fallback, as
3DBAG's roofer does: ``"few_points"`` (fewer than ``min_points``: a LoD 1.2
block from the heights there are, the footprint as outline),
``"no_building_points"`` (the cloud covers the footprint but nothing on it was
detected as a building: no model) and ``"no_points"`` (no point of the
cloud over the footprint: no model).  Everything here is numpy/shapely in and
out; reading the file is :func:`rooftrace.io.footprints.read_footprints`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import shapely
from scipy.spatial import cKDTree

from rooftrace.cloud import ASPRS
from rooftrace.graph import components

__all__ = ["Footprints", "FootprintOptions", "FootprintAssignment", "assign_footprints", "footprint_outlines",
           "footprint_attributes", "touching_points", "planar_spread", "tree_points", "last_returns",
           "chimney_edges", "STATUSES", "LEFT_OUT"]

log = logging.getLogger(__name__)

#: the status of a footprint building and what the model builders do with it
STATUSES = {
    "ok": "building points over the footprint: roof outline, planes and all levels of detail",
    "few_points": "fewer building points than min_points: LoD 1.2 from their heights on the footprint",
    "no_building_points": "the cloud covers the footprint but no building was detected on it: no model",
    "no_points": "no point of the cloud over the footprint: no model",
}

#: why a non-ground point over an ``ok`` footprint is not in its building (:attr:`FootprintAssignment.left_out`)
LEFT_OUT = {
    "low": "not building by the detection and under min_height / 2 above the ground (a fence, a car, a wall's foot)",
    "tree": "a tree's by footprints.tree_points: vegetation by the detection, or half or more of its 10 nearest "
            "non-ground points vegetation or returns that went on through, and those 10 points no plane within "
            "planar_vegetation; and no grazed edge of a chimney (footprints.chimney_edges)",
    "detached": "not building by the detection, no tree's, and neither unclassified min_height above the ground "
                "nor linked to the building's points within 2.5 point spacings in 3D (three links)",
    "not_building": "not building by the detection, and unclassified = false or no heights above the ground given",
}

#: nearest building points a candidate of :func:`touching_points` looks among for its own building's
TOUCH_NEIGHBOURS = 8

#: neighbours whose plane fit decides whether a point is on a roof or in a crown (``planar_vegetation``)
PLANAR_NEIGHBOURS = 10


@dataclass(frozen=True)
class Footprints:
    """Building footprints in the point cloud's CRS.

    Attributes
    ----------
    polygons : tuple of shapely.Polygon or MultiPolygon
        2D, metres, in the CRS of the cloud they go with.
    ids : tuple
        One identifier per polygon (int or str): the value of ``id_field``.
    id_field : str
        Name of the attribute the ids come from (``"fid"`` for the feature id).
    """

    polygons: tuple
    ids: tuple
    id_field: str = "fid"

    def __post_init__(self) -> None:
        if len(self.polygons) != len(self.ids):
            raise ValueError(f"Footprints: {len(self.ids)} ids for {len(self.polygons)} polygons")
        kinds = {shapely.get_type_id(p) for p in self.polygons}
        if not kinds <= {3, 6}:  # Polygon, MultiPolygon
            raise TypeError("Footprints: polygons must be shapely Polygons or MultiPolygons")

    def __len__(self) -> int:
        return len(self.polygons)


@dataclass(frozen=True)
class FootprintOptions:
    """Options of the footprint assignment (``[footprints]`` in the TOML config).

    Attributes
    ----------
    overhang : float, default 1.5
        Width (m) of the band around a footprint whose building points may
        belong to it: roof overhangs of Dutch and French houses reach
        0.2–1 m beyond the wall line, plus the LiDAR's planimetric error.
    min_points : int or None, default None
        Fewer building points make the footprint ``"few_points"`` (LoD 1.2
        only).  None: T_Np = Ar_min · d_avg with Ar_min = 4 m² (thesis
        §3.3), the smallest building the detection keeps.
    min_height : float, default 2.0
        A non-building point must stand this high (m) above the ground to
        count for a ``"few_points"`` fallback when no building point is
        there (a low shed or a missed roof still gives a LoD 1.2 block),
        or to join an ``"ok"`` footprint's points (``unclassified``).
    unclassified : bool, default True
        Inside an ``"ok"`` footprint, points the detection left unclassified
        (neither building, ground, vegetation nor noise) standing
        ``min_height`` above the ground belong to its building too: the
        footprint says a building stands there, and on AHN3 Delft two
        thirds of them are the provider's building points (chimneys,
        parapets and roof clutter too rough or too small for the
        detection's roof test), which the roof must model.  So do the
        unclassified points inside it or in its overhang band, half
        ``min_height`` above the ground, that touch the building's points
        (within 2.5 point spacings in 3D): judged by the building's own
        points, not by a class.
    planar_vegetation : float, default 0.05
        With ``unclassified``, the tree test (:func:`tree_points`): a point
        the detection called vegetation, or one amid vegetation or amid
        returns that went on through (half or more of its 10 nearest
        non-ground points), is a tree's unless those 10 points fit a plane
        within this RMS (m).  A tree's point never joins; any other non-building
        point over an ``"ok"`` footprint or in its band may (vegetation then
        joins like unclassified points that touch the building: a roof
        under a tree's edge, a lower roof part the detection's eigen-entropy
        test called vegetation).  0: the detection's vegetation is the
        trees, and nothing else is (the rule before the test).
    crown_extent : float, default 0.0
        With ``planar_vegetation``: the points the tree test calls a
        tree's, linked in 3D within 2.5 point spacings (and through the
        detection's vegetation nearby), that form a clump at most this wide
        in plan (m) are the roof's after all (:func:`small_clumps`): a
        chimney's or a dormer's edge, first of two returns where the pulse
        grazed it, looks as porous as a crown but is no wider.  Off by
        default: on AHN3 Delft with the BGT footprints 3 m takes
        ``top_building_mean`` 0.160 -> 0.145 m, but the non-building points
        that join are then 60 % AHN3 building points instead of 82 %, and
        over the footprint under a tree (BGT 503100000026154) 41 % instead
        of 78 %: a crown's fringe joins too.
    edge_drop : float, default 3.5
        With ``planar_vegetation`` and the pulses' last returns: a point of
        the tree test whose pulse ended on its footprint's building points
        (the detection's roof or the unclassified clutter standing on it)
        at most this far (m) under it, in a flat clump (``edge_spread``),
        is the edge of a chimney, a dormer or a parapet that the beam
        grazed (:func:`chimney_edges`), and joins its building.  A crown's
        pulses end on the ground or in lower foliage, or it stands metres
        over the roof, or its clump is rounded.  0: off.
    edge_spread : float, default 0.15
        The standard deviation (m) of the heights of the clump (the
        non-building points ``min_height / 2`` above the ground linked
        within 2.5 point spacings in 3D) within which it stands at one
        height: a chimney's or a parapet's top, not a crown.
    """

    section = "footprints"

    overhang: float = 1.5
    min_points: int | None = None
    min_height: float = 2.0
    unclassified: bool = True
    planar_vegetation: float = 0.05
    crown_extent: float = 0.0
    edge_drop: float = 3.5
    edge_spread: float = 0.15

    def __post_init__(self) -> None:
        if not np.isfinite(self.overhang) or self.overhang < 0:
            raise ValueError(f"footprints.overhang must be >= 0 metres, got {self.overhang!r}")
        if self.min_points is not None and self.min_points < 1:
            raise ValueError(f"footprints.min_points must be >= 1, got {self.min_points!r}")
        if not np.isfinite(self.min_height) or self.min_height < 0:
            raise ValueError(f"footprints.min_height must be >= 0 metres, got {self.min_height!r}")
        if not np.isfinite(self.planar_vegetation) or self.planar_vegetation < 0:
            raise ValueError(f"footprints.planar_vegetation must be >= 0 metres, got {self.planar_vegetation!r}")
        if not np.isfinite(self.crown_extent) or self.crown_extent < 0:
            raise ValueError(f"footprints.crown_extent must be >= 0 metres, got {self.crown_extent!r}")
        for name in ("edge_drop", "edge_spread"):
            value = getattr(self, name)
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"footprints.{name} must be >= 0 metres, got {value!r}")



@dataclass
class FootprintAssignment:
    """Result of :func:`assign_footprints`.

    Attributes
    ----------
    building_id : ndarray of shape (N,), int32
        1 + the footprint's index for the points that belong to a footprint
        building, 0 elsewhere (the ids of the output layers).
    status : list of str
        Per footprint, a key of :data:`STATUSES`.
    reason : list of str
        Per footprint, a sentence for the user ("" when ``"ok"``).
    n_inside, n_overhang : ndarray of shape (F,), int64
        Building points of each footprint inside it and in its overhang band.
    n_cloud : ndarray of shape (F,), int64
        Points of any class inside each footprint (0: not covered by the cloud).
    fallback : list of ndarray of int
        Per footprint, indices of the points a ``"few_points"`` LoD 1.2 takes
        its height from (building points, or high non-ground points when there
        are none); empty for the other statuses.
    params : dict
        The resolved options (``min_points`` derived from the density).
    touching : ndarray of int
        Indices of the points that joined a building by touching its points
        (``unclassified``): roof points, but not for the outline, which they
        would pull out over what lies beyond the building's own points.
    edges : ndarray of int
        Indices of the tree test's points that joined as a grazed edge
        (:func:`chimney_edges`; also in ``touching``), sorted.
    left_out : dict of str to ndarray of int
        Per reason of :data:`LEFT_OUT`, the indices of the non-ground,
        non-noise points inside an ``"ok"`` footprint that are not in its
        building (sorted); every such point is in exactly one list.
    """

    building_id: np.ndarray
    status: list[str]
    reason: list[str]
    n_inside: np.ndarray
    n_overhang: np.ndarray
    n_cloud: np.ndarray
    fallback: list[np.ndarray] = field(default_factory=list)
    params: dict[str, Any] = field(default_factory=dict)
    touching: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    edges: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    left_out: dict[str, np.ndarray] = field(default_factory=dict)


def _containing(polygons: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(point index, footprint index) pairs of points inside footprints (boundary included).

    Points are bucketed in a grid of cells about twice the median footprint
    size; each footprint tests only the points of the cells its bounding box
    covers, with ``shapely.contains_xy`` (no point objects: making a million
    shapely points costs more than the tests).
    """
    if len(xy) == 0 or len(polygons) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    bounds = shapely.bounds(polygons)
    size = np.maximum(bounds[:, 2] - bounds[:, 0], bounds[:, 3] - bounds[:, 1])
    cell = max(2.0 * float(np.median(size)), 1.0)
    lo = xy.min(axis=0)
    ij = np.floor((xy - lo) / cell).astype(np.int64)
    ny = int(ij[:, 1].max()) + 1
    key = ij[:, 0] * ny + ij[:, 1]
    order = np.argsort(key, kind="stable")
    skey = key[order]
    nx = int(ij[:, 0].max()) + 1
    pts, fps = [], []
    for f, (x0, y0, x1, y1) in enumerate(bounds):
        i0, i1 = np.clip(np.floor((np.array([x0, x1]) - lo[0]) / cell).astype(np.int64), 0, nx - 1)
        j0, j1 = np.clip(np.floor((np.array([y0, y1]) - lo[1]) / cell).astype(np.int64), 0, ny - 1)
        if x1 < lo[0] or y1 < lo[1] or x0 > lo[0] + nx * cell or y0 > lo[1] + ny * cell:
            continue
        cols = np.arange(i0, i1 + 1) * ny
        starts = np.searchsorted(skey, cols + j0, side="left")
        ends = np.searchsorted(skey, cols + j1, side="right")
        cand = np.concatenate([order[a:b] for a, b in zip(starts, ends)]) if len(cols) else np.zeros(0, np.int64)
        if not len(cand):
            continue
        x, y = xy[cand, 0], xy[cand, 1]
        cand = cand[(x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)]
        inside = cand[shapely.intersects_xy(polygons[f], xy[cand, 0], xy[cand, 1])]
        pts.append(inside)
        fps.append(np.full(len(inside), f, np.int64))
    if not pts:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(pts).astype(np.int64), np.concatenate(fps)


def _first_per_point(point: np.ndarray, footprint: np.ndarray, n: int) -> np.ndarray:
    """Per point, the lowest footprint index among its pairs (-1 without any): overlaps resolve deterministically."""
    owner = np.full(n, np.iinfo(np.int64).max, np.int64)
    np.minimum.at(owner, point, footprint)
    owner[owner == np.iinfo(np.int64).max] = -1
    return owner


def assign_footprints(
    xyz: np.ndarray,
    classification: np.ndarray,
    detected_id: np.ndarray,
    footprints: Footprints,
    options: FootprintOptions | None = None,
    *,
    hag: np.ndarray | None = None,
    density: float | None = None,
    through: np.ndarray | None = None,
    last_return: np.ndarray | None = None,
) -> FootprintAssignment:
    """Give every footprint its building points (roof above it plus the overhang band).

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), float64
        Points (m), in the footprints' CRS.
    classification : ndarray of shape (N,), uint8
        ASPRS classes from the detection (6 building, 2 ground, 7 noise).
    detected_id : ndarray of shape (N,), int
        Building id from the detection (0 = none): a band point joins a
        footprint only when its detected building has points inside it.
    footprints : Footprints
    options : FootprintOptions, optional
    hag : ndarray of shape (N,), float64, optional
        Height above ground (m); without it no non-building fallback points
        are taken.
    density : float, optional
        d_avg (pts/m²), for the derived ``min_points``.
    through : ndarray of shape (N,), bool, optional
        Per point, whether its pulse had a later return
        (``return_number < number_of_returns``): with it a crown the
        detection left unclassified is told from roof clutter
        (:func:`tree_points`).
    last_return : ndarray of shape (N,), int, optional
        Per point, the index of its pulse's last return (itself for a
        single or last return; :func:`last_returns`): with it a chimney's
        grazed edge is told from a crown (:func:`chimney_edges`).

    Returns
    -------
    FootprintAssignment

    Notes
    -----
    Overlapping footprints (a data error, but it happens) give a point to the
    one listed first.  Inside tests include the boundary.  The band point's
    nearest footprint is found with ``STRtree.query_nearest``; equidistant
    footprints go to the lowest index, so the result does not depend on the
    order of the points.

    Examples
    --------
    >>> import shapely
    >>> fp = Footprints((shapely.box(0, 0, 10, 10),), ("a",))
    >>> xyz = np.array([[5.0, 5.0, 6.0], [10.8, 5.0, 5.5], [30.0, 5.0, 6.0]])
    >>> res = assign_footprints(xyz, np.array([6, 6, 6]), np.array([1, 1, 2]), fp,
    ...                         FootprintOptions(min_points=1))
    >>> res.building_id.tolist(), res.status
    ([1, 1, 0], ['ok'])
    """
    options = options or FootprintOptions()
    xyz = np.asarray(xyz, dtype=np.float64)
    classification = np.asarray(classification)
    detected_id = np.asarray(detected_id).astype(np.int64)
    n, f = len(xyz), len(footprints)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise ValueError(f"assign_footprints: xyz must have shape (N, 3), got {xyz.shape}")
    if len(classification) != n or len(detected_id) != n \
            or any(a is not None and len(a) != n for a in (hag, through, last_return)):
        raise ValueError("assign_footprints: classification, detected_id, hag, through and last_return need one "
                         "value per point")
    min_points = options.min_points
    if min_points is None:
        min_points = max(3, int(np.ceil(4.0 * density))) if density and np.isfinite(density) else 10
    polygons = np.asarray(footprints.polygons, dtype=object)
    tree = shapely.STRtree(polygons)

    # which footprint holds each point (any class: the coverage counts them too)
    shapely.prepare(polygons)
    all_p, all_f = _containing(polygons, xyz[:, :2])
    all_owner = _first_per_point(all_p, all_f, n)
    n_cloud = np.bincount(all_owner[all_owner >= 0], minlength=f).astype(np.int64)

    building = np.flatnonzero(classification == ASPRS.BUILDING)
    inside_owner = all_owner[building]
    owner = inside_owner.copy()

    # the band: building points outside every footprint, near one, whose detected building reaches inside it
    outside = np.flatnonzero(inside_owner < 0)
    n_overhang = np.zeros(f, np.int64)
    if len(outside) and options.overhang > 0:
        # only points in some footprint's band are worth a distance (most of a cloud is far from any)
        bands = shapely.buffer(polygons, options.overhang, quad_segs=4)
        shapely.prepare(bands)
        near_any = np.unique(_containing(bands, xyz[building[outside], :2])[0])
        outside = outside[near_any]
    if len(outside) and options.overhang > 0:
        pts = shapely.points(xyz[building[outside], :2])
        near_p, near_f = tree.query_nearest(pts, max_distance=options.overhang, all_matches=True)
        near = _first_per_point(near_p, near_f, len(outside))
        hit = np.flatnonzero(near >= 0)
        # pairs (detected building, footprint) with points inside: keys b * f + i
        det_in = detected_id[building[inside_owner >= 0]]
        inside_keys = np.unique(det_in[det_in > 0] * f + inside_owner[inside_owner >= 0][det_in > 0])
        det_band = detected_id[building[outside[hit]]]
        ok = (det_band > 0) & np.isin(det_band * f + near[hit], inside_keys)
        owner[outside[hit[ok]]] = near[hit[ok]]
        n_overhang = np.bincount(near[hit[ok]], minlength=f).astype(np.int64)

    building_id = np.zeros(n, np.int32)
    assigned = owner >= 0
    building_id[building[assigned]] = (owner[assigned] + 1).astype(np.int32)
    n_inside = np.bincount(inside_owner[inside_owner >= 0], minlength=f).astype(np.int64)
    n_total = n_inside + n_overhang


    status, reason, fallback = [], [], []
    touching = edges = np.zeros(0, np.int64)
    high = None
    if hag is not None:
        hag = np.asarray(hag, dtype=np.float64)
        high = (hag >= options.min_height) & ~np.isin(classification, (ASPRS.GROUND, ASPRS.NOISE))
    members_sorted = np.argsort(building_id, kind="stable")
    starts = np.searchsorted(building_id[members_sorted], np.arange(1, f + 2))
    for i in range(f):
        own = members_sorted[starts[i]:starts[i + 1]]
        if n_total[i] >= min_points:
            status.append("ok")
            reason.append("")
            fallback.append(np.zeros(0, np.int64))
            continue
        if n_cloud[i] == 0:
            status.append("no_points")
            reason.append("no point of the cloud over the footprint (outside the cloud or a data gap)")
            fallback.append(np.zeros(0, np.int64))
            continue
        source = own
        if len(source) == 0 and high is not None:
            source = np.flatnonzero((all_owner == i) & high)
        if len(source):
            status.append("few_points")
            reason.append(f"{n_total[i]} building points (fewer than {min_points}); LoD 1.2 from "
                          f"{len(source)} {'building' if len(own) else 'non-ground'} points")
            fallback.append(np.sort(source))
            # too few to outline or fit planes: the fallback block takes them
            building_id[own] = 0
        else:
            status.append("no_building_points")
            reason.append(f"{n_cloud[i]} points over the footprint, none of a building or higher than "
                          f"{options.min_height:g} m above the ground")
            fallback.append(np.zeros(0, np.int64))
            building_id[own] = 0
    ok = np.array([s == "ok" for s in status] + [False])  # index -1: in no footprint
    trees = np.zeros(0, np.int64)
    spacing = 1.0 / np.sqrt(density) if density and np.isfinite(density) and density > 0 else 0.5
    if high is not None and options.unclassified:
        # the points the detection called neither building, ground nor noise, over an ok footprint or in its band
        other = np.flatnonzero(np.isin(classification, (ASPRS.UNCLASSIFIED, ASPRS.HIGH_VEGETATION))
                               & (hag >= options.min_height / 2))
        where = _near_ok_footprint(other, xyz, all_owner, ok, polygons, tree, options.overhang)
        other, where = other[where >= 0], where[where >= 0]
        tree_like = tree_points(xyz, other, classification, options.planar_vegetation, through=through)
        if options.crown_extent > 0 and tree_like.any():
            # a chimney's grazed edge is as porous as a crown, but no wider than a chimney
            leafy = np.flatnonzero((classification == ASPRS.HIGH_VEGETATION) & (hag >= options.min_height / 2))
            tree_like[tree_like] = ~small_clumps(xyz, other[tree_like], 2.5 * spacing, options.crown_extent,
                                                 among=leafy)
        # standing in the footprint: chimneys, parapets, clutter too rough for the detection's roof test
        standing = ~tree_like & (all_owner[other] >= 0) & (classification[other] == ASPRS.UNCLASSIFIED) \
            & (hag[other] >= options.min_height)
        building_id[other[standing]] = (where[standing] + 1).astype(np.int32)
        edge = np.zeros(len(other), bool)
        if options.edge_drop > 0 and last_return is not None and tree_like.any():
            # a beam that grazed a chimney's top returned from it and then from the roof at its foot (the
            # detection's roof or the clutter standing on it)
            porous = np.flatnonzero(np.isin(classification, (ASPRS.UNCLASSIFIED, ASPRS.HIGH_VEGETATION))
                                    & (hag >= options.min_height / 2))
            edge[tree_like] = chimney_edges(xyz, other[tree_like], where[tree_like] + 1, building_id, last_return,
                                            2.5 * spacing, options.edge_drop, options.edge_spread, among=porous)
            tree_like &= ~edge
        trees, edges = other[tree_like], other[edge]
        building_id[edges] = (where[edge] + 1).astype(np.int32)
        # the rest joins when it touches the building's own points, in the footprint or its band (a chimney of a
        # few points, clutter along the eaves, a shed roof under min_height, a roof the detection called
        # vegetation): roof points, not outline points; so are the grazed edges, which hang beside their chimney
        rest = ~tree_like & ~edge & ~standing
        joined, to = touching_points(xyz, other[rest], building_id, 2.5 * spacing, owner=where[rest] + 1)
        building_id[joined] = to.astype(np.int32)
        touching = np.sort(np.concatenate([joined, edges]))
    left_out = _left_out(classification, building_id, all_owner, ok, hag, options, trees)
    counts = {s: status.count(s) for s in STATUSES}
    log.debug("footprints: %s", counts)
    return FootprintAssignment(building_id, status, reason, n_inside, n_overhang, n_cloud, fallback,
                               params={"overhang": options.overhang, "min_points": int(min_points),
                                       "min_height": options.min_height, "unclassified": options.unclassified,
                                       "planar_vegetation": options.planar_vegetation,
                                       "edge_drop": options.edge_drop if last_return is not None else 0.0},
                               touching=touching, edges=np.sort(edges), left_out=left_out)


def _near_ok_footprint(points: np.ndarray, xyz: np.ndarray, all_owner: np.ndarray, ok: np.ndarray,
                       polygons: np.ndarray, tree: shapely.STRtree, overhang: float) -> np.ndarray:
    """Per point, the ``"ok"`` footprint it lies in, or else the nearest footprint within ``overhang`` (m) if ok; -1.

    ``ok`` has one more entry than there are footprints (False: index -1).
    """
    where = all_owner[points].copy()
    out = np.flatnonzero(where < 0)
    if len(out) and overhang > 0:
        # only points in some ok footprint's band are worth a distance: the bands circumscribe the true
        # ones (quad_segs 4 chords lie inside a circle), the distance then decides
        bands = shapely.buffer(polygons[ok[:-1]], overhang / np.cos(np.pi / 16), quad_segs=4)
        shapely.prepare(bands)
        out = out[np.unique(_containing(bands, xyz[points[out], :2])[0])]
    if len(out):
        p, f_ = tree.query_nearest(shapely.points(xyz[points[out], :2]), max_distance=overhang, all_matches=True)
        where[out] = _first_per_point(p, f_, len(out))
    where[~ok[where]] = -1
    return where


def planar_spread(xyz: np.ndarray, points: np.ndarray, among: np.ndarray, k: int = PLANAR_NEIGHBOURS) -> np.ndarray:
    """RMS distance (m) of each point's ``k`` nearest neighbours (3D) to their best-fitting plane.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), float64
        Points (m).
    points : ndarray of int
        Indices of the points to test.
    among : ndarray of shape (N,), bool
        The points that count as neighbours (a tested point is one of its
        own neighbours when it is among them).
    k : int
        Neighbours per point.

    Returns
    -------
    ndarray of shape (len(points),), float64
        The square root of the smallest eigenvalue of the neighbours'
        covariance: a roof's noise (centimetres) on a roof, decimetres in a
        crown.  ``inf`` where fewer than 3 neighbours exist.
    """
    return _neighbourhood(xyz, points, among, k)[0]


def _neighbourhood(xyz: np.ndarray, points: np.ndarray, among: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`planar_spread` and the indices (into ``xyz``) of the ``k`` neighbours, shape (len(points), k)."""
    points = np.asarray(points, dtype=np.int64)
    pool = np.flatnonzero(among)
    none = (np.full(len(points), np.inf), np.zeros((len(points), 0), np.int64))
    if len(points) == 0 or len(pool) < 3:
        return none
    # only the pool near the tested points is worth a tree (most of a cloud is far from them): the
    # 4 m cells around theirs hold every neighbour within 4 m, farther ones say nothing of a roof plane
    pool = _near_cells(xyz, points, pool, 4.0)
    if len(pool) < 3:
        return none
    k = min(k, len(pool))
    _, j = cKDTree(xyz[pool]).query(xyz[points], k=k)
    j = pool[j.reshape(len(points), k)]
    nb = xyz[j] - xyz[j].mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", nb, nb) / k
    return np.sqrt(np.clip(np.linalg.eigvalsh(cov)[:, 0], 0.0, None)), j


def tree_points(xyz: np.ndarray, points: np.ndarray, classification: np.ndarray, planar: float, *,
                through: np.ndarray | None = None, k: int = PLANAR_NEIGHBOURS) -> np.ndarray:
    """Which of ``points`` are a tree's: vegetation, or amid vegetation or porous returns; and not on a plane.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), float64
        Points (m).
    points : ndarray of int
        Indices of the points to judge.
    classification : ndarray of shape (N,), uint8
        ASPRS classes of the detection (5 vegetation, 2 ground, 7 noise).
    planar : float
        RMS (m) of a plane fit through the ``k`` nearest non-ground,
        non-noise points (:func:`planar_spread`) within which they are a
        roof, whatever else is said of them; 0: the vegetation points are a
        tree's and no other.
    through : ndarray of shape (N,), bool, optional
        Per point, whether its pulse had a later return (return number
        under the number of returns): the pulse went on through a crown
        (or past an edge).  None when the cloud has no return numbers.
    k : int
        Neighbours.

    Returns
    -------
    ndarray of shape (len(points),), bool
        True for a tree's point: the detection called it vegetation, or
        half or more of its ``k`` nearest non-ground points are vegetation
        or returns that went on through; and neither those points nor its
        ``k`` nearest non-ground points the detection did not call
        building fit a plane within ``planar``.
        A roof under a tree's edge or a lower roof part the eigen-entropy
        test called vegetation lies on a plane; a chimney's top amid the
        roof's single returns is none; a crown, even where the detection
        left it unclassified, is porous and rough.
    """
    points = np.asarray(points, dtype=np.int64)
    leafy = classification[points] == ASPRS.HIGH_VEGETATION
    if planar <= 0 or len(points) == 0:
        return leafy
    solid = ~np.isin(classification, (ASPRS.GROUND, ASPRS.NOISE))
    spread, nb = _neighbourhood(xyz, points, solid, k)
    if nb.shape[1] == 0:
        return leafy
    # a lower roof part's edge mixes its points with the roof's above it: its plane shows without them
    spread = np.minimum(spread, planar_spread(xyz, points, solid & (classification != ASPRS.BUILDING), k))
    amid = np.mean(classification[nb] == ASPRS.HIGH_VEGETATION, axis=1) >= 0.5
    if through is not None:
        amid |= np.mean(np.asarray(through, dtype=bool)[nb], axis=1) >= 0.5
    return (leafy | amid) & ~(spread <= planar)


def small_clumps(xyz: np.ndarray, points: np.ndarray, link: float, max_extent: float, *,
                 among: np.ndarray | None = None) -> np.ndarray:
    """Which of ``points`` lie in a clump at most ``max_extent`` (m) across in plan.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), float64
        Points (m).
    points : ndarray of int
        Indices of the points to group: a clump is a connected component of
        them linked within ``link`` (m, 3D).
    link : float
    max_extent : float
        Widest side (m) of a clump's plan bounding box.
    among : ndarray of int, optional
        Other points that link the clumps and widen them without being
        judged (a crown's points beyond the footprint's band).

    Returns
    -------
    ndarray of shape (len(points),), bool

    Examples
    --------
    >>> xyz = np.array([[0.0, 0, 9], [0.5, 0, 9], [10, 0, 9], [10.5, 0, 9], [11, 0, 9], [14.5, 0, 9]])
    >>> small_clumps(xyz, np.arange(6), 0.6, 0.5).tolist()
    [True, True, False, False, False, True]
    """
    points = np.asarray(points, dtype=np.int64)
    if len(points) == 0:
        return np.zeros(0, dtype=bool)
    if among is not None and len(among):
        among = np.setdiff1d(np.asarray(among, dtype=np.int64), points)
        d, _ = cKDTree(xyz[points]).query(xyz[among], distance_upper_bound=max_extent + link)
        points_all = np.concatenate([points, among[np.isfinite(d)]])
    else:
        points_all = points
    pairs = cKDTree(xyz[points_all]).query_pairs(link, output_type="ndarray")
    comp = components(len(points_all), pairs)
    n = int(comp.max()) + 1
    xy = xyz[points_all, :2]
    lo = np.full((n, 2), np.inf)
    hi = np.full((n, 2), -np.inf)
    np.minimum.at(lo, comp, xy)
    np.maximum.at(hi, comp, xy)
    return (hi - lo).max(axis=1)[comp[:len(points)]] <= max_extent


def last_returns(gps_time: np.ndarray, source: np.ndarray, return_number: np.ndarray,
                 number_of_returns: np.ndarray) -> np.ndarray:
    """Per point, the index of the last return of its pulse (itself for a single or a last return).

    Parameters
    ----------
    gps_time : ndarray of shape (N,), float64
        Time of the pulse (s): the returns of one pulse share it.
    source : ndarray of shape (N,), int
        Flight line (``point_source_id``): two strips may repeat a time.
    return_number, number_of_returns : ndarray of shape (N,), int
        LAS return fields.

    Returns
    -------
    ndarray of shape (N,), int64
        A return whose pulse's last return is missing (cut off by a tile's
        edge, or a sensor's dropped echo) gets the highest-numbered return
        of its pulse present, and one alone in its pulse itself.

    Examples
    --------
    >>> last_returns(np.array([5.0, 7.0, 5.0, 5.0]), np.array([1, 1, 1, 2]), np.array([1, 1, 2, 1]),
    ...              np.array([2, 1, 2, 1])).tolist()
    [2, 1, 2, 3]
    """
    n = len(gps_time)
    last = np.arange(n, dtype=np.int64)
    multi = np.flatnonzero(np.asarray(number_of_returns) > 1)
    if not len(multi):
        return last
    rn = np.asarray(return_number)[multi]
    order = np.lexsort((rn, np.asarray(gps_time)[multi], np.asarray(source)[multi]))
    m = multi[order]
    t, s = np.asarray(gps_time)[m], np.asarray(source)[m]
    # the pulse of each sorted return, and its highest-numbered return (the last in the sort)
    new = np.r_[True, (t[1:] != t[:-1]) | (s[1:] != s[:-1])]
    pulse = np.cumsum(new) - 1
    ends = np.r_[np.flatnonzero(new)[1:], len(m)] - 1
    last[m] = m[ends[pulse]]
    return last


def chimney_edges(xyz: np.ndarray, points: np.ndarray, owner: np.ndarray, building_id: np.ndarray,
                  last_return: np.ndarray, link: float, max_drop: float, spread: float, *,
                  among: np.ndarray | None = None) -> np.ndarray:
    """Which of ``points`` are the grazed edge of a chimney, a dormer or a parapet on their building.

    A beam that grazes a chimney's top returns first from it and last from
    the roof at its foot: the first return hangs beside the chimney at its
    top's height, as porous as a crown's.  A crown's pulses end on the
    ground, in lower foliage or on a roof far under it, and its points
    spread over its rounded height; a chimney's top stands at one height.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), float64
        Points (m).
    points : ndarray of int
        Indices of the points to judge.
    owner : ndarray of int
        Per judged point, the building id whose roof its pulse must end on.
    building_id : ndarray of shape (N,), int
        The buildings' points so far (0: none): those a grazing pulse may
        end on.
    last_return : ndarray of shape (N,), int
        Per point, its pulse's last return (:func:`last_returns`).
    link : float
        3D distance (m) that links points into a clump.
    max_drop : float
        Greatest height (m) of the last return under the point: a box's
        height over the roof.
    spread : float
        Greatest standard deviation (m) of the heights of the point's clump.
    among : ndarray of int, optional
        Other points the clumps are made of, judged or not (the crown
        beyond a footprint's band); the judged points always count.

    Returns
    -------
    ndarray of shape (len(points),), bool
        True where the point's pulse ended on a point of ``owner`` less than
        ``max_drop`` under it and its clump's heights spread at most
        ``spread``.

    Examples
    --------
    >>> xyz = np.array([[0.0, 0, 6], [0.2, 0, 6.05], [0.1, 0, 5], [5, 0, 9], [5.2, 0, 7], [5.1, 0, 5]])
    >>> chimney_edges(xyz, np.array([0, 1, 3, 4]), np.array([1, 1, 1, 1]), np.array([0, 0, 1, 0, 0, 1]),
    ...               np.array([2, 2, 2, 5, 5, 5]), 2.1, 3.5, 0.15).tolist()
    [True, True, False, False]
    """
    points = np.asarray(points, dtype=np.int64)
    if len(points) == 0:
        return np.zeros(0, dtype=bool)
    last = np.asarray(last_return)[points]
    drop = xyz[points, 2] - xyz[last, 2]
    landed = (last != points) & (drop > 0) & (drop <= max_drop) & (building_id[last] == owner)
    if not landed.any():
        return landed
    # the clumps of the landed points, with every point within reach that may widen or deepen them
    pool = np.unique(points)  # sorted: each judged point's clump is found by a binary search
    if among is not None and len(among):
        pool = np.union1d(pool, _near_cells(xyz, points[landed], np.asarray(among, dtype=np.int64),
                                              max(2.0, 10 * link)))
    comp = components(len(pool), cKDTree(xyz[pool]).query_pairs(link, output_type="ndarray"))
    n = int(comp.max()) + 1
    count = np.bincount(comp, minlength=n)
    z = xyz[pool, 2] - xyz[pool, 2].mean()  # centred: the variance by sums of squares stays exact
    mean = np.bincount(comp, z, n) / count
    var = np.bincount(comp, z ** 2, n) / count - mean ** 2
    flat = np.sqrt(np.clip(var, 0.0, None)) <= spread
    return landed & flat[comp[np.searchsorted(pool, points)]]


def _near_cells(xyz: np.ndarray, points: np.ndarray, among: np.ndarray, cell: float) -> np.ndarray:
    """The ``among`` points in the plan cells (``cell`` metres wide) of ``points`` and their 8 neighbours.

    Every point within ``cell`` of one of ``points`` in plan is among them; a cell key per point and a
    membership test cost less than a tree over a cloud's worth of ``among``.
    """
    lo = xyz[points, :2].min(axis=0) - 2 * cell
    mine = np.floor((xyz[points, :2] - lo) / cell).astype(np.int64)
    ny = int(mine[:, 1].max()) + 3
    step = np.array([-1, 0, 1])
    keys = np.unique((mine[:, 0, None, None] + step[:, None]) * ny + (mine[:, 1, None, None] + step[None, :]))
    theirs = np.floor((xyz[among, :2] - lo) / cell).astype(np.int64)
    inside = (theirs >= 0).all(axis=1) & (theirs[:, 1] < ny)
    return among[inside][np.isin(theirs[inside, 0] * ny + theirs[inside, 1], keys)]


def _left_out(classification: np.ndarray, building_id: np.ndarray, all_owner: np.ndarray, ok: np.ndarray,
              hag: np.ndarray | None, options: FootprintOptions, trees: np.ndarray) -> dict[str, np.ndarray]:
    """The non-ground, non-noise points inside an ``"ok"`` footprint not in its building, by reason of :data:`LEFT_OUT`.

    The reasons follow the rules of :func:`assign_footprints`: a building
    point inside a footprint always joins it; without heights or with
    ``unclassified`` off nothing else does; then near the ground; a tree's
    (``trees``, by :func:`tree_points`); any other that did not join was not
    linked to the building.
    """
    over = np.flatnonzero(ok[all_owner] & ~np.isin(classification, (ASPRS.GROUND, ASPRS.NOISE)))
    out = over[building_id[over] != all_owner[over] + 1]
    if hag is None or not options.unclassified:
        return {"not_building": out}
    low = hag[out] < options.min_height / 2
    tree_like = ~low & np.isin(out, trees)
    return {"low": out[low], "tree": out[tree_like], "detached": out[~low & ~tree_like]}


def touching_points(xyz: np.ndarray, candidates: np.ndarray, building_id: np.ndarray, link: float, *,
                    owner: np.ndarray | None = None, rounds: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """The ``candidates`` that touch a building's points, and that building.

    A candidate touches a building when its nearest point of a building
    (``building_id > 0``) lies within ``link`` (m, 3D), or its nearest
    candidate that joined in the round before does (``rounds`` rounds: a
    chain of clutter reaches from the roof).  With ``owner``, the nearest
    point of that building among the ``TOUCH_NEIGHBOURS`` nearest counts,
    though another building's be nearer.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), float64
    candidates : ndarray of int
        Indices of the points that may join.
    building_id : ndarray of shape (N,), int
        0 for none.
    link : float
        3D distance (m).
    owner : ndarray of int, optional
        Per candidate, the only building id it may join (a footprint's);
        default any.
    rounds : int

    Returns
    -------
    joined : ndarray of int
        Point indices.
    to : ndarray of int
        The building id each joins.
    """
    joined, to = [], []
    members = np.flatnonzero(building_id > 0)
    ids = building_id[members].astype(np.int64)
    candidates = np.asarray(candidates, dtype=np.int64)
    for _ in range(rounds):
        if not len(candidates) or not len(members):
            break
        if owner is None:
            d, j = cKDTree(xyz[members]).query(xyz[candidates], distance_upper_bound=link)
            hit = np.isfinite(d)
            j = np.where(hit, j, 0)
        else:
            # the nearest point of the candidate's own building within the link, though another's be nearer
            # (a neighbour's roof edge beside a footprint's band)
            k = min(TOUCH_NEIGHBOURS, len(members))
            d, jj = cKDTree(xyz[members]).query(xyz[candidates], k=k, distance_upper_bound=link)
            d, jj = d.reshape(len(candidates), k), jj.reshape(len(candidates), k)
            mine = np.isfinite(d)
            mine[mine] = ids[jj[mine]] == np.broadcast_to(owner[:, None], jj.shape)[mine]
            hit = mine.any(axis=1)
            j = jj[np.arange(len(candidates)), np.argmax(mine, axis=1)]
        if not hit.any():
            break
        joined.append(candidates[hit])
        to.append(ids[j[hit]])
        members, ids = candidates[hit], ids[j[hit]]
        candidates = candidates[~hit]
        owner = owner[~hit] if owner is not None else None
    if not joined:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(joined), np.concatenate(to)


def _nearest_zone(footprint, neighbours, extent, step: float = 0.1):
    """The plan region closer to ``footprint`` than to any of ``neighbours`` (within ``extent``'s envelope).

    A Voronoi diagram of the footprints' boundaries sampled every ``step``
    metres: the cells of this footprint's samples, merged.  It splits the
    street-side overhang of a row where the party wall meets the facade, as
    the band assignment of the points does.
    """
    mine = shapely.get_coordinates(shapely.segmentize(footprint.boundary, step))
    others = shapely.union_all(neighbours)
    theirs = shapely.get_coordinates(shapely.segmentize(others.boundary, step))
    # a shared wall is sampled by both sides: drop it from both, the footprints themselves decide there,
    # and the bisector of the nearest samples on each side of a wall's end stays within step / 2 of it
    shared = footprint.boundary.intersection(others.boundary).buffer(1e-6)
    mine = mine[~shapely.intersects_xy(shared, mine[:, 0], mine[:, 1])]
    theirs = theirs[~shapely.intersects_xy(shared, theirs[:, 0], theirs[:, 1])]
    pts = np.vstack([mine, theirs])
    pts, first = np.unique(np.round(pts, 6), axis=0, return_index=True)
    own = first < len(mine)
    envelope = shapely.box(*shapely.union_all([extent, footprint]).buffer(1.0).bounds)
    cells = shapely.get_parts(shapely.voronoi_polygons(shapely.multipoints(pts), extend_to=envelope))
    # voronoi_polygons returns the cells in no guaranteed order: match each to the sample inside it
    tree = shapely.STRtree(cells)
    owner_of_cell = np.zeros(len(cells), bool)
    pi, ci = tree.query(shapely.points(pts), predicate="intersects")
    owner_of_cell[ci[own[pi]]] = True
    zone = shapely.union_all(cells[owner_of_cell])
    # inside a footprint the cadastre decides, not the distance to the boundary
    return shapely.union_all([zone.intersection(envelope), footprint]).difference(
        shapely.union_all(neighbours).difference(footprint))


def footprint_outlines(outlines: list, footprints: Footprints, assignment: FootprintAssignment,
                       xyz: np.ndarray, *, overhang: float | None = None) -> list:
    """One roof outline per footprint, in footprint order: the traced one, or the footprint's fallback.

    A traced outline (the outline stage run on the footprint's points) is
    clipped off the neighbouring footprints, so the roofs of two houses
    sharing a wall do not overlap; it keeps its overhang over the street.
    A ``"few_points"`` footprint gets the footprint itself at the 70th
    percentile of its fallback points' heights (3DBAG's LoD 1.2 roof height);
    ``"no_points"``, ``"no_building_points"`` ones no geometry, the status
    saying why.

    Parameters
    ----------
    outlines : list of RoofOutline
        From :func:`rooftrace.contour.outline.outline_buildings` on
        ``assignment.building_id`` (building id = footprint index + 1).
    footprints : Footprints
    assignment : FootprintAssignment
    xyz : ndarray of shape (N, 3), float64
        The points ``assignment`` indexes.
    overhang : float, optional
        Search distance (m) for the neighbouring footprints; default from
        ``assignment.params``.

    Returns
    -------
    list of RoofOutline
        ``len(footprints)`` outlines, ``building_id`` = index + 1.
    """
    from rooftrace.contour.outline import RoofOutline

    overhang = assignment.params.get("overhang", 1.5) if overhang is None else overhang
    by_id = {o.building_id: o for o in outlines}
    polygons = np.asarray(footprints.polygons, dtype=object)
    tree = shapely.STRtree(polygons)
    out = []
    for i, fp in enumerate(footprints.polygons):
        bid = i + 1
        outline = by_id.get(bid)
        if outline is not None and outline.polygon is not None:
            near = [j for j in tree.query(fp.buffer(2.0 * overhang)) if j != i]
            if near:
                zone = _nearest_zone(fp, polygons[near], outline.polygon)
                clipped = shapely.make_valid(outline.polygon.intersection(zone))
                parts = [g for g in shapely.get_parts(clipped) if g.geom_type == "Polygon" and g.area > 0]
                if parts:
                    outline.polygon = shapely.geometry.polygon.orient(max(parts, key=lambda g: g.area), 1.0)
            out.append(outline)
            continue
        status = assignment.status[i]
        src = assignment.fallback[i] if i < len(assignment.fallback) else np.zeros(0, np.int64)
        if status == "few_points" and len(src):
            z = xyz[src, 2]
            height = float(np.percentile(z, 70))
            ring = shapely.force_3d(fp if fp.geom_type == "Polygon" else max(fp.geoms, key=lambda g: g.area), height)
            out.append(RoofOutline(bid, shapely.geometry.polygon.orient(ring, 1.0), n_points=len(src),
                                   status="few_points", z_min=float(z.min()), z_mean=float(z.mean()),
                                   z_max=float(z.max())))
        elif outline is not None:  # points, but the outline stage failed: its status says why
            out.append(outline)
        else:
            out.append(RoofOutline(bid, None, n_points=0, status=status))
    return out


def footprint_attributes(footprints: Footprints, assignment: FootprintAssignment) -> dict[str, list]:
    """Per footprint (in order) the columns the ``roof_outlines`` layer gets: id, status, reason, point counts."""
    return {
        "footprint_id": list(footprints.ids),
        "footprint_status": list(assignment.status),
        "footprint_reason": list(assignment.reason),
        "n_inside": assignment.n_inside.tolist(),
        "n_overhang": assignment.n_overhang.tolist(),
    }
