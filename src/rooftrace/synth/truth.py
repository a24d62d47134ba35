"""Exact ground truth from building geometry: visible roof faces, ridges, 3D outlines.

A building's roof is the maximum over blocks of the minimum over each
block's planes (see :mod:`rooftrace.synth.buildings`).  Where plane ``k`` of
block ``b`` is the visible surface is therefore an intersection of
half-planes: inside the block, ``p_bk <= p_bj`` for the block's other planes,
and outside every region where another block is higher (another block ``g``
is higher where all of its planes exceed ``p_bk``).  Half-planes are clipped
exactly with shapely, so faces share their boundaries, and the lines shared
by two faces are the ridges (convex, horizontal), hips (convex, sloped),
valleys (concave) and steps (a jump in height).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry import LineString, Polygon

from rooftrace.synth.buildings import Building

__all__ = ["RoofFace", "Ridge", "roof_faces", "roof_ridges", "roof_outline_3d", "plane_z"]

_EPS = 1e-7  # plane-coefficient tolerance
_MIN_AREA = 1e-3  # m^2, slivers below this are dropped


@dataclass
class RoofFace:
    """A visible planar roof face: 2D polygon, absolute plane z = a x + b y + c.

    ``support`` holds the absolute planes of the block the face belongs to
    (K, 3): the roof there is their minimum, which the ray caster uses to
    stay exact across ridges and hips; None for faces merged from several
    blocks.
    """

    building_id: int
    polygon: Polygon
    plane: np.ndarray
    support: np.ndarray | None = None

    @property
    def slope_deg(self) -> float:
        return float(np.degrees(np.arctan(np.hypot(self.plane[0], self.plane[1]))))

    @property
    def aspect_deg(self) -> float:
        """Downhill direction, degrees clockwise from north (0 for a flat face)."""
        a, b = self.plane[:2]
        if math.hypot(a, b) < 1e-9:
            return 0.0
        return float(np.degrees(np.arctan2(-a, -b)) % 360.0)


@dataclass
class Ridge:
    """A line shared by two faces of a building: ``kind`` ridge | hip | valley | step."""

    building_id: int
    line: LineString  # 3D
    kind: str


def plane_z(plane: np.ndarray, x, y):
    """Height of plane (a, b, c) at map points."""
    return plane[0] * np.asarray(x) + plane[1] * np.asarray(y) + plane[2]


def _halfplane(coef: np.ndarray, box: tuple[float, float, float, float], strict: bool) -> Polygon | None:
    """Region {a x + b y + c >= 0} (or > 0 when ``strict``) inside ``box``; None = empty, box = everything.

    The box corners are clipped against the line (Sutherland-Hodgman); the
    coefficients are shifted to the box centre so that map-sized
    coordinates keep full precision.
    """
    a, b, c = coef
    x0, y0, x1, y1 = box
    if abs(a) < _EPS and abs(b) < _EPS:
        if c > 1e-6 or (not strict and c >= -1e-6):
            return shapely.box(*box)
        return None
    corners = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    vals = a * corners[:, 0] + b * corners[:, 1] + c
    out = []
    for i in range(4):
        p, q = corners[i], corners[(i + 1) % 4]
        vp, vq = vals[i], vals[(i + 1) % 4]
        if vp >= 0:
            out.append(p)
        if (vp >= 0) != (vq >= 0):
            t = vp / (vp - vq)
            out.append(p + t * (q - p))
    if len(out) < 3:
        return None
    poly = Polygon(out)
    return poly if poly.area > 0 else None


def _clip(geom, coef, box, strict=False):
    hp = _halfplane(coef, box, strict)
    if hp is None:
        return Polygon()
    return shapely.intersection(geom, hp)


def roof_faces(building: Building, base_height: float | None = None) -> list[RoofFace]:
    """Visible planar faces of a building's roof, coplanar pieces merged.

    Parameters
    ----------
    building : Building
    base_height : float, optional
        Absolute terrain height added to the relative planes; default the
        building's ``base_height`` (0 when unset).

    Returns
    -------
    list of RoofFace
        Polygons partition the roof outline (up to slivers under 1e-3 m²).
    """
    base = building.base_height if base_height is None else base_height
    base = 0.0 if base is None else float(base)
    blocks = building.blocks
    xmin, ymin, xmax, ymax = building.roof_outline.bounds
    box = (xmin - 1.0, ymin - 1.0, xmax + 1.0, ymax + 1.0)
    pieces: list[tuple[Polygon, np.ndarray, int]] = []
    for bi, blk in enumerate(blocks):
        for k, pk in enumerate(blk.planes):
            cell = blk.polygon
            for j, pj in enumerate(blk.planes):
                if j != k and not cell.is_empty:
                    cell = _clip(cell, pj - pk, box)  # p_k <= p_j
            if cell.is_empty:
                continue
            for gi, other in enumerate(blocks):
                if gi == bi or not cell.intersects(other.polygon):
                    continue
                higher = other.polygon
                for pg in other.planes:  # other higher where all its planes exceed p_k (ties: earlier block wins)
                    higher = _clip(higher, pg - pk, box, strict=gi > bi)
                    if higher.is_empty:
                        break
                if not higher.is_empty:
                    cell = shapely.difference(cell, higher)
                if cell.is_empty:
                    break
            if not cell.is_empty and cell.area > _MIN_AREA:
                pieces.append((cell, pk, bi))
    # merge coplanar pieces (wings with the same roof plane)
    merged: list[tuple[list[Polygon], np.ndarray, set[int]]] = []
    cx, cy = box[0], box[1]
    for cell, p, bi in pieces:
        for group in merged:
            q = group[1]
            if abs(p[0] - q[0]) < _EPS and abs(p[1] - q[1]) < _EPS and abs(plane_z(p - q, cx, cy)) < 1e-6:
                group[0].append(cell)
                group[2].add(bi)
                break
        else:
            merged.append(([cell], p, {bi}))
    faces = []
    shift = np.array([0.0, 0.0, base])
    for cells, p, bis in merged:
        geom = shapely.set_precision(shapely.union_all(cells), 1e-6)
        support = blocks[next(iter(bis))].planes + shift if len(bis) == 1 else None
        for part in shapely.get_parts(geom):
            if part.geom_type == "Polygon" and part.area > _MIN_AREA:
                faces.append(RoofFace(building.building_id, part, p + shift, support))
    return faces


def roof_ridges(faces: list[RoofFace], min_length: float = 0.2) -> list[Ridge]:
    """Lines shared by two faces of the same building, classified.

    A shared line is continuous when both planes agree on it: ``ridge`` when
    convex and horizontal, ``hip`` when convex and sloped, ``valley`` when
    concave.  Otherwise it is a ``step`` drawn at the upper face's height.
    """
    out: list[Ridge] = []
    for i in range(len(faces)):
        for j in range(i + 1, len(faces)):
            fi, fj = faces[i], faces[j]
            if fi.building_id != fj.building_id:
                continue
            if shapely.distance(fi.polygon, fj.polygon) > 1e-4:
                continue
            lines = [g for g in _shared_lines(fi.polygon, fj.polygon) if g.length >= min_length]
            for line in lines:
                out.extend(_classify(fi, fj, run) for run in _continuity_runs(fi, fj, line))
    return out


def _continuity_runs(fi: RoofFace, fj: RoofFace, line: LineString) -> list[LineString]:
    """Split a shared line where it changes between continuous and stepped."""
    xy = np.asarray(line.coords)[:, :2]
    mid = (xy[1:] + xy[:-1]) / 2
    cont = np.abs(plane_z(fi.plane - fj.plane, mid[:, 0], mid[:, 1])) <= 1e-3
    runs, start = [], 0
    for s in range(1, len(cont) + 1):
        if s == len(cont) or cont[s] != cont[start]:
            runs.append(LineString(xy[start:s + 1]))
            start = s
    return runs


def _shared_lines(pi: Polygon, pj: Polygon, tol: float = 1e-5) -> list[LineString]:
    """Pieces of ``pi``'s boundary lying on ``pj``'s boundary (within ``tol``), merged into lines.

    Each edge of ``pi`` is split at the vertices of ``pj`` lying on it, and a
    piece is kept when its middle lies on ``pj``'s boundary, so shared
    lines end exactly at the faces' vertices.
    """
    bj = pj.boundary
    vj = shapely.get_coordinates(bj)
    pieces = []
    for ring in [pi.exterior, *pi.interiors]:
        c = np.asarray(ring.coords)[:, :2]
        for a, b in zip(c[:-1], c[1:]):
            d = b - a
            length2 = float(d @ d)
            if length2 < 1e-18:
                continue
            w = vj - a
            t = w @ d / length2
            perp = np.abs(d[0] * w[:, 1] - d[1] * w[:, 0]) / math.sqrt(length2)
            ts = np.unique(np.concatenate([[0.0, 1.0], t[(perp < tol) & (t > 1e-9) & (t < 1 - 1e-9)]]))
            mids = a + ((ts[:-1] + ts[1:]) / 2)[:, None] * d
            on = shapely.distance(bj, shapely.points(mids)) < tol
            for k in np.flatnonzero(on):
                pieces.append(LineString([a + ts[k] * d, a + ts[k + 1] * d]))
    if not pieces:
        return []
    return list(shapely.get_parts(shapely.line_merge(shapely.MultiLineString(pieces))))


def _classify(fi: RoofFace, fj: RoofFace, line: LineString) -> Ridge:
    xy = np.asarray(line.coords)[:, :2]
    mid = np.asarray(line.interpolate(0.5, normalized=True).coords[0][:2])
    zi, zj = plane_z(fi.plane, xy[:, 0], xy[:, 1]), plane_z(fj.plane, xy[:, 0], xy[:, 1])
    zm = plane_z(fi.plane - fj.plane, *np.asarray(line.interpolate(0.5, normalized=True).coords[0][:2]))
    if abs(zm) > 1e-3:
        kind = "step"
        z = np.maximum(zi, zj)
    else:
        z = zi
        # a point on face i's side: is face j's plane above it there (convex) or below (concave)?
        d = xy[-1] - xy[0]
        n = np.array([-d[1], d[0]]) / max(np.hypot(*d), 1e-12)
        q = mid + 0.05 * n
        if not fi.polygon.buffer(1e-9).contains(shapely.Point(q)):
            q = mid - 0.05 * n
        convex = plane_z(fj.plane, *q) > plane_z(fi.plane, *q)
        if not convex:
            kind = "valley"
        else:
            kind = "ridge" if abs(z[0] - z[-1]) < 0.05 else "hip"
    return Ridge(fi.building_id, LineString(np.column_stack([xy, z])), kind)


def roof_outline_3d(building: Building, faces: list[RoofFace]) -> Polygon:
    """The roof outline as a PolygonZ: each vertex at the roof height there.

    Vertices of the faces that lie on the outline (gable apexes, wing
    junctions) are inserted, so the 3D edges follow the real roof edge; at a
    step the higher surface wins.
    """
    outline = building.roof_outline
    if outline.geom_type != "Polygon":
        outline = max(shapely.get_parts(outline), key=lambda g: g.area)
    fverts = np.vstack([np.asarray(shapely.get_coordinates(f.polygon)) for f in faces]) if faces else np.empty((0, 2))
    rings = [_ring_3d(np.asarray(r.coords)[:-1, :2], fverts, faces) for r in [outline.exterior, *outline.interiors]]
    return Polygon(rings[0], rings[1:])


def _ring_3d(ring: np.ndarray, fverts: np.ndarray, faces: list[RoofFace]) -> np.ndarray:
    line = LineString(np.vstack([ring, ring[:1]]))
    pos = [(line.project(shapely.Point(p)), tuple(p)) for p in ring]
    if len(fverts):
        pts = shapely.points(fverts)
        near = shapely.distance(line, pts) < 1e-5
        for p in np.unique(np.round(fverts[near], 7), axis=0):
            if np.min(np.hypot(*(ring - p).T)) > 1e-4:
                pos.append((line.project(shapely.Point(p)), tuple(p)))
    pos.sort(key=lambda t: t[0])
    xy = np.array([p for _, p in pos])
    z = np.full(len(xy), -np.inf)
    pts = shapely.points(xy)
    for f in faces:
        touch = shapely.distance(f.polygon, pts) < 1e-4
        if touch.any():
            z[touch] = np.maximum(z[touch], plane_z(f.plane, xy[touch, 0], xy[touch, 1]))
    if not np.isfinite(z).all():  # no face reaches a vertex (sliver): nearest face height
        for i in np.flatnonzero(~np.isfinite(z)):
            f = min(faces, key=lambda f: f.polygon.distance(pts[i]))
            z[i] = plane_z(f.plane, *xy[i])
    return np.column_stack([xy, z])
