"""Roof planes: least-squares plane fits with their precision, point normals, point spacing.

The segmentation of a roof's points into planes is
:func:`rooftrace.roof.segmentation.segment_planes`.

Planes are fitted as ``z = p (x - cx) + q (y - cy) + r`` by ordinary least
squares on heights: the ALS range error is close to vertical, so the height
residual is the one with a known variance.  The covariance of ``(p, q, r)``
is ``sigma^2 (A^T A)^-1``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from rooftrace.errors import GeometryError
from rooftrace.roof.plane_kernels import hull_areas, neighbourhood_covariances, normal_sums, plane_parameters

__all__ = [
    "PlaneFit",
    "estimate_spacing",
    "point_normals",
    "fit_planes",
    "plane_height",
    "neighbourhood_normals",
    "level_untilted",
    "with_horizontal_planes",
    "plan_hull_area",
    "plan_hull_areas",
    "hull_area_test",
]

log = logging.getLogger(__name__)


@dataclass
class PlaneFit:
    """Least-squares planes of labelled points.

    Attributes
    ----------
    planes : ndarray of shape (K, 4), float64
        ``(a, b, c, d)`` with ``a x + b y + c z + d = 0``, unit normal, ``c > 0``.
    pqr : ndarray of shape (K, 3), float64
        ``(p, q, r)`` of ``z = p (x - cx) + q (y - cy) + r``.
    centre : ndarray of shape (K, 2), float64
        ``(cx, cy)``, the centroid of each plane's points (m).
    cov : ndarray of shape (K, 3, 3), float64
        Covariance of ``(p, q, r)`` (slopes unitless, ``r`` in m).
    sigma : ndarray of shape (K,), float64
        RMS of the height residuals (m), with ``n - 3`` degrees of freedom.
    n : ndarray of shape (K,), int64
        Number of points per plane.
    """

    planes: np.ndarray
    pqr: np.ndarray
    centre: np.ndarray
    cov: np.ndarray
    sigma: np.ndarray
    n: np.ndarray


def estimate_spacing(xy: np.ndarray) -> float:
    """Mean point spacing ``s = sqrt(A / N)`` (m), ``A`` the convex hull area.

    For a regular grid of density ``d`` this is ``1 / sqrt(d)`` (0.289 m at
    12 pts/m²).
    """
    from scipy.spatial import ConvexHull, QhullError

    xy = np.asarray(xy, dtype=np.float64)[:, :2]
    if len(xy) < 3:
        raise GeometryError(f"cannot estimate the point spacing from {len(xy)} points")
    try:
        area = ConvexHull(xy).volume
    except QhullError:
        raise GeometryError("cannot estimate the point spacing: points are collinear") from None
    if not area > 0:
        raise GeometryError("cannot estimate the point spacing: zero hull area")
    return float(np.sqrt(area / len(xy)))


def plan_hull_areas(xy: np.ndarray, groups: np.ndarray, n_groups: int) -> np.ndarray:
    """Area (m²) of the plan convex hull of every group of points, all groups in one compiled call.

    Parameters
    ----------
    xy : ndarray of shape (N, 2+), float64
        Points (m); only x and y are read.
    groups : ndarray of shape (N,), int
        Group per point, ``-1`` for none.
    n_groups : int
        Number of groups.

    Returns
    -------
    ndarray of shape (n_groups,), float64
        0 for a group of fewer than 3 points or of collinear points.

    Examples
    --------
    >>> xy = np.array([[0, 0], [2, 0], [0, 2], [1, 1], [5, 5]], dtype=float)
    >>> plan_hull_areas(xy, np.array([0, 0, 0, 0, 1]), 3).tolist()
    [2.0, 0.0, 0.0]
    """
    groups = np.asarray(groups, dtype=np.int64)
    on = np.flatnonzero(groups >= 0)
    members = on[np.argsort(groups[on], kind="stable")]
    starts = np.searchsorted(groups[members], np.arange(int(n_groups) + 1))
    return hull_areas(np.asarray(xy, dtype=np.float64), members, starts)


def plan_hull_area(xy: np.ndarray) -> float:
    """Area (m²) of the plan convex hull of the points ``xy`` (N, 2+): :func:`plan_hull_areas` of one group."""
    xy = np.asarray(xy, dtype=np.float64)
    return float(hull_areas(xy, np.arange(len(xy)), np.array([0, len(xy)]))[0])


def hull_area_test(xy: np.ndarray, approx: float, test, degenerate: bool) -> bool:
    """``test(area)`` of the plan convex hull of ``xy`` as Qhull measures it, from an approximate area.

    ``test`` must be monotone in the area.  When it gives the same answer
    1e-6 (relative, at least 1e-6 m²) below and above ``approx`` (the same
    hull's area by :func:`plan_hull_areas`, within 1e-9 relative of
    Qhull's in national-grid coordinates), that is the answer; only near a
    threshold is the hull computed again by Qhull (whose area the
    thresholds were set with), so the answers are those of Qhull at a
    fraction of its cost.

    Parameters
    ----------
    xy : ndarray of shape (M, 2+), float64
        The points (m).
    approx : float
        Their hull's area (m²) by another method.
    test : callable
        Area (m²) -> bool, monotone.
    degenerate : bool
        The answer when Qhull finds no hull (collinear points).

    Returns
    -------
    bool
    """
    from scipy.spatial import ConvexHull, QhullError

    tol = 1e-6 * max(approx, 1.0)
    low, high = bool(test(approx - tol)), bool(test(approx + tol))
    if low == high:
        return low
    try:
        return bool(test(ConvexHull(np.asarray(xy, dtype=np.float64)[:, :2]).volume))
    except QhullError:
        return degenerate


def point_normals(xyz: np.ndarray, k: int = 16, tree: cKDTree | None = None):
    """Unit normals (``nz >= 0``) and local plane RMS from k-NN PCA.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3)
    k : int
        Neighbours including the point itself.

    Returns
    -------
    normals : ndarray of shape (N, 3)
    rms : ndarray of shape (N,)
        ``sqrt(lambda_3)``: RMS distance of the neighbours to their plane (m).
    neighbours : ndarray of shape (N, k), int64
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    k = int(min(k, len(xyz)))
    tree = cKDTree(xyz) if tree is None else tree
    _, nn = tree.query(xyz, k=k)
    return neighbourhood_normals(xyz, nn.reshape(len(xyz), k))


