"""Building shapes from fitted lines: model selection on the traced boundary (beyond the thesis).

The alpha-shape ring runs through the outermost roof points, so it is as
jagged as the sampling: its Douglas-Peucker corners sit on noisy points and
a straight wall often gets extra corners.  Here every segment between two
corners becomes a model of the boundary points it holds — a straight line
(robust total least squares) or, when the data asks for it, the CD-spline's
curve — and the shape is simplified while an information criterion (BIC)
says the simpler model explains the points as well:

- a segment is curved only if its spline beats the line by more than the
  noise the sampling implies (a boundary point lies anywhere within one
  sampling step across the edge, a standard deviation of ``noise_factor``
  times that step, the floor of every residual variance below; the step is
  measured behind each ring point, :func:`boundary_step`); a run of short
  lines along one arc becomes a curve on the same criterion;
- neighbouring lines merge, and short runs of segments (notches, small loops,
  cut corners) are dropped, when the simpler shape's BIC is lower;
- walls take the building's dominant direction (or its perpendicular) when
  the constrained fit's BIC beats the free one, wall by wall;
- corners are where neighbouring lines meet, so straight walls are exactly
  straight and corners do not sit on points.

Narrow inlets of the ring (no points on a step between two roof levels) are
bridged first by a morphological closing.  The edge position is handled by
:mod:`rooftrace.contour.edge`.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import shapely
from numba import njit
from scipy.spatial import cKDTree

from rooftrace.contour.cdspline import fit_cdspline
from rooftrace.contour.corners import douglas_peucker
from rooftrace.contour.edge import EdgeContext, edge_shift
from rooftrace.errors import GeometryError

__all__ = ["Line", "Curve", "LineOutline", "line_outline", "fit_line", "segment_bic", "bridge_inlets",
           "dominant_wall_direction", "simplify_lines", "constrain_directions", "line_corners", "boundary_step",
           "curved_runs", "chord_curve"]

log = logging.getLogger(__name__)

#: lines meeting at less than this angle (degrees) are parallel: a step (jog) joins them, not an intersection
_PARALLEL_DEG = 15.0
#: two lines splitting a curved segment turn by at least this (degrees) where the curve hides a corner
_CORNER_DEG = 45.0
#: a wall within this angle (degrees) of the dominant direction or its perpendicular is a candidate for it
_DIRECTION_DEG = 20.0


@dataclass(eq=False)
class Line:
    """A straight segment's model: the boundary points it holds and its fitted line.

    Attributes
    ----------
    idx : ndarray of int
        Ring indices of its points, in ring order.
    point : ndarray of shape (2,)
        A point on the line (the robust centroid), metres.
    direction : ndarray of shape (2,)
        Unit direction, along the ring's direction of travel.
    rss : float
        Sum of squared distances of its points to the line, m².
    free : bool
        False when the direction was fixed to the dominant one (one parameter less).
    span : float
        Extent of its points along the line, metres.
    noise2 : float
        Mean squared noise floor σ0² of its points, m².
    """

    idx: np.ndarray
    point: np.ndarray
    direction: np.ndarray
    rss: float
    free: bool = True
    span: float = 0.0
    noise2: float = 0.0

    @property
    def normal(self) -> np.ndarray:
        """Unit normal to the right of the direction of travel: outwards, the roof being on the left."""
        return np.array([self.direction[1], -self.direction[0]])

    @property
    def n_params(self) -> int:
        return 2 if self.free else 1


def fit_line(xy: np.ndarray, sigma0: float, direction: np.ndarray | None = None, rounds: int = 3):
    """Robust total-least-squares line (Huber weights), or the best line of a given direction.

    Parameters
    ----------
    xy : ndarray of shape (n, 2) float64
        Points in travel order (their first-to-last vector orients the line).
    sigma0 : float
        Noise floor in metres; the Huber threshold is 1.5 times the larger of it
        and the robust scale of the residuals.
    direction : ndarray of shape (2,), optional
        Fixed unit direction; only the offset is fitted.
    rounds : int
        Reweighting rounds.

    Returns
    -------
    point, direction : ndarray of shape (2,)
    rss : float
        Unweighted sum of squared distances, m².
    """
    xy = np.ascontiguousarray(xy, dtype=np.float64)
    fixed = direction is not None
    d0 = np.asarray(direction, dtype=np.float64) if fixed else np.zeros(2)
    cx, cy, dx, dy, rss = _fit_line(xy, float(sigma0), float(d0[0]), float(d0[1]), fixed, int(rounds))
    return np.array([cx, cy]), np.array([dx, dy]), rss


@njit(cache=True)
def _fit_line(xy, sigma0, dx, dy, fixed, rounds):  # pragma: no cover - compiled
    # thousands of small fits per building while the model is chosen: numpy's per-call overhead
    # (average, eigh, median) made the choice ten times slower than the whole CD-spline
    n = xy.shape[0]
    w = np.ones(n)
    r = np.zeros(n)
    cx = cy = 0.0
    for _ in range(rounds + 1):
        sw = w.sum()
        cx = (w * xy[:, 0]).sum() / sw
        cy = (w * xy[:, 1]).sum() / sw
        if not fixed:
            ex = xy[:, 0] - cx
            ey = xy[:, 1] - cy
            sxx = (w * ex * ex).sum()
            syy = (w * ey * ey).sum()
            sxy = (w * ex * ey).sum()
            phi = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)  # major axis of the 2x2 scatter matrix
            dx, dy = np.cos(phi), np.sin(phi)
        r = (xy[:, 0] - cx) * dy - (xy[:, 1] - cy) * dx
        med = np.median(r)
        scale = max(sigma0, 1.4826 * np.median(np.abs(r - med)))
        for i in range(n):
            a = abs(r[i])
            w[i] = 1.0 if a <= 1.5 * scale else 1.5 * scale / max(a, 1e-12)
    if dx * (xy[n - 1, 0] - xy[0, 0]) + dy * (xy[n - 1, 1] - xy[0, 1]) < 0:
        dx, dy = -dx, -dy
    return cx, cy, dx, dy, (r * r).sum()


def segment_bic(rss: float, n: int, n_params: float, sigma0: float) -> float:
    """BIC of a boundary model with ``n_params`` parameters: n·ln(max(rss/n, σ0²)) + k·ln(n).

    The floor σ0² is the residual variance the sampling alone gives a perfect
    model: below it a better fit is noise, and buys no parameter.
    """
    return float(_bic(float(rss), int(n), float(n_params), float(sigma0)))


def bridge_inlets(xy: np.ndarray, width: float) -> np.ndarray:
    """Ring points left after closing the ring's inlets narrower than ``width`` (morphological closing).

    Parameters
    ----------
    xy : ndarray of shape (N, 2) float64
        Outer ring, first point not repeated.
    width : float
        Metres; 0 keeps every point.

    Returns
    -------
    ndarray of bool, shape (N,)
        True for the points still on the closed outline.  Mitred buffers keep
        straight walls and corners exactly, so only the inlets lose points.
    """
    keep = np.ones(len(xy), bool)
    if width <= 0 or len(xy) < 4:
        return keep
    poly = shapely.Polygon(xy)
    if not poly.is_valid or poly.area <= 0:
        return keep
    closed = poly.buffer(width / 2, join_style="mitre", mitre_limit=10.0).buffer(
        -width / 2, join_style="mitre", mitre_limit=10.0)
    if not isinstance(closed, shapely.Polygon) or closed.is_empty:
        return keep
    d = shapely.distance(shapely.points(xy), closed.exterior)
    keep = d <= 1e-6 * max(1.0, float(np.abs(xy).max()))
    return keep if keep.sum() >= 4 else np.ones(len(xy), bool)


def _noise(sigma0, n: int) -> np.ndarray:
    """σ0 per ring point (a scalar is the same everywhere)."""
    return np.ascontiguousarray(np.broadcast_to(np.asarray(sigma0, dtype=np.float64), (n,)))


def _fit(xy_ring: np.ndarray, idx: np.ndarray, sigma0: np.ndarray, trim: int) -> Line:
    idx = np.ascontiguousarray(idx, dtype=np.int64)
    if np.ndim(sigma0) == 0:
        sigma0 = _noise(sigma0, len(xy_ring))
    cx, cy, dx, dy, rss, span, noise2 = _fit_segment(xy_ring, idx, sigma0, trim)
    return Line(idx, np.array([cx, cy]), np.array([dx, dy]), rss, span=span, noise2=noise2)


def _pooled(lines) -> float:
    """The noise floor σ0 of the points of several lines together, metres."""
    n = sum(len(ln.idx) for ln in lines)
    return float(np.sqrt(sum(len(ln.idx) * ln.noise2 for ln in lines) / max(n, 1)))


@njit(cache=True)
def _fit_segment(xy, idx, sigma0, trim):  # pragma: no cover - compiled
    # corners of the alpha shape are cut off (few points reach into them): the points at either end
    # of a segment bend away from its wall, so long segments are fitted without them
    n = len(idx)
    noise2 = 0.0
    for i in idx:
        noise2 += sigma0[i] * sigma0[i]
    noise2 /= n
    floor = np.sqrt(noise2)
    core = idx[trim:n - trim] if n > 2 * trim + 4 else idx
    cx, cy, dx, dy, _ = _fit_line(xy[core], floor, 0.0, 0.0, False, 3)
    if dx * (xy[idx[n - 1], 0] - xy[idx[0], 0]) + dy * (xy[idx[n - 1], 1] - xy[idx[0], 1]) < 0:
        dx, dy = -dx, -dy
    rss = 0.0
    lo, hi = np.inf, -np.inf
    for i in idx:
        r = (xy[i, 0] - cx) * dy - (xy[i, 1] - cy) * dx
        rss += r * r
        a = (xy[i, 0] - cx) * dx + (xy[i, 1] - cy) * dy
        lo, hi = min(lo, a), max(hi, a)
    return cx, cy, dx, dy, rss, hi - lo, noise2


def _angle(a: Line, b: Line) -> float:
    """Angle between two lines' directions of travel, degrees in [0, 180]."""
    return float(np.degrees(np.arccos(np.clip(np.dot(a.direction, b.direction), -1.0, 1.0))))


