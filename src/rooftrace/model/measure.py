"""What a model says about heights: the roof height above a plan position, and the fit of points to it."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import shapely

from rooftrace.model.validity import surface_normal, surface_normals, surface_polygons
from rooftrace.roof.planes import plane_height

__all__ = ["roof_height_at", "surface_distance", "vertical_rmse", "points_off_their_roof"]


def roof_height_at(solids: Iterable, xy: np.ndarray) -> np.ndarray:
    """Height (m) of the roof surfaces of ``solids`` above each plan position.

    Parameters
    ----------
    solids : iterable of Solid
        E.g. the LoD 2.2 solids of a building's parts.
    xy : ndarray of shape (N, 2)
        Plan positions (m).

    Returns
    -------
    ndarray of shape (N,), float64
        The highest roof surface over each position; NaN where there is none.

    Examples
    --------
    >>> import shapely
    >>> from rooftrace.model.solid import prism_solid, horizontal_plane
    >>> box = prism_solid([(shapely.box(0, 0, 4, 4), horizontal_plane(5.0))], 0.0)
    >>> roof_height_at([box], np.array([[1.0, 1.0], [9.0, 9.0]])).tolist()
    [5.0, nan]
    """
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    out = np.full(len(xy), np.nan)
    roofs = [s for solid in solids for s in solid.surfaces if s.kind == "RoofSurface"]
    if not roofs or not len(xy):
        return out
    # every roof's normal, centre and plan polygon from one table of its rings
    normal, centre = surface_normals(roofs)
    polys = surface_polygons(roofs, plan=True)
    # a vertical roof surface covers no plan area
    flat = np.abs(normal[:, 2]) >= 1e-9 * np.maximum(np.linalg.norm(normal, axis=1), 1e-300)
    if not flat.any():
        return out
    polys = polys[flat]
    normal, centre = normal[flat], centre[flat]
    # the same dot product per surface as ever (a batched one may round differently), without np.r_
    planes = np.column_stack([normal, np.array([-n @ c for n, c in zip(normal, centre)], dtype=np.float64)])
    shapely.prepare(polys)
    # a few hundred surfaces over up to 10^5 points: each surface tests the points in its box
    # (sorted by X, a slice) rather than each point querying a tree of the surfaces
    order = np.argsort(xy[:, 0], kind="stable")
    xs = xy[order, 0]
    box = shapely.bounds(polys)
    lo = np.searchsorted(xs, box[:, 0], side="left")
    hi = np.searchsorted(xs, box[:, 2], side="right")
    for k in np.flatnonzero(hi > lo):
        cand = order[lo[k]:hi[k]]
        y = xy[cand, 1]
        cand = cand[(y >= box[k, 1]) & (y <= box[k, 3])]
        at = cand[shapely.intersects_xy(polys[k], xy[cand, 0], xy[cand, 1])]
        pl = planes[k]
        np.fmax.at(out, at, -(pl[0] * xy[at, 0] + pl[1] * xy[at, 1] + pl[3]) / pl[2])
    return out


def points_off_their_roof(solids: Iterable, xyz: np.ndarray, labels: np.ndarray, planes: np.ndarray, *,
                          max_dz: float = 0.1) -> np.ndarray:
    """The labelled points whose roof in ``solids`` is more than ``max_dz`` (m) off their own plane there.

    With :func:`rooftrace.roof.faces.points_on_their_faces` this states what
    the model step keeps (:func:`rooftrace.model.build.build_model`): a
    point the roof faces put under a face of its plane (or of one within
    ``max_dz``) lies under a roof surface within ``max_dz`` plus the solids'
    ``z_tolerance`` of its plane; the plan lattice moves a face edge by up
    to its half diagonal, and a point that close to it is given the lattice
    square around it (unless the solid so built is invalid).

    Parameters
    ----------
    solids : iterable of Solid
        E.g. the LoD 2.2 solids of a building's parts.
    xyz : ndarray of shape (N, 3)
    labels : ndarray of shape (N,), int
        Plane per point, ``-1`` on none (never off).
    planes : ndarray of shape (K, 4)
    max_dz : float

    Returns
    -------
    ndarray of shape (N,), bool
        False where there is no roof or no label.

    Examples
    --------
    >>> import shapely
    >>> from rooftrace.model.solid import prism_solid, horizontal_plane
    >>> box = prism_solid([(shapely.box(0, 0, 4, 4), horizontal_plane(5.0))], 0.0)
    >>> xyz = np.array([[1.0, 1.0, 5.0], [2.0, 2.0, 8.0], [9.0, 9.0, 8.0]])
    >>> planes = np.array([[0.0, 0.0, 1.0, -5.0], [0.0, 0.0, 1.0, -8.0]])
    >>> points_off_their_roof([box], xyz, np.array([0, 1, 1]), planes).tolist()
    [False, True, False]
    """
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    labels = np.asarray(labels)
    out = np.zeros(len(xyz), dtype=bool)
    sel = np.flatnonzero(labels >= 0)
    if not len(sel):
        return out
    own = plane_height(np.asarray(planes, dtype=np.float64)[labels[sel]], xyz[sel, :2])
    h = roof_height_at(list(solids), xyz[sel, :2])
    out[sel] = np.isfinite(h) & (np.abs(h - own) > max_dz)
    return out


def vertical_rmse(solids: Iterable, xyz: np.ndarray) -> float:
    """Root mean square of the height differences (m) of points to the roof surfaces above/below them.

    Points outside the solids' roofs in plan are ignored; NaN when none is inside.
    """
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    d = xyz[:, 2] - roof_height_at(list(solids), xyz[:, :2])
    d = d[np.isfinite(d)]
    return float(np.sqrt(np.mean(d * d))) if len(d) else float("nan")


def surface_distance(solids: Iterable, xyz: np.ndarray) -> np.ndarray:
    """Distance (m) in 3D from each point to the nearest surface (roof, wall or ground) of ``solids``.

    The measure of 3D city model software (roofer, the 3DBAG) for the fit of
    points to a mesh: a facade point scores its distance to the wall, not
    its height below the roof.

    Parameters
    ----------
    solids : iterable of Solid
        E.g. the LoD 2.2 solids of one building's parts.
    xyz : ndarray of shape (N, 3)
        Points (m).

    Returns
    -------
    ndarray of shape (N,), float64
        Inf where there is no surface.

    Examples
    --------
    >>> import shapely
    >>> from rooftrace.model.solid import prism_solid, horizontal_plane
    >>> box = prism_solid([(shapely.box(0, 0, 4, 4), horizontal_plane(5.0))], 0.0)
    >>> surface_distance([box], np.array([[2.0, 2.0, 5.5], [2.0, 2.0, 2.0], [6.0, 2.0, 5.0]])).tolist()
    [0.5, 2.0, 2.0]
    """
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    best = np.full(len(xyz), np.inf)
    surfaces = [s for solid in solids for s in solid.surfaces]
    if not surfaces or not len(xyz):
        return best
    origin = xyz.mean(axis=0)  # local coordinates keep map coordinates' precision in the projections
    p = xyz - origin
    frames = []
    for s in surfaces:
        rings = [np.asarray(r, dtype=np.float64) - origin for r in s.rings]
        n = surface_normal(rings)
        norm = np.linalg.norm(n)
        if norm == 0:
            continue  # a degenerate surface has no plane and no area
        n = n / norm
        u = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
        u /= np.linalg.norm(u)
        v = np.cross(n, u)
        c = rings[0][0]
        flat = shapely.Polygon((rings[0] - c) @ np.c_[u, v], [(r - c) @ np.c_[u, v] for r in rings[1:]])
        allv = np.vstack(rings)
        frames.append((allv.min(axis=0), allv.max(axis=0), c, n, np.c_[u, v], flat))
    # the roofs first: their distances bound the rest, so most walls and grounds need no exact test
    frames.sort(key=lambda f: -abs(f[3][2]))
    for lo, hi, c, n, uv, flat in frames:
        # distance to the surface's box is a lower bound of the distance to the surface
        gap = np.linalg.norm(np.maximum(np.maximum(lo - p, p - hi), 0.0), axis=1)
        cand = np.flatnonzero(gap < best)
        if not len(cand):
            continue
        q = p[cand] - c
        w = q @ n
        inplane = shapely.distance(flat, shapely.points(q @ uv))
        np.fmin.at(best, cand, np.hypot(w, inplane))
    return best
