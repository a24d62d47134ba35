"""TIN surface model of the LiDAR points for the object-space snake.

Why our own: scipy gives the Delaunay triangulation, but the snake needs two
things no library offers together: vectorised barycentric interpolation of
Z for millions of object-space samples (done once on a raster, then looked up
bilinearly), and a *roof* height at an eave.  The TIN of all points blends
roof and ground across the eave: every triangle that straddles the outline
has roof and ground vertices, so Z on the true outline is some mid value.
Two choices follow from that (Dal Poz & Fazan):

* for projecting snake sides into the image (relief displacement), the
  surface is the TIN dilated by a grey-scale maximum over ``radius`` m
  (:func:`roof_surface`): on and just outside the eave it carries the roof
  height, which is where the image edge is;
* for the output vertex heights, the TIN is sampled along each corner's
  inward bisector; samples in triangles spanning more than 1 m of height
  (the blended band) are dropped and a line through the rest is
  extrapolated back to the corner (:func:`vertex_heights`); this is exact
  for flat and planar (gable, shed, hip) roof faces.

Point location is our own too (a bucket grid of triangles, in numba):
Qhull's ``find_simplex`` spends seconds on its first call.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy import ndimage
from scipy.spatial import Delaunay, QhullError

from rooftrace.errors import GeometryError

__all__ = ["Tin", "RasterSurface", "roof_surface", "vertex_heights"]

log = logging.getLogger(__name__)


class Tin:
    """Delaunay TIN of points with linear (barycentric) interpolation of Z.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), float64
        Points in a projected CRS (m), N >= 3 and not all collinear.

    Raises
    ------
    GeometryError
        Fewer than 3 points, non-finite coordinates or a degenerate layout.

    Examples
    --------
    >>> xyz = np.array([[0, 0, 0], [10, 0, 10], [0, 10, 0], [10, 10, 10.]])
    >>> Tin(xyz)(np.array([[5.0, 5.0], [20.0, 0.0]]))
    array([ 5., nan])
    """

    def __init__(self, xyz: np.ndarray) -> None:
        xyz = np.asarray(xyz, float)
        if xyz.ndim != 2 or xyz.shape[1] != 3:
            raise ValueError(f"xyz must have shape (N, 3), got {xyz.shape}")
        if len(xyz) < 3 or not np.isfinite(xyz).all():
            raise GeometryError(f"a TIN needs at least 3 finite points, got {len(xyz)}")
        # Qhull works in local coordinates: map coordinates of 1e5..1e6 m
        # would cost precision in the barycentric transform
        self.origin = xyz[:, :2].min(axis=0)
        try:
            self._tri = Delaunay(xyz[:, :2] - self.origin)
        except QhullError as exc:
            raise GeometryError(f"cannot triangulate the points ({str(exc).splitlines()[0]})") from None
        self.z = xyz[:, 2].copy()
        self._index = None

    @property
    def simplices(self) -> np.ndarray:
        """Triangles as vertex indices, (M, 3) int."""
        return self._tri.simplices

    def edge_lengths(self) -> np.ndarray:
        """Planimetric lengths (m) of the unique triangle edges, (E,) float64."""
        s = self._tri.simplices
        e = np.sort(np.concatenate([s[:, [0, 1]], s[:, [1, 2]], s[:, [2, 0]]]), axis=1)
        e = np.unique(e, axis=0)
        p = self._tri.points
        return np.linalg.norm(p[e[:, 0]] - p[e[:, 1]], axis=1)

    def spacing(self) -> float:
        """Typical point spacing (m): the median TIN edge length.

        The median, not the mean (the detection's s_avg), because hull slivers
        and gaps in the local cloud would pull the mean up.
        """
        s = self._tri.simplices
        p = self._tri.points
        # every triangle's three sides: interior edges count twice, which
        # leaves the median where it is and saves the np.unique of edge_lengths
        d = np.concatenate([p[s[:, 0]] - p[s[:, 1]], p[s[:, 1]] - p[s[:, 2]], p[s[:, 2]] - p[s[:, 0]]])
        return float(np.median(np.hypot(d[:, 0], d[:, 1])))

    def grid(self, x0: float, y0: float, cell: float, nx: int, ny: int) -> np.ndarray:
        """Z on the cell centres ``(x0 + i cell, y0 + j cell)``, (ny, nx) float64; NaN outside the hull.

        Equal to ``self`` at those points, but scan-converts triangle by
        triangle (O(triangles + cells)) instead of locating every node by a
        walk through the triangulation, which is what makes Qhull's
        ``find_simplex`` slow for dense grids.
        """
        return _rasterise(self._tri.points, self._tri.simplices.astype(np.int64), self.z,
                          float(x0 - self.origin[0]), float(y0 - self.origin[1]), float(cell), int(nx), int(ny))

    def _locate(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Triangle index (M,) (-1 outside) and barycentric weights (M, 3) of (X, Y) positions."""
        if self._index is None:
            # a bucket grid of triangles by bounding box: Qhull's find_simplex
            # spends seconds on its first call (per-simplex transforms)
            self._index = _bucket_index(self._tri.points, self._tri.simplices.astype(np.int64))
        xy = np.atleast_2d(np.asarray(xy, float)) - self.origin
        cell, x0, y0, nx, ny, start, items = self._index
        return _locate(np.ascontiguousarray(xy), self._tri.points, self._tri.simplices.astype(np.int64),
                       cell, x0, y0, nx, ny, start, items)

    def relief(self, xy: np.ndarray) -> np.ndarray:
        """Height range (m) of the triangle under each (X, Y), (M,); NaN outside the hull.

        A triangle spanning an eave has a roof and a ground vertex: a large
        range flags the blended band.
        """
        tri, _ = self._locate(xy)
        out = np.full(len(tri), np.nan)
        ok = tri >= 0
        zt = self.z[self._tri.simplices[tri[ok]]]
        out[ok] = zt.max(axis=1) - zt.min(axis=1)
        return out

    def __call__(self, xy: np.ndarray) -> np.ndarray:
        """Z at (X, Y) positions by barycentric interpolation, (M,) float64; NaN outside the hull."""
        tri, bary = self._locate(xy)
        out = np.full(len(tri), np.nan)
        ok = tri >= 0
        out[ok] = (bary[ok] * self.z[self._tri.simplices[tri[ok]]]).sum(axis=1)
        return out


def _bucket_index(pts: np.ndarray, tris: np.ndarray):
    """CSR lists of the triangles whose bounding box meets each cell of a square grid."""
    lo = pts.min(axis=0)
    span = np.maximum(pts.max(axis=0) - lo, 1e-9)
    cell = float(np.sqrt(span[0] * span[1] / max(len(tris), 1)) * 2.0) or 1.0
    nx, ny = int(span[0] / cell) + 1, int(span[1] / cell) + 1
    start, items = _bucket_fill(pts, tris, float(lo[0]), float(lo[1]), cell, nx, ny)
    return cell, float(lo[0]), float(lo[1]), nx, ny, start, items


@njit(cache=True)
def _bucket_fill(pts, tris, x0, y0, cell, nx, ny):  # pragma: no cover - compiled
    count = np.zeros(nx * ny + 1, np.int64)
    for pass_ in range(2):
        if pass_ == 1:
            for i in range(nx * ny):
                count[i + 1] += count[i]
            items = np.empty(count[nx * ny], np.int64)
            fill = count[:-1].copy()
        for t in range(tris.shape[0]):
            xs = pts[tris[t], 0]
            ys = pts[tris[t], 1]
            c0 = int((xs.min() - x0) / cell)
            c1 = min(nx - 1, int((xs.max() - x0) / cell))
            r0 = int((ys.min() - y0) / cell)
            r1 = min(ny - 1, int((ys.max() - y0) / cell))
            for r in range(r0, r1 + 1):
                for c in range(c0, c1 + 1):
                    if pass_ == 0:
                        count[r * nx + c + 1] += 1
                    else:
                        items[fill[r * nx + c]] = t
                        fill[r * nx + c] += 1
    return count, items


@njit(cache=True)
def _locate(xy, pts, tris, cell, x0, y0, nx, ny, start, items):  # pragma: no cover - compiled
    m = xy.shape[0]
    tri = np.full(m, -1, np.int64)
    bary = np.zeros((m, 3))
    for k in range(m):
        px, py = xy[k, 0], xy[k, 1]
        if not (np.isfinite(px) and np.isfinite(py)):
            continue
        c = int(np.floor((px - x0) / cell))
        r = int(np.floor((py - y0) / cell))
        if c < 0 or r < 0 or c >= nx or r >= ny:
            continue
        b = r * nx + c
        for j in range(start[b], start[b + 1]):
            t = items[j]
            i0, i1, i2 = tris[t, 0], tris[t, 1], tris[t, 2]
            ax, ay = pts[i0, 0], pts[i0, 1]
            bx, by = pts[i1, 0], pts[i1, 1]
            cx, cy = pts[i2, 0], pts[i2, 1]
            det = (by - cy) * (ax - cx) + (cx - bx) * (ay - cy)
            if det == 0.0:
                continue
            l0 = ((by - cy) * (px - cx) + (cx - bx) * (py - cy)) / det
            l1 = ((cy - ay) * (px - cx) + (ax - cx) * (py - cy)) / det
            l2 = 1.0 - l0 - l1
            if l0 >= -1e-12 and l1 >= -1e-12 and l2 >= -1e-12:
                tri[k] = t
                bary[k, 0] = l0
                bary[k, 1] = l1
                bary[k, 2] = l2
                break
    return tri, bary


@njit(cache=True)
def _rasterise(pts, tris, z, x0, y0, cell, nx, ny):  # pragma: no cover - compiled
    out = np.full((ny, nx), np.nan)
    for t in range(tris.shape[0]):
        i0, i1, i2 = tris[t, 0], tris[t, 1], tris[t, 2]
        ax, ay = pts[i0, 0], pts[i0, 1]
        bx, by = pts[i1, 0], pts[i1, 1]
        cx, cy = pts[i2, 0], pts[i2, 1]
        det = (by - cy) * (ax - cx) + (cx - bx) * (ay - cy)
        if det == 0.0:
            continue
        c_lo = max(0, int(np.ceil((min(ax, bx, cx) - x0) / cell)))
        c_hi = min(nx - 1, int(np.floor((max(ax, bx, cx) - x0) / cell)))
        r_lo = max(0, int(np.ceil((min(ay, by, cy) - y0) / cell)))
        r_hi = min(ny - 1, int(np.floor((max(ay, by, cy) - y0) / cell)))
        for r in range(r_lo, r_hi + 1):
            py = y0 + r * cell
            for c in range(c_lo, c_hi + 1):
                px = x0 + c * cell
                l0 = ((by - cy) * (px - cx) + (cx - bx) * (py - cy)) / det
                l1 = ((cy - ay) * (px - cx) + (ax - cx) * (py - cy)) / det
                l2 = 1.0 - l0 - l1
                # a node on a shared edge is inside both triangles; both give the same value
                if l0 >= -1e-12 and l1 >= -1e-12 and l2 >= -1e-12:
                    out[r, c] = l0 * z[i0] + l1 * z[i1] + l2 * z[i2]
    return out


@dataclass(frozen=True)
class RasterSurface:
    """A height raster looked up bilinearly: cell centres at ``origin + (i, j) * cell``.

    ``grid`` has shape (rows, cols), row index along Y, column along X.
    Positions outside take the nearest edge value.
    """

    grid: np.ndarray
    origin: tuple[float, float]
    cell: float

    def __call__(self, xy: np.ndarray) -> np.ndarray:
        """Z at (X, Y), (..., 2) -> (...,) float64."""
        xy = np.asarray(xy, float)
        c = (xy[..., 0] - self.origin[0]) / self.cell
        r = (xy[..., 1] - self.origin[1]) / self.cell
        h, w = self.grid.shape
        c = np.clip(c, 0, w - 1)
        r = np.clip(r, 0, h - 1)
        c0 = np.minimum(np.floor(c).astype(np.intp), w - 2) if w > 1 else np.zeros(c.shape, np.intp)
        r0 = np.minimum(np.floor(r).astype(np.intp), h - 2) if h > 1 else np.zeros(r.shape, np.intp)
        fc, fr = c - c0, r - r0
        g = self.grid
        c1, r1 = np.minimum(c0 + 1, w - 1), np.minimum(r0 + 1, h - 1)
        return ((g[r0, c0] * (1 - fc) + g[r0, c1] * fc) * (1 - fr)
                + (g[r1, c0] * (1 - fc) + g[r1, c1] * fc) * fr)


def roof_surface(tin: Tin, bounds: tuple[float, float, float, float], cell: float = 0.25,
                 radius: float = 1.0) -> RasterSurface:
    """The TIN rasterised on ``bounds`` and dilated so that eaves carry the roof height.

    Parameters
    ----------
    tin : Tin
    bounds : (xmin, ymin, xmax, ymax)
        Area to cover (m).
    cell : float, default 0.25
        Raster cell (m); the snake uses about the image GSD.
    radius : float, default 1.0
        Radius (m) of the disk of the grey-scale maximum filter; 0 gives the
        plain TIN.  About 1.5 point spacings covers the blended band.

    Returns
    -------
    RasterSurface
        Heights (m); cells outside the TIN's hull take the nearest value
        inside.

    Notes
    -----
    The dilation raises a sloped roof's eave by at most ``radius * tan(slope)``
    (0.6 m for 1 m and 30 deg); in the image that is a relief shift of
    0.6 m * r / H (r the distance from nadir, H the flying height), a few
    centimetres for usual blocks, far less than the blend of a plain TIN.
    """
    if cell <= 0 or radius < 0:
        raise ValueError(f"cell must be > 0 and radius >= 0, got cell={cell}, radius={radius}")
    xmin, ymin, xmax, ymax = bounds
    nx = max(2, int(np.ceil((xmax - xmin) / cell)) + 1)
    ny = max(2, int(np.ceil((ymax - ymin) / cell)) + 1)
    z = tin.grid(xmin, ymin, cell, nx, ny)
    nan = np.isnan(z)
    if nan.all():
        raise GeometryError("no LiDAR points under the area of the seeds")
    if nan.any():
        idx = ndimage.distance_transform_edt(nan, return_distances=False, return_indices=True)
        z = z[tuple(idx)]
    k = int(round(radius / cell))
    if k > 0:
        yy, xx = np.mgrid[-k:k + 1, -k:k + 1]
        z = ndimage.maximum_filter(z, footprint=(xx * xx + yy * yy) <= k * k, mode="nearest")
    return RasterSurface(z, (float(xmin), float(ymin)), float(cell))


def _inward_bisectors(ring: np.ndarray) -> np.ndarray:
    """Unit vectors (n, 2) from each vertex into the polygon along the corner's bisector."""
    prev = np.roll(ring, 1, axis=0)
    nxt = np.roll(ring, -1, axis=0)
    area2 = np.sum(ring[:, 0] * nxt[:, 1] - nxt[:, 0] * ring[:, 1])
    sign = 1.0 if area2 > 0 else -1.0  # counter-clockwise: interior on the left
    u_in = ring - prev
    u_out = nxt - ring
    u_in /= np.maximum(np.linalg.norm(u_in, axis=1, keepdims=True), 1e-12)
    u_out /= np.maximum(np.linalg.norm(u_out, axis=1, keepdims=True), 1e-12)
    left = lambda u: sign * np.column_stack([-u[:, 1], u[:, 0]])  # noqa: E731
    b = left(u_in) + left(u_out)  # sum of the two inward side normals
    n = np.linalg.norm(b, axis=1, keepdims=True)
    # a 180 deg spike has no bisector: fall back to the incoming side's normal
    return np.where(n > 1e-9, b / np.maximum(n, 1e-12), left(u_in))


def vertex_heights(tin: Tin, ring: np.ndarray, offset: float, fallback: RasterSurface | None = None,
                   max_relief: float = 1.0) -> np.ndarray:
    """Roof height (m) at each vertex of a ring, extrapolated from inside the roof.

    Parameters
    ----------
    tin : Tin
        TIN of all points (roof and ground).
    ring : ndarray of shape (n, 2)
        Polygon vertices (X, Y), open ring, either orientation.
    offset : float
        Step (m) of the samples along the inward bisector, at 1 to 5 steps
        from the corner; about one point spacing.
    fallback : RasterSurface, optional
        Used where fewer than one clean sample remains.
    max_relief : float, default 1.0
        Samples whose TIN triangle spans more than this height range (m)
        straddle the eave (roof and ground vertices) and are left out, with
        every sample before them (ground when the vertex lies outside).

    Returns
    -------
    ndarray of shape (n,)
        Intercept at the corner of the least-squares line z(t) through the
        clean samples (their value when only one is clean): exact on planar
        roof faces.

    Examples
    --------
    >>> g = np.mgrid[0:20:0.5, 0:20:0.5].reshape(2, -1).T
    >>> z = np.where((g > 5).all(axis=1) & (g < 15).all(axis=1), 10.0 + 0.5 * g[:, 0], 0.0)
    >>> ring = np.array([[5.0, 5.0], [15.0, 5.0], [15.0, 15.0], [5.0, 15.0]])
    >>> vertex_heights(Tin(np.column_stack([g, z])), ring, 0.7).round(3)
    array([12.5, 17.5, 17.5, 12.5])
    """
    ring = np.asarray(ring, float)
    if not offset > 0:
        raise ValueError(f"offset must be > 0, got {offset}")
    b = _inward_bisectors(ring)
    t = offset * np.arange(1.0, 5.01, 0.5)
    pts = ring[:, None, :] + t[None, :, None] * b[:, None, :]  # (n, 5, 2)
    z = tin(pts.reshape(-1, 2)).reshape(len(ring), len(t))
    relief = tin.relief(pts.reshape(-1, 2)).reshape(z.shape)
    clean = np.isfinite(z) & (relief <= max_relief)
    # a vertex a little outside the roof starts on clean *ground* triangles:
    # keep only the clean samples beyond the last blended one (the roof side)
    blended = np.isfinite(z) & ~clean
    last = np.where(blended.any(axis=1), len(t) - 1 - np.argmax(blended[:, ::-1], axis=1), -1)
    clean &= np.arange(len(t))[None, :] > last[:, None]
    out = np.full(len(ring), np.nan)
    for i in range(len(ring)):
        k = clean[i]
        if k.sum() >= 2:
            slope, icpt = np.polyfit(t[k], z[i, k], 1)
            out[i] = icpt
        elif k.sum() == 1:
            out[i] = z[i, k][0]
    bad = ~np.isfinite(out)
    if bad.any() and fallback is not None:
        out[bad] = fallback(ring[bad])
    return out
