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
edges the top's.  Nothing else of the solid changes.
"""

from __future__ import annotations

import numpy as np
import shapely
from scipy.spatial import cKDTree

from rooftrace.model.solid import split_tilted
from rooftrace.model.types import Solid, Surface
from rooftrace.model.validity import surface_normals, surface_polygons, surface_tilt

__all__ = ["with_boxes", "BOX_REASONS"]

#: why a top point more than ``rise`` above the LoD 2.2 roof got no box (``with_boxes``' second value)
BOX_REASONS = ("at a roof edge", "beside a higher box", "crowded by lower points", "too low above the surface",
               "would tilt its roof surface", "on no roof surface")


def with_boxes(solid: Solid, points: np.ndarray, side: float, *, others: np.ndarray | None = None, rise: float = 0.5,
               grid: float = 1e-3, snap: float = 0.01, max_tilt: float = 10.0) -> tuple[Solid, np.ndarray]:
    """``solid`` with a box under each of ``points`` that stands more than ``rise`` above its roof.

    Guarantee: every one of ``points`` over a roof surface of ``solid``
    lies within ``rise`` (m) under the returned solid's roof, or above it,
    unless one of :data:`BOX_REASONS` holds for it: its box, cut to the
    roof surface it stands on two lattice steps inside that surface's edges,
    does not hold it ("at a roof edge": a vent at the eaves, a chimney on a
    ridge); it meets the box of a higher point ("beside a higher box"); a
    point of ``others`` standing more than ``rise`` lower lies within two
    lattice steps of it ("crowded by lower points"); the surface is within
    two lattice steps under the box's top at one of its corners ("too low
    above the surface"); the hole would make the roof surface's triangles
    tilt more than ``max_tilt`` apart ("would tilt its roof surface").  A
    box is the hull of the squares, ``side`` wide (less where a point of
    ``others`` standing more than ``rise`` lower would be under it), of the
    points beside each other on one surface within ``rise`` under the
    highest of them, at that one's height.

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
                                max_tilt=max_tilt)
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
    for (j, members), plan_m, edge, own_in in zip(groups, plans_m, at_edge, inside):
        top, k = int(top_g[j]), int(under[j])
        if edge:
            skipped[need[members]] = "at a roof edge"
            continue
        # (surfaces do not overlap in plan: only boxes on the same one can meet; within half a lattice step, as
        # the hull's coordinates and a cut one's, both on the lattice, may differ in their last bits)
        if k in placed and shapely.dwithin(plan_m, placed[k], 0.5 * snap).any():
            skipped[need[members]] = "beside a higher box"
            continue
        ring = np.round(np.asarray(plan_m.exterior.coords)[:-1] / grid).astype(np.int64)
        if not shapely.is_ccw(plan_m.exterior):
            ring = ring[::-1]
        foot = np.round(_plane_z(np.repeat(normal[k:k + 1], len(ring), 0), np.repeat(centre[k:k + 1], len(ring), 0),
                                 ring * grid) / grid).astype(np.int64)
        if top - foot.max() < 2 * lattice:
            skipped[need[members]] = "too low above the surface"
            continue
        placed.setdefault(k, []).append(plan_m)
        n = len(ring)
        nxt = np.r_[1:n, 0]
        walls = np.stack([np.column_stack([ring, foot]), np.column_stack([ring[nxt], foot[nxt]]),
                          np.column_stack([ring[nxt], np.full(n, top)]), np.column_stack([ring, np.full(n, top)])],
                         axis=1) * grid
        box = [Surface([np.column_stack([ring, np.full(n, top)]) * grid], "RoofSurface")]
        box.extend(Surface([w], "WallSurface") for w in walls)
        # a hole: clockwise seen from above
        on_roof.setdefault(k, []).append((np.column_stack([ring, foot])[::-1] * grid, box, need[members]))
        skipped[need[members[~own_in]]] = "at a roof edge"
    if not on_roof:
        return solid, skipped
    holed = {k: [Surface(list(roofs[k].rings) + [hole for hole, _, _ in boxes], "RoofSurface")]
             for k, boxes in on_roof.items()}
    # a roof surface's own vertices lie on its plane to the tolerance of its heights, its holes' exactly: thin
    # triangles between them may tilt beyond what a validator takes (val3dity's 204); such a surface is written as
    # its triangles, as the solid builder writes one
    # (a horizontal surface's triangles cannot tilt)
    keys = [k for k in holed if np.ptp(roofs[k].rings[0][:, 2]) > 0]
    tilted = np.asarray(keys, dtype=np.int64)[surface_tilt([holed[k][0] for k in keys], max_tilt) > max_tilt].tolist() \
        if keys else []
    for k in tilted:
        triangles = split_tilted([[np.round(r / grid).astype(np.int64) for r in holed[k][0].rings]], max_tilt)
        if len(triangles) > 1:
            holed[k] = [Surface([np.asarray(r, dtype=np.float64) * grid for r in tri], "RoofSurface")
                        for tri in triangles]
        else:  # not cut: that surface keeps no box
            for _, _, at in on_roof.pop(k):
                skipped[at] = "would tilt its roof surface"
    if not on_roof:
        return solid, skipped
    by_index = {roof_at[k]: holed[k] for k in on_roof}
    surfaces = [t for i, s in enumerate(solid.surfaces) for t in by_index.get(i, [s])]
    added = [face for k in sorted(on_roof) for _, box, _ in on_roof[k] for face in box]
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
