"""Boxes on a LoD 2.2 roof for the top points its faces leave far under them: vent pipes, chimneys, roof lights.

A chimney or a vent pipe of one return at AHN3's spacing is no plane and no
flat block of the face partition (:func:`rooftrace.roof.superstructures.superstructures`
names such points, with the blocks' points whose face the partition lost).
Giving each one a face of the raster partition doubles the faces, and the
part and model steps' CPU follows the face count.  Here such a point
becomes a box built straight into the finished solid: a square of the
spacing's side centred on the point, a hole of that square in the roof
surface under it (its corners on that surface's plane), four walls up to
the point's height and a flat top (``RoofSurface``).  The shell stays
closed and 2-manifold: the hole's edges are the walls' feet, their upper
edges the top's.  Nothing else of the solid changes, but at an edge with
a wall: the outline drawn through the outermost returns puts a vent's
return at the eaves millimetres from the edge, where a hole cannot reach;
there the box is a notch in the roof surface, and the wall under the edge
gets the notch's two corners (the box's outer wall stands on it) or, a
wall over the edge (a step's foot), goes round the box's outer side.
"""

from __future__ import annotations

import numpy as np
import shapely
from scipy.spatial import cKDTree

from rooftrace.model.solid import split_tilted
from rooftrace.model.types import Solid, Surface
from rooftrace.model.validity import surface_normal, surface_normals, surface_polygons, surface_tilt

__all__ = ["with_boxes", "BOX_REASONS"]

#: why a top point more than ``rise`` above the LoD 2.2 roof got no box (``with_boxes``' second value)
BOX_REASONS = ("at a roof edge", "beside a higher box", "crowded by lower points", "too low above the surface",
               "would tilt its roof surface", "on no roof surface")


