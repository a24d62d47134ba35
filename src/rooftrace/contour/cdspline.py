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
from dataclasses import dataclass, field

import numpy as np
from numba import njit
from scipy.special import fdtri

from rooftrace.contour.cdbasis import cd_basis, chord_parameters, cox_de_boor
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


def fit_cdspline(points: np.ndarray, corners: np.ndarray, degrees, *, t: np.ndarray | None = None) -> CDSpline:
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
        equations P = (AᵀA)⁻¹AᵀQ are solved by a banded Cholesky
        factorisation (:func:`_normal_fit`), or, when they are singular (a
        segment with too few points for its degree), by least squares on A.
    """
    return _RingFit(points, corners, t).fit(degrees)


class _RingFit:
    """A ring and its knots, ready for fits of any segment degrees: the F-test refits one ring hundreds of times."""

    def __init__(self, points: np.ndarray, corners: np.ndarray, t: np.ndarray | None = None):
        points = np.asarray(points, dtype=np.float64)
        corners = np.asarray(corners, dtype=np.int64)
        q = len(points)
        start = int(corners[0])
        self.rolled = np.roll(points, -start, axis=0)
        self.t = chord_parameters(self.rolled) if t is None else t
        self.breaks = np.append(self.t[corners - start], 1.0)
        if np.any(np.diff(self.breaks) <= 0):
            raise GeometryError("degenerate_segment")
        self.back = (np.arange(q) - start) % q  # original order
        # shared by every fit of the ring, so read-only
        self.t_original = self.t[self.back]
        self.segment = np.clip(np.searchsorted(self.breaks, self.t, side="right") - 1, 0, len(corners) - 1)[self.back]
        for shared in (self.breaks, self.t_original, self.segment):
            shared.flags.writeable = False

    def fit(self, degrees) -> CDSpline:
        degrees = np.asarray(degrees, dtype=np.int64)
        if degrees.sum() > len(self.rolled):
            raise GeometryError("too_few_points")
        ctrl, res, ok = _normal_fit(self.rolled, self.t, self.breaks, degrees)
        if not ok:
            a = cd_basis(self.t, self.breaks, degrees)
            ctrl, *_ = np.linalg.lstsq(a, self.rolled, rcond=None)
            res = np.linalg.norm(a @ ctrl - self.rolled, axis=1)
        return CDSpline(ctrl, self.breaks, degrees.tolist(), self.t_original, res[self.back], self.segment)


@njit(cache=True, error_model="numpy")
def _normal_fit(rolled, t, breaks, degrees):  # pragma: no cover - compiled
    # Each trial degree of the F-test loop is a new least-squares fit of the whole ring (thousands per
    # building): building A and AᵀA as matrices (dense, or scipy.sparse beyond 80 control points) was
    # most of the outline stage's time.  Here AᵀA is accumulated span by span straight into its band:
    # a span's columns are contiguous, so AᵀA is banded (half-width the largest degree) but for the
    # first control point, which the last span shares (the closed ring).  That point is the border of
    # a bordered band system: B y1 + c y0 = r1, cᵀ y1 + s y0 = r0, solved with B's Cholesky factor and
    # a scalar Schur complement.  Returns the control points, the residuals |A·P - Q| (rows as t) and
    # whether B and the Schur complement were positive definite (else the caller solves by least squares).
    q = len(t)
    m = len(degrees)
    offsets = np.zeros(m + 1, np.int64)
    for k in range(m):
        offsets[k + 1] = offsets[k] + degrees[k]
    n = offsets[m]
    p = 1
    for k in range(m):
        p = max(p, degrees[k])
    bounds = np.empty(m + 1, np.int64)
    bounds[:m] = np.searchsorted(t, breaks[:m])
    bounds[m] = q
    band = np.zeros((n, p + 1))  # band[i, j] = (AᵀA)[i, i - j] for i - j >= 1
    border = np.zeros(n)  # (AᵀA)[i, 0]
    rhs = np.zeros((n, 3))
    vals = np.zeros((q, p + 1))
    cols = np.zeros((q, p + 1), np.int64)
    width = np.zeros(q, np.int64)
    for k in range(m):
        d = degrees[k]
        lo, hi = bounds[k], bounds[k + 1]
        knots = np.empty(2 * d + 2)
        knots[:d + 1] = breaks[k]
        knots[d + 1:] = breaks[k + 1]
        basis = cox_de_boor(t[lo:hi], knots, d)
        for r in range(hi - lo):
            row = lo + r
            width[row] = d + 1
            for a in range(d + 1):
                vals[row, a] = basis[r, a]
                cols[row, a] = (offsets[k] + a) % n
            for a in range(d + 1):
                va, i = vals[row, a], cols[row, a]
                for c3 in range(3):
                    rhs[i, c3] += va * rolled[row, c3]
                for b in range(d + 1):
                    j = cols[row, b]
                    if j == 0:
                        border[i] += va * vals[row, b]
                    elif 0 < j <= i:
                        band[i, i - j] += va * vals[row, b]
    ctrl = np.zeros((n, 3))
    fitted = np.zeros((q, 3))
    if n < 2:
        return ctrl, np.zeros(q), False
    # Cholesky factor of B = (AᵀA)[1:, 1:], in place in the band
    for i in range(1, n):
        for j in range(max(1, i - p), i + 1):
            s = band[i, i - j]
            for k in range(max(1, i - p), j):
                s -= band[i, i - k] * band[j, j - k]
            if i == j:
                if not s > 1e-13 * max(band[i, 0], 1e-300):
                    return ctrl, np.zeros(q), False
                band[i, 0] = np.sqrt(s)
            else:
                band[i, i - j] = s / band[j, 0]
    # B⁻¹ [r1, c]: forward then backward substitution, four right-hand sides at once
    w = np.zeros((n, 4))
    for i in range(1, n):
        for c4 in range(4):
            s = rhs[i, c4] if c4 < 3 else border[i]
            for k in range(max(1, i - p), i):
                s -= band[i, i - k] * w[k, c4]
            w[i, c4] = s / band[i, 0]
    for i in range(n - 1, 0, -1):
        for c4 in range(4):
            s = w[i, c4]
            for k in range(i + 1, min(n, i + p + 1)):
                s -= band[k, k - i] * w[k, c4]
            w[i, c4] = s / band[i, 0]
    schur = border[0]
    for i in range(1, n):
        schur -= border[i] * w[i, 3]
    if not schur > 1e-13 * max(border[0], 1e-300):
        return ctrl, np.zeros(q), False
    for c3 in range(3):
        s = rhs[0, c3]
        for i in range(1, n):
            s -= border[i] * w[i, c3]
        ctrl[0, c3] = s / schur
        for i in range(1, n):
            ctrl[i, c3] = w[i, c3] - w[i, 3] * ctrl[0, c3]
    for row in range(q):
        for a in range(width[row]):
            for c3 in range(3):
                fitted[row, c3] += vals[row, a] * ctrl[cols[row, a], c3]
    res = np.empty(q)
    for row in range(q):
        s = 0.0
        for c3 in range(3):
            diff = fitted[row, c3] - rolled[row, c3]
            s += diff * diff
        res[row] = np.sqrt(s)
    return ctrl, res, True


def _segment_points(points: np.ndarray, corners: np.ndarray, k: int) -> np.ndarray:
    q = len(points)
    lo = corners[k]
    hi = corners[k + 1] if k + 1 < len(corners) else corners[0] + q
    return points[np.arange(lo, hi + 1) % q]


def _overshoot(fit: CDSpline, k: int, seg_points: np.ndarray) -> float:
    """Largest distance from samples of segment k's curve to the polyline of its points (metres)."""
    if len(seg_points) < 2:
        return 0.0
    d = fit.degrees[k]
    offset = sum(fit.degrees[:k])
    ctrl = fit.control_points[np.arange(offset, offset + d + 1) % len(fit.control_points)]
    return _polyline_overshoot(np.ascontiguousarray(ctrl), float(fit.breaks[k]), float(fit.breaks[k + 1]), d,
                               np.ascontiguousarray(seg_points, dtype=np.float64))


