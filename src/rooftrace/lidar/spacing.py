"""Data-derived scale parameters of a point cloud: s_avg, d_avg and sigma_H.

The thesis (Santos 2019, §6.1, Table 6.1) derives every detection threshold
from three numbers: the mean point spacing s_avg (mean Delaunay edge length),
the mean density d_avg (pts/m²) and the height precision sigma_H (residual of a
planar fit).  The thesis picked a flat roof by hand for sigma_H; here planes
are fitted to small cells everywhere and the planar cells (the lower quartile
of the residuals: ground, roofs) give the estimate.
"""

from __future__ import annotations

import logging

import numpy as np
from scipy.spatial import Delaunay, QhullError, cKDTree

from rooftrace.lidar._kernels import column_max, column_min, dense_cells, unique_pairs

__all__ = ["edge_spacing", "mean_spacing", "point_density", "height_precision", "spanning_neighbours"]

log = logging.getLogger(__name__)


def _blocks(xy: np.ndarray, max_points: int) -> list[np.ndarray]:
    """Index arrays of a few square blocks of about ``max_points // 4`` points each.

    Subsampling at random would thin the cloud and lengthen the edges, so the
    spacing is measured on whole blocks instead, chosen deterministically (the
    most populated ones).
    """
    n = len(xy)
    if n <= max_points:
        return [np.arange(n)]
    lo, hi = column_min(xy), column_max(xy)
    area = max(float(np.prod(hi - lo)), 1e-9)
    per_block = max_points // 4
    side = np.sqrt(area * per_block / n)
    ij = np.floor((xy - lo) / side).astype(np.int64)
    inverse = dense_cells(ij)
    counts = np.bincount(inverse)
    # blocks holding about the mean population: the densest ones are tree
    # crowns with several returns per pulse, the sparsest ones slivers at
    # the grid's edge, fringe or water (ties: the first in (i, j) order)
    best = np.lexsort((np.arange(len(counts)), np.abs(counts - per_block)))[:4]
    return [np.flatnonzero(inverse == b) for b in best]


def _unique_rows(xy: np.ndarray) -> np.ndarray:
    """``np.unique(xy, axis=0)`` of finite (N, 2) floats: the distinct rows in (x, y) order, by one lexsort."""
    order = np.lexsort((xy[:, 1], xy[:, 0]))
    s = xy[order]
    keep = np.ones(len(s), bool)
    keep[1:] = (s[1:, 0] != s[:-1, 0]) | (s[1:, 1] != s[:-1, 1])
    return s[keep]


def _edge_lengths(xy: np.ndarray, max_points: int) -> np.ndarray:
    """Delaunay edge lengths (m) of the blocks of :func:`_blocks`, each without its edges over mean + 3 std."""
    xy = np.asarray(xy, dtype=np.float64)
    if xy.ndim != 2 or xy.shape[1] < 2:
        raise ValueError(f"xy must have shape (N, 2), got {xy.shape}")
    lengths = []
    for idx in _blocks(xy[:, :2], max_points):
        # Qhull loses points to round-off on large map coordinates: centre them
        pts = _unique_rows(np.round(xy[idx, :2] - column_min(xy[idx, :2]), 4))
        if len(pts) < 3:
            continue
        try:
            tri = Delaunay(pts)
        except QhullError:
            continue
        s = tri.simplices
        e = np.concatenate([s[:, [0, 1]], s[:, [1, 2]], s[:, [2, 0]]])
        e.sort(axis=1)
        e = unique_pairs(e[:, 0], e[:, 1], len(pts))
        ln = np.hypot(*(pts[e[:, 0]] - pts[e[:, 1]]).T)
        ln = ln[ln <= ln.mean() + 3 * ln.std()]
        lengths.append(ln)
    if not lengths:
        raise ValueError("mean spacing needs at least 3 points not on one line")
    return np.concatenate(lengths)


def mean_spacing(xy: np.ndarray, *, max_points: int = 60_000) -> float:
    """Mean point spacing s_avg: the mean length of the Delaunay edges.

    Parameters
    ----------
    xy : ndarray of shape (N, 2), float64
        Planimetric coordinates (m).
    max_points : int, default 60000
        Above this, the mean is taken over four square blocks holding about
        ``max_points / 4`` points each (the blocks of a grid closest to that population),
        so the cost stays bounded while the local density is untouched.

    Returns
    -------
    float
        s_avg in metres.  Duplicated (x, y) are merged first; edges longer
        than mean + 3 std of their block (the convex-hull fringe, gaps over
        water) are left out (Santos 2019, §6.1).

    Examples
    --------
    >>> g = np.stack(np.meshgrid(np.arange(20.0), np.arange(20.0)), -1).reshape(-1, 2)
    >>> 1.0 < mean_spacing(g) < 1.2
    True
    """
    return float(_edge_lengths(xy, max_points).mean())


