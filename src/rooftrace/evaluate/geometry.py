"""Outline geometry shared by the metrics: polygonal inputs, their rings and
segments, and the closest points on a boundary (planimetric or 3D).

The conventions are those of :mod:`rooftrace.evaluate.metrics`, which
re-exports :func:`ring_vertices` and :func:`ring_segments`.
"""

from __future__ import annotations

import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry

__all__ = ["polygonal", "ring_vertices", "ring_segments", "closest_on_segments"]

# points × segments evaluated at once in the 3D distance; bounds memory (~100 MB)
_CHUNK = 2_000_000


def _as_geometry(geom) -> BaseGeometry | None:
    """One geometry from a geometry, a sequence of them (unioned) or None."""
    if geom is None:
        return None
    if isinstance(geom, BaseGeometry):
        return geom
    parts = [g for g in geom if g is not None]
    if not parts:
        return None
    return shapely.union_all(np.asarray(parts, dtype=object))


def polygonal(geom, name: str) -> BaseGeometry | None:
    geom = _as_geometry(geom)
    if geom is None or geom.is_empty:
        return None
    if isinstance(geom, shapely.GeometryCollection) and not isinstance(geom, shapely.MultiPolygon):
        polys = [g for g in shapely.get_parts(geom) if isinstance(g, (shapely.Polygon, shapely.MultiPolygon))]
        geom = shapely.union_all(polys) if polys else None
        if geom is None or geom.is_empty:
            return None
    if not isinstance(geom, (shapely.Polygon, shapely.MultiPolygon)):
        raise TypeError(f"{name} must be a Polygon or MultiPolygon, not {geom.geom_type}")
    return geom


def _rings(geom: BaseGeometry) -> list[np.ndarray]:
    """Closed coordinate arrays (k, 3) of every ring; z is NaN when absent."""
    rings = shapely.get_rings(shapely.get_parts(geom))
    return [shapely.get_coordinates(r, include_z=True) for r in rings if not r.is_empty]


def ring_vertices(geom) -> np.ndarray:
    """Vertices of all rings of a (Multi)Polygon, closing vertices dropped.

    Parameters
    ----------
    geom : Polygon or MultiPolygon

    Returns
    -------
    ndarray of shape (N, 3) float64
        x, y, z; z is NaN for a 2D geometry. Empty for None/empty input.
    """
    geom = polygonal(geom, "geom")
    if geom is None:
        return np.empty((0, 3))
    rings = [r[:-1] for r in _rings(geom)]
    return np.concatenate(rings) if rings else np.empty((0, 3))


def ring_segments(geom) -> tuple[np.ndarray, np.ndarray]:
    """Start and end points, each (M, 3) float64, of every boundary segment."""
    geom = polygonal(geom, "geom")
    if geom is None:
        return np.empty((0, 3)), np.empty((0, 3))
    rings = _rings(geom)
    return np.concatenate([r[:-1] for r in rings]), np.concatenate([r[1:] for r in rings])


def closest_on_segments(points: np.ndarray, p0: np.ndarray, p1: np.ndarray, dims: int, *,
                         z_tie: float | None = None) -> np.ndarray:
    """Closest point (N, 3) on a set of segments for each point, measured in ``dims`` dimensions.

    Along the chosen segment the point is found in ``dims`` dimensions and the
    remaining coordinates (z when dims = 2) are interpolated linearly.  With
    ``z_tie`` (dims = 2) z is instead taken by :func:`_z_among_ties`; x and y
    stay those of the plan-closest point.
    """
    out = np.empty((len(points), 3))
    d = p1 - p0
    dd = np.einsum("ij,ij->i", d[:, :dims], d[:, :dims])
    safe = np.where(dd > 0, dd, 1.0)
    step = max(1, _CHUNK // max(1, len(p0)))
    for i in range(0, len(points), step):
        pts = points[i:i + step]
        rel = pts[:, None, :dims] - p0[None, :, :dims]
        t = np.clip(np.einsum("ijk,jk->ij", rel, d[:, :dims]) / safe, 0.0, 1.0)
        t = np.where(dd > 0, t, 0.0)
        foot = p0[None, :, :dims] + t[..., None] * d[None, :, :dims]
        dist2 = ((pts[:, None, :dims] - foot) ** 2).sum(axis=2)
        j = np.argmin(dist2, axis=1)  # first segment on ties: deterministic
        tj = t[np.arange(len(pts)), j]
        out[i:i + step] = p0[j] + tj[:, None] * d[j]
        if z_tie is not None:
            out[i:i + step, 2] = _z_among_ties(pts[:, 2], foot, j, t, p0[:, 2], p1[:, 2], dd == 0, z_tie)
    return out


def _z_among_ties(z, foot, j, t, z0, z1, vertical, tol) -> np.ndarray:
    """Height on the outline nearest to each point's ``z`` where its plan-closest point lies.

    The candidates of point i are its feet ``foot[i]`` (plan, on every
    segment) within ``tol`` in plan of the plan-closest one, ``foot[i, j[i]]``.
    At a vertical step of the outline (two vertices at one xy) several
    segments meet there and the first one may lie on the wrong side of the
    step; the z nearest to the point's picks the side the point belongs to.
    A vertical segment offers its two ends, the roof heights on either side,
    not the wall between them, which would hide a height error of both.
    Where the outline has no step, candidates within ``tol`` differ in z by
    at most ``tol`` times its slope.
    """
    zf = z0 + t * (z1 - z0)
    if vertical.any():
        zf[:, vertical] = np.where(np.abs(z0[vertical] - z[:, None]) <= np.abs(z1[vertical] - z[:, None]),
                                   z0[vertical], z1[vertical])
    rows = np.arange(len(z))
    near = ((foot - foot[rows, j][:, None, :]) ** 2).sum(axis=2) <= tol * tol
    k = np.argmin(np.where(near, np.abs(zf - z[:, None]), np.inf), axis=1)  # first on ties
    return zf[rows, k]
