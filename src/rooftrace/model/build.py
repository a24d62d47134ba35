"""LoD 1.2, 1.3 and 2.2 models of one building from its outline, roof faces, points and ground height.

:func:`build_model` takes what the roof stage gives per building (the roof
outline, the :class:`~rooftrace.roof.structure.RoofStructure` with its
planes and faces, the roof points) and the ground height, and returns a
:class:`~rooftrace.model.types.BuildingModel`:

- **LoD 1.2**: the footprint extruded to one height, the ``roof_percentile``
  (70th, as the 3DBAG) of the part's roof point heights;
- **LoD 1.3**: one flat block per roof height level: roof faces joined
  where their shared edges do not jump more than ``level_step``, each level
  at the ``roof_percentile`` of its points;
- **LoD 2.2**: the roof faces on their planes, walls under every step
  between faces and around the footprint, down to the ground; a box under
  each superstructure top point the faces leave more than ``box_rise``
  under them (:func:`rooftrace.model.superstructures.with_boxes`).  A roof
  point that the faces hold under its own plane stays under it in the
  solid: where the plan lattice moved a face edge across it, it gets the
  lattice square around it (:func:`_points_kept`).

Every solid comes from :func:`rooftrace.model.solid.prism_solid` and is
checked by :func:`rooftrace.model.validity.solid_errors`; a level that
cannot be built or is not valid is left out and the building's ``status``
and ``status_reason`` say which and why (never an invalid solid).  LoD 2.2
is never left out where LoD 1.3 stands: without roof faces, or when the
planar solid fails, it is the LoD 1.3 solid (flat roofs, as 3DBAG's roofer
models a roof without planes), status ``flat_lod22``.

Building parts (``parts``: plan polygons, e.g. cadastral footprints of a
terraced row, or the split of one LiDAR building) each get their own
solids, cut from the same roof faces, so neighbouring parts share their
party walls.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import shapely

from rooftrace.errors import GeometryError
from rooftrace.graph import components
from rooftrace.model.solid import horizontal_plane, party_walls, prism_solid
from rooftrace.model.superstructures import with_boxes
from rooftrace.model.types import LODS, BuildingModel, PartModel, Solid
from rooftrace.model.validity import PartExtent, overlapping_extents, solid_errors, solid_volume
from rooftrace.roof.face_kernels import points_in_boxes
from rooftrace.roof.faces import points_in_faces
from rooftrace.roof.planes import plane_height

__all__ = ["ModelOptions", "build_model", "ground_height"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ModelOptions:
    """Options of the 3D model builders (config section ``[model]``).

    Attributes
    ----------
    roof_percentile : float
        Percentile (0-100) of the roof point heights that gives the flat
        roofs of LoD 1.2 and 1.3 (70, as the 3DBAG).
    ground_percentile : float
        Percentile of the terrain heights under the building's points that
        gives its ground height (10: the walls reach the lower side of a
        sloping street).
    level_step : float
        LoD 1.3: neighbouring roof faces whose shared edge jumps more than
        this (m) are separate height levels.
    grid : float
        Vertex grid (m); the CityJSON writer's scale.
    snap : float
        Plan lattice of the solids' vertices (m), a multiple of ``grid``:
        vertices are at least this far apart, well above the 1 mm within
        which validators (val3dity) merge vertices when they read a file.
    z_tolerance : float
        Heights of one vertex closer than this (m) are one height.
    planarity : float
        Largest distance (m) of a vertex to its surface's plane in the
        validity check (val3dity's default).
    validate : bool
        Check every solid and leave out the invalid ones (with a reason).
    box_rise : float
        LoD 2.2: a top point of a superstructure (``RoofStructure.top_points``)
        standing more than this (m) above the roof faces gets a box of the
        point spacing's side (:func:`rooftrace.model.superstructures.with_boxes`).
    """

    section = "model"

    roof_percentile: float = 70.0
    ground_percentile: float = 10.0
    level_step: float = 0.5
    grid: float = 0.001
    snap: float = 0.01
    z_tolerance: float = 0.01
    planarity: float = 0.01
    validate: bool = True
    box_rise: float = 0.5

    def __post_init__(self) -> None:
        for name in ("roof_percentile", "ground_percentile"):
            if not 0 <= getattr(self, name) <= 100:
                raise ValueError(f"{name} must be in [0, 100], got {getattr(self, name)}")
        for name in ("level_step", "grid", "snap", "z_tolerance", "planarity", "box_rise"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0 m, got {getattr(self, name)}")
        if self.snap < self.grid or abs(self.snap / self.grid - round(self.snap / self.grid)) > 1e-6:
            raise ValueError(f"snap must be a multiple of grid ({self.grid} m), got {self.snap}")


def ground_height(terrain_z: np.ndarray, percentile: float = 10.0) -> float:
    """Ground height of a building (m): a low percentile of the terrain heights under its points.

    Parameters
    ----------
    terrain_z : ndarray of shape (N,)
        Height of the ground surface (the ground TIN) below each of the
        building's points, e.g. ``z - hag``.
    percentile : float, default 10

    Returns
    -------
    float
        NaN when there are no finite heights.
    """
    z = np.asarray(terrain_z, dtype=np.float64)
    z = z[np.isfinite(z)]
    return float(np.percentile(z, percentile)) if len(z) else float("nan")


def _largest_polygon(geom):
    geom = shapely.make_valid(shapely.force_2d(geom))
    parts = [g for g in shapely.get_parts(geom) if g.geom_type == "Polygon" and g.area > 0]
    return max(parts, key=lambda g: g.area) if parts else None


def _own_heights(roof, xyz: np.ndarray) -> np.ndarray | None:
    """Per point the height of its own roof plane at it (NaN on none); None without labels for these points."""
    labels = getattr(roof, "labels", None)
    if labels is None or len(labels) != len(xyz) or not len(getattr(roof, "planes", [])):
        return None
    labels = np.asarray(labels)
    out = np.full(len(xyz), np.nan)
    on = labels >= 0
    out[on] = plane_height(np.asarray(roof.planes, dtype=np.float64)[labels[on]], xyz[on, :2])
    return out


def _roof_cells(roof, *, detail: bool = True) -> list[tuple[Any, np.ndarray]]:
    """The roof faces as (plan polygon, plane) cells; without ``detail`` those of the superstructures' planes
    (``RoofStructure.plane_detail``: chimney tops, flat blocks) left out, their place filled by the neighbours."""
    if roof is None or not len(getattr(roof, "faces", [])):
        return []
    skip = np.asarray(getattr(roof, "plane_detail", np.zeros(0, bool)), dtype=bool)
    return [(shapely.force_2d(f), np.asarray(roof.planes[k], dtype=np.float64))
            for f, k in zip(roof.faces, roof.face_plane) if detail or not (k < len(skip) and skip[k])]


#: no roof comes closer to the ground than this (m): a face that does is a steep plane carried
#: beyond its points, and the part of it lower than this is left to its neighbours
MIN_EAVES_HEIGHT = 1.0


def _above_ground(cells: list, ground: float, clearance: float = MIN_EAVES_HEIGHT) -> list:
    """The cells cut to where their plane is at least ``clearance`` above ``ground`` (m).

    :func:`~rooftrace.model.solid.prism_solid` refuses a roof at or below
    the ground; a steep face (a dormer's cheek, a plane fitted to a wall)
    carried by the face partition past its points can reach it.  The part
    cut off becomes a gap of the partition, which ``prism_solid`` gives to
    the neighbouring face; so does a cell entirely that low (on Delft a
    0.3 m² wedge of a 45 degree plane, 0-1 m above the ground, cost a
    208 m² part its LoD 2.2).  Only when every cell is that low are they
    kept as they are (the roof then is under the ground and the level
    fails with that reason).
    """
    out = []
    for poly, plane in cells:
        a, b, c, d = plane
        x0, y0, x1, y1 = poly.bounds
        box = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
        # the plane's height over the clearance is linear in plan: the cut is one straight line
        lift = -(a * box[:, 0] + b * box[:, 1] + d) / c - ground - clearance if abs(c) > 1e-9 else np.zeros(4)
        if (lift >= 0).all():  # a vertical plane too: prism_solid says why it fails
            out.append((poly, plane))
            continue
        keep = []
        for k in range(4):
            j = (k + 1) % 4
            if lift[k] >= 0:
                keep.append(box[k])
            if (lift[k] >= 0) != (lift[j] >= 0):
                keep.append(box[k] + lift[k] / (lift[k] - lift[j]) * (box[j] - box[k]))
        high = shapely.intersection(poly, shapely.Polygon(keep)) if len(keep) >= 3 else shapely.Polygon()
        out.extend((g, plane) for g in shapely.get_parts(high) if g.geom_type == "Polygon" and g.area > 0)
    return out or list(cells)


def _clip(cells: list, footprint) -> list:
    """The cells cut to ``footprint`` (a polygon each, with its plane)."""
    if not cells:
        return []
    cut = shapely.intersection(np.array([c for c, _ in cells], dtype=object), footprint)
    return [(g, plane) for piece, (_, plane) in zip(cut, cells) for g in shapely.get_parts(piece)
            if g.geom_type == "Polygon" and g.area > 0]


def _with_face_corners(footprint, cells: list):
    """The footprint with the corners of the cells that lie on its edges as vertices of its own.

    A face boundary meets the footprint between two of its vertices; rounded
    to the vertex grid apart, the cut point falls up to half a grid step off
    the rounded footprint edge and the solid gets a wall a grid step long
    (val3dity: repeated points).  As a footprint vertex it rounds as the
    faces' corner does.  The footprint's shape is unchanged.
    """
    corners = shapely.multipoints(shapely.get_coordinates(np.array([c for c, _ in cells], dtype=object)))
    snapped = shapely.snap(footprint, corners, 1e-7)
    return snapped if snapped.is_valid and abs(snapped.area - footprint.area) <= 1e-9 * footprint.area else footprint


def _levels(cells: list, step: float) -> list[list[int]]:
    """Cells joined into height levels: neighbours whose shared boundary jumps at most ``step`` (m)."""
    n = len(cells)
    if n == 1:
        return [[0]]
    polys = np.array([c for c, _ in cells], dtype=object)
    tree = shapely.STRtree(polys)
    a, b = tree.query(polys, predicate="intersects")
    keep = a < b
    a, b = a[keep], b[keep]
    # every neighbour pair's shared boundary in one call, the planes' heights along it in a few more
    boundary = shapely.boundary(polys)
    shared = shapely.intersection(boundary[a], boundary[b])
    along = shapely.length(shared) > 0
    a, b = a[along], b[along]
    xy, pair = shapely.get_coordinates(shapely.segmentize(shared[along], 0.5), return_index=True)
    plane = np.array([pl for _, pl in cells], dtype=np.float64)
    pi, pj = plane[a[pair]], plane[b[pair]]
    zi = -(pi[:, 0] * xy[:, 0] + pi[:, 1] * xy[:, 1] + pi[:, 3]) / pi[:, 2]
    zj = -(pj[:, 0] * xy[:, 0] + pj[:, 1] * xy[:, 1] + pj[:, 3]) / pj[:, 2]
    jump = np.full(len(a), -np.inf)
    np.maximum.at(jump, pair, np.abs(zi - zj))
    pairs = np.column_stack([a, b])[jump <= step]
    label = components(n, pairs)
    return [list(np.flatnonzero(label == k)) for k in np.unique(label)]


#: what one level of one building may fail with; the run goes on (a city must not stop at one
#: odd roof) and the building's status says why
_FAILURES = (GeometryError, shapely.errors.GEOSException, ValueError, np.linalg.LinAlgError)


def _checked(solid: Solid, options: ModelOptions) -> Solid:
    if options.validate:
        errors = solid_errors(solid, planarity=options.planarity, grid=options.grid)
        if errors:
            raise GeometryError("invalid solid (" + "; ".join(errors[:2]) + ")")
    return solid


def _cut(footprints: list, cells: list, snap: float) -> list[tuple[Any, list]]:
    """Per part its footprint and the roof cells cut to it.

    Several parts are cut from one arrangement on the plan lattice
    (:func:`~rooftrace.model.solid.party_walls`), so that their solids
    share their party walls vertex for vertex instead of overlapping by a
    sliver there.
    """
    if len(footprints) > 1:
        try:
            return party_walls(footprints, cells, snap)
        except _FAILURES as exc:
            log.warning("parts not cut together (%s): each part on its own", exc)
    out = []
    for k, fp in enumerate(footprints, start=1):
        try:
            out.append((fp, _clip(cells, fp)))
        except _FAILURES as exc:
            log.warning("part %d: roof faces not cut to the part (%s)", k, exc)
            out.append((fp, []))
    return out


def _inside(poly, xyz: np.ndarray) -> np.ndarray:
    """Which of the points lie inside ``poly`` (prepared): only those in its box are tested.

    ``contains_xy`` costs per point tested, and a level of a large roof holds a small share of the
    building's points; outside the box nothing is inside, so the mask is the same.
    """
    inside = np.zeros(len(xyz), dtype=bool)
    if not len(xyz):
        return inside
    x0, y0, x1, y1 = poly.bounds
    x, y = xyz[:, 0], xyz[:, 1]
    box = np.flatnonzero((x >= x0) & (x <= x1) & (y >= y0) & (y <= y1))
    inside[box] = shapely.contains_xy(poly, x[box], y[box])
    return inside


def _part(part_id: int, footprint, cells: list, xyz: np.ndarray, ground: float, roof_status: str,
          options: ModelOptions, lods: tuple[str, ...] = LODS, tops: tuple | None = None,
          own_z: np.ndarray | None = None, held_by: list | None = None,
          party=None) -> tuple[PartModel, dict[str, str]]:
    """One part's solids of ``lods`` from its roof ``cells`` (cut to ``footprint``), and why any is missing.

    ``tops``: the superstructures' top points and the side of their boxes (m), for LoD 2.2; ``party``: the
    building's other parts in plan, whose party walls no box reaches (:func:`with_boxes`).
    ``own_z``: per point the height of its own roof plane (NaN on none), and ``held_by``: the roof faces
    as they were before the parts were cut on the lattice (default ``cells``), for :func:`_points_kept`.
    """
    part = PartModel(part_id, footprint)
    why: dict[str, str] = {}
    shapely.prepare(footprint)
    inside = _inside(footprint, xyz)
    z = xyz[inside, 2]
    part.attributes["n_points"] = int(len(z))
    if not len(z):
        return part, dict.fromkeys(("1.2", "1.3", "2.2"), "no roof points in the footprint")
    h = float(np.percentile(z, options.roof_percentile))
    part.attributes["h_roof_lod12"] = round(h, 3)
    kw = dict(footprint=footprint, grid=options.grid, snap=options.snap, z_tolerance=options.z_tolerance)
    if "1.2" in lods or not cells:
        try:
            part.lods["1.2"] = _checked(prism_solid([(footprint, horizontal_plane(h))], ground, **kw), options)
        except _FAILURES as exc:
            why["1.2"] = str(exc)
    if not cells:
        why["2.2"] = f"no roof faces ({roof_status})"
        if "1.2" in part.lods:
            part.lods["1.3"] = part.lods["1.2"]  # one height level is all there is
        else:
            why["1.3"] = why["1.2"]
        _flat_lod22(part, why, lods)
        _volumes(part)
        return part, why
    kw["footprint"] = _with_face_corners(footprint, cells)
    if "1.3" in lods:
        try:
            levels = []
            for members in _levels(cells, options.level_step):
                poly = shapely.union_all([cells[i][0] for i in members])
                shapely.prepare(poly)
                zl = xyz[_inside(poly, xyz), 2]
                hl = float(np.percentile(zl, options.roof_percentile)) if len(zl) >= 3 else h
                levels.extend((g, horizontal_plane(hl)) for g in shapely.get_parts(poly) if g.area > 0)
            part.lods["1.3"] = _checked(prism_solid(levels, ground, **kw), options)
        except _FAILURES as exc:
            why["1.3"] = str(exc)
    if "2.2" in lods:
        kept = cells if own_z is None else _points_kept(cells, held_by or cells, xyz[inside, :2], own_z[inside],
                                                        kw["footprint"], options)
        try:
            try:
                part.lods["2.2"] = _checked_with_boxes(prism_solid(kept, ground, **kw), tops, xyz, options, party)
            except _FAILURES:
                if kept is cells:
                    raise
                part.lods["2.2"] = _checked_with_boxes(prism_solid(cells, ground, **kw), tops, xyz, options, party)
        except _FAILURES as exc:
            why["2.2"] = str(exc)
            _flat_lod22(part, why, lods)
    _volumes(part)
    return part, why


#: height difference (m) between a point's own plane and the roof over it that still counts as its own
#: (the roof faces' ``max_dz``)
OWN_PLANE_DZ = 0.1


def _points_kept(cells: list, held_by: list, xy: np.ndarray, own_z: np.ndarray, footprint,
                 options: ModelOptions) -> list:
    """The cells with each point the plan lattice would hand to another roof level given the lattice square around it.

    ``prism_solid`` (and the parts' cut, :func:`~rooftrace.model.solid.party_walls`)
    put the cells' vertices on the ``snap`` lattice, which moves a cell
    edge by up to the lattice's half diagonal: a point of a roof level that
    close to its face's edge (a height step's edge row) would fall under the
    other level, metres off.  Each point within ``snap`` of an edge that a
    face of ``held_by`` (the roof faces before any rounding) of a plane
    within :data:`OWN_PLANE_DZ` of its own holds, and that no cell of such a
    plane holds once rounded to the lattice, gets the lattice square around
    it (a lattice step beyond it on every side, within ``footprint``) for
    the nearest of ``cells`` of such a plane, taken from the others.
    """
    mine = np.flatnonzero(np.isfinite(own_z))
    if not len(mine) or not cells or not held_by:
        return cells
    snap = options.snap

    def heights_fit(planes: np.ndarray, at: np.ndarray) -> np.ndarray:
        return np.abs(plane_height(planes, xy[at]) - own_z[at]) <= OWN_PLANE_DZ

    ref = np.array([c for c, _ in held_by], dtype=object)
    ref_planes = np.array([pl for _, pl in held_by], dtype=np.float64).reshape(-1, 4)
    # the lattice moves an edge by less than its step: only a point that close to a face of another level
    # (more than OWN_PLANE_DZ off) and inside a face of its own can change sides.  Face by face, only the
    # points of other levels in its box (grown by twice the step) are measured: most of a face's points are
    # its own level's, and a prepared face measures the rest without a tree of point geometries
    mxy = xy[mine]
    grown = shapely.bounds(ref) + np.array([-2.0, -2.0, 2.0, 2.0]) * snap
    ptr, inbox = points_in_boxes(mxy[:, 0], mxy[:, 1], np.argsort(mxy[:, 0], kind="stable"), grown)
    of = np.repeat(np.arange(len(ref)), np.diff(ptr))
    other = ~heights_fit(ref_planes[of], mine[inbox])
    inbox, of = inbox[other], of[other]
    near_other = np.zeros(len(mine), dtype=bool)
    for k in np.unique(of):
        cand = inbox[of == k]
        shapely.prepare(ref[k])
        near_other[cand[shapely.dwithin(ref[k], shapely.points(mxy[cand]), snap)]] = True
    near = np.flatnonzero(near_other)
    at, f = points_in_faces(ref, mxy[near])
    held = np.zeros(len(mine), dtype=bool)
    held[near[at[heights_fit(ref_planes[f], mine[near[at]])]]] = True
    mine = mine[held]
    if not len(mine):
        return cells
    polys = np.array([c for c, _ in cells], dtype=object)
    planes = np.array([pl for _, pl in cells], dtype=np.float64).reshape(-1, 4)
    # which of them the cells, rounded to the lattice, put under another level and none of their own
    i, c = shapely.STRtree(polys).query(shapely.points(xy[mine]), predicate="dwithin", distance=2 * snap)
    # each cell rounded once, however many points it is near
    rounded = np.full(len(polys), None, dtype=object)
    used = np.unique(c)
    rounded[used] = shapely.set_precision(polys[used], snap)
    on = shapely.intersects_xy(rounded[c], xy[mine[i], 0], xy[mine[i], 1])
    fit = heights_fit(planes[c], mine[i])
    own, other = np.zeros(len(mine), dtype=bool), np.zeros(len(mine), dtype=bool)
    own[i[on & fit]] = True
    other[i[on & ~fit]] = True
    lost = mine[other & ~own]
    if not len(lost):
        return cells
    # per lost point the nearest cell of a plane within OWN_PLANE_DZ of its own
    p = xy[lost]
    z = plane_height(planes[None, :, :], p[:, None, :])  # (lost points, cells)
    d = shapely.distance(polys[None, :], shapely.points(p)[:, None])
    d = np.where(np.abs(z - own_z[lost][:, None]) <= OWN_PLANE_DZ, d, np.inf)
    c = np.argmin(d, axis=1)
    ok = d[np.arange(len(lost)), c] <= 2 * snap
    if not ok.any():
        return cells
    p, c = p[ok], c[ok]
    lo, hi = (np.floor(p / snap) - 1) * snap, (np.ceil(p / snap) + 1) * snap
    squares = shapely.intersection(shapely.box(lo[:, 0], lo[:, 1], hi[:, 0], hi[:, 1]), footprint)
    new = list(polys)
    for k in np.unique(c):
        take = shapely.union_all(squares[c == k])
        new = [shapely.difference(g, take) if j != k else shapely.union(g, take) for j, g in enumerate(new)]
    return [(g, planes[j]) for j, piece in enumerate(new) for g in shapely.get_parts(piece)
            if g.geom_type == "Polygon" and g.area > 0]


def _checked_with_boxes(solid: Solid, tops: tuple | None, xyz: np.ndarray, options: ModelOptions,
                        party=None) -> Solid:
    """``solid`` with boxes under the top points it leaves more than ``box_rise`` under it, checked.

    The boxed solid is checked (once: the boxes change no other surface); should it fail, the solid without them is.
    """
    if tops is not None and len(tops[0]):
        boxed, _ = with_boxes(solid, tops[0], tops[1], others=xyz, rise=options.box_rise, grid=options.grid,
                              snap=options.snap, party=party)
        if boxed is not solid:
            try:
                return _checked(boxed, options)
            except GeometryError as exc:
                log.warning("boxes left out (%s)", exc)
    return _checked(solid, options)


#: the prefix of a ``status_reason`` entry whose level was built flat: the roof of LoD 1.3
FLAT = "flat, the LoD 1.3 roof: "


def _flat_lod22(part: PartModel, why: dict[str, str], lods: tuple[str, ...]) -> None:
    """LoD 2.2 from what there is when the roof faces give none: the LoD 1.3 solid, its roofs flat.

    As 3DBAG's roofer, every building with points gets a LoD 2.2: with no
    roof planes (too few points, no planar region) or a planar roof that
    failed, its roof surfaces are LoD 1.3's (one flat roof per height level,
    each at the ``roof_percentile`` of its points): a closed, checked solid
    with ``RoofSurface`` semantics.  ``why["2.2"]`` keeps the cause, marked
    :data:`FLAT` so that the status can tell a flat LoD 2.2 from a missing one.
    """
    if "2.2" in lods and "2.2" in why and "1.3" in part.lods:
        part.lods["2.2"] = part.lods["1.3"]
        why["2.2"] = FLAT + why["2.2"]


def _volumes(part: PartModel) -> None:
    for lod, solid in part.lods.items():
        part.attributes[f"volume_lod{lod.replace('.', '')}"] = round(solid_volume(solid), 3)


def _align_party_walls(parts: list[PartModel], cut: list, xyz: np.ndarray, ground: float, roof_status: str,
                       options: ModelOptions, rounds: int = 3, tops: tuple | None = None,
                       own_z: np.ndarray | None = None, held_by: list | None = None,
                       party: list | None = None) -> None:
    """Rebuild the solids of parts that overlap a neighbour, their party wall bent as the neighbour's.

    Cut from one arrangement, two parts start with the same party wall; but
    ``prism_solid`` may still move it in one of them (the disk that opens a
    saddle vertex on the wall crosses it between two vertices, and the
    crossing, on the lattice, is up to 0.7 lattice steps off the wall).  The
    two solids then overlap by a sliver (val3dity's error 601).  The other
    part gets that vertex in its footprint and cells too
    (:func:`shapely.snap`) and its solid of that level of detail is rebuilt,
    so both walls bend alike; a few rounds, as a rebuild may move another
    vertex.  ``parts`` are changed in place; ``own_z``, ``held_by`` and ``party`` (per part) as in :func:`_part`.
    """
    tol = 0.9 * options.snap  # above the half diagonal of a lattice cell, below a step
    extents: dict[int, tuple[Solid, PartExtent]] = {}  # by id of the solid: measured once, again only when rebuilt

    def extent(solid: Solid) -> PartExtent:
        if id(solid) not in extents:
            extents[id(solid)] = (solid, PartExtent.of(solid, grid=options.grid))  # the solid kept: ids stay its own
        return extents[id(solid)][1]

    for lod in LODS:
        bases = {k: cut[k] for k in range(len(parts))}
        for attempt in range(rounds + 1):
            have = [k for k, p in enumerate(parts) if lod in p.lods]
            pairs = overlapping_extents([extent(parts[k].lods[lod]) for k in have], grid=options.grid)
            if not pairs:
                break
            if attempt == rounds:
                log.warning("LoD %s: parts %s still overlap", lod, [(have[a] + 1, have[b] + 1) for a, b in pairs])
                break
            plans = {have[i]: extent(parts[have[i]].lods[lod]).plan for pair in pairs for i in pair}
            extra: dict[int, list] = {}
            for a, b in pairs:
                for i, j in ((have[a], have[b]), (have[b], have[a])):
                    xy = shapely.get_coordinates(plans[i])
                    mine = {tuple(v) for v in np.round(shapely.get_coordinates(plans[j]) / options.grid).tolist()}
                    new = np.array([tuple(v) not in mine for v in np.round(xy / options.grid).tolist()], dtype=bool)
                    near = new & (shapely.distance(shapely.points(xy), plans[j].boundary) < tol)
                    if near.any():
                        extra.setdefault(j, []).append(xy[near])
            if not extra:
                log.warning("LoD %s: parts %s overlap", lod, [(have[a] + 1, have[b] + 1) for a, b in pairs])
                break
            for j, points in sorted(extra.items()):
                ref = shapely.multipoints(np.vstack(points))
                fp, cells = bases[j]
                bases[j] = (shapely.snap(fp, ref, tol), [(shapely.snap(c, ref, tol), plane) for c, plane in cells])
                again, _ = _part(parts[j].part_id, *bases[j], xyz, ground, roof_status, options, (lod,), tops,
                                 own_z=own_z, held_by=held_by, party=party[j] if party else None)
                if lod in again.lods:
                    parts[j].lods[lod] = again.lods[lod]
                    parts[j].attributes[f"volume_lod{lod.replace('.', '')}"] = again.attributes[
                        f"volume_lod{lod.replace('.', '')}"]


def _other_parts(cut: list) -> list:
    """Per part of ``cut``, the other parts' footprints in plan (None for a building of one part)."""
    if len(cut) < 2:
        return [None] * len(cut)
    return [shapely.union_all([fp for j, (fp, _) in enumerate(cut) if j != k]) for k in range(len(cut))]


def build_model(outline, roof, xyz: np.ndarray, ground: float, *, parts: Sequence | None = None,
                building_id: int = 0, options: ModelOptions | None = None) -> BuildingModel:
    """LoD 1.2, 1.3 and 2.2 solids of one building (per part), with status.

    Parameters
    ----------
    outline : shapely Polygon
        Plan outline of the building (Z ignored, holes allowed): the roof
        outline, or a footprint.
    roof : RoofStructure or None
        Roof planes and faces (:func:`rooftrace.roof.roof_structure`);
        without faces LoD 1.3 is LoD 1.2 and LoD 2.2 is LoD 1.3.
    xyz : ndarray of shape (N, 3), float64
        The building's roof points (m), for the flat roof heights.
    ground : float
        Ground height (m), e.g. :func:`ground_height`.
    parts : sequence of shapely Polygon, optional
        Plan outlines of the building's parts; each is cut by ``outline``
        and gets its own solids.  Default: one part, the outline.
    building_id : int
    options : ModelOptions, optional

    Returns
    -------
    BuildingModel
        ``attributes`` holds ``status`` (``ok``; ``flat_lod22`` when LoD 2.2
        is the flat LoD 1.3 solid in some part; ``partial`` when a level of
        detail is missing in some part; ``no_model`` when no solid could be
        built) and ``status_reason``.

    Examples
    --------
    >>> import numpy as np, shapely
    >>> rng = np.random.default_rng(0)
    >>> xyz = np.column_stack([rng.uniform(0, 10, 500), rng.uniform(0, 8, 500), np.full(500, 7.0)])
    >>> model = build_model(shapely.box(0, 0, 10, 8), None, xyz, 1.0, building_id=3)
    >>> sorted(model.parts[0].lods), model.attributes["status"]
    (['1.2', '1.3', '2.2'], 'flat_lod22')
    """
    opt = options or ModelOptions()
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    model = BuildingModel(int(building_id))
    poly = _largest_polygon(outline) if outline is not None else None
    if poly is None or not np.isfinite(ground):
        model.attributes.update(status="no_model",
                                status_reason="no outline" if poly is None else "no ground height")
        return model
    footprints = [poly] if parts is None else [
        g for p in parts for g in shapely.get_parts(shapely.intersection(shapely.force_2d(p), poly))
        if g.geom_type == "Polygon" and g.area > 0]
    cells = _above_ground(_roof_cells(roof), float(ground))
    own_z = _own_heights(roof, xyz)
    roof_status = getattr(roof, "status", "no roof structure") if roof is not None else "no roof structure"
    cut = _cut(footprints, cells, opt.snap)
    top_points = getattr(roof, "top_points", None)
    tops = (top_points, float(roof.spacing)) if top_points is not None and len(top_points) else None
    whys = []
    plain = None
    party = _other_parts(cut) if tops is not None else [None] * len(cut)  # only boxes ask for it
    for k, (fp, part_cells) in enumerate(cut, start=1):
        part, why = _part(k, fp, part_cells, xyz, float(ground), roof_status, opt, tops=tops, own_z=own_z,
                          held_by=cells, party=party[k - 1])
        if "1.3" in why or "2.2" in why:
            # a superstructure's face may close a saddle the solid cannot open (a block at a pinch of the
            # outline): the part's solids without the superstructures, when that gives more levels or a planar
            # LoD 2.2 for a flat one (cut as the parts were, so that the party walls still match)
            if plain is None:
                bare = _above_ground(_roof_cells(roof, detail=False), float(ground))
                plain = _cut(footprints, bare, opt.snap) if bare and len(bare) < len(cells) else []
            if len(plain) == len(cut) and plain[k - 1][1]:
                try:
                    again, why_again = _part(k, plain[k - 1][0], plain[k - 1][1], xyz, float(ground), roof_status,
                                             opt, tops=tops, party=party[k - 1])
                except _FAILURES:
                    again = None
                if again is not None and (len(again.lods), -len(why_again)) > (len(part.lods), -len(why)):
                    log.debug("building %d part %d: solids without the superstructures' faces (%s)", building_id,
                              k, "; ".join(why.values()))
                    part, why = again, why_again
        model.parts.append(part)
        whys.append(why)
    if len(model.parts) > 1:
        _align_party_walls(model.parts, cut, xyz, float(ground), roof_status, opt, tops=tops, own_z=own_z,
                           held_by=cells, party=party)
    reasons: list[str] = []
    for k, why in enumerate(whys, start=1):
        for lod, reason in sorted(why.items()):
            reasons.append(f"lod{lod.replace('.', '')}" + (f" part {k}" if len(footprints) > 1 else "")
                           + f": {reason}")
    built = any(p.lods for p in model.parts)
    missing = [r for r in reasons if FLAT not in r]
    status = "ok" if not reasons else "flat_lod22" if not missing else "partial" if built else "no_model"
    model.attributes.update(status=status, status_reason="; ".join(reasons) or None)
    if reasons:
        log.debug("building %d: %s", building_id, "; ".join(reasons))
    return model
