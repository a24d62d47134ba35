import numpy as np
import pytest
from scipy.interpolate import BSpline
from scipy.special import comb

from rooftrace.contour.cdspline import CDSplineOptions, cd_basis, chord_parameters, fit_cdspline, iterative_cdspline


def _bernstein(u, d):
    return np.column_stack([comb(d, r) * u**r * (1 - u) ** (d - r) for r in range(d + 1)])


@pytest.mark.parametrize("p", [1, 2, 3])
def test_equal_degrees_match_scipy_bspline(p):
    breaks = np.array([0.0, 0.2, 0.45, 0.7, 1.0])
    knots = np.concatenate([[0.0] * (p + 1), np.repeat(breaks[1:-1], p), [1.0] * (p + 1)])
    t = np.linspace(0, 1, 97)
    want = BSpline.design_matrix(t, knots, p).toarray()
    got = cd_basis(t, breaks, [p] * 4, closed=False)
    np.testing.assert_allclose(got, want, atol=1e-12)


def test_mixed_degrees_are_bezier_spans_sharing_end_points():
    breaks = np.array([0.0, 0.3, 0.6, 1.0])
    degrees = [1, 3, 2]
    t = np.linspace(0, 1, 101)
    a = cd_basis(t, breaks, degrees, closed=False)
    assert a.shape == (101, 7)
    np.testing.assert_allclose(a.sum(axis=1), 1.0, atol=1e-12)
    offsets = np.concatenate([[0], np.cumsum(degrees)])
    for k, d in enumerate(degrees):
        sel = (t >= breaks[k]) & (t < breaks[k + 1]) if k < 2 else (t >= breaks[k])
        u = (t[sel] - breaks[k]) / (breaks[k + 1] - breaks[k])
        block = a[np.ix_(sel, np.arange(offsets[k], offsets[k] + d + 1))]
        np.testing.assert_allclose(block, _bernstein(u, d), atol=1e-12)
        rest = np.delete(a[sel], np.arange(offsets[k], offsets[k] + d + 1), axis=1)
        assert np.all(rest == 0)


def test_closed_basis_wraps_last_control_point_onto_first():
    breaks = np.array([0.0, 0.5, 1.0])
    t = np.array([0.0, 0.999999])
    a = cd_basis(t, breaks, [1, 2])
    assert a.shape == (2, 3)
    assert a[0, 0] == 1.0 and a[1, 0] == pytest.approx(1.0, abs=1e-5)


def test_chord_parameters():
    pts = np.array([[0, 0, 0], [3, 0, 0], [3, 4, 0]], float)
    np.testing.assert_allclose(chord_parameters(pts), [0, 0.25, 7 / 12])
    np.testing.assert_allclose(chord_parameters(pts, closed=False), [0, 3 / 7, 1])


def _half_disc(n_line=40, n_arc=80, noise=0.0, seed=0):
    """Closed ring: a 10 m straight diameter then a radius-5 semicircle (3D, z = 6)."""
    rng = np.random.default_rng(seed)
    x = np.linspace(-5, 5, n_line, endpoint=False)
    line = np.column_stack([x, np.zeros_like(x)])
    a = np.linspace(0, np.pi, n_arc, endpoint=False)
    arc = np.column_stack([5 * np.cos(a), 5 * np.sin(a)])
    xy = np.concatenate([line, arc]) + rng.normal(0, noise, (n_line + n_arc, 2))
    return np.column_stack([xy, np.full(len(xy), 6.0)]), np.array([0, n_line])


def test_fit_recovers_exact_cdspline_curve():
    rng = np.random.default_rng(1)
    ctrl = rng.uniform(0, 10, (5, 3))  # closed, degrees 2 and 3: 5 control points
    breaks = np.array([0.0, 0.4, 1.0])
    t = np.linspace(0, 1, 60, endpoint=False)
    pts = cd_basis(t, breaks, [2, 3]) @ ctrl
    corners = np.array([0, 24])
    fit = fit_cdspline(pts, corners, [2, 3], t=t)
    np.testing.assert_allclose(fit.control_points, ctrl, atol=1e-9)
    assert fit.residuals.max() < 1e-9


def test_degree_selection_line_stays_straight_arc_is_raised():
    pts, corners = _half_disc(noise=0.03)
    for test in ("segment", "global"):
        fit = iterative_cdspline(pts, corners, CDSplineOptions(test=test))
        assert fit.degrees[0] == 1
        assert fit.degrees[1] >= 3
        assert fit.residuals.max() < 0.15


def test_degree_cap_and_history():
    pts, corners = _half_disc(noise=0.0)
    fit = iterative_cdspline(pts, corners, CDSplineOptions(max_degree=2))
    assert fit.degrees == [1, 2]
    assert fit.history[0][0] == [1, 1]


