import numpy as np
import pytest
from scipy.ndimage import gaussian_filter
from shapely.geometry import box

from rooftrace.image.camera import FrameCamera
from rooftrace.image.walls import mark_wall_lines, wall_strips

CAM = FrameCamera((400, 400), 0.01, 100.0, np.array([-30.0, 10.0, 1000.0, 0, 0, 0]))
# a 10 m x 10 m roof at 10 m (counter-clockwise ring: south, east, north, west) and a ridge
LINES = np.array([[[-5, -5, 10], [5, -5, 10]], [[5, -5, 10], [5, 5, 10]], [[5, 5, 10], [-5, 5, 10]],
                  [[-5, 5, 10], [-5, -5, 10]], [[-5, 0, 14], [5, 0, 14]]], float)
KINDS = ["outline"] * 4 + ["ridge"]


def test_walls_facing_the_camera_are_visible_by_their_relief_displacement():
    w, n = wall_strips(CAM, LINES, KINDS, box(-5, -5, 5, 5), 0.0)
    # the camera stands west and north of the roof: west and north walls show, south and east do not
    assert w[0] == 0 and w[1] == 0 and w[3] > 2 and w[2] > 0.3
    # the west wall's width is the image distance between eave and foot across the side
    mid_top, mid_foot = CAM.project(np.array([[-5, 0, 10.0], [-5, 0, 0.0]]))
    assert w[3] == pytest.approx(abs(mid_foot[0] - mid_top[0]), abs=0.05)
    assert w[4] == 0 and np.isnan(n[4]).all()
    np.testing.assert_allclose(np.linalg.norm(n[:4], axis=1), 1.0)
    # outward: away from the projected roof centre
    centre = CAM.project(np.array([[0.0, 0.0, 10.0]]))[0]
    mids = CAM.project(LINES[:4].mean(axis=1))
    assert (np.einsum("ij,ij->i", mids - centre, n[:4]) > 0).all()
    # the orientation of the ring does not matter
    w2, _ = wall_strips(CAM, LINES[:4, ::-1], KINDS[:4], box(-5, -5, 5, 5), 0.0)
    np.testing.assert_allclose(w2, w[:4])


def _wall_image(roof=0.66, wall=0.70, ground=0.45, width=3, seed=0):
    """Roof for columns < 30, a visible wall strip of ``width`` px, then ground; roof edge at 29.5."""
    img = np.full((60, 60), ground)
    img[:, :30] = roof
    img[:, 30:30 + width] = wall
    img = gaussian_filter(img, 0.7)
    return img + 0.012 * np.random.default_rng(seed).standard_normal(img.shape)


def test_weak_roof_edge_is_found_inward_of_the_wall_foot():
    img = _wall_image()
    foot = np.array([[[32.5, 5.0], [32.5, 55.0]]])  # the only candidate Canny gives: the wall's foot
    seg, src, wall = mark_wall_lines(img, foot, ["canny"], np.array([1.0, 0.0]), 3.0, noise=0.012)
    assert src == ["canny", "inner"] and wall.tolist() == [True, False]
    np.testing.assert_allclose(seg[1, :, 0], 29.5, atol=0.3)


def test_without_a_roof_edge_nothing_is_added_or_marked():
    img = _wall_image(wall=0.66)  # wall as bright as the roof: the foot might be the roof edge
    foot = np.array([[[32.5, 5.0], [32.5, 55.0]]])
    seg, src, wall = mark_wall_lines(img, foot, ["canny"], np.array([1.0, 0.0]), 3.0, noise=0.012)
    assert src == ["canny"] and not wall.any()
    # no visible wall: nothing to do
    seg, src, wall = mark_wall_lines(_wall_image(), foot, ["canny"], np.array([1.0, 0.0]), 0.0)
    assert len(seg) == 1 and not wall.any()


def test_pair_marks_the_outer_line_only_within_the_wall_width():
    img = _wall_image(wall=0.9)
    pair = np.array([[[29.5, 5.0], [29.5, 55.0]], [[32.5, 5.0], [32.5, 55.0]]])
    seg, src, wall = mark_wall_lines(img, pair, ["canny", "canny"], np.array([1.0, 0.0]), 3.0, noise=0.012)
    assert wall[:2].tolist() == [False, True]
    # a predicted wall of 1 px cannot explain a line 3 px out
    _, _, wall = mark_wall_lines(img, pair, ["canny", "canny"], np.array([1.0, 0.0]), 1.0, noise=0.012)
    assert not wall[:2].any()
