"""Corners of a closed 3D contour: Douglas-Peucker in 3D plus a turning-angle filter (thesis §5.5).

The corners are the knots of the CD-spline: they split the ring into the
segments whose polynomial degree is chosen afterwards.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from numba import njit

__all__ = ["CornerOptions", "douglas_peucker", "ring_douglas_peucker", "turning_angles", "segment_deviation", "ring_corners"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class CornerOptions:
    """Options of the corner stage (TOML table ``[corners]``).

    Attributes
    ----------
    t_dist : float
        Douglas-Peucker distance threshold T_dist in metres (3D).  The thesis
        (§5.5, DESIGN.md stage 7) used 0.6 m; 0.3 m measured better on
        City3D/AHN3 at ~9 pts/m² (docs/design-notes.md).
    t_ang : float
        Turning-angle threshold T_ang in degrees (0 = straight on): corners
        turning less are redundant (thesis eq. 5.10; DESIGN.md: 50°).
    keep_curve_breaks : bool
        Beyond the thesis: keep a low-angle corner when removing it would
        leave a segment that is not straight (a point farther than ``t_dist``
        from the chord), so arcs keep their Douglas-Peucker vertices as knots
        and straight walls that run tangentially into an arc stay separate
        segments.  False (default) is the thesis's filter; the CD-spline stage
        splits badly fitting segments at the dropped vertices instead
        (``cdspline.split``), which measures better.
    """

    section = "corners"

    t_dist: float = 0.3
    t_ang: float = 50.0
    keep_curve_breaks: bool = False

    def __post_init__(self) -> None:
        if not self.t_dist > 0:
            raise ValueError(f"corners.t_dist must be > 0 m, not {self.t_dist}")
        if not 0 <= self.t_ang < 180:
            raise ValueError(f"corners.t_ang must be in [0, 180) degrees, not {self.t_ang}")


def _point_segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    den = float(ab @ ab)
    if den == 0:
        return np.linalg.norm(p - a, axis=1)
    s = np.clip((p - a) @ ab / den, 0.0, 1.0)
    return np.linalg.norm(p - (a + s[:, None] * ab), axis=1)


def douglas_peucker(points: np.ndarray, tolerance: float) -> np.ndarray:
    """Douglas-Peucker on an open polyline, in as many dimensions as ``points`` has.

    Parameters
    ----------
    points : ndarray of shape (N, D) float64
    tolerance : float
        Largest distance (same units) a dropped vertex may have to the kept polyline.

    Returns
    -------
    ndarray of int64
        Sorted indices of the kept vertices, always including 0 and N-1.
    """
    points = np.ascontiguousarray(points, dtype=np.float64)
    if len(points) < 2:
        return np.arange(len(points), dtype=np.int64)
    return np.flatnonzero(_douglas_peucker(points, float(tolerance)))


@njit(cache=True)
def _douglas_peucker(points, tolerance):  # pragma: no cover - compiled
    # thousands of small spans per building (corners, candidates, wall height profiles): numpy's
    # per-call overhead on each span made the Python loop 7 % of the outline stage
    n, dim = points.shape
    keep = np.zeros(n, np.bool_)
    keep[0] = keep[n - 1] = True
    stack = np.empty((2 * n, 2), np.int64)
    stack[0, 0], stack[0, 1] = 0, n - 1
    top = 1
    while top > 0:
        top -= 1
        i, j = stack[top, 0], stack[top, 1]
        if j <= i + 1:
            continue
        den = 0.0
        for d in range(dim):
            den += (points[j, d] - points[i, d]) ** 2
        best, k = -1.0, i + 1
        for m in range(i + 1, j):
            s = 0.0
            if den > 0:
                for d in range(dim):
                    s += (points[m, d] - points[i, d]) * (points[j, d] - points[i, d])
                s = min(max(s / den, 0.0), 1.0)
            dist = 0.0
            for d in range(dim):
                e = points[m, d] - (points[i, d] + s * (points[j, d] - points[i, d]))
                dist += e * e
            dist = np.sqrt(dist)
            if dist > best:
                best, k = dist, m
        if best > tolerance:
            keep[k] = True
            stack[top, 0], stack[top, 1] = i, k
            stack[top + 1, 0], stack[top + 1, 1] = k, j
            top += 2
    return keep


def _closed_dp(points: np.ndarray, start: int, tolerance: float) -> np.ndarray:
    n = len(points)
    rolled = np.roll(points, -start, axis=0)
    far = int(np.argmax(np.linalg.norm(rolled - rolled[0], axis=1)))
    closed = np.concatenate([rolled, rolled[:1]])
    first = douglas_peucker(closed[: far + 1], tolerance)
    second = douglas_peucker(closed[far:], tolerance) + far
    idx = np.unique(np.concatenate([first, second[:-1]]))
    return np.sort((idx + start) % n)


def ring_douglas_peucker(points: np.ndarray, tolerance: float) -> np.ndarray:
    """Critical vertices of a closed ring by Douglas-Peucker, vertex 0 not forced (thesis §5.5).

    Runs once from vertex 0 (and the vertex farthest from it), then again
    from the sharpest vertex found, so vertex 0 stays only if it is critical.
    Returns sorted ring indices.
    """
    points = np.asarray(points, dtype=np.float64)
    if len(points) < 4:
        return np.arange(len(points), dtype=np.int64)
    first = _closed_dp(points, 0, tolerance)
    sharpest = int(first[np.argmax(turning_angles(points, first))]) if len(first) >= 3 else int(first[-1])
    return _closed_dp(points, sharpest, tolerance).astype(np.int64)


def turning_angles(points: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Turning angle in degrees at each corner of a closed polygon (eq. 5.10; 0 = straight on)."""
    c = points[corners]
    v1 = c - np.roll(c, 1, axis=0)
    v2 = np.roll(c, -1, axis=0) - c
    den = np.linalg.norm(v1, axis=1) * np.linalg.norm(v2, axis=1)
    cos = np.einsum("ij,ij->i", v1, v2) / np.where(den > 0, den, 1.0)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def segment_deviation(points: np.ndarray, i: int, j: int) -> float:
    """Largest distance of the ring's points from ``i`` to ``j`` (cyclic) to the chord i-j."""
    n = len(points)
    idx = np.arange(i, i + ((j - i) % n or n) + 1) % n
    return float(_point_segment_distance(points[idx], points[i], points[j]).max(initial=0.0))


