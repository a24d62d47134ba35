"""Geometric validity of a solid, checked by our own code (the val3dity rules we rely on).

A valid :class:`~rooftrace.model.types.Solid` here is one outer shell that is

- **closed and 2-manifold**: every edge is used by exactly two surfaces, once
  in each direction (so the orientations agree), the surfaces around every
  vertex form one fan, and the shell is one connected piece;
- **outward**: the enclosed (signed) volume is positive;
- **planar**: every surface lies within ``planarity`` of its plane
  (val3dity's error 203), and the triangles of its constrained
  triangulation all face the same way, within ``normals_deviation``
  degrees of each other (error 204: a surface a few millimetres wide is
  flat by distance but its triangles tilt at random);
- **simple in its plane**: every surface, projected on its plane, is a valid
  polygon (no self-intersection, holes inside the outer ring, area > 0),
  outer ring counter-clockwise seen from outside, holes clockwise.

Vertices are first rounded to ``grid`` (1 mm by default, the precision of
the CityJSON writer), then vertices closer than ``snap_tolerance`` are one,
as val3dity snaps them when it reads a file: two vertices one grid step
apart become one there, and a ring through both repeats a vertex (its
error 102).

Between the solids of one building's parts, :func:`overlapping_parts` finds
those whose interiors overlap (val3dity's error 601, ``BUILDINGPARTS_OVERLAP``).

What is *not* checked: intersections between different surfaces of the
shell (val3dity's ``SHELL_SELF_INTERSECTION``); the builders make 2.5D
shells (walls vertical, one roof height per plan position) where those
cannot occur unless a surface is invalid in its plane.
"""

from __future__ import annotations

import numpy as np
import shapely
from scipy.spatial import cKDTree

from rooftrace.graph import components

__all__ = ["solid_errors", "is_valid_solid", "solid_volume", "surface_normal", "surface_normals", "surface_triangles",
           "triangle_tilt", "surface_tilt", "overlapping_parts", "PartExtent",
           "overlapping_extents", "t_junctions", "solid_plan", "surface_polygons"]


def _ring_table(surfaces):
    """All rings stacked: vertices (V, 3), ring of each vertex, next vertex, surface of each ring."""
    per_surface = [s.rings for s in surfaces]
    rings = [r for rs in per_surface for r in rs]
    sizes = np.fromiter(map(len, rings), dtype=np.int64, count=len(rings))
    owner = np.repeat(np.arange(len(surfaces)), np.fromiter(map(len, per_surface), dtype=np.int64,
                                                            count=len(per_surface)))
    try:
        # the builders' rings are (K, 3) float arrays: one concatenation, no conversion per ring
        xyz = np.concatenate(rings).astype(np.float64, copy=False) if rings else np.zeros((0, 3))
    except ValueError:  # rings of mixed shapes (an empty one)
        xyz = None
    if xyz is None or xyz.ndim != 2 or xyz.shape[1] != 3:
        rings = [np.asarray(r, dtype=np.float64).reshape(-1, 3) for r in rings]
        sizes = np.array([len(r) for r in rings], dtype=np.int64)
        xyz = np.vstack(rings)
    ring = np.repeat(np.arange(len(rings)), sizes)
    start = np.concatenate(([0], np.cumsum(sizes)[:-1])).astype(np.int64)
    nxt = np.arange(len(xyz)) + 1
    nxt[start + sizes - 1] = start
    return xyz, ring, nxt, owner, sizes, start


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.column_stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                            a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]])


def _area_vectors(xyz, ring, nxt, owner, sizes, n_surfaces, origin):
    """Newell area vector (twice the area, along the normal) of every surface; holes count negatively."""
    p = xyz - origin
    per_ring = np.add.reduceat(_cross(p, p[nxt]), np.concatenate(([0], np.cumsum(sizes)[:-1])), axis=0) if len(p) else \
        np.zeros((0, 3))
    out = np.zeros((n_surfaces, 3))
    np.add.at(out, owner, per_ring)
    return out


def surface_normal(rings: list[np.ndarray]) -> np.ndarray:
    """Area vector of a planar surface (Newell's method): its direction is the normal.

    The outer ring counts positively and holes (opposite orientation)
    negatively, so the norm is twice the area of the surface (m²).
    """
    total = np.zeros(3)
    for r in rings:
        r = np.asarray(r, dtype=np.float64)
        r = r - r.mean(axis=0)
        n = np.roll(r, -1, axis=0)
        total += _cross(r, n).sum(axis=0)
    return total


