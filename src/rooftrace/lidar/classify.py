"""Building versus vegetation by mean eigen-entropy and 1-D k-means (Santos et al. 2019b; thesis §3.4).

For each point the covariance of its N nearest neighbours
(:mod:`rooftrace.lidar.features`; optionally an adaptive size) gives
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
  ``max_linearity`` and narrower than ``linear_width`` are never buildings.
- Beyond the thesis (``decision = 'residual'``, the default), a level whose
  points lie within ``max_residual``·sigma_H of their local planes (median)
  is a building whatever its entropy, and when the k-means finds one
  population that residual alone decides: it needs no second class and
  holds with single returns and scan lines far apart, where the entropy
  of a crown's top or of a roof's line-bound neighbourhoods misleads.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from rooftrace.lidar._kernels import count_within, pair_pull, sort_by_bucket
from rooftrace.options import optional

__all__ = ["ClassifyOptions", "cluster_means", "cluster_medians", "interior_points", "kmeans_1d", "local_penetration",
           "penetration", "separate_buildings"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ClassifyOptions:
    """Options of the building/vegetation separation (TOML table ``[classify]``).

    Attributes
    ----------
    decision : {'residual', 'entropy'}, default 'residual'
        ``'entropy'``: the thesis' decision alone, a roof level is a building
        when its mean eigen-entropy is on the building side of the k-means
        threshold.  ``'residual'``: also when the median distance of its
        points to their local planes (the plane of the normal's
        neighbourhood) is at most ``max_residual``·sigma_H.  That test
        needs no second class (a scene of only houses) and holds where
        the entropy does not: with single returns a crown's top is a
        surface and its entropy low, with scan lines far apart a roof's
        neighbourhoods look linear, but a crown is rough and a roof face
        is not (simulated scenes at 2 pts/m², lines 2.5 m apart, single
        returns: roofs 0.018 m, crowns 0.32 m).
    max_residual : float, default 3.0
        Largest median plane residual of a building level, in units of sigma_H.
    neighbours : int or None
        N, neighbours of the covariance; ``None``: ``Ar_min·d_avg``
        (thesis §3.4), clipped to ``[10, max_neighbours]``.
    max_neighbours : int, default 60
        Upper bound of the derived N (cost grows linearly with it).
    neighbourhood : {'adaptive', 'fixed'}, default 'adaptive'
        ``'fixed'``: every point's features come from its N nearest points
        (thesis §3.4).  ``'adaptive'``: from the size between
        ``min_neighbours`` and N, in steps of ``neighbour_step``, whose
        neighbourhood has the lowest entropy (Demantké et al. 2011, Weinmann
        et al. 2015; :mod:`rooftrace.lidar.features`), so that small low
        roofs next to walls and crowns keep their planar look.  The k-means
        on the clusters' mean entropy is the same either way.  Delft (AHN3)
        building F1 0.933 -> 0.950, IGN 0.897 -> 0.917 (with
        ``max_penetration`` 0.3); see docs/design-notes.md.
    min_neighbours : int, default 10
        Smallest adaptive neighbourhood.
    neighbour_step : int, default 5
        Step between the adaptive sizes.
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
        Clusters with a higher mean linearity (of the N-point
        neighbourhoods), narrower in plan than ``linear_width``, are linear
        objects (power lines, fences).
    linear_width : float or None
        Plan width (m, as :func:`rooftrace.lidar.buildings.group_widths`)
        under which a cluster of linear points is a linear object;
        ``None``: L_Dxy (a row of points).  Where scan lines lie farther apart than the
        points along them (low density, oscillating mirrors) the
        neighbourhoods of a roof's points hold one or two lines and look
        linear too, but the roof is wide: without the width a simulated
        scene at 2 pts/m² lost 4 of its 25 buildings.
    linear_joins : bool, default True
        Beyond the thesis: a linear cluster on the building side of the
        entropy threshold, not penetrated, joins the building clusters when
        a quarter of its points have a plan neighbour in one that is not
        lower than them by more than 2·L_Dxy (repeated, so a row of them
        joins): a narrow roof strip beside a higher wall, whose scan lines
        the height test cut apart, is a row of one-line clusters (three
        Delft strips at 5.6-6 m next to a 10 m block, 52 m²), while a wire
        crossing over a roof touches it only from above.  Delft area F
        0.9246 -> 0.9267, IGN building F1 0.917 -> 0.919.
    boundary : {'zscore', 'midpoint'}, default 'zscore'
        Where the threshold sits between the two k-means centroids c0 < c1:
        ``'midpoint'`` (c0 + c1)/2, the plain k-means rule (thesis); ``'zscore'``
        (c0·s1 + c1·s0)/(s0 + s1) with s0, s1 the classes' standard
        deviations, equally many deviations from both centroids.
    max_penetration : float or None, default 0.3
        Beyond the thesis: clusters where more than this fraction of points
        are not the last return of their pulse are not buildings (the laser
        went through them: hedges, crowns trimmed flat).  Used only when the
        file has return numbers; ``None`` (``false`` in a config file)
        disables it.  0.5 before the
        adaptive neighbourhood, which lets the flat tops of some crowns and
        hedges look planar (a 60 m² Delft hedge at 0.46); with it, 0.3 gave
        IGN building F1 0.898 -> 0.911 and Delft area F 0.915 -> 0.918, the
        rest unchanged (docs/design-notes.md, measured with the linear
        guard on the adaptive size).
    penetrated_joins : bool, default True
        Beyond the thesis: a level over its penetration limit on the
        building side of the decision still joins the building levels
        beside it, as :attr:`linear_joins` does (a quarter of its points
        next to one, not lower than them by more than 2·L_Dxy); the
        whole-building and patch tests then judge it with its building.
        Delft (AHN3) thinned to 2 pts/m², tile 1: building F1 0.877 -> 0.883.
    edge_allowance : float, default 0.3
        Beyond the thesis: the per-level limit is ``max_penetration +
        edge_allowance · e`` with e = min(1, 2·sqrt(pi/n)), the share of a
        disc of n points that lies on its edge.  Pulses split on roof
        edges, and the edge band, a spacing wide, is a larger part of a
        level the fewer points it has: a few percent of a roof face at
        full density, a third or more at 2 pts/m².  The share is taken from
        the size, not measured on the level's shape, because ragged crowns
        have long edges too.  Delft tile 1 thinned to 2 pts/m²: 0.883 ->
        0.885 (0.931 at 0.5, but IGN LiDAR HD then 0.918 -> 0.909: crowns
        get in; without the per-level test 0.933).  0: the fixed limit.
    building_penetration : float, default 0.6
        A whole building (its roof levels merged) is dropped when its
        fraction of non-last returns exceeds
        ``max_penetration · building_penetration``.
    penetration_edge : float or None, default 0.2
        The whole-building test (``max_penetration · building_penetration``)
        counts only the interior points of the building's roof levels: a
        point is on the edge when the centroid of its same-level neighbours
        within L_Dxy is farther than this fraction of L_Dxy from it
        (:func:`interior_points`).  A pulse that meets a roof edge splits
        (first return on the roof, last on the ground), so on a small roof
        the edge alone makes a quarter of the returns non-last: Delft garden
        sheds of 8-10 m² had 0.24-0.29 (over the 0.18 of that test), their
        interior 0.03-0.16, while hedges and crowns keep 0.8-0.97 inside.
        The per-level test keeps every point: counting only the interior
        there too lets IGN crowns in (IGN building F1 0.917 -> 0.906).
        ``None`` (``false`` in a config file): every point counts.
    max_patch_penetration : float or None, default 0.5
        After the buildings are assembled, a building point leaves when
        more than this fraction of the building's points within
        ``patch_factor · L_Dxy`` in plan are non-last returns
        (:func:`rooftrace.lidar.buildings.drop_penetrated`): a hedge or
        crown that grew into a shed's roof level at the same height.  A
        building that falls apart then becomes one building per part of at
        least T_Np points.  Used only when the file has return numbers;
        ``None`` (``false`` in a config file) disables it.
    patch_factor : float, default 2.0
        Radius of that neighbourhood, in units of L_Dxy.
    split_patches_from : float or None, default 1.0
        Beyond the thesis: from this L_Dxy on (m), a roof level's penetrated
        patches (``max_patch_penetration``) become a level of their own
        before the building/vegetation decision when the rest of the level
        is a solid roof (at least T_Np points, at most ``max_penetration ·
        building_penetration`` non-last returns;
        :func:`rooftrace.lidar.buildings.split_patches`).  At 2 pts/m²
        (L_Dxy about 1.6 m) the roof level of a 100 m² house took in 215
        points of the crowns beside it (non-last returns 0.76, the roof's 0)
        and the penetration tests dropped the house.  At AHN3 and LiDAR HD
        densities (L_Dxy 0.49-0.66 m) region growing does not reach across
        the gap between eaves and crown, and the split there took hedge
        cores in as roofs (Delft building F1 0.9605 -> 0.9594).  ``None``
        (``false`` in a config file): never.
    """

    section: ClassVar[str] = "classify"
    decision: str = "residual"
    max_residual: float = 3.0
    neighbours: int | None = None
    max_neighbours: int = 60
    neighbourhood: str = "adaptive"
    min_neighbours: int = 10
    neighbour_step: int = 5
    min_gap: float = 0.15
    fallback_entropy: float = 0.8
    entropy_floor: float = 0.6
    entropy_ceiling: float = 0.95
    max_linearity: float = 0.7
    linear_width: float | None = None
    linear_joins: bool = True
    boundary: str = "zscore"
    max_penetration: float | None = optional(0.3)
    building_penetration: float = 0.6
    penetrated_joins: bool = True
    edge_allowance: float = 0.3
    penetration_edge: float | None = optional(0.2)
    max_patch_penetration: float | None = optional(0.5)
    patch_factor: float = 2.0
    split_patches_from: float | None = optional(1.0)

    def __post_init__(self) -> None:
        if self.decision not in ("residual", "entropy"):
            raise ValueError(f"classify.decision must be 'residual' or 'entropy', got {self.decision!r}")
        if not self.max_residual > 0:
            raise ValueError(f"classify.max_residual must be > 0, got {self.max_residual}")
        if self.boundary not in ("zscore", "midpoint"):
            raise ValueError(f"classify.boundary must be 'zscore' or 'midpoint', got {self.boundary!r}")
        if self.neighbourhood not in ("adaptive", "fixed"):
            raise ValueError(f"classify.neighbourhood must be 'adaptive' or 'fixed', got {self.neighbourhood!r}")
        if self.min_neighbours < 4:
            raise ValueError(f"classify.min_neighbours must be >= 4, got {self.min_neighbours}")
        if self.neighbour_step < 1:
            raise ValueError(f"classify.neighbour_step must be >= 1, got {self.neighbour_step}")
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
        if self.max_patch_penetration is not None and not 0 < self.max_patch_penetration <= 1:
            raise ValueError(
                f"classify.max_patch_penetration must be in (0, 1] or unset, got {self.max_patch_penetration}")
        if self.split_patches_from is not None and not self.split_patches_from >= 0:
            raise ValueError(f"classify.split_patches_from must be >= 0 m or unset, got {self.split_patches_from}")
        if not self.patch_factor > 0:
            raise ValueError(f"classify.patch_factor must be > 0, got {self.patch_factor}")
        if not 0 <= self.edge_allowance <= 1:
            raise ValueError(f"classify.edge_allowance must be in [0, 1], got {self.edge_allowance}")
        if self.penetration_edge is not None and not 0 < self.penetration_edge <= 1:
            raise ValueError(f"classify.penetration_edge must be in (0, 1] or unset, got {self.penetration_edge}")


def cluster_means(labels: np.ndarray, values: np.ndarray, k: int | None = None) -> np.ndarray:
    """Mean of ``values`` per cluster label 0..K-1 (eq. 3.5); NaN for empty labels."""
    labels = np.asarray(labels)
    k = int(labels.max(initial=-1)) + 1 if k is None else k
    ok = labels >= 0
    counts = np.bincount(labels[ok], minlength=k)
    sums = np.bincount(labels[ok], np.asarray(values, float)[ok], minlength=k)
    with np.errstate(invalid="ignore", divide="ignore"):
        return sums / counts


def cluster_medians(labels: np.ndarray, values: np.ndarray, k: int | None = None) -> np.ndarray:
    """Median of ``values`` per cluster label 0..K-1 (the lower middle value for an even count); NaN for empty labels.

    Examples
    --------
    >>> cluster_medians(np.array([0, 0, 0, 1, -1]), np.array([3.0, 1.0, 2.0, 5.0, 9.0]), 3).tolist()
    [2.0, 5.0, nan]
    """
    labels = np.asarray(labels)
    k = int(labels.max(initial=-1)) + 1 if k is None else k
    ok = np.flatnonzero(labels >= 0)
    values = np.asarray(values, float)[ok]
    # a counting sort on the (dense) labels, then each cluster: np.lexsort((values, labels))'s order
    order = sort_by_bucket(values, labels[ok])
    counts = np.bincount(labels[ok], minlength=k)
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    out = np.full(k, np.nan)
    has = counts > 0
    out[has] = values[order[start[has] + (counts[has] - 1) // 2]]
    return out


def interior_points(xy: np.ndarray, labels: np.ndarray, pairs: np.ndarray, radius: float,
                    max_offset: float) -> np.ndarray:
    """Points inside their cluster, not on its edge, from the plan-neighbour pairs.

    A point is interior when it has at least three neighbours of its own
    cluster among ``pairs`` and their centroid lies within
    ``max_offset · radius`` of it; on an edge the neighbours all lie on one
    side and pull the centroid about 0.4·radius away.

    Parameters
    ----------
    xy : ndarray of shape (N, 2), float64
        Plan coordinates (m).
    labels : ndarray of shape (N,), int
        Cluster of each point.
    pairs : ndarray of shape (P, 2), int
        Pairs of points closer than ``radius`` in plan.
    radius : float
        The pairs' distance limit (m).
    max_offset : float
        Largest centroid offset of an interior point, as a fraction of ``radius``.

    Returns
    -------
    ndarray of shape (N,), bool

    Examples
    --------
    >>> g = np.stack(np.meshgrid(np.arange(5.0), np.arange(5.0)), -1).reshape(-1, 2)
    >>> from scipy.spatial import cKDTree
    >>> inner = interior_points(g, np.zeros(25, int), cKDTree(g).query_pairs(1.5, output_type="ndarray"), 1.5, 0.2)
    >>> inner.reshape(5, 5).astype(int).tolist()[:2]
    [[0, 0, 0, 0, 0], [0, 1, 1, 1, 0]]
    """
    xy = np.asarray(xy, dtype=np.float64)
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    count, pull = pair_pull(np.ascontiguousarray(xy), np.ascontiguousarray(labels, dtype=np.int64),
                            np.ascontiguousarray(pairs))
    offset = np.hypot(pull[:, 0], pull[:, 1]) / np.maximum(count, 1)
    return (count >= 3) & (offset < max_offset * radius)


def penetration(labels: np.ndarray, returns: np.ndarray, interior: np.ndarray | None, k: int,
                min_interior: int = 5) -> np.ndarray:
    """Fraction of non-last returns per cluster, over its interior points when it has ``min_interior`` of them.

    ``returns`` is 1.0 for a point that is not the last return of its
    pulse; clusters too small to have an interior are measured on all
    their points.  NaN for empty labels.
    """
    every = cluster_means(labels, returns, k)
    if interior is None:
        return every
    ok = labels >= 0
    n_in = np.bincount(labels[ok & interior], minlength=k)
    inner = cluster_means(np.where(interior, labels, -1), returns, k)
    return np.where(n_in >= min_interior, inner, every)


def local_penetration(xy: np.ndarray, labels: np.ndarray, returns: np.ndarray, radius: float) -> np.ndarray:
    """Fraction of non-last returns among each point's cluster-mates within ``radius`` in plan (itself included).

    Parameters
    ----------
    xy : ndarray of shape (N, 2), float64
        Plan coordinates (m).
    labels : ndarray of shape (N,), int
        Cluster of each point, negative = none.
    returns : ndarray of shape (N,), float64
        1.0 where a point is not the last return of its pulse.
    radius : float
        Plan radius (m).

    Returns
    -------
    ndarray of shape (N,), float64
        NaN for points of no cluster.
    """
    labels = np.asarray(labels, dtype=np.int64)
    out = np.full(len(labels), np.nan)
    inb = np.flatnonzero(labels >= 0)
    if len(inb) == 0:
        return out
    # counting (not listing) neighbours keeps memory linear (~70 neighbours
    # a point at 15 pts/m² and 1.2 m)
    through = np.asarray(returns, dtype=np.float64)[inb] > 0
    count, n_through = count_within(np.asarray(xy, dtype=np.float64)[inb], labels[inb], through, radius)
    out[inb] = n_through / count
    return out


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