def _best_move(xy: np.ndarray, touched: tuple, sigma0, trim: int) -> tuple[float, list | None]:
    """The better of merging lines ``a, run.., b`` into one and dropping the run between them: (BIC gain, new lines).

    The new lines are made only when the move gains (``None`` otherwise): most
    moves scored are never made.
    """
    idx = np.concatenate([t.idx for t in touched])
    # each segment's end, rss, parameters and noise gathered in Python lists: numpy's cumsum of a
    # list cost more than the compiled scoring itself (about 200 moves are scored per ring)
    ends, rss, n_params, noise2 = [0], [], [], []
    for t in touched:
        ends.append(ends[-1] + len(t.idx))
        rss.append(t.rss)
        n_params.append(t.n_params)
        noise2.append(t.noise2)
    a, b = touched[0], touched[-1]
    gain, kind, near_a, p1, d1, rss1 = _score_move(
        xy, sigma0, trim, idx, np.array(ends, np.int64), np.array(rss), np.array(n_params, np.int64),
        np.array(noise2), a.point, a.direction, b.point, b.direction)
    if not gain > 0:
        return gain, None
    if kind == 0:  # one wall through all of them
        return gain, [_fit(xy, idx, sigma0, trim)]
    if kind == 1:  # one wall through a and b, the run's points counted against it
        merged = _fit(xy, idx, sigma0, trim)
        return gain, [Line(merged.idx, p1, d1, rss1, span=merged.span, noise2=merged.noise2)]
    run_idx = idx[ends[1]:ends[-2]]  # two walls meeting at a corner: the run's points go to the nearer
    return gain, [_fit(xy, np.concatenate([a.idx, run_idx[near_a]]), sigma0, trim),
                  _fit(xy, np.concatenate([run_idx[~near_a], b.idx]), sigma0, trim)]


