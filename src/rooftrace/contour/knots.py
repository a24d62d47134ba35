"""Knot placement for the CD-spline beyond the thesis: corner refinement and segment splitting.

The thesis's knots are the Douglas-Peucker corners that survive the angle
filter.  A wall that runs tangentially into an arc has no corner there, so
its straight and curved parts end up in one high-degree segment; splitting
such a segment at a finer Douglas-Peucker vertex gives a line plus a curve.
"""

from __future__ import annotations

import numpy as np

from rooftrace.contour.cdspline import CDSpline, CDSplineOptions, fit_cdspline, iterative_cdspline
from rooftrace.errors import GeometryError

__all__ = ["refine_corners", "spline_outline"]


def refine_corners(points: np.ndarray, corners: np.ndarray, rounds: int = 2) -> np.ndarray:
    """Move each corner to the ring point nearest its corner in an all-straight least-squares fit.

    Returns sorted unique ring indices (corners that collapse are merged).
    """
    corners = np.unique(np.asarray(corners, dtype=np.int64))
    if len(corners) < 3:
        return corners
    for _ in range(rounds):
        fit = fit_cdspline(points, corners, [1] * len(corners))
        # the all-straight fit's control points are the fitted corners, in corner order
        d = np.linalg.norm(points[None, :, :2] - fit.control_points[:, None, :2], axis=2)
        moved = np.unique(np.argmin(d, axis=1))
        if len(moved) < 3 or np.array_equal(moved, corners):
            break
        corners = moved
    return corners


def _merge_collinear(points: np.ndarray, corners: np.ndarray, fit: CDSpline, options: CDSplineOptions):
    """Drop corners between two straight segments whose fitted directions differ by < ``merge_angle``.

    Douglas-Peucker on a ragged alpha boundary leaves extra vertices along
    straight walls; the fitted control points are far less noisy than the
    boundary points, so the angle is measured on them.  Non-adjacent corners
    go in one batch, then the curve is refitted, until none is left.
    """
    for _ in range(len(corners)):
        deg = np.asarray(fit.degrees)
        m = len(corners)
        if m <= 3:
            break
        offsets = np.concatenate([[0], np.cumsum(deg)])
        ctrl = fit.control_points[:, :2]
        start = ctrl[offsets[:-1] % len(ctrl)]
        end = ctrl[offsets[1:] % len(ctrl)]
        d = end - start
        d_in = np.roll(d, 1, axis=0)  # segment k-1 ends at corner k
        cos = np.einsum("ij,ij->i", d_in, d) / np.maximum(np.linalg.norm(d_in, axis=1) * np.linalg.norm(d, axis=1), 1e-12)
        angle = np.degrees(np.arccos(np.clip(cos, -1, 1)))
        straight = (deg == 1) & (np.roll(deg, 1) == 1)
        cand = np.flatnonzero(straight & (angle < options.merge_angle))
        if len(cand) == 0:
            break
        cand = cand[np.argsort(angle[cand], kind="stable")]
        drop: list[int] = []
        for k in cand:  # not two neighbours at once: the merged direction changes
            if all(abs(k - j) not in (1, m - 1) for j in drop) and m - len(drop) > 3:
                drop.append(int(k))
        keep = np.setdiff1d(np.arange(m), drop)
        new_corners = corners[keep]
        # the merged segment keeps the degree of the segment it starts with (1 on both sides)
        new_deg = deg[keep]
        try:
            fit = fit_cdspline(points, new_corners, new_deg)
        except GeometryError:
            break
        corners = new_corners
    return corners, fit


def spline_outline(points: np.ndarray, corners: np.ndarray, candidates: np.ndarray | None = None,
                   options: CDSplineOptions | None = None) -> CDSpline:
    """Refined corners, iterative CD-spline, and splitting of segments that need degree >= 4.

    Parameters
    ----------
    points : ndarray of shape (Q, 3) float64
        Closed ring.
    corners : ndarray of int
        Knots (thesis corners).
    candidates : ndarray of int, optional
        Extra ring indices where a segment may be split (the Douglas-Peucker
        vertices the angle filter dropped).
    options : CDSplineOptions, optional
    """
    options = options or CDSplineOptions()
    corners = np.unique(np.asarray(corners, dtype=np.int64))
    if options.refine and len(corners) >= 3:
        try:
            corners = refine_corners(points, corners, options.refine)
        except GeometryError:
            pass
    fit = iterative_cdspline(points, corners, options)
    if options.merge_angle > 0:
        corners, fit = _merge_collinear(points, corners, fit, options)
    if not options.split or candidates is None or len(candidates) == 0:
        return fit
    q = len(points)
    changed = True
    while changed:
        changed = False
        for k in np.flatnonzero(np.asarray(fit.degrees) >= 4):
            lo = corners[k]
            hi = corners[k + 1] if k + 1 < len(corners) else corners[0] + q
            inside = [int(c) for c in candidates if lo < c < hi or lo < c + q < hi]
            best = None
            for c in inside:
                trial = np.unique(np.append(corners, c % q))
                try:
                    new = iterative_cdspline(points, trial, options)
                except GeometryError:
                    continue
                if (sum(new.degrees) <= sum(fit.degrees) + 1 and new.sigma <= 1.02 * fit.sigma
                        and (best is None or new.sigma < best[1].sigma)):
                    best = (trial, new)
            if best is not None:
                corners, fit = best
                changed = True
                break
    return fit
