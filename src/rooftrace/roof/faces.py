"""Roof faces that tile the outline, and the step edges between roof levels.

The outline's bounding box is rasterised (cell ``cell`` m) and each cell
takes the plane of its nearest labelled point (the Voronoi partition of the
labelled points, to the cell size): at a height step the boundary then lies
halfway between the points of the two levels, so every labelled point sits
under its own plane.  Near a ridge, hip or valley found by
:mod:`rooftrace.roof.ridges` the nearest point is not good enough, so there a
cell takes the candidate plane (of its ``k`` nearest labelled points) that
agrees with the line's geometry: the lower of the two planes across a convex
line, the higher across a concave one.  The face boundaries then follow the
intersection lines (to the cell size) rather than the point pattern; a line
that would put the points beside it under the other plane (two roof levels
whose extended planes cross near their step) is not used.  The
label raster is turned into polygons (``rasterio.features.shapes``) and
each shared boundary, from node to node, is simplified once by its own rule
(``boundaries='each'``): a ridge or valley, where the two planes meet, goes
straight between its nodes; a height step only as far as it moves no
labelled point to under a face more than ``max_dz`` off its own plane (a
cell holding points of both levels is first split in four, ``refine_steps``).  The
simplified boundaries are polygonised, so neighbours
keep identical edges.  (``'held'`` simplifies all boundaries together,
``shapely.coverage_simplify``, at one tolerance per roof held back by the
same rule; ``'free'`` at ``simplify`` cells.)  Each region is cut by the
outline; slivers are merged into the neighbour they share most boundary
with.  The faces therefore tile the outline exactly, and each face takes its
Z from its plane.
"""

from __future__ import annotations

import logging
from collections import Counter
from itertools import chain

import numpy as np
import shapely
from scipy import ndimage
from scipy.spatial import cKDTree
from shapely.geometry import LineString

from rooftrace.graph import components
from rooftrace.roof.face_kernels import cell_choice, cell_lines, nearest_points, points_in_boxes, simplify_arcs
from rooftrace.roof.lowparts import open_to_sky
from rooftrace.roof.planes import plane_height

__all__ = ["partition_outline", "snap_to_lines", "merge_close_vertices", "lift_to_plane", "step_edges",
           "points_off_their_faces", "points_on_their_faces", "claim_points", "hidden_under", "eaves",
           "attached_points", "points_in_faces", "faces_off_their_points", "fit_faces"]

log = logging.getLogger(__name__)

