"""Compiled sums of :func:`rooftrace.roof.planes.fit_planes`.

The plane segmentation fits planes thousands of times per building (every
refinement round, every coplanar-merge candidate, every RANSAC refit), most
of them small; the ten ``np.bincount`` passes per fit cost more than the
arithmetic.  These loops add the same products in the same order (point
order, from 0.0, as ``np.bincount`` does), so the sums are identical.

The covariance of every point's neighbourhood (:func:`rooftrace.roof.planes.neighbourhood_normals`)
is summed here too, in the order of the numpy form it replaced (the mean
over the neighbours, then each product summed over them), which gathered
an (N, k, 3) array per building.

The kernels of :mod:`rooftrace.roof.planes`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from rooftrace.lidar.features import scatter_sums

__all__ = ["hull_areas", "neighbourhood_covariances", "normal_sums", "plane_parameters", "residual_sums"]


@njit(cache=True)
def normal_sums(xyz, labels, K):  # pragma: no cover - compiled
    """Counts (K,), centres (K, 3), normal matrices (K, 3, 3) and right-hand sides (K, 3).

    Design ``[x - cx, y - cy, 1]`` per label, ``-1`` labels skipped.
    """
    n = np.zeros(K, dtype=np.int64)
    s = np.zeros((K, 3))
    for p in range(len(labels)):
        lab = labels[p]
        if lab >= 0:
            n[lab] += 1
            s[lab, 0] += xyz[p, 0]
            s[lab, 1] += xyz[p, 1]
            s[lab, 2] += xyz[p, 2]
    centre = np.empty((K, 3))
    for lab in range(K):
        nf = max(n[lab], 1)
        for c in range(3):
            centre[lab, c] = s[lab, c] / nf
    N = np.zeros((K, 3, 3))
    u = np.zeros((K, 3))
    for p in range(len(labels)):
        lab = labels[p]
        if lab >= 0:
            dx = xyz[p, 0] - centre[lab, 0]
            dy = xyz[p, 1] - centre[lab, 1]
            z = xyz[p, 2]
            N[lab, 0, 0] += dx * dx
            N[lab, 0, 1] += dx * dy
            N[lab, 0, 2] += dx
            N[lab, 1, 1] += dy * dy
            N[lab, 1, 2] += dy
            N[lab, 2, 2] += 1.0
            u[lab, 0] += dx * z
            u[lab, 1] += dy * z
            u[lab, 2] += z
    for lab in range(K):
        N[lab, 1, 0] = N[lab, 0, 1]
        N[lab, 2, 0] = N[lab, 0, 2]
        N[lab, 2, 1] = N[lab, 1, 2]
    return n, centre, N, u


@njit(cache=True)
def residual_sums(xyz, labels, centre, pqr):  # pragma: no cover - compiled
    """Sum of squared height residuals per label, (K,)."""
    rss = np.zeros(len(pqr))
    for p in range(len(labels)):
        lab = labels[p]
        if lab >= 0:
            dx = xyz[p, 0] - centre[lab, 0]
            dy = xyz[p, 1] - centre[lab, 1]
            res = xyz[p, 2] - (pqr[lab, 0] * dx + pqr[lab, 1] * dy + pqr[lab, 2])
            rss[lab] += res * res
    return rss


@njit(cache=True)
def plane_parameters(xyz, labels, centre, Ninv, u, n, good):  # pragma: no cover - compiled
    """``(p, q, r)`` (K, 3), sigma (K,), covariance (K, 3, 3) and ``(a, b, c, d)`` (K, 4) of the fits.

    The numpy expressions they replaced, operation for operation: the
    solution ``Ninv u`` summed as ``einsum`` sums three products, ``(0 + 2) + 1``;
    the residuals in point order; ``sqrt(rss / max(n - 3, 1))``, NaN for a
    plane that is not ``good``; ``Ninv sigma²``; ``(-p, -q, 1, p cx + q cy - r)``
    over ``sqrt(1 + p² + q²)``.
    """
    K = len(n)
    pqr = np.empty((K, 3))
    for k in range(K):
        for i in range(3):
            pqr[k, i] = (Ninv[k, i, 0] * u[k, 0] + Ninv[k, i, 2] * u[k, 2]) + Ninv[k, i, 1] * u[k, 1]
    rss = residual_sums(xyz, labels, centre, pqr)
    sigma = np.empty(K)
    cov = np.empty((K, 3, 3))
    planes = np.empty((K, 4))
    for k in range(K):
        sigma[k] = np.sqrt(rss[k] / max(n[k] - 3, 1)) if good[k] else np.nan
        s2 = sigma[k] * sigma[k]
        for i in range(3):
            for j in range(3):
                cov[k, i, j] = Ninv[k, i, j] * s2
        p, q, r = pqr[k, 0], pqr[k, 1], pqr[k, 2]
        norm = np.sqrt(1 + p * p + q * q)
        d = p * centre[k, 0] + q * centre[k, 1] - r
        planes[k, 0] = -p / norm
        planes[k, 1] = -q / norm
        planes[k, 2] = 1.0 / norm
        planes[k, 3] = d / norm
    return pqr, sigma, cov, planes


@njit(cache=True)
def neighbourhood_covariances(xyz, nn):  # pragma: no cover - compiled
    """Covariance (N, 3, 3) of every point's neighbours ``nn`` (N, k) about their mean, divided by k."""
    n, k = nn.shape
    cov = np.empty((n, 3, 3))
    for p in range(n):
        xx, yy, zz, xy, xz, yz = scatter_sums(xyz, nn[p], k)
        cov[p, 0, 0], cov[p, 1, 1], cov[p, 2, 2] = xx / k, yy / k, zz / k
        cov[p, 0, 1] = cov[p, 1, 0] = xy / k
        cov[p, 0, 2] = cov[p, 2, 0] = xz / k
        cov[p, 1, 2] = cov[p, 2, 1] = yz / k
    return cov