def surface_normals(surfaces) -> tuple[np.ndarray, np.ndarray]:
    """:func:`surface_normal` of every surface at once, and the mean of each surface's vertices.

    The same sums in the same order as :func:`surface_normal` (each ring
    centred on its own mean), so the results are equal bit for bit.

    Parameters
    ----------
    surfaces : sequence of Surface

    Returns
    -------
    normal : ndarray of shape (S, 3)
        Area vectors (m²; twice the area along the normal).
    centre : ndarray of shape (S, 3)
        Mean of the vertices of all rings of each surface (m).
    """
    xyz, ring, nxt, owner, sizes, start = _ring_table(surfaces)
    n_rings = np.bincount(owner, minlength=len(surfaces))
    if not len(xyz) or not (n_rings > 0).all() or not (sizes > 0).all():
        return (np.array([surface_normal(s.rings) for s in surfaces]).reshape(-1, 3),
                np.array([np.vstack(s.rings).mean(axis=0) for s in surfaces]).reshape(-1, 3))
    normal = np.zeros((len(surfaces), 3))
    rel = xyz - (np.add.reduceat(xyz, start, axis=0) / sizes[:, None])[ring]
    np.add.at(normal, owner, np.add.reduceat(_cross(rel, rel[nxt]), start, axis=0))
    first = start[np.concatenate(([0], np.cumsum(n_rings)[:-1]))]
    count = np.add.reduceat(sizes, np.concatenate(([0], np.cumsum(n_rings)[:-1])))
    return normal, np.add.reduceat(xyz, first, axis=0) / count[:, None]


def solid_volume(solid, origin: np.ndarray | None = None) -> float:
    """Signed volume (m³) enclosed by the solid's surfaces, positive when they face outward.

    Divergence theorem: ``V = 1/3 sum_f (A_f . p_f)`` with ``A_f`` the area
    vector of surface ``f`` and ``p_f`` a point of its plane (its outer
    ring's first vertex).  Coordinates are taken relative to ``origin``
    (default the first vertex) so that map coordinates keep their precision.
    """
    if not solid.surfaces:
        return 0.0
    return _volume(*_ring_table(solid.surfaces), len(solid.surfaces), origin)


def _volume(xyz, ring, nxt, owner, sizes, start, n_surfaces, origin=None) -> float:
    """:func:`solid_volume` from the solid's ring table."""
    if origin is None:
        origin = xyz[0]
    area = _area_vectors(xyz, ring, nxt, owner, sizes, n_surfaces, origin) / 2.0
    first = np.unique(owner, return_index=True)[1]
    p = xyz[start[first]] - origin
    return float((area * p).sum()) / 3.0


def _rows(a: np.ndarray) -> np.ndarray:
    """Each row of a 2D array as one opaque value (equal rows, equal values; sortable)."""
    a = np.ascontiguousarray(a)
    return a.view(np.dtype((np.void, a.dtype.itemsize * a.shape[1]))).ravel()


def _parallel_triangles(xyz: np.ndarray, surf: np.ndarray, n_surfaces: int) -> np.ndarray:
    """Surfaces whose triangles are parallel however they are cut: all vertices at one height, or on two plan positions.

    A horizontal surface's triangles all have normals ``(0, 0, ±1)``
    exactly, a vertical wall's (its two sides' vertices over two plan
    positions) all lie in one vertical plane to the rounding of the
    coordinates: neither can tilt, and triangulating them (most of a
    building's surfaces) tells nothing.  ``surf`` is sorted (surfaces in
    order, as :func:`_ring_table` stacks them).
    """
    out = np.zeros(n_surfaces, dtype=bool)
    if not len(surf):
        return out
    start = np.flatnonzero(np.r_[True, surf[1:] != surf[:-1]])
    z = xyz[:, 2]
    level = np.minimum.reduceat(z, start) == np.maximum.reduceat(z, start)
    o = np.lexsort((xyz[:, 1], xyz[:, 0], surf))
    s, x, y = surf[o], xyz[o, 0], xyz[o, 1]
    new = np.r_[True, (s[1:] != s[:-1]) | (x[1:] != x[:-1]) | (y[1:] != y[:-1])]
    positions = np.bincount(s[new], minlength=n_surfaces)
    out[surf[start]] = level | (positions[surf[start]] <= 2)
    return out


