import numpy as np
import pytest

from rooftrace.contour.corners import CornerOptions, douglas_peucker, ring_corners, turning_angles


def _rectangle_ring(start: float = 0.0, step: float = 0.3, noise: float = 0.03, seed: int = 0):
    """Points every ``step`` m around a 20 x 12 m rectangle, counter-clockwise, starting ``start`` m along."""
    rng = np.random.default_rng(seed)
    corners = np.array([(0, 0), (20, 0), (20, 12), (0, 12), (0, 0)], float)
    s = np.arange(0, 64, step)
    cum = np.array([0, 20, 32, 52, 64])
    seg = np.searchsorted(cum, s, side="right") - 1
    u = (s - cum[seg]) / np.diff(cum)[seg]
    xy = corners[seg] + u[:, None] * (corners[seg + 1] - corners[seg])
    xy += rng.normal(0, noise, xy.shape)
    xy = np.roll(xy, -int(round(start / step)), axis=0)
    return np.column_stack([xy, np.full(len(xy), 8.0)])


def test_douglas_peucker_keeps_the_bend():
    pts = np.array([[0, 0, 0], [1, 0.01, 0], [2, 0, 0], [3, 1, 0], [4, 2, 0]], float)
    assert douglas_peucker(pts, 0.1).tolist() == [0, 2, 4]
    assert douglas_peucker(pts, 5.0).tolist() == [0, 4]


def test_douglas_peucker_is_3d():
    pts = np.array([[0, 0, 0], [1, 0, 1.0], [2, 0, 0]], float)
    assert douglas_peucker(pts, 0.5).tolist() == [0, 1, 2]


@pytest.mark.parametrize("start", [0.0, 7.3, 25.0])
def test_rectangle_corners_found_and_start_not_forced(start):
    ring = _rectangle_ring(start)
    c = ring_corners(ring)
    assert len(c) == 4
    truth = np.array([(0, 0), (20, 0), (20, 12), (0, 12)], float)
    d = np.min(np.linalg.norm(ring[c, None, :2] - truth[None], axis=2), axis=0)
    assert d.max() < 0.35
    if start % 20:  # vertex 0 lies mid-side: it must not survive as a corner
        assert 0 not in c.tolist()


def test_angle_filter_drops_a_shallow_bend():
    # a 0.7 m bow in a 20 m wall passes Douglas-Peucker (T_dist 0.6) but turns only ~8°
    ring = _rectangle_ring(noise=0.0)
    bottom = (ring[:, 1] < 1e-9) & (ring[:, 0] > 0) & (ring[:, 0] < 20)
    ring[bottom, 1] = -0.7 * (1 - np.abs(ring[bottom, 0] - 10) / 10)
    thesis = ring_corners(ring, CornerOptions(keep_curve_breaks=False))
    assert len(thesis) == 4
    angles = turning_angles(ring, thesis)
    assert angles.min() > 80


def test_curve_breaks_kept_on_arcs():
    t = np.linspace(0, 2 * np.pi, 200, endpoint=False)
    ring = np.column_stack([8 * np.cos(t), 8 * np.sin(t), np.zeros_like(t)])
    thesis = ring_corners(ring)
    kept = ring_corners(ring, CornerOptions(keep_curve_breaks=True))
    assert len(kept) >= 8 and len(kept) > len(thesis)


def test_bad_options():
    with pytest.raises(ValueError, match="t_dist"):
        CornerOptions(t_dist=0)
