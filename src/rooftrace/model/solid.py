"""Closed 2.5D solids from roof cells: roof surfaces on their planes, vertical walls, a ground surface.

:func:`prism_solid` is the one construction behind every level of detail:
LoD 1.2 is one cell (the footprint) with a horizontal plane, LoD 1.3 one
horizontal cell per roof height level, LoD 2.2 one cell per roof face with
the face's plane.

Construction (all coordinates on a grid, 1 mm by default, so that equal
vertices are equal numbers and the CityJSON writer's integer vertices are
exact; plan positions on a coarser lattice, ``snap``, 1 cm by default):

0. A footprint that touches itself on the ``snap`` lattice (a hole touching
   the shell or another hole at one point, pieces touching at a corner) is
   mended first (:func:`_unpinched`): the walls of both sides would stand on
   one vertical edge, which no roof cell can open.
1. The cells' and the footprint's boundaries are snapped to the ``snap``
   lattice, noded together and polygonised (so two plan vertices are at
   least ``snap`` apart: a validator reading the file merges vertices
   closer than its own tolerance, 1 mm for val3dity, and a ring through
   two such vertices would repeat one; faces narrower than the lattice
   vanish instead of tilting at random); each piece goes to the cell
   holding it (pieces no cell holds - gaps of the roof partition - to the
   neighbour sharing most boundary), so the cells tile the footprint
   exactly, edge to edge.
2. Every vertex lying on another cell's edge is inserted in that edge (no
   T-junctions), and where two neighbouring planes cross along a shared
   edge the crossing point is inserted too (the wall between them changes
   side there).
3. Each cell vertex takes the height of the cell's plane; heights of one
   vertex closer than ``z_tolerance`` are made one (a ridge seen from its
   two planes).
4. Roof surfaces are the cells at those heights.  Along every shared edge
   where the two cells' heights differ there is a vertical wall between
   them; along the footprint's boundary a wall from the roof down to the
   ground height.  A wall's vertical sides carry every height the vertex has
   between its bottom and top, so that each vertical edge is shared by
   exactly two walls.  The ground surface is the footprint at the ground
   height, facing down.
5. A roof surface that is flat only to the grid and ``z_tolerance`` but
   whose triangles tilt apart (vertices a lattice step apart) is written
   as those triangles (each one planar).

Walls are vertical and every plan position has one roof height, so the
shell cannot fold over itself; curved outlines stay curved (every outline
vertex is kept).

The parts of one building are cut from one arrangement on the lattice
(:func:`party_walls`) before their solids are built, so that a party wall
has the same vertices on both sides and the parts' solids do not overlap.
"""

from __future__ import annotations

import numpy as np
import shapely
from shapely.geometry import Polygon

from rooftrace.errors import GeometryError
from rooftrace.model.types import Solid, Surface
from rooftrace.model.validity import surface_tilt, surface_triangles

__all__ = ["prism_solid", "horizontal_plane", "party_walls", "split_tilted"]


def horizontal_plane(height: float) -> np.ndarray:
    """The plane ``Z = height`` as ``(a, b, c, d)`` with ``a X + b Y + c Z + d = 0``."""
    return np.array([0.0, 0.0, 1.0, -float(height)])


def _polygons(geom) -> list[Polygon]:
    parts = shapely.get_parts(geom)
    return list(parts[(shapely.get_type_id(parts) == 3) & ~shapely.is_empty(parts) & (shapely.area(parts) > 0)])


def _tile(cells: list, footprint, lattice: float) -> tuple[list[Polygon], list[int], Polygon]:
    """Pieces of the noded arrangement, dissolved per cell; and the footprint they tile."""
    polys = list(shapely.set_precision(shapely.force_2d(np.array([p for p, _ in cells], dtype=object)), lattice))
    fp = shapely.set_precision(shapely.force_2d(footprint), lattice)
    if len(polys) == 1 and shapely.equals(polys[0], fp) and fp.geom_type == "Polygon":
        pieces = np.array([fp], dtype=object)  # one cell that is the footprint (LoD 1.2): nothing to node
    else:
        lines = [shapely.boundary(fp)] + [shapely.boundary(p) for p in polys if not p.is_empty]
        noded = shapely.union_all(lines, grid_size=lattice)
        pieces = np.array(_polygons(shapely.polygonize(shapely.get_parts(noded))), dtype=object)
    if not len(pieces):
        raise GeometryError("the footprint has no area")
    reps = shapely.point_on_surface(pieces)
    pieces = pieces[shapely.contains(fp, reps)]
    reps = reps[shapely.contains(fp, reps)]
    if not len(pieces):
        raise GeometryError("the footprint has no area")
    owner = np.full(len(pieces), len(polys), dtype=np.int64)
    tree = shapely.STRtree(np.array(polys, dtype=object))
    at, cell = tree.query(reps, predicate="within")
    # overlapping cells: the first one wins (a fixed rule, so the result is deterministic)
    np.minimum.at(owner, at, cell)
    owner[owner == len(polys)] = -1
    # gaps of the partition go to the neighbour they share most boundary with
    while (owner < 0).any():
        changed = False
        ptree = shapely.STRtree(pieces)
        for i in np.flatnonzero(owner < 0):
            near = ptree.query(pieces[i], predicate="touches")
            near = near[owner[near] >= 0]
            if not len(near):
                continue
            shared = shapely.length(shapely.intersection(pieces[i].boundary, shapely.boundary(pieces[near])))
            if shared.max() > 0:
                owner[i] = owner[near[np.argmax(shared)]]
                changed = True
        if not changed:
            if (owner >= 0).any():
                # an island no cell touches: the nearest cell's plane
                done = np.flatnonzero(owner >= 0)
                for i in np.flatnonzero(owner < 0):
                    owner[i] = owner[done[np.argmin(shapely.distance(pieces[i], pieces[done]))]]
            else:
                owner[:] = 0
    faces, face_cell = [], []
    for c in np.unique(owner):
        mine = pieces[owner == c]
        merged = mine if len(mine) == 1 else _polygons(shapely.coverage_union_all(mine))
        if not all(g.is_valid for g in merged):
            merged = _polygons(shapely.union_all(mine, grid_size=lattice))
        faces.extend(shapely.orient_polygons(np.array(merged, dtype=object), exterior_cw=False))
        face_cell.extend([int(c)] * len(merged))
    # the pieces are a coverage (edges shared exactly): their fast coverage union
    whole = _polygons(shapely.coverage_union_all(pieces))
    if len(whole) != 1 or not whole[0].is_valid:
        whole = _polygons(shapely.union_all(pieces, grid_size=lattice))
    if len(whole) != 1:
        raise GeometryError(f"the footprint falls into {len(whole)} pieces")
    return faces, face_cell, shapely.orient_polygons(whole[0], exterior_cw=False)