def with_boxes(solid: Solid, points: np.ndarray, side: float, *, others: np.ndarray | None = None, rise: float = 0.5,
               grid: float = 1e-3, snap: float = 0.01, max_tilt: float = 10.0, party=None) -> tuple[Solid, np.ndarray]:
    """``solid`` with a box under each of ``points`` that stands more than ``rise`` above its roof.

    Guarantee: every one of ``points`` over a roof surface of ``solid``
    lies within ``rise`` (m) under the returned solid's roof, or above it,
    unless one of :data:`BOX_REASONS` holds for it: its box, cut to the
    roof surface it stands on two lattice steps inside that surface's edges,
    does not hold it and neither does the box reaching the edges of that
    surface nearest to it where walls meet them ("at a roof edge": a
    chimney on a ridge or in a valley, a box at a corner of the surface, one
    rising over the wall that stands over the edge); it meets the box of a
    higher point ("beside a higher box"); a
    point of ``others`` standing more than ``rise`` lower lies within two
    lattice steps of it ("crowded by lower points"); the surface is within
    two lattice steps under the box's top at one of its corners ("too low
    above the surface"); the hole would make the roof surface's triangles
    tilt more than ``max_tilt`` apart ("would tilt its roof surface").  A
    box is the hull of the squares, ``side`` wide (less where a point of
    ``others`` standing more than ``rise`` lower would be under it), of the
    points beside each other on one surface within ``rise`` under the
    highest of them, at that one's height.  A box at an edge is a notch in
    its roof surface: where the wall stands under the edge (the eaves, a
    step's top) its outer wall stands on the wall's top; where the wall
    stands over it (a step's foot) the wall goes round the box's outer side
    (the box then stays two lattice steps under the wall's top).

    Parameters
    ----------
    solid : Solid
        A closed 2.5D solid (:func:`rooftrace.model.solid.prism_solid`).
    points : ndarray of shape (N, 3)
        Top points of superstructures (m).
    side : float
        Side of a box's square (m): the point spacing.
    others : ndarray of shape (M, 3), optional
        The building's points, which a box must not stand over by more
        than ``rise`` (m).
    rise : float
        A point within this (m) above or under the roof needs no box.
    grid, snap : float
        Vertex grid and plan lattice (m), as the solid was built.
    max_tilt : float
        Largest angle (degrees) between the triangles of a roof surface with
        holes (half of val3dity's 20, as :func:`rooftrace.model.solid.prism_solid`).
    party : shapely geometry, optional
        The building's other parts in plan (m): no box reaches an edge over
        a party wall ("at a roof edge"), whose wall the neighbour's solid
        shares vertex for vertex.

    Returns
    -------
    solid : Solid
        A new solid (``solid`` itself when no box was added).
    why : ndarray of shape (N,), object
        Per point, why it is left more than ``rise`` under the roof (one of
        :data:`BOX_REASONS`), ``""`` for the others.

    Examples
    --------
    >>> import shapely
    >>> from rooftrace.model.solid import prism_solid, horizontal_plane
    >>> from rooftrace.model.validity import solid_errors
    >>> from rooftrace.model.measure import roof_height_at
    >>> house = prism_solid([(shapely.box(0, 0, 10, 6), horizontal_plane(8.0))], 2.0)
    >>> vent = np.array([[3.0, 3.0, 9.1]])
    >>> boxed, why = with_boxes(house, vent, 0.4)
    >>> solid_errors(boxed), why.tolist(), len(boxed.surfaces) - len(house.surfaces)
    ([], [''], 5)
    >>> roof_height_at([boxed], vent[:, :2]).round(3).tolist()
    [9.1]
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    skipped = np.full(len(points), "", dtype=object)
    roof_at = [k for k, s in enumerate(solid.surfaces) if s.kind == "RoofSurface"]
    if not len(points) or not roof_at:
        return solid, skipped
    roofs = [solid.surfaces[k] for k in roof_at]
    # a building's top points against one of its parts: only those in the part's box are looked at
    xy = np.concatenate([s.rings[0][:, :2] for s in roofs])
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    near = np.flatnonzero(((points[:, :2] >= lo) & (points[:, :2] <= hi)).all(axis=1))
    skipped[:] = "on no roof surface"
    if not len(near):
        return solid, skipped
    if others is not None:
        others = np.asarray(others, dtype=np.float64).reshape(-1, 3)
        others = others[((others[:, :2] >= lo - side) & (others[:, :2] <= hi + side)).all(axis=1)]
    if len(near) < len(points):
        boxed, why = with_boxes(solid, points[near], side, others=others, rise=rise, grid=grid, snap=snap,
                                max_tilt=max_tilt, party=party)
        skipped[near] = why
        return boxed, skipped
    skipped[:] = ""
    normal, centre = surface_normals(roofs)
    plans = surface_polygons(roofs, plan=True)
    up = np.abs(normal[:, 2]) > 1e-9 * np.maximum(np.linalg.norm(normal, axis=1), 1e-300)
    tree = shapely.STRtree(plans)
    # the roof surface over each point and its height there: only points that stand more than rise above it
    pt_at, surf = tree.query(shapely.points(points[:, :2]), predicate="intersects")
    ok = up[surf]
    pt_at, surf = pt_at[ok], surf[ok]
    height = np.full(len(points), np.nan)
    zs = _plane_z(normal[surf], centre[surf], points[pt_at, :2])
    np.fmax.at(height, pt_at, zs)
    # the roof surface the point stands on: the highest over it (as the solid's roof height is)
    surface_of = np.full(len(points), -1)
    best = np.lexsort((zs, pt_at))
    last = np.r_[pt_at[best][1:] != pt_at[best][:-1], True][:len(best)]
    surface_of[pt_at[best][last]] = surf[best][last]
    skipped[np.isnan(height)] = "on no roof surface"
    need = np.flatnonzero(points[:, 2] - height > rise)
    if not len(need):
        return solid, skipped
    lattice = int(round(snap / grid))
    half = _half_sides(points[need], side, others, rise, snap) * lattice  # grid units
    crowded = half < 2 * lattice
    if crowded.any():
        skipped[need[crowded]] = "crowded by lower points"
        need, half = need[~crowded], half[~crowded]
        if not len(need):
            return solid, skipped
    centre_g = np.round(points[need, :2] / snap).astype(np.int64) * lattice
    top_g = np.round(points[need, 2] / grid).astype(np.int64)
    under = surface_of[need]
    order = np.argsort(-points[need, 2], kind="stable")  # the highest first
    tree_c = cKDTree(centre_g.astype(np.float64))
    rise_g = rise / grid
    groups = _box_groups(order, centre_g, half, under, top_g, rise_g, lattice, tree_c)
    plans_m, at_edge, inside = _box_plans(groups, centre_g, half, plans[under[[j for j, _ in groups]]],
                                          points[need, :2], grid, snap)
    on_roof: dict[int, list[tuple]] = {}  # per roof surface: its boxes' holes, surfaces and points
    placed: dict[int, list] = {}
    edges = None  # the solid's directed edges, for the boxes at an edge
    for (j, members), plan_m, edge, own_in in zip(groups, plans_m, at_edge, inside):
        top, k = int(top_g[j]), int(under[j])
        notch = None
        held = np.zeros(len(members), dtype=bool) if edge else own_in
        if not held.all():
            # at an eave, a step's top or foot: the box reaches the edge, its outer side on the wall or cut into it
            if edges is None:
                edges = _directed_edges(solid, grid)
            own = shapely.points(points[need[members], :2])
            notch = _notch(_hull(centre_g[members], half[members], grid), roofs[k], own, edges, solid, top, rise,
                           grid, snap, party)
            if notch is not None and k in placed and shapely.dwithin(notch[0], placed[k], 2 * snap).any():
                if not held.any():
                    skipped[need[members]] = "beside a higher box"
                    continue
                notch = None
            if notch is not None:
                plan_m, top = notch[0], notch[4]
                own_in = shapely.contains(plan_m, own)
            elif not held.any():
                skipped[need[members]] = "at a roof edge"
                continue
        # (surfaces do not overlap in plan: only boxes on the same one can meet; within half a lattice step, as
        # the hull's coordinates and a cut one's, both on the lattice, may differ in their last bits)
        if k in placed and shapely.dwithin(plan_m, placed[k], 0.5 * snap).any():
            skipped[need[members]] = "beside a higher box"
            continue
        if notch is None:
            ring = np.round(np.asarray(plan_m.exterior.coords)[:-1] / grid).astype(np.int64)
            if not shapely.is_ccw(plan_m.exterior):
                ring = ring[::-1]
        else:
            ring = notch[1]
        foot = np.round(_plane_z(np.repeat(normal[k:k + 1], len(ring), 0), np.repeat(centre[k:k + 1], len(ring), 0),
                                 ring * grid) / grid).astype(np.int64)
        if notch is not None:  # the corners on the edges: on them, as the walls' tops have them
            foot[:len(notch[2])] = notch[2]
        if top - foot.max() < 2 * lattice:
            skipped[need[members]] = "too low above the surface"
            continue
        placed.setdefault(k, []).append(plan_m)
        n = len(ring)
        nxt = np.r_[1:n, 0]
        walls = np.stack([np.column_stack([ring, foot]), np.column_stack([ring[nxt], foot[nxt]]),
                          np.column_stack([ring[nxt], np.full(n, top)]), np.column_stack([ring, np.full(n, top)])],
                         axis=1) * grid
        if notch is not None and notch[3][2]:  # against a higher wall: its notch is the box's outer side
            walls = walls[1:]
        box = [Surface([np.column_stack([ring, np.full(n, top)]) * grid], "RoofSurface")]
        box.extend(Surface([w], "WallSurface") for w in walls)
        # a hole: clockwise seen from above; a notch: the same, from the edge's first corner, into the outer ring
        on_roof.setdefault(k, []).append((np.column_stack([ring, foot])[::-1] * grid, box, need[members])
                                         if notch is None else
                                         (None, box, need[members], notch[3], np.column_stack([ring, foot]), top))
        skipped[need[members[~own_in]]] = "at a roof edge"
    if not on_roof:
        return solid, skipped
    notched = _notches_kept(solid, roofs, roof_at, on_roof, skipped, grid, max_tilt)
    if not on_roof:
        return solid, skipped
    holed = {k: [Surface([notched.get(roof_at[k], roofs[k].rings[0])] + list(roofs[k].rings[1:])
                         + [b[0] for b in boxes if b[0] is not None], "RoofSurface")]
             for k, boxes in on_roof.items()}
    # a roof surface's own vertices lie on its plane to the tolerance of its heights, its holes' exactly: thin
    # triangles between them may tilt beyond what a validator takes (val3dity's 204); such a surface is written as
    # its triangles, as the solid builder writes one
    # (a horizontal surface's triangles cannot tilt)
    keys = [k for k in holed if np.ptp(roofs[k].rings[0][:, 2]) > 0]
    tilted = np.asarray(keys, dtype=np.int64)[surface_tilt([holed[k][0] for k in keys], max_tilt) > max_tilt].tolist() \
        if keys else []
    dropped = False
    for k in tilted:
        triangles = split_tilted([[np.round(r / grid).astype(np.int64) for r in holed[k][0].rings]], max_tilt)
        if len(triangles) > 1:
            holed[k] = [Surface([np.asarray(r, dtype=np.float64) * grid for r in tri], "RoofSurface")
                        for tri in triangles]
        else:  # not cut: that surface keeps no box
            dropped = True
            for b in on_roof.pop(k):
                skipped[b[2]] = "would tilt its roof surface"
    if not on_roof:
        return solid, skipped
    if dropped:  # a surface that keeps no box keeps its edges: the walls under its notches are built again
        notched = _notches_kept(solid, roofs, roof_at, on_roof, skipped, grid, max_tilt)
    by_index = {roof_at[k]: holed[k] for k in on_roof}
    by_index.update({i: [Surface([ring], solid.surfaces[i].kind)] for i, ring in notched.items() if i not in by_index})
    surfaces = [t for i, s in enumerate(solid.surfaces) for t in by_index.get(i, [s])]
    added = [face for k in sorted(on_roof) for b in on_roof[k] for face in b[1]]
    roof_end = max(roof_at) + 1 + sum(len(v) - 1 for v in by_index.values())
    return Solid(surfaces[:roof_end] + added + surfaces[roof_end:]), skipped


def _box_groups(order: np.ndarray, centre_g: np.ndarray, half: np.ndarray, under: np.ndarray, top_g: np.ndarray,
                rise_g: float, lattice: int, tree: cKDTree) -> list[tuple[int, np.ndarray]]:
    """Each box's highest point and its points, taken in ``order`` (highest first): the free points whose squares
    touch the highest free one's on the same surface, standing at most ``rise_g`` grid steps lower, are one box
    with it (a chimney's top of a few returns, its rim).  Lattice and grid units as in :func:`with_boxes`."""
    # every point's neighbours in one query (only a free point's are used; the query is cheap beside the loop)
    reach = (half + half.max() + lattice).astype(np.float64)
    near_all = tree.query_ball_point(centre_g.astype(np.float64), r=reach, p=np.inf, return_sorted=False)
    taken = np.zeros(len(order), dtype=bool)
    groups = []
    for j in order.tolist():
        if taken[j]:
            continue
        near = np.asarray(near_all[j])
        gap = np.abs(centre_g[near] - centre_g[j]).max(axis=1)
        members = near[~taken[near] & (under[near] == under[j]) & (top_g[j] - top_g[near] <= rise_g)
                       & (gap <= half[j] + half[near] + lattice)]
        taken[members] = True
        groups.append((j, members))
    return groups


def _box_plans(groups: list, centre_g: np.ndarray, half: np.ndarray, surface_plans: np.ndarray, xy: np.ndarray,
               grid: float, snap: float) -> tuple[np.ndarray, np.ndarray, list]:
    """Plan of each box of ``groups`` (:func:`_box_groups`) on its roof surface's plan, all in a few calls.

    A box is the hull of its points' squares cut to its surface two
    lattice steps inside the surface's edges (a vent at the eaves, a
    chimney at a ridge: the box stops there), its vertices put back on the
    lattice.  Returns the plans, whether each box is "at a roof edge" (its
    plan is no polygon, has a hole, comes within a lattice step of the
    surface's edges, or holds none of its points) and, per box, which of its
    points its plan holds.
    """
    sizes = np.array([len(m) for _, m in groups], dtype=np.int64)
    members = np.concatenate([m for _, m in groups])
    of = np.repeat(np.arange(len(groups)), sizes)
    c, hm = centre_g[members], half[members, None]
    # per box its squares' corners as one box's were listed: all lower left corners, then the lower right, ...
    corners = np.stack([c + hm * [-1, -1], c + hm * [1, -1], c + hm * [1, 1], c + hm * [-1, 1]])
    box_of, corner, rank = np.tile(of, 4), np.repeat(np.arange(4), len(members)), np.tile(np.arange(len(members)), 4)
    listed = np.lexsort((rank, corner, box_of))
    hull = shapely.convex_hull(shapely.multipoints(corners.reshape(-1, 2)[listed].astype(np.float64) * grid,
                                                   indices=box_of[listed]))
    # (the surface cut to the hull's box first: a roof's whole outline is slow to buffer, and the cut's own edges
    # lie three steps beyond the hull, out of the buffers' reach)
    local = np.array([shapely.clip_by_rect(g, x0 - 3 * snap, y0 - 3 * snap, x1 + 3 * snap, y1 + 3 * snap)
                      for g, (x0, y0, x1, y1) in zip(surface_plans, shapely.bounds(hull).tolist())], dtype=object)
    inner = shapely.buffer(local, -2 * snap, join_style="mitre")
    # (the hull of lattice points is on the lattice; only a cut one needs putting back on it)
    cut = ~shapely.contains(inner, hull)
    plan = hull.copy()
    plan[cut] = shapely.set_precision(shapely.intersection(hull[cut], inner[cut]), snap)
    ok = (shapely.get_type_id(plan) == 3) & ~shapely.is_empty(plan) & (shapely.get_num_interior_rings(plan) == 0)
    check = np.flatnonzero(ok & cut)
    ok[check] = shapely.contains(shapely.buffer(local[check], -snap, join_style="mitre"), plan[check])
    inside = np.zeros(len(members), dtype=bool)
    on = ok[of]
    inside[on] = shapely.contains(plan[of[on]], shapely.points(xy[members[on]]))
    ok &= np.bincount(of, weights=inside, minlength=len(groups)) > 0
    starts = np.r_[0, np.cumsum(sizes)[:-1]]
    return plan, ~ok, [inside[a:a + n] for a, n in zip(starts, sizes)]


def _half_sides(points: np.ndarray, side: float, others: np.ndarray | None, rise: float, snap: float) -> np.ndarray:
    """Half the side of each point's square, in lattice steps: ``side / 2``, less where a point of ``others``
    standing more than ``rise`` lower lies nearer (Chebyshev, plan) than that (the box would stand over it)."""
    half = np.full(len(points), max(int(round(side / 2 / snap)), 2), dtype=np.int64)
    if others is None or not len(others) or not len(points):
        return half
    others = np.asarray(others, dtype=np.float64).reshape(-1, 3)
    # a few points against a building's many: each looks at the slice of them sorted by x within its square
    order = np.argsort(others[:, 0], kind="stable")
    xs = others[order, 0]
    lo = np.searchsorted(xs, points[:, 0] - side / 2, side="left")
    hi = np.searchsorted(xs, points[:, 0] + side / 2, side="right")
    for j in range(len(points)):
        idx = order[lo[j]:hi[j]]
        idx = idx[np.abs(others[idx, 1] - points[j, 1]) <= side / 2]
        low = idx[others[idx, 2] < points[j, 2] - rise]
        if len(low):
            d = np.abs(others[low, :2] - points[j, :2]).max(axis=1).min()
            half[j] = min(half[j], int(np.floor(d / snap)) - 1)
    return half


def _plane_z(normal: np.ndarray, centre: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Height (m) at ``xy`` of the planes through ``centre`` with ``normal`` (one per row)."""
    return centre[:, 2] - (normal[:, 0] * (xy[:, 0] - centre[:, 0]) + normal[:, 1] * (xy[:, 1] - centre[:, 1])) \
        / normal[:, 2]


def _hull(centre_g: np.ndarray, half: np.ndarray, grid: float):
    """The convex hull (m) of the squares of ``half`` (grid units) centred on ``centre_g``: one box's plan uncut."""
    hm = half[:, None]
    corners = np.concatenate([centre_g + hm * [-1, -1], centre_g + hm * [1, -1], centre_g + hm * [1, 1],
                              centre_g + hm * [-1, 1]])
    return shapely.convex_hull(shapely.multipoints(corners.astype(np.float64) * grid))


def _directed_edges(solid: Solid, grid: float) -> tuple[np.ndarray, np.ndarray]:
    """The directed edges of the solid's outer rings, vertices on the grid (integer): a table of (N, 6), each
    edge's start and end, and the surface each bounds (see :func:`_edge_surface`)."""
    rings = [s.rings[0] for s in solid.surfaces]
    size = np.array([len(r) for r in rings])
    first = np.repeat(np.cumsum(size) - size, size)
    at = np.arange(len(first))
    following = first + (at - first + 1) % np.repeat(size, size)
    v = np.round(np.concatenate(rings) / grid).astype(np.int64)
    return np.hstack([v, v[following]]), np.repeat(np.arange(len(rings)), size)


def _edge_surface(edges: tuple[np.ndarray, np.ndarray], a, b) -> int | None:
    """The surface whose outer ring runs from ``a`` to ``b`` (grid units), ``None`` if none does."""
    hit = np.flatnonzero((edges[0] == np.concatenate([a, b])).all(axis=1))
    return int(edges[1][hit[0]]) if len(hit) else None


def _notch(hull, roof: Surface, own: np.ndarray, edges: tuple, solid: Solid, top: int, rise: float, grid: float,
           snap: float, party=None):
    """A box reaching the edge of its roof surface where a wall meets that edge (an eave, a step, its foot).

    The box is ``hull`` cut to the surface (not inside it): a notch cut from the edges of the surface's outer
    ring it reaches (one edge, or several through the ring's corners it covers, walls under each), its other
    edges two lattice steps away.  Where walls stand under those edges (the eaves, a step's top) the box's outer walls stand on
    their top edges; where a wall stands over the one edge (a step's foot) the box's outer side is a notch cut
    into that wall, its top (``top``, grid units) put two lattice steps under the wall's top when it is higher,
    by ``rise`` (m) at most.  ``None`` where none is so (a ridge, a valley; the box would not hold one of
    ``own``).

    Returns
    -------
    plan : shapely Polygon
        The box in plan (m).
    ring : ndarray of shape (K, 2), int64
        Its corners (grid units), counter-clockwise: the one on the first edge reached, the ring's corners
        covered, the one on the last edge, then the others.
    foot : ndarray, int64
        The heights (grid units) of the first of those: on the edges, where the walls' tops have them.
    where : tuple
        The ring's corners from the first edge's start to the last edge's end (grid units), the walls' indices
        in ``solid`` (one per edge), and whether the wall stands over the edge.
    top : int
        The box's top (grid units).
    """
    ring3 = np.round(roof.rings[0] / grid).astype(np.int64)
    xy = ring3[:, :2] * grid
    n = len(xy)
    nxt = np.r_[1:n, 0]
    seg = shapely.linestrings(np.stack([xy, xy[nxt]], axis=1))
    i = int(np.argmin(shapely.distance(seg, shapely.multipoints(shapely.get_coordinates(own)))))
    # the edges reached: on from the nearest one through each ring corner the box covers (at most all but two)
    covered = shapely.covers(hull, shapely.points(xy))
    first, last = i, i
    while covered[first] and (last - first) % n < n - 2:
        first = (first - 1) % n
    while covered[nxt[last]] and (last - first) % n < n - 2:
        last = nxt[last]
    widest = [(first + j) % n for j in range((last - first) % n + 2)]  # ring corners from the first edge's start
    for chain in (widest, [i, int(nxt[i])]):
        walls = [_edge_surface(edges, ring3[b], ring3[a]) for a, b in zip(chain, chain[1:])]
        # only at walls (a box on a ridge or a valley would need a notch in both roofs); a wall, counter-clockwise
        # seen from outside, lies left of its edge b -> a: under the edge or over it
        if any(w is None or solid.surfaces[w].kind != "WallSurface" for w in walls):
            return None
        # nor at a party wall: the neighbour's solid shares it vertex for vertex, a notch would move it
        if party is not None and shapely.dwithin(shapely.points((xy[chain[:-1]] + xy[chain[1:]]) / 2), party,
                                                 snap).any():
            return None
        over = [bool(np.cross(surface_normal(solid.surfaces[w].rings), (ring3[a] - ring3[b]).astype(np.float64))[2]
                     > 0) for w, a, b in zip(walls, chain, chain[1:])]
        # (a wall over an edge takes a box on that edge alone: the box is cut back from the corners)
        if len(walls) == 1 or not any(over):
            break
    holes = [h[:, :2] for h in roof.rings[1:]]
    # the surface's other edges (from the last edge's end round to the first one's start) and its holes stay two
    # lattice steps away (a box at another corner is cut back from the other edge, on the lattice); both cut to
    # the hull's box three steps wide, out of the buffer's reach (a roof's whole outline is slow to buffer)
    near = np.asarray(hull.bounds) + np.array([-3, -3, 3, 3]) * snap
    surface = shapely.clip_by_rect(shapely.Polygon(xy, holes), *near)
    rest = shapely.clip_by_rect(shapely.MultiLineString([np.roll(xy, -int(chain[-1]), axis=0)[:(n - len(chain) + 2)]]
                                                        + [np.vstack([h, h[:1]]) for h in holes]), *near)
    if shapely.distance(shapely.intersection(hull, surface), rest) < 2 * snap - 0.5 * grid:
        hull = shapely.set_precision(shapely.difference(hull, shapely.buffer(rest, 2 * snap, join_style="mitre")),
                                     snap)
    plan = shapely.intersection(hull, surface)
    if plan.geom_type != "Polygon" or plan.is_empty or len(plan.interiors) or not shapely.contains(plan, own).any() \
            or shapely.distance(plan, rest) < snap:
        return None
    corners = np.asarray(plan.exterior.coords)[:-1]
    if not shapely.is_ccw(plan.exterior):
        corners = corners[::-1]
    on = shapely.distance(shapely.points(corners), shapely.linestrings(xy[chain])) < 0.5 * grid
    # the run of corners on the edges: its two ends and the ring's corners between (the others lie on the edges'
    # lines, nothing is lost)
    start = np.flatnonzero(on & ~np.roll(on, 1))
    if len(start) != 1 or on.all():
        return None
    corners = np.roll(corners, -int(start[0]), axis=0)
    run = int(on.sum())
    # the ends on the grid on the surface's side of their edges: a wall bent outwards by the rounding would stand
    # over a neighbouring part by a fraction of a millimetre (val3dity's 601)
    ends = np.array([_grid_inside(corners[0] / grid, ring3[chain[0], :2], ring3[chain[1], :2]),
                     _grid_inside(corners[run - 1] / grid, ring3[chain[-2], :2], ring3[chain[-1], :2])])
    others = np.round(corners[run:] / grid).astype(np.int64)
    # (a lattice corner of the hull within a lattice step of an end: a sliver side; the end takes its place)
    lattice = round(snap / grid)
    while len(others) > 1 and np.abs(others[0] - ends[1]).max() < lattice:
        others = others[1:]
    while len(others) > 1 and np.abs(others[-1] - ends[0]).max() < lattice:
        others = others[:-1]
    ring = np.vstack([ends[:1], ring3[chain[1:-1], :2], ends[1:], others])
    if np.abs(ring - np.roll(ring, -1, axis=0)).max(axis=1).min() < 2 or \
            not shapely.is_valid(shapely.Polygon(ring)) or not shapely.is_ccw(shapely.LinearRing(ring)):
        return None
    # the two ends' heights and places along their edges, as the edges' straight lines give them
    a, b = ring3[chain[:2]], ring3[chain[-2:]]
    t = np.array([(ends[0] - a[0, :2]) @ (a[1, :2] - a[0, :2]) / float((a[1, :2] - a[0, :2]) @ (a[1, :2] - a[0, :2])),
                  (ends[1] - b[0, :2]) @ (b[1, :2] - b[0, :2]) / float((b[1, :2] - b[0, :2]) @ (b[1, :2] - b[0, :2]))])
    if not (0 < t[0] < 1 and 0 < t[1] < 1 and (len(chain) > 2 or t[0] < t[1])):
        return None
    foot = np.concatenate([np.round(a[0, 2:] + t[0] * (a[1, 2:] - a[0, 2:])), ring3[chain[1:-1], 2],
                           np.round(b[0, 2:] + t[1] * (b[1, 2:] - b[0, 2:]))]).astype(np.int64)
    if over[0]:
        # the notch in the wall (across it from the edge, up from its feet) two lattice steps inside its other edges
        wall = solid.surfaces[walls[0]].rings[0]
        along = (a[1, :2] - a[0, :2]) / np.sqrt(float((a[1, :2] - a[0, :2]) @ (a[1, :2] - a[0, :2])))
        side = shapely.Polygon(np.column_stack([(wall[:, :2] - a[0, :2] * grid) @ along, wall[:, 2]]))
        s = (ends * grid - a[0, :2] * grid) @ along
        strip = shapely.box(s[0] - 2 * snap, foot.max() * grid + 0.5 * grid, s[1] + 2 * snap, top * grid + 2 * snap)
        if not shapely.contains(side, strip):
            # (a parapet's return a centimetre off the step's top: the box as high as the wall lets it)
            above = shapely.difference(strip, side)
            if above.is_empty or not shapely.contains(side, shapely.box(*strip.bounds[:3], above.bounds[1])):
                return None
            highest = int(np.floor(above.bounds[1] / grid)) - 2 * int(round(snap / grid))
            if (top - highest) * grid > rise:
                return None
            top = highest
    plan = shapely.Polygon(ring * grid)
    if not shapely.contains(plan, own).any():
        return None
    return plan, ring, foot, ([tuple(p) for p in ring3[chain].tolist()], walls, over[0]), top


def _grid_inside(point: np.ndarray, p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The grid point (integer) nearest to ``point`` (grid units) on the edge ``p`` -> ``q`` or left of it."""
    cand = np.floor(point).astype(np.int64) + np.array([[0, 0], [1, 0], [0, 1], [1, 1]])
    d = (q - p).astype(np.float64)
    left = d[0] * (cand[:, 1] - p[1]) - d[1] * (cand[:, 0] - p[0]) >= 0
    far = np.hypot(*(cand - point).T) + np.where(left, 0.0, np.inf)
    return cand[int(np.argmin(far))]


def _split_edge(ring: list, p: tuple, q: tuple, at: tuple, new: list) -> None:
    """Insert ``new`` into ``ring`` (integer vertices) where it runs along the edge ``p``-``q`` past ``at``.

    The edge may be cut already (other notches' corners on it, within a grid unit of its line): ``new`` goes
    between the two of its vertices on the line that ``at`` lies between.
    """
    r = np.asarray(ring, dtype=np.float64)
    p_, d = np.asarray(p, dtype=np.float64), np.subtract(q, p).astype(np.float64)
    t = (r - p_) @ d / (d @ d)
    online = np.linalg.norm(r - p_ - t[:, None] * d, axis=1) <= 2.0
    tc = (np.asarray(at, dtype=np.float64) - p_) @ d / (d @ d)
    for j in range(len(ring)):
        k = (j + 1) % len(ring)
        if online[j] and online[k] and min(t[j], t[k]) < tc < max(t[j], t[k]):
            ring[j + 1:j + 1] = new
            return
    raise ValueError("a notch's corner on no edge of its ring")


def _notches_kept(solid: Solid, roofs: list, roof_at: list, on_roof: dict, skipped: np.ndarray, grid: float,
                  max_tilt: float) -> dict:
    """:func:`_with_notches`, the boxes at an edge left out (from ``on_roof``, their points "at a roof edge" in
    ``skipped``) where a wall they change would tilt: its top's new corners lie on its plane only to the grid, and
    corners close together make thin triangles a validator finds tilted (val3dity's 204)."""
    while True:  # each pass returns or leaves out a box
        try:
            notched = _with_notches(solid, roofs, roof_at, on_roof, grid)
        except ValueError:  # (a notch's end on no edge of the ring: not seen; every box at an edge is left out)
            notched, bad = {}, None
        else:
            walls = [i for i in notched if solid.surfaces[i].kind == "WallSurface"]
            tilt = surface_tilt([Surface([notched[i]], "WallSurface") for i in walls], max_tilt) if walls else []
            bad = {i for i, t in zip(walls, tilt) if t > max_tilt}
            if not bad:
                return notched
        for k in list(on_roof):
            out = [b[0] is None and (bad is None or bool(set(b[3][1]) & bad)) for b in on_roof[k]]
            for b, o in zip(on_roof[k], out):
                if o:
                    skipped[b[2]] = "at a roof edge"
            on_roof[k] = [b for b, o in zip(on_roof[k], out) if not o]
            if not on_roof[k]:
                del on_roof[k]
        if bad is None:
            return {}


def _with_notches(solid: Solid, roofs: list, roof_at: list, on_roof: dict, grid: float) -> dict:
    """The outer rings (m) of the roof surfaces and walls the boxes at an edge change: the roof's ring goes round
    each notch (the ring's corners the box covers left out); a wall's edge gets the notch's corner on it (a wall
    under the edge: the box's outer wall stands on it) or goes round the box's outer side (a wall over it)."""
    rings: dict[int, list] = {}

    def ring_of(i):
        return rings.setdefault(i, [tuple(p) for p in np.round(solid.surfaces[i].rings[0] / grid).astype(np.int64)
                                    .tolist()])

    for k in sorted(on_roof):
        for b in on_roof[k]:
            if b[0] is not None:
                continue
            (chain, walls, over), box, top = b[3], [tuple(p) for p in b[4].tolist()], b[5]
            inner = len(chain) - 2  # the ring's corners the box covers
            c_a, c_b = box[0], box[inner + 1]
            cut = [c_a] + box[inner + 2:][::-1] + [c_b]
            roof = ring_of(roof_at[k])
            if inner:
                at = roof.index(chain[1])
                roof[at:at + inner] = cut
            else:
                _split_edge(roof, chain[0], chain[1], c_a, cut)
            if over:
                _split_edge(ring_of(walls[0]), chain[0], chain[1], c_a,
                            [c_b, (*c_b[:2], top), (*c_a[:2], top), c_a])
            elif inner:
                _split_edge(ring_of(walls[0]), chain[0], chain[1], c_a, [c_a])
                _split_edge(ring_of(walls[-1]), chain[-2], chain[-1], c_b, [c_b])
            else:
                _split_edge(ring_of(walls[0]), chain[0], chain[1], c_a, [c_b, c_a])
    return {i: np.asarray(r, dtype=np.float64) * grid for i, r in rings.items()}
