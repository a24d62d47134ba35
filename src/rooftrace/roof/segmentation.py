"""Roof plane segmentation: :func:`segment_planes`.

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

The helpers below keep the regions' bookkeeping, reassign points, merge
coplanar regions and rescue small planes by RANSAC.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numba
import numpy as np
from numba import njit
from scipy.spatial import cKDTree

from rooftrace.errors import GeometryError
from rooftrace.graph import components
from rooftrace.lidar.neighbours import GridKnn
from rooftrace.roof.planes import (
    PlaneFit,
    fit_planes,
    hull_area_test,
    neighbourhood_normals,
    plan_hull_area,
    plan_hull_areas,
    plane_height,
)

__all__ = ["Neighbourhoods", "point_neighbourhoods", "segment_planes", "detail_planes"]

log = logging.getLogger(__name__)


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
    K = int(labels.max()) + 1 if len(labels) and labels.max() >= 0 else 0
    n = np.bincount(labels[labels >= 0], minlength=K)
    ok = n >= 2 * min_pts
    measured = ~ok & (n >= max(6, 0.4 * min_pts))
    if not measured.any():
        return ok
    areas = plan_hull_areas(xy, np.where(measured[np.maximum(labels, 0)] & (labels >= 0), labels, -1), K)
    for k in np.flatnonzero(measured):
        ok[k] = hull_area_test(xy[labels == k], areas[k], lambda a: a >= min_area, False)
    return ok


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Row-wise cross product of (M, 3) arrays: ``np.cross``'s products and differences, without its
    per-call axis handling (the RANSAC of :func:`_rescue` calls it for every candidate plane)."""
    return np.column_stack([u[:, 1] * v[:, 2] - u[:, 2] * v[:, 1], u[:, 2] * v[:, 0] - u[:, 0] * v[:, 2],
                            u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]])