def edge_spacing(xy: np.ndarray, quantile: float = 0.99, *, max_points: int = 60_000) -> tuple[float, float]:
    """s_avg and a high quantile of the Delaunay edge lengths (one triangulation).

    The quantile measures the widest common gaps of the sampling: on points
    scattered evenly it is about twice s_avg, where scan lines lie farther
    apart than the points along them it is the gap between the lines (an
    oscillating mirror's lines open to twice their mean spacing towards
    the swath edges).

    Parameters
    ----------
    xy : ndarray of shape (N, 2), float64
        Planimetric coordinates (m).
    quantile : float, default 0.99
    max_points : int, default 60000
        As :func:`mean_spacing`.

    Returns
    -------
    (float, float)
        s_avg (m, exactly :func:`mean_spacing`) and the quantile (m).

    Examples
    --------
    >>> x, y = np.meshgrid(np.arange(0, 30, 0.3), np.arange(0, 30, 2.0))
    >>> s, gap = edge_spacing(np.column_stack([x.ravel(), y.ravel()]))
    >>> round(gap, 2)
    2.02
    """
    lengths = _edge_lengths(xy, max_points)
    return float(lengths.mean()), float(np.quantile(lengths, quantile))


def point_density(xy: np.ndarray, cell: float = 2.0) -> float:
    """Mean density d_avg (pts/m²) over the occupied area.

    Parameters
    ----------
    xy : ndarray of shape (N, 2), float64
        Planimetric coordinates (m).
    cell : float, default 2.0
        Side (m) of the grid cells; the area is the number of cells holding
        at least one point times ``cell²``, so gaps (water, outside an
        irregular survey) do not dilute the density.

    Returns
    -------
    float
        Points per square metre.

    Examples
    --------
    >>> g = np.stack(np.meshgrid(np.arange(0, 10, 0.5), np.arange(0, 10, 0.5)), -1).reshape(-1, 2)
    >>> round(point_density(g), 1)
    4.0
    """
    xy = np.asarray(xy, dtype=np.float64)
    if len(xy) == 0:
        raise ValueError("point density of an empty cloud")
    ij = np.floor((xy[:, :2] - column_min(xy[:, :2])) / cell).astype(np.int64)
    cells = int(dense_cells(ij).max()) + 1
    return float(len(xy) / (cells * cell * cell))