@njit(cache=True, error_model="numpy")
def _bic(rss, n, n_params, sigma0):  # pragma: no cover - compiled
    n = max(n, 1)
    return n * np.log(max(rss / n, sigma0 * sigma0)) + n_params * np.log(max(n, 2))


@njit(cache=True, error_model="numpy")
def _score_move(xy, sigma0, trim, idx, bounds, rss, n_params, noise2, pa, da, pb, db):  # pragma: no cover
    # simplify_lines scores every run of up to five segments after each round of moves, about 200 per
    # ring: the same arithmetic as segment_bic and _fit, compiled (numpy's per-call overhead on arrays
    # of a few dozen points made the scoring most of the line regularisation's time).  Returns the gain,
    # the move (0 merged line, 1 line through a and b, 2 corner), which run points lie nearer a, and
    # for move 1 the line (point, direction, rss); move 2's lines are fitted by the caller.
    m = len(rss)
    n = bounds[m]
    total_rss, params, pooled = 0.0, 0, 0.0
    for j in range(m):
        total_rss += rss[j]
        params += n_params[j] + 1
        pooled += (bounds[j + 1] - bounds[j]) * noise2[j]
    floor = np.sqrt(pooled / max(n, 1))
    before = _bic(total_rss, n, params, floor)
    cx, cy, dx, dy, merged_rss, _, _ = _fit_segment(xy, idx, sigma0, trim)
    kind = 0
    p1 = np.array([cx, cy])
    d1 = np.array([dx, dy])
    rss1 = merged_rss
    run = idx[bounds[1]:bounds[m - 1]]
    near_a = np.zeros(len(run), np.bool_)
    if m > 2:
        ends = np.concatenate((idx[:bounds[1]], idx[bounds[m - 1]:]))
        ex, ey, fx, fy, _, _, _ = _fit_segment(xy, ends, sigma0, trim)
        core_rss = 0.0
        for i in idx:
            r = abs((xy[i, 0] - ex) * fy - (xy[i, 1] - ey) * fx)
            core_rss += r * r
        if core_rss < merged_rss:
            kind, p1[0], p1[1], d1[0], d1[1], rss1 = 1, ex, ey, fx, fy, core_rss
    after = _bic(rss1, n, 3, floor)
    if m > 2:
        cos = min(max(da[0] * db[0] + da[1] * db[1], -1.0), 1.0)
        if np.degrees(np.arccos(cos)) >= _PARALLEL_DEG:
            corner_rss = rss[0] + rss[m - 1]
            run_rss = 0.0
            for q in range(len(run)):
                i = run[q]
                ra = abs((xy[i, 0] - pa[0]) * da[1] - (xy[i, 1] - pa[1]) * da[0])
                rb = abs((xy[i, 0] - pb[0]) * db[1] - (xy[i, 1] - pb[1]) * db[0])
                near_a[q] = ra <= rb
                r = min(ra, rb)
                run_rss += r * r
            corner = _bic(corner_rss + run_rss, n, n_params[0] + n_params[m - 1] + 2, floor)
            if corner < after:
                after, kind = corner, 2
    return before - after, kind, near_a, p1, d1, rss1


def simplify_lines(xy: np.ndarray, segments: list, sigma0, trim: int = 1, max_run: int = 3) -> list:
    """Merge and drop straight segments while the BIC of the ring's boundary model decreases.

    Parameters
    ----------
    xy : ndarray of shape (N, 2)
        Ring points.
    segments : list
        One entry per segment in ring order: a :class:`Line`, or anything
        else for a curved segment, which is kept as it is.
    sigma0 : float or ndarray of shape (N,)
        Noise floor, metres (per ring point: a set of points takes their RMS).
    trim : int
        End points left out of each line fit.
    max_run : int
        Longest run of segments that may be dropped at once (a notch is three).

    Returns
    -------
    list
        The simplified segments; a line that absorbed a dropped run holds its points.

    Notes
    -----
    Two moves are scored on the points of the segments they touch: merging
    lines ``a, r1..rk, b`` into one line (a wall with a wobble or a small
    notch; the line fitted through all of them or through a and b alone,
    whichever fits better) and, between two walls that meet at a corner,
    dropping the run between them, whose points then count against the
    nearer wall (a cut corner, a small loop).  Each segment costs its line's
    parameters plus 1 for its break point.  The best move is made until none
    lowers the BIC.
    """
    segments = list(segments)
    sigma0 = _noise(sigma0, len(xy))
    scored: dict = {}  # moves by the segments they touch (compared by identity): most survive a move
    while sum(isinstance(s, Line) for s in segments) > 3:
        m = len(segments)
        moves = []
        for start in range(m):
            if not isinstance(segments[start], Line):
                continue
            for k in range(min(max_run, m - 4) + 1):
                touched = tuple(segments[(start + j) % m] for j in range(k + 2))
                if not all(isinstance(t, Line) for t in touched):
                    continue
                if touched not in scored:
                    scored[touched] = _best_move(xy, touched, sigma0, trim)
                gain, new = scored[touched]
                if gain > 0:
                    moves.append((gain, start, k, new))
        if not moves:
            break
        # the best move, and with it every other move in gain order that touches none of the
        # segments already changed: moves on disjoint segments do not change each other's BIC
        moves.sort(key=lambda mv: -mv[0])
        busy: set[int] = set()
        chosen = {}
        n_lines = sum(isinstance(s, Line) for s in segments)
        for _gain, start, k, new in moves:
            span = {(start + j) % m for j in range(k + 2)}
            if span & busy or n_lines - (k + 2) + len(new) < 3:
                continue
            busy |= {(start + j) % m for j in range(-1, k + 3)}  # and their neighbours: the next move's corners
            chosen[start] = (k, new)
            n_lines += len(new) - (k + 2)
        drop = {(start + j) % m for start, (k, _) in chosen.items() for j in range(k + 2)}
        out = []
        for j in range(m):
            if j in chosen:
                out.extend(chosen[j][1])  # a run across the end of the list leaves them last: still cyclic
            elif j not in drop:
                out.append(segments[j])
        segments = out
    return segments