def _heights(P: np.ndarray, origin: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Height (m) at the points ``P`` of the plane through ``origin`` with the (unnormalised) ``normal``."""
    return origin[2] - ((P[:, 0] - origin[0]) * normal[0] + (P[:, 1] - origin[1]) * normal[1]) / normal[2]


@njit(cache=True)
def _consensus(P, origin, normal, distance):  # pragma: no cover - compiled
    """Points of ``P`` within ``distance`` in height of each sampled plane (the count per plane).

    The height is :func:`_heights`' expression, operation for operation
    (the (points x planes) array it replaced held every residual).
    """
    count = np.zeros(len(origin), np.int64)
    for t in range(len(origin)):
        x0, y0, z0 = origin[t, 0], origin[t, 1], origin[t, 2]
        a, b, c = normal[t, 0], normal[t, 1], normal[t, 2]
        for p in range(len(P)):
            z = z0 - ((P[p, 0] - x0) * a + (P[p, 1] - y0) * b) / c
            if abs(z - P[p, 2]) <= distance:
                count[t] += 1
    return count


def _rescue(xyz, labels, distance, link, min_area, min_pts, max_slope, trials: int = 64, per_cluster: int = 3,
            min_density: float = 0.5):
    """Planes among the unassigned points: seeded RANSAC per 3D cluster.

    Clusters are connected within ``link`` m; in each, up to ``per_cluster``
    planes are taken, best inlier count first: the largest plan-connected
    set of inliers (height residual under ``distance``) with a plan hull of
    ``min_area``, at least ``min_density`` times the mean density
    (``min_pts / min_area``), an RMS under ``distance / 2`` and a slope under
    ``max_slope``.  Deterministic (fixed seed).
    """
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
        for _ in range(per_cluster):
            if len(idx) < floor:
                break
            P = xyz[idx]
            tri = rng.integers(0, len(P), (trials, 3))
            # no part of points whose plan hull is under min_area can pass the area test below: the search
            # would end there (drawn first, so the random stream and every later cluster stay the same)
            if plan_hull_area(P) < min_area - 1e-6 * max(min_area, 1.0):
                break
            v1, v2 = P[tri[:, 1]] - P[tri[:, 0]], P[tri[:, 2]] - P[tri[:, 0]]
            n = _cross(v1, v2)
            nz = np.abs(n[:, 2])
            ok = nz > 1e-9
            if not ok.any():
                break
            origin, normal = P[tri[ok, 0]], n[ok]
            best = int(np.argmax(_consensus(P, origin, normal, distance)))
            inl = np.abs(_heights(P, origin[best], normal[best]) - P[:, 2]) <= distance
            for _ in range(3):  # LS refinement of the consensus set
                f, fitted = fit_planes(P[inl], np.zeros(int(inl.sum()), dtype=np.int64), 1), inl
                if not np.isfinite(f.planes[0]).all():
                    break
                inl = np.abs(plane_height(f.planes[0], P[:, :2]) - P[:, 2]) <= distance
                if np.array_equal(inl, fitted):
                    break  # a refit of the same points gives the same plane and inliers
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
            n_in = inl.sum()

            def spans(a, n_in=n_in):  # a plane of min_area, at least min_density of the mean density
                return not (a < min_area or n_in < min_density * a * min_pts / min_area)

            if not hull_area_test(P[inl], plan_hull_area(P[inl]), spans, False):
                break
            if not np.array_equal(inl, fitted):
                f = fit_planes(P[inl], np.zeros(int(inl.sum()), dtype=np.int64), 1)
            if not f.sigma[0] <= distance / 2:
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


def _grown(xyz, nn, labels, planes, tol):
    """``labels`` with every unassigned point on its best candidate plane (:func:`_best_candidate`).

    Only the unassigned points are evaluated (a few per cent of a roof):
    their own labels come first in the label array the kernel reads, the
    neighbours' after them.
    """
    un = np.flatnonzero(labels < 0)
    out = labels.copy()
    if len(un):
        out[un] = _best_candidate(xyz[un], nn[un] + len(un), np.concatenate([labels[un], labels]), planes, tol)
    return out


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


@njit(cache=True)
def _graph_edges(xyz, normals, rms, planar, nn):  # pragma: no cover - compiled
    """Candidate edges of the region graph: (i, j) for every neighbour j of i, both planar, i != j.

    Returns i, j, the cosine of their normals' angle, the larger distance
    of each point to the other's tangent plane and the larger RMS.  The
    products are summed in the order of the ``einsum`` it replaced (on
    (3·N·k) gathered arrays), so the values are identical.
    """
    n, k = nn.shape
    m = 0
    for p in range(n):
        if planar[p]:
            for q in range(k):
                if nn[p, q] != p and planar[nn[p, q]]:
                    m += 1
    i = np.empty(m, np.int64)
    j = np.empty(m, np.int64)
    cosang = np.empty(m)
    off = np.empty(m)
    worst = np.empty(m)
    m = 0
    for p in range(n):
        if not planar[p]:
            continue
        for q in range(k):
            b = nn[p, q]
            if b == p or not planar[b]:
                continue
            i[m] = p
            j[m] = b
            dx, dy, dz = xyz[b, 0] - xyz[p, 0], xyz[b, 1] - xyz[p, 1], xyz[b, 2] - xyz[p, 2]
            # numpy's einsum adds a 3-vector's products as (x + z) + y (two SIMD lanes)
            cosang[m] = (normals[p, 0] * normals[b, 0] + normals[p, 2] * normals[b, 2]) + normals[p, 1] * normals[b, 1]
            oi = (normals[p, 0] * dx + normals[p, 2] * dz) + normals[p, 1] * dy
            oj = (normals[b, 0] * dx + normals[b, 2] * dz) + normals[b, 1] * dy
            off[m] = max(abs(oi), abs(oj))
            worst[m] = max(rms[p], rms[b])
            m += 1
    return i, j, cosang, off, worst


@njit(cache=True)
def _adjacent_labels(labels, point_pairs, K):  # pragma: no cover - compiled
    """The distinct label pairs (i < j) of the point pairs, (P, 2) in (i, j) order (``np.unique`` of their keys)."""
    seen = np.zeros((K, K), np.bool_)
    count = 0
    for p in range(len(point_pairs)):
        a, b = labels[point_pairs[p, 0]], labels[point_pairs[p, 1]]
        if a >= 0 and b >= 0 and a != b:
            lo, hi = min(a, b), max(a, b)
            if not seen[lo, hi]:
                seen[lo, hi] = True
                count += 1
    out = np.empty((count, 2), np.int64)
    t = 0
    for i in range(K):
        for j in range(i + 1, K):
            if seen[i, j]:
                out[t, 0] = i
                out[t, 1] = j
                t += 1
    return out


def _merge_coplanar(xyz, labels, fit, angle_deg, tol, plan_pairs):
    """Union adjacent labels whose planes agree.

    ``plan_pairs`` (P, 2) are the point pairs within the link distance in
    plan, over all the points: found once per building, the labelled ones
    are taken each round.
    """
    K = len(fit.planes)
    if K * K <= 1 << 22:
        pairs = _adjacent_labels(np.ascontiguousarray(labels, dtype=np.int64), plan_pairs, K)
    else:  # too many planes for a K x K table
        a, b = labels[plan_pairs[:, 0]], labels[plan_pairs[:, 1]]
        m = (a >= 0) & (b >= 0) & (a != b)
        key = np.unique(np.minimum(a[m], b[m]) * K + np.maximum(a[m], b[m]))
        pairs = np.stack([key // K, key % K], axis=1)
    if not len(pairs):
        return labels, False
    cosang = np.abs(np.einsum("ij,ij->i", fit.planes[pairs[:, 0], :3], fit.planes[pairs[:, 1], :3]))
    close = np.flatnonzero(cosang >= np.cos(np.radians(angle_deg)))
    ok = np.zeros(len(pairs), dtype=bool)
    if len(close):
        # Coplanar when one plane fits both regions about as well as each
        # fits its own (a narrow region's own plane extrapolates badly, so
        # testing each region against the other's plane is not enough).
        # All candidate pairs are fitted in one call, each pair's points in
        # point order: the sums, and so the planes, are those of one call per pair.
        order = np.argsort(labels, kind="stable")
        bounds = np.searchsorted(labels[order], np.arange(K + 1))
        members = [np.sort(np.concatenate([order[bounds[i]:bounds[i + 1]], order[bounds[j]:bounds[j + 1]]]))
                   for i, j in pairs[close]]
        joint = fit_planes(xyz[np.concatenate(members)],
                           np.repeat(np.arange(len(close)), [len(x) for x in members]), len(close))
        si, sj = fit.sigma[pairs[close, 0]], fit.sigma[pairs[close, 1]]
        # min(1.3 max(si, sj), tol) with Python's min and max (a NaN sigma as they treat it)
        worst = 1.3 * np.where(sj > si, sj, si)
        ok[close] = joint.sigma <= np.where(tol < worst, tol, worst)
    if not ok.any():
        return labels, False
    comp = components(K, pairs[ok])
    out = np.where(labels >= 0, comp[np.maximum(labels, 0)], -1)
    _, out_c = np.unique(out, return_inverse=True)
    out_c = out_c.reshape(out.shape) - (1 if (out < 0).any() else 0)
    return out_c, True


def _two_neighbourhoods(xyz: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The k and the min(2k, N) nearest neighbours of every point, as ``cKDTree(xyz).query`` gives them.

    The 2k nearest come from the plan-grid search (:class:`GridKnn`, the
    tree's neighbours in the tree's order, three times as fast on roofs);
    the rows where it sees two of the 2k + 1 nearest distances tie, whose
    order follows the tree's traversal, are asked from the tree.  The first
    k of the 2k neighbours are the k nearest unless distances tie within
    them (duplicate points, a grid); the order of tied neighbours depends
    on the query's k, so those points are queried again with k and the
    result equals two separate tree queries.
    """
    n = len(xyz)
    m = min(2 * k, n)
    if n > m:
        threads = numba.get_num_threads()
        # one thread (this thread's setting only): a building's few thousand rows
        # cost 60 % more CPU time on two threads, which mostly wait for each other
        numba.set_num_threads(1)
        try:
            wide, tie = GridKnn(xyz, m).query(np.arange(n))
        finally:
            numba.set_num_threads(threads)
        rows = np.flatnonzero(tie)
    else:  # every point is every point's neighbour: the tree's order throughout
        wide, rows = np.empty((n, m), np.int64), np.arange(n)
    nn = wide[:, :k].copy()
    if len(rows):
        tree = cKDTree(xyz)
        dist, again = tree.query(xyz[rows], k=m)
        dist, wide[rows] = dist.reshape(len(rows), -1), again.reshape(len(rows), -1)
        nn[rows] = wide[rows, :k]
        tied = rows[(np.diff(dist[:, : k + 1], axis=1) <= 0).any(axis=1)]  # within the k, or the k-th with the next
        if len(tied):
            _, again = tree.query(xyz[tied], k=k)
            nn[tied] = again.reshape(-1, k)
    return nn, wide


@dataclass(frozen=True)
class Neighbourhoods:
    """The nearest neighbours of one building's points, found once for both segmentation passes.

    Attributes
    ----------
    near : ndarray of shape (N, k), int64
        The ``k = min(k, N)`` nearest points of every point, itself first
        (normals and the region graph).
    wide : ndarray of shape (N, min(2 k, N)), int64
        The ``2 k`` nearest: the candidate planes of growing and reassignment.
    """

    near: np.ndarray
    wide: np.ndarray

    def check(self, n: int, k: int) -> None:
        """Raise ValueError unless these are the neighbourhoods of ``n`` points with ``k`` neighbours."""
        k = int(min(k, n))
        if self.near.shape != (n, k) or self.wide.shape != (n, min(2 * k, n)):
            raise ValueError(f"neighbourhoods of shape {self.near.shape} and {self.wide.shape} are not those of "
                             f"{n} points with k={k}")


def point_neighbourhoods(xyz: np.ndarray, k: int = 16) -> Neighbourhoods:
    """The ``k`` and ``2 k`` nearest neighbours (3D) of every point, for :func:`segment_planes` and :func:`detail_planes`.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), float64
        One building's roof points (m).
    k : int
        Neighbours (capped at N).

    Returns
    -------
    Neighbourhoods

    Examples
    --------
    >>> xyz = np.random.default_rng(0).uniform(0, 10, (100, 3))
    >>> nb = point_neighbourhoods(xyz, 8)
    >>> nb.near.shape, nb.wide.shape, bool((nb.near[:, 0] == np.arange(100)).all())
    ((100, 8), (100, 16), True)
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    near, wide = _two_neighbourhoods(xyz, int(min(k, len(xyz))))
    return Neighbourhoods(near, wide)


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
    neighbourhoods: Neighbourhoods | None = None,
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
    neighbourhoods : Neighbourhoods, optional
        :func:`point_neighbourhoods` of ``xyz`` with ``k``, when the caller
        has them (they are found here otherwise).

    Returns
    -------
    labels : ndarray of shape (N,), int64
        Plane index per point, ``-1`` unassigned (chimneys, walls, noise).
    fit : PlaneFit
    distance : float
        The distance tolerance used (m).
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    N = len(xyz)
    min_pts = max(int(np.ceil(min_area / spacing**2)), 6)
    if min_pts > N:
        raise GeometryError(f"{N} points, fewer than the {min_pts} of one plane of {min_area} m²")
    if neighbourhoods is None:
        neighbourhoods = point_neighbourhoods(xyz, k)
    neighbourhoods.check(N, k)
    nn, nn_c = neighbourhoods.near, neighbourhoods.wide
    normals, rms, nn = neighbourhood_normals(xyz, nn)
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
    i, j, cosang, off, worst = _graph_edges(xyz, normals, rms, planar, np.ascontiguousarray(nn, dtype=np.int64))
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
    plan_pairs = cKDTree(xyz[:, :2]).query_pairs(link, output_type="ndarray")

    def refine(labels, rounds):
        for it in range(rounds):
            fit = fit_planes(xyz, labels)
            # Grow into unassigned points first (ridge zones), then let every
            # point choose among its neighbours' planes.
            for _ in range(3):
                new = _grown(xyz, nn_c, labels, fit.planes, distance)
                if np.array_equal(new, labels):
                    break
                labels = new
            labels = _best_candidate(xyz, nn_c, labels, fit.planes, distance, margin=distance / 3)
            labels = _compact(labels, _big_enough(xyz[:, :2], labels, min_area, min_pts))
            if labels.max() < 0:
                raise GeometryError("no roof plane kept after refinement")
            fit = fit_planes(xyz, labels)
            labels, merged = _merge_coplanar(xyz, labels, fit, merge_angle, distance, plan_pairs)
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


def detail_planes(
    xyz: np.ndarray,
    labels: np.ndarray,
    spacing: float,
    *,
    distance: float,
    min_area: float = 0.5,
    k: int = 16,
    max_slope: float = 75.0,
    link: float | None = None,
    neighbourhoods: Neighbourhoods | None = None,
) -> np.ndarray:
    """A second pass of the segmentation: small planes among the points left on no plane.

    The region graph of :func:`segment_planes` needs planar neighbourhoods of
    ``k`` points, which a chimney top or a dormer cheek of a square metre
    does not have, and it drops regions under its ``min_area``.  Here RANSAC
    per 3D cluster of the leftover points (up to 8 planes each, the
    segmentation's rescue step) takes the planes the leftovers support, then
    each new plane grows into its unassigned neighbours.  Points already on
    a plane keep it, and only the new planes are candidates while growing:
    a main plane does not creep along its extension into the leftovers.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), float64
        One building's roof points (m).
    labels : ndarray of shape (N,), int
        The planes of :func:`segment_planes`, ``-1`` for none.
    spacing : float
        Mean point spacing ``s`` (m).
    distance : float
        Largest height residual (m) of a point to its plane (the one
        :func:`segment_planes` returned).
    min_area : float
        Smallest new plane (m², plan hull of its points); it must also hold
        ``min_pts = max(8, min_area / s²)`` points at a density of at least
        ``min_pts / (4 min_area)`` (a quarter of the mean density ``1 / s²``
        when that is over ``16 pts/m²``), so at low density only planes that
        carry 8 points are found.
    k : int
        Neighbours (``2 k`` are candidates while growing, as in
        :func:`segment_planes`).
    max_slope : float
        Steeper planes (deg) are walls and are not taken.
    link : float, optional
        3D distance (m) linking leftover points into clusters; default ``2.5 s``.
    neighbourhoods : Neighbourhoods, optional
        :func:`point_neighbourhoods` of ``xyz`` with ``k`` (those of
        :func:`segment_planes`), when the caller has them.

    Returns
    -------
    ndarray of shape (N,), int64
        ``labels`` with the new planes numbered after the old ones.

    Examples
    --------
    >>> from rooftrace.roof.models import flat_annex, sample_roof
    >>> xyz, face = sample_roof(flat_annex(chimney=True), density=12, noise=0.03, seed=1)
    >>> labels, fit, tol = segment_planes(xyz, 0.29)
    >>> int(labels.max()) + 1, int(detail_planes(xyz, labels, 0.29, distance=tol).max()) + 1
    (2, 3)
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    labels = np.asarray(labels, dtype=np.int64)
    if xyz.ndim != 2 or xyz.shape[1] != 3 or len(labels) != len(xyz):
        raise ValueError(f"detail_planes: xyz {xyz.shape} and labels {labels.shape} do not match")
    if not spacing > 0 or not distance > 0 or not min_area > 0:
        raise ValueError(f"detail_planes: spacing, distance and min_area must be > 0, got {spacing}, {distance}, "
                         f"{min_area}")
    link = link or 2.5 * spacing
    min_pts = max(8, int(np.ceil(min_area / spacing**2)))
    first = int(labels.max()) + 1
    # A quarter of the mean density, not the rescue's half: a lower roof
    # part seen by one strip only (scan lines a metre apart) is a plane too;
    # the RMS test still keeps scattered clutter out.
    labels, added = _rescue(xyz, labels, distance, link, min_area, min_pts, max_slope, per_cluster=8,
                            min_density=0.25)
    if not added:
        return labels
    fit = fit_planes(xyz, labels)
    planes = fit.planes.copy()
    planes[:first] = np.nan
    # only the unassigned points can grow a plane: their neighbours, not
    # every point's (a city block has 10^5 points and a few hundred left over)
    un = np.flatnonzero(labels < 0)
    if neighbourhoods is None:
        _, nn = cKDTree(xyz).query(xyz[un], k=min(2 * k, len(xyz)))
        nn = nn.reshape(len(un), -1)
    else:
        neighbourhoods.check(len(xyz), k)
        nn = neighbourhoods.wide[un]
    nn = nn + len(un)  # into [the unassigned points' own labels, every label]
    for _ in range(3):
        grow = _best_candidate(xyz[un], nn, np.concatenate([labels[un], labels]), planes, distance)
        grow = np.where(labels[un] < 0, grow, labels[un])
        if np.array_equal(grow, labels[un]):
            break
        labels = labels.copy()
        labels[un] = grow
    # Grown, a plane may tilt past the walls' slope or fit worse than the
    # tolerance: its points stay on none.  A new plane whose points a main
    # plane explains within twice the tolerance is a strip of that plane the
    # first pass missed (rough tiles, the edge of a ridge zone), not a
    # superstructure: dropped too, the main plane's face covers it.
    fit = fit_planes(xyz, labels)
    bad = ~np.isfinite(fit.planes).all(axis=1) | (fit.planes[:, 2] < np.cos(np.radians(max_slope)))
    bad |= ~(fit.sigma <= distance)
    for j in np.flatnonzero(~bad[first:]) + first:
        P = xyz[labels == j]
        off = P[:, 2:3] - plane_height(fit.planes[:first], P[:, :2])
        bad[j] = bool(np.sqrt(np.mean(off**2, axis=0)).min() <= 2 * distance) if first else False
    bad[:first] = False
    if bad.any():
        labels = _compact(labels, ~bad)
    log.debug("detail pass: %d planes of %g m² or more", int(labels.max()) + 1 - first, min_area)
    return labels