@njit(cache=True, error_model="numpy")
def _polyline_overshoot(ctrl, lo, hi, degree, poly):  # pragma: no cover - compiled
    # thousands of raises per building are each checked: the numpy form's temporaries (a curve-sample ×
    # polyline-edge grid per raise) cost a tenth of the outline stage
    count = 4 * degree + 6
    u = np.linspace(lo, hi, count)[1:-1]
    knots = np.empty(2 * degree + 2)
    knots[:degree + 1] = lo
    knots[degree + 1:] = hi
    basis = cox_de_boor(u, knots, degree)
    worst = 0.0
    for r in range(len(u)):
        c = np.zeros(3)
        for a in range(degree + 1):
            for j in range(3):
                c[j] += basis[r, a] * ctrl[a, j]
        best = np.inf
        for e in range(len(poly) - 1):
            ab2 = 0.0
            t = 0.0
            for j in range(3):
                ab = poly[e + 1, j] - poly[e, j]
                ab2 += ab * ab
                t += (c[j] - poly[e, j]) * ab
            t = min(max(t / max(ab2, 1e-12), 0.0), 1.0)
            d2 = 0.0
            for j in range(3):
                x = c[j] - (poly[e, j] + t * (poly[e + 1, j] - poly[e, j]))
                d2 += x * x
            best = min(best, d2)
        worst = max(worst, best)
    return np.sqrt(worst)


@functools.lru_cache(maxsize=4096)
def _f_low(significance: float, dof: int) -> float:
    # scipy.special's F quantile, which scipy.stats.f.ppf returns: importing scipy.stats took 0.6 s of every run
    return float(fdtri(dof, dof, significance / 2))


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
    ring = _RingFit(points, corners, t)
    fit = ring.fit(degrees)
    history = [(degrees.tolist(), fit.sigma)]
    frozen = degrees >= cap
    lo, hi = fdtri(q - 1, q - 1, np.array([options.significance / 2, 1 - options.significance / 2]))
    while not frozen.all():
        seg_sum = np.bincount(fit.segment, fit.residuals, len(corners))
        seg_sum[frozen] = -1.0
        k = int(np.argmax(seg_sum))
        trial = degrees.copy()
        trial[k] += 1
        if trial.sum() > q:
            break
        new = ring.fit(trial)
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