def dominant_wall_direction(lines: list) -> float | None:
    """Dominant direction (radians in [0, π/2)) of straight segments, each weighted by n·L².

    The variance of a fitted direction falls with the number of points n and
    the square of the wall's length L, so long, well-sampled walls decide.
    """
    th, w = [], []
    for ln in lines:
        if not isinstance(ln, Line) or len(ln.idx) < 2:
            continue
        th.append(np.arctan2(ln.direction[1], ln.direction[0]))
        w.append(len(ln.idx) * ln.span ** 2)
    if not w or sum(w) == 0:
        return None
    th, w = np.asarray(th), np.asarray(w)
    return float((np.arctan2(np.sum(w * np.sin(4 * th)), np.sum(w * np.cos(4 * th))) / 4.0) % (np.pi / 2))


def constrain_directions(xy: np.ndarray, lines: list, sigma0, trim: int = 1) -> tuple[list, float | None]:
    """Walls near the dominant direction (mod 90°) take it exactly where the BIC prefers it.

    Parameters
    ----------
    xy : ndarray of shape (N, 2)
    lines : list
        Segments in ring order; entries that are not :class:`Line` (curves) are passed through.
    sigma0 : float or ndarray of shape (N,)
        Noise floor, metres (per ring point).
    trim : int

    Returns
    -------
    lines : list
        Constrained walls have ``free = False``; other entries (curves) as given.
    direction : float or None
        The dominant direction (radians) or None when no wall took it.

    Notes
    -----
    Per wall, the free line (2 parameters) is compared with the line of the
    dominant direction (1 parameter) on the wall's points; the dominant
    direction is re-estimated from the walls that took it, and the choice
    made again.
    """
    sigma0 = _noise(sigma0, len(xy))
    theta = dominant_wall_direction(lines)
    if theta is None:
        return lines, None
    out = lines
    for _ in range(2):
        out, taken = [], []
        for ln in lines:
            if not isinstance(ln, Line):
                out.append(ln)
                continue
            free = _fit(xy, ln.idx, sigma0, trim)
            phi = np.arctan2(free.direction[1], free.direction[0])
            delta = (phi - theta + np.pi / 4) % (np.pi / 2) - np.pi / 4
            if abs(np.degrees(delta)) > _DIRECTION_DEG:
                out.append(free)
                continue
            d = np.array([np.cos(phi - delta), np.sin(phi - delta)])
            core = ln.idx[trim:len(ln.idx) - trim] if len(ln.idx) > 2 * trim + 4 else ln.idx
            floor = float(np.sqrt(free.noise2))
            c, d, _ = fit_line(xy[core], floor, direction=d)
            r = (xy[ln.idx] - c) @ np.array([d[1], -d[0]])
            fixed = Line(ln.idx, c, d, float(r @ r), free=False, span=free.span, noise2=free.noise2)
            n = len(ln.idx)
            if segment_bic(fixed.rss, n, 1, floor) <= segment_bic(free.rss, n, 2, floor):
                out.append(fixed)
                taken.append(free)
            else:
                out.append(free)
        new_theta = dominant_wall_direction(taken) if taken else None
        if new_theta is None or abs(new_theta - theta) < 1e-9:
            break
        theta = new_theta
    return out, theta if any(isinstance(ln, Line) and not ln.free for ln in out) else None


def line_corners(a: Line, b: Line, xy_break: np.ndarray, max_move: float) -> np.ndarray:
    """Vertices joining line ``a`` to the next line ``b``: their intersection, or a step between parallels.

    Parameters
    ----------
    a, b : Line
    xy_break : ndarray of shape (2,)
        Where the ring passes from a to b (the last point of a and first of b, averaged).
    max_move : float
        An intersection farther than this from ``xy_break`` (metres) is
        treated as parallel lines.

    Returns
    -------
    ndarray of shape (1, 2) or (2, 2)
    """
    den = a.direction[0] * b.direction[1] - a.direction[1] * b.direction[0]
    if abs(den) >= np.sin(np.radians(_PARALLEL_DEG)):
        s = ((b.point - a.point)[0] * b.direction[1] - (b.point - a.point)[1] * b.direction[0]) / den
        p = a.point + s * a.direction
        if np.hypot(*(p - xy_break)) <= max_move:
            return p[None, :]
    # nearly parallel lines (a step in a wall): the feet of the break point on both
    fa = a.point + np.dot(xy_break - a.point, a.direction) * a.direction
    fb = b.point + np.dot(xy_break - b.point, b.direction) * b.direction
    if np.hypot(*(fa - fb)) < 1e-9:
        return fa[None, :]
    return np.vstack([fa, fb])


@dataclass(eq=False)
class Curve:
    """A curved segment: the CD-spline's vertices from its first corner to the next, and its points.

    Attributes
    ----------
    idx : ndarray of int
        Ring indices of its points, in ring order.
    vertices : ndarray of shape (k, 3)
        Spline samples, both corners included.
    degree : int
    """

    idx: np.ndarray
    vertices: np.ndarray
    degree: int