def neighbourhood_normals(xyz: np.ndarray, nn: np.ndarray):
    """:func:`point_normals` from given neighbour indices (N, k)."""
    cov = neighbourhood_covariances(np.ascontiguousarray(xyz, dtype=np.float64),
                                    np.ascontiguousarray(nn, dtype=np.int64))
    w, v = np.linalg.eigh(cov)  # ascending eigenvalues
    normals = v[:, :, 0]
    normals *= np.where(normals[:, 2] < 0, -1.0, 1.0)[:, None]
    return normals, np.sqrt(np.clip(w[:, 0], 0, None)), nn


def fit_planes(xyz: np.ndarray, labels: np.ndarray, n_planes: int | None = None) -> PlaneFit:
    """Fit ``z = p (x - cx) + q (y - cy) + r`` to the points of every label at once.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3)
    labels : ndarray of shape (N,), int
        Plane index per point, ``-1`` for none.
    n_planes : int, optional
        Number of planes K (default ``labels.max() + 1``).

    Returns
    -------
    PlaneFit
        Planes with fewer than 3 points or a singular design (collinear
        points) have NaN parameters.
    """
    xyz = np.ascontiguousarray(xyz, dtype=np.float64)
    lab = np.ascontiguousarray(labels, dtype=np.int64)
    top = int(lab.max()) if len(lab) else -1
    K = top + 1 if n_planes is None else int(n_planes)
    if top >= K:
        raise ValueError(f"fit_planes: labels up to {top} but n_planes={K}")
    # Centred design [x', y', 1]: well conditioned whatever the CRS offsets.
    # The sums per label are compiled (rooftrace.roof.plane_kernels), in point order.
    n, centre, N, u = normal_sums(xyz, lab, K)
    good = n >= 3
    # A singular N means collinear points: no plane.
    good &= np.abs(np.linalg.det(N[:, :2, :2])) > 1e-9 * np.maximum(N[:, 0, 0] * N[:, 1, 1], 1e-30)
    Ninv = np.full((K, 3, 3), np.nan)
    if good.any():
        Ninv[good] = np.linalg.inv(N[good])
    # the rest (solution, residuals, precision, the plane's normal form) in one compiled pass
    pqr, sigma, cov, planes = plane_parameters(xyz, lab, centre, Ninv, u, n, good)
    return PlaneFit(planes, pqr, centre[:, :2].copy(), cov, sigma, n)


