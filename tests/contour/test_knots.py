import numpy as np

from rooftrace.contour.cdspline import iterative_cdspline
from rooftrace.contour.corners import ring_douglas_peucker
from rooftrace.contour.knots import refine_corners, spline_outline


def _stadium_end_ring():
    """Closed ring: flat end x=0, straight walls y=0 and y=10 to x=14, a semicircle of radius 5 beyond."""
    step = 0.25
    bottom = np.column_stack([np.arange(0, 14, step), np.zeros(56)])
    a = np.arange(-np.pi / 2, np.pi / 2, step / 5)
    arc = np.column_stack([14 + 5 * np.cos(a), 5 + 5 * np.sin(a)])
    top = np.column_stack([np.arange(14, 0, -step), np.full(56, 10.0)])
    left = np.column_stack([np.zeros(40), np.arange(10, 0, -step)])
    xy = np.concatenate([bottom, arc, top, left])
    return np.column_stack([xy, np.full(len(xy), 4.0)]), np.array([0, 56 + len(arc) + 56])


def test_tangent_wall_and_arc_are_split():
    ring, corners = _stadium_end_ring()
    candidates = np.setdiff1d(ring_douglas_peucker(ring, 0.1), corners)
    plain = iterative_cdspline(ring, corners)
    assert max(plain.degrees) >= 4  # wall + arc + wall in one polynomial
    fit = spline_outline(ring, corners, candidates)
    assert len(fit.degrees) > len(plain.degrees)
    assert fit.sigma < 0.2 * plain.sigma
    # every segment whose points all lie on the straight walls is a line; the arc is curved
    for k, d in enumerate(fit.degrees):
        pts = ring[fit.segment == k]
        if len(pts) > 4 and np.all(pts[1:, 0] < 13.9):
            assert d == 1, fit.degrees
    assert max(fit.degrees) >= 2
    assert fit.residuals.max() < 0.3


def test_refine_corners_moves_a_misplaced_corner():
    ring, _ = _stadium_end_ring()
    square = np.array([(0, 0), (10, 0), (10, 10), (0, 10)], float)
    s = np.arange(0, 40, 0.2)
    seg = (s // 10).astype(int)
    u = (s % 10) / 10
    xy = square[seg] + u[:, None] * (square[(seg + 1) % 4] - square[seg])
    pts = np.column_stack([xy, np.zeros(len(xy))])
    got = refine_corners(pts, np.array([0, 53, 100, 150]))  # corner 1 is 0.6 m up the right side
    assert got[[0, 2, 3]].tolist() == [0, 100, 150] and abs(got[1] - 50) <= 1


def test_merge_collinear_drops_vertices_along_straight_walls():
    from rooftrace.contour.cdspline import CDSplineOptions

    square = np.array([(0, 0), (10, 0), (10, 10), (0, 10)], float)
    s = np.arange(0, 40, 0.2)
    seg = (s // 10).astype(int)
    u = (s % 10) / 10
    xy = square[seg] + u[:, None] * (square[(seg + 1) % 4] - square[seg])
    xy += np.random.default_rng(0).normal(0, 0.02, xy.shape)
    pts = np.column_stack([xy, np.zeros(len(xy))])
    corners = np.array([0, 20, 50, 75, 100, 130, 150, 170])  # 4 true corners + 4 mid-wall vertices
    plain = spline_outline(pts, corners, options=CDSplineOptions(merge_angle=0.0))
    merged = spline_outline(pts, corners, options=CDSplineOptions(merge_angle=15.0))
    assert len(plain.degrees) == 8 and len(merged.degrees) == 4
    assert merged.sigma < 0.05