def _bases(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row of ``normal`` (S, 3), unit vectors u, v with (u, v, n) right-handed."""
    n = normal / np.linalg.norm(normal, axis=1, keepdims=True)
    a = np.where((np.abs(n[:, 0]) < 0.9)[:, None], [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    u = _cross(a, n)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return u, _cross(n, u)


def surface_triangles(polys: np.ndarray, flat: np.ndarray, surf: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Constrained Delaunay triangles of surfaces drawn in 2D, as indices of their vertices.

    Parameters
    ----------
    polys : ndarray of shapely Polygon, shape (S,)
        Each surface in 2D (its plane, or plan view for a roof), built from
        the rows of ``flat`` (the triangulation adds no vertex).
    flat : ndarray of shape (V, 2)
        2D vertices of all surfaces (m).
    surf : ndarray of shape (V,), int
        Surface of each vertex.

    Returns
    -------
    corners : ndarray of shape (T, 3), int
        Rows of ``flat`` at each triangle's corners, counter-clockwise in 2D.
    of : ndarray of shape (T,), int
        Surface of each triangle.
    """
    tris, of = shapely.get_parts(shapely.constrained_delaunay_triangles(polys), return_index=True)
    if not len(tris):
        return np.zeros((0, 3), dtype=np.int64), np.zeros(0, dtype=np.int64)
    # triangles have no holes: their coordinates are their exterior rings' (no ring objects made)
    xy = shapely.get_coordinates(tris).reshape(-1, 4, 2)[:, :3]
    # back to the vertex each corner is: the triangulation copies the vertices it is given, so
    # (surface, x, y) finds it bit for bit
    table = _rows(np.column_stack([surf.astype(np.float64), flat]))
    wanted = _rows(np.column_stack([np.repeat(of, 3).astype(np.float64), xy.reshape(-1, 2)]))
    order = np.argsort(table, kind="stable")
    at = order[np.minimum(np.searchsorted(table[order], wanted), len(order) - 1)]
    if not (table[at] == wanted).all():
        # a corner that is no vertex (GEOS moved it): the nearest vertex of its surface, surfaces
        # far apart in a third coordinate
        span = np.abs(flat).max() * 4.0 + 1.0
        _, at = cKDTree(np.column_stack([flat, surf * span])).query(
            np.column_stack([xy.reshape(-1, 2), np.repeat(of, 3) * span]))
    corners = at.reshape(-1, 3)
    e1, e2 = xy[:, 1] - xy[:, 0], xy[:, 2] - xy[:, 0]
    cw = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] < 0
    corners[cw] = corners[cw][:, ::-1]
    return corners, of


def triangle_tilt(xyz: np.ndarray, corners: np.ndarray, of: np.ndarray, unit: np.ndarray,
                  limit: float) -> np.ndarray:
    """Largest angle (degrees) between the normals of two triangles of each surface, where it matters.

    val3dity's error 204 compares the normals of a surface's triangles; a
    surface a few millimetres wide, or with vertices a centimetre apart, is
    flat by distance yet its triangles tilt at random.

    Parameters
    ----------
    xyz : ndarray of shape (V, 3)
        Vertices (m).
    corners, of : ndarray
        Triangles as :func:`surface_triangles` gives them.
    unit : ndarray of shape (S, 3)
        Unit normal of each surface, on the side the triangles face.
    limit : float
        Tolerance (degrees) the result is compared with: the exact pairwise
        angle is computed only for surfaces with a triangle more than half
        of it from ``unit`` (two triangles within half of it of one
        direction are within ``limit`` of each other).

    Returns
    -------
    ndarray of shape (S,)
        Triangles of zero area in 3D have no normal and are skipped.
    """
    tilt = np.zeros(len(unit))
    p = xyz[corners]
    normal = _cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    norm = np.linalg.norm(normal, axis=1)
    ok = norm > 1e-12
    normal, of = normal[ok] / norm[ok, None], of[ok]
    off = np.degrees(np.arccos(np.clip((normal * unit[of]).sum(axis=1), -1.0, 1.0)))
    np.maximum.at(tilt, of, off)
    for k in np.flatnonzero(tilt > limit / 2):
        n = normal[of == k]
        tilt[k] = np.degrees(np.arccos(np.clip((n @ n.T).min(), -1.0, 1.0)))
    return tilt