def plane_height(planes: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Height of plane(s) at points: ``z = -(a x + b y + d) / c``.

    ``planes`` (K, 4) and ``xy`` (M, 2) give (M, K); matching leading shapes
    ``(..., 4)`` and ``(..., 2)`` give elementwise heights.
    """
    planes = np.asarray(planes, dtype=np.float64)
    xy = np.asarray(xy, dtype=np.float64)
    if planes.ndim == 2 and xy.ndim == 2 and planes.shape[0] != xy.shape[0]:
        return -(xy[:, :1] * planes[:, 0] + xy[:, 1:2] * planes[:, 1] + planes[:, 3]) / planes[:, 2]
    return -(xy[..., 0] * planes[..., 0] + xy[..., 1] * planes[..., 1] + planes[..., 3]) / planes[..., 2]


def level_untilted(xyz: np.ndarray, labels: np.ndarray, fit: PlaneFit, candidates: np.ndarray,
                   chi2: float = 9.21) -> PlaneFit:
    """The planes among ``candidates`` whose tilt their points do not support, made horizontal.

    A plane of a dozen points (a chimney top) has a slope error of a few
    degrees; when its fitted slopes ``(p, q)`` are within the 99 % ellipse
    of their covariance (``(p, q) C⁻¹ (p, q)ᵀ < chi2``, ``chi2(2)`` at 0.99
    = 9.21) it is taken as horizontal at its points' mean height, which is
    the least-squares horizontal plane.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3)
    labels : ndarray of shape (N,), int
        Plane per point, ``-1`` for none (the labels ``fit`` was made from).
    fit : PlaneFit
    candidates : ndarray of shape (K,), bool
        Planes that may be levelled.
    chi2 : float
        Threshold of the tilt's squared Mahalanobis norm.

    Returns
    -------
    PlaneFit
        A copy; levelled planes have ``p = q = 0``, ``r`` the mean height,
        ``sigma`` with ``n - 1`` degrees of freedom and only ``var(r) = sigma² / n``.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> xyz = np.column_stack([rng.uniform(0, 1, (12, 2)), 10 + rng.normal(0, 0.03, 12)])
    >>> lab = np.zeros(12, dtype=np.int64)
    >>> level_untilted(xyz, lab, fit_planes(xyz, lab), np.array([True])).planes.round(3).tolist()
    [[0.0, 0.0, 1.0, -9.997]]
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    labels = np.asarray(labels, dtype=np.int64)
    K = len(fit.planes)
    candidates = np.asarray(candidates, dtype=bool)
    if candidates.shape != (K,):
        raise ValueError(f"level_untilted: candidates has shape {candidates.shape}, expected ({K},)")
    pq = fit.pqr[:, :2]
    C = fit.cov[:, :2, :2]
    det = C[:, 0, 0] * C[:, 1, 1] - C[:, 0, 1] ** 2
    ok = candidates & np.isfinite(pq).all(axis=1) & np.isfinite(det) & (det > 0)
    t2 = np.full(K, np.inf)
    # (p, q) C^-1 (p, q)^T with the 2 x 2 inverse written out
    t2[ok] = (C[ok, 1, 1] * pq[ok, 0] ** 2 - 2 * C[ok, 0, 1] * pq[ok, 0] * pq[ok, 1]
              + C[ok, 0, 0] * pq[ok, 1] ** 2) / det[ok]
    flat = ok & (t2 < chi2)
    out = PlaneFit(fit.planes.copy(), fit.pqr.copy(), fit.centre.copy(), fit.cov.copy(), fit.sigma.copy(),
                   fit.n.copy())
    if not flat.any():
        return out
    on = labels >= 0
    n = np.bincount(labels[on], minlength=K).astype(np.float64)
    mean = np.bincount(labels[on], weights=xyz[on, 2], minlength=K) / np.maximum(n, 1)
    rss = np.bincount(labels[on], weights=(xyz[on, 2] - mean[labels[on]]) ** 2, minlength=K)
    sigma = np.sqrt(rss / np.maximum(n - 1, 1))
    out.pqr[flat] = np.column_stack([np.zeros(flat.sum()), np.zeros(flat.sum()), mean[flat]])
    out.planes[flat] = np.column_stack([np.zeros((flat.sum(), 2)), np.ones(flat.sum()), -mean[flat]])
    out.sigma[flat] = sigma[flat]
    out.cov[flat] = 0.0
    out.cov[flat, 2, 2] = sigma[flat] ** 2 / n[flat]
    return out


def with_horizontal_planes(xyz: np.ndarray, labels: np.ndarray, fit: PlaneFit, groups: list) -> tuple:
    """``labels`` and ``fit`` with each group of points a horizontal plane at its mean height, numbered after ``fit``'s.

    The least-squares horizontal plane of a flat block (a chimney's top, a
    terrace's floor): ``p = q = 0``, ``r`` the mean height, ``sigma`` with
    ``n - 1`` degrees of freedom and only ``var(r) = sigma² / n``.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3)
    labels : ndarray of shape (N,), int
        Plane per point, ``-1`` for none.
    fit : PlaneFit
        The planes of ``labels``.
    groups : list of ndarray of int
        Point indices of each new plane (disjoint, at least one point each).

    Returns
    -------
    labels : ndarray of shape (N,), int64
    fit : PlaneFit
    """
    K = len(fit.planes)
    labels = np.asarray(labels, dtype=np.int64).copy()
    n = np.array([len(b) for b in groups])
    mean = np.array([xyz[b, 2].mean() for b in groups])
    sigma = np.array([np.sqrt(np.sum((xyz[b, 2] - m) ** 2) / max(len(b) - 1, 1)) for b, m in zip(groups, mean)])
    for j, b in enumerate(groups):
        labels[b] = K + j
    cov = np.zeros((len(groups), 3, 3))
    cov[:, 2, 2] = sigma**2 / n
    zeros = np.zeros(len(groups))
    out = PlaneFit(
        np.vstack([fit.planes, np.column_stack([zeros, zeros, np.ones(len(groups)), -mean])]),
        np.vstack([fit.pqr, np.column_stack([zeros, zeros, mean])]),
        np.vstack([fit.centre, np.array([xyz[b, :2].mean(axis=0) for b in groups])]),
        np.concatenate([fit.cov, cov]),
        np.concatenate([fit.sigma, sigma]),
        np.concatenate([fit.n, n]).astype(fit.n.dtype),
    )
    return labels, out