@dataclass(frozen=True)
class LineOutline:
    """Result of :func:`line_outline`.

    Attributes
    ----------
    vertices : ndarray of shape (K, 3)
        Closed ring, first vertex not repeated, roof on the left.
    corner_index : ndarray of int, shape (M,)
        Vertex of each segment's first corner.
    degrees : list of int
        Per segment: 1 for a line, the spline degree for a curve.
    sigma : float
        Root mean square distance of the ring points to the outline before the edge shift, metres.
    direction : float or None
        Dominant direction the walls took (radians), None when none did.
    measured_edges : int
        Segments whose edge shift came from the non-roof points around them.
    """

    vertices: np.ndarray
    corner_index: np.ndarray
    degrees: list
    sigma: float
    direction: float | None
    measured_edges: int


def _curve_normals(v: np.ndarray) -> np.ndarray:
    """Unit outward (right-hand) normals at a polyline's vertices, from the neighbouring vertices."""
    d = np.gradient(v[:, :2], axis=0) if len(v) > 1 else np.array([[1.0, 0.0]])
    d /= np.maximum(np.linalg.norm(d, axis=1), 1e-12)[:, None]
    return np.column_stack([d[:, 1], -d[:, 0]])


def line_outline(points: np.ndarray, spline, spacing: float, *, noise_factor: float, edge_factor: float,
                 directions: bool = True, context: EdgeContext | None = None, densify: float = 0.5,
                 z_tolerance: float = 0.3, refit: Callable | None = None,
                 roof: cKDTree | None = None) -> LineOutline:
    """Building-shaped ring from the ring points and the CD-spline fitted to them.

    Parameters
    ----------
    points : ndarray of shape (N, 3) float64
        Ring points (alpha-shape boundary), roof on the left, metres.
    spline : CDSpline
        The CD-spline of ``points`` (its segments, degrees and curves).
    spacing : float
        Local mean point spacing of the ring, metres.
    noise_factor : float
        The boundary points' scatter about a straight edge, in spacings (σ0).
    edge_factor : float
        Outward edge shift in spacings where ``context`` does not measure it.
    directions : bool
        Try the dominant direction on every wall (model selection).
    context : EdgeContext, optional
        The points around the building that are not its roof.
    densify : float
        Step of the curve samples, metres.
    z_tolerance : float
        A wall gets a vertex where its height profile leaves a straight line
        by more than this (metres; a gable's apex).
    refit : callable, optional
        ``refit(corners)`` -> CDSpline of ``points`` with these corners (ring
        indices, increasing): the spline fitted again when a simplified line
        bends beyond the noise.
    roof : cKDTree, optional
        K-d tree of all the roof's points (x, y; the ring points among them),
        in the ring's frame: the sampling step across the edge is measured on
        them (:func:`boundary_step`).  One tree serves every ring of a building.

    Returns
    -------
    LineOutline
    """
    xy = points[:, :2]
    sigma0 = noise_factor * boundary_step(xy, spacing, roof)
    trim = 1
    segments = _curves_on(points, None, spline, sigma0, trim, densify)
    if len(segments) < 3:
        raise ValueError("line_outline: fewer than 3 segments")
    segments = simplify_lines(xy, segments, sigma0, trim)
    if refit is not None and any(isinstance(g, Line) and _bends(xy, g) for g in segments):
        # merged lines can hide a gentle curve the first segmentation cut into straight pieces:
        # the spline is fitted again on the simplified segments, and the same test decides
        first = int(np.argmin([g.idx[0] for g in segments]))
        segments = segments[first:] + segments[:first]  # the spline's corners increase
        segments = _curves_on(points, segments, refit(np.array([int(g.idx[0]) for g in segments])), sigma0,
                              trim, densify)
    # short straight pieces of one arc, each within a line's noise: one curve if the BIC says so
    segments = curved_runs(points, segments, densify)
    theta = None
    if directions:
        segments, theta = constrain_directions(xy, segments, sigma0, trim)
    residual_fit = [_segment_residual(xy, s) for s in segments]
    # the edge: every segment moves out to where the roof ends
    measured = 0
    shifted = []
    for s, (res, normal) in zip(segments, residual_fit):
        shift, ok = edge_shift(xy[s.idx], res, normal, spacing, context, edge_factor)
        measured += ok
        if isinstance(s, Line):
            shifted.append(Line(s.idx, s.point + shift * s.normal, s.direction, s.rss, s.free, s.span, s.noise2))
        else:
            v = s.vertices.copy()
            v[:, :2] += shift * _curve_normals(v)
            shifted.append(Curve(s.idx, v, s.degree))
    ring, corners, degrees = _assemble(xy, points[:, 2], shifted, max(2.0, 5.0 * spacing), z_tolerance)
    rms = float(np.sqrt(np.mean(np.concatenate([r for r, _ in residual_fit]) ** 2)))
    return LineOutline(ring, np.asarray(corners, dtype=np.int64), degrees, rms, theta, measured)


