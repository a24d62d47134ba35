"""Roof levels into buildings: merge, filters, and the points a building takes in.

Beyond the thesis (§3.3-3.4), after the building/vegetation decision of the
roof levels (:mod:`rooftrace.lidar.classify`):

1. building levels that touch in plan are merged into buildings
   (:func:`rooftrace.lidar.segment.merge_touching`);
2. a building needs one roof level of at least T_Np points; it is dropped
   when the laser went through it (``classify.max_penetration`` ×
   ``classify.building_penetration``) or when it is narrower than
   ``segment.min_width``;
3. it takes in the non-ground points next to it whose own entropy is on the
   building side (walls, roof edges, dormers cut off by the height test),
   then any point touching it and the points under its roof edge; with
   ``segment.absorb_min_height`` set, points of no roof level lower than
   that stay out.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from rooftrace.lidar.classify import ClassifyOptions, cluster_means
from rooftrace.lidar.segment import SegmentOptions, merge_touching

__all__ = ["assemble_buildings"]


def _absorb(pts: np.ndarray, group: np.ndarray, eligible: np.ndarray, radius: float, rounds: int) -> np.ndarray:
    """Let buildings take in eligible unassigned points within ``radius`` (3D) of them, ``rounds`` times.

    Recovers roof edges, dormers and wall tops that the height test cut into
    clusters too small to keep; only points whose own entropy is on the
    building side are eligible, so tree crowns stay out.
    """
    group = group.copy()
    for _ in range(rounds):
        inb = np.flatnonzero(group >= 0)
        todo = np.flatnonzero((group < 0) & eligible)
        if len(inb) == 0 or len(todo) == 0:
            break
        dist, j = cKDTree(pts[inb]).query(pts[todo], distance_upper_bound=radius, workers=-1)
        hit = np.isfinite(dist)
        if not hit.any():
            break
        group[todo[hit]] = group[inb[j[hit]]]
    return group


def _absorb_below(pts: np.ndarray, group: np.ndarray, radius: float, eligible: np.ndarray) -> np.ndarray:
    """Eligible unassigned points under a building's roof (plan distance < radius, lower) join it: walls, eaves."""
    group = group.copy()
    inb = np.flatnonzero(group >= 0)
    todo = np.flatnonzero((group < 0) & eligible)
    if len(inb) == 0 or len(todo) == 0:
        return group
    dist, j = cKDTree(pts[inb, :2]).query(pts[todo, :2], distance_upper_bound=radius, workers=-1)
    hit = np.isfinite(dist)
    hit[hit] &= pts[todo[hit], 2] <= pts[inb[j[hit]], 2]
    group[todo[hit]] = group[inb[j[hit]]]
    return group


def group_widths(xy: np.ndarray, group: np.ndarray, k: int) -> np.ndarray:
    """Width of each group in plan: sqrt(12 · smallest variance), exact for a filled rectangle (m)."""
    ok = group >= 0
    if not ok.any():
        return np.zeros(k)
    g = group[ok]
    cnt = np.maximum(np.bincount(g, minlength=k), 1)
    c = xy[ok] - xy[ok].mean(axis=0)
    mx, my = np.bincount(g, c[:, 0], k) / cnt, np.bincount(g, c[:, 1], k) / cnt
    sxx = np.bincount(g, c[:, 0] ** 2, k) / cnt - mx**2
    syy = np.bincount(g, c[:, 1] ** 2, k) / cnt - my**2
    sxy = np.bincount(g, c[:, 0] * c[:, 1], k) / cnt - mx * my
    small = (sxx + syy) / 2 - np.sqrt(((sxx - syy) / 2) ** 2 + sxy**2)
    return np.sqrt(12 * np.maximum(small, 0))


def absorb_entropy(threshold: float, centroids: list | None, margin: float) -> float:
    """Entropy limit of absorbed points: ``margin`` of the way from the threshold to the vegetation centroid."""
    if not centroids or centroids[1] <= threshold:
        return threshold
    return threshold + margin * (centroids[1] - threshold)