def ring_corners(points: np.ndarray, options: CornerOptions | None = None) -> np.ndarray:
    """Corners of a closed 3D ring.

    Parameters
    ----------
    points : ndarray of shape (N, 3) float64
        Ordered ring vertices (first not repeated), metres.
    options : CornerOptions, optional

    Returns
    -------
    ndarray of int64
        Sorted indices of the corners (at least 2 when N >= 2).

    Notes
    -----
    Douglas-Peucker runs once from vertex 0 (and the vertex farthest from it),
    then again from the sharpest corner found, so vertex 0 is kept only if it
    is itself critical (thesis §5.5).  Corners whose turning angle is below
    ``t_ang`` are then removed one at a time, smallest angle first.

    Examples
    --------
    >>> import numpy as np
    >>> side = np.linspace(0, 1, 10, endpoint=False)[:, None]
    >>> square = np.concatenate([np.hstack([side * 10, 0 * side]), np.hstack([10 + 0 * side, side * 10]),
    ...                          np.hstack([10 - side * 10, 10 + 0 * side]), np.hstack([0 * side, 10 - side * 10])])
    >>> ring = np.roll(np.column_stack([square, np.zeros(40)]), 5, axis=0)  # start mid-side
    >>> ring_corners(ring).tolist()
    [5, 15, 25, 35]
    """
    options = options or CornerOptions()
    points = np.asarray(points, dtype=np.float64)
    n = len(points)
    if n < 4:
        return np.arange(n, dtype=np.int64)
    corners = list(ring_douglas_peucker(points, options.t_dist))
    locked: set[int] = set()
    while len(corners) > 3:
        c = np.asarray(corners)
        ang = turning_angles(points, c)
        order = np.argsort(ang, kind="stable")
        removed = False
        for k in order:
            if ang[k] >= options.t_ang:
                break
            if c[k] in locked:
                continue
            prev, nxt = c[k - 1], c[(k + 1) % len(c)]
            if options.keep_curve_breaks and segment_deviation(points, prev, nxt) > options.t_dist:
                locked.add(int(c[k]))
                continue
            del corners[k]
            removed = True
            break
        if not removed:
            break
        locked.clear()  # neighbours changed: earlier refusals may no longer hold
    log.debug("corners: %d of %d ring vertices", len(corners), n)
    return np.asarray(corners, dtype=np.int64)