def boundary_step(ring_xy: np.ndarray, spacing: float, roof: np.ndarray | cKDTree | None = None,
                  window: float = 2.0) -> np.ndarray:
    """The sampling step across the edge at each ring point: how far its position is uncertain, metres.

    The roof edge lies somewhere between a boundary point and the next roof
    position the sampling could have put beyond it, so a boundary point's
    position across the edge is uncertain by the step to the next row of
    roof points behind it, measured across the edge (σ = step / √12 for a
    uniform position).  Along an even sampling that is the mean spacing; where
    the scan lines run nearly parallel to a wall the ring follows one scan
    line until the next reaches the wall (a saw-tooth), and the step is the
    scan-line distance, however short the gaps along the ring are.

    Parameters
    ----------
    ring_xy : ndarray of shape (N, 2) float64
        Ring points in order, roof on the left, metres.
    spacing : float
        Local mean point spacing, metres: the step where no roof point lies
        behind a ring point, and the least step counted as a row behind.
    roof : ndarray of shape (M, 2) float64 or cKDTree, optional
        The roof's points, or a k-d tree of them (built once per building by
        the caller).  Without them, the step is the mean gap between ring
        neighbours (never below ``spacing``).
    window : float
        Length of ring (in spacings) whose chord gives the edge's direction at a point.

    Returns
    -------
    ndarray of shape (N,) float64
        Metres, smoothed along the ring over five points (a saw-tooth
        alternates rows).
    """
    xy = np.asarray(ring_xy, dtype=np.float64)
    n = len(xy)
    gap = np.linalg.norm(np.diff(np.vstack([xy, xy[:1]]), axis=0), axis=1)  # point i to i + 1
    if roof is not None and not isinstance(roof, cKDTree):
        roof = cKDTree(np.asarray(roof, dtype=np.float64)[:, :2])
    if roof is None or roof.n < 4 or n < 4:
        step = np.maximum(spacing, 0.5 * (gap + np.roll(gap, 1)))
    else:
        # the edge's direction at each point: the chord over about `window` spacings of ring
        along = np.concatenate([[0.0], np.cumsum(gap)])
        total = along[-1]
        ext = np.concatenate([along[:-1] - total, along[:-1], along[:-1] + total])
        half = 0.5 * window * spacing
        lo = np.searchsorted(ext, along[:-1] - half, side="left") % n
        hi = (np.searchsorted(ext, along[:-1] + half, side="right") - 1) % n
        t = xy[hi] - xy[lo]
        t /= np.maximum(np.linalg.norm(t, axis=1), 1e-12)[:, None]
        inward = np.column_stack([-t[:, 1], t[:, 0]])  # the roof is on the left
        _, nb = roof.query(xy, k=min(24, roof.n))
        rel = roof.data[nb] - xy[:, None, :]
        depth = np.einsum("nkj,nj->nk", rel, inward)
        side = np.abs(np.einsum("nkj,nj->nk", rel, t))
        # the next row behind: more behind the point than beside it (a scan line running nearly
        # along the edge is the point's own row, however short its gaps), and at least one mean
        # spacing in, the step of an even sampling (nearer points are neighbours in the same row,
        # set slightly in where rows are slanted to the edge, or wall points below the eave)
        behind = (depth >= spacing) & (side <= depth)
        step = np.where(behind, depth, np.inf).min(axis=1)
        step = np.where(np.isfinite(step), step, spacing)
    width = 5
    kernel = np.ones(width) / width
    return np.convolve(np.concatenate([step[-width:], step, step[:width]]), kernel, mode="same")[width:-width]


def _turning_runs(segments: list) -> list[list[int]]:
    """Runs of consecutive lines that turn the same way by less than a corner's angle, each turning <= 90°.

    Short straight pieces of one arc (each within the noise of a line) turn
    by a few degrees at every break, all the same way; a straight wall's
    wobbles and steps turn both ways.  Returns segment positions per run,
    three lines at least; a run round the whole ring is cut where its
    turning passes 90° (one spline segment does not turn farther).
    """
    m = len(segments)
    turn = np.full(m, np.nan)  # at break k, from segment k - 1 to segment k, degrees (left positive)
    for k in range(m):
        a, b = segments[k - 1], segments[k]
        if isinstance(a, Line) and isinstance(b, Line):
            cross = a.direction[0] * b.direction[1] - a.direction[1] * b.direction[0]
            turn[k] = np.degrees(np.arctan2(cross, np.dot(a.direction, b.direction)))
    smooth = np.abs(turn) < _CORNER_DEG  # nan (a curve on either side) is False
    # start where the ring does not run smoothly on: a corner or a curve (else anywhere)
    starts = np.flatnonzero(~smooth)
    first = int(starts[0]) if len(starts) else 0
    runs, cur, total, sense = [], [first], 0.0, 0.0
    for j in range(1, m + 1):
        k = (first + j) % m
        t = turn[k]
        same = bool(smooth[k]) and (sense == 0.0 or np.sign(t) == sense)
        if same and abs(total + t) <= 90.0 and j < m:
            cur.append(k)
            total += t
            sense = float(np.sign(t))
            continue
        if len(cur) >= 3:
            runs.append(cur)
        elif smooth[k] and j < m:
            # a smooth break turning the other way: the segment before it (in no run) starts the next run
            cur, total, sense = [(k - 1) % m, k], float(t), float(np.sign(t))
            continue
        cur, total, sense = [k], 0.0, 0.0
    return runs


