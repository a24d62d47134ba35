"""Region growing of non-ground points into roof levels, and roof levels into buildings.

Thesis §3.3 (after Sampath & Shan 2007): two points are linked when their
planimetric distance is under L_Dxy = 2·s_avg and their height difference
under L_Dh = 2·sigma_H; clusters are the connected components of that graph.
The thesis grows regions from a seed with a moving sphere of radius
R = sqrt(L_Dxy² + L_Dh²); every point reached that way is linked to a point
within the thresholds, so the result equals the connected components of the
link graph, which a KD-tree pair query and :mod:`scipy.sparse.csgraph` give
without a Python loop.

Beyond the thesis: with sigma_H of a few centimetres (AHN3, LiDAR HD),
``|dz| < 2·sigma_H`` shatters every pitched roof into strips.  The default
test (``height_test='normal'``) measures the pair's height difference along
each point's surface normal instead, which is the thesis' ``|dz|`` on a flat
roof, keeps a pitched roof plane whole and still breaks at steps between roof
levels and in tree crowns (no consistent normal).  The other test
(``'slope'``) keeps the vertical difference but allows the roof slope,
``|dz| < L_Dh + d_xy·tan(max_slope)``.  Roof levels that touch in plan (some
pair of their points closer than L_Dxy) are merged
into one building, keeping the roof-level labels.

Optionally (``max_normal_angle``) the normal test also requires coherent normals (the
smoothness constraint of Rabbani et al. 2006): the angle between the two
normals at most ``max_normal_angle``.  A trimmed hedge or a crown with a flat
top passes the distance test often enough, by chance, to chain into the roof
it touches; its normals scatter, a roof plane's do not.

References
----------
Rabbani, T., van den Heuvel, F. A., Vosselman, G. (2006). Segmentation of point
clouds using smoothness constraint. IAPRS 36(5), 248-253.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy.spatial import cKDTree

from rooftrace.graph import components
from rooftrace.lidar._kernels import (
    cross_pairs,
    dense_unique,
    lowest_point_per_group,
    normal_links,
    pair_mask,
    sector_nearest,
    unique_pairs,
)
from rooftrace.options import optional

__all__ = ["SegmentOptions", "contact_share", "join_strips", "link_pairs", "region_growing", "merge_touching", "order_labels",
           "sector_pairs"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SegmentOptions:
    """Options of the segmentation (TOML table ``[segment]``).

    Attributes
    ----------
    min_height : float, default 2.0
        Points lower than this above the ground (m) are not segmented
        (cars, walls' feet, low vegetation).
    link_distance : float or None
        L_Dxy (m); ``None``: ``link_factor·s_avg``, with ``link_sectors``
        s_avg taken at most the mean Delaunay edge of random points of the
        same density, 1.132/sqrt(d_avg): scan lines far apart lengthen
        s_avg, and the sector links bridge them instead.
    link_factor : float, default 2.25
        L_Dxy in units of s_avg.  The thesis uses 2 (Table 6.1); with s_avg
        measured over every return (crowns pull it down) 2.25 keeps roofs
        whole on AHN3 (building F1 0.907 at 2, 0.933 at 2.25 on Delft; see
        docs/design-notes.md).
    link_height : float or None
        L_Dh (m); ``None``: ``2·sigma_H`` (thesis Table 6.1) with the
        ``'slope'`` test, ``max(2·sigma_H, 0.3·L_Dxy)`` with the ``'normal'``
        test (the pair's distance along the normals also carries the
        normals' error, about 17° over L_Dxy).
    max_slope : float, default 60.0
        Roof slope (deg) allowed in the height test, see the module notes;
        0 gives the thesis' test.
    min_area : float, default 4.0
        Ar_min (m²), the smallest building kept (thesis Table 6.1).
    min_points : int or None
        T_Np, the smallest cluster kept; ``None``: ``Ar_min·d_avg`` (eq. 3.4).
    height_test : {'normal', 'slope'}, default 'normal'
        How the height difference of a pair is measured: along the local
        surface normals (see :func:`region_growing`) or vertically with the
        ``max_slope`` allowance.
    normal_neighbours : int, default 12
        Neighbours of the plane fit giving each point's normal.
    max_normal_angle : float or None, default None
        Beyond the thesis (deg): with the ``'normal'`` test, two points are
        linked only when their normals differ by at most this angle
        (smoothness constraint, Rabbani et al. 2006), so that hedges and
        flat-topped crowns touching a roof do not chain into its roof level.
        ``None``: no angle test (the thesis' linking).  Not on by default:
        at 45 deg IGN LiDAR HD building F1 rises 0.903 -> 0.922 and Delft
        0.933 -> 0.936, but only within 44-47 deg (below 43 a rough Delft
        roof breaks up, above 48 a hedge chains into an IGN roof again), and
        crowns then fall apart into clusters too small for the k-means, which
        on a scene with few trees splits flat roofs from gables instead
        (tests/lidar/test_detect.py town: building F1 1.0 -> 0.93).  See
        docs/design-notes.md.
    merge_distance : float or None
        Beyond the thesis: building levels closer than this in plan (m) are
        one building.  ``None``: the larger of L_Dxy and the widest common
        gap of the sampling (the 0.99 quantile of the Delaunay edges,
        :func:`rooftrace.lidar.spacing.edge_spacing`), which is L_Dxy on
        evenly sampled clouds (AHN3, LiDAR HD: the quantile is 1.6-1.9
        s_avg) and the gap between scan lines where they lie far apart: an
        oscillating mirror's lines open towards the swath edges, and the
        roof between two of them falls into strips narrower than
        ``min_width`` (simulated zigzag scans at 3 pts/m², lines 1.5 m
        apart: building F1 0.65-0.78 -> 0.90-0.94).
    absorb_rounds : int, default 3
        Rounds in which a building takes in unassigned points within L_Dxy
        (3D) whose own entropy is on the building side (roof edges, dormers
        cut off by the height test); 0 disables it (the thesis' behaviour).
    min_width : float or None, default 2.5
        Beyond the thesis: buildings narrower than this in plan (m,
        ``sqrt(12·smallest variance)`` of their roof points, exact for a
        rectangle) are dropped: hedges and walls trimmed flat look like
        roofs to the entropy test.  ``None`` (``false`` in a config file)
        disables it.
    absorb_margin : float, default 1.0
        Entropy limit of absorbed points, as the fraction of the way from the
        k-means threshold to the vegetation centroid (0: the threshold; 1:
        the vegetation centroid).  A point next to a roof is a roof edge or a
        wall unless it looks at least as volumetric as a typical crown.
    absorb_min_height : float or None, default None
        Points that belong to no roof level and are lower than this above
        the ground (m) are not taken in by any absorption: bins, bicycles and
        shrubs by a wall would otherwise join the building through the wall
        and, in a narrow yard, close it over for the alpha shape.  ``None``:
        no limit.  Not on by default: 1.0 gives Delft (AHN3) area F
        0.915 -> 0.921 (a 130 m² yard no longer filled) but the synthetic
        demo's PoLiS 0.080 -> 0.097 m (one building's outline flips to a
        jagged one, median 0.073 -> 0.077 m); see docs/design-notes.md.
    link_sectors : int or None, default 8
        Beyond the thesis: besides the pairs within L_Dxy, each point is
        linked to its nearest point in each of this many directions, among
        all points, when both are segmented and at most the larger of L_Dxy
        and twice the widest common gap apart (:func:`sector_pairs`), so
        region growing crosses scan lines farther apart than L_Dxy.  An
        oscillating mirror's lines pair up towards the swath edges, twice
        their spacing apart; the roof between them fell into linear strips
        (simulated zigzag scans, lines 1.5 m apart, 3 pts/m²: up to 3
        buildings of over 100 m² missed per scene, building F1 0.91).
        ``None`` (``false`` in a config file): the thesis' pairs only.
    sector_max_angle : float, default 30.0
        Those links need normals within this angle (deg): where a crown
        overhangs a roof no ground point lies between them.  IGN LiDAR HD
        building F1 0.918 at 20 and 30, 0.915 at 45 and without the test
        (crowns join roofs); the simulated scan lines need none.
    sector_max_residual : float, default 3.0
        And both points on a smooth surface: the RMS distance of each one's
        normal neighbourhood to its plane at most this many sigma_H (roof
        faces about 1, crowns 4-25).  Randomly sampled clouds have
        directions with no point within L_Dxy too (a tenth of the points at
        2 pts/m²), and without this test their links chain roofs into
        crowns: Delft (AHN3) tile 1 thinned to 2 pts/m², building F1
        0.885 -> 0.828 (0.885 with it).
    absorb_touching : bool, default True
        After that, a building also takes in any unassigned point closer
        than s_avg (3D) to it, whatever its entropy (points interleaved with
        the roof whose normals are noisy: ridges, eaves).
    """

    section: ClassVar[str] = "segment"
    min_height: float = 2.0
    link_distance: float | None = None
    link_factor: float = 2.25
    link_height: float | None = None
    max_slope: float = 60.0
    min_area: float = 4.0
    min_points: int | None = None
    height_test: str = "normal"
    normal_neighbours: int = 12
    merge_distance: float | None = None
    max_normal_angle: float | None = None
    absorb_rounds: int = 3
    absorb_touching: bool = True
    absorb_min_height: float | None = None
    absorb_margin: float = 1.0
    min_width: float | None = optional(2.5)
    link_sectors: int | None = optional(8)
    sector_max_angle: float = 30.0
    sector_max_residual: float = 3.0

    def __post_init__(self) -> None:
        if not self.link_factor > 0:
            raise ValueError(f"segment.link_factor must be > 0, got {self.link_factor}")
        if self.height_test not in ("normal", "slope"):
            raise ValueError(f"segment.height_test must be 'normal' or 'slope', got {self.height_test!r}")
        if self.normal_neighbours < 3:
            raise ValueError(f"segment.normal_neighbours must be >= 3, got {self.normal_neighbours}")
        if not 0 <= self.absorb_margin <= 1:
            raise ValueError(f"segment.absorb_margin must be in [0, 1], got {self.absorb_margin}")
        for name in ("link_distance", "link_height", "min_area", "merge_distance"):
            v = getattr(self, name)
            if v is not None and not v > 0:
                raise ValueError(f"segment.{name} must be > 0, got {v}")
        if self.max_normal_angle is not None and not 0 < self.max_normal_angle <= 90:
            raise ValueError(f"segment.max_normal_angle must be in (0, 90] deg or None, got {self.max_normal_angle}")
        if not 0 <= self.max_slope < 90:
            raise ValueError(f"segment.max_slope must be in [0, 90) deg, got {self.max_slope}")
        if self.link_sectors is not None and not 3 <= self.link_sectors <= 32:
            raise ValueError(f"segment.link_sectors must be in 3..32 or unset, got {self.link_sectors}")
        if not self.sector_max_residual > 0:
            raise ValueError(f"segment.sector_max_residual must be > 0, got {self.sector_max_residual}")
        if not 0 < self.sector_max_angle <= 90:
            raise ValueError(f"segment.sector_max_angle must be in (0, 90] deg, got {self.sector_max_angle}")
        if self.min_points is not None and self.min_points < 1:
            raise ValueError(f"segment.min_points must be >= 1, got {self.min_points}")
        # heights above the ground model: below 0 the ground itself would be grown into roof levels
        if not self.min_height >= 0:
            raise ValueError(f"segment.min_height must be >= 0 m, got {self.min_height}")
        if self.absorb_min_height is not None and not self.absorb_min_height >= 0:
            raise ValueError(f"segment.absorb_min_height must be >= 0 m or unset, got {self.absorb_min_height}")


def link_pairs(xy: np.ndarray, link_distance: float) -> np.ndarray:
    """All pairs of points closer than ``link_distance`` in plan.

    Parameters
    ----------
    xy : ndarray of shape (N, 2), float64
    link_distance : float
        L_Dxy (m).

    Returns
    -------
    ndarray of shape (M, 2), int64
        Index pairs ``i < j``.
    """
    if len(xy) < 2:
        return np.empty((0, 2), np.int64)
    tree = cKDTree(np.asarray(xy)[:, :2])
    return tree.query_pairs(link_distance, output_type="ndarray").astype(np.int64, copy=False)


def sector_pairs(xy: np.ndarray, sources: np.ndarray, max_distance: float, n_sectors: int = 8, *,
                 normals: np.ndarray | None = None, max_angle: float = 30.0,
                 smooth: np.ndarray | None = None) -> np.ndarray:
    """Pairs of ``sources`` that are each other's nearest point in some direction, among all points.

    Scan lines farther apart than the points along them (low-density and
    older surveys; an oscillating mirror's lines pair up towards the swath
    edges, twice their mean spacing apart) leave no point of the next line
    within L_Dxy: a roof falls apart into strips one or two lines wide,
    which look linear and are too narrow for a building.  Every point is
    linked to the nearest point in each of ``n_sectors`` directions, so the
    links reach across a gap whatever its width, but only where no other
    point lies nearer in that direction: the nearest point beyond a roof's
    edge is on the wall or the ground (not a source), so the links do not
    jump from a roof to the crown beyond it.  On evenly sampled clouds these
    are pairs within L_Dxy anyway.  Where a crown overhangs a roof nothing
    lies between them; with ``normals`` a pair is kept only when its two
    normals differ by at most ``max_angle``, as on one roof face (the
    smoothness constraint of Rabbani et al. 2006; :func:`region_growing`
    does not need it within L_Dxy), and with ``smooth`` only when both lie
    on a smooth surface.

    Parameters
    ----------
    xy : ndarray of shape (N, 2), float64
        Plan coordinates (m) of every point (ground included).
    sources : ndarray of shape (S,), int
        Indices into ``xy`` of the points to link (the segmented points).
    max_distance : float
        Longest link (m): voids (water, occlusions) are not bridged.
    n_sectors : int, default 8
        Directions (equal angular sectors).
    normals : ndarray of shape (S, 3), optional
        Unit surface normals of the sources.
    max_angle : float, default 30.0
        Largest angle (deg, sign-free) between the normals of a pair, with ``normals``.
    smooth : ndarray of shape (S,), bool, optional
        Sources on a smooth surface; when given, only those are linked.

    Returns
    -------
    ndarray of shape (M, 2), int64
        Index pairs ``i < j`` into ``sources``.

    Examples
    --------
    Two scan lines 2 m apart, points 0.2 m apart along them, and a third
    line of ground points between the second and a fourth line:

    >>> x = np.arange(0, 4, 0.2)
    >>> xy = np.vstack([np.column_stack([x, y + 0 * x]) for y in (0.0, 2.0, 3.0, 4.0)])
    >>> pairs = sector_pairs(xy, np.r_[0:40, 60:80], 3.0)
    >>> lines = np.r_[0:40, 60:80] // 20
    >>> sorted({(int(lines[i]), int(lines[j])) for i, j in pairs})
    [(0, 0), (0, 1), (1, 1), (3, 3)]
    """
    sources = np.asarray(sources, dtype=np.int64)
    # only points that may be linked ask for their neighbours; every point answers
    asking = np.arange(len(sources)) if smooth is None else np.flatnonzero(smooth)
    nearest = sector_nearest(xy, sources[asking], max_distance, n_sectors)
    local = np.full(len(xy), -1, np.int64)
    local[sources] = np.arange(len(sources))
    a = np.repeat(asking, n_sectors)
    b = np.where(nearest.ravel() >= 0, local[nearest.ravel()], -1)
    ok = b >= 0
    a, b = a[ok], b[ok]
    if normals is not None:
        n = np.asarray(normals, dtype=np.float64)
        coherent = np.abs(np.einsum("ij,ij->i", n[a], n[b])) >= np.cos(np.radians(max_angle))
        a, b = a[coherent], b[coherent]
    if smooth is not None:
        both = np.asarray(smooth, dtype=bool)[a] & np.asarray(smooth, dtype=bool)[b]
        a, b = a[both], b[both]
    return unique_pairs(np.minimum(a, b), np.maximum(a, b), len(sources))


#: pairs tested at once by :func:`region_growing`
_PAIR_CHUNK = 2_000_000


def _linked(xyz, pairs, link_height, max_slope, normals, max_normal_angle) -> np.ndarray:
    """The height (or normal-distance) test of :func:`region_growing` for each pair."""
    if normals is not None:
        # one compiled pass: numpy's differences and normals of every pair
        # (72 bytes a pair) were a fifth of the segmentation's time
        min_cos = -2.0 if max_normal_angle is None else float(np.cos(np.radians(max_normal_angle)))
        return normal_links(xyz, np.ascontiguousarray(normals, np.float64), np.ascontiguousarray(pairs, np.int64),
                            float(link_height), min_cos)
    keep = np.empty(len(pairs), bool)
    # in chunks: the differences of all pairs at once were the peak memory
    # of a whole tile's detection
    for start in range(0, len(pairs), _PAIR_CHUNK):
        part = pairs[start:start + _PAIR_CHUNK]
        d = xyz[part[:, 0]] - xyz[part[:, 1]]
        dxy = np.hypot(d[:, 0], d[:, 1])
        keep[start:start + len(part)] = np.abs(d[:, 2]) < link_height + dxy * np.tan(np.radians(max_slope))
    return keep


def region_growing(
    xyz: np.ndarray,
    link_distance: float,
    link_height: float,
    max_slope: float = 60.0,
    *,
    pairs: np.ndarray | None = None,
    normals: np.ndarray | None = None,
    max_normal_angle: float | None = None,
) -> np.ndarray:
    """Label the roof-level clusters of non-ground points.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), float64
        Points to segment (m).
    link_distance : float
        L_Dxy (m).
    link_height : float
        L_Dh (m).
    max_slope : float, default 60.0
        Slope allowance (deg); 0 gives the thesis' test ``|dz| < L_Dh``.
    pairs : ndarray of shape (M, 2), optional
        Output of :func:`link_pairs` when already computed.
    normals : ndarray of shape (N, 3), optional
        Unit surface normals.  When given, the height difference is measured
        along each point's normal, ``|n_i·(p_j − p_i)| < L_Dh`` and
        ``|n_j·(p_i − p_j)| < L_Dh`` (on a flat roof exactly the thesis'
        ``|dz|``), and ``max_slope`` is not used: pitched roof planes stay whole
        while tree crowns, with no consistent normal, fall apart into small
        clusters.
    max_normal_angle : float, optional
        With ``normals``: pairs whose normals differ by more than this angle
        (deg; sign-free) are not linked either.  Default: no angle test.

    Returns
    -------
    ndarray of shape (N,), int64
        Cluster label per point, 0..K-1, numbered by :func:`order_labels`.

    Examples
    --------
    >>> x = np.arange(0, 5, 0.5)
    >>> p = np.vstack([np.column_stack([x, 0 * x, 0 * x]), np.column_stack([x, 0 * x + 0.2, 0 * x + 3])])
    >>> region_growing(p, 1.0, 0.2).tolist() == [0] * 10 + [1] * 10
    True
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    if pairs is None:
        pairs = link_pairs(xyz[:, :2], link_distance)
    keep = _linked(xyz, pairs, link_height, max_slope, normals, max_normal_angle)
    labels = components(len(xyz), pairs[keep])
    return order_labels(xyz, labels)


def merge_touching(labels: np.ndarray, pairs: np.ndarray, members: np.ndarray) -> np.ndarray:
    """Merge clusters that touch in plan into groups (buildings).

    Parameters
    ----------
    labels : ndarray of shape (N,), int
        Cluster label per point, 0..K-1; negative = no cluster.
    pairs : ndarray of shape (M, 2), int
        Plan-neighbour pairs (:func:`link_pairs`).
    members : ndarray of shape (K,), bool
        Clusters taking part (e.g. the building clusters).

    Returns
    -------
    ndarray of shape (K,), int64
        Group index per cluster (0..G-1 over members), -1 for non-members.
    """
    k = len(members)
    members = np.asarray(members, bool)
    touching = pairs[cross_pairs(labels, pairs, members, members)]
    comp = components(k, unique_pairs(labels[touching[:, 0]], labels[touching[:, 1]], k))
    group = np.full(k, -1, np.int64)
    _, group[members] = np.unique(comp[members], return_inverse=True)
    return group


def contact_share(labels: np.ndarray, pairs: np.ndarray, members: np.ndarray, others: np.ndarray) -> np.ndarray:
    """Fraction of each member cluster's points that have a plan neighbour in an ``others`` cluster.

    Parameters
    ----------
    labels : ndarray of shape (N,), int
        Cluster label per point, 0..K-1; negative = no cluster.
    pairs : ndarray of shape (M, 2), int
        Directed pairs (member point, neighbour point); pass both orders of
        :func:`link_pairs` for an undirected contact.
    members, others : ndarray of shape (K,), bool

    Returns
    -------
    ndarray of shape (K,), float64
        0 for clusters not in ``members`` (and for empty ones).
    """
    members, others = np.asarray(members, bool), np.asarray(others, bool)
    k = len(members)
    ok = cross_pairs(labels, pairs, members, others)
    touched = np.zeros(len(labels), bool)
    touched[pairs[ok, 0]] = True
    size = np.bincount(labels[labels >= 0], minlength=k)
    hits = np.bincount(labels[touched], minlength=k)
    return np.where(members & (size > 0), hits / np.maximum(size, 1), 0.0)


def join_strips(labels: np.ndarray, pairs: np.ndarray, z: np.ndarray, strips: np.ndarray, members: np.ndarray,
                max_drop: float, min_share: float = 0.25) -> np.ndarray:
    """Add to ``members`` the ``strips`` clusters lying beside one of them, repeatedly.

    A strip joins when ``min_share`` of its points have a plan neighbour in
    a member cluster that is not lower than them by more than ``max_drop``;
    the test is repeated so that a row of strips joins one after the other.

    Parameters
    ----------
    labels : ndarray of shape (N,), int
        Cluster label per point, 0..K-1; negative = no cluster.
    pairs : ndarray of shape (M, 2), int
        Plan-neighbour pairs (:func:`link_pairs`).
    z : ndarray of shape (N,), float64
        Heights of the points (m).
    strips, members : ndarray of shape (K,), bool
    max_drop : float
        How far a member's point may lie below the strip's point (m): a wire
        crossing over a roof touches it in plan too, but from above.
    min_share : float, default 0.25

    Returns
    -------
    ndarray of shape (K,), bool
        ``members`` with the joined strips.
    """
    members = np.asarray(members, bool).copy()
    on_strip = np.asarray(strips, bool)[labels]
    near = pairs[pair_mask(on_strip, pairs, False)]
    both = np.concatenate([near, near[:, ::-1]])
    below = both[z[both[:, 0]] <= z[both[:, 1]] + max_drop]
    while True:
        joins = strips & ~members & (contact_share(labels, below, strips, members) >= min_share)
        if not joins.any():
            return members
        members |= joins


def order_labels(xyz: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Renumber labels 0..K-1 by each group's lowest (x, y) point.

    Makes the numbering independent of the point order.  Negative labels
    stay -1.
    """
    labels = np.asarray(labels)
    out = np.full(len(labels), -1, np.int64)
    valid = labels >= 0
    if not valid.any():
        return out
    idx = np.flatnonzero(valid)
    uniq, inv = dense_unique(labels[idx])
    # the lexicographically smallest (x, y, z) of each group is its key;
    # one pass instead of a lexsort of every point
    first = lowest_point_per_group(np.ascontiguousarray(xyz, np.float64), idx, inv, len(uniq))
    key = np.lexsort((xyz[idx[first], 2], xyz[idx[first], 1], xyz[idx[first], 0]))
    rank = np.empty(len(uniq), np.int64)
    rank[key] = np.arange(len(uniq))
    out[idx] = rank[inv]
    return out
