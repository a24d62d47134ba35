"""A TIN surface over LiDAR points and the intersection of pixel rays with it.

The TIN is the Delaunay triangulation of the points' (X, Y) with linear
interpolation of Z (scipy / Qhull).  A ray from the camera is marched
downwards from above the highest point; the first sample below the surface
brackets the visible intersection (so a ray meets the roof, not the ground
hidden under it), and bisection refines it.  This is how image positions go
back to object space over a surface model (Dal Poz & Fazan, and the back-projection
of refined lines).
"""

from __future__ import annotations

import logging

import matplotlib.tri as mtri
import numpy as np
from scipy.spatial import Delaunay

__all__ = ["TinSurface", "intersect_tin"]

log = logging.getLogger(__name__)


class TinSurface:
    """Linear interpolation of Z over the Delaunay triangulation of points (P, 3).

    Examples
    --------
    >>> tin = TinSurface(np.array([[0, 0, 0], [10, 0, 10], [0, 10, 0], [10, 10, 10.0]]))
    >>> tin.height(np.array([[5.0, 5.0], [20.0, 0.0]])).tolist()
    [5.0, nan]
    """

    def __init__(self, points_xyz):
        pts = np.asarray(points_xyz, float).reshape(-1, 3)
        pts = pts[np.isfinite(pts).all(axis=1)]
        if len(pts) < 3:
            raise ValueError(f"a TIN needs at least 3 points, got {len(pts)}")
        xy, idx = np.unique(pts[:, :2], axis=0, return_index=True)  # duplicates break Qhull
        self.points = pts[idx]
        self.xy = xy
        try:
            self.tri = Delaunay(xy)
        except Exception as exc:  # scipy raises QhullError for collinear input
            raise ValueError(f"points do not span a surface ({exc.__class__.__name__})") from None
        self.z = self.points[:, 2]
        self.z_min, self.z_max = float(self.z.min()), float(self.z.max())
        edges = xy[self.tri.simplices] - xy[np.roll(self.tri.simplices, 1, axis=1)]
        #: mean Delaunay edge length: the sampling step along rays
        self.spacing = float(np.hypot(edges[..., 0], edges[..., 1]).mean())
        # Qhull's find_simplex walks and falls back to brute force on near-regular
        # (gridded) clouds: ~1 ms per query.  Matplotlib's trapezoid map on the
        # same triangles answers in O(log n), ~1 us per query.
        self._finder = mtri.Triangulation(xy[:, 0], xy[:, 1], self.tri.simplices).get_trifinder()

    def height(self, xy) -> np.ndarray:
        """Interpolated Z (N,) at (N, 2) positions; NaN outside the convex hull."""
        xy = np.atleast_2d(np.asarray(xy, float))
        simplex = self._finder(xy[:, 0], xy[:, 1])
        out = np.full(len(xy), np.nan)
        ok = simplex >= 0
        if ok.any():
            # barycentric coordinates from the vertices (scipy's ``transform``
            # is computed for every triangle at once and takes seconds on 10^4)
            tri = self.tri.simplices[simplex[ok]]
            a, b, c = (self.xy[tri[:, k]] for k in range(3))
            v0, v1, v2 = b - a, c - a, xy[ok] - a
            d00, d01, d11 = (v0 * v0).sum(1), (v0 * v1).sum(1), (v1 * v1).sum(1)
            d20, d21 = (v2 * v0).sum(1), (v2 * v1).sum(1)
            den = d00 * d11 - d01 * d01
            with np.errstate(divide="ignore", invalid="ignore"):
                v = (d11 * d20 - d01 * d21) / den
                w = (d00 * d21 - d01 * d20) / den
            z = self.z[tri]
            out[ok] = (1 - v - w) * z[:, 0] + v * z[:, 1] + w * z[:, 2]
        return out


def intersect_tin(camera, cr, surface: TinSurface, *, iterations: int = 40, max_samples: int = 4000) -> np.ndarray:
    """Object points where pixel rays first meet a TIN surface.

    Parameters
    ----------
    camera : FrameCamera or OrthoCamera
    cr : ndarray of shape (N, 2)
        Pixels (col, row).
    surface : TinSurface
    iterations : int, default 40
        Bisection steps after bracketing (each halves the bracket).
    max_samples : int, default 4000
        Cap on the marching samples per ray.

    Returns
    -------
    ndarray of shape (N, 3)
        Intersections; NaN for rays that miss the TIN.

    Notes
    -----
    Rays are sampled at heights from ``z_max + 1`` down to ``z_min - 1`` with
    a step whose horizontal move is at most half the TIN's mean edge length,
    so no triangle is stepped over; the sign change of ``Z - h(X, Y)`` is
    then refined by bisection.
    """
    o, d = camera.ray(np.atleast_2d(np.asarray(cr, float)))
    n = len(o)
    out = np.full((n, 3), np.nan)
    down = d[:, 2] < -1e-12
    if not down.any():
        return out
    o, d = o[down], d[down]
    z_top, z_bot = surface.z_max + 1.0, surface.z_min - 1.0
    slope = np.hypot(d[:, 0], d[:, 1]) / -d[:, 2]  # horizontal move per unit of Z
    dz = 0.5 * surface.spacing / max(float(slope.max()), 1e-9)
    m = int(min(max(np.ceil((z_top - z_bot) / dz) + 1, 16), max_samples))
    levels = np.linspace(z_top, z_bot, m)

    def at(z):  # points on each ray at heights z (k, S) -> (k, S, 3)
        t = (z - o[:, 2, None]) / d[:, 2, None]
        return o[:, None, :] + t[..., None] * d[:, None, :]

    pts = at(np.broadcast_to(levels, (len(o), m)))
    h = surface.height(pts[..., :2].reshape(-1, 2)).reshape(len(o), m)
    below = (levels[None, :] - h) <= 0  # NaN compares False: outside the TIN counts as above
    hit = below.any(axis=1)
    first = np.argmax(below, axis=1)
    hit &= first > 0
    idx = np.flatnonzero(hit)
    hi = levels[first[idx] - 1].copy()  # above the surface
    lo = levels[first[idx]].copy()  # on or below it
    oo, dd = o[idx], d[idx]
    for _ in range(iterations):
        mid = 0.5 * (hi + lo)
        p = oo + ((mid - oo[:, 2]) / dd[:, 2])[:, None] * dd
        hm = surface.height(p[:, :2])
        above = ~(mid - hm <= 0)
        hi = np.where(above, mid, hi)
        lo = np.where(above, lo, mid)
    z = 0.5 * (hi + lo)
    res = oo + ((z - oo[:, 2]) / dd[:, 2])[:, None] * dd
    # the surface's own height at the final XY: exact on the TIN
    h_final = surface.height(res[:, :2])
    res[:, 2] = np.where(np.isfinite(h_final), h_final, z)
    sub = np.full((len(o), 3), np.nan)
    sub[idx] = res
    out[down] = sub
    return out