def curved_runs(points: np.ndarray, segments: list, densify: float) -> list:
    """Replace runs of short lines along one arc by a curve where the BIC prefers it.

    Arc pieces shorter than a few metres each stay within the noise of a
    line, so an arc becomes a polygon of many short walls.  Every run of
    lines turning the same way (:func:`_turning_runs`) is fitted as one
    curve of degree 2 or 3, both as a CD-spline segment and as a polynomial
    across the run's chord (:func:`chord_curve`, which a ring stepping
    where scan lines end does not drag off the points), and the latter also
    with the run's first or last line left straight when that line is
    longer than the rest of the run (a wall running on into an arc without
    a corner).  The BIC decides, as for every other model here, not the
    F-test: a curve (2·degree parameters plus its break point) replaces
    the run's lines (each with its parameters and break point, at their
    pooled noise floor) when it explains their points better.

    Parameters
    ----------
    points : ndarray of shape (N, 3) float64
        Ring points.
    segments : list of Line or Curve
        In ring order, each segment's ring indices increasing.
    densify : float
        Step of the curve samples, metres.

    Returns
    -------
    list of Line or Curve
    """
    runs = _turning_runs(segments)
    if not runs:
        return segments
    xy = points[:, :2]
    in_run = {k: r for r in runs for k in r}
    units = []  # (segment positions) per spline segment, in ring order
    for k in range(len(segments)):
        if k in in_run:
            if in_run[k][0] == k:
                units.append(in_run[k])
        else:
            units.append([k])
    starts = np.array([int(segments[u[0]].idx[0]) for u in units])
    order = np.argsort(starts, kind="stable")
    corners = starts[order]
    rank = np.empty(len(units), np.int64)
    rank[order] = np.arange(len(units))
    is_run = np.array([len(units[u]) >= 3 for u in order])
    fits = []
    # every run at degree 2, then at 3 (the other segments straight): the pieces join with C0 only, so
    # each run's curve barely depends on the others', and the BIC picks the degree run by run
    for d in (2, 3):
        try:
            fits.append((d, fit_cdspline(points, corners, np.where(is_run, d, 1))))
        except GeometryError:
            continue
    # each fit's ring, sampled once for all its runs: (degree, closed vertices, corner vertex per unit and the end)
    rings = []
    for d, fit in fits:
        verts, corner_index = fit.ring(densify)
        rings.append((d, np.vstack([verts, verts[:1]]), list(corner_index) + [len(verts)]))
    m = len(segments)
    replace = {}
    for u, unit in enumerate(units):
        if len(unit) < 3:
            continue
        k = int(rank[u])
        lines = [segments[j] for j in unit]
        idx = np.concatenate([ln.idx for ln in lines])
        floor = _pooled(lines)
        best = (segment_bic(sum(ln.rss for ln in lines), len(idx), sum(ln.n_params + 1 for ln in lines), floor), None)
        for d, ring, corner_index in rings:
            arc = ring[corner_index[k]:corner_index[k + 1] + 1]
            bic = segment_bic(_rss_to_curve(xy[idx], arc), len(idx), 2 * d + 1, floor)
            if bic < best[0]:
                best = (bic, [Curve(idx, arc, d)])
        # the curve over the whole run, or with its first or last line left straight: where a straight
        # wall runs on into an arc without a corner (a stadium's side), that line holds both.  It is the
        # wall only if longer than the arc pieces together (one arc's pieces are about equally long)
        total = sum(ln.span for ln in lines)
        for lo, hi in ((0, len(unit)), (1, len(unit)), (0, len(unit) - 1)):
            kept = lines[:lo] + lines[hi:]
            if kept and 2 * kept[0].span <= total:
                continue
            bent = np.concatenate([ln.idx for ln in lines[lo:hi]])
            ends = (0.5 * (xy[segments[(unit[lo] - 1) % m].idx[-1]] + xy[bent[0]]),
                    0.5 * (xy[bent[-1]] + xy[segments[(unit[hi - 1] + 1) % m].idx[0]]))
            for d in (2, 3):
                arc = chord_curve(points[bent], ends, d, densify)
                bic = segment_bic(_rss_to_curve(xy[bent], arc) + sum(ln.rss for ln in kept), len(idx),
                                  2 * d + 1 + sum(ln.n_params + 1 for ln in kept), floor)
                if bic < best[0]:
                    best = (bic, lines[:lo] + [Curve(bent, arc, d)] + lines[hi:])
        if best[1] is not None:
            replace[unit[0]] = (unit, best[1])
    if not replace:
        return segments
    log.debug("lines: %d runs of short lines became curves", len(replace))
    drop = {j for unit, _ in replace.values() for j in unit}
    out = []
    for k in range(len(segments)):
        if k in replace:
            out.extend(replace[k][1])
        elif k not in drop:
            out.append(segments[k])
    return out


def _rss_to_curve(xy: np.ndarray, arc: np.ndarray) -> float:
    """Squared plan distances of points to a sampled curve, summed (m²)."""
    res = shapely.distance(shapely.points(xy), shapely.LineString(arc[:, :2]))
    return float(res @ res)


def chord_curve(points: np.ndarray, ends: tuple, degree: int, densify: float) -> np.ndarray:
    """A run's curve as a polynomial across its chord: offset (and height) as polynomials of the position along it.

    The CD-spline puts its knots at the chord-length parameters of ring
    points, so a ring that steps where scan lines end (a saw-tooth along a
    gently curved wall) stretches the parameter at every step and the joint
    fit drags the curve and its corners off the points.  A graph over the
    chord has no parameter to stretch: the offset across it is fitted by
    least squares, as a line's is.  A run turns by at most 90°, so its curve
    is a graph over its chord.

    Parameters
    ----------
    points : ndarray of shape (n, 3) float64
        The run's ring points, in ring order, metres.
    ends : tuple of two ndarray of shape (2,)
        Where the run meets the segments before and after it; the curve
        spans their chord.
    degree : int
        Polynomial degree (2 or 3).
    densify : float
        Step of the samples along the chord, metres.

    Returns
    -------
    ndarray of shape (k, 3) float64
        Samples of the curve from the first end to the last.
    """
    a, b = np.asarray(ends[0], dtype=np.float64), np.asarray(ends[1], dtype=np.float64)
    length = float(np.hypot(*(b - a)))
    t = (b - a) / max(length, 1e-12)
    across = np.array([t[1], -t[0]])
    rel = points[:, :2] - a
    basis = np.vander(rel @ t, degree + 1)
    coef, *_ = np.linalg.lstsq(basis, np.column_stack([rel @ across, points[:, 2]]), rcond=None)
    u = np.linspace(0.0, length, max(int(np.ceil(length / densify)), 4 * degree) + 1)
    v, z = (np.vander(u, degree + 1) @ coef).T
    return np.column_stack([a + u[:, None] * t + v[:, None] * across, z])


def _bends(xy: np.ndarray, line: Line) -> bool:
    """Whether a parabola across the line explains its points better than the line (BIC, noise floor)."""
    floor = float(np.sqrt(line.noise2))
    rel = xy[line.idx] - line.point
    u, v = rel @ line.direction, rel @ line.normal
    if len(u) < 6:
        return False
    coef, *_ = np.linalg.lstsq(np.column_stack([u * u, u, np.ones_like(u)]), v, rcond=None)
    r = v - np.column_stack([u * u, u, np.ones_like(u)]) @ coef
    return segment_bic(float(r @ r), len(u), 3, floor) < segment_bic(line.rss, len(u), 2, floor)