def _centres(xyz, surf, n_surfaces):
    count = np.bincount(surf, minlength=n_surfaces)
    return np.column_stack([np.bincount(surf, weights=xyz[:, i], minlength=n_surfaces)
                            for i in range(3)]) / np.maximum(count, 1)[:, None]


def _in_plane(xyz, ring, nxt, owner, sizes, start, n_surfaces):
    """Every surface drawn in its own plane (through its vertices' mean, across its Newell normal).

    Returns the origin the coordinates are taken from, the area vectors, the
    2D vertices, the rings and the first ring of each surface, and the
    surfaces as 2D polygons.
    """
    origin = xyz.min(axis=0)
    normal = _area_vectors(xyz, ring, nxt, owner, sizes, n_surfaces, origin)
    surf = owner[ring]
    rel = xyz - origin - _centres(xyz - origin, surf, n_surfaces)[surf]
    u, v = _bases(np.where(np.linalg.norm(normal, axis=1, keepdims=True) > 1e-12, normal, [[0.0, 0.0, 1.0]]))
    flat = np.column_stack([(rel * u[surf]).sum(axis=1), (rel * v[surf]).sum(axis=1)])
    lr, first, polys = _ring_polygons(flat, sizes, start, owner, n_surfaces)
    return origin, normal, flat, lr, first, polys


def surface_polygons(surfaces, *, plan: bool = False) -> np.ndarray:
    """Each surface as one shapely Polygon (Z kept, or its plan), all built in a few array calls.

    Parameters
    ----------
    surfaces : sequence of Surface
    plan : bool, default False
        Drop Z (the plan view of roofs).

    Returns
    -------
    ndarray of shapely Polygon, shape (S,)
    """
    xyz, _, _, owner, sizes, start = _ring_table(surfaces)
    return _ring_polygons(xyz[:, :2] if plan else xyz, sizes, start, owner, len(surfaces))[2]


