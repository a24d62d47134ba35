"""Helpers of the plane segmentation: region bookkeeping, reassignment,
coplanar merging and the RANSAC rescue of small planes.

Private to :mod:`rooftrace.roof.planes`; see :func:`~rooftrace.roof.planes.segment_planes`.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from scipy.spatial import cKDTree

from rooftrace.graph import components
from rooftrace.roof.planes import fit_planes, plane_height

__all__: list[str] = []


def _compact(labels: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Relabel kept labels 0..K'-1 in order, others -1."""
    mapping = np.full(len(keep) + 1, -1, dtype=np.int64)
    mapping[:-1][keep] = np.arange(int(keep.sum()))
    return mapping[labels]  # labels == -1 reads mapping[-1] == -1


def _big_enough(xy: np.ndarray, labels: np.ndarray, min_area: float, min_pts: int) -> np.ndarray:
    """Labels whose plan hull covers ``min_area`` (m²).

    The area comes from the convex hull of the region's points rather than
    from its point count, which depends on the local density (scan-line
    gaps, occlusion).  Regions with at least ``2 min_pts`` points are large
    anyway; regions under ``0.4 min_pts`` (or 6) points are too small anyway.
    """
    from scipy.spatial import ConvexHull, QhullError

    K = int(labels.max()) + 1 if len(labels) and labels.max() >= 0 else 0
    n = np.bincount(labels[labels >= 0], minlength=K)
    ok = n >= 2 * min_pts
    for k in np.flatnonzero(~ok & (n >= max(6, 0.4 * min_pts))):
        try:
            ok[k] = ConvexHull(xy[labels == k]).volume >= min_area
        except QhullError:
            pass
    return ok


def _rescue(xyz, labels, distance, link, min_area, min_pts, max_slope, trials: int = 64):
    """Planes among the unassigned points: seeded RANSAC per 3D cluster.

    Clusters are connected within ``link`` m; in each, up to three planes are
    taken, best inlier count first: the largest plan-connected set of inliers
    (height residual under ``distance``) with a plan hull of ``min_area``, at
    least half the mean density, an RMS under ``distance / 2`` and a slope
    under ``max_slope``.  Deterministic (fixed seed).
    """
    from scipy.spatial import ConvexHull, QhullError

    rng = np.random.default_rng(0)
    labels = labels.copy()
    floor = max(6, int(0.4 * min_pts))
    un = np.flatnonzero(labels < 0)
    if len(un) < floor:
        return labels, False
    ij = cKDTree(xyz[un]).query_pairs(link, output_type="ndarray")
    comp = components(len(un), ij)
    nxt, added = labels.max() + 1, False
    cos_max = np.cos(np.radians(max_slope))
    for c in np.flatnonzero(np.bincount(comp) >= floor):
        idx = un[comp == c]
        for _ in range(3):
            if len(idx) < floor:
                break
            P = xyz[idx]
            tri = rng.integers(0, len(P), (trials, 3))
            v1, v2 = P[tri[:, 1]] - P[tri[:, 0]], P[tri[:, 2]] - P[tri[:, 0]]
            n = np.cross(v1, v2)
            nz = np.abs(n[:, 2])
            ok = nz > 1e-9
            if not ok.any():
                break
            # Height residuals of every point to every sampled plane.
            zs = P[tri[ok, 0], 2][None, :] - (
                (P[:, :1] - P[tri[ok, 0], 0][None, :]) * n[ok, 0] + (P[:, 1:2] - P[tri[ok, 0], 1][None, :]) * n[ok, 1]
            ) / n[ok, 2]
            count = (np.abs(zs - P[:, 2:3]) <= distance).sum(axis=0)
            best = int(np.argmax(count))
            inl = np.abs(zs[:, best] - P[:, 2]) <= distance
            for _ in range(3):  # LS refinement of the consensus set
                f = fit_planes(P[inl], np.zeros(int(inl.sum()), dtype=np.int64), 1)
                if not np.isfinite(f.planes[0]).all():
                    break
                inl = np.abs(plane_height(f.planes[0], P[:, :2]) - P[:, 2]) <= distance
            if inl.sum() < floor or not np.isfinite(f.planes[0]).all() or f.planes[0, 2] < cos_max:
                break
            # Keep the largest plan-connected part of the consensus set, and
            # only a dense, well-fitting one (not scattered clutter).
            sub = np.flatnonzero(inl)
            pq = cKDTree(P[sub, :2]).query_pairs(link, output_type="ndarray")
            cc = components(len(sub), pq)
            inl = np.zeros(len(P), dtype=bool)
            inl[sub[cc == np.argmax(np.bincount(cc))]] = True
            if inl.sum() < floor:
                break
            try:
                area = ConvexHull(P[inl, :2]).volume
            except QhullError:
                break
            f = fit_planes(P[inl], np.zeros(int(inl.sum()), dtype=np.int64), 1)
            if area < min_area or inl.sum() < 0.5 * area * min_pts / min_area or not f.sigma[0] <= distance / 2:
                break
            labels[idx[inl]] = nxt
            nxt, added = nxt + 1, True
            idx = idx[~inl]
    return labels, added


