"""Closed changeable-degree spline (CD-spline) with C0 joints and F-test degree selection (thesis ch. 5).

A CD-spline (Shen & Wang 2010) lets every segment between two knots have its
own polynomial degree.  With C0 joints (knot multiplicity = degree, thesis
§5.3) its normalised basis is, span by span, the Bernstein basis of the
span's degree in the span's local parameter, each span sharing its end
control points with its neighbours; the curve is closed by making the last
control point the first (thesis §5.4).  Here each span's basis comes from
the Cox-de Boor recursion on a clamped knot vector of the span's degree,
which is the recursion of eq. 5.5 restricted to one span
(:mod:`rooftrace.contour.cdbasis`).
"""

from __future__ import annotations

import functools
import logging
import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy import sparse, stats
from scipy.sparse import linalg as sparse_linalg

from rooftrace.contour.cdbasis import cd_basis, chord_parameters, span_basis
from rooftrace.errors import GeometryError

__all__ = ["CDSplineOptions", "CDSpline", "chord_parameters", "cd_basis", "fit_cdspline", "iterative_cdspline"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class CDSplineOptions:
    """Options of the CD-spline stage (TOML table ``[cdspline]``).

    Attributes
    ----------
    significance : float
        beta of the two-sided F-test on residual variances (thesis eq. 5.12): 0.10.
    max_degree : int
        Cap on any segment's degree (DESIGN.md stage 7: 5).
    test : {'segment', 'global'}
        'global' is the thesis's rule: stop at the first raise that does not
        change the standard deviation of all residuals significantly
        (F_{beta/2, q-1, q-1} < F_c < F_{1-beta/2, q-1, q-1}) and keep the
        previous iteration.  'segment' applies the same F-test to the raised
        segment's own residuals (q_s - 1 degrees of freedom), undoes an
        insignificant raise, freezes that segment and goes on with the next
        worst one, so one long straight wall cannot stop the curved ones
        from being raised.
    points_per_degree : int
        Interior points a segment needs per degree above 1 (a segment with n
        interior points gets at most degree 1 + n // points_per_degree), so
        short, jagged pieces stay straight.
    max_overshoot : float
        A raise is refused when the raised segment's curve strays farther
        from the polyline of the segment's points than this (metres) and
        than the curve before the raise did (loops, overshoots).
    refine : int
        Beyond the thesis: rounds of moving each corner to the ring point
        nearest its least-squares corner of an all-straight fit (the
        Douglas-Peucker vertex is only the farthest point, often a little off).
    split : bool
        Beyond the thesis: a segment that needs degree >= 4 is split at the
        Douglas-Peucker vertex inside it that gives the best fit, when the
        split fit is no worse (sigma within 2 %) and needs at most one more
        control point, repeatedly (a straight wall running tangentially into
        an arc becomes a line and a curve).
    merge_angle : float
        Beyond the thesis: a corner between two straight segments whose
        fitted directions differ by less than this (degrees) is dropped and
        the curve refitted (0, the default, disables it).  It gives cleaner
        polygons (e.g. 24 -> 6 sides on a City3D house) but a worse PoLiS
        (0.122 -> 0.178 m at 15°): PoLiS averages over the extracted
        vertices, and the dropped ones lay mid-wall where the error is small.
    densify : float
        Spacing in metres of the output vertices along curved (degree >= 2)
        segments; straight segments are output as their two corners.
    """

    section = "cdspline"

    significance: float = 0.10
    max_degree: int = 5
    test: str = "segment"
    points_per_degree: int = 3
    max_overshoot: float = 0.3
    refine: int = 0
    split: bool = True
    merge_angle: float = 0.0
    densify: float = 0.5

    def __post_init__(self) -> None:
        if not 0 < self.significance < 1:
            raise ValueError(f"cdspline.significance must be in (0, 1), not {self.significance}")
        if self.max_degree < 1:
            raise ValueError(f"cdspline.max_degree must be >= 1, not {self.max_degree}")
        if self.test not in ("segment", "global"):
            raise ValueError(f"cdspline.test must be 'segment' or 'global', not {self.test!r}")
        if not self.densify > 0:
            raise ValueError(f"cdspline.densify must be > 0 m, not {self.densify}")


@dataclass
class CDSpline:
    """A fitted closed CD-spline.

    Attributes
    ----------
    control_points : ndarray of shape (sum(d), 3) float64
    breaks : ndarray of shape (M+1,) float64
        Knot parameters of the corners, ``breaks[-1] = 1``.
    degrees : list of int
    t : ndarray of shape (Q,) float64
        Parameters of the fitted points (in the points' original order).
    residuals : ndarray of shape (Q,) float64
        |C(t_i) - Q_i| in metres (eq. 5.11).
    segment : ndarray of shape (Q,) int
        Segment of each fitted point.
    history : list of (list of int, float)
        Degrees and residual standard deviation of each iteration.
    """

    control_points: np.ndarray
    breaks: np.ndarray
    degrees: list[int]
    t: np.ndarray
    residuals: np.ndarray
    segment: np.ndarray
    history: list = field(default_factory=list)

    @property
    def sigma(self) -> float:
        """Residual standard deviation sqrt(sum r² / (q - 1)) in metres."""
        return float(np.sqrt(np.sum(self.residuals**2) / max(len(self.residuals) - 1, 1)))

    def evaluate(self, t: np.ndarray) -> np.ndarray:
        """Curve points C(t), shape (len(t), 3)."""
        return cd_basis(np.asarray(t, dtype=np.float64) % 1.0, self.breaks, self.degrees) @ self.control_points

    def ring(self, step: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
        """Vertices of the closed outline: corners, plus samples every ``step`` m along curved segments.

        Returns ``(vertices (K, 3), corner_index (M,))`` with the first
        vertex not repeated and ``corner_index[k]`` the vertex of corner k.
        """
        offsets = np.concatenate([[0], np.cumsum(self.degrees)])
        params, corner_index = [], []
        for k, d in enumerate(self.degrees):
            corner_index.append(len(params))
            params.append(self.breaks[k])
            if d >= 2:
                ctrl = self.control_points[np.arange(offsets[k], offsets[k] + d + 1) % len(self.control_points)]
                length = np.linalg.norm(np.diff(ctrl, axis=0), axis=1).sum()
                count = max(int(np.ceil(length / step)), 4 * d)
                params.extend(np.linspace(self.breaks[k], self.breaks[k + 1], count + 1)[1:-1])
        return self.evaluate(np.asarray(params)), np.asarray(corner_index, dtype=np.int64)


_DENSE_UP_TO = 80  # control points; beyond, sparse normal equations are faster


def _design(t: np.ndarray, breaks: np.ndarray, degrees, cache: dict | None):
    """cd_basis for sorted ``t`` (closed), dense or (many control points) sparse; span blocks cached."""
    offsets = np.concatenate([[0], np.cumsum(degrees)])
    n_ctrl = int(offsets[-1])
    bounds = np.append(np.searchsorted(t, breaks[:-1], side="left"), len(t))
    vals = _span_values(t, breaks, degrees, bounds, cache)
    rows, cols = _design_index(bounds, offsets)
    if n_ctrl <= _DENSE_UP_TO:
        # bincount adds in input order from 0.0, as np.add.at did (the columns of a
        # one-segment ring wrap onto column 0 and are summed), and is much faster
        flat = np.bincount(rows * n_ctrl + cols, vals, minlength=len(t) * n_ctrl)
        return flat.reshape(len(t), n_ctrl)
    return sparse.csr_matrix((vals, (rows, cols)), shape=(len(t), n_ctrl))


def _span_values(t: np.ndarray, breaks: np.ndarray, degrees, bounds: np.ndarray, cache: dict | None) -> np.ndarray:
    """The span-basis values of all spans, span by span (row-major within a span).

    ``cache`` keeps each span's block under ``(k, d, breaks[k], breaks[k+1])``
    and, under ``"last"``, the previous call's values: the F-test loop raises
    one segment at a time, so only the spans whose degree changed are looked
    up again and the rest is copied in slices (a loop over every span of every
    trial took a tenth of the outline stage on Delft).
    """
    def block(k: int, d: int) -> np.ndarray:
        key = (k, d, breaks[k], breaks[k + 1])
        out = cache.get(key) if cache is not None else None
        if out is None:
            knots = np.concatenate([np.full(d + 1, breaks[k]), np.full(d + 1, breaks[k + 1])])
            out = span_basis(t[bounds[k]:bounds[k + 1]], knots, d).ravel()
            if cache is not None:
                cache[key] = out
        return out

    deg = np.asarray(degrees, dtype=np.int64)
    last = cache.get("last") if cache is not None else None
    if last is not None and len(last[0]) == len(deg) and np.array_equal(last[1], breaks) \
            and np.array_equal(last[2], bounds):
        last_deg, _, _, last_vals, last_start = last
        pieces, pos = [], 0
        for k in np.flatnonzero(last_deg != deg).tolist():
            pieces += [last_vals[pos:last_start[k]], block(k, int(deg[k]))]
            pos = last_start[k + 1]
        pieces.append(last_vals[pos:])
        vals = np.concatenate(pieces)
    else:
        vals = np.concatenate([block(k, int(d)) for k, d in enumerate(deg)])
    if cache is not None:
        start = np.concatenate([[0], np.cumsum(np.diff(bounds) * (deg + 1))])
        cache["last"] = (deg, breaks.copy(), bounds, vals, start)
    return vals


def _design_index(bounds: np.ndarray, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Row and column of every span-basis value, span by span, row-major within a span.

    Row ``r`` of span k (``bounds[k] <= r < bounds[k+1]``) holds columns
    ``offsets[k] .. offsets[k+1]`` modulo the control-point count (the last
    control point is the first).  Built without a loop over the spans: a
    building ring has dozens of them and the design is rebuilt for every
    trial degree.
    """
    n_ctrl = int(offsets[-1])
    counts = np.diff(bounds)
    width = np.repeat(np.diff(offsets) + 1, counts)  # values per row
    rows = np.repeat(np.arange(bounds[0], bounds[-1]), width)
    first = np.repeat(np.repeat(offsets[:-1], counts), width)
    within = np.arange(len(rows)) - np.repeat(np.cumsum(width) - width, width)
    return rows, (first + within) % n_ctrl


def fit_cdspline(points: np.ndarray, corners: np.ndarray, degrees, *, t: np.ndarray | None = None,
                 _cache: dict | None = None) -> CDSpline:
    """Least-squares closed CD-spline through a ring's points (eq. 5.7).

    Parameters
    ----------
    points : ndarray of shape (Q, 3) float64
        Ordered closed ring (first point not repeated), metres.
    corners : ndarray of int, shape (M,)
        Increasing ring indices of the knots (M >= 1).
    degrees : sequence of M int
        Degree of the segment starting at each corner.
    t : ndarray of shape (Q,), optional
        Chord-length parameters of the ring rotated to start at ``corners[0]``
        (computed when omitted).

    Returns
    -------
    CDSpline
        x, y and z are fitted together with one design matrix; the normal
        equations P = (AᵀA)⁻¹AᵀQ are solved as a sparse (banded) system.
    """
    points = np.asarray(points, dtype=np.float64)
    corners = np.asarray(corners, dtype=np.int64)
    degrees = [int(d) for d in degrees]
    q = len(points)
    start = int(corners[0])
    rolled = np.roll(points, -start, axis=0)
    if t is None:
        t = chord_parameters(rolled)
    breaks = np.append(t[corners - start], 1.0)
    if np.any(np.diff(breaks) <= 0):
        raise GeometryError("degenerate_segment")
    a = _design(t, breaks, degrees, _cache)
    if a.shape[1] > q:
        raise GeometryError("too_few_points")
    if not sparse.issparse(a):
        try:
            ctrl = np.linalg.solve(a.T @ a, a.T @ rolled)
        except np.linalg.LinAlgError:
            ctrl, *_ = np.linalg.lstsq(a, rolled, rcond=None)
        return _finish(a, ctrl, rolled, breaks, degrees, t, corners, start)
    # AᵀA is banded (cyclic): a sparse solve keeps big terraced blocks linear in size
    ata = (a.T @ a).tocsc()
    atq = a.T @ rolled
    with warnings.catch_warnings():
        warnings.simplefilter("error", sparse_linalg.MatrixRankWarning)
        try:
            ctrl = sparse_linalg.spsolve(ata, atq)
        except (sparse_linalg.MatrixRankWarning, RuntimeError):
            ctrl, *_ = np.linalg.lstsq(a.toarray(), rolled, rcond=None)
    return _finish(a, np.asarray(ctrl).reshape(-1, 3), rolled, breaks, degrees, t, corners, start)


def _finish(a, ctrl, rolled, breaks, degrees, t, corners, start) -> CDSpline:
    q = len(rolled)
    res = np.linalg.norm(a @ ctrl - rolled, axis=1)
    seg = np.clip(np.searchsorted(breaks, t, side="right") - 1, 0, len(corners) - 1)
    back = (np.arange(q) - start) % q  # original order
    return CDSpline(ctrl, breaks, degrees, t[back], res[back], seg[back])


def _segment_points(points: np.ndarray, corners: np.ndarray, k: int) -> np.ndarray:
    q = len(points)
    lo = corners[k]
    hi = corners[k + 1] if k + 1 < len(corners) else corners[0] + q
    return points[np.arange(lo, hi + 1) % q]


def _overshoot(fit: CDSpline, k: int, seg_points: np.ndarray) -> float:
    """Largest distance from samples of segment k's curve to the polyline of its points (metres)."""
    if len(seg_points) < 2:
        return 0.0
    u = np.linspace(fit.breaks[k], fit.breaks[k + 1], 4 * fit.degrees[k] + 6)[1:-1]
    curve = fit.evaluate(u)[:, None, :]
    a, b = seg_points[None, :-1], seg_points[None, 1:]
    ab = b - a
    s = np.clip(np.sum((curve - a) * ab, axis=2) / np.maximum(np.sum(ab * ab, axis=2), 1e-12), 0.0, 1.0)
    d = np.linalg.norm(curve - (a + s[..., None] * ab), axis=2)
    return float(d.min(axis=1).max())


@functools.lru_cache(maxsize=4096)
def _f_low(significance: float, dof: int) -> float:
    return float(stats.f.ppf(significance / 2, dof, dof))


def iterative_cdspline(points: np.ndarray, corners: np.ndarray, options: CDSplineOptions | None = None) -> CDSpline:
    """CD-spline whose segment degrees are chosen by the F-test on residuals (thesis §5.6).

    All segments start as straight lines; the segment with the largest sum of
    absolute residuals is raised by one degree and the curve refitted while
    the F-test finds the change significant (see :class:`CDSplineOptions`).
    Degrees never exceed ``max_degree`` nor what the segment's points can
    determine (interior points + 1).

    Parameters
    ----------
    points : ndarray of shape (Q, 3) float64
    corners : ndarray of int, shape (M,), sorted
    options : CDSplineOptions, optional

    Returns
    -------
    CDSpline
    """
    options = options or CDSplineOptions()
    points = np.asarray(points, dtype=np.float64)
    corners = np.unique(np.asarray(corners, dtype=np.int64))
    q = len(points)
    if len(corners) == 0:
        corners = np.array([0], dtype=np.int64)
    start = int(corners[0])
    t = chord_parameters(np.roll(points, -start, axis=0))
    interior = np.diff(np.append(corners, corners[0] + q)) - 1
    cap = np.minimum(options.max_degree, 1 + interior // options.points_per_degree)
    if len(corners) == 1:
        cap = np.minimum(cap, max(options.max_degree, 2))
    degrees = np.ones(len(corners), dtype=np.int64)
    if len(corners) < 2:
        degrees[:] = min(2, int(cap[0]))  # a one-segment closed curve cannot be a straight line
    cache: dict = {}
    fit = fit_cdspline(points, corners, degrees, t=t, _cache=cache)
    history = [(degrees.tolist(), fit.sigma)]
    frozen = degrees >= cap
    lo, hi = stats.f.ppf([options.significance / 2, 1 - options.significance / 2], q - 1, q - 1)
    while not frozen.all():
        seg_sum = np.bincount(fit.segment, fit.residuals, len(corners))
        seg_sum[frozen] = -1.0
        k = int(np.argmax(seg_sum))
        trial = degrees.copy()
        trial[k] += 1
        if trial.sum() > q:
            break
        new = fit_cdspline(points, corners, trial, t=t, _cache=cache)
        history.append((trial.tolist(), new.sigma))
        seg_points = _segment_points(points, corners, k)
        # the current curve's overshoot only matters when the raised one
        # exceeds max_overshoot (evaluating it every time cost a tenth of the outline)
        over = _overshoot(new, k, seg_points)
        if over > options.max_overshoot and over > max(options.max_overshoot, _overshoot(fit, k, seg_points)):
            frozen[k] = True
            continue
        if options.test == "global":
            f_c = (new.sigma / fit.sigma) ** 2 if fit.sigma > 0 else 1.0
            if lo < f_c < hi:
                break
            degrees, fit = trial, new
        else:
            sel = fit.segment == k
            n_k = int(sel.sum())
            old_s = np.sum(fit.residuals[sel] ** 2)
            new_s = np.sum(new.residuals[sel] ** 2)
            f_lo = _f_low(options.significance, max(n_k - 1, 1))
            if old_s > 0 and new_s / old_s < f_lo:
                degrees, fit = trial, new
            else:
                frozen[k] = True
        frozen |= degrees >= cap
    fit.history = history
    log.debug("cd-spline: degrees %s after %d fits", degrees.tolist(), len(history))
    return fit