def height_precision(
    xyz: np.ndarray, cell: float | None = None, *, min_points: int | None = None, quantile: float = 0.25,
    floor: float = 0.01, max_cell: float = 1.5,
) -> float:
    """Height precision sigma_H from least-squares planes fitted to small cells.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), float64
        Coordinates (m).
    cell : float, optional
        Cell side (m).  Default ``sqrt(20 / d_avg)``, so a cell holds about 20
        points, but at most ``max_cell``.
    min_points : int, optional
        Cells with fewer points are not fitted.  Default: 0.4 of the mean
        number of points a cell holds, within [4, 8].
    max_cell : float, default 1.5
        Largest default cell (m): the cells must be small against roof
        faces and yards, or most of them straddle an edge.  At 2 pts/m² a
        cell of 20 points is 3.2 m wide, and on Delft (AHN3) thinned to
        2 pts/m² sigma_H came out 0.49 m instead of about 0.03 m (1.5 m
        cells: 0.035 m; full density: unchanged, its cells are 1.15 m).
    quantile : float, default 0.25
        sigma_H is this quantile of the per-cell RMS residuals of
        ``z = a x + b y + c``: cells on planes (ground, roofs) have the low
        residuals, those on trees and edges the high ones.
    floor : float, default 0.01
        Lower bound (m), for quantised or synthetic noise-free data.

    Returns
    -------
    float
        sigma_H in metres.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> p = rng.uniform(0, 30, (9000, 3)); p[:, 2] = 0.3 * p[:, 0] + rng.normal(0, 0.05, 9000)
    >>> 0.04 < height_precision(p) < 0.06
    True
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    density = point_density(xyz[:, :2])
    if cell is None:
        cell = min(float(np.sqrt(20.0 / density)), max_cell)
    if min_points is None:
        # three points fit any plane: at least one degree of freedom left
        min_points = int(np.clip(round(0.4 * density * cell * cell), 4, 8))
    lo = column_min(xyz)
    ij = np.floor((xyz[:, :2] - lo[:2]) / cell).astype(np.int64)
    inv = dense_cells(ij)
    counts = np.bincount(inv)
    # centre each cell so the normal equations stay well conditioned
    centre = np.stack([np.bincount(inv, xyz[:, k]) / counts for k in range(3)], axis=1)
    d = xyz - centre[inv]
    x, y, z = d.T
    m = len(counts)
    sxx, sxy, syy = (np.bincount(inv, v, m) for v in (x * x, x * y, y * y))
    sxz, syz, szz = (np.bincount(inv, v, m) for v in (x * z, y * z, z * z))
    det = sxx * syy - sxy**2
    ok = (counts >= min_points) & (det > 1e-12 * np.maximum(sxx * syy, 1e-30))
    if not ok.any():
        raise ValueError("height precision: no cell holds enough points for a plane fit")
    a = np.where(ok, (sxz * syy - syz * sxy) / np.where(ok, det, 1), 0)
    b = np.where(ok, (syz * sxx - sxz * sxy) / np.where(ok, det, 1), 0)
    # residual sum of squares of the centred fit (the intercept is zero)
    rss = szz - a * sxz - b * syz
    dof = np.maximum(counts - 3, 1)
    rms = np.sqrt(np.maximum(rss, 0) / dof)[ok]
    sigma = float(np.quantile(rms, quantile))
    log.debug("sigma_H %.3f m from %d cells of %.2f m", sigma, len(rms), cell)
    return max(sigma, floor)


def spanning_neighbours(xy: np.ndarray, density: float, *, width: float = 0.3, share: float = 0.9,
                        max_neighbours: int = 64, sample: int = 5000) -> int:
    """Smallest neighbourhood size that reaches across the scan lines for most points.

    Scanners lay points in lines; where the lines lie farther apart than the
    points along them (low-density and older surveys, oscillating mirrors
    towards the swath edges) the k nearest neighbours of a point all lie on
    its own line when k is small: they fit no plane, their normal turns
    freely about the line.  A neighbourhood reaches the next line when its
    plan extent across its long axis (the standard deviation along the
    minor axis of its plan covariance) is at least ``width``/sqrt(d_avg),
    a share of the isotropic point spacing.

    Parameters
    ----------
    xy : ndarray of shape (N, 2), float64
        Planimetric coordinates (m).
    density : float
        d_avg (pts/m²), :func:`point_density`.
    width : float, default 0.3
        Smallest minor-axis standard deviation, in units of 1/sqrt(d_avg).
    share : float, default 0.9
        Share of the points whose neighbourhood must reach that width.
    max_neighbours : int, default 64
        Largest size returned.
    sample : int, default 5000
        Points measured (every n-th point; the neighbours come from all).

    Returns
    -------
    int
        k.  On AHN3 and LiDAR HD 9-11, on random points 8-9, on simulated
        zigzag scans 15 (lines converge at the swath edges), 20-27 for
        lines 4-9 times farther apart than the points along them.

    Examples
    --------
    >>> x, y = np.meshgrid(np.arange(0, 40, 0.25), np.arange(0, 40, 2.0))
    >>> lines = np.column_stack([x.ravel(), y.ravel()])
    >>> spanning_neighbours(lines, point_density(lines)) > 12
    True
    """
    xy = np.asarray(xy, dtype=np.float64)[:, :2]
    n = len(xy)
    if n < 4 or not density > 0:
        return 3
    local = xy - column_min(xy)
    q = np.arange(0, n, max(1, n // sample))
    _, idx = cKDTree(local).query(local[q], k=min(max_neighbours, n))
    p = local[idx] - local[q][:, None, :]
    m = np.arange(1, p.shape[1] + 1)
    # plan moments of the growing neighbourhood, all sizes at once
    mx, my = np.cumsum(p[..., 0], axis=1) / m, np.cumsum(p[..., 1], axis=1) / m
    sxx = np.cumsum(p[..., 0] ** 2, axis=1) / m - mx**2
    syy = np.cumsum(p[..., 1] ** 2, axis=1) / m - my**2
    sxy = np.cumsum(p[..., 0] * p[..., 1], axis=1) / m - mx * my
    minor = (sxx + syy) / 2 - np.sqrt(((sxx - syy) / 2) ** 2 + sxy**2)
    reach = np.sqrt(np.maximum(np.quantile(minor, 1.0 - share, axis=0), 0.0))
    ok = np.flatnonzero(reach >= width / np.sqrt(density))
    return int(m[ok[0]]) if len(ok) else int(m[-1])
