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
   that stay out;
4. patches of a building where the laser went through (``classify.max_patch_penetration``:
   a hedge or crown grown into a shed's roof level) leave it, and a
   building that falls apart in plan becomes one building per part of at
   least T_Np points.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from rooftrace.graph import components
from rooftrace.lidar._kernels import nearest_within, pair_mask
from rooftrace.lidar.classify import ClassifyOptions, interior_points, local_penetration, penetration
from rooftrace.lidar.segment import SegmentOptions, link_pairs, merge_touching

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
        j = _nearest(pts[inb], pts[todo], radius)
        hit = j >= 0
        if not hit.any():
            break
        group[todo[hit]] = group[inb[j[hit]]]
    return group


def _nearest(data: np.ndarray, queries: np.ndarray, radius: float) -> np.ndarray:
    """``cKDTree(data).query(queries, distance_upper_bound=radius)``'s neighbour (-1 none), on a grid.

    The tree decides only the queries with two nearest points at one distance.
    """
    j, tie = nearest_within(data, queries, radius)
    if tie.any():
        _, jt = cKDTree(data).query(queries[tie], distance_upper_bound=radius, workers=-1)
        j[tie] = np.where(jt < len(data), jt, -1)
    return j


def _absorb_below(pts: np.ndarray, group: np.ndarray, radius: float, eligible: np.ndarray) -> np.ndarray:
    """Eligible unassigned points under a building's roof (plan distance < radius, lower) join it: walls, eaves."""
    group = group.copy()
    inb = np.flatnonzero(group >= 0)
    todo = np.flatnonzero((group < 0) & eligible)
    if len(inb) == 0 or len(todo) == 0:
        return group
    j = _nearest(pts[inb, :2], pts[todo, :2], radius)
    hit = j >= 0
    hit[hit] &= pts[todo[hit], 2] <= pts[inb[j[hit]], 2]
    group[todo[hit]] = group[inb[j[hit]]]
    return group


def _same_group_pairs(xy: np.ndarray, group: np.ndarray, radius: float) -> np.ndarray:
    """Plan pairs closer than ``radius`` between points of the same group (indices into ``xy``)."""
    pairs = cKDTree(xy).query_pairs(radius, output_type="ndarray").astype(np.int64, copy=False)
    return pairs[group[pairs[:, 0]] == group[pairs[:, 1]]]


def drop_penetrated(xy: np.ndarray, group: np.ndarray, returns: np.ndarray, radius: float,
                    max_fraction: float) -> np.ndarray:
    """Take out of their building the points around which the laser went through the roof.

    Around each building point the fraction of non-last returns among the
    building's points within ``radius`` in plan (itself included) is
    measured; where it exceeds ``max_fraction`` the point leaves.  A solid
    roof gives last returns except in the thin band along its edges where
    pulses split (about 0.3 of a 2·L_Dxy disc there), a crown or hedge
    grown into the roof level gives 0.5-0.9.

    Parameters
    ----------
    xy : ndarray of shape (M, 2), float64
        Plan coordinates (m).
    group : ndarray of shape (M,), int
        Building of each point, -1 none.
    returns : ndarray of shape (M,), float64
        1.0 where a point is not the last return of its pulse.
    radius : float
        Plan radius of the neighbourhood (m).
    max_fraction : float
        Largest fraction of non-last returns a building point may have around it.

    Returns
    -------
    ndarray of shape (M,), int64
        ``group`` with the penetrated points set to -1.
    """
    group = np.asarray(group, dtype=np.int64).copy()
    group[local_penetration(xy, group, returns, radius) > max_fraction] = -1
    return group


def split_patches(xy: np.ndarray, levels: np.ndarray, returns: np.ndarray, radius: float, max_fraction: float,
                  min_points: int, max_share: float) -> np.ndarray:
    """Take the penetrated patches out of the roof levels whose remaining points are a solid roof.

    A patch is the points of a level around which more than
    ``max_fraction`` of the level's points within ``radius`` in plan are
    non-last returns (:func:`drop_penetrated`): a crown over the eaves that
    region growing joined to the roof at low density.  When the rest of the
    level has at least ``min_points`` points and at most ``max_share`` of
    them are non-last returns, the patches become a level of their own, so
    the roof and the crown are judged apart; otherwise (a crown, a heap of
    crowns, a roof without patches) the level stays whole.

    Parameters
    ----------
    xy : ndarray of shape (N, 2), float64
        Plan coordinates (m).
    levels : ndarray of shape (N,), int
        Roof level of each point, 0..K-1.
    returns : ndarray of shape (N,), float64
        1.0 where a point is not the last return of its pulse.
    radius : float
        Plan radius of the neighbourhood (m).
    max_fraction : float
        Largest fraction of non-last returns around a point of the roof.
    min_points : int
        Smallest roof left once the patches are out (T_Np).
    max_share : float
        Largest fraction of non-last returns of that roof.

    Returns
    -------
    ndarray of shape (N,), int64
        Levels 0..K'-1: the split levels' patches numbered from K on.

    Examples
    --------
    >>> g = np.stack(np.meshgrid(np.arange(10.0), np.arange(4.0)), -1).reshape(-1, 2)
    >>> crown = (g[:, 0] >= 6).astype(float)  # the east part lets pulses through
    >>> split_patches(g, np.zeros(40, int), crown, 1.5, 0.5, 10, 0.2).reshape(4, 10)[0].tolist()
    [0, 0, 0, 0, 0, 0, 1, 1, 1, 1]
    """
    levels = np.asarray(levels, dtype=np.int64)
    k = int(levels.max(initial=-1)) + 1
    own = drop_penetrated(xy, levels, returns, radius, max_fraction)
    n_own = np.bincount(own[own >= 0], minlength=k)
    share = np.bincount(own[own >= 0], np.asarray(returns, np.float64)[own >= 0], minlength=k) / np.maximum(n_own, 1)
    solid = (n_own >= min_points) & (share <= max_share)
    patch = (own < 0) & solid[levels]
    if not patch.any():
        return levels
    # one new level per split level, numbered in the order of the old ones
    split = np.flatnonzero(solid & (np.bincount(levels[patch], minlength=k) > 0))
    new = np.full(k, -1, np.int64)
    new[split] = k + np.arange(len(split))
    return np.where(patch, new[levels], levels)


def split_parts(xy: np.ndarray, group: np.ndarray, radius: float, min_points: int) -> np.ndarray:
    """One group per part of a building that is connected in plan at ``radius``; parts under ``min_points`` leave.

    Returns the new group of each point (-1 none; numbered in no order).
    """
    group = np.asarray(group, dtype=np.int64)
    inb = np.flatnonzero(group >= 0)
    out = np.full(len(group), -1, np.int64)
    if len(inb) == 0:
        return out
    part = components(len(inb), _same_group_pairs(xy[inb], group[inb], radius))
    out[inb] = np.where(np.bincount(part)[part] >= min_points, part, -1)
    return out


def split_cut(xy: np.ndarray, before: np.ndarray, after: np.ndarray, radius: float, min_points: int) -> np.ndarray:
    """Groups after points left them: a group that lost points becomes one group per part (:func:`split_parts`).

    Parameters
    ----------
    xy : ndarray of shape (M, 2), float64
        Plan coordinates (m).
    before, after : ndarray of shape (M,), int
        Group of each point before and after some left (-1 none); a point
        never changes group, it only leaves.
    radius : float
        Plan distance connecting a part (m).
    min_points : int
        Smallest part kept.

    Returns
    -------
    ndarray of shape (M,), int64
        Groups numbered in no order, -1 none; untouched groups keep their number.
    """
    before = np.asarray(before, dtype=np.int64)
    out = np.asarray(after, dtype=np.int64).copy()
    # only a group that lost points can have fallen apart
    cut = np.zeros(int(before.max(initial=-1)) + 1, bool)
    cut[before[(before >= 0) & (out < 0)]] = True
    redo = np.flatnonzero(out >= 0)
    redo = redo[cut[out[redo]]]
    if len(redo):
        parts = split_parts(xy[redo], out[redo], radius, min_points)
        out[redo] = np.where(parts >= 0, parts + len(cut), -1)
    return out


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
    merge_distance: float | None = None,
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
    returns : ndarray of shape (M,), float64 or None
        1.0 where a point is not the last return of its pulse (None: the
        file has no return numbers, no penetration test).
    min_points : int
        T_Np.
    link_distance, mean_spacing : float
        L_Dxy and s_avg (m).
    threshold : float
        Entropy threshold of the building levels.
    centroids : list of two floats or None
        k-means centroids (building, vegetation).
    segment, classify : SegmentOptions, ClassifyOptions
    merge_distance : float, optional
        Building levels closer than this in plan (m) are one building;
        default (and anything shorter) ``link_distance``.

    Returns
    -------
    group : ndarray of shape (M,), int64
        Building group of each point (not numbered in any order), -1 none.
    levels_all : ndarray of shape (M,), int64
        ``levels`` spread over ``pts``, -1 for points not segmented.
    """
    so, co = segment, classify
    near = pairs
    if merge_distance is not None and merge_distance > link_distance and building_level.any():
        # pairs between building levels only: crowns never bridge a gap
        on = np.flatnonzero(building_level[levels])
        near = on[link_pairs(pts[high[on], :2], merge_distance)]
    group = merge_touching(levels, near, building_level)
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
        # roof lets few pulses through, a heap of crowns many; counted
        # inside the roof levels, where pulses do not split on an edge
        interior = None
        if co.penetration_edge is not None:
            on_building = building_level[levels]
            inside = pairs[pair_mask(on_building, pairs, True)]
            interior = interior_points(pts[high, :2], levels, inside, link_distance, co.penetration_edge)
        pen = penetration(group_high, returns[high], interior, len(gsize))
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
        # bins and shrubs by a wall would join through the wall, in any round
        allowed = np.ones(len(pts), bool) if so.absorb_min_height is None else (
            (levels_all >= 0) | (hag >= so.absorb_min_height))
        group_all = _absorb(pts, group_all, eligible & allowed, link_distance, so.absorb_rounds)
        if so.absorb_touching:
            group_all = _absorb(pts, group_all, allowed, mean_spacing, 1)
            group_all = _absorb_below(pts, group_all, mean_spacing, eligible & allowed)
    if co.max_patch_penetration is not None and returns is not None and len(pts):
        kept = drop_penetrated(pts[:, :2], group_all, returns, co.patch_factor * link_distance,
                               co.max_patch_penetration)
        group_all = split_cut(pts[:, :2], group_all, kept, link_distance, min_points)
    return group_all, levels_all