def assemble_buildings(
    pts: np.ndarray,
    hag: np.ndarray,
    entropy: np.ndarray,
    high: np.ndarray,
    levels: np.ndarray,
    pairs: np.ndarray,
    building_level: np.ndarray,
    big: np.ndarray,
    returns: np.ndarray | None,
    *,
    min_points: int,
    link_distance: float,
    mean_spacing: float,
    threshold: float,
    centroids: list | None,
    segment: SegmentOptions,
    classify: ClassifyOptions,
) -> tuple[np.ndarray, np.ndarray]:
    """Building of every non-ground point, from its roof levels (see the module notes).

    Parameters
    ----------
    pts : ndarray of shape (M, 3), float64
        Non-ground, non-noise points (m, any fixed local frame).
    hag : ndarray of shape (M,), float64
        Their height above the ground (m).
    entropy : ndarray of shape (M,), float64
        Their eigen-entropy (:func:`rooftrace.lidar.features.eigen_features`).
    high : ndarray of shape (H,), int
        Indices into ``pts`` of the segmented points.
    levels : ndarray of shape (H,), int
        Roof-level label (0..K-1) of each segmented point.
    pairs : ndarray of shape (P, 2), int
        Plan-neighbour pairs of the segmented points (:func:`rooftrace.lidar.segment.link_pairs`).
    building_level, big : ndarray of shape (K,), bool
        Levels decided as building; levels of at least T_Np points.
    returns : ndarray of shape (H,), float64 or None
        1.0 where a segmented point is not the last return of its pulse.
    min_points : int
        T_Np.
    link_distance, mean_spacing : float
        L_Dxy and s_avg (m).
    threshold : float
        Entropy threshold of the building levels.
    centroids : list of two floats or None
        k-means centroids (building, vegetation).
    segment, classify : SegmentOptions, ClassifyOptions

    Returns
    -------
    group : ndarray of shape (M,), int64
        Building group of each point (not numbered in any order), -1 none.
    levels_all : ndarray of shape (M,), int64
        ``levels`` spread over ``pts``, -1 for points not segmented.
    """
    so, co = segment, classify
    group = merge_touching(levels, pairs, building_level)
    group_high = np.where(building_level[levels], group[levels], -1) if len(levels) else levels
    gsize = np.bincount(group_high[group_high >= 0], minlength=int(group.max(initial=-1)) + 1)
    # a building needs one roof level of T_Np points itself; small
    # clusters only join one (a heap of small ones is a crown cut up)
    keep = gsize >= min_points
    anchored = np.zeros(len(gsize), bool)
    anchored[group[building_level & big]] = True
    keep &= anchored
    if co.max_penetration is not None and returns is not None:
        # the same test on the whole building, at a stricter level: a
        # roof lets few pulses through, a heap of crowns many
        pen = cluster_means(group_high, returns, len(gsize))
        keep &= ~(pen > co.max_penetration * co.building_penetration)
    if so.min_width:
        keep &= group_widths(pts[high, :2], group_high, len(gsize)) >= so.min_width
    keep = np.append(keep, False)  # slot for "no group"
    group_high = np.where(keep[np.where(group_high >= 0, group_high, len(keep) - 1)], group_high, -1)
    group_all = np.full(len(pts), -1, np.int64)
    group_all[high] = group_high
    levels_all = np.full(len(pts), -1, np.int64)
    levels_all[high] = levels
    if so.absorb_rounds and len(pts):
        # only points whose own neighbourhood is on the building side
        # (roof edges, dormers, walls) join; hedges and crowns do not
        eligible = entropy <= absorb_entropy(threshold, centroids, so.absorb_margin)
        group_all = _absorb(pts, group_all, eligible, link_distance, so.absorb_rounds)
        if so.absorb_touching:
            group_all = _absorb(pts, group_all, np.ones(len(pts), bool), mean_spacing, 1)
            group_all = _absorb_below(pts, group_all, mean_spacing, eligible)
        if so.absorb_min_height is not None:
            group_all[(levels_all < 0) & (hag < so.absorb_min_height)] = -1
    return group_all, levels_all
