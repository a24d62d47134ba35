"""Building versus vegetation by mean eigen-entropy and 1-D k-means (Santos et al. 2019b; thesis §3.4).

For each point the covariance of its N nearest neighbours gives
lambda1 >= lambda2 >= lambda3; linearity L = (l1 - l2)/l1, planarity
P = (l2 - l3)/l1, sphericity S = l3/l1 and entropy E = -L ln L - P ln P - S ln S
(eq. 3.6-3.9).  A cluster's entropy is the mean over its points (eq. 3.5);
k-means with k = 2 on the clusters' entropies splits buildings (low) from
vegetation (high).

Guards the thesis does not need on its test scenes:

- k-means always splits, even a scene of only buildings or only trees.  When
  the two centroids are closer than ``min_gap`` there is one population, and
  the fixed threshold ``fallback_entropy`` decides instead; the k-means
  threshold is also kept inside ``[entropy_floor, entropy_ceiling]``, so that
  clusters clearly planar are always buildings and clearly volumetric never.
- Linear clusters (power lines, fences): mean linearity above
  ``max_linearity`` are never buildings.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import ClassVar

import numba
import numpy as np
from scipy.spatial import cKDTree

__all__ = ["ClassifyOptions", "eigen_features", "cluster_means", "kmeans_1d", "separate_buildings"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ClassifyOptions:
    """Options of the building/vegetation separation (TOML table ``[classify]``).

    Attributes
    ----------
    neighbours : int or None
        N, neighbours of the covariance; ``None``: ``Ar_min·d_avg``
        (thesis §3.4), clipped to ``[10, max_neighbours]``.
    max_neighbours : int, default 60
        Upper bound of the derived N (cost grows linearly with it).
    min_gap : float, default 0.15
        Smallest distance between the two k-means centroids (entropy units,
        0..ln 3) for the split to be trusted.
    fallback_entropy : float, default 0.8
        Fixed threshold used when the scene holds one population.
    entropy_floor : float, default 0.6
        Clusters with a lower mean entropy are always buildings.
    entropy_ceiling : float, default 0.95
        Clusters with a higher mean entropy are never buildings.
    max_linearity : float, default 0.7
        Clusters with a higher mean linearity are linear objects (power lines).
    boundary : {'zscore', 'midpoint'}, default 'zscore'
        Where the threshold sits between the two k-means centroids c0 < c1:
        ``'midpoint'`` (c0 + c1)/2, the plain k-means rule (thesis); ``'zscore'``
        (c0·s1 + c1·s0)/(s0 + s1) with s0, s1 the classes' standard
        deviations, equally many deviations from both centroids.
    max_penetration : float or None, default 0.5
        Beyond the thesis: clusters where more than this fraction of points
        are not the last return of their pulse are not buildings (the laser
        went through them: hedges, crowns trimmed flat).  Used only when the
        file has return numbers; ``None`` disables it.
    building_penetration : float, default 0.6
        A whole building (its roof levels merged) is dropped when its
        fraction of non-last returns exceeds
        ``max_penetration · building_penetration``.
    """

    section: ClassVar[str] = "classify"
    neighbours: int | None = None
    max_neighbours: int = 60
    min_gap: float = 0.15
    fallback_entropy: float = 0.8
    entropy_floor: float = 0.6
    entropy_ceiling: float = 0.95
    max_linearity: float = 0.7
    boundary: str = "zscore"
    max_penetration: float | None = 0.5
    building_penetration: float = 0.6

    def __post_init__(self) -> None:
        if self.boundary not in ("zscore", "midpoint"):
            raise ValueError(f"classify.boundary must be 'zscore' or 'midpoint', got {self.boundary!r}")
        if self.neighbours is not None and self.neighbours < 4:
            raise ValueError(f"classify.neighbours must be >= 4, got {self.neighbours}")
        if self.max_neighbours < 4:
            raise ValueError(f"classify.max_neighbours must be >= 4, got {self.max_neighbours}")
        if not self.entropy_floor <= self.fallback_entropy <= self.entropy_ceiling:
            raise ValueError(
                "classify: need entropy_floor <= fallback_entropy <= entropy_ceiling, got "
                f"{self.entropy_floor}, {self.fallback_entropy}, {self.entropy_ceiling}"
            )
        if not 0 < self.max_linearity <= 1:
            raise ValueError(f"classify.max_linearity must be in (0, 1], got {self.max_linearity}")


@numba.njit(cache=True, parallel=False, fastmath=False)
def _features(xyz: np.ndarray, idx: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover - compiled
    n, k = idx.shape
    for i in range(n):
        mx = my = mz = 0.0
        for j in range(k):
            p = idx[i, j]
            mx += xyz[p, 0]
            my += xyz[p, 1]
            mz += xyz[p, 2]
        mx /= k
        my /= k
        mz /= k
        a = b = c = d = e = f = 0.0
        for j in range(k):
            p = idx[i, j]
            dx = xyz[p, 0] - mx
            dy = xyz[p, 1] - my
            dz = xyz[p, 2] - mz
            a += dx * dx
            b += dy * dy
            c += dz * dz
            d += dx * dy
            e += dx * dz
            f += dy * dz
        # eigenvalues of the symmetric 3x3 matrix [[a d e] [d b f] [e f c]] (trigonometric method)
        q = (a + b + c) / 3.0
        p1 = d * d + e * e + f * f
        p2 = (a - q) ** 2 + (b - q) ** 2 + (c - q) ** 2 + 2.0 * p1
        if p2 <= 1e-30 * max(q * q, 1e-300):
            l1 = l2 = l3 = q
        else:
            pp = np.sqrt(p2 / 6.0)
            ba = (a - q) / pp
            bb = (b - q) / pp
            bc = (c - q) / pp
            bd = d / pp
            be = e / pp
            bf = f / pp
            r = (ba * (bb * bc - bf * bf) - bd * (bd * bc - bf * be) + be * (bd * bf - bb * be)) / 2.0
            r = min(max(r, -1.0), 1.0)
            phi = np.arccos(r) / 3.0
            l1 = q + 2.0 * pp * np.cos(phi)
            l3 = q + 2.0 * pp * np.cos(phi + 2.0 * np.pi / 3.0)
            l2 = 3.0 * q - l1 - l3
        if l1 <= 0.0:
            out[i, 0] = 0.0
            out[i, 1] = 0.0
            out[i, 2] = 1.0
            continue
        l3 = max(l3, 0.0)
        l2 = min(max(l2, l3), l1)
        out[i, 0] = (l1 - l2) / l1
        out[i, 1] = (l2 - l3) / l1
        out[i, 2] = l3 / l1


@numba.njit(cache=True)
def _normals(xyz: np.ndarray, idx: np.ndarray, kn: int, out: np.ndarray) -> None:  # pragma: no cover - compiled
    n = idx.shape[0]
    for i in range(n):
        mx = my = mz = 0.0
        for j in range(kn):
            p = idx[i, j]
            mx += xyz[p, 0]
            my += xyz[p, 1]
            mz += xyz[p, 2]
        mx /= kn
        my /= kn
        mz /= kn
        c = np.zeros((3, 3))
        for j in range(kn):
            p = idx[i, j]
            v0 = xyz[p, 0] - mx
            v1 = xyz[p, 1] - my
            v2 = xyz[p, 2] - mz
            c[0, 0] += v0 * v0
            c[1, 1] += v1 * v1
            c[2, 2] += v2 * v2
            c[0, 1] += v0 * v1
            c[0, 2] += v0 * v2
            c[1, 2] += v1 * v2
        c[1, 0] = c[0, 1]
        c[2, 0] = c[0, 2]
        c[2, 1] = c[1, 2]
        w, v = np.linalg.eigh(c)
        nx, ny, nz = v[0, 0], v[1, 0], v[2, 0]
        if nz < 0:
            nx, ny, nz = -nx, -ny, -nz
        out[i, 0] = nx
        out[i, 1] = ny
        out[i, 2] = nz


def eigen_features(
    xyz: np.ndarray, neighbours: int, *, normal_neighbours: int | None = None, chunk: int = 100_000
) -> np.ndarray:
    """Linearity, planarity, sphericity and entropy of each point's neighbourhood.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), float64
        Points (m); neighbours are searched among these points.
    neighbours : int
        N, the neighbourhood size (the point itself included).
    chunk : int, default 100000
        Points per KD-tree query, to bound memory.

    normal_neighbours : int, optional
        When given, the unit normal (upward) of the plane fitted to the
        ``normal_neighbours`` nearest points is returned too (a smaller
        neighbourhood than N keeps roof ridges sharp).

    Returns
    -------
    ndarray of shape (N, 4) or (N, 7), float64
        Columns L, P, S (each in [0, 1], summing to 1), E (in [0, ln 3]),
        then nx, ny, nz when ``normal_neighbours`` is given.

    Examples
    --------
    >>> g = np.stack(np.meshgrid(np.arange(10.0), np.arange(10.0)), -1).reshape(-1, 2)
    >>> f = eigen_features(np.column_stack([g, np.zeros(100)]), 9)
    >>> bool(np.all(f[:, 2] < 1e-9))
    True
    """
    xyz = np.ascontiguousarray(xyz, dtype=np.float64)
    n = len(xyz)
    out = np.zeros((n, 4 if normal_neighbours is None else 7))
    if n == 0:
        return out
    k = int(min(neighbours, n))
    local = xyz - xyz.mean(axis=0)
    tree = cKDTree(local)
    lps = np.empty((n, 3))
    for start in range(0, n, chunk):
        stop = min(start + chunk, n)
        _, idx = tree.query(local[start:stop], k=k, workers=-1)
        idx = np.asarray(idx, np.int64).reshape(stop - start, k)
        _features(local, idx, lps[start:stop])
        if normal_neighbours is not None:
            kn = int(min(max(normal_neighbours, 3), k))
            normals = np.empty((stop - start, 3))
            _normals(local, np.ascontiguousarray(idx[:, :kn]), kn, normals)
            out[start:stop, 4:] = normals
    out[:, :3] = lps
    with np.errstate(divide="ignore", invalid="ignore"):
        terms = np.where(lps > 0, -lps * np.log(lps), 0.0)
    out[:, 3] = terms.sum(axis=1)
    return out


def cluster_means(labels: np.ndarray, values: np.ndarray, k: int | None = None) -> np.ndarray:
    """Mean of ``values`` per cluster label 0..K-1 (eq. 3.5); NaN for empty labels."""
    labels = np.asarray(labels)
    k = int(labels.max(initial=-1)) + 1 if k is None else k
    ok = labels >= 0
    counts = np.bincount(labels[ok], minlength=k)
    sums = np.bincount(labels[ok], np.asarray(values, float)[ok], minlength=k)
    with np.errstate(invalid="ignore", divide="ignore"):
        return sums / counts


def kmeans_1d(values: np.ndarray, k: int = 2, max_iter: int = 100) -> tuple[np.ndarray, np.ndarray]:
    """Lloyd's k-means on a 1-D sample, started from evenly spaced quantiles.

    Deterministic: no random start.  Returns the sorted centroids (k,) and
    the cluster index of each value (N,).

    Examples
    --------
    >>> c, lab = kmeans_1d(np.array([0.1, 0.2, 0.15, 1.0, 1.1]))
    >>> np.round(c, 2).tolist(), lab.tolist()
    ([0.15, 1.05], [0, 0, 0, 1, 1])
    """
    v = np.asarray(values, dtype=np.float64)
    if len(v) == 0:
        raise ValueError("k-means of an empty sample")
    centres = np.quantile(v, (np.arange(k) + 0.5) / k)
    lab = np.zeros(len(v), np.int64)
    for _ in range(max_iter):
        lab = np.argmin(np.abs(v[:, None] - centres[None, :]), axis=1)
        new = np.array([v[lab == j].mean() if np.any(lab == j) else centres[j] for j in range(k)])
        if np.allclose(new, centres):
            break
        centres = new
    order = np.argsort(centres)
    rank = np.empty(k, np.int64)
    rank[order] = np.arange(k)
    return centres[order], rank[lab]


def separate_buildings(
    entropy: np.ndarray, linearity: np.ndarray, options: ClassifyOptions | None = None
) -> tuple[np.ndarray, dict]:
    """Decide which clusters are buildings from their mean entropy and linearity.

    Parameters
    ----------
    entropy : ndarray of shape (K,), float64
        Mean eigen-entropy per cluster (eq. 3.5).
    linearity : ndarray of shape (K,), float64
        Mean linearity per cluster.
    options : ClassifyOptions, optional

    Returns
    -------
    is_building : ndarray of shape (K,), bool
    params : dict
        ``entropy_threshold``, ``method`` (``"kmeans"``, ``"fallback"`` or
        ``"none"``) and the centroids.

    Examples
    --------
    >>> e = np.array([0.4, 0.45, 0.5, 1.0, 1.05])
    >>> separate_buildings(e, np.zeros(5))[0].tolist()
    [True, True, True, False, False]
    >>> separate_buildings(np.array([0.4, 0.45, 0.5]), np.zeros(3))[0].tolist()
    [True, True, True]
    """
    opt = options or ClassifyOptions()
    e = np.asarray(entropy, dtype=np.float64)
    lin = np.asarray(linearity, dtype=np.float64)
    params: dict = {"method": "none", "entropy_threshold": opt.fallback_entropy, "centroids": None}
    if len(e) == 0:
        return np.zeros(0, bool), params
    threshold = opt.fallback_entropy
    method = "fallback"
    if len(e) >= 2:
        centres, lab = kmeans_1d(e, 2)
        params["centroids"] = centres.tolist()
        if centres[1] - centres[0] >= opt.min_gap:
            # the boundary where both classes are equally many standard
            # deviations away; the midpoint assumes equal spreads, while
            # roofs (walls, dormers, chimneys) spread far more than crowns
            sd = np.array([e[lab == j].std() for j in (0, 1)])
            if opt.boundary == "zscore" and np.all(sd > 0):
                cut = (centres[0] * sd[1] + centres[1] * sd[0]) / sd.sum()
            else:
                cut = centres.mean()
            threshold = float(np.clip(cut, opt.entropy_floor, opt.entropy_ceiling))
            method = "kmeans"
    params.update(method=method, entropy_threshold=threshold)
    is_building = (e <= threshold) & (lin <= opt.max_linearity)
    return is_building, params