def _ring_polygons(flat: np.ndarray, sizes: np.ndarray, start: np.ndarray, owner: np.ndarray,
                   n_surfaces: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Surfaces as polygons from their stacked open rings (as :func:`_ring_table` gives them).

    Parameters
    ----------
    flat : ndarray of shape (V, 2) or (V, 3)
        Vertices of all rings, one after the other (m).
    sizes, start : ndarray of shape (R,), int
        Vertices of each ring and where it starts in ``flat``.
    owner : ndarray of shape (R,), int
        Surface of each ring (sorted; the first ring of a surface is its outer ring).
    n_surfaces : int

    Returns
    -------
    rings : ndarray of shapely LinearRing, shape (R,)
    first : ndarray of shape (S,), int
        First ring of each surface.
    polys : ndarray of shapely Polygon, shape (S,)
    """
    closed_idx = np.insert(np.arange(len(flat)), np.cumsum(sizes), start)
    closed_ring = np.repeat(np.arange(len(sizes)), sizes + 1)
    lr = shapely.linearrings(flat[closed_idx], indices=closed_ring)
    n_rings = np.bincount(owner, minlength=n_surfaces)
    first = np.concatenate(([0], np.cumsum(n_rings)[:-1]))
    simple = np.flatnonzero(n_rings == 1)
    polys = np.empty(n_surfaces, dtype=object)
    polys[simple] = shapely.polygons(lr[first[simple]])
    for k in np.flatnonzero(n_rings > 1):
        polys[k] = shapely.polygons(lr[first[k]], lr[first[k] + 1:first[k] + n_rings[k]])
    return lr, first, polys


def surface_tilt(surfaces, limit: float = 20.0) -> np.ndarray:
    """Largest angle (degrees) between two triangles of each surface, triangulated in its plane.

    What :func:`solid_errors` compares with ``normals_deviation`` (see
    :func:`triangle_tilt` for ``limit``).

    Parameters
    ----------
    surfaces : sequence of Surface
    limit : float, default 20

    Returns
    -------
    ndarray of shape (S,)
        0 for a surface that is not a valid polygon in its plane, and for
        one that is horizontal or on two plan positions (a wall): their
        triangles are parallel (to the rounding of the coordinates).
    """
    xyz, ring, nxt, owner, sizes, start = _ring_table(surfaces)
    n = len(surfaces)
    tilt = np.zeros(n)
    can_tilt = ~_parallel_triangles(xyz, owner[ring], n)
    if not can_tilt.any():
        return tilt  # e.g. the flat roofs of LoD 1.2 and 1.3
    origin, normal, flat, _, _, polys = _in_plane(xyz, ring, nxt, owner, sizes, start, n)
    norm = np.linalg.norm(normal, axis=1)
    ok = (norm > 1e-12) & can_tilt
    ok[ok] = shapely.is_valid(polys[ok])
    if ok.any():
        keep = ok[owner[ring]]
        index = np.cumsum(ok) - 1
        corners, of = surface_triangles(polys[ok], flat[keep], index[owner[ring]][keep])
        sub = triangle_tilt(xyz[keep] - origin, corners, of, normal[ok] / norm[ok, None], limit)
        tilt[ok] = sub
    return tilt


def _surface_errors(xyz, vid, ring, nxt, owner, sizes, start, n_surfaces, planarity,
                    normals_deviation) -> list[str]:
    """Rings with too few or repeated vertices, non-planar surfaces, surfaces not simple in their plane."""
    errors = []
    bad_ring = sizes < 3
    dup = vid == vid[nxt]
    o = np.lexsort((vid, ring))
    twice = np.zeros(len(vid), bool)
    twice[o[1:]] = (ring[o[1:]] == ring[o[:-1]]) & (vid[o[1:]] == vid[o[:-1]])
    for k in np.unique(owner[bad_ring]):
        errors.append(f"surface {k}: a ring has fewer than 3 vertices")
    for k in np.unique(owner[ring[dup]]):
        errors.append(f"surface {k}: consecutive duplicate vertices")
    for k in np.unique(owner[ring[twice & ~dup]]):
        errors.append(f"surface {k}: a ring passes twice through one vertex")
    if errors:
        return errors
    origin, normal, flat, lr, first, polys = _in_plane(xyz, ring, nxt, owner, sizes, start, n_surfaces)
    norm = np.linalg.norm(normal, axis=1)
    for k in np.flatnonzero(~(norm > 1e-12)):
        errors.append(f"surface {k}: zero area")
    if errors:
        return errors
    surf = owner[ring]
    unit = normal / norm[:, None]
    centre = _centres(xyz - origin, surf, n_surfaces)
    dist = np.abs(((xyz - origin - centre[surf]) * unit[surf]).sum(axis=1))
    worst = np.zeros(n_surfaces)
    np.maximum.at(worst, surf, dist)
    for k in np.flatnonzero(worst > planarity):
        errors.append(f"surface {k}: not planar ({worst[k]:.4f} m from its plane)")
    valid = shapely.is_valid(polys)
    for k in np.flatnonzero(~valid):
        errors.append(f"surface {k}: self-intersecting in its plane ({shapely.is_valid_reason(polys[k])})")
    if valid.all():
        tilt = np.zeros(n_surfaces)
        tilted = ~_parallel_triangles(xyz, surf, n_surfaces)
        if tilted.any():
            keep = tilted[surf]
            index = np.cumsum(tilted) - 1
            corners, of = surface_triangles(polys[tilted], flat[keep], index[surf][keep])
            tilt[tilted] = triangle_tilt(xyz[keep] - origin, corners, of, unit[tilted], normals_deviation)
        for k in np.flatnonzero(tilt > normals_deviation):
            errors.append(f"surface {k}: not planar (its triangles' normals {tilt[k]:.1f} degrees apart)")
    ccw = shapely.is_ccw(lr)
    hole = np.ones(len(lr), bool)
    hole[first] = False
    for k in np.flatnonzero(valid & ~ccw[first]):
        errors.append(f"surface {k}: outer ring not counter-clockwise seen from outside")
    for k in np.unique(owner[hole & ccw]):
        errors.append(f"surface {k}: a hole is not clockwise seen from outside")
    return errors


def solid_errors(solid, *, planarity: float = 0.01, grid: float = 1e-3, snap_tolerance: float = 1e-3,
                 normals_deviation: float = 20.0) -> list[str]:
    """What makes a solid invalid; an empty list when it is valid.

    Parameters
    ----------
    solid : Solid
    planarity : float, default 0.01
        Largest distance (m) of a vertex from its surface's plane (the
        Newell normal through the vertices' mean; val3dity's default
        ``planarity_d2p_tol``).
    grid : float, default 0.001
        Vertices are rounded to this grid (m), as the CityJSON writer does.
    snap_tolerance : float, default 0.001
        Rounded vertices this close (m) or closer are one vertex
        (val3dity's default ``--snap_tol``; ``0``: only equal vertices).
    normals_deviation : float, default 20
        Largest angle (degrees) between the normals of two triangles of a
        surface (val3dity's default ``--planarity_n_tol``).

    Returns
    -------
    list of str
        One line per problem found.

    Examples
    --------
    >>> from rooftrace.model.build import prism_solid
    >>> import shapely
    >>> box = prism_solid([(shapely.box(0, 0, 10, 8), (0.0, 0.0, 1.0, -6.0))], 0.0)
    >>> solid_errors(box), round(solid_volume(box), 6)
    ([], 480.0)
    """
    surfaces = solid.surfaces
    if len(surfaces) < 4:
        return [f"a solid needs at least 4 surfaces, this one has {len(surfaces)}"]
    xyz, ring, nxt, owner, sizes, start = _ring_table(solid.surfaces)
    keys = np.round((xyz - xyz.min(axis=0)) / grid).astype(np.int64)
    span = keys.max(axis=0) + 1
    # vertex numbers serve only to tell vertices apart: any numbering of the distinct rows will do
    # (one integer per row when they fit: much faster than rows)
    packed = float(span[0]) * float(span[1]) * float(span[2]) < 2.0**62
    if packed:
        code = (keys[:, 0] * span[1] + keys[:, 1]) * span[2] + keys[:, 2]
        codes, first, vid = np.unique(code, return_index=True, return_inverse=True)
    else:
        _, first, vid = np.unique(_rows(keys), return_index=True, return_inverse=True)
    unique, vid = keys[first], vid.ravel()
    if snap_tolerance > 0:
        # val3dity compares decoded floats (``d < tol``): a pair exactly one tolerance apart may
        # merge or not there, so it counts as merged here
        reach = snap_tolerance * (1 + 1e-6)
        if packed and grid * (1 + 1e-9) <= reach < grid * np.sqrt(2.0) * (1 - 1e-9):
            pairs = _grid_neighbours(unique, codes, span)  # within one step and under a diagonal: axis neighbours
        else:
            pairs = cKDTree(unique * grid).query_pairs(reach, output_type="ndarray")
        if len(pairs):
            vid = components(len(unique), pairs)[vid].astype(np.int64)
    errors = _surface_errors(xyz, vid, ring, nxt, owner, sizes, start, len(surfaces), planarity,
                             normals_deviation)
    if errors:
        return errors
    # closed and consistently oriented: each directed edge once, and its reverse once
    a, b = vid, vid[nxt]
    face = owner[ring]
    n = int(vid.max()) + 1
    key = a * n + b
    uk, counts = np.unique(key, return_counts=True)
    if (counts > 1).any():
        errors.append(f"{int((counts > 1).sum())} edges used twice in the same direction (flipped or non-manifold)")
    at = np.minimum(np.searchsorted(uk, b * n + a), len(uk) - 1)  # uk is sorted: the same test as np.isin
    missing = uk[at] != b * n + a
    if missing.any():
        errors.append(f"not closed: {int(missing.sum())} edges without an opposite edge")
    if errors:
        return errors
    # one connected shell: surfaces joined through their shared edges
    order = np.argsort(key)
    opposite = order[np.searchsorted(key[order], b * n + a)]
    if components(len(surfaces), np.column_stack([face, face[opposite]])).max() > 0:
        errors.append("the shell is not connected")
    # 2-manifold at vertices: around each vertex, the edges (next -> previous)
    # of the surfaces using it chain into one cycle.  Each directed edge v -> to is
    # followed by v -> back, ``back`` the vertex before v on the ring of v -> to (closed and
    # each edge once: v -> back exists); around v the edges make one cycle of that map
    prev = np.empty_like(vid)
    prev[nxt] = vid
    follow = order[np.searchsorted(key[order], a * n + prev)]
    cycle = components(len(a), np.column_stack([np.arange(len(a)), follow]))
    fans = np.unique(a * len(a) + cycle) // len(a)
    bad = int((np.bincount(fans) > 1).sum())
    if bad:
        errors.append(f"{bad} non-manifold vertices (the surfaces around them make several fans)")
    volume = _volume(xyz, ring, nxt, owner, sizes, start, len(surfaces))
    if not volume > 0:
        errors.append(f"surfaces face inward (signed volume {volume:.3f} m³)")
    return errors


def _grid_neighbours(unique: np.ndarray, codes: np.ndarray, span: np.ndarray) -> np.ndarray:
    """Pairs of rows of ``unique`` (distinct grid vertices, ``codes`` their sorted packed values) one step apart
    along one axis: the pairs a k-d tree finds within a radius of one step (and under a diagonal's)."""
    out = []
    for axis, step in enumerate((span[1] * span[2], span[2], 1)):
        has = np.flatnonzero(unique[:, axis] + 1 < span[axis])  # its neighbour's code would be another row's
        at = np.minimum(np.searchsorted(codes, codes[has] + step), len(codes) - 1)
        found = codes[at] == codes[has] + step
        out.append(np.column_stack([has[found], at[found]]))
    return np.vstack(out)


def is_valid_solid(solid, **kwargs) -> bool:
    """``solid_errors(solid, **kwargs) == []``."""
    return not solid_errors(solid, **kwargs)


def solid_plan(solid, *, grid: float = 1e-3):
    """The plan of a 2.5D solid: the union of its ``GroundSurface``\\ s, vertices rounded to ``grid`` (m)."""
    rings = [[np.round(np.asarray(r, dtype=np.float64)[:, :2] / grid) * grid for r in s.rings]
             for s in solid.surfaces if s.kind == "GroundSurface"]
    return shapely.union_all([shapely.Polygon(r[0], r[1:]) for r in rings])


def overlapping_parts(solids, *, tolerance: float = 0.0, grid: float = 1e-3) -> list[tuple[int, int]]:
    """Pairs of 2.5D solids (the parts of one building) whose interiors overlap.

    val3dity's test of BuildingParts (error 601): two parts may share wall
    surfaces but no volume.  For the builders' solids (vertical walls, one
    ground surface, every plan position under the roof inside) two solids
    overlap in 3D exactly when their plans' interiors overlap and their
    height ranges do.

    Parameters
    ----------
    solids : sequence of Solid
        Each with its ``GroundSurface``\\ s: their union is its plan.
    tolerance : float, default 0
        Plans and height ranges are first shrunk by this distance (m), as
        val3dity's ``--overlap_tol`` (default 0: any overlap counts, however
        thin - a sliver of a few mm² between two party walls is one).
    grid : float, default 0.001
        Vertices are rounded to this grid (m) first, as the CityJSON writer
        does.

    Returns
    -------
    list of (int, int)
        Index pairs ``i < j`` into ``solids``, in order.

    Examples
    --------
    >>> from rooftrace.model.solid import horizontal_plane, prism_solid
    >>> import shapely
    >>> a = prism_solid([(shapely.box(0, 0, 5, 8), horizontal_plane(6.0))], 0.0)
    >>> b = prism_solid([(shapely.box(5, 0, 10, 8), horizontal_plane(7.0))], 0.0)
    >>> c = prism_solid([(shapely.box(4.99, 0, 10, 8), horizontal_plane(7.0))], 0.0)
    >>> overlapping_parts([a, b]), overlapping_parts([a, b, c]), overlapping_parts([a, c], tolerance=0.01)
    ([], [(0, 2), (1, 2)], [])
    """
    return overlapping_extents([PartExtent.of(solid, tolerance=tolerance, grid=grid) for solid in solids],
                               tolerance=tolerance, grid=grid)


class PartExtent:
    """What :func:`overlapping_parts` measures of one solid: its plan and height range, shrunk by ``tolerance``.

    Made once per solid, it serves every test of that solid against its
    neighbours (a building's parts are tested again after each rebuild of
    one of them).  ``vertices`` and ``boundary`` (for the T-junction test)
    are made on first use.

    Attributes
    ----------
    plan : shapely Polygon or MultiPolygon
    low, high : float
        Height range (m).
    grid : float
    """

    def __init__(self, plan, low: float, high: float, grid: float):
        self.plan, self.low, self.high, self.grid = plan, low, high, grid
        self._vertices = self._boundary = None

    @classmethod
    def of(cls, solid, *, tolerance: float = 0.0, grid: float = 1e-3) -> PartExtent:
        """The extent of a 2.5D ``solid`` (see :func:`overlapping_parts` for the arguments)."""
        plan = solid_plan(solid, grid=grid)
        z = _ring_table(solid.surfaces)[0][:, 2]
        return cls(plan.buffer(-tolerance, join_style="mitre") if tolerance > 0 else plan,
                   np.round(z.min() / grid) * grid + tolerance, np.round(z.max() / grid) * grid - tolerance, grid)

    @property
    def vertices(self) -> np.ndarray:
        """The plan's distinct vertices in grid units (rows sorted)."""
        if self._vertices is None:
            self._vertices = np.unique(np.round(shapely.get_coordinates(self.plan) / self.grid), axis=0)
        return self._vertices

    @property
    def boundary(self):
        """The plan's boundary, prepared."""
        if self._boundary is None:
            self._boundary = self.plan.boundary
            shapely.prepare(self._boundary)
        return self._boundary


def overlapping_extents(extents: list[PartExtent], *, tolerance: float = 0.0,
                        grid: float = 1e-3) -> list[tuple[int, int]]:
    """:func:`overlapping_parts` of solids given by their :class:`PartExtent` (made with the same arguments)."""
    plans = np.array([e.plan for e in extents], dtype=object)
    i, j = shapely.STRtree(plans).query(plans, predicate="intersects")
    keep = i < j
    i, j = i[keep], j[keep]
    # interiors meet (touching along a party wall does not count), or the shared wall has a T-junction
    inner = shapely.relate_pattern(plans[i], plans[j], "T********")
    if tolerance <= 0:
        inner |= np.array([_t_junctions(extents[a], extents[b]) > 0 for a, b in zip(i.tolist(), j.tolist())], bool)
    pairs = zip(i[inner].tolist(), j[inner].tolist())
    return sorted((a, b) for a, b in pairs if min(extents[a].high, extents[b].high) > max(extents[a].low,
                                                                                          extents[b].low))


def t_junctions(a, b, grid: float = 1e-3) -> int:
    """Vertices of one plan on the other's boundary that are not vertices of it (both ways).

    Two parts share a party wall exactly only vertex for vertex.  A vertex of
    one on a straight stretch of the other's wall is collinear on the
    integer grid, but not in the floating-point coordinates a reader makes of
    them (``translate + i * scale``): val3dity, in exact arithmetic, finds
    a sliver of about 10⁻¹⁰ m² between the two grounds there whenever the
    vertex falls on the neighbour's side (its error 601), which no
    area-based test on rounded coordinates sees.

    Parameters
    ----------
    a, b : shapely Polygon or MultiPolygon
        Plans, vertices on the ``grid``.
    grid : float, default 0.001
        Vertex grid (m); a vertex within half of it of the other's boundary is on it.

    Returns
    -------
    int
        Number of such vertices.

    Examples
    --------
    >>> import shapely
    >>> left, right = shapely.box(0, 0, 5, 8), shapely.box(5, 0, 10, 8)
    >>> kinked = shapely.Polygon([(5, 0), (10, 0), (10, 8), (5, 8), (5, 3)])
    >>> t_junctions(left, right), t_junctions(left, kinked)
    (0, 1)
    """
    return _t_junctions(PartExtent(a, 0.0, 0.0, grid), PartExtent(b, 0.0, 0.0, grid))


def _t_junctions(a: PartExtent, b: PartExtent) -> int:
    """:func:`t_junctions` of two extents' plans (their vertices and boundaries made once per extent)."""
    count, grid = 0, a.grid
    for one, other in ((a, b), (b, a)):
        theirs = other.vertices  # distinct: the same membership and box as all of them
        if not len(theirs):
            continue
        xy = one.vertices
        xy = xy[~np.isin(xy @ [1, 1j], theirs @ [1, 1j])]  # grid integers: exact as complex keys
        # only vertices within the other's box can lie on its boundary (most of a plan is far from it)
        lo, hi = theirs.min(axis=0) - 1, theirs.max(axis=0) + 1
        xy = xy[((xy >= lo) & (xy <= hi)).all(axis=1)]
        if len(xy):
            # the exact distance only for the vertices within a grid step (an indexed test of the
            # prepared boundary): those further off are not within half a step either
            points = shapely.points(xy * grid)
            near = shapely.dwithin(points, other.boundary, grid)
            count += int(np.sum(shapely.distance(points[near], other.boundary) < 0.5 * grid))
    return count
