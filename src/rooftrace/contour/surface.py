"""Which of a building's points lie on its roof surface, and which below it (walls, points under eaves).

Beyond the thesis.  Its alpha shape is traced from the roof points its
region growing found; our detection (like AHN's class 6) also gives a building
the wall points and the points under its eaves, because that is what a user
expects of a classified cloud.  Those points lie inside the roof's plan outline
or on it (a wall with no overhang), but metres below the eave, and an outline
vertex taken from them carries a wall's height instead of the eave's — and the
3D Douglas-Peucker of the corner search sees every jump between eave and wall
as a corner.  A point is *below the roof* when some point within ``radius`` in
plan is higher than a roof of slope ``max_slope`` through it could explain
(plus ``tolerance``); those points are lifted to the height of the nearest
roof point before the outline is traced.

No library does this test; it runs on the pairs of points closer than
``radius`` in plan (``cKDTree.query_pairs``), vectorised over the pairs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numba import njit
from scipy.spatial import cKDTree

__all__ = ["SurfaceOptions", "below_roof", "lift_to_roof", "outline_points"]


@dataclass(frozen=True)
class SurfaceOptions:
    """Options of the roof-surface filter (TOML table ``[surface]``).

    Attributes
    ----------
    enabled : bool, default True
        False traces the outline from the points as they are (the thesis).
    radius_factor : float, default 2.0
        Search radius in plan, as a multiple of the mean point spacing.
    max_slope : float, default 60.0
        Steepest roof (degrees) whose height change over a distance is not a wall.
    tolerance : float, default 0.3
        Height (m) a point may lie below what the slope allowance explains
        (range noise, gutters).  0.5 m leaves the top of a wall flush with
        the eave in the outline, with a corner at every dip.
    """

    section: ClassVar[str] = "surface"
    enabled: bool = True
    radius_factor: float = 2.0
    max_slope: float = 60.0
    tolerance: float = 0.3

    def __post_init__(self) -> None:
        if not self.radius_factor > 0:
            raise ValueError(f"surface.radius_factor must be > 0, got {self.radius_factor}")
        if not 0 <= self.max_slope < 90:
            raise ValueError(f"surface.max_slope must be in [0, 90) deg, got {self.max_slope}")
        if not self.tolerance >= 0:
            raise ValueError(f"surface.tolerance must be >= 0, got {self.tolerance}")


def below_roof(xyz: np.ndarray, radius: float, *, max_slope: float = 60.0, tolerance: float = 0.3) -> np.ndarray:
    """Flag points that lie below a higher roof point nearby (walls, points under eaves).

    Point *i* is below the roof when a point *j* closer than ``radius`` in
    plan satisfies ``z_j - z_i > tolerance + d_ij · tan(max_slope)``, with
    ``d_ij`` the plan distance.  A sloped roof never flags itself: its rise over ``d`` is at
    most ``d · tan(max_slope)``.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3)
        One building's points, metres.
    radius : float
        Plan search radius (m), about twice the point spacing so that every
        wall point has a roof point in its neighbourhood.
    max_slope : float, default 60.0
        Degrees.
    tolerance : float, default 0.3
        Metres.

    Returns
    -------
    ndarray of shape (N,), bool
        True for points below the roof surface.

    Examples
    --------
    >>> roof = np.array([[x, y, 10.0] for x in range(5) for y in range(5)], float)
    >>> wall = np.array([[0.0, 2.0, z] for z in (2.0, 5.0, 9.8)])
    >>> below_roof(np.vstack([roof, wall]), 1.0)[-3:].tolist()
    [True, True, False]
    """
    return _below(np.asarray(xyz, dtype=np.float64), radius, max_slope, tolerance)[0]


def lift_to_roof(xyz: np.ndarray, radius: float, *, max_slope: float = 60.0, tolerance: float = 0.3) -> np.ndarray:
    """Give every point below the roof (see :func:`below_roof`) the height of its nearest roof point in plan.

    The points keep their plan position, so the alpha shape traced from
    them is the one of all the building's points (removing wall points
    would open gaps at steps between roof levels and split the building);
    only their height changes, to the height of the roof above them.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3)
    radius, max_slope, tolerance
        As in :func:`below_roof`.

    Returns
    -------
    ndarray of shape (N, 3)
        A copy; points with no roof point within ``radius`` keep their height.

    Examples
    --------
    >>> roof = np.array([[x, y, 10.0] for x in range(5) for y in range(5)], float)
    >>> wall = np.array([[0.0, 2.2, 3.0]])
    >>> lift_to_roof(np.vstack([roof, wall]), 1.0)[-1].tolist()
    [0.0, 2.2, 10.0]
    """
    xyz = np.array(xyz, dtype=np.float64)
    flagged, i, j, d = _below(xyz, radius, max_slope, tolerance)
    # nearest roof point first, ties to the lower index (deterministic), over both directions of every pair
    roof = _nearest_unflagged(flagged, i, j, d)
    has = roof >= 0
    xyz[has, 2] = xyz[roof[has], 2]
    return xyz


@njit(cache=True)
def _nearest_unflagged(flagged, i, j, d):  # pragma: no cover - compiled
    # for every flagged point the nearest unflagged one it is paired with (-1: none); the pairs come
    # by the million on a large roof, and the sort of both directions of every pair took longer
    best = np.full(len(flagged), np.inf)
    roof = np.full(len(flagged), -1, np.int64)
    for k in range(len(i)):
        a, b, dk = i[k], j[k], d[k]
        for src, dst in ((a, b), (b, a)):
            if flagged[src] and not flagged[dst] and (dk < best[src] or (dk == best[src] and dst < roof[src])):
                best[src] = dk
                roof[src] = dst
    return roof


def _below(xyz: np.ndarray, radius: float, max_slope: float, tolerance: float):
    if not radius > 0:
        raise ValueError(f"below_roof: radius must be > 0, got {radius}")
    flagged = np.zeros(len(xyz), bool)
    empty = np.zeros(0, np.int64)
    if len(xyz) < 2:
        return flagged, empty, empty, np.zeros(0)
    pairs = cKDTree(xyz[:, :2]).query_pairs(radius, output_type="ndarray")
    if len(pairs) == 0:
        return flagged, empty, empty, np.zeros(0)
    i, j = np.ascontiguousarray(pairs[:, 0]), np.ascontiguousarray(pairs[:, 1])
    d = _flag_below(xyz, i, j, tolerance, float(np.tan(np.radians(max_slope))), flagged)
    return flagged, i, j, d


@njit(cache=True)
def _flag_below(xyz, i, j, tolerance, slope, flagged):  # pragma: no cover - compiled
    # the plan distance of every pair (hypot, as numpy's) and the flags, in one pass over the pairs
    d = np.empty(len(i))
    for k in range(len(i)):
        a, b = i[k], j[k]
        d[k] = np.hypot(xyz[a, 0] - xyz[b, 0], xyz[a, 1] - xyz[b, 1])
        allowance = tolerance + d[k] * slope
        dz = xyz[b, 2] - xyz[a, 2]
        if dz > allowance:
            flagged[a] = True
        if -dz > allowance:
            flagged[b] = True
    return d


def outline_points(xyz: np.ndarray, options: SurfaceOptions | None = None,
                   mean_spacing: float | None = None, *, walls: bool = False):
    """The points an outline is traced from: one per plan position (the highest), at roof height.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3)
        One building's points, metres.
    options : SurfaceOptions, optional
    mean_spacing : float, optional
        Point spacing (m); estimated from nearest neighbours when not given.
    walls : bool, default False
        Also return which of the points were below the roof (lifted to it):
        walls, points under eaves, clutter taken in at a wall's foot.

    Returns
    -------
    points : ndarray of shape (M, 3), M <= N
        In input order.
    below : ndarray of shape (M,), bool
        Only with ``walls``: True for the points lifted to the roof.
    """
    options = options or SurfaceOptions()
    lifted = np.zeros(len(xyz), bool)
    if options.enabled and len(xyz) >= 4:
        spacing = mean_spacing if mean_spacing else _nn_spacing(xyz[:, :2])
        if spacing > 0:
            moved = lift_to_roof(xyz, options.radius_factor * spacing, max_slope=options.max_slope,
                                 tolerance=options.tolerance)
            # a flagged point with no roof point near keeps its height: it marks no wall
            lifted = moved[:, 2] != xyz[:, 2]
            xyz = moved
    # points sharing a plan position (a wall seen from two strips): keep the highest, it is the roof
    order = np.lexsort((-xyz[:, 2], xyz[:, 1], xyz[:, 0]))
    keep = np.ones(len(order), bool)
    keep[1:] = np.any(xyz[order][1:, :2] != xyz[order][:-1, :2], axis=1)
    kept = np.sort(order[keep])
    return (xyz[kept], lifted[kept]) if walls else xyz[kept]


def _nn_spacing(xy: np.ndarray) -> float:
    d, _ = cKDTree(xy).query(xy, k=2)
    return float(np.median(d[:, 1]))