def test_rotation_of_the_ring_does_not_change_the_fit():
    pts, corners = _half_disc(noise=0.02)
    a = iterative_cdspline(pts, corners)
    b = iterative_cdspline(np.roll(pts, -7, axis=0), (corners - 7) % len(pts))
    assert a.degrees == b.degrees[::-1]  # the arc's corner comes first after the roll
    np.testing.assert_allclose(np.roll(a.residuals, -7), b.residuals, atol=1e-9)


def test_ring_densifies_only_curved_segments():
    pts, corners = _half_disc(noise=0.0)
    fit = iterative_cdspline(pts, corners)
    vertices, corner_index = fit.ring(step=0.5)
    assert corner_index.tolist()[0] == 0 and corner_index[1] == 1  # the straight side has no inner vertex
    assert len(vertices) > 25
    r = np.hypot(vertices[2:, 0], vertices[2:, 1])
    np.testing.assert_allclose(r, 5.0, atol=0.02)
    np.testing.assert_allclose(vertices[:, 2], 6.0, atol=1e-9)


def test_span_basis_equals_the_vectorised_recursion():
    """The compiled span basis gives the values of the numpy Cox-de Boor
    recursion it replaced, bit for bit (right end included)."""
    from rooftrace.contour.cdbasis import span_basis

    def recursion(t, knots, degree):
        n0 = len(knots) - 1
        b = ((knots[:-1] <= t[:, None]) & (t[:, None] < knots[1:])).astype(np.float64)
        at_end = t == knots[-1]
        if at_end.any():
            b[at_end] = 0.0
            b[at_end, np.flatnonzero(knots[:-1] < knots[-1])[-1]] = 1.0
        for p in range(1, degree + 1):
            left_den = knots[p:n0] - knots[: n0 - p]
            right_den = knots[p + 1: n0 + 1] - knots[1: n0 - p + 1]
            with np.errstate(divide="ignore", invalid="ignore"):
                left = np.where(left_den > 0, (t[:, None] - knots[: n0 - p]) / left_den, 0.0)
                right = np.where(right_den > 0, (knots[p + 1: n0 + 1] - t[:, None]) / right_den, 0.0)
            b = left * b[:, :-1] + right * b[:, 1:]
        return b

    rng = np.random.default_rng(5)
    for degree in range(1, 6):
        b0, b1 = np.sort(rng.random(2))
        knots = np.concatenate([np.full(degree + 1, b0), np.full(degree + 1, b1)])
        t = np.concatenate([[b0], np.sort(rng.uniform(b0, b1, 50)), [b1]])
        got, want = span_basis(t, knots, degree), recursion(t, knots, degree)
        assert got.shape == want.shape == (52, degree + 1)
        assert np.array_equal(got.view(np.int64), want.view(np.int64))


@pytest.mark.parametrize("n_corners, max_degree", [(1, 3), (2, 2), (7, 3), (60, 5)])
def test_banded_normal_equations_give_the_least_squares_fit(n_corners, max_degree):
    # the compiled fit solves AᵀA by a bordered banded Cholesky; the reference is lstsq on the dense A
    rng = np.random.default_rng(n_corners)
    q = 40 * n_corners + 60
    phi = np.sort(rng.uniform(0, 2 * np.pi, q))
    radius = 20 + np.sin(5 * phi) + rng.normal(0, 0.05, q)
    points = np.column_stack([radius * np.cos(phi), radius * np.sin(phi), rng.normal(5, 0.1, q)])
    corners = np.sort(rng.choice(q, n_corners, replace=False))
    degrees = rng.integers(1, max_degree + 1, n_corners)
    if n_corners == 1:
        degrees[:] = max_degree  # a one-segment closed curve cannot be straight
    fit = fit_cdspline(points, corners, degrees)
    rolled = np.roll(points, -corners[0], axis=0)
    a = cd_basis(chord_parameters(rolled), fit.breaks, degrees)
    want, *_ = np.linalg.lstsq(a, rolled, rcond=None)
    np.testing.assert_allclose(fit.control_points, want, atol=1e-8)
    res = np.linalg.norm(a @ want - rolled, axis=1)
    np.testing.assert_allclose(fit.residuals, np.roll(res, corners[0]), atol=1e-8)
    if n_corners == 60:
        assert sum(degrees) > 80  # the size that took scipy.sparse before


def test_segment_without_points_for_its_degree_falls_back_to_least_squares():
    # a cubic span holding only its corner point: AᵀA is singular, the minimum-norm fit is kept
    square = np.array([[0, 0], [4, 0], [8, 0], [10, 0], [10, 5], [10, 10], [5, 10], [0, 10], [0, 5]], float)
    points = np.column_stack([square, np.zeros(len(square))])
    fit = fit_cdspline(points, [0, 2, 3, 7], [1, 3, 1, 1])
    a = cd_basis(chord_parameters(points), fit.breaks, [1, 3, 1, 1])
    assert np.linalg.matrix_rank(a) < a.shape[1]
    want, *_ = np.linalg.lstsq(a, points, rcond=None)
    np.testing.assert_allclose(fit.control_points, want, atol=1e-9)
