"""The CD-spline basis with C0 joints and chord-length parameters (thesis §5.2-5.4, eq. 5.3-5.5).

With C0 joints (knot multiplicity = degree) the normalised basis of a
changeable-degree spline is, span by span, the Bernstein basis of the span's
degree in its local parameter; each span's basis comes from the Cox-de Boor
recursion on a clamped knot vector of the span's degree.  Written here
because scipy's B-splines have one degree for the whole curve.

Notes
-----
Eq. 5.5 as printed in the thesis (denominators indexed by the recursion
level k instead of the span's degree) does not give a partition of unity
when a lower-degree span precedes a higher-degree one, so it is not used
literally; for C0 joints the basis below is the unique normalised B-basis of
the same spline space.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from rooftrace.errors import GeometryError

__all__ = ["chord_parameters", "span_basis", "cd_basis"]


def chord_parameters(points: np.ndarray, closed: bool = True) -> np.ndarray:
    """Chord-length parameters (eq. 5.3-5.4).

    Returns ``t`` of shape (N,), ``t[0] = 0``, increasing; for a closed ring
    the closing chord counts in L, so ``t = 1`` is the first point again.
    """
    points = np.asarray(points, dtype=np.float64)
    ends = np.concatenate([points, points[:1]]) if closed else points
    chords = np.linalg.norm(np.diff(ends, axis=0), axis=1)
    total = chords.sum()
    if total <= 0:
        raise GeometryError("degenerate_ring")
    return np.concatenate([[0.0], np.cumsum(chords)[: len(points) - 1]]) / total


def span_basis(t: np.ndarray, knots: np.ndarray, degree: int) -> np.ndarray:
    """B-spline basis of ``degree`` on ``knots`` at ``t`` (right end included); (len(t), len(knots)-degree-1)."""
    # compiled: the CD-spline calls this for every span of every trial degree,
    # thousands of small arrays per building (numpy's temporaries dominated)
    return cox_de_boor(np.ascontiguousarray(t, dtype=np.float64), np.ascontiguousarray(knots, dtype=np.float64),
                       int(degree))


@njit(cache=True, error_model="numpy")
def cox_de_boor(t, knots, degree):  # pragma: no cover - compiled
    """:func:`span_basis` for contiguous float64 ``t`` and ``knots``, callable from compiled fits."""
    # Cox-de Boor, row by row, with the float operations of the numpy form it
    # replaced (each ratio only where its denominator is positive, else 0;
    # left * b[c] + right * b[c + 1]), so the values are identical
    n0 = len(knots) - 1
    last = knots[n0]
    j_end = -1
    for c in range(n0):
        if knots[c] < last:
            j_end = c
    out = np.empty((len(t), n0 - degree))
    b = np.empty(n0)
    for r in range(len(t)):
        x = t[r]
        if x == last:
            for c in range(n0):
                b[c] = 0.0
            b[j_end] = 1.0
        else:
            for c in range(n0):
                b[c] = 1.0 if knots[c] <= x and x < knots[c + 1] else 0.0
        for p in range(1, degree + 1):
            for c in range(n0 - p):
                left_den = knots[c + p] - knots[c]
                right_den = knots[c + p + 1] - knots[c + 1]
                left = (x - knots[c]) / left_den if left_den > 0 else 0.0
                right = (knots[c + p + 1] - x) / right_den if right_den > 0 else 0.0
                b[c] = left * b[c] + right * b[c + 1]
        for c in range(n0 - degree):
            out[r, c] = b[c]
    return out


def cd_basis(t: np.ndarray, breaks: np.ndarray, degrees, closed: bool = True) -> np.ndarray:
    """CD-spline design matrix A (eq. 5.8) for C0 joints.

    Parameters
    ----------
    t : ndarray of shape (Q,) float64
        Parameters in ``[breaks[0], breaks[-1]]``.
    breaks : ndarray of shape (M+1,) float64
        Increasing knot values: segment k spans ``[breaks[k], breaks[k+1])``.
    degrees : sequence of M int
        Degree d_k of each segment (>= 1).
    closed : bool
        Close the curve: the last control point is the first (its column is
        added onto the first, thesis §5.4).

    Returns
    -------
    ndarray of shape (Q, sum(d)) if closed else (Q, sum(d) + 1)
        Column ``offset_k + r`` holds the r-th basis function of segment k,
        ``offset_k = sum(d[:k])``; neighbouring segments share a column.

    Examples
    --------
    >>> a = cd_basis([0.0, 0.25, 0.5, 0.75], [0.0, 0.5, 1.0], [1, 2])
    >>> a.round(3).tolist()
    [[1.0, 0.0, 0.0], [0.5, 0.5, 0.0], [0.0, 1.0, 0.0], [0.25, 0.25, 0.5]]
    """
    t = np.asarray(t, dtype=np.float64)
    breaks = np.asarray(breaks, dtype=np.float64)
    degrees = [int(d) for d in degrees]
    if len(breaks) != len(degrees) + 1 or np.any(np.diff(breaks) <= 0):
        raise ValueError("cd_basis: breaks must be increasing with one more value than degrees")
    offsets = np.concatenate([[0], np.cumsum(degrees)])
    a = np.zeros((len(t), offsets[-1] + 1))
    span = np.clip(np.searchsorted(breaks, t, side="right") - 1, 0, len(degrees) - 1)
    # only the spans that hold parameters, each one's rows found by one sort (a ring has hundreds
    # of segments, and a mask of all rows per span cost more than the basis)
    order = np.argsort(span, kind="stable")
    bounds = np.searchsorted(span[order], np.arange(len(degrees) + 1))
    for k in np.flatnonzero(np.diff(bounds)).tolist():
        d = degrees[k]
        rows = order[bounds[k]:bounds[k + 1]]
        knots = np.concatenate([np.full(d + 1, breaks[k]), np.full(d + 1, breaks[k + 1])])
        a[rows[:, None], np.arange(offsets[k], offsets[k] + d + 1)] = span_basis(t[rows], knots, d)
    if closed:
        a[:, 0] += a[:, -1]
        a = a[:, :-1]
    return a
