"""Roof plane segmentation and least-squares plane fits with their precision.

The segmentation is region growing on normals done as a graph problem: every
point is linked to its k nearest neighbours when both neighbourhoods are
planar, their normals agree and each lies on the other's local plane; the
connected components of that graph (union-find, numbered as by
``scipy.sparse.csgraph``) are the seed regions.  Regions then go through
rounds of least-squares refit and reassignment of every point to the best
plane among its neighbours' planes, which pulls the points near ridges (whose
neighbourhoods straddle two planes and so were left out of the graph) onto
the right plane.  Coplanar adjacent regions are merged and regions smaller
than ``min_area`` are dropped.

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
from rooftrace.roof._planefit import _normal_sums, _residual_sums

__all__ = [
    "PlaneFit",
    "estimate_spacing",
    "point_normals",
    "fit_planes",
    "plane_height",
    "segment_planes",
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
    return _pca_normals(xyz, nn.reshape(len(xyz), k))


def _pca_normals(xyz: np.ndarray, nn: np.ndarray):
    """:func:`point_normals` from given neighbour indices (N, k)."""
    k = nn.shape[1]
    nb = xyz[nn]
    nb = nb - nb.mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", nb, nb) / k
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
    labels = np.asarray(labels)
    K = int(labels.max()) + 1 if n_planes is None else int(n_planes)
    lab = np.ascontiguousarray(labels, dtype=np.int64)
    if len(lab) and lab.max() >= K:
        raise ValueError(f"fit_planes: labels up to {int(lab.max())} but n_planes={K}")
    # Centred design [x', y', 1]: well conditioned whatever the CRS offsets.
    # The sums per label are compiled (rooftrace.roof._planefit), in point order.
    n, centre, N, u = _normal_sums(xyz, lab, K)
    good = n >= 3
    # A singular N means collinear points: no plane.
    good &= np.abs(np.linalg.det(N[:, :2, :2])) > 1e-9 * np.maximum(N[:, 0, 0] * N[:, 1, 1], 1e-30)
    Ninv = np.full((K, 3, 3), np.nan)
    if good.any():
        Ninv[good] = np.linalg.inv(N[good])
    pqr = np.einsum("kij,kj->ki", Ninv, u)
    rss = _residual_sums(xyz, lab, centre, pqr)
    dof = np.maximum(n - 3, 1)
    sigma = np.sqrt(rss / dof)
    sigma[~good] = np.nan
    cov = Ninv * (sigma**2)[:, None, None]
    p, q, r = pqr.T
    norm = np.sqrt(1 + p * p + q * q)
    d = p * centre[:, 0] + q * centre[:, 1] - r
    planes = np.stack([-p, -q, np.ones_like(p), d], axis=1) / norm[:, None]
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


def _two_neighbourhoods(tree: cKDTree, xyz: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The k and the min(2k, N) nearest neighbours of every point, from one k-d tree query.

    The first k of the 2k neighbours are the k nearest unless distances tie
    within them (duplicate points, a grid); the order of tied neighbours
    depends on the query's k, so those points are queried again with k and
    the result equals two separate queries.  One query instead of two saved
    a third of the normal estimation.
    """
    n = len(xyz)
    dist, wide = tree.query(xyz, k=min(2 * k, n))
    dist, wide = dist.reshape(n, -1), wide.reshape(n, -1)
    nn = wide[:, :k].copy()
    tied = (np.diff(dist[:, : k + 1], axis=1) <= 0).any(axis=1)  # within the k, or the k-th with the next
    if tied.any():
        _, again = tree.query(xyz[tied], k=k)
        nn[tied] = again.reshape(-1, k)
    return nn, wide