def _best_candidate(xyz, nn, labels, planes, tol, margin=0.0):
    """For every point the label among its own and its neighbours' labels
    whose plane is closest in height; -1 when none is within ``tol``.

    A labelled point changes plane only when another is closer by more than
    ``margin`` (m): without this hysteresis a plane creeps along the line
    where its extension crosses another plane (two coplanar dormers would
    join along their common valley line).
    """
    # compiled: the vectorised form gathered an (N, 2k + 1, 4) array of planes
    # per call and dominated the plane segmentation (1.5 s of 8.5 s on Delft)
    return _best_candidate_kernel(np.ascontiguousarray(xyz, dtype=np.float64), np.ascontiguousarray(nn, dtype=np.int64),
                                  np.ascontiguousarray(labels, dtype=np.int64),
                                  np.ascontiguousarray(planes, dtype=np.float64), float(tol), float(margin))


@njit(cache=True, error_model="numpy")  # x / 0 gives inf, as in numpy
def _best_candidate_kernel(xyz, nn, labels, planes, tol, margin):  # pragma: no cover - compiled
    # the same float operations, in the same order, as the numpy form it
    # replaced (height -(a x + b y + d) / c, residual minus the margin for the
    # point's own label, first minimum wins), so the labels are identical
    n, k = nn.shape
    out = np.empty(n, dtype=np.int64)
    for p in range(n):
        x, y, zp = xyz[p, 0], xyz[p, 1], xyz[p, 2]
        best_r = np.inf
        best_j = 0
        for j in range(k + 1):
            c = labels[p] if j == 0 else labels[nn[p, j - 1]]
            r = np.inf
            if c >= 0:
                h = -(x * planes[c, 0] + y * planes[c, 1] + planes[c, 3]) / planes[c, 2]
                r = abs(h - zp)
                if not np.isfinite(r):
                    r = np.inf
            if j == 0:
                r -= margin
            if r < best_r:
                best_r = r
                best_j = j
        best = labels[p] if best_j == 0 else labels[nn[p, best_j - 1]]
        rb = best_r + margin if best_j == 0 else best_r + 0.0
        out[p] = best if rb <= tol else -1
    return out


def _merge_coplanar(xyz, labels, fit, angle_deg, tol, link):
    """Union adjacent labels (points within ``link`` m in plan) whose planes agree."""
    K = len(fit.planes)
    sel = np.flatnonzero(labels >= 0)
    ij = cKDTree(xyz[sel, :2]).query_pairs(link, output_type="ndarray")
    if len(ij) == 0:
        return labels, False
    a, b = labels[sel[ij[:, 0]]], labels[sel[ij[:, 1]]]
    m = a != b
    if not m.any():
        return labels, False
    key = np.unique(np.minimum(a[m], b[m]) * K + np.maximum(a[m], b[m]))
    pairs = np.stack([key // K, key % K], axis=1)
    cosang = np.abs(np.einsum("ij,ij->i", fit.planes[pairs[:, 0], :3], fit.planes[pairs[:, 1], :3]))
    close = cosang >= np.cos(np.radians(angle_deg))
    ok = np.zeros(len(pairs), dtype=bool)
    for idx in np.flatnonzero(close):
        i, j = pairs[idx]
        both = xyz[(labels == i) | (labels == j)]
        # Coplanar when one plane fits both regions about as well as each
        # fits its own (a narrow region's own plane extrapolates badly, so
        # testing each region against the other's plane is not enough).
        joint = fit_planes(both, np.zeros(len(both), dtype=np.int64))
        ok[idx] = joint.sigma[0] <= min(1.3 * max(fit.sigma[i], fit.sigma[j]), tol)
    if not ok.any():
        return labels, False
    comp = components(K, pairs[ok])
    out = np.where(labels >= 0, comp[np.maximum(labels, 0)], -1)
    _, out_c = np.unique(out, return_inverse=True)
    out_c = out_c.reshape(out.shape) - (1 if (out < 0).any() else 0)
    return out_c, True