#: most raster cells per building before the cell is coarsened
MAX_CELLS = 1_000_000


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Plan distance of points (V, 2) to segments a-b (V, 2) each, elementwise."""
    ab = b - a
    L2 = np.maximum((ab * ab).sum(axis=1), 1e-12)
    ap = p - a
    t = np.clip((ap * ab).sum(axis=1) / L2, 0, 1)
    d = ap - t[:, None] * ab
    return np.hypot(d[:, 0], d[:, 1])


def _polygons(shapes) -> tuple[list, list]:
    """The polygons and values of ``rasterio.features.shapes``' GeoJSON-like output, built in one call.

    As ``shapely.geometry.shape`` builds each (first ring the shell, the
    others holes), without a Python loop over vertices or polygons.
    """
    rings, of, ids = [], [], []
    for geom, value in shapes:
        rings.extend(geom["coordinates"])
        of.extend([len(ids)] * len(geom["coordinates"]))
        ids.append(int(value))
    if not ids:
        return [], []
    n = np.fromiter((len(r) for r in rings), dtype=np.int64, count=len(rings))
    xy = np.array(list(chain.from_iterable(rings)), dtype=np.float64).reshape(-1, 2)
    return list(shapely.polygons(shapely.linearrings(xy, indices=np.repeat(np.arange(len(rings)), n)), indices=of)), ids


def _nearest(xy: np.ndarray, lab: np.ndarray, C: np.ndarray, k: int) -> np.ndarray:
    """Indices (M, k) of the ``k`` points ``xy`` nearest each cell centre ``C``, nearest first.

    The labels ``lab[idx]`` are those of ``cKDTree(xy).query(C, k)``, cell
    for cell: the compiled bucket search
    (:func:`rooftrace.roof.face_kernels.nearest_points`, several times
    faster on a raster's million cells) leaves to the k-d tree the cells
    where a tie could order points of different labels otherwise.
    """
    if not len(C) or not len(xy):
        return np.zeros((len(C), k), dtype=np.int64)
    # buckets about as wide as the (k + 1)-th neighbour's distance: most cells find theirs in 3 x 3 buckets
    extent = np.ptp(xy, axis=0)
    density = len(xy) / max(float(extent[0] * extent[1]), 1e-6)
    bucket = max(float(np.sqrt((k + 1) / (np.pi * density))), 1e-3 * max(float(extent.max()), 1e-3))
    idx, unsure = nearest_points(np.ascontiguousarray(xy[:, 0]), np.ascontiguousarray(xy[:, 1]), lab,
                                 np.ascontiguousarray(C[:, 0]), np.ascontiguousarray(C[:, 1]), k, bucket)
    if unsure.any():
        idx[unsure] = cKDTree(xy).query(C[unsure], k=k)[1].reshape(-1, k)
    return idx


def _absorb_slivers(polys: list, ids: list, min_area: float, kept: np.ndarray | None = None):
    """Merge faces smaller than ``min_area`` into the neighbour sharing most boundary, but those ``kept`` (bool per face)."""
    geoms = np.array(polys, dtype=object)
    ids = list(ids)
    if len(geoms) < 2:
        return list(geoms), ids
    # areas, boxes and boundaries are kept per face and renewed only for the merged one (a roof has hundreds of
    # faces and as many merges); the list order is the index order of the faces still alive
    alive = np.ones(len(geoms), dtype=bool)
    areas = shapely.area(geoms)
    box = shapely.bounds(geoms)
    edges = shapely.boundary(geoms)
    spared = np.zeros(len(geoms), dtype=bool) if kept is None else np.asarray(kept, dtype=bool)
    while alive.sum() >= 2:
        small = np.flatnonzero(alive & (areas < min_area) & ~spared)
        if not len(small):
            break
        i = int(small[np.argmin(areas[small])])
        # only faces whose boxes touch this one's can share boundary with it
        near = np.flatnonzero(alive & (box[:, 0] <= box[i, 2]) & (box[:, 2] >= box[i, 0]) & (box[:, 1] <= box[i, 3])
                              & (box[:, 3] >= box[i, 1]))
        near = near[near != i]
        if not len(near) or (shared := shapely.length(shapely.intersection(edges[i], edges[near]))).max() <= 0:
            # Isolated island: keep it (it is still part of the tiling).
            if areas[i] < 1e-9:
                alive[i] = False
                continue
            break
        j = int(near[np.argmax(shared)])
        merged = shapely.union(geoms[j], geoms[i])
        if merged.geom_type != "Polygon":
            merged = merged.buffer(0)
        geoms[j], areas[j], box[j], edges[j] = merged, merged.area, merged.bounds, merged.boundary
        alive[i] = False
    return list(geoms[alive]), [pid for pid, on in zip(ids, alive) if on]


def _under_fitting_face(faces: np.ndarray, pids: np.ndarray, xy: np.ndarray, own_z: np.ndarray,
                        planes: np.ndarray, max_dz: float) -> tuple[np.ndarray, np.ndarray]:
    """Per point (plan ``xy``, own plane height ``own_z``): the plane of a face over it (``-1`` none), and
    whether some face over it has its plane within ``max_dz`` (m) of its own there (a point on a shared
    edge is under both faces)."""
    cover = np.full(len(xy), -1, dtype=np.int64)
    fits = np.zeros(len(xy), dtype=bool)
    if not len(faces) or not len(xy):
        return cover, fits
    at, f = points_in_faces(faces, xy)
    cover[at] = pids[f]
    fits[at[np.abs(plane_height(planes[pids[f]], xy[at]) - own_z[at]) <= max_dz]] = True
    return cover, fits


def points_in_faces(polys: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (point, polygon) of the points ``xy`` in (or on) each polygon, as an STR tree's query gives them.

    Polygon by polygon on the points in its box (:func:`points_in_boxes`),
    without a point geometry per point: a roof has tens of thousands of
    points and a few dozen faces.  All pairs in one call, each polygon
    prepared (as :func:`shapely.intersects_xy` prepares a single one).
    """
    polys = np.asarray(polys, dtype=object)
    ptr, inbox = points_in_boxes(xy[:, 0], xy[:, 1], np.argsort(xy[:, 0], kind="stable"), shapely.bounds(polys))
    of = np.repeat(np.arange(len(polys)), np.diff(ptr))
    if not len(inbox):
        return inbox, of
    shapely.prepare(polys)
    hit = shapely.intersects_xy(polys[of], xy[inbox, 0], xy[inbox, 1])
    return inbox[hit], of[hit]


def _off_their_faces(faces: np.ndarray, pids: np.ndarray, xy: np.ndarray, lab: np.ndarray, own_z: np.ndarray,
                     planes: np.ndarray, radius: float, max_dz: float, under_eave=None):
    """The labelled points under another level, each with the nearest face of its own plane within ``radius``.

    Returns the points (indices into ``xy``), that face, its point nearest
    the point, and whether a face over each point fits it (all points).  A
    point whose covering plane meets its own at that nearest face point (within
    ``max_dz``: a ridge, hip or valley, where the line rule of
    :func:`partition_outline` decides and the plane error, not the face,
    puts a few points across) is left out, and so is one ``under_eave``
    (a function of the points and the planes over them: True where the
    point lies under that plane's eave).
    """
    cover, fits = _under_fitting_face(faces, pids, xy, own_z, planes, max_dz)
    off = np.flatnonzero((cover >= 0) & ~fits)
    if under_eave is not None and len(off):
        off = off[~under_eave(off, cover[off])]
    none = np.zeros(0, dtype=np.int64)
    if not len(off):
        return none, none, np.zeros((0, 2)), fits
    at, f = shapely.STRtree(faces).query(shapely.points(xy[off]), predicate="dwithin", distance=radius)
    mine = pids[f] == lab[off[at]]
    at, f = at[mine], f[mine]
    if not len(at):
        return none, none, np.zeros((0, 2)), fits
    d = shapely.distance(faces[f], shapely.points(xy[off[at]]))
    order = np.lexsort((f, d, at))
    first = np.r_[True, at[order][1:] != at[order][:-1]]
    pt, target = off[at[order][first]], f[order][first]
    near = shapely.get_coordinates(shapely.shortest_line(faces[target], shapely.points(xy[pt])))[::2]
    step = np.abs(plane_height(planes[lab[pt]], near) - plane_height(planes[cover[pt]], near)) > max_dz
    return pt[step], target[step], near[step], fits


def _faces_and_labelled(polys, plane_ids, xyz, labels):
    """As arrays: the points, their labels, the faces, their planes, and the indices of the labelled points."""
    xyz = np.asarray(xyz, dtype=np.float64)
    labels = np.asarray(labels)
    faces = np.asarray(list(polys), dtype=object)
    return xyz, labels, faces, np.asarray(list(plane_ids), dtype=np.int64), np.flatnonzero(labels >= 0)


def points_off_their_faces(polys, plane_ids, xyz: np.ndarray, labels: np.ndarray, planes: np.ndarray, *,
                           radius: float, max_dz: float = 0.1, hidden_within: float = 0.0, step_height: float = 0.5,
                           overhanging: np.ndarray | None = None) -> np.ndarray:
    """The labelled points under a face of another level while a face of their own plane is near.

    The faces' promise at height steps: a labelled point lies under a face
    of its own plane, or of a plane within ``max_dz`` of it at the point,
    unless no face of its own plane lies within ``radius`` in plan (a stray
    point its plane holds by its equation only, metres from its own points),
    no face covers it (outside the outline), or the plane over it meets its
    own plane (within ``max_dz``) where its own nearest face is nearest it:
    across a ridge, hip or valley, where the faces follow the planes'
    intersection line and a few points lie beyond it by the planes' error;
    with ``hidden_within``, nor a point under the eave of the plane over it
    (:func:`hidden_under`: a point of that plane within ``hidden_within``
    stands ``step_height`` higher; ``overhanging`` as in :func:`claim_points`).

    Parameters
    ----------
    polys : sequence of shapely Polygon
        Faces tiling the outline (Z ignored).
    plane_ids : sequence of int
        Plane of each face.
    xyz : ndarray of shape (N, 3)
    labels : ndarray of shape (N,), int
        Plane per point, ``-1`` on none.
    planes : ndarray of shape (K, 4)
    radius : float
        Plan distance (m) within which a face of the point's own plane makes it count.
    max_dz : float
        Height difference (m) between the planes at the point that still counts as its own.

    Returns
    -------
    ndarray of shape (N,), bool
        The points that break the promise.

    Examples
    --------
    >>> import shapely
    >>> planes = np.array([[0.0, 0.0, 1.0, -8.0], [0.0, 0.0, 1.0, -5.0]])  # upper level 8 m, lower 5 m
    >>> faces = [shapely.box(0, 0, 4, 4), shapely.box(4, 0, 8, 4)]
    >>> xyz = np.array([[3.9, 2.0, 8.0], [4.2, 2.0, 8.0], [6.0, 2.0, 8.0], [6.0, 2.0, 5.0]])
    >>> points_off_their_faces(faces, [0, 1], xyz, np.array([0, 0, 0, 1]), planes, radius=0.5).tolist()
    [False, True, False, False]
    """
    xyz, labels, faces, pids, sel = _faces_and_labelled(polys, plane_ids, xyz, labels)
    out = np.zeros(len(xyz), dtype=bool)
    if not len(sel) or not len(faces):
        return out
    xy, lab = xyz[sel, :2], labels[sel]
    under_eave = _eave_rule(xyz[sel], lab, planes, hidden_within, step_height, overhanging)
    pt = _off_their_faces(faces, pids, xy, lab, plane_height(planes[lab], xy), planes, radius, max_dz, under_eave)[0]
    out[sel[pt]] = True
    return out


#: steepest plane (degrees) whose points hide a lower roof's points under its eave (:func:`hidden_under`):
#: a plane fitted to a wall has none
EAVES_SLOPE = 60.0


def eaves(planes: np.ndarray) -> np.ndarray:
    """Per plane: whether it is flat enough (at most :data:`EAVES_SLOPE`) to reach over a lower roof."""
    planes = np.asarray(planes, dtype=np.float64).reshape(-1, 4)
    return np.abs(planes[:, 2]) >= np.cos(np.radians(EAVES_SLOPE)) * np.linalg.norm(planes[:, :3], axis=1)


def hidden_under(xyz: np.ndarray, labels: np.ndarray, at: np.ndarray, plane: np.ndarray, within: float,
                 rise: float, tree: cKDTree | None = None) -> np.ndarray:
    """Whether each point ``at`` has a point of ``plane`` (one per point) within ``within`` (m, plan) more than ``rise`` (m) higher.

    Such a point (a lower roof's return under the upper level's eave, a
    second return through its gutter) lies under that level's roof in plan:
    no 2.5D roof can put it under its own plane there, and it says nothing
    about where the step between the two is.  ``tree``: a k-d tree of
    ``xyz[:, :2]``, when the caller has one.
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    at = np.asarray(at, dtype=np.int64)
    out = np.zeros(len(at), dtype=bool)
    if not len(at) or within <= 0:
        return out
    tree = cKDTree(xyz[:, :2]) if tree is None else tree
    near = tree.query_ball_point(xyz[at, :2], within, return_sorted=False)
    n = np.fromiter((len(x) for x in near), dtype=np.int64, count=len(near))
    if not n.sum():
        return out
    who = np.repeat(np.arange(len(at)), n)
    by = np.fromiter((j for x in near for j in x), dtype=np.int64, count=int(n.sum()))
    higher = (labels[by] == np.broadcast_to(plane, len(at))[who]) & (xyz[by, 2] - xyz[at[who], 2] > rise)
    out[who[higher]] = True
    return out


def points_on_their_faces(polys, plane_ids, xyz: np.ndarray, labels: np.ndarray, planes: np.ndarray, *,
                          max_dz: float = 0.1, margin: float = 0.0) -> np.ndarray:
    """The labelled points under a face of their own plane, or of one within ``max_dz`` (m) of it at the point,
    at least ``margin`` (m, plan) inside that face.

    What the models must keep (:func:`rooftrace.model.measure.points_off_their_roof`):
    a solid rounds its plan vertices to a lattice, so a point closer to its
    face's edge than the lattice's half diagonal may change sides.

    Examples
    --------
    >>> import shapely
    >>> planes = np.array([[0.0, 0.0, 1.0, -8.0], [0.0, 0.0, 1.0, -5.0]])
    >>> faces = [shapely.box(0, 0, 4, 4), shapely.box(4, 0, 8, 4)]
    >>> xyz = np.array([[3.0, 2.0, 8.0], [3.995, 2.0, 8.0], [4.2, 2.0, 8.0], [6.0, 2.0, 5.0]])
    >>> points_on_their_faces(faces, [0, 1], xyz, np.array([0, 0, 0, 1]), planes, margin=0.01).tolist()
    [True, False, False, True]
    """
    xyz, labels, faces, pids, sel = _faces_and_labelled(polys, plane_ids, xyz, labels)
    out = np.zeros(len(xyz), dtype=bool)
    if not len(sel) or not len(faces):
        return out
    xy, lab = xyz[sel, :2], labels[sel]
    own_z = plane_height(planes[lab], xy)
    at, f = points_in_faces(faces, xy)
    fit = np.abs(plane_height(planes[pids[f]], xy[at]) - own_z[at]) <= max_dz
    if margin > 0:
        fit &= shapely.distance(shapely.boundary(faces[f]), shapely.points(xy[at])) >= margin
    out[sel[at[fit]]] = True
    return out


def _eave_rule(xyz: np.ndarray, lab: np.ndarray, planes: np.ndarray, within: float, rise: float,
               overhanging: np.ndarray | None):
    """``under_eave(points, planes)`` of :func:`_off_their_faces` for labelled points ``xyz`` (None when off)."""
    if within <= 0:
        return None
    hides = eaves(planes) if overhanging is None else eaves(planes) & np.asarray(overhanging, dtype=bool)
    tree = cKDTree(xyz[:, :2])

    def under_eave(at: np.ndarray, plane: np.ndarray) -> np.ndarray:
        return hides[plane] & hidden_under(xyz, lab, at, plane, within, rise, tree)

    return under_eave


def _grouped(polys: np.ndarray, group: np.ndarray, n: int) -> np.ndarray:
    """A MultiPolygon per group ``0 .. n - 1`` of the (disjoint) polygons, None for a group without any."""
    out = np.full(n, None, dtype=object)
    if len(polys):
        present, inv = np.unique(group, return_inverse=True)
        order = np.argsort(inv, kind="stable")
        out[present] = shapely.multipolygons(polys[order], indices=inv[order])
    return out


def _claimed(polys: list, ids: list, outline, P: np.ndarray, lab: np.ndarray, planes: np.ndarray, *,
             radius: float, max_dz: float, width: float, hidden_within: float = 0.0,
             step_height: float = 0.5, overhanging: np.ndarray | None = None) -> tuple[list, list, bool]:
    """The faces with each labelled point under another level handed to its own plane's nearest face.

    A point under a face whose plane is more than ``max_dz`` (m) off its
    own (the edge row of a roof level given to the neighbouring level's
    face by a raster cell, or by a sliver merged away), with a face of its
    own plane within ``radius`` (m), is joined to that face by a wedge: the
    convex hull of the point (with a margin of ``width / 4`` beyond it and
    to either side) and the part of the face within ``width`` (m) of the
    face's point nearest it, cut by the outline.  The wedge is taken from
    the faces it covers, unless it would put a labelled point of theirs
    under a plane more than ``max_dz`` off its own (another level's point
    between the two: that point stays where it is; one with a point of the
    claiming plane within ``hidden_within`` more than ``step_height``
    higher, under its eave, is not protected), it meets a wedge of
    another face (the first in point order stands), or it would cut a face
    in two or open a hole in one.  Wedges of one face are joined.  If the
    faces would stop tiling the outline they are returned unchanged.  The
    flag says whether a wedge was dropped (a narrower one may pass).
    """
    faces = np.asarray(polys, dtype=object)
    pids = np.asarray(ids, dtype=np.int64)
    if len(faces) < 2 or not len(P):
        return polys, ids, False
    xy = P[:, :2]
    own_z = plane_height(planes[lab], xy)
    under_eave = _eave_rule(P, lab, planes, hidden_within, step_height, overhanging)
    # (a point under another level's eave is still claimed back where no point of that level is in the way)
    pt, target, near, fits = _off_their_faces(faces, pids, xy, lab, own_z, planes, radius, max_dz)
    if not len(pt):
        return polys, ids, False
    reach = shapely.intersection(faces[target], shapely.box(*(near - width).T, *(near + width).T))
    # the point with a margin of width / 4 beyond it and to either side, away from the face: a point near the
    # wedge's edge would fall across it when the model rounds its vertices
    u = xy[pt] - near
    u /= np.maximum(np.hypot(u[:, 0], u[:, 1]), 1e-12)[:, None]
    t = np.column_stack([-u[:, 1], u[:, 0]])
    margin = np.concatenate([xy[pt] + (u + t) * width / 4, xy[pt] + (u - t) * width / 4])
    rc, ri = shapely.get_coordinates(reach, return_index=True)
    corners, of = np.concatenate([rc, margin]), np.concatenate([ri, np.arange(len(pt)), np.arange(len(pt))])
    order = np.argsort(of, kind="stable")
    hull = shapely.convex_hull(shapely.multipoints(corners[order], indices=of[order]))
    shapely.prepare(outline)
    wedge = hull.copy()
    out = ~shapely.contains_properly(outline, hull)
    wedge[out] = shapely.intersection(hull[out], outline)
    # a wedge must not put another level's point under its face: a point that fits where it is and would not
    # fit under the target's plane
    q, wi = points_in_faces(wedge, xy)
    harm = fits[q] & (np.abs(plane_height(planes[pids[target[wi]]], xy[q]) - own_z[q]) > max_dz)
    if under_eave is not None and harm.any():
        # a point under the claiming level's eave: no 2.5D roof puts it under its own plane there
        harm[harm] = ~under_eave(q[harm], pids[target[wi[harm]]])
    ok = np.ones(len(wedge), dtype=bool)
    ok[wi[harm]] = False
    ok &= shapely.get_type_id(wedge) == 3
    # wedges of different faces that meet: the first one (in point order) stands
    wi, wj = shapely.STRtree(wedge).query(wedge, predicate="intersects")
    for i, j in zip(wi, wj):
        if i < j and ok[i] and ok[j] and target[i] != target[j]:
            ok[j] = False
    retry = not ok.all()
    if not ok.any():
        return polys, ids, retry
    # a wedge that would cut a face in two or open a hole in one (faces meeting at a point, which the solids and
    # the part split refuse) is dropped, and the others applied again
    for _ in range(4):
        # the claim in pieces, each the wedges of one face (wedges of different faces are apart)
        pieces = np.asarray(shapely.get_parts(shapely.union_all(wedge[ok])), dtype=object)
        pi, wj = shapely.STRtree(wedge[ok]).query(pieces, predicate="intersects")
        owner = np.full(len(pieces), -1, dtype=np.int64)
        owner[pi] = target[ok][wj]
        # only the faces the pieces touch change (each less the pieces on it, plus its own); they must tile what
        # they tiled
        pj, fi = shapely.STRtree(faces).query(pieces, predicate="intersects")
        changed, at = np.unique(np.concatenate([fi, owner]), return_inverse=True)
        at_cut, at_own = at[:len(fi)], at[len(fi):]
        cut = _grouped(pieces[pj], at_cut, len(changed))
        g = np.where(shapely.is_missing(cut), faces[changed], shapely.difference(faces[changed], cut))
        own = _grouped(pieces, at_own, len(changed))
        g = np.where(shapely.is_missing(own), g, shapely.union(g, own))
        # judged on the centimetre grid: a neck narrower than that closes when the model rounds its vertices
        coarse = shapely.set_precision(g, 0.01)
        split = ((shapely.get_num_geometries(g) != 1) | (shapely.get_num_geometries(coarse) != 1)
                 | (shapely.get_num_interior_rings(g) > shapely.get_num_interior_rings(faces[changed]))
                 | (shapely.get_num_interior_rings(coarse) > shapely.get_num_interior_rings(faces[changed])))
        if not split.any():
            break
        ok[shapely.STRtree(wedge).query(faces[np.asarray(changed)[split]], predicate="intersects")[1]] = False
        retry = True
        if not ok.any():
            return polys, ids, retry
    else:
        return polys, ids, retry
    new_faces = [[q for q in shapely.get_parts(x) if q.geom_type == "Polygon" and q.area > 0] for x in g]
    new_ids = [[int(pids[i])] * len(parts) for i, parts in zip(changed, new_faces)]
    flat = np.asarray([q for parts in new_faces for q in parts], dtype=object)
    area = _area_sum(faces[changed])
    # (the new faces are apart by construction: the areas tell a gap)
    if not len(flat) or not shapely.is_valid(flat).all() or abs(_area_sum(flat) - area) > 1e-6 * max(area, 1.0):
        log.debug("points handed to their faces undone (would break the tiling)")
        return polys, ids, False
    out_faces, out_ids = [], []
    at = {i: k for k, i in enumerate(changed)}
    for i, (g, pid) in enumerate(zip(faces, pids)):
        if i in at:
            out_faces.extend(new_faces[at[i]])
            out_ids.extend(new_ids[at[i]])
        else:
            out_faces.append(g)
            out_ids.append(int(pid))
    return out_faces, out_ids, retry


def _interior_rings(g: np.ndarray) -> np.ndarray:
    """Per geometry (a polygon, a multipolygon or a collection): its holes."""
    parts, of = shapely.get_parts(g, return_index=True)
    return np.bincount(of, weights=shapely.get_num_interior_rings(parts), minlength=len(g)).astype(np.int64)


def _one_wedge(face, near: np.ndarray, at: np.ndarray, width: float, outline):
    """The claim's wedge: the convex hull of the point ``at`` (with a margin of ``width / 4`` beyond it and to
    either side) and the part of ``face`` within ``width`` of its point ``near``, cut by the outline."""
    reach = shapely.intersection(face, shapely.box(*(near - width), *(near + width)))
    u = at - near
    u = u / max(float(np.hypot(u[0], u[1])), 1e-12)
    t = np.array([-u[1], u[0]])
    margin = np.array([at + (u + t) * width / 4, at + (u - t) * width / 4])
    hull = shapely.convex_hull(shapely.multipoints(np.concatenate([shapely.get_coordinates(reach), margin])))
    return hull if shapely.contains_properly(outline, hull) else shapely.intersection(hull, outline)


def _claimed_singly(polys: list, ids: list, outline, P: np.ndarray, lab: np.ndarray, planes: np.ndarray, *,
                    radius: float, max_dz: float, width: float, hidden_within: float = 0.0,
                    step_height: float = 0.5, overhanging: np.ndarray | None = None) -> tuple[list, list]:
    """The points :func:`_claimed` left under another level, claimed one at a time.

    :func:`_claimed` applies all wedges at once and, when the faces a
    wedge changes would be cut in two or get a hole, drops every wedge on
    those faces; two wedges of different faces that meet drop one.  Here
    each point still off its faces gets its wedge (``width``, then
    ``width / 4``) against the faces as the earlier wedges left them, kept
    under the same rules (no point that fits where it is is put under a
    plane more than ``max_dz`` off its own unless it lies under the
    claiming level's eave; every changed face stays one polygon with no new
    hole, also on the centimetre grid; the faces tile what they tiled).
    """
    faces = np.asarray(polys, dtype=object)
    pids = np.asarray(ids, dtype=np.int64)
    if len(faces) < 2 or not len(P):
        return polys, ids
    xy = P[:, :2]
    own_z = plane_height(planes[lab], xy)
    under_eave = _eave_rule(P, lab, planes, hidden_within, step_height, overhanging)
    pt, target, near, _ = _off_their_faces(faces, pids, xy, lab, own_z, planes, radius, max_dz, under_eave)
    if not len(pt):
        return polys, ids
    tree = cKDTree(xy)
    box = shapely.bounds(faces)

    def faces_over(b) -> np.ndarray:
        return np.flatnonzero((box[:, 0] <= b[2]) & (box[:, 2] >= b[0]) & (box[:, 1] <= b[3]) & (box[:, 3] >= b[1]))

    def points_in(g) -> np.ndarray:
        b = shapely.bounds(g)
        near = np.asarray(tree.query_ball_point(((b[0] + b[2]) / 2, (b[1] + b[3]) / 2),
                                                np.hypot(b[2] - b[0], b[3] - b[1]) / 2 + 1e-9), dtype=np.int64)
        return near[shapely.intersects_xy(g, xy[near, 0], xy[near, 1])] if len(near) else near

    def harms(g, hit: np.ndarray, tgt: int) -> bool:
        # a point in g that fits the face it is under now and would not fit the target's plane, not under its eave
        q = points_in(g)
        q = q[np.abs(plane_height(planes[pids[tgt]], xy[q]) - own_z[q]) > max_dz]
        if not len(q):
            return False
        qa, qf = points_in_faces(faces[hit], xy[q])
        fits = np.zeros(len(q), dtype=bool)
        fits[qa[np.abs(plane_height(planes[pids[hit[qf]]], xy[q[qa]]) - own_z[q[qa]]) <= max_dz]] = True
        if fits.any() and under_eave is not None:
            fits[fits] = ~under_eave(q[fits], np.full(int(fits.sum()), pids[tgt]))
        return bool(fits.any())

    changed_any = False
    for i, tgt, nr in zip(pt, target, near):
        over = faces_over((*xy[i], *xy[i]))
        cover = over[shapely.intersects_xy(faces[over], *xy[i])]
        if (np.abs(plane_height(planes[pids[cover]], xy[i]) - own_z[i]) <= max_dz).any():
            continue  # an earlier wedge took it
        # (a GEOS error on one wedge, as on odd slivers, leaves the faces as they were: they change only at the end)
        try:
            for w in (width, width / 4):
                wedge = _one_wedge(faces[tgt], nr, xy[i], w, outline)
                if shapely.get_type_id(wedge) != 3:
                    continue
                hit = faces_over(shapely.bounds(wedge))
                hit = hit[(hit != tgt) & shapely.intersects(faces[hit], wedge)]
                if not len(hit):
                    break
                if harms(wedge, hit, tgt):
                    continue
                rest = shapely.difference(faces[hit], wedge)
                cut = shapely.get_num_geometries(rest) > 1
                if cut.any():
                    # a face the wedge cuts in two: its pieces other than the largest go with the wedge when small (a
                    # corner's sliver face, the tip of a face beyond the point), under the same rules
                    pieces = [sorted(shapely.get_parts(r), key=shapely.area) for r in rest[cut]]
                    bits = [p for ps in pieces for p in ps[:-1]]
                    if _area_sum(bits) > 16 * width * width or harms(shapely.union_all(bits), hit, tgt):
                        continue
                    wedge = shapely.union_all([wedge, *bits])
                    rest[cut] = [ps[-1] for ps in pieces]
                old = faces[np.r_[hit, tgt]]
                new = np.concatenate([rest, [shapely.union(faces[tgt], wedge)]])
                # (the overlay's output is valid: the areas tell a gap or an overlap)
                if ((shapely.get_type_id(new) != 3).any() or shapely.is_empty(new).any()
                        or (shapely.get_num_interior_rings(new) > shapely.get_num_interior_rings(old)).any()
                        or abs(_area_sum(new) - _area_sum(old)) > 1e-6 * max(_area_sum(old), 1.0)):
                    continue
                # judged on the centimetre grid too (a neck narrower than that closes when the model rounds its
                # vertices), in a window on that grid around the wedge: a neck the wedge makes lies within a
                # centimetre of it, and rounding a whole face of hundreds of vertices costs more than the rest
                b = shapely.bounds(wedge)
                win = shapely.box(*np.floor((b[:2] - 0.02) / 0.01) * 0.01, *np.ceil((b[2:] + 0.02) / 0.01) * 0.01)
                local = shapely.intersection(new, win)
                coarse = shapely.set_precision(local, 0.01)
                if ((shapely.get_num_geometries(coarse) > shapely.get_num_geometries(local)).any()
                        or (shapely.is_empty(coarse) & ~shapely.is_empty(local)).any()
                        or (_interior_rings(coarse) > _interior_rings(local)).any()):
                    continue
                faces[hit], faces[tgt] = new[:-1], new[-1]
                box[hit], box[tgt] = shapely.bounds(new[:-1]), shapely.bounds(new[-1])
                changed_any = True
                break
        except shapely.errors.GEOSException:
            continue
    if not changed_any:
        return polys, ids
    return list(faces), list(ids)


def claim_points(polys: list, plane_ids: list, outline, xyz: np.ndarray, labels: np.ndarray, planes: np.ndarray, *,
                 radius: float, width: float, max_dz: float = 0.1, hidden_within: float = 0.0,
                 step_height: float = 0.5, overhanging: np.ndarray | None = None,
                 one_by_one: bool = True) -> tuple[list, list]:
    """Faces that hold every labelled point of a level near its own face: the step boundaries mended.

    At a height step the raster, its simplification and the sliver merging
    can leave the edge row of a roof level under the neighbouring level's
    face, metres off its own plane.  Each labelled point under a face whose
    plane is more than ``max_dz`` off its own there, with a face of its own
    plane within ``radius`` in plan, is joined to the nearest such face by a
    wedge (the convex hull of the point with a margin of ``width / 4``
    beyond it and to either side, and the part of the face within ``width``
    of the face's point nearest it), taken from the faces it covers; after
    a wedge is dropped, again with wedges a quarter as wide; the points
    still left, one wedge at a time against the faces the others left (a
    piece of another face the wedge cuts off going with it when small).

    What it guarantees, on any data: no labelled point that lay under a face
    of its own plane (or one within ``max_dz``) is moved from it, the faces
    still tile the outline, and afterwards every labelled point with a face
    of its own plane within ``radius`` lies under a face of its own plane or
    of one within ``max_dz`` of it at the point
    (:func:`points_off_their_faces` finds none; it leaves ridges, hips and
    valleys, where the two planes meet, to the line rule), unless

    - both wedges would cover a labelled point of another level (the two
      levels' points interleave there: that point keeps its face) that
      is not hidden from above (no point of the claiming plane within
      ``hidden_within`` in plan stands ``step_height`` higher: a lower
      level's return under the upper level's eave may go under the upper
      face, as no 2.5D roof can put it under its own there),
    - both would cut a face in two with more than ``16 width²`` beside its
      largest piece, or open a hole in one, or leave the claiming face in
      two pieces, also once rounded to a centimetre (faces meeting at a
      point, which the solids and the building parts refuse), each wedge
      judged against the faces the earlier claims left (another point's
      wedge is no obstacle); a point under the eave of the level over it
      (as above) is claimed only with all the others at once.

    Parameters
    ----------
    polys : list of shapely Polygon
        Faces tiling ``outline`` (2D).
    plane_ids : list of int
        Plane of each face.
    outline : shapely Polygon
        The outline the faces tile; wedges are cut by it.
    xyz : ndarray of shape (N, 3)
    labels : ndarray of shape (N,), int
        Plane per point, ``-1`` on none (those take no part).
    planes : ndarray of shape (K, 4)
    radius : float
        Farthest face of a point's own plane (m, plan) it is joined to: a
        point farther from all of them (a stray its plane holds by its
        equation only) stays where it is.
    width : float
        Half-width (m) of the part of the face a wedge starts from (the face
        partition's raster cell).
    max_dz : float
        Height difference (m) between two planes at a point under which either is its own.
    hidden_within, step_height : float
        Plan distance and height (m) of :func:`hidden_under`; ``hidden_within = 0`` protects every point.
    overhanging : ndarray of shape (K,), bool, optional
        The planes whose points may hide another level's (default: every
        plane flatter than :data:`EAVES_SLOPE`; a small plane fitted to a
        messy corner or a wall reaches over nothing).
    one_by_one : bool
        Claim the points all wedges at once left one wedge at a time (off:
        the guarantee's second exception reads "both meet the wedge of a
        point of another face, or both would cut a face in two").

    Returns
    -------
    polygons : list of shapely Polygon
    plane_ids : list of int
        As many faces as before, in the same order.

    Examples
    --------
    >>> import shapely
    >>> planes = np.array([[0.0, 0.0, 1.0, -8.0], [0.0, 0.0, 1.0, -5.0]])  # upper level 8 m, lower 5 m
    >>> outline = shapely.box(0, 0, 8, 4)
    >>> faces = [shapely.box(0, 0, 4, 4), shapely.box(4, 0, 8, 4)]
    >>> xyz = np.array([[3.9, 2.0, 8.0], [4.2, 2.0, 8.0], [6.0, 2.0, 5.0]])  # the second under the lower face
    >>> polys, ids = claim_points(faces, [0, 1], outline, xyz, np.array([0, 0, 1]), planes, radius=0.5, width=0.2)
    >>> points_off_their_faces(polys, ids, xyz, np.array([0, 0, 1]), planes, radius=0.5).any()
    np.False_
    >>> round(sum(p.area for p in polys), 9)
    32.0
    """
    labels = np.asarray(labels)
    sel = labels >= 0
    P, lab = np.asarray(xyz, dtype=np.float64)[sel], labels[sel]
    outline = shapely.force_2d(outline)
    # a second round with narrower wedges for the points whose first wedge would have covered another level's point
    for w in (width, width / 4):
        polys, plane_ids, dropped = _claimed(polys, plane_ids, outline, P, lab, planes, radius=radius, max_dz=max_dz,
                                             width=w, hidden_within=hidden_within, step_height=step_height,
                                             overhanging=overhanging)
        if not dropped:
            break
    else:
        if not one_by_one:
            return list(polys), list(plane_ids)
        # what the batch dropped for a neighbour's wedge or for the faces it shared with one, one at a time
        polys, plane_ids = _claimed_singly(polys, plane_ids, outline, P, lab, planes, radius=radius, max_dz=max_dz,
                                           width=width, hidden_within=hidden_within, step_height=step_height,
                                           overhanging=overhanging)
    return list(polys), list(plane_ids)


def _misplaced(regions: np.ndarray, ids: np.ndarray, xy: np.ndarray, own_z: np.ndarray, planes: np.ndarray,
               max_dz: float) -> int:
    """Labelled points (plan ``xy``, own plane height ``own_z``) in a region whose plane is more than ``max_dz`` off."""
    n = 0
    box = shapely.bounds(regions)
    for reg, pid, (x0, y0, x1, y1) in zip(regions, ids, box):
        if pid < 0:
            continue
        # only points whose own plane this region's is far from can be misplaced in it: test just those
        cand = np.flatnonzero((xy[:, 0] >= x0) & (xy[:, 0] <= x1) & (xy[:, 1] >= y0) & (xy[:, 1] <= y1))
        a, b, c, d = planes[pid]
        cand = cand[np.abs(-(a * xy[cand, 0] + b * xy[cand, 1] + d) / c - own_z[cand]) > max_dz]
        if len(cand):
            n += int(np.count_nonzero(shapely.contains_xy(reg, xy[cand, 0], xy[cand, 1])))
    return n


def _line_misplaces(ends: np.ndarray, a: int, b: int, convex: int, P: np.ndarray, lab: np.ndarray,
                    planes: np.ndarray, tolerance: float, max_dz: float, few: float = 0.05) -> bool:
    """Would the line rule (the lower plane across a convex line, the higher across a concave one) put
    more than ``few`` of the points of planes ``a``, ``b`` within ``tolerance`` (m) of the line
    ``ends`` under the other plane, more than ``max_dz`` (m) off their own?

    True where the two planes' intersection line is not where they meet: a
    step between two roof levels whose extended planes happen to cross near it
    (there about half the points are across; at a true ridge only the few
    the segmentation put on the wrong side, about 2 % on a sampled hip roof).
    """
    mine = np.flatnonzero((lab == a) | (lab == b))
    mine = mine[_segment_distance(P[mine, :2], np.broadcast_to(ends[0], (len(mine), 2)),
                                  np.broadcast_to(ends[1], (len(mine), 2))) <= tolerance]
    if not len(mine):
        return False
    za, zb = plane_height(planes[[a, b]], P[mine, :2]).T
    rule_a = za <= zb if convex > 0 else za >= zb  # where the rule gives plane a
    wrong = np.where(lab[mine] == a, ~rule_a, rule_a) & (np.abs(za - zb) > max_dz)
    return bool(wrong.sum() > max(3, few * len(mine)))


def _regularised(regions: list, ids: list, P: np.ndarray, lab: np.ndarray, planes: np.ndarray, *,
                 tolerance: float, floor: float, max_dz: float):
    """The regions simplified together at the largest tolerance (m) that misplaces no more labelled points.

    Tolerances ``tolerance, tolerance / 2, ...`` down to ``floor`` are
    tried; a misplaced point is one under a region whose plane is more than
    ``max_dz`` (m) off the point's own plane, counted against the raster
    regions themselves (whose own misplacements are the cell size's).  When
    none passes, the regions are simplified at ``floor``: below a cell that
    only straightens the raster's staircases, within the raster's own error.
    """
    geoms = np.array(regions, dtype=object)
    if tolerance <= 0 or not len(P):
        return geoms
    ids = np.asarray(ids, dtype=np.int64)
    own_z = plane_height(planes[lab], P[:, :2])
    base = _misplaced(geoms, ids, P[:, :2], own_z, planes, max_dz)
    t = tolerance
    while t > floor:
        simplified = shapely.coverage_simplify(geoms, t, simplify_boundary=False)
        if _misplaced(simplified, ids, P[:, :2], own_z, planes, max_dz) <= base:
            return simplified
        t /= 2
    return shapely.coverage_simplify(geoms, floor, simplify_boundary=False) if floor > 0 else geoms


def _boundary_arcs(regions: np.ndarray) -> np.ndarray:
    """The raster regions' boundaries as arcs: polylines between nodes (where three or more regions meet)."""
    net = shapely.line_merge(shapely.union_all(shapely.boundary(regions)))
    return np.asarray(shapely.get_parts(net), dtype=object)


def _arc_sides(V: np.ndarray, vptr: np.ndarray, grid: np.ndarray, x0: float, y1: float, cell: float) -> np.ndarray:
    """Labels (R, 2) left and right of each arc's first cell edge (``-2`` off the raster).

    The arcs run along cell edges, so the cells beside the middle of the
    first edge's first cell are the two regions the arc separates.
    """
    p0, p1 = V[vptr[:-1]], V[vptr[:-1] + 1]
    u = (p1 - p0) / np.hypot(*(p1 - p0).T)[:, None]
    mid = p0 + u * cell / 2
    normal = np.column_stack([-u[:, 1], u[:, 0]]) * cell / 2
    out = np.empty((len(p0), 2), dtype=np.int64)
    for side, at in enumerate((mid + normal, mid - normal)):
        col = np.floor((at[:, 0] - x0) / cell).astype(np.int64)
        row = np.floor((y1 - at[:, 1]) / cell).astype(np.int64)
        on = (col >= 0) & (col < grid.shape[1]) & (row >= 0) & (row < grid.shape[0])
        out[:, side] = -2
        out[on, side] = grid[row[on], col[on]]
    return out


def _meets_only_at_ends(arcs: np.ndarray) -> np.ndarray:
    """Per arc: False where it crosses itself or meets another arc anywhere but at ends of both.

    Two arcs between the same two nodes that simplify to the same chord
    overlap along their whole length: they count as meeting inside (the
    region between them would vanish from the polygonised faces).
    """
    noded = shapely.get_parts(shapely.node(shapely.multilinestrings(arcs)))
    # noding splits arcs that cross (more pieces) and dissolves arcs that overlap (less length): one of each
    # keeps the count, so both are compared
    if len(noded) == len(arcs) and np.isclose(shapely.length(noded).sum(), shapely.length(arcs).sum(),
                                              rtol=0, atol=1e-9 * len(arcs)):
        return np.ones(len(arcs), dtype=bool)  # noding changed nothing: no arc meets another inside
    ok = shapely.is_simple(arcs)
    # an arc that meets another anywhere but at ends of both is split there by the noding (or, overlapping it,
    # dissolved): only pairs with an arc that did not come through the noding whole and alone need the test
    whole = Counter(shapely.to_wkb(noded).tolist())
    mine = shapely.to_wkb(arcs).tolist()
    alone = Counter(mine)
    changed = np.array([whole[w] != 1 or alone[w] != 1 for w in mine], dtype=bool)
    i, j = shapely.STRtree(arcs).query(arcs, predicate="intersects")
    keep = (i < j) & (changed[i] | changed[j])
    i, j = i[keep], j[keep]
    ends = shapely.multipoints(np.stack([shapely.get_point(arcs, 0), shapely.get_point(arcs, -1)], axis=1))
    extra = shapely.difference(shapely.intersection(arcs[i], arcs[j]), shapely.intersection(ends[i], ends[j]))
    bad = ~shapely.is_empty(extra)
    ok[i[bad]] = False
    ok[j[bad]] = False
    return ok


def _face_labels(faces: np.ndarray, arcs: np.ndarray, sides: np.ndarray) -> np.ndarray:
    """The label of each polygonised face: the side of the arc its exterior's first edge runs along.

    Every face edge is an edge of one arc, in the arc's direction or
    against it; with the exterior turned counter-clockwise the face lies on
    its left.
    """
    V, at = shapely.get_coordinates(arcs, return_index=True)
    k = np.flatnonzero(np.r_[at[1:] == at[:-1], False])
    c, i = shapely.get_coordinates(shapely.get_exterior_ring(shapely.orient_polygons(faces)), return_index=True)
    start = np.r_[0, np.flatnonzero(i[1:] != i[:-1]) + 1]
    # vertices as integers (equal coordinates, equal number; + 0.0 makes -0.0 equal to 0.0 bytewise, as in a
    # comparison), then each directed edge as one integer: the arc edges along and against their arc, and the
    # faces' first edges
    ends = np.concatenate([V[k], V[k + 1], c[start], c[start + 1]]) + 0.0
    _, vid = np.unique(ends.view(np.dtype((np.void, 16))).ravel(), return_inverse=True)
    n, m = len(k), len(start)
    a, b, fa, fb = np.split(vid.ravel().astype(np.int64), [n, 2 * n, 2 * n + m])
    nv = np.int64(len(ends))
    key = np.concatenate([a * nv + b, b * nv + a])
    arc = np.concatenate([at[k], at[k]])
    side = np.repeat([0, 1], n)
    # an edge listed twice takes its last listing (along before against, arcs in order)
    order = np.argsort(key, kind="stable")
    last = np.r_[key[order][1:] != key[order][:-1], True]
    key, order = key[order][last], order[last]
    want = fa * nv + fb
    pos = np.minimum(np.searchsorted(key, want), len(key) - 1)
    out = np.full(len(faces), -3, dtype=np.int64)  # -3: no arc found
    hit = key[pos] == want if len(key) else np.zeros(m, dtype=bool)
    out[hit] = sides[arc[order[pos[hit]]], side[order[pos[hit]]]]
    return out


def attached_points(U: np.ndarray, P: np.ndarray, lab: np.ndarray, planes: np.ndarray, k: int,
              max_dz: float, rise: float) -> tuple[np.ndarray, np.ndarray]:
    """The points ``U`` on no plane that stand on one of their neighbours' planes, and that plane.

    A point on no plane (a parapet's or a coping's top, a gutter) stands on
    the roof under it: of the planes of its ``k`` nearest labelled points
    ``P`` (labels ``lab``), the one it stands least high above, at most
    ``rise`` (m) above and ``max_dz`` (m) under it.  At a height step the
    upper level's coping then pulls the face boundary out with it instead of
    lying over the lower level's face.  Points higher above all those planes
    (a chimney: a flat block's business) or under them all (a wall between
    two levels) are left out.
    """
    idx = cKDTree(P[:, :2]).query(U[:, :2], k=int(min(k, len(P))))[1].reshape(len(U), -1)
    cand = lab[idx]
    above = U[:, 2:3] - plane_height(planes[cand], U[:, None, :2])
    above[(above < -max_dz) | (above > rise)] = np.inf
    best = np.argmin(above, axis=1)
    ok = np.isfinite(above[np.arange(len(U)), best])
    return U[ok], cand[np.arange(len(U)), best][ok]


def _steps_refined(grid: np.ndarray, x0: float, y1: float, cell: float, xy: np.ndarray, lab: np.ndarray,
                   planes: np.ndarray, max_dz: float, plane_of) -> tuple[np.ndarray, float]:
    """The label raster at half the cell, the cells that misplace a labelled point labelled anew.

    At a height step the points of the two levels lie closer than the point
    spacing in plan, so a cell of half the spacing can hold points of both,
    and its centre's nearest point gives the other level's point to the
    wrong face.  Each cell holding a labelled point (plan ``xy``, plane
    ``lab``) whose plane is more than ``max_dz`` (m) off the cell's there is
    split in four, and each quarter takes the plane of its centre
    (``plane_of``, the rule of the coarse cells); every other quarter keeps
    its cell's plane, so the finer raster adds vertices only where a point
    asks for them.

    Returns
    -------
    grid : ndarray of shape (2 ny, 2 nx), int32
    cell : float
        The refined raster's cell (m), ``cell / 2``.
    """
    ny, nx = grid.shape
    col = np.floor((xy[:, 0] - x0) / cell).astype(np.int64)
    row = np.floor((y1 - xy[:, 1]) / cell).astype(np.int64)
    on = (col >= 0) & (col < nx) & (row >= 0) & (row < ny)
    row, col, pts, own = row[on], col[on], xy[on], lab[on]
    g = grid[row, col]
    mixed = (g >= 0) & (g != own)
    row, col, pts, own, g = row[mixed], col[mixed], pts[mixed], own[mixed], g[mixed]
    apart = np.abs(plane_height(planes[g], pts) - plane_height(planes[own], pts)) > max_dz
    fine = np.repeat(np.repeat(grid, 2, axis=0), 2, axis=1)
    cells = np.unique(row[apart] * nx + col[apart])
    if len(cells):
        r = (2 * (cells // nx))[:, None] + np.array([0, 0, 1, 1])
        c = (2 * (cells % nx))[:, None] + np.array([0, 1, 0, 1])
        r, c = r.ravel(), c.ravel()
        half = cell / 2
        fine[r, c] = plane_of(np.column_stack([x0 + (c + 0.5) * half, y1 - (r + 0.5) * half]))
    return fine, cell / 2


def _arcs_simplified(regions: list, ids: list, grid: np.ndarray, x0: float, y1: float, cell: float,
                     P: np.ndarray, lab: np.ndarray, planes: np.ndarray, *, tolerance: float, floor: float,
                     max_dz: float, plane_sigma: np.ndarray | None = None, few: int = 0):
    """Faces from the raster regions with each shared boundary simplified once, by its own rule.

    Each boundary between two planes' regions, from node to node, is
    simplified by :func:`rooftrace.roof.face_kernels.simplify_arcs`: where
    the two planes meet along it (their heights within the crease tolerance
    ``max(max_dz, 2 hypot(sigma_a, sigma_b))`` m at every vertex: a ridge or
    valley) a chord between nodes replaces it whatever the points (the
    faces' Z along it differs by no more than that tolerance, and
    :func:`snap_to_lines` then puts it on the intersection line); elsewhere
    (a height step, where a wall separates the planes) a chord replaces a
    stretch only if it lies within ``tolerance`` (m) and moves at most
    ``few`` labelled points from under their own plane's face (or one
    within ``max_dz``) to under a face more than ``max_dz`` (m) off it.
    Within ``floor`` (m) a chord always replaces it (the raster's
    staircase).  Boundaries with the outside (more than ``tolerance`` and a
    cell beyond the outline) are simplified at ``tolerance``.  The
    simplified arcs are polygonised (every boundary simplified once, so the
    faces share it vertex for vertex); an arc that would cross another
    keeps its raster vertices.

    Returns
    -------
    polygons : list of shapely Polygon
    plane_ids : list of int
    """
    regions = np.asarray(regions, dtype=object)
    ids = np.asarray(ids, dtype=np.int64)
    arcs = _boundary_arcs(regions)
    V, at = shapely.get_coordinates(arcs, return_index=True)
    vptr = np.r_[0, np.cumsum(np.bincount(at, minlength=len(arcs)))]
    sides = _arc_sides(V, vptr, grid, x0, y1, cell)
    inner = (sides >= 0).all(axis=1) & (sides[:, 0] != sides[:, 1])
    # a boundary with the outside lies more than `tolerance` + a cell beyond the outline, which cuts it off: a
    # chord within `tolerance` of it never reaches the outline, so it is simplified without points (fewer
    # vertices for the noding, the polygonising and the cut)
    outside = (sides == -1).any(axis=1) & (sides >= 0).any(axis=1)
    # crease vertices: the two planes of the arc within the crease tolerance there
    a, b = np.maximum(sides[at], 0).T
    if plane_sigma is None:
        tol = np.full(len(V), max_dz)
    else:
        tol = np.maximum(max_dz, 2 * np.hypot(plane_sigma[a], plane_sigma[b]))
    crease = (np.abs(plane_height(planes[a], V) - plane_height(planes[b], V)) <= tol) & inner[at]
    # the labelled points near each arc that can be moved, and what a move does to each
    # (the points in each inner arc's bounding box, by arc then point: an STR tree's pairs without a point
    # geometry per labelled point)
    boxes = shapely.bounds(arcs)
    boxes[~inner] = [np.inf, np.inf, -np.inf, -np.inf]  # empty: only inner arcs move points
    pptr, pi = points_in_boxes(P[:, 0], P[:, 1], np.argsort(P[:, 0], kind="stable"), boxes)
    ri = np.repeat(np.arange(len(arcs)), np.diff(pptr))
    xy = P[pi, :2]
    col = np.clip(np.floor((xy[:, 0] - x0) / cell).astype(np.int64), 0, grid.shape[1] - 1)
    row = np.clip(np.floor((y1 - xy[:, 1]) / cell).astype(np.int64), 0, grid.shape[0] - 1)
    g = grid[row, col]
    sa, sb = sides[ri, 0], sides[ri, 1]
    foreign = (g != sa) & (g != sb)
    za, zb = plane_height(planes[sa], xy), plane_height(planes[sb], xy)
    own = plane_height(planes[lab[pi]], xy)
    now, other = np.where(g == sa, za, zb), np.where(g == sa, zb, za)
    # a move counts against the chord only where it misplaces a point, not where it mends one (a swap of
    # misplaced points is no gain: the points lie where they lie)
    newly = ((np.abs(own - other) > max_dz) & (np.abs(own - now) <= max_dz)).astype(np.int64)
    keep = simplify_arcs(V, vptr, crease, xy, pptr, newly, foreign, inner | outside, floor, tolerance, few)
    raw = np.zeros(len(arcs), dtype=bool)
    for _ in range(8):
        kept = keep | raw[at]
        simplified = shapely.linestrings(V[kept], indices=at[kept])
        ok = _meets_only_at_ends(simplified)
        if ok.all():
            faces, cuts, _, _ = shapely.polygonize_full(simplified)
            faces = np.asarray(shapely.get_parts(faces), dtype=object)
            # one face per raster region; fewer faces means regions merged under one label, where an arc with
            # the same face on both sides (a cut edge) lost the region it bounded
            if len(faces) == len(regions) and shapely.is_empty(cuts):
                break
            lost = shapely.STRtree(simplified).query(shapely.get_parts(cuts), predicate="covers")[1]
            ok[lost if len(lost) else slice(None)] = False
        raw |= ~ok
    else:
        simplified = arcs
        faces = np.asarray(shapely.get_parts(shapely.polygonize(simplified)), dtype=object)
    if (len(faces) != len(regions)
            or abs(shapely.area(faces).sum() - shapely.area(regions).sum()) > 1e-6 * shapely.area(regions).sum()):
        log.debug("simplified face boundaries do not polygonise; raster faces kept")
        return list(regions), ids.tolist()
    label = _face_labels(faces, simplified, sides)
    if (lost := np.flatnonzero(label == -3)).size:
        # not expected (every face edge is an arc's), but a face without a label must not leave a hole
        fi, gi = shapely.STRtree(regions).query(faces[lost], predicate="intersects")
        share = shapely.area(shapely.intersection(faces[lost][fi], regions[gi]))
        for f in np.unique(fi):
            label[lost[f]] = ids[gi[fi == f][np.argmax(share[fi == f])]]
    return list(faces), label.tolist()


def partition_outline(
    outline,
    xyz: np.ndarray,
    labels: np.ndarray,
    planes: np.ndarray,
    lines=None,
    *,
    cell: float,
    line_tolerance: float,
    k: int = 8,
    min_area: float | None = None,
    simplify: float = 5.0,
    vote: bool = False,
    max_dz: float | None = 0.1,
    boundaries: str = "each",
    plane_sigma: np.ndarray | None = None,
    refine_steps: bool = True,
    rise: float | None = None,
    kept_planes: np.ndarray | None = None,
):
    """Split the outline among the planes.

    Parameters
    ----------
    outline : shapely Polygon
        Roof outline (Z ignored), possibly with holes.
    xyz : ndarray of shape (N, 3)
    labels : ndarray of shape (N,), int
        Plane per point, ``-1`` unassigned.
    planes : ndarray of shape (K, 4)
    lines : IntersectionLines, optional
        Ridge, hip and valley lines with their plane pairs and convexity.
    cell : float
        Raster cell (m).
    line_tolerance : float
        Cells within this plan distance (m) of a line follow its geometry.
    k : int
        Candidate planes from the k nearest labelled points.
    min_area : float, optional
        Faces smaller than this (m²) are merged into a neighbour; default ``4 cell²``.
    simplify : float
        Largest tolerance of the shared-boundary simplification, in cells.
    vote : bool
        A cell away from the lines takes the majority plane of its ``k``
        nearest points (ties to the nearest) rather than the nearest point's:
        smoother boundaries, but at a height step the majority moves the
        boundary off the points (see docs/design-notes.md, 3D models).
    max_dz : float or None
        Simplification may not put more labelled points under a face more
        than this (m) off their own plane than the raster does (see
        ``boundaries``), and a line whose rule puts more than 5 % of the
        points near it that far off is not used; None: every line, and
        simplify at ``simplify`` cells regardless.
    boundaries : {'each', 'held', 'free'}
        How the shared face boundaries are simplified.  ``'each'``: every
        boundary between two nodes by its own rule (a ridge or valley, where
        the planes meet, straight from node to node; a height step only as
        far as ``max_dz`` allows, at most ``simplify`` cells; see
        :func:`_arcs_simplified`).  ``'held'``: all of a roof's boundaries
        at one tolerance, halved from ``simplify`` cells until no more
        points are misplaced than by the raster, down to 0.75 cells (about
        four times the vertices of ``'free'`` on AHN3).  ``'free'``: at
        ``simplify`` cells (a boundary at a height step may move by that
        much; the line rule of ``max_dz`` still applies).
    plane_sigma : ndarray of shape (K,), optional
        Height residual (m) of each plane's points; with ``'each'`` the
        crease tolerance of two planes is ``max(max_dz, 2 hypot(sigma_a,
        sigma_b))``, without it ``max_dz``.
    refine_steps : bool
        With ``'each'``: the raster is halved, and each cell that puts a
        labelled point under a plane more than ``max_dz`` off its own (a
        cell holding points of both levels of a height step) is split in
        four and labelled anew (:func:`_steps_refined`); ``simplify`` and
        ``min_area`` stay in cells of ``cell``, the staircase floor (0.75
        cells) is the halved raster's.
    rise : float or None
        A point on no plane (``labels == -1``: a parapet's coping, a
        gutter, roof clutter) takes part in the partition, and in the
        simplification's point checks, as a point of the plane it stands
        on: of its ``k`` nearest labelled points' planes, the one it stands
        least high above, at most ``rise`` (m) above and ``max_dz`` under
        (:func:`attached_points`); one standing higher (a chimney, a flat block's
        business) or under them all (a wall) takes no part.  None: only
        labelled points take part.
    kept_planes : ndarray of shape (K,), bool, optional
        Planes whose face holding most of their points is kept whatever its
        area (the flat blocks of
        :func:`rooftrace.roof.superstructures.block_planes`: a chimney of
        one point); their other faces are merged as slivers when small.

    Returns
    -------
    polygons : list of shapely Polygon (2D)
    plane_ids : list of int
    """
    if boundaries not in ("each", "held", "free"):
        raise ValueError(f"boundaries must be 'each', 'held' or 'free', got {boundaries!r}")
    outline = shapely.force_2d(outline)
    sel = labels >= 0
    P, lab = np.asarray(xyz)[sel], np.asarray(labels)[sel]
    if len(P) == 0 or outline.is_empty:
        return [], []
    if rise is not None and max_dz is not None and (~sel).any():
        # the points on no plane take part as points of the plane they stand on
        extra, on = attached_points(np.asarray(xyz)[~sel], P, lab, planes, k, max_dz, rise)
        P, lab = np.vstack([P, extra]), np.concatenate([lab, on])
    minx, miny, maxx, maxy = outline.bounds
    area = (maxx - minx + 20 * cell) * (maxy - miny + 20 * cell)
    if area / cell**2 > MAX_CELLS:
        cell = float(np.sqrt(area / MAX_CELLS))
    pad = int(np.ceil(simplify)) + 3
    x0, y1 = minx - pad * cell, maxy + pad * cell
    nx = int(np.ceil((maxx - minx) / cell)) + 2 * pad
    ny = int(np.ceil((maxy - miny) / cell)) + 2 * pad
    cx = x0 + (np.arange(nx) + 0.5) * cell
    cy = y1 - (np.arange(ny) + 0.5) * cell
    gx, gy = np.meshgrid(cx, cy)
    C_all = np.column_stack([gx.ravel(), gy.ravel()])
    # Cells away from the outline are cut off anyway: label them -1.
    # (wider than the simplification tolerance, which can move region edges)
    inside = shapely.contains_xy(outline.buffer((simplify + 2) * cell), C_all[:, 0], C_all[:, 1])
    C = C_all[inside]
    # Where no line is near, the nearest point's plane (or with ``vote`` the
    # majority of the k nearest, a smoother boundary that drifts off the
    # points at a step).
    K = len(planes)
    segidx = np.full((K, K), -1, dtype=np.int64)
    seg, sign = np.zeros((0, 2, 2)), np.zeros(0, dtype=np.int64)
    if lines is not None and len(lines.lines):
        # One segment per plane pair, spanning all its pieces (a ridge cut
        # by a courtyard is collinear pieces).
        spans: dict = {}
        for g, pair, cv in zip(lines.lines, lines.pairs, lines.convex):
            spans.setdefault(tuple(pair), ([], cv))[0].extend(np.asarray(g.coords)[:, :2])
        seg, sign = [], []
        for (a, b), (pts, cv) in spans.items():
            pts = np.asarray(pts)
            d = pts - pts[0]
            t = d @ (d[np.argmax(np.hypot(d[:, 0], d[:, 1]))] if len(pts) > 1 else np.zeros(2))
            ends = pts[[np.argmin(t), np.argmax(t)]]
            if max_dz is not None and _line_misplaces(ends, a, b, cv, P, lab, planes, line_tolerance, max_dz):
                continue  # the planes do not meet here (a step): the points decide
            segidx[a, b] = segidx[b, a] = len(seg)
            seg.append(ends)
            sign.append(cv)
        seg, sign = np.asarray(seg, dtype=np.float64).reshape(-1, 2, 2), np.asarray(sign, dtype=np.int64)

    def plane_of(C: np.ndarray) -> np.ndarray:
        """The plane each cell centre ``C`` takes."""
        cand = lab[_nearest(P[:, :2], lab, C, int(min(k, len(P))))]
        choice = cand[:, 0].copy()
        # Only cells whose neighbours disagree need a decision.
        rows = np.flatnonzero((cand != cand[:, :1]).any(axis=1))
        if not len(rows):
            return choice
        cm, Cm = cand[rows], C[rows]
        # Only candidate pairs joined by a line matter, and only near the line:
        # each cell's distance to each such line, then fewest violations first,
        # then the vote (compiled, see rooftrace.roof.face_kernels).
        ptr, line = cell_lines(cm, segidx)
        at = np.repeat(np.arange(len(rows)), np.diff(ptr))
        near = _segment_distance(Cm[at], seg[line, 0], seg[line, 1]) <= line_tolerance
        z = plane_height(planes[cm], Cm[:, None, :]) if len(line) else np.zeros(cm.shape)
        choice[rows] = cm[np.arange(len(rows)), cell_choice(cm, segidx, ptr, line, near, sign, z, vote)]
        return choice

    choice = plane_of(C)
    grid = np.full(len(C_all), -1, dtype=np.int32)
    grid[inside] = choice
    grid = grid.reshape(ny, nx)
    raster_cell = cell
    if refine_steps and boundaries == "each" and max_dz is not None:
        grid, raster_cell = _steps_refined(grid, x0, y1, cell, P[:, :2], lab, planes, max_dz, plane_of)
    # rasterio (GDAL) only here: importing it costs every command's start-up a tenth of a second
    from rasterio import features
    from rasterio.transform import Affine

    transform = Affine(raster_cell, 0, x0, 0, -raster_cell, y1)
    regions, ids = _polygons(features.shapes(grid, transform=transform, connectivity=4))
    if max_dz is None or boundaries == "free":
        regions = shapely.coverage_simplify(np.array(regions, dtype=object), simplify * cell, simplify_boundary=False)
    elif boundaries == "each":
        regions, ids = _arcs_simplified(regions, ids, grid, x0, y1, raster_cell, P, lab, planes,
                                        tolerance=simplify * cell,
                                        floor=min(0.75, simplify) * raster_cell, max_dz=max_dz, plane_sigma=plane_sigma)
    else:
        # only points near a region boundary can change region: those whose
        # cell has another label within the tolerance (plus a cell)
        r = int(np.ceil(simplify)) + 1
        mixed = ndimage.maximum_filter(grid, 2 * r + 1) != ndimage.minimum_filter(grid, 2 * r + 1)
        col = np.clip(((P[:, 0] - x0) / cell).astype(np.int64), 0, nx - 1)
        row = np.clip(((y1 - P[:, 1]) / cell).astype(np.int64), 0, ny - 1)
        near = mixed[row, col]
        regions = _regularised(regions, ids, P[near], lab[near], planes, tolerance=simplify * cell,
                               floor=min(0.75, simplify) * cell, max_dz=max_dz)
    # each plane's regions cut by the outline, their polygons kept
    labelled = np.asarray(ids) >= 0
    parts, of = shapely.get_parts(shapely.intersection(shapely.make_valid(np.asarray(regions, dtype=object)[labelled]),
                                                       outline), return_index=True)
    keep = (shapely.get_type_id(parts) == 3) & ~shapely.is_empty(parts)
    keep[keep] = shapely.area(parts[keep]) > 0
    polys, pids = list(parts[keep]), np.asarray(ids)[labelled][of[keep]].tolist()
    min_area = 4 * cell**2 if min_area is None else min_area
    kept = None
    if kept_planes is not None and len(polys):
        # of a kept plane's faces, the one holding most of its points (one face per block)
        kept = np.zeros(len(polys), dtype=bool)
        faces_of = np.flatnonzero(np.asarray(kept_planes, dtype=bool)[pids])
        held = np.array([shapely.contains_xy(polys[i], *P[lab == pids[i], :2].T).sum() for i in faces_of])
        for plane in np.unique(np.asarray(pids)[faces_of]):
            mine = np.asarray(pids)[faces_of] == plane
            best = int(np.argmax(np.where(mine, held, -1)))
            kept[faces_of[best]] = held[best] > 0
    polys, pids = _absorb_slivers(polys, pids, min_area, kept)
    return polys, pids


def _area_sum(faces) -> float:
    """Total area of the faces, summed in order as ``sum(p.area for p in faces)`` (the tiling checks compare it)."""
    return sum(shapely.area(np.asarray(faces, dtype=object)).tolist())


def merge_close_vertices(polys: list, outline, eps: float) -> list:
    """Face vertices moved onto a vertex within ``eps`` (m): no face edge that short, the outline's vertices kept.

    Where a cell staircase meets the outline, or its steps are projected onto
    a ridge line (:func:`snap_to_lines`), vertices come out a fraction of a
    millimetre apart, which the models' vertex grid and validators (val3dity
    snaps at 1 mm) turn into repeated points or hair-thin walls.  A vertex
    within ``eps`` of the outline goes onto it; a cluster of close vertices
    moves onto its outline vertex, else onto a vertex on the outline, else
    onto its first vertex in coordinate order, so vertices shared by two
    faces stay shared; the outline's own vertices never move.  A face the
    moves would make invalid keeps its vertices (and its neighbours keep the
    shared ones); if the faces would stop tiling the outline, they are
    returned unchanged.
    """
    if eps <= 0 or not polys:
        return polys
    faces = np.array(polys, dtype=object)
    allxy, owner = shapely.get_coordinates(faces, return_index=True)
    xy, inv = np.unique(allxy, axis=0, return_inverse=True)
    ring = shapely.boundary(outline)
    off = shapely.distance(ring, shapely.points(xy))
    # vertices a hair inside the outline go onto it (else the wall there is a hair long)
    graze = (off > 0) & (off < eps)
    pos = xy.copy()
    if graze.any():
        pos[graze] = shapely.get_coordinates(shapely.line_interpolate_point(
            ring, shapely.line_locate_point(ring, shapely.points(xy[graze]))))
    pairs = cKDTree(pos).query_pairs(eps, output_type="ndarray")
    if not len(pairs) and not graze.any():
        return polys
    corners = shapely.get_coordinates(ring)
    fixed = cKDTree(corners).query(xy)[0] == 0
    label = components(len(xy), pairs.reshape(-1, 2))
    # the target of each cluster: its outline vertex, else a vertex on the outline (cuts of a face boundary with
    # it), else its first vertex; ties in coordinate order (xy is sorted)
    order = np.lexsort((np.arange(len(xy)), off >= eps, ~fixed))
    rank = np.empty(len(xy), dtype=np.int64)
    rank[order] = np.arange(len(xy))
    best = np.full(label.max() + 1, len(xy), dtype=np.int64)
    np.minimum.at(best, label, rank)
    target = np.where(fixed, np.arange(len(xy)), order[best[label]])  # the outline's own vertices stay
    inv = inv.ravel()
    area = _area_sum(faces)
    held = np.zeros(len(xy), bool)
    # a face the moves would make invalid keeps its vertices (and so do its neighbours, which share them)
    for _ in range(8):
        at = np.where(held[:, None], xy, pos)[np.where(held, np.arange(len(xy)), target)][inv]
        try:
            moved = shapely.remove_repeated_points(shapely.transform(faces, lambda _, to=at: to))
        except shapely.errors.GEOSException:
            break
        bad = ~((shapely.get_type_id(moved) == 3) & ~shapely.is_empty(moved) & shapely.is_valid(moved))
        if not bad.any():
            if (abs(_area_sum(moved) - area) <= 1e-6 * max(area, 1.0)
                    and abs(shapely.union_all(moved).area - area) <= 1e-6 * max(area, 1.0)):
                return list(moved)
            break
        held[inv[bad[owner]]] = True
    log.debug("merging close face vertices undone (would break the tiling)")
    return polys


def snap_to_lines(polys: list, lines: list, outline, tol: float) -> list:
    """Move face vertices onto the ridge, hip and valley lines they follow.

    Vertices on the outline stay (the faces must keep tiling it).  Any other
    vertex within ``tol`` (m, plan) of a line end goes to the end, else one
    within ``tol`` of a line is projected on it.  The move is a function of the vertex alone, so vertices shared by two
    faces stay shared.  Afterwards the face edges along a line are the line
    (in 3D too, once lifted, as the line lies on both planes).  If any face
    comes out invalid or the faces stop tiling the outline, the faces are
    returned unchanged.
    """
    if not lines or not polys:
        return polys
    seg = np.array([np.asarray(g.coords)[[0, -1], :2] for g in lines])
    ends = seg.reshape(-1, 2)
    a, b = seg[:, 0], seg[:, 1]
    ab = b - a
    L2 = np.maximum((ab * ab).sum(axis=1), 1e-12)
    boundary = outline.boundary

    def _snap(coords):
        # every vertex of every face at once, in slices: the (vertices, lines) arrays stay small
        return np.concatenate([_snap_some(coords[k:k + 4096, :2]) for k in range(0, len(coords), 4096)]
                              + [np.zeros((0, 2))])

    def _snap_some(xy):
        out = xy.copy()
        de = np.hypot(xy[:, None, 0] - ends[None, :, 0], xy[:, None, 1] - ends[None, :, 1])
        je = np.argmin(de, axis=1)
        at_end = de[np.arange(len(xy)), je] <= tol
        ap = xy[:, None, :] - a[None]
        t = np.clip((ap * ab[None]).sum(axis=2) / L2, 0, 1)
        proj = a[None] + t[..., None] * ab[None]
        ds = np.hypot(xy[:, None, 0] - proj[..., 0], xy[:, None, 1] - proj[..., 1])
        js = np.argmin(ds, axis=1)
        on_seg = ds[np.arange(len(xy)), js] <= tol
        on_outline = shapely.distance(boundary, shapely.points(xy)) < 1e-9
        end_ok = at_end & ~on_outline
        move = on_seg & ~on_outline & ~end_ok
        out[move] = proj[np.flatnonzero(move), js[move]]
        out[end_ok] = ends[je[end_ok]]
        return out

    try:
        snapped = list(shapely.remove_repeated_points(shapely.transform(np.array(polys, dtype=object), _snap)))
        area = _area_sum(polys)
        ok = (bool(shapely.is_valid(snapped).all() and (shapely.get_type_id(snapped) == 3).all())
              and abs(_area_sum(snapped) - area) <= 1e-6 * max(area, 1.0)
              and abs(shapely.union_all(snapped).area - area) <= 1e-6 * max(area, 1.0))
    except shapely.errors.GEOSException:
        ok = False
    if not ok:
        log.debug("face snapping to lines undone (would break the tiling)")
        return polys
    return snapped


def lift_to_plane(geom, plane: np.ndarray):
    """Give a plan geometry the Z of a plane ``(a, b, c, d)`` at every vertex.

    ``geom`` may also be an array of K geometries with ``plane`` of shape
    (K, 4), one plane each (one call for a roof's faces).
    """
    plane = np.asarray(plane, dtype=np.float64)
    geom = shapely.force_3d(geom)
    if plane.ndim == 2:
        _, owner = shapely.get_coordinates(geom, include_z=True, return_index=True)

        def _z(coords):
            return np.column_stack([coords[:, :2], plane_height(plane[owner], coords[:, :2])])
    else:

        def _z(coords):
            return np.column_stack([coords[:, :2], plane_height(plane[None, :], coords[:, :2])[:, 0]])

    return shapely.transform(geom, _z, include_z=True)


def step_edges(polys: list, plane_ids: list, planes: np.ndarray, *, step_height: float, min_length: float,
               simplify: float = 0.0):
    """Step edges: shared face boundaries where the two planes differ in height.

    Parameters
    ----------
    polys : list of shapely Polygon (2D)
        Faces tiling the outline.
    plane_ids : list of int
    planes : ndarray of shape (K, 4)
    step_height : float
        Smallest median height jump (m) along the shared boundary.
    min_length : float
        Shorter boundaries (m) are ignored.
    simplify : float
        Douglas-Peucker tolerance (m) applied to each step line.

    Returns
    -------
    lines : list of LineString (3D)
        On the upper plane (the top of the wall).
    pairs : list of tuple of int
        ``(upper plane, lower plane)``.
    """
    lines, pairs = [], []
    if len(polys) < 2:
        return lines, pairs
    faces = np.array(polys, dtype=object)
    plane_ids = np.asarray(plane_ids)
    i, j = shapely.STRtree(faces).query(faces, predicate="intersects")
    keep = (i < j) & (plane_ids[i] != plane_ids[j])
    i, j = i[keep], j[keep]
    # the shared boundaries of all touching pairs in one call, each pair's line pieces merged
    rims = shapely.boundary(faces)
    parts, of = shapely.get_parts(shapely.intersection(rims[i], rims[j]), return_index=True)
    line = np.isin(shapely.get_type_id(parts), (1, 2)) & ~shapely.is_empty(parts)
    parts, of = parts[line], of[line]
    if not len(parts):
        return lines, pairs
    pair, of = np.unique(of, return_inverse=True)
    merged, of = shapely.get_parts(shapely.line_merge(shapely.multilinestrings(parts, indices=of)), return_index=True)
    length = shapely.length(merged)
    long = length >= min_length
    merged, of, length = merged[long], pair[of[long]], length[long]
    # A shared boundary can be partly a step and partly a crease (a dormer's
    # cheeks and its top): keep the runs where the planes are apart, judged
    # on a densified copy of the boundary.
    dense, at = shapely.get_coordinates(shapely.segmentize(merged, np.maximum(length / 200, 0.05)), return_index=True)
    start = np.r_[0, np.cumsum(np.bincount(at, minlength=len(merged)))]
    for m, k in enumerate(of):
        a, b = plane_ids[i[k]], plane_ids[j[k]]
        xy = dense[start[m]:start[m + 1]]
        za = plane_height(planes[a][None, :], xy)[:, 0]
        zb = plane_height(planes[b][None, :], xy)[:, 0]
        jump = np.abs(za - zb) > step_height
        edges = np.flatnonzero(np.diff(np.r_[0, jump.astype(np.int8), 0]))
        for r0, r1 in zip(edges[::2], edges[1::2]):
            if r1 - r0 < 2:
                continue
            run = shapely.simplify(LineString(xy[r0:r1]), simplify)
            if run.length < min_length:
                continue
            up, lo = (a, b) if np.median(za[r0:r1] - zb[r0:r1]) > 0 else (b, a)
            lines.append(run)
            pairs.append((int(up), int(lo)))
    if lines:
        lines = list(lift_to_plane(np.array(lines, dtype=object), planes[[up for up, _ in pairs]]))
    return lines, pairs


def _answered_points(xyz: np.ndarray, spacing: float, rise: float, detected: np.ndarray | None) -> np.ndarray:
    """Indices of the points a roof face answers for: those no point within ``spacing`` (plan) stands ``rise`` over.

    The LoD 2.2 roof is the top surface: a point with a point of the
    building (of ``detected``, default all) standing more than ``rise`` over
    it within the spacing (a wall or a lower roof's edge under the eaves, a
    floor under a canopy) is under something, labelled or not.
    """
    allp = np.arange(len(xyz))
    return allp[open_to_sky(xyz, allp, spacing, rise, by=detected)] if len(allp) else allp


class _FaceFit:
    """A roof's faces with the answered points under each, their neighbours, and the planes that fit them.

    A face is judged by the detection's building points under it when it
    has any (the others break ties), unless it is its plane's main face
    (holding most of its plane's answered points), judged by all.
    """

    def __init__(self, polys, plane_ids, xyz: np.ndarray, labels: np.ndarray, planes: np.ndarray, spacing: float,
                 rise: float, detected: np.ndarray | None = None):
        self.faces = np.array(list(polys), dtype=object)
        self.pids = np.asarray(list(plane_ids), dtype=np.int64).copy()
        self.planes, self.rise = planes, rise
        pts = _answered_points(xyz, spacing, rise, detected) if len(self.faces) else np.zeros(0, np.int64)
        self.P, self.lab = xyz[pts], np.asarray(labels)[pts]
        self.detected = np.ones(len(pts), dtype=bool) if detected is None else np.asarray(detected, dtype=bool)[pts]
        at, of = points_in_faces(self.faces, self.P[:, :2]) if len(pts) else (np.zeros(0, np.int64),) * 2
        # a point on a shared edge is under both faces
        order = np.argsort(of, kind="stable")
        self.members = np.split(at[order], np.searchsorted(of[order], np.arange(1, len(self.faces))))
        self.alive = np.ones(len(self.faces), dtype=bool)
        per_plane = np.bincount(self.lab[self.lab >= 0], minlength=len(planes))
        own = np.array([np.count_nonzero(self.lab[m] == k) for m, k in zip(self.members, self.pids)], dtype=np.int64)
        self.main = 2 * own > per_plane[self.pids]
        self.box = shapely.bounds(self.faces)
        self.edges = shapely.boundary(self.faces)

    def _decisive(self, i: int, m: np.ndarray) -> np.ndarray:
        """Which of the points ``m`` under face ``i`` decide its fit (all, for a main face or with no detected one)."""
        sure = self.detected[m] | self.main[i]
        return sure if sure.any() else np.ones(len(m), dtype=bool)

    def fitted(self, i: int, plane: int) -> tuple[int, int, float]:
        """How many of face ``i``'s deciding points and of all its points ``plane`` lies within ``rise`` of, and
        minus the squared residuals of the latter."""
        m = self.members[i]
        r = self.P[m, 2] - plane_height(self.planes[plane], self.P[m, :2])
        near = np.abs(r) <= self.rise
        return int(np.count_nonzero(near & self._decisive(i, m))), int(near.sum()), -float(np.sum(r[near] ** 2))

    def unfit(self) -> np.ndarray:
        """The live faces whose plane fits fewer than half of their deciding points, or that have none, smallest first."""
        live = np.flatnonzero(self.alive)
        sizes = np.array([len(self.members[i]) for i in live], dtype=np.int64)
        at = np.concatenate([self.members[i] for i in live]) if len(live) else np.zeros(0, np.int64)
        of = np.repeat(live, sizes)
        near = np.abs(self.P[at, 2] - plane_height(self.planes[self.pids[of]], self.P[at, :2])) <= self.rise
        sure = self.detected[at] | self.main[of]
        n_sure = np.bincount(of, weights=sure, minlength=len(self.faces))[live]
        fit_sure = np.bincount(of, weights=near & sure, minlength=len(self.faces))[live]
        fit_all = np.bincount(of, weights=near, minlength=len(self.faces))[live]
        off = np.where(n_sure > 0, 2 * fit_sure < n_sure, 2 * fit_all < sizes)
        out = live[off | (sizes == 0)]
        return out[np.argsort(shapely.area(self.faces[out]), kind="stable")]

    def neighbours(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """The live faces sharing an edge with face ``i``, and the shared length (m)."""
        b = self.box
        near = np.flatnonzero(self.alive & (b[:, 0] <= b[i, 2]) & (b[:, 2] >= b[i, 0]) & (b[:, 1] <= b[i, 3])
                              & (b[:, 3] >= b[i, 1]))
        near = near[near != i]
        if not len(near):
            return near, np.zeros(0)
        shared = shapely.length(shapely.intersection(self.edges[i], self.edges[near]))
        return near[shared > 0], shared[shared > 0]

    def better_plane(self, i: int) -> tuple[int, np.ndarray, np.ndarray]:
        """The plane fitting face ``i``'s points best among its neighbours' and its labelled points' own planes,
        when the face's plane fits fewer than half of its deciding points and that one fits more of them (or as
        many and more of all); else -1.  With the neighbours."""
        nb, shared = self.neighbours(i)
        m = self.members[i]
        now = self.fitted(i, self.pids[i])
        if not len(m) or 2 * now[0] >= np.count_nonzero(self._decisive(i, m)):
            return -1, nb, shared
        own = self.lab[m]
        cand = np.unique(np.concatenate([self.pids[nb], own[own >= 0]]))
        best, score = -1, now
        for c in cand:  # (lowest plane first: ties keep it)
            s = self.fitted(i, int(c))
            if s > score:
                best, score = int(c), s
        return (best if score[:2] > now[:2] else -1), nb, shared

    def merge(self, i: int, j: int) -> bool:
        """Face ``i`` joined to face ``j``, when that makes one polygon with no new hole (also on the centimetre grid)."""
        u = shapely.union(self.faces[j], self.faces[i])
        holes = shapely.get_num_interior_rings(self.faces[j]) + shapely.get_num_interior_rings(self.faces[i])
        coarse = shapely.set_precision(u, 0.01)
        if (u.geom_type != "Polygon" or not u.is_valid or shapely.get_num_interior_rings(u) > holes
                or coarse.geom_type != "Polygon" or shapely.get_num_interior_rings(coarse) > holes):
            return False
        self.faces[j], self.box[j], self.edges[j] = u, u.bounds, u.boundary
        self.members[j] = np.union1d(self.members[j], self.members[i])
        self.alive[i] = False
        return True


def faces_off_their_points(polys, plane_ids, xyz: np.ndarray, labels: np.ndarray, planes: np.ndarray, *,
                           spacing: float, rise: float = 0.5, detected: np.ndarray | None = None) -> np.ndarray:
    """The faces whose plane fits fewer than half of the points under them while a plane at hand fits more.

    The faces' promise to the points under them: of the points a face
    answers for (the points under it that no point of the building within
    ``spacing`` in plan stands more than ``rise`` over: the top surface,
    labelled or not), its plane lies within ``rise`` of at least half,
    unless no plane at hand (a neighbouring face's, sharing an edge, or the
    own plane of a labelled one of those points) lies within ``rise`` of
    more.  With ``detected``, "half" and "more" count the detection's
    building points under the face when it holds any, but on a plane's
    main face.  :func:`fit_faces` keeps it.

    Parameters
    ----------
    polys : sequence of shapely Polygon
        Faces tiling the outline (Z ignored).
    plane_ids : sequence of int
        Plane of each face.
    xyz : ndarray of shape (N, 3)
        The building's points (m).
    labels : ndarray of shape (N,), int
        Plane per point, ``-1`` on none.
    planes : ndarray of shape (K, 4)
    spacing : float
        Mean point spacing ``s`` (m): the plan radius within which a higher point covers another.
    rise : float
        Height (m) within which a plane fits a point (the roof's ``step_height``).
    detected : ndarray of shape (N,), bool, optional
        The points the detection calls building (default all): only they
        hide a point under them, and where a face holds any they decide its
        fit (the others break ties), but on its plane's main face (the one
        holding most of its plane's answered points).

    Returns
    -------
    ndarray of shape (len(polys),), bool
        The faces that break the promise.

    Examples
    --------
    >>> import shapely
    >>> planes = np.array([[0.0, 0.0, 1.0, -8.0], [0.0, 0.0, 1.0, -5.0]])  # upper level 8 m, lower 5 m
    >>> notch = shapely.box(3.5, 1.5, 4, 2.5)  # a sliver of the lower level over a point of the upper one
    >>> faces = [shapely.box(0, 0, 4, 4) - notch, shapely.box(4, 0, 8, 4), notch]
    >>> xyz = np.array([[2.0, 2.0, 8.0], [6.0, 2.0, 5.0], [3.8, 2.0, 8.0]])
    >>> faces_off_their_points(faces, [0, 1, 1], xyz, np.array([0, 1, 0]), planes, spacing=0.5).tolist()
    [False, False, True]
    """
    fit = _FaceFit(polys, plane_ids, np.asarray(xyz, dtype=np.float64), labels, planes, spacing, rise, detected)
    out = np.zeros(len(fit.faces), dtype=bool)
    for i in fit.unfit():
        out[i] = fit.better_plane(i)[0] >= 0
    return out


def fit_faces(polys: list, plane_ids: list, xyz: np.ndarray, labels: np.ndarray, planes: np.ndarray, *,
              spacing: float, rise: float = 0.5, detected: np.ndarray | None = None) -> tuple[list, list]:
    """Faces whose plane fits the points under them: each face that fits fewer than half of them given away.

    The raster, the sliver merging and the claim of the step edges work on
    the labelled points near a boundary, each level's own; where several
    levels' points interleave (the foot of a wall under a higher roof's
    eaves, a messy corner of small planes) they can leave a face of a few
    tenths of a m² whose plane lies metres above or below the one to three
    points of the top surface under it.  Such a face (its plane within
    ``rise`` of fewer than half of the points it answers for, those no point
    within ``spacing`` stands ``rise`` over: see
    :func:`faces_off_their_points`) takes the plane that fits most of them,
    within ``rise`` (ties: the smaller sum of squared residuals), among the
    planes of the faces sharing an edge with it and the own planes of its
    labelled points (with ``detected``, the detection's building points
    under it count first: :func:`faces_off_their_points`); it is merged into the neighbour
    of that plane sharing most edge, or, with none (or when the union would
    not be one polygon without a new hole, also on the centimetre grid),
    keeps its outline under the new plane.  A face under which no point is
    answered for (a sliver a claim or a kept block left) is merged into the
    neighbour sharing most edge on the same terms.  Faces are taken
    smallest first, three rounds at most.

    What it guarantees, on any data: the faces still tile what they tiled,
    none is added, and afterwards :func:`faces_off_their_points` finds none
    (every face's plane lies within ``rise`` of at least half of the points
    it answers for, or no plane at hand fits more of them).  The faces of
    the small steep planes fitted to a messy corner, which cover another
    level's points rather than their own, go to that level.

    Parameters
    ----------
    polys, plane_ids, xyz, labels, planes, spacing, rise, detected
        As in :func:`faces_off_their_points` (``polys`` 2D, tiling the outline).

    Returns
    -------
    polygons : list of shapely Polygon
    plane_ids : list of int
        The faces left, in their order.

    Examples
    --------
    >>> import shapely
    >>> planes = np.array([[0.0, 0.0, 1.0, -8.0], [0.0, 0.0, 1.0, -5.0]])  # upper level 8 m, lower 5 m
    >>> notch, empty = shapely.box(3.5, 1.5, 4, 2.5), shapely.box(7.5, 0, 8, 0.5)
    >>> faces = [shapely.box(0, 0, 4, 4) - notch, notch, shapely.box(4, 0, 8, 4) - empty, empty]
    >>> xyz = np.array([[2.0, 2.0, 8.0], [3.8, 2.0, 8.0], [6.0, 2.0, 5.0]])  # an upper point under the notch
    >>> polys, ids = fit_faces(faces, [0, 1, 1, 0], xyz, np.array([0, 0, 1]), planes, spacing=0.5)
    >>> ids, [p.area for p in polys]  # the notch to the upper face, the face over no point to the lower one
    ([0, 1], [16.0, 16.0])
    """
    fit = _FaceFit(polys, plane_ids, np.asarray(xyz, dtype=np.float64), labels, planes, spacing, rise, detected)
    if len(fit.faces) < 2:
        return list(polys), list(plane_ids)
    for _ in range(3):
        changed = False
        for i in fit.unfit():
            if not fit.alive[i]:
                continue
            best, nb, shared = fit.better_plane(i)
            if not len(fit.members[i]):
                changed |= bool(len(nb)) and fit.merge(i, int(nb[np.argmax(shared)]))
                continue
            if best < 0:
                continue
            mine = fit.pids[nb] == best
            if not (mine.any() and fit.merge(i, int(nb[mine][np.argmax(shared[mine])]))):
                fit.pids[i] = best
            changed = True
        if not changed:
            break
    return list(fit.faces[fit.alive]), fit.pids[fit.alive].tolist()