def party_walls(footprints: list, cells: list, snap: float) -> list[tuple]:
    """Each part's footprint and roof cells, all cut from one arrangement on the plan lattice.

    Built one part at a time, the party wall between two parts would be
    snapped to the ``snap`` lattice twice: where a roof face's edge meets it
    one part gets a vertex there, rounded off the straight wall, and the
    other part does not, so the two solids overlap by a sliver (val3dity's
    error 601, BuildingParts overlap).  Noded once for the whole building -
    every part's boundary and every face's boundary together - both sides of
    a party wall have the same vertices, every face cut point included, and
    :func:`~rooftrace.model.solid.prism_solid` finds nothing left to move.

    Parameters
    ----------
    footprints : list of shapely Polygon
        The parts' plan outlines (they should tile the building).
    cells : list of (shapely Polygon, ndarray of shape (4,))
        Roof faces in plan with their planes.
    snap : float
        Plan lattice (m).

    Returns
    -------
    list of (shapely geometry, list of (shapely Polygon, ndarray))
        Per footprint, in order: the footprint on the lattice (empty when it
        vanished there) and its cells, overlaps to the first cell as in
        ``prism_solid``; pieces no cell holds stay gaps for it to fill.
    """
    fps = shapely.set_precision(np.array(footprints, dtype=object), snap)
    cps = shapely.set_precision(np.array([c for c, _ in cells], dtype=object), snap)
    lines = [shapely.boundary(g) for g in (*fps, *cps) if not g.is_empty]
    noded = shapely.union_all(lines, grid_size=snap)
    pieces = np.array(_polygons(shapely.polygonize(shapely.get_parts(noded))), dtype=object)
    reps = shapely.point_on_surface(pieces)

    part_of = np.full(len(pieces), len(fps), dtype=np.int64)
    at, of = shapely.STRtree(fps).query(reps, predicate="within")
    np.minimum.at(part_of, at, of)  # the first one wins: a fixed rule, deterministic
    # a piece takes the first face that holds it as the faces were, among the faces of its part:
    # snapped on its own a face may bulge a lattice step across a party wall
    raw = shapely.force_2d(np.array([c for c, _ in cells], dtype=object))
    fp_raw = shapely.force_2d(np.array(footprints, dtype=object))
    k, c = shapely.STRtree(raw).query(fp_raw, predicate="intersects")
    own = shapely.area(shapely.intersection(fp_raw[k], raw[c])) > snap * snap
    allowed = set(zip(k[own].tolist(), c[own].tolist()))
    cell_of = np.full(len(pieces), len(raw), dtype=np.int64)
    at, of = shapely.STRtree(raw).query(reps, predicate="within")
    for i, c in sorted(zip(at.tolist(), of.tolist()), reverse=True):
        if (int(part_of[i]), c) in allowed:
            cell_of[i] = c
    out = []
    for k in range(len(fps)):
        mine = part_of == k
        footprint = _dissolve(pieces[mine], snap)
        mine_cells = []
        for c in np.unique(cell_of[mine & (cell_of < len(raw))]):
            mine_cells.extend((g, cells[c][1]) for g in shapely.get_parts(_dissolve(pieces[mine & (cell_of == c)], snap)))
        out.append((footprint, mine_cells))
    return out


def _dissolve(pieces: np.ndarray, snap: float):
    """Union of pieces of one noded arrangement (edges shared exactly: the coverage union keeps every node)."""
    if not len(pieces):
        return shapely.Polygon()
    whole = shapely.coverage_union_all(pieces)
    return whole if whole.is_valid else shapely.union_all(pieces, grid_size=snap)


