import numpy as np
import pytest

from rooftrace.image.camera import FrameCamera, OrthoCamera
from rooftrace.image.projection import clip_to_window, in_window, line_windows, project_lines, window_slices


def _nadir(cov=None):
    return FrameCamera((400, 400), 0.01, 100.0, np.array([0.0, 0.0, 1000.0, 0, 0, 0]), exterior_covariance=cov)


def test_project_lines_known_pixels_and_error():
    lines = np.array([[[0, 0, 0], [10, 0, 0]], [[0, 0, 0], [0, -5, 0]]], float)
    ref, err = project_lines(_nadir(), lines)
    np.testing.assert_allclose(ref[0], [[199.5, 199.5], [299.5, 199.5]], atol=1e-9)
    np.testing.assert_allclose(ref[1], [[199.5, 199.5], [199.5, 249.5]], atol=1e-9)
    # only the LiDAR precision: 0.48 m at 0.1 m / px on both axes (+ a little from sigma_z off-centre)
    assert err[0] == pytest.approx(np.sqrt(2) * 4.8, rel=0.01)
    cov = np.diag([0.2**2, 0.2**2, 0.2**2, 1e-4**2, 1e-4**2, 1e-4**2])
    _, err2 = project_lines(_nadir(cov), lines)
    assert np.all(err2 > err)
    _, err3 = project_lines(_nadir(), lines, sigma_xy=0.1)
    assert np.all(err3 < err)


def test_project_lines_orthophoto():
    cam = OrthoCamera((100, 100), (0.2, 0, 1000.0, 0, -0.2, 2000.0))
    ref, err = project_lines(cam, np.array([[[1001.0, 1999.0, 30.0], [1002.0, 1999.0, 5.0]]]))
    np.testing.assert_allclose(ref[0], [[4.5, 4.5], [9.5, 4.5]])
    assert err[0] == pytest.approx(np.sqrt(2) * 0.48 / 0.2)


def test_project_lines_rejects_bad_shapes():
    with pytest.raises(ValueError, match="shape"):
        project_lines(_nadir(), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="NaN"):
        project_lines(_nadir(), np.full((1, 2, 3), np.nan))


def test_windows_follow_the_formula_and_contain_the_line(rng):
    ref = np.array([[[50.0, 60.0], [150.0, 110.0]]])
    win = line_windows(ref, [4.0], k=3.0, margin=2.0)[0]
    hw, ext = 3 * 4 + 2, 3 * 4
    length = np.hypot(100, 50)
    assert np.hypot(*(win[0] - win[3])) == pytest.approx(2 * hw)
    assert np.hypot(*(win[1] - win[0])) == pytest.approx(length + 2 * ext)
    # the projected line is the symmetry axis
    np.testing.assert_allclose((win[0] + win[3]) / 2 + (win[1] + win[2]) / 2, 2 * ref[0].mean(0))
    t = rng.uniform(0, 1, 50)
    on_line = ref[0, 0] + t[:, None] * (ref[0, 1] - ref[0, 0])
    assert in_window(on_line, win).all()
    u = (ref[0, 1] - ref[0, 0]) / length
    n = np.array([-u[1], u[0]])
    assert not in_window(ref[0].mean(0) + (hw + 0.1) * n, win).any()
    assert in_window(ref[0].mean(0) + (hw - 0.1) * n, win).all()
    assert not in_window(ref[0, 0] - (ext + 0.1) * u, win).any()
    with pytest.raises(ValueError, match="non-negative"):
        line_windows(ref, [1.0], k=-1)


def test_window_slices_clip_and_miss():
    win = np.array([[-5.0, -5.0], [20, -5], [20, 10], [-5, 10]])
    rows, cols = window_slices(win, (50, 15), pad=2)
    assert (rows.start, rows.stop, cols.start, cols.stop) == (0, 13, 0, 15)
    assert window_slices(win + 100, (50, 50)) is None


def test_clip_to_window():
    win = np.array([[0.0, 0.0], [10, 0], [10, 4], [0, 4]])
    segs = np.array([[[-5, 2], [15, 2]], [[2, 1], [3, 3]], [[-5, 10], [15, 10]], [[5, -3], [5, 8]], [[12, 0], [20, 4]]], float)
    out, keep = clip_to_window(segs, win)
    np.testing.assert_array_equal(keep, [True, True, False, True, False])
    np.testing.assert_allclose(out[0], [[0, 2], [10, 2]])
    np.testing.assert_allclose(out[1], segs[1])
    np.testing.assert_allclose(out[2], [[5, 0], [5, 4]])
    # a rotated window
    rot = line_windows(np.array([[[0.0, 0.0], [10.0, 10.0]]]), [1.0], k=1.0, margin=0.0)[0]
    out, keep = clip_to_window(np.array([[[-10.0, -10.0], [20.0, 20.0]]]), rot)
    assert keep[0] and in_window(out[0], rot + 1e-9 * (rot - rot.mean(0))).all()
    np.testing.assert_allclose(np.hypot(*(out[0, 1] - out[0, 0])), np.hypot(10, 10) + 2.0)