@njit(cache=True)
def hull_areas(xy, members, starts):  # pragma: no cover - compiled
    """Plan convex hull area of each group, the points ``members[starts[g]:starts[g + 1]]`` of ``xy``.

    Andrew's monotone chain on coordinates relative to the group's first
    point (national-grid offsets would cost digits); 0 for fewer than 3
    points or collinear points.
    """
    n_groups = len(starts) - 1
    areas = np.zeros(n_groups)
    for g in range(n_groups):
        idx = members[starts[g]:starts[g + 1]]
        m = len(idx)
        if m < 3:
            continue
        x = np.empty(m)
        y = np.empty(m)
        for t in range(m):
            x[t] = xy[idx[t], 0] - xy[idx[0], 0]
            y[t] = xy[idx[t], 1] - xy[idx[0], 1]
        by_y = np.argsort(y, kind="mergesort")
        order = by_y[np.argsort(x[by_y], kind="mergesort")]  # by x, then y
        hull = np.empty(2 * m, np.int64)
        h = 0
        for t in range(m):  # lower chain
            q = order[t]
            while h >= 2 and ((x[hull[h - 1]] - x[hull[h - 2]]) * (y[q] - y[hull[h - 2]])
                              - (y[hull[h - 1]] - y[hull[h - 2]]) * (x[q] - x[hull[h - 2]])) <= 0.0:
                h -= 1
            hull[h] = q
            h += 1
        low = h + 1
        for t in range(m - 2, -1, -1):  # upper chain
            q = order[t]
            while h >= low and ((x[hull[h - 1]] - x[hull[h - 2]]) * (y[q] - y[hull[h - 2]])
                                - (y[hull[h - 1]] - y[hull[h - 2]]) * (x[q] - x[hull[h - 2]])) <= 0.0:
                h -= 1
            hull[h] = q
            h += 1
        a = 0.0
        for t in range(h - 1):  # the last vertex repeats the first
            a += x[hull[t]] * y[hull[t + 1]] - x[hull[t + 1]] * y[hull[t]]
        areas[g] = abs(a) / 2.0
    return areas