def segment_planes(
    xyz: np.ndarray,
    spacing: float,
    *,
    k: int = 16,
    normal_angle: float = 10.0,
    max_local_rms: float | None = None,
    distance: float | None = None,
    min_area: float = 2.0,
    merge_angle: float = 5.0,
    iterations: int = 4,
    max_slope: float = 75.0,
    link: float | None = None,
) -> tuple[np.ndarray, PlaneFit, float]:
    """Segment a building's points into roof planes.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), float64
        One building's roof points (m).
    spacing : float
        Mean point spacing ``s`` (m).
    k : int
        Neighbours for normals and the region graph.
    normal_angle : float
        Largest angle (deg) between the normals of two linked points.
    max_local_rms : float, optional
        Largest neighbourhood RMS (m) for a point to seed a region.  Default
        ``2 * median(rms)`` over the building: twice the typical planar
        neighbourhood noise.
    distance : float, optional
        Largest height residual (m) of a point to its plane.  Default
        ``max(3 * sigma_n, 0.05)`` with ``sigma_n = median(rms) * sqrt(k / (k - 3))``
        the height noise estimated from the planar neighbourhoods.
    min_area : float
        Smallest plane kept (m², convex hull of its points in plan).
    merge_angle : float
        Adjacent regions whose normals differ by less (deg) are merged when
        one plane fits both with an RMS under ``min(1.3 max(sigma_i, sigma_j),
        distance)``.
    iterations : int
        Rounds of refit and reassignment.
    max_slope : float
        Regions and planes steeper than this (deg) are walls, not roof planes:
        their points stay unassigned.
    link : float, optional
        Plan distance (m) within which points of two regions make them
        neighbours for merging; default ``2.5 s``.

    Returns
    -------
    labels : ndarray of shape (N,), int64
        Plane index per point, ``-1`` unassigned (chimneys, walls, noise).
    fit : PlaneFit
    distance : float
        The distance tolerance used (m).
    """
    from rooftrace.graph import components
    from rooftrace.roof._regions import _best_candidate, _big_enough, _compact, _merge_coplanar, _rescue

    xyz = np.asarray(xyz, dtype=np.float64)
    N = len(xyz)
    min_pts = max(int(np.ceil(min_area / spacing**2)), 6)
    if min_pts > N:
        raise GeometryError(f"{N} points, fewer than the {min_pts} of one plane of {min_area} m²")
    tree = cKDTree(xyz)
    nn, nn_c = _two_neighbourhoods(tree, xyz, int(min(k, N)))
    normals, rms, nn = _pca_normals(xyz, nn)
    kk = nn.shape[1]
    med = float(np.median(rms))
    noise = med * np.sqrt(kk / max(kk - 3, 1))
    if max_local_rms is None:
        max_local_rms = 2.0 * med
    if distance is None:
        distance = max(3.0 * noise, 0.05)
    planar = rms <= max_local_rms
    # Edges of the region graph: both ends planar, normals within the angle,
    # each point on the other's tangent plane.
    i = np.repeat(np.arange(N), kk)
    j = nn.ravel()
    keep = (i != j) & planar[i] & planar[j]
    i, j = i[keep], j[keep]
    cosang = np.einsum("ij,ij->i", normals[i], normals[j])
    off = np.maximum(
        np.abs(np.einsum("ij,ij->i", normals[i], xyz[j] - xyz[i])),
        np.abs(np.einsum("ij,ij->i", normals[j], xyz[j] - xyz[i])),
    )
    worst = np.maximum(rms[i], rms[j])
    e = (cosang >= np.cos(np.radians(normal_angle))) & (off <= distance)
    # Connected components are single linkage: a chain of points with
    # bending normals can join two planes across a gentle crease.  A
    # component whose plane fit is noisier than the points is cut again with
    # stricter edges (tighter angle, flatter neighbourhoods), down to 3 levels.
    for level in range(4):
        comp = components(N, np.column_stack([i[e], j[e]]))
        comp = np.where(planar, comp, -1)
        w = (comp >= 0).astype(float)
        size = np.bincount(np.maximum(comp, 0), weights=w)
        # Walls: the mean normal of the region is close to horizontal.
        nz = np.bincount(np.maximum(comp, 0), weights=w * normals[:, 2]) / np.maximum(size, 1)
        steep = nz < np.cos(np.radians(max_slope))
        comp = _compact(comp, ~steep & (size >= max(6, 0.4 * min_pts)))
        labels = _compact(comp, _big_enough(xyz[:, :2], comp, min_area, min_pts))
        if labels.max() < 0 or level == 3:
            break
        fit = fit_planes(xyz, labels)
        bad = fit.sigma > 1.5 * noise
        if not bad.any():
            break
        in_bad = np.zeros(N, dtype=bool)
        in_bad[labels >= 0] = bad[labels[labels >= 0]]
        f = 0.7 ** (level + 1)
        strict = (cosang >= np.cos(np.radians(normal_angle * f))) & (worst <= med * (1 + f))
        e &= ~(in_bad[i] | in_bad[j]) | strict
    log.debug("region graph: %d seeds from %d points (noise %.3f m, tol %.3f m)", labels.max() + 1, N, noise, distance)
    if labels.max() < 0:
        raise GeometryError("no planar region large enough for a roof plane")

    # Candidate planes for growing and reassignment come from a wider
    # neighbourhood (2k): on scan-line patterns the k nearest points of a
    # point can all lie on its own line, which may be wholly unassigned.
    link = link or 2.5 * spacing

    def refine(labels, rounds):
        for it in range(rounds):
            fit = fit_planes(xyz, labels)
            # Grow into unassigned points first (ridge zones), then let every
            # point choose among its neighbours' planes.
            for _ in range(3):
                grow = _best_candidate(xyz, nn_c, labels, fit.planes, distance)
                new = np.where(labels < 0, grow, labels)
                if np.array_equal(new, labels):
                    break
                labels = new
            labels = _best_candidate(xyz, nn_c, labels, fit.planes, distance, margin=distance / 3)
            labels = _compact(labels, _big_enough(xyz[:, :2], labels, min_area, min_pts))
            if labels.max() < 0:
                raise GeometryError("no roof plane kept after refinement")
            fit = fit_planes(xyz, labels)
            labels, merged = _merge_coplanar(xyz, labels, fit, merge_angle, distance, link)
            if not merged and it >= 1:
                break
        return labels

    labels = refine(labels, iterations)
    # Small planes at low density (dormers) may have no planar neighbourhood
    # at all; look for them among the points left over.
    labels, added = _rescue(xyz, labels, distance, link, min_area, min_pts, max_slope)
    if added:
        labels = refine(labels, 2)
    fit = fit_planes(xyz, labels)
    bad = ~np.isfinite(fit.planes).all(axis=1) | (fit.planes[:, 2] < np.cos(np.radians(max_slope)))
    if bad.any():
        labels = _compact(labels, ~bad)
        fit = fit_planes(xyz, labels)
    return labels, fit, float(distance)