def _curves_on(points: np.ndarray, segments: list | None, spline, sigma0, trim: int, densify: float) -> list:
    """Segments of a CD-spline: a curve where the spline beats the line by the BIC, else a fitted line.

    ``segments`` (if given) are the segments the spline was fitted on, in the
    same order; their points are kept as they are.
    """
    xy = points[:, :2]
    verts, corner_index = spline.ring(densify)
    corner_index = list(corner_index) + [len(verts)]
    closed = np.vstack([verts, verts[:1]])
    out: list = []
    for k, d in enumerate(spline.degrees):
        if segments is not None:
            idx = segments[k].idx
        else:
            idx = np.flatnonzero(spline.segment == k)
            idx = idx[np.argsort(spline.t[idx], kind="stable")]
        if len(idx) < 2:
            continue
        line = segments[k] if segments is not None and isinstance(segments[k], Line) else _fit(xy, idx, sigma0, trim)
        if d >= 2:
            # distances across the curve, as the lines' are (not to the point's spline parameter)
            arc = closed[corner_index[k]:corner_index[k + 1] + 1]
            res = shapely.distance(shapely.points(xy[idx]), shapely.LineString(arc[:, :2]))
            rss = float(res @ res)
            # curved only if the spline's extra control points pay for themselves over the line
            floor = float(np.sqrt(line.noise2))
            if segment_bic(rss, len(idx), 2 * d, floor) < segment_bic(line.rss, len(idx), 2, floor):
                # a corner the segmentation missed also bends the segment: two lines meeting at the
                # point farthest from the chord are the other model a curve has to beat
                chord = xy[idx[-1]] - xy[idx[0]]
                off = np.abs(np.cross(chord, xy[idx] - xy[idx[0]])) / max(np.hypot(*chord), 1e-12)
                cut = int(np.clip(np.argmax(off), 2, len(idx) - 2))
                pair = [_fit(xy, idx[:cut], sigma0, trim), _fit(xy, idx[cut:], sigma0, trim)]
                # (a smooth curve cannot turn sharply: at a missed corner the two lines fit closer, and
                # meet at an angle no arc piece between two Douglas-Peucker corners turns through)
                if len(idx) >= 8 and pair[0].rss + pair[1].rss <= rss and _angle(*pair) >= _CORNER_DEG:
                    out.extend(pair)
                else:
                    out.append(Curve(idx, closed[corner_index[k]:corner_index[k + 1] + 1], d))
                continue
        out.append(line)
    return out


def _segment_residual(xy: np.ndarray, s) -> tuple[np.ndarray, np.ndarray]:
    """Signed outward distances of a segment's points to its model, and the outward normal(s)."""
    if isinstance(s, Line):
        return (xy[s.idx] - s.point) @ s.normal, s.normal
    v = s.vertices[:, :2]
    normals = _curve_normals(s.vertices)
    near = cKDTree(v).query(xy[s.idx])[1]
    return np.einsum("ij,ij->i", xy[s.idx] - v[near], normals[near]), normals[near]


def _height_breaks(xy: np.ndarray, z: np.ndarray, line: Line, tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """Where the height along a straight wall breaks (a gable's apex): positions on the line and heights.

    A 1D Douglas-Peucker on (position along the line, z) of the wall's points;
    the kept inner points become vertices on the line, so the plan shape keeps
    its corners and the outline its 3D profile.
    """
    along = (xy[line.idx] - line.point) @ line.direction
    order = np.argsort(along, kind="stable")
    profile = np.column_stack([along[order], z[line.idx][order]])
    keep = douglas_peucker(profile, tolerance)[1:-1]
    return profile[keep, 0], profile[keep, 1]


def _assemble(xy: np.ndarray, z: np.ndarray, segments: list, max_move: float, z_tolerance: float):
    """Vertices, corner indices and degrees of the ring the segments make, corners where lines meet."""
    verts, corners, degrees, heights = [], [], [], []
    m = len(segments)
    for k in range(m):
        prev, cur = segments[k - 1], segments[k]
        if isinstance(prev, Line) and isinstance(cur, Line):
            brk = 0.5 * (xy[prev.idx[-1]] + xy[cur.idx[0]])
            at = list(line_corners(prev, cur, brk, max_move))
        elif isinstance(cur, Line):
            p = prev.vertices[-1, :2]
            at = [cur.point + np.dot(p - cur.point, cur.direction) * cur.direction]
        elif isinstance(prev, Line):
            p = cur.vertices[0, :2]
            at = [prev.point + np.dot(p - prev.point, prev.direction) * prev.direction]
        else:
            at = [cur.vertices[0, :2]]
        for j, p in enumerate(at):
            corners.append(len(verts))
            verts.append(np.asarray(p, dtype=np.float64))
            heights.append(np.nan)
            degrees.append(1 if j < len(at) - 1 or isinstance(cur, Line) else cur.degree)
        if not isinstance(cur, Line):
            verts.extend(cur.vertices[1:-1, :2])
            heights.extend(cur.vertices[1:-1, 2])
            continue
        nxt = segments[(k + 1) % m]
        start = np.dot(verts[-1] - cur.point, cur.direction)
        end = np.dot((nxt.point if isinstance(nxt, Line) else nxt.vertices[0, :2]) - cur.point, cur.direction)
        for pos, height in zip(*_height_breaks(xy, z, cur, z_tolerance)):
            if start < pos < end:
                # an apex on a wall is a corner of the 3D outline, not of its plan
                corners.append(len(verts))
                verts.append(cur.point + pos * cur.direction)
                heights.append(height)
                degrees.append(1)
    v2 = np.asarray(verts)
    zz = np.asarray(heights, dtype=np.float64)
    # corner heights: the eave's, from the nearest ring point
    gap = np.isnan(zz)
    zz[gap] = z[cKDTree(xy).query(v2[gap])[1]]
    return np.column_stack([v2, zz]), corners, degrees