def _first_and_inverse(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For integer rows ``keys`` (N, 2): the first row of each distinct value, and each row's value (0..U-1)."""
    lo = keys.min(axis=0) if len(keys) else np.zeros(2, np.int64)
    span = keys.max(axis=0) - lo + 1 if len(keys) else np.ones(2, np.int64)
    if float(span[0]) * float(span[1]) < 2.0**62:
        _, first, inverse = np.unique((keys[:, 0] - lo[0]) * span[1] + (keys[:, 1] - lo[1]), return_index=True,
                                      return_inverse=True)
    else:
        _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    return first, inverse.ravel()


class _Rings:
    """Rings as indices into one table of integer grid vertices."""

    def __init__(self, grid: float):
        self.grid = grid
        self.index: dict[tuple[int, int], int] = {}
        self.xy: list[tuple[int, int]] = []
        self._tree = None

    def vertex(self, key: tuple[int, int]) -> int:
        v = self.index.get(key)
        if v is None:
            v = self.index[key] = len(self.xy)
            self.xy.append(key)
        return v

    def ring(self, coords) -> list[int]:
        keys = np.round(np.asarray(coords)[:-1, :2] / self.grid).astype(np.int64)
        out = [self.vertex((x, y)) for x, y in keys.tolist()]
        return [v for k, v in enumerate(out) if v != out[k - 1]] if len(out) > 1 else out

    def polygon(self, poly: Polygon) -> list[list[int]]:
        return [self.ring(poly.exterior.coords)] + [self.ring(h.coords) for h in poly.interiors]

    def polygons(self, polys: list) -> list[list[list[int]]]:
        """:meth:`polygon` of each of ``polys`` in turn (vertices numbered as it would), in a few array calls."""
        if self.xy:  # numbering after existing vertices: one polygon at a time
            return [self.polygon(p) for p in polys]
        rings, of = shapely.get_rings(np.asarray(polys, dtype=object), return_index=True)
        coords, at = shapely.get_coordinates(rings, return_index=True)
        size = np.bincount(at, minlength=len(rings)) - 1  # rings are closed: the last coordinate is the first
        open_ = np.ones(len(coords), bool)
        open_[np.cumsum(size + 1) - 1] = False
        keys = np.round(coords[open_, :2] / self.grid).astype(np.int64)
        # vertices numbered in order of first appearance, as vertex() numbers them (whatever order
        # np.unique sorts them in: one integer per (x, y) is much faster than rows)
        first, inverse = _first_and_inverse(keys)
        uniq = keys[first]
        by_first = np.argsort(first, kind="stable")
        rank = np.empty(len(first), dtype=np.int64)
        rank[by_first] = np.arange(len(first))
        vid = rank[inverse.ravel()]
        self.xy = [tuple(k) for k in uniq[by_first].tolist()]
        self.index = {k: v for v, k in enumerate(self.xy)}
        # consecutive repeats out, the ring's last vertex being its first one's predecessor (as ring())
        start = np.concatenate(([0], np.cumsum(size)[:-1]))
        prev = np.arange(len(vid)) - 1
        prev[start] = start + size - 1
        keep = (vid != vid[prev]) | np.repeat(size <= 1, size)
        vid, keep, cut = vid.tolist(), keep.tolist(), np.cumsum(size).tolist()
        kept = [[v for v, k in zip(vid[a:b], keep[a:b]) if k] for a, b in zip([0] + cut[:-1], cut)]
        bounds = np.concatenate(([0], np.cumsum(np.bincount(of, minlength=len(polys))))).tolist()
        return [kept[a:b] for a, b in zip(bounds[:-1], bounds[1:])]

    def split_edges(self, rings: list[list[int]]) -> list[list[int]]:
        """Insert into every ring edge the table's vertices lying exactly on it (no T-junctions)."""
        xy = np.asarray(self.xy, dtype=np.float64)
        if self._tree is None or self._tree[0] != len(xy):
            self._tree = (len(xy), shapely.STRtree(shapely.points(xy)))
        r = np.concatenate([np.asarray(x, dtype=np.int64) for x in rings])
        sizes = np.array([len(x) for x in rings])
        start = np.r_[0, np.cumsum(sizes)[:-1]]
        nxt = np.arange(len(r)) + 1
        nxt[start + sizes - 1] = start
        p, q = xy[r], xy[r[nxt]]
        # the vertices in each edge's box; the exact test below keeps those on it
        seg, cand = self._tree[1].query(shapely.linestrings(np.stack([p, q], axis=1)))
        d = q[seg] - p[seg]
        w = xy[cand] - p[seg]
        L2 = np.maximum((d * d).sum(axis=1), 1e-12)
        t = (w * d).sum(axis=1) / L2
        # integer grid coordinates: on the segment means a zero cross product
        on = (t > 0) & (t < 1) & (d[:, 0] * w[:, 1] - d[:, 1] * w[:, 0] == 0)
        on &= (cand != r[seg]) & (cand != r[nxt][seg])
        if not on.any():
            return [list(x) for x in rings]
        seg, cand, t = seg[on], cand[on], t[on]
        order = np.lexsort((t, seg))
        extra: dict[int, list[int]] = {}
        for k, c in zip(seg[order].tolist(), cand[order].tolist()):
            extra.setdefault(k, []).append(c)
        out = []
        for j, x in enumerate(rings):
            new = []
            for k, v in enumerate(x):
                new.append(v)
                new.extend(extra.get(int(start[j]) + k, ()))
            out.append([v for k, v in enumerate(new) if v != new[k - 1]])
        return out


def split_tilted(roofs: list[list], max_tilt: float) -> list[list]:
    """Roof surfaces, each one whose triangles tilt apart more than ``max_tilt`` degrees cut into them.

    A roof vertex is on its plane only to the grid (and to ``z_tolerance``
    where two faces' heights were made one): with vertices a lattice step
    apart, or nearly in line, the triangles a validator cuts the surface into
    tilt by tens of degrees (val3dity's error 204).  Such a surface becomes
    the triangles of its constrained triangulation in plan, each one planar
    and none degenerate (the plan vertices are on the integer lattice), all
    ``RoofSurface``; the shell stays closed, the triangles share their inner
    edges.
    """
    if not roofs:
        return roofs
    tilt = surface_tilt([Surface([np.asarray(r, dtype=np.float64) for r in rings], "RoofSurface") for rings in roofs],
                        max_tilt)
    split = np.flatnonzero(tilt > max_tilt)
    if not len(split):
        return roofs
    xyz = [np.asarray([v for r in roofs[k] for v in r], dtype=np.float64) for k in split]
    plans = np.array([shapely.Polygon(np.asarray(roofs[k][0])[:, :2], [np.asarray(h)[:, :2] for h in roofs[k][1:]])
                      for k in split])
    corners, of = surface_triangles(plans, np.vstack(xyz)[:, :2], np.repeat(np.arange(len(split)), [len(x) for x in xyz]))
    table = np.vstack(xyz).astype(np.int64)
    triangles = {int(k): [[[tuple(v) for v in table[tri].tolist()]] for tri in corners[of == j]]
                 for j, k in enumerate(split)}
    out = []
    for k, rings in enumerate(roofs):
        out.extend(triangles.get(k, [rings]))
    return out


def _crossing_candidates(p: np.ndarray, q: np.ndarray, ex: float, ey: float, lattice: int,
                         taken: dict) -> list[tuple[int, int]]:
    """Lattice points that may stand for the crossing ``(ex, ey)`` (in lattice steps) of edge ``p -> q`` (grid units).

    The free lattice points (not a vertex yet: a crossing within half a step
    of a vertex would land on it) within a step of the exact crossing, nearest
    first, whose projection falls strictly inside the edge: the edge bends by
    at most a step there, in both faces.  A point beyond an end of the edge
    would fold the ring back on itself (a spike: the surface's plan is no
    longer a valid polygon and cannot be triangulated).
    """
    d = q - p
    length2 = float(d @ d)
    out = []
    for x in range(int(np.floor(ex)) - 1, int(np.ceil(ex)) + 2):
        for y in range(int(np.floor(ey)) - 1, int(np.ceil(ey)) + 2):
            dist2 = (x - ex) ** 2 + (y - ey) ** 2
            key = (x * lattice, y * lattice)
            t = ((key[0] - p[0]) * d[0] + (key[1] - p[1]) * d[1]) / length2 if length2 > 0 else -1.0
            if dist2 <= 2.0 and 0.0 < t < 1.0 and key not in taken:
                out.append((dist2, key))
    return [key for _, key in sorted(out)]


def _simple_with(rings: list[list[int]], edge: tuple[int, int], point: tuple[int, int], xy: np.ndarray) -> bool:
    """Whether the face of ``rings`` stays a valid polygon with ``point`` put into ``edge`` (either direction).

    A lattice point near an end of a short edge can fold the ring back onto
    the next edge (a spike), which no triangulation takes.
    """
    a, b = edge
    coords = []
    for ring in rings:
        r = np.asarray(ring, dtype=np.int64)
        w = np.roll(r, -1)
        at = np.flatnonzero(((r == a) & (w == b)) | ((r == b) & (w == a)))
        coords.append(np.insert(xy[r], at + 1, np.broadcast_to(np.asarray(point, dtype=np.float64), (len(at), 2)),
                                axis=0))
    return bool(shapely.Polygon(coords[0], coords[1:]).is_valid)


def _simple_with_all(faces: list, edges: list, points: list, xy: np.ndarray) -> np.ndarray:
    """:func:`_simple_with` of each ``(faces[k], edges[k], points[k])``, the polygons built and tested in array calls."""
    if not faces:
        return np.zeros(0, dtype=bool)
    ring_v = [np.asarray(r, dtype=np.int64) for rings in faces for r in rings]
    n_rings = [len(rings) for rings in faces]
    v = np.concatenate(ring_v)
    size = np.array([len(r) for r in ring_v])
    ring = np.repeat(np.arange(len(ring_v)), size)
    face = np.repeat(np.arange(len(faces)), n_rings)[ring]
    after = np.arange(len(v)) + 1
    ends = np.cumsum(size) - 1
    after[ends] = ends - size + 1
    a, b = np.array(edges, dtype=np.int64).T
    w = v[after]
    hit = np.flatnonzero(((v == a[face]) & (w == b[face])) | ((v == b[face]) & (w == a[face])))
    # the point after every occurrence of the edge, in its ring
    coords = np.insert(xy[v], hit + 1, np.asarray(points, dtype=np.float64)[face[hit]], axis=0)
    ring = np.insert(ring, hit + 1, ring[hit])
    rings = shapely.linearrings(coords, indices=ring)
    return shapely.is_valid(shapely.polygons(rings, indices=np.repeat(np.arange(len(faces)), n_rings)))


def _insert(ring: list[int], between: dict[tuple[int, int], int], ends: set[int] | None = None) -> list[int]:
    """``ring`` with ``between[(p, q)]`` inserted between consecutive vertices ``p, q``.

    ``ends``: the vertices of ``between``'s keys; a ring through none of them is copied as it is.
    """
    if ends is not None and ends.isdisjoint(ring):
        return list(ring)
    out = []
    for k, p in enumerate(ring):
        out.append(p)
        w = between.get((p, ring[(k + 1) % len(ring)]))
        if w is not None:
            out.append(w)
    return out


def prism_solid(cells, ground_height: float, *, footprint=None, grid: float = 1e-3, snap: float = 0.01,
                z_tolerance: float = 0.01, max_tilt: float = 10.0) -> Solid:
    """A closed solid from roof cells, walls down to ``ground_height`` and a ground surface.

    Parameters
    ----------
    cells : sequence of (shapely Polygon, array_like of shape (4,))
        Roof cells in plan (Z ignored, holes allowed) with the plane
        ``(a, b, c, d)``, ``a X + b Y + c Z + d = 0`` (``c != 0``), that
        gives their height.  They should tile ``footprint``; gaps are filled
        by the neighbouring cell, overlaps go to the first cell.
    ground_height : float
        Height of the ground surface (m).
    footprint : shapely Polygon, optional
        The plan outline of the solid; default the union of the cells.
        Where it touches itself at a point on the ``snap`` lattice it gets a
        notch there, an octagon of 2 lattice steps (up to 64 in a narrow
        wedge); pieces touching its largest one at a point are dropped
        (under 1 m²) or joined to it by the octagon.
    grid : float, default 0.001
        Every vertex is rounded to this grid (m).
    snap : float, default 0.01
        Plan positions are rounded to this lattice (m), a multiple of
        ``grid``: distinct vertices are at least this far apart.
    z_tolerance : float, default 0.01
        Heights of one vertex closer than this (m) are made one.
    max_tilt : float, default 10
        A roof surface whose triangles' normals are more than this
        (degrees) apart is written as its triangles (half of val3dity's
        20 degree tolerance: its triangulation may differ from ours).

    Returns
    -------
    Solid
        Surfaces in the order roofs, walls, ground.

    Raises
    ------
    GeometryError
        The footprint is empty or falls apart, a roof lies at or below the
        ground, or two cells cross along a shared edge where no crossing
        point can be inserted.

    Examples
    --------
    >>> import shapely
    >>> solid = prism_solid([(shapely.box(0, 0, 10, 6), horizontal_plane(8.0))], 2.0)
    >>> [s.kind for s in solid.surfaces].count("WallSurface")
    4
    """
    if not (snap >= grid and abs(snap / grid - round(snap / grid)) < 1e-6):
        raise ValueError(f"snap must be a multiple of grid, got {snap} and {grid}")
    cells = [(c, np.asarray(pl, dtype=np.float64)) for c, pl in cells]
    if not cells:
        raise GeometryError("no roof cells")
    if footprint is None:
        footprint = shapely.union_all([shapely.force_2d(c) for c, _ in cells])
    footprint = _unpinched(footprint, snap)
    attempt = 0
    while True:
        try:
            return _prism(cells, ground_height, footprint, grid, snap, z_tolerance, max_tilt)
        except _Saddle as saddle:
            if attempt == 3:
                raise GeometryError(f"roof faces meet at {len(saddle.points)} saddle or pinch vertices") from None
            if attempt == 0:  # two lattice steps
                radius, small = 2 * snap, 0.0
            elif attempt == 1:  # a disk's own edge made a new one: cut the narrowest sector two steps wide
                radius, small = np.clip(snap / np.sin(saddle.angles / 2), 4 * snap, 25 * snap), 0.0
            else:
                radius, small = 2 * snap * 4 ** (attempt - 1), 1.0
            opened = _open_saddles(cells, saddle.points, saddle.faces, radius, small=small)
            # dropping slivers opens no disk: the saddles it leaves get this attempt's disks next time (the
            # cells only get fewer, so this ends)
            dropped = small > 0 and len(opened) < len(cells)
            cells = opened
            attempt += 0 if dropped else 1


def _pinch_points(polygon) -> np.ndarray:
    """Plan positions (M, 2) where the rings of ``polygon`` pass more than once (a hole touching the shell or
    another hole at one point)."""
    rings = shapely.get_rings(polygon)
    xy = np.concatenate([shapely.get_coordinates(r)[:-1] for r in rings]) if len(rings) else np.zeros((0, 2))
    uniq, count = np.unique(xy, axis=0, return_counts=True)
    return uniq[count > 1]


def _unpinched(footprint, snap: float):
    """``footprint`` without the points where its boundary touches itself on the ``snap`` lattice.

    Where a hole touches the shell (or another hole) at one point, the walls
    of both rings stand on the same vertical edge: four walls, a
    non-manifold edge no roof cell can mend (the disks of
    :func:`_open_saddles` stop at the footprint).  A notch, an octagon of
    radius two lattice steps around the point, is cut out of the footprint
    there (the hole then opens onto the outside, or the two holes become
    one): the outline moves inward by at most ``2 snap`` (m) within that
    octagon, no roof height changes.  Where the cut would split the
    footprint, the octagon is added instead (the roof there is the
    neighbouring cell's plane carried over at most ``2 snap``).  The octagon
    grows (4, 8, ... 64 steps) while the lattice makes a new pinch of a
    narrow sector's tip (a wedge of a few degrees is under a step wide for
    decimetres).

    A footprint of pieces touching at points (a part's footprint cut from a
    building's arrangement may keep a lobe of a few cm² at a corner) first
    loses the pieces under ``SLIVER_AREA`` that touch the largest one; a
    larger piece touching it is joined to it by the octagon.  Pieces that do
    not touch are left: such a footprint is not one solid.

    A footprint without such a point is returned as it is.
    """
    fp = shapely.set_precision(shapely.force_2d(footprint), snap)
    joined = fp.geom_type == "MultiPolygon"
    if joined:
        fp = _one_piece(fp, snap)
        if fp is None:
            return footprint
    elif fp.geom_type != "Polygon":
        return footprint
    points = _pinch_points(fp)
    if not len(points):
        return fp if joined else footprint
    for steps in (2, 4, 8, 16, 32, 64):
        notch = shapely.union_all(shapely.buffer(shapely.points(points), steps * snap, quad_segs=2))
        cut = shapely.set_precision(shapely.difference(fp, notch), snap)
        if cut.geom_type != "Polygon":
            cut = shapely.set_precision(shapely.union(fp, notch), snap)
        if cut.geom_type == "Polygon" and not len(_pinch_points(cut)):
            return cut
    return footprint  # left as it was: the solid reports the saddle


#: pieces of a footprint (m²) touching its largest piece at a point that are dropped rather than joined to it
SLIVER_AREA = 1.0


def _one_piece(pieces, snap: float):
    """The largest of ``pieces`` (polygons on the lattice), with those touching it at points dropped (under
    ``SLIVER_AREA``) or joined to it by an octagon of two lattice steps; None if some piece does not touch."""
    parts = sorted(shapely.get_parts(pieces), key=lambda g: -g.area)
    main, rest = parts[0], parts[1:]
    if not all(shapely.intersects(main, g) for g in rest):
        return None
    big = [g for g in rest if g.area >= SLIVER_AREA]
    if big:
        touch = shapely.get_coordinates(shapely.intersection(main, shapely.union_all(big)))
        notch = shapely.buffer(shapely.points(touch), 2 * snap, quad_segs=2)
        main = shapely.set_precision(shapely.union_all([main, *big, *notch]), snap)
    return main if main.geom_type == "Polygon" else None


class _Saddle(Exception):
    """A vertex where the shell would not be 2-manifold: four or more walls sharing a vertical
    edge (faces high, low, high, low around it), or a face touching itself."""

    def __init__(self, points: np.ndarray, faces: list[int], angles: np.ndarray):
        super().__init__(f"{len(points)} saddle vertices")
        self.points, self.faces, self.angles = points, faces, angles


def _narrowest_sector(vertices: list[int], rings: list[list[int]], xy: np.ndarray) -> np.ndarray:
    """Per vertex, the smallest angle (radians) between two consecutive ring edges leaving it in plan."""
    out = []
    for v in vertices:
        ends = {r[(k + d) % len(r)] for r in rings for k in np.flatnonzero(np.asarray(r) == v) for d in (-1, 1)}
        d = xy[sorted(ends)] - xy[v]
        theta = np.sort(np.arctan2(d[:, 1], d[:, 0]))
        gaps = np.diff(np.r_[theta, theta[0] + 2 * np.pi]) if len(theta) > 1 else np.array([2 * np.pi])
        out.append(float(np.clip(gaps.min(), 1e-3, np.pi)))
    return np.asarray(out)


def _open_saddles(cells: list, points: np.ndarray, faces: list[int], radius, small: float = 0.0) -> list:
    """Give a cell a small disk around each vertex: at a saddle the highest cell, so that its high
    neighbours join it through an edge and the low ones stay apart (two walls per vertical edge); at
    a pinch the cell touching itself, which then surrounds the vertex.  Cells under ``small`` m² at
    such a vertex (slivers wedged between a face and the outline) are dropped first: their neighbours
    fill the gap, and the next attempt opens what is left."""
    cells = list(cells)
    if small > 0:
        near = shapely.union_all(shapely.buffer(shapely.points(points), radius))
        keep = [not (poly.area < small and poly.intersects(near)) for poly, _ in cells]
        if not all(keep) and any(keep):
            return [c for c, k in zip(cells, keep) if k]  # the next attempt finds what is left
    polys = np.array([poly for poly, _ in cells], dtype=object)
    for (x, y), c, r in zip(points, faces, np.broadcast_to(radius, len(points))):
        disk = shapely.Point(x, y).buffer(r, quad_segs=2)
        grown = shapely.union(polys[c], disk)
        polys = shapely.difference(polys, disk)
        polys[c] = grown
    return [(poly, plane) for poly, (_, plane) in zip(polys, cells) if not poly.is_empty]


def _walls(wp: np.ndarray, wq: np.ndarray, zlp: np.ndarray, zlq: np.ndarray, zrp: np.ndarray, zrq: np.ndarray,
           v: np.ndarray, z: np.ndarray, ground_v: np.ndarray, g: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The wall under each edge ``wp -> wq``: its rings' vertices and heights, all walls one after the other.

    A wall runs ``(p, zrp), (q, zrq)``, up ``q`` through every height the
    vertex has between ``zrq`` and ``zlq``, ``(q, zlq), (p, zlp)``, and down
    ``p`` through its heights between ``zlp`` and ``zrp`` (so that each
    vertical edge is shared by exactly two walls); a vertex equal to the one
    before it (the first one's predecessor being the last) is left out.  The
    heights of a vertex are those of every roof ring vertex ``v`` at ``z``
    and ``g`` for the ground ring's vertices (grid units).

    Returns
    -------
    wall_v, wall_z : ndarray of shape (M,), int
        Vertex and height of each wall vertex.
    wall_of : ndarray of shape (M,), int
        Wall of each (sorted).
    """
    n = len(wp)
    if not n:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64)
    # every vertex's distinct heights, sorted by (vertex, height): one key per pair
    all_v = np.concatenate([v, ground_v])
    all_z = np.concatenate([z, np.full(len(ground_v), g, dtype=np.int64)])
    low = min(int(all_z.min()), int(min(zrp.min(), zrq.min(), zlp.min(), zlq.min())))
    span = max(int(all_z.max()), int(max(zrp.max(), zrq.max(), zlp.max(), zlq.max()))) - low + 1
    level = np.unique(all_v * span + (all_z - low))
    level_z = level % span + low

    def strictly_between(u, z0, z1):
        """Where the heights of ``u`` strictly between z0 and z1 start in ``level``, how many, and their direction."""
        lo, hi = np.minimum(z0, z1), np.maximum(z0, z1)
        first = np.searchsorted(level, u * span + (lo - low), side="right")
        count = np.maximum(np.searchsorted(level, u * span + (hi - low), side="left") - first, 0)
        return first, count, z1 > z0

    c_first, c_count, c_up = strictly_between(wq, zrq, zlq)
    f_first, f_count, f_up = strictly_between(wp, zlp, zrp)
    size = 4 + c_count + f_count
    of = np.repeat(np.arange(n), size)
    pos = np.arange(len(of)) - np.repeat(np.cumsum(size) - size, size)
    cc, fc = c_count[of], f_count[of]
    on_q = (pos >= 1) & (pos <= 2 + cc)
    out_v = np.where(on_q, wq[of], wp[of])
    out_z = np.empty(len(of), dtype=np.int64)
    # the four corners
    for at, zz in ((pos == 0, zrp), (pos == 1, zrq), (pos == 2 + cc, zlq), (pos == 3 + cc, zlp)):
        out_z[at] = zz[of[at]]
    # up (or down) q from zrq to zlq, then p from zlp to zrp
    for at, k, first, count, up in (((pos >= 2) & (pos < 2 + cc), pos - 2, c_first, c_count, c_up),
                                   ((pos >= 4 + cc) & (pos < 4 + cc + fc), pos - 4 - cc, f_first, f_count, f_up)):
        w = of[at]
        out_z[at] = level_z[np.where(up[w], first[w] + k[at], first[w] + count[w] - 1 - k[at])]
    # consecutive repeats out, each ring closing on itself
    before = np.arange(len(of)) - 1
    starts = np.cumsum(size) - size
    before[starts] = starts + size - 1
    keep = (out_v != out_v[before]) | (out_z != out_z[before])
    return out_v[keep], out_z[keep], of[keep]


def _prism(cells: list, ground_height: float, footprint, grid: float, snap: float, z_tolerance: float,
           max_tilt: float) -> Solid:
    faces, face_cell, whole = _tile(cells, footprint, snap)
    table = _Rings(grid)
    *face_rings, ground_rings = table.polygons([*faces, whole])
    g = int(round(ground_height / grid))
    planes = np.array([cells[c][1] for c in face_cell], dtype=np.float64)
    if not (np.abs(planes[:, 2]) > 1e-9).all():
        raise GeometryError("a vertical roof plane")
    tol = z_tolerance / grid
    lattice = int(round(snap / grid))  # plan lattice in grid steps

    def edges(face_rings):
        """Every directed ring edge: its face, start and end vertex, the next edge of its ring and the
        opposite edge (-1: none)."""
        sizes = np.array([len(r) for rings in face_rings for r in rings], dtype=np.int64)
        f = np.repeat(np.repeat(np.arange(len(face_rings)), [len(rings) for rings in face_rings]), sizes)
        p = np.array([v for rings in face_rings for r in rings for v in r], dtype=np.int64)
        start = np.r_[0, np.cumsum(sizes)[:-1]]
        nx = np.arange(len(p)) + 1  # the next edge of the same ring
        nx[start + sizes - 1] = start
        q = p[nx]
        m = len(table.xy)
        key = p * m + q
        order = np.argsort(key)
        at = np.clip(np.searchsorted(key[order], q * m + p), 0, len(key) - 1)
        opp = np.where(key[order][at] == q * m + p, order[at], -1)
        return f, p, q, nx, opp

    def z_at(f, v):
        xy = np.asarray(table.xy, dtype=np.float64)[v] * grid
        pl = planes[f]
        return np.round(-(pl[:, 0] * xy[:, 0] + pl[:, 1] * xy[:, 1] + pl[:, 3]) / pl[:, 2] / grid)

    crossings: set[int] = set()  # vertices where two planes cross: one height, whatever the tolerance

    def one_height(p, zz):
        """One height per (vertex, near-equal heights): a ridge is one line for both of its planes."""
        order = np.lexsort((zz, p))
        sv, sz = p[order], zz[order]
        forced = np.isin(sv[1:], np.fromiter(crossings, dtype=np.int64, count=len(crossings)))
        new_group = np.r_[True, (sv[1:] != sv[:-1]) | ((np.diff(sz) >= tol) & ~forced)]
        gid = np.cumsum(new_group) - 1
        mean = np.round(np.bincount(gid, weights=sz) / np.bincount(gid)).astype(np.int64)
        out = np.empty_like(zz)
        out[order] = mean[gid]
        return out

    # T-junctions out (every vertex lying exactly on another cell's edge)
    counts = np.cumsum([0] + [len(rings) for rings in face_rings])
    flat = table.split_edges([r for rings in face_rings for r in rings] + ground_rings)
    face_rings = [flat[counts[i]:counts[i + 1]] for i in range(len(face_rings))]
    ground_rings = flat[counts[-1]:]
    # a face whose rings pass twice through a vertex (a hole touching its
    # outer ring) would pinch the shell there: open it like a saddle
    ring_v = np.concatenate([r for rings in face_rings for r in rings]).astype(np.int64)
    ring_face = np.repeat(np.arange(len(face_rings)), [sum(map(len, rings)) for rings in face_rings])
    uses, twice = np.unique(ring_face * len(table.xy) + ring_v, return_counts=True)
    # by face, then vertex
    pinch = [(v, i) for i, v in zip(*(a.tolist() for a in np.divmod(uses[twice > 1], len(table.xy))))]
    if pinch:
        xy = np.asarray(table.xy, dtype=np.float64)
        at = [v for v, _ in pinch]
        raise _Saddle(xy[at] * grid, [face_cell[i] for _, i in pinch],
                      _narrowest_sector(at, [r for rings in face_rings for r in rings] + ground_rings, xy))
    # where two neighbouring planes cross along their shared edge the wall
    # between them changes side: put the crossing point into both rings
    for _ in range(4):
        f, p, q, nx, opp = edges(face_rings)
        zz = z_at(f, p).astype(np.int64)
        snapped = one_height(p, zz)
        has = opp >= 0
        o = np.maximum(opp, 0)
        zl_q = snapped[nx]
        zr_p = np.where(has, snapped[nx[o]], g)
        zr_q = np.where(has, snapped[o], g)
        cross = np.flatnonzero(has & (f < f[o]) & ((snapped - zr_p) * (zl_q - zr_q) < 0))
        if not len(cross):
            break
        xyf = np.asarray(table.xy, dtype=np.float64)
        d0 = (zz[cross] - zz[nx[o[cross]]]).astype(np.float64)
        d1 = (zz[nx[cross]] - zz[o[cross]]).astype(np.float64)
        t = np.clip(d0 / np.where(d0 != d1, d0 - d1, 1.0), 0.0, 1.0)
        exact = (xyf[p[cross]] + t[:, None] * (xyf[q[cross]] - xyf[p[cross]])) / lattice
        crossing: dict[tuple[int, int], int] = {}
        pq = list(zip(p[cross].tolist(), q[cross].tolist()))
        candidates = [_crossing_candidates(xyf[pp], xyf[qq], ex, ey, lattice, table.index)
                      for (pp, qq), (ex, ey) in zip(pq, exact.tolist())]
        # the nearest candidate of every crossing tested in both faces at once (nearly always the one taken)
        nearest = [k for k, c in enumerate(candidates) if c]
        sides = [(int(f[cross[k]]), int(f[o[cross[k]]])) for k in nearest]
        valid = _simple_with_all([face_rings[i] for pair in sides for i in pair],
                                 [pq[k] for k in nearest for _ in range(2)],
                                 [candidates[k][0] for k in nearest for _ in range(2)], xyf).reshape(-1, 2).all(axis=1)
        first_ok = dict(zip(nearest, valid.tolist()))
        added: set[tuple[int, int]] = set()
        for n, (k, (pp, qq)) in enumerate(zip(cross.tolist(), pq)):
            # the nearest candidate that keeps both faces valid (the points taken by the crossings before are
            # taken for this one too)
            free = None
            for j, c in enumerate(candidates[n]):
                if c in added:
                    continue
                if (j == 0 and first_ok[n]) or (j > 0 and all(
                        _simple_with(face_rings[i], (pp, qq), c, xyf) for i in (f[k], f[o[k]]))):
                    free = c
                    break
            if free is None:
                raise GeometryError("two roof faces cross along their shared edge at one of its vertices")
            crossing[(pp, qq)] = crossing[(qq, pp)] = table.vertex(free)
            added.add(free)
            # on the lattice the point is up to half a step off the crossing, where the two
            # heights may differ by more than the tolerance: they are made one there
            crossings.add(crossing[(pp, qq)])
        ends = {v for key in crossing for v in key}
        face_rings = [[_insert(r, crossing, ends) for r in rings] for rings in face_rings]
    else:
        raise GeometryError("two roof faces cross along their shared edge")
    if snapped.min() <= g:
        raise GeometryError(f"a roof lies at or below the ground height ({snapped.min() * grid:.2f} <= "
                            f"{ground_height:.2f} m)")
    xy = np.asarray(table.xy, dtype=np.int64)  # (x, y) per vertex, grid units
    bounds = np.concatenate(([0], np.cumsum([len(r) for rings in face_rings for r in rings]))).tolist()
    roof_xyz = np.column_stack([xy[p], snapped])  # the roof rings' vertices, in order
    flat_rings = [roof_xyz[a:b] for a, b in zip(bounds[:-1], bounds[1:])]
    counts = np.cumsum([0] + [len(rings) for rings in face_rings])
    roofs = [flat_rings[counts[i]:counts[i + 1]] for i in range(len(face_rings))]
    need = np.flatnonzero((~has | (f < f[o])) & ((snapped != zr_p) | (zl_q != zr_q)))
    wall_v, wall_z, wall_of = _walls(p[need], q[need], snapped[need], zl_q[need], zr_p[need], zr_q[need], p, snapped,
                                     np.concatenate(ground_rings).astype(np.int64), g)
    # each elementary vertical edge must be in exactly two walls; more means a
    # saddle vertex (heights high, low, high, low around it)
    after = np.arange(len(wall_v)) + 1
    ends = np.flatnonzero(np.r_[wall_of[1:] != wall_of[:-1], True]) if len(wall_of) else np.zeros(0, np.int64)
    after[ends] = np.r_[0, ends[:-1] + 1]
    upright = wall_v == wall_v[after]
    edge_v, edge_z = wall_v[upright], np.minimum(wall_z, wall_z[after])[upright]
    saddle_v = np.zeros(0, dtype=np.int64)
    if len(edge_v):
        # one integer per (vertex, lower height): a vertical edge's uses counted without unique rows
        z0 = edge_z.min()
        zspan = int(edge_z.max() - z0) + 1
        codes, uses = np.unique(edge_v * zspan + (edge_z - z0), return_counts=True)
        saddle_v = np.unique(codes[uses > 2] // zspan)
    if len(saddle_v):
        at = saddle_v[np.lexsort((xy[saddle_v, 1], xy[saddle_v, 0]))].tolist()  # in (x, y) order
        highest = [int(f[p == v][np.argmax(snapped[p == v])]) for v in at]
        raise _Saddle(xy[at].astype(np.float64) * grid, [face_cell[i] for i in highest],
                      _narrowest_sector(at, [r for rings in face_rings for r in rings] + ground_rings,
                                        xy.astype(np.float64)))
    wall_xyz = np.column_stack([xy[wall_v], wall_z])
    cut = np.r_[0, ends + 1].tolist()
    walls = [[wall_xyz[a:b]] for a, b in zip(cut[:-1], cut[1:])]
    ground = [np.column_stack([xy[np.asarray(r[::-1], dtype=np.int64)], np.full(len(r), g, dtype=np.int64)])
              for r in ground_rings]

    roofs = split_tilted(roofs, max_tilt)
    surfaces = [(r, "RoofSurface") for r in roofs] + [(r, "WallSurface") for r in walls] + [(ground, "GroundSurface")]
    # every vertex of the shell converted in one call (the roofs' are arrays already), then cut into rings
    rings = [r for rs, _ in surfaces for r in rs]
    stacked = [isinstance(r, np.ndarray) for r in rings]
    sizes = [len(r) for r in rings]
    table_xyz = np.empty((sum(sizes), 3), dtype=np.int64)
    in_array = np.repeat(stacked, sizes)
    if in_array.any():
        table_xyz[in_array] = np.concatenate([r for r, a in zip(rings, stacked) if a])
    if not in_array.all():
        table_xyz[~in_array] = np.array([v for r, a in zip(rings, stacked) if not a for v in r], dtype=np.int64)
    cut = np.cumsum([0] + sizes).tolist()
    table_xyz = table_xyz.astype(np.float64) * grid
    coords = [table_xyz[a:b] for a, b in zip(cut[:-1], cut[1:])]
    at = np.cumsum([0] + [len(rs) for rs, _ in surfaces]).tolist()
    return Solid([Surface(coords[at[i]:at[i + 1]], kind) for i, (_, kind) in enumerate(surfaces)])
