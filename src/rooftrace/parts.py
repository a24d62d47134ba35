"""Building parts of a LiDAR-only building: split where the data shows a boundary.

Without footprints, a terraced row comes out of the detection as one
building (its roofs touch in plan).  Its houses show in the roof where

* a **height step** runs between two roof faces (neighbours of different
  heights: the faces' planes differ by more than ``step_height`` along their
  shared edge), or
* a **gutter** runs between two roof planes that slope towards each other
  from opposite sides (aspects more than ``gutter_angle`` apart, the shared
  edge the lowest line of both): the party-wall line between two gabled
  houses whose ridges run across the row.

Faces joined by anything else (ridges, hips, valleys of an L-shaped roof,
coplanar continuations) stay in one part.  Parts too small to be a house
(``min_area``) or owning too little of the building's outline
(``min_facade``: a dormer or a roof terrace inside the roof owns none) merge
into the neighbour they share the longest edge with.  A row of identical
roofs at one height gives no boundary and stays one part: nothing in the
points tells its houses apart (footprints do, see :mod:`rooftrace.footprints`).

The part polygons partition the building's roof outline; every point gets
the part whose polygon holds it (the nearest one for points just outside).
Everything is numpy/shapely in and out.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
import shapely

from rooftrace.graph import components

__all__ = ["PartOptions", "BuildingParts", "split_parts", "parts_layer"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PartOptions:
    """Options of the building-part split (``[parts]`` in the TOML config).

    Attributes
    ----------
    step_height : float, default 0.5
        Height jump (m) between two neighbouring roof faces along their
        shared edge that separates two parts, as the roof stage's step edges
        (``[planes] step_height``): neighbouring houses of one row differ by
        0.3–1.5 m at the eaves, and the planes' heights at their shared
        edge are known to a few centimetres.
    gutter_angle : float, default 135.0
        Two planes sloping towards their shared edge whose downslope
        directions differ by more than this (deg) meet in a gutter between
        two houses; the valleys of L- and T-shaped roofs meet at about 90°.
    min_slope : float, default 10.0
        Planes flatter than this (deg) have no reliable aspect and make no
        gutter.
    min_area : float, default 15.0
        Parts smaller than this (m²) merge into a neighbour (dormers,
        chimneys' faces, roof clutter); the smallest Dutch row houses are
        about 4 m x 6 m.
    min_facade : float, default 2.0
        A part must own this much (m) of the building's outline, or it
        merges into a neighbour: a dormer stands inside the roof.
    min_edge : float, default 0.5
        Shared face edges shorter than this (m) join nothing and split
        nothing; nor do faces smaller than its square (slivers of the face
        partition), which go with the part they share most edge with.
    """

    section = "parts"

    step_height: float = 0.5
    gutter_angle: float = 135.0
    min_slope: float = 10.0
    min_area: float = 15.0
    min_facade: float = 2.0
    min_edge: float = 0.5

    def __post_init__(self) -> None:
        for name in ("step_height", "min_area", "min_facade", "min_edge"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"parts.{name} must be >= 0, got {v!r}")
        if not 90.0 <= self.gutter_angle <= 180.0:
            raise ValueError(f"parts.gutter_angle must be in [90, 180] degrees, got {self.gutter_angle!r}")
        if not 0.0 <= self.min_slope < 90.0:
            raise ValueError(f"parts.min_slope must be in [0, 90) degrees, got {self.min_slope!r}")



@dataclass
class BuildingParts:
    """The parts of one building.

    Attributes
    ----------
    building_id : int
    part_id : ndarray of shape (N,), int32
        1..P per point of the building (in the order given).
    polygons : list of shapely.Polygon
        2D, part ``p`` at index ``p - 1``: a partition of the outline.
    boundaries : list of str
        Per split made, why (``"step"`` or ``"gutter"``); empty for one part.
    """

    building_id: int
    part_id: np.ndarray
    polygons: list = field(default_factory=list)
    boundaries: list = field(default_factory=list)

    @property
    def n_parts(self) -> int:
        return len(self.polygons)


def _outline_2d(outline):
    outline = shapely.make_valid(shapely.force_2d(outline))
    polys = [g for g in shapely.get_parts(outline) if g.geom_type == "Polygon" and g.area > 0]
    return max(polys, key=lambda g: g.area) if polys else None


def _one_part(building_id: int, n: int, outline) -> BuildingParts:
    return BuildingParts(building_id, np.ones(n, np.int32), [outline] if outline is not None else [], [])


def _union_each(geoms: np.ndarray, group: np.ndarray) -> np.ndarray:
    """``shapely.union_all`` of each run of equal ``group`` values (sorted) in ``geoms``, in one call.

    The rows of a None-padded table are unioned one by one (``axis=1``;
    None is skipped), each from the same geometries in the same order as
    ``union_all`` of the run alone: the same GEOS union, the same result.
    """
    if not len(geoms):
        return np.empty(0, dtype=object)
    start = np.flatnonzero(np.r_[True, group[1:] != group[:-1]])
    size = np.diff(np.r_[start, len(geoms)])
    table = np.full((len(start), int(size.max())), None, dtype=object)
    table[np.repeat(np.arange(len(start)), size), np.arange(len(geoms)) - np.repeat(start, size)] = geoms
    return shapely.union_all(table, axis=1)


def _face_links(faces: list, planes_of_face: np.ndarray, planes: np.ndarray, min_edge: float,
                skip: np.ndarray | None = None):
    """Pairs of faces sharing an edge longer than ``min_edge``: (i, j, shared line, plane gap along it in m).

    Pairs with a face in ``skip`` (faces that neither join nor split) are not measured.
    """
    polys = np.array(faces, dtype=object)
    left, right = shapely.STRtree(polys).query(polys, predicate="intersects")
    keep = left < right
    if skip is not None:
        keep &= ~(skip[left] | skip[right])
    left, right = left[keep], right[keep]
    boundary = shapely.boundary(polys)
    # every pair's shared boundary in one call; its line parts are merged pair by pair
    touch, pair = shapely.get_parts(shapely.intersection(boundary[left], boundary[right]), return_index=True)
    lines = np.isin(shapely.get_type_id(touch), (1, 5))  # LineString, MultiLineString
    touch, pair = touch[lines], pair[lines]
    cut = np.flatnonzero(np.r_[True, pair[1:] != pair[:-1]]).tolist() + [len(pair)]
    # each pair's parts merged as union_all of them alone would, all pairs in one call
    merged = shapely.line_merge(_union_each(touch, pair))
    out = []
    for a, shared in zip(cut[:-1], merged):
        if shared.is_empty or shared.length < min_edge:
            continue
        i, j = left[pair[a]], right[pair[a]]
        xy = shapely.get_coordinates(shapely.segmentize(shared, 0.5))
        pa, pb = planes[planes_of_face[i]], planes[planes_of_face[j]]
        za = -(pa[0] * xy[:, 0] + pa[1] * xy[:, 1] + pa[3]) / pa[2]
        zb = -(pb[0] * xy[:, 0] + pb[1] * xy[:, 1] + pb[3]) / pb[2]
        out.append((int(i), int(j), shared, float(np.median(np.abs(za - zb)))))
    return out


def _is_gutter(pa: np.ndarray, pb: np.ndarray, ca: np.ndarray, cb: np.ndarray, line, options: PartOptions) -> bool:
    """Two planes sloping down towards their shared line from opposite sides."""
    slope = np.degrees(np.arccos(np.clip([pa[2], pb[2]], -1.0, 1.0)))
    if (slope < options.min_slope).any():
        return False
    down_a, down_b = pa[:2] / np.hypot(*pa[:2]), pb[:2] / np.hypot(*pb[:2])  # downslope in plan
    if np.degrees(np.arccos(np.clip(down_a @ down_b, -1.0, 1.0))) < options.gutter_angle:
        return False
    mid = np.asarray(line.interpolate(0.5, normalized=True).coords[0][:2])
    return bool(down_a @ (mid - ca) > 0 and down_b @ (mid - cb) > 0)


def split_parts(xyz: np.ndarray, outline, faces: list, face_plane: list, planes: np.ndarray,
                options: PartOptions | None = None, *, building_id: int = 0,
                plane_detail: np.ndarray | None = None) -> BuildingParts:
    """Split one building into parts where its roof shows a boundary (height step or party gutter).

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), float64
        The building's points (m).
    outline : shapely.Polygon
        Its roof outline (Z ignored); the parts partition it.
    faces : list of shapely.Polygon
        Roof faces tiling the outline (``RoofStructure.faces``).
    face_plane : list of int
        Plane index of each face.
    planes : ndarray of shape (K, 4)
        ``a X + b Y + c Z + d = 0``, unit normals, ``c > 0``.
    options : PartOptions, optional
    building_id : int
    plane_detail : ndarray of shape (K,), bool, optional
        Planes of superstructures (``RoofStructure.plane_detail``: chimney
        tops, small dormers).  Their faces neither join nor split parts:
        each goes with the part it shares most edge with, as a small part
        does (a chimney on a party wall must not join two houses, nor its
        step split one).

    Returns
    -------
    BuildingParts
        One part (the outline) when the roof has no faces or shows no boundary.

    Examples
    --------
    >>> import shapely
    >>> low, high = shapely.box(0, 0, 6, 10), shapely.box(6, 0, 12, 10)
    >>> planes = np.array([[0, 0, 1.0, -6.0], [0, 0, 1.0, -9.0]])  # flat roofs at 6 m and 9 m
    >>> xyz = np.array([[3.0, 5.0, 6.0], [9.0, 5.0, 9.0]])
    >>> parts = split_parts(xyz, shapely.box(0, 0, 12, 10), [low, high], [0, 1], planes)
    >>> parts.part_id.tolist(), [p.area for p in parts.polygons], parts.boundaries
    ([1, 2], [60.0, 60.0], ['step'])
    """
    options = options or PartOptions()
    xyz = np.asarray(xyz, dtype=np.float64)
    outline = _outline_2d(outline) if outline is not None else None
    if outline is None or not faces:
        return _one_part(building_id, len(xyz), outline)
    planes = np.asarray(planes, dtype=np.float64)
    faces2d = [shapely.force_2d(f) for f in faces]
    face_plane = np.asarray(face_plane, dtype=np.int64)
    centre = np.array([np.asarray(f.centroid.coords[0][:2]) for f in faces2d])
    # superstructures' faces and slivers of the partition (a plane's stray corner where its extension happens
    # to cross a neighbour's: a 0.1 m² face joined two houses of a simulated row) neither join nor split
    detail = (np.zeros(len(planes), bool) if plane_detail is None
              else np.asarray(plane_detail, dtype=bool))[face_plane]
    detail |= np.array([f.area < options.min_edge**2 for f in faces2d])
    links = _face_links(faces2d, face_plane, planes, options.min_edge, skip=detail)
    joined, cuts = [], []
    for i, j, line, gap in links:
        if gap > options.step_height:
            cuts.append((i, j, "step"))
        elif _is_gutter(planes[face_plane[i]], planes[face_plane[j]], centre[i], centre[j], line, options):
            cuts.append((i, j, "gutter"))
        else:
            joined.append((i, j))
    # faces of one plane are one surface even where another face cuts between them
    same_plane = np.argwhere(np.triu((face_plane[:, None] == face_plane[None, :]) & ~detail[:, None] & ~detail[None, :],
                                     k=1))
    group = components(len(faces2d), np.vstack([np.array(joined, dtype=np.int64).reshape(-1, 2), same_plane]))
    group = _details_joined(faces2d, group, detail)
    pieces = _group_polygons(faces2d, group, outline)
    pieces = _merge_small(pieces, outline, options)
    if len(pieces) <= 1:
        return _one_part(building_id, len(xyz), outline)
    at = _part_of(pieces, centre)
    kinds = sorted({k for i, j, k in cuts if at[i] != at[j]})
    part_id = _points_to_parts(xyz[:, :2], pieces)
    return BuildingParts(building_id, part_id, pieces, kinds)


def _details_joined(faces: list, group: np.ndarray, detail: np.ndarray) -> np.ndarray:
    """``group`` with each detail face in the group of the face it shares most edge with.

    A superstructure's face or a sliver goes with the part it shares most
    edge with, as a small part does (:func:`_merge_small`), but before the
    pieces are built: a roof with hundreds of chimney and vent blocks would
    otherwise make as many pieces, and their union and merging grow with the
    square of their number.  A detail face touching only detail faces (a
    block on a block) follows once its neighbour is placed; one touching no
    face keeps its group.
    """
    group = np.asarray(group).copy()
    todo = np.flatnonzero(detail)
    if not len(todo) or detail.all():
        return group
    geoms = np.array(faces, dtype=object)
    edges = shapely.boundary(geoms)
    placed = ~np.asarray(detail, dtype=bool)
    pairs = shapely.STRtree(geoms).query(geoms[todo], predicate="intersects")
    near_of = np.split(pairs[1], np.searchsorted(pairs[0], np.arange(1, len(todo))))
    while len(todo):
        # one round against the faces placed before it: the result does not depend on the order within a round
        choice = np.full(len(todo), -1)
        for t, (i, near) in enumerate(zip(todo, near_of)):
            near = near[placed[near] & (near != i)]
            if len(near) and (shared := shapely.length(shapely.intersection(edges[i], edges[near]))).max() > 0:
                choice[t] = near[np.argmax(shared)]
        done = choice >= 0
        if not done.any():
            break
        group[todo[done]] = group[choice[done]]
        placed[todo[done]] = True
        todo, near_of = todo[~done], [n for n, d in zip(near_of, done) if not d]
    return group


def _group_polygons(faces: list, group: np.ndarray, outline) -> list:
    """One polygon per connected piece of each face group, together a partition of the outline."""
    order = np.argsort(group, kind="stable")  # each group's faces in their order
    pieces = []
    for merged in _union_each(np.array(faces, dtype=object)[order], group[order]):
        pieces += [p for p in shapely.get_parts(shapely.make_valid(merged)) if p.geom_type == "Polygon"]
    # an exact partition: earlier pieces win overlaps, the outline's leftovers go to the piece sharing most edge
    pieces = sorted(pieces, key=lambda g: -g.area)
    out, taken = [], shapely.Polygon()
    for clipped in shapely.intersection(np.array(pieces, dtype=object), outline):
        q = _largest(clipped.difference(taken))
        if q is not None:
            out.append(q)
            taken = shapely.union_all([taken, q])
    rest = outline.difference(taken)
    for r in shapely.get_parts(rest):
        if r.geom_type != "Polygon" or r.area <= 0 or not out:
            continue
        shared = shapely.length(shapely.intersection(r.boundary, shapely.boundary(np.array(out, dtype=object))))
        k = int(np.argmax(shared)) if shared.max() > 0 else int(np.argmin(shapely.distance(r, np.array(out, dtype=object))))
        out[k] = _largest(shapely.union_all([out[k], r])) or out[k]
    return out


def _largest(geom):
    polys = [g for g in shapely.get_parts(shapely.make_valid(geom)) if g.geom_type == "Polygon" and g.area > 1e-6]
    if not polys:
        return None
    return max(polys, key=lambda g: g.area) if len(polys) > 1 else polys[0]


def _merge_small(pieces: list, outline, options: PartOptions) -> list:
    """Merge parts under ``min_area`` or owning under ``min_facade`` of the outline into their longest neighbour."""
    ring = outline.boundary
    # each piece's area, facade, boundary and box are measured once and again only when a merge changes it
    # (measuring every piece on every merge was most of the step: O(P²) intersections); a merged piece is
    # marked gone rather than deleted, so the pieces left keep their order (first minimum, first maximum)
    pieces = np.array(pieces, dtype=object)
    boundaries = shapely.boundary(pieces)
    area = shapely.area(pieces)
    facade = shapely.length(shapely.intersection(boundaries, ring))
    box = shapely.bounds(boundaries)
    alive = np.ones(len(pieces), dtype=bool)
    while alive.sum() > 1:
        small = np.flatnonzero(alive & ((area < options.min_area) | (facade < options.min_facade)))
        if not len(small):
            break
        k = int(small[np.argmin(area[small])])  # the smallest first: it may make its neighbour big enough
        # only boundaries whose boxes meet k's can share a length with it
        near = np.flatnonzero(alive & (box[:, 0] <= box[k, 2]) & (box[:, 2] >= box[k, 0]) & (box[:, 1] <= box[k, 3])
                              & (box[:, 3] >= box[k, 1]))
        shared = np.zeros(len(pieces))
        shared[near] = shapely.length(shapely.intersection(boundaries[k], boundaries[near]))
        shared[k] = -1.0
        shared[~alive] = -np.inf
        if shared.max() <= 0:
            break  # an island part touching nothing: nothing to merge it into
        j = int(np.argmax(shared))
        pieces[j] = _largest(shapely.union_all([pieces[j], pieces[k]])) or pieces[j]
        boundaries[j] = pieces[j].boundary
        area[j], facade[j] = pieces[j].area, boundaries[j].intersection(ring).length
        box[j] = shapely.bounds(boundaries[j])
        alive[k] = False
    # stable order: by lowest (x, y) of the part's centroid, so ids do not depend on the face order
    return sorted(pieces[alive], key=lambda p: (round(p.centroid.x, 6), round(p.centroid.y, 6)))


def _part_of(pieces: list, xy: np.ndarray) -> np.ndarray:
    """Per point of ``xy`` (M, 2), the first piece holding it (boundary included), -1 for none."""
    out = np.full(len(xy), -1, dtype=np.int64)
    for k, p in enumerate(pieces):
        free = np.flatnonzero(out < 0)
        out[free[shapely.intersects_xy(p, xy[free, 0], xy[free, 1])]] = k
    return out


def _points_to_parts(xy: np.ndarray, pieces: list) -> np.ndarray:
    """Part (1..P) of each point: the polygon holding it, else the nearest polygon."""
    part = np.zeros(len(xy), np.int32)
    for k, p in enumerate(pieces):
        inside = (part == 0) & shapely.intersects_xy(p, xy[:, 0], xy[:, 1])
        part[inside] = k + 1
    rest = np.flatnonzero(part == 0)
    if len(rest):
        tree = shapely.STRtree(pieces)
        near = tree.query_nearest(shapely.points(xy[rest]), all_matches=False)
        part[rest[near[0]]] = near[1] + 1
    return part


def parts_layer(parts: list[BuildingParts], heights: dict[int, np.ndarray]):
    """The ``building_parts`` layer: one PolygonZ per part, at the 70th percentile of its points' heights.

    Parameters
    ----------
    parts : list of BuildingParts
    heights : dict of int to ndarray of shape (N_b,)
        Per building id, the heights (m) of its points, in the order of
        ``BuildingParts.part_id``.

    Returns
    -------
    rooftrace.io.vector.Layer
        Attributes: ``building_id``, ``part_id`` (1..P within the building),
        ``n_parts``, ``area`` (m²), ``n_points``, ``z_min``, ``z_50``,
        ``z_70``, ``z_max`` (m; NaN for a part holding no point),
        ``boundaries`` (why the building was split, e.g. ``"step,gutter"``).
    """
    from rooftrace.io.vector import Layer

    cols: dict[str, list] = {k: [] for k in ("building_id", "part_id", "n_parts", "area", "n_points", "z_min",
                                             "z_50", "z_70", "z_max", "boundaries")}
    geoms = []
    for bp in parts:
        z_all = np.asarray(heights.get(bp.building_id, np.zeros(0)), dtype=np.float64)
        for k, poly in enumerate(bp.polygons, start=1):
            z = z_all[bp.part_id == k] if len(z_all) == len(bp.part_id) else np.zeros(0)
            q = np.percentile(z, [0, 50, 70, 100]) if len(z) else np.full(4, np.nan)
            geoms.append(shapely.force_3d(poly, float(q[2]) if len(z) else 0.0))
            cols["building_id"].append(int(bp.building_id))
            cols["part_id"].append(k)
            cols["n_parts"].append(bp.n_parts)
            cols["area"].append(float(poly.area))
            cols["n_points"].append(int(len(z)))
            for name, v in zip(("z_min", "z_50", "z_70", "z_max"), q):
                cols[name].append(float(v))
            cols["boundaries"].append(",".join(bp.boundaries))
    for k in ("building_id", "part_id", "n_parts", "n_points"):
        cols[k] = np.asarray(cols[k], dtype=np.int64)
    for k in ("area", "z_min", "z_50", "z_70", "z_max"):
        cols[k] = np.asarray(cols[k], dtype=np.float64)
    return Layer(geoms, cols, "PolygonZ")
