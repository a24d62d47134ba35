import numpy as np
import pytest

from rooftrace.image.corners import HarrisOptions, harris_corners
from tests.image._render import render


def _square(angle_deg=20.0, centre=(60.3, 58.7), half=25.0):
    a = np.radians(angle_deg)
    u, v = np.array([np.cos(a), np.sin(a)]), np.array([-np.sin(a), np.cos(a)])
    c = np.array(centre)
    return np.array([c - half * u - half * v, c + half * u - half * v, c + half * u + half * v, c - half * u + half * v])


def test_harris_finds_the_corners_of_a_rotated_roof(rng):
    corners = _square()
    img = render((120, 120), [(corners, 0.8)], background=0.2, noise=0.01, seed=1)
    found = harris_corners(img)
    assert len(found) == 4
    d = np.hypot(*(found[:, None, :] - corners[None]).transpose(2, 0, 1)).min(axis=0)
    assert d.max() < 0.5
    # the raw response maximum sits ~2 px inside the corner; the quadratic refinement keeps that bias
    quad = harris_corners(img, options=HarrisOptions(subpixel="quadratic"))
    dq = np.hypot(*(quad[:, None, :] - corners[None]).transpose(2, 0, 1)).min(axis=0)
    assert dq.min() > 1.0 and dq.max() < 3.0


def test_harris_mask_and_window_restrict_the_search():
    corners = _square(0.0, (60, 60), 30)
    img = render((120, 120), [(corners, 0.8)], background=0.2)
    win = np.array([[20, 20], [50, 20], [50, 50], [20, 50]], float)  # around the top-left corner
    found = harris_corners(img, win)
    assert len(found) == 1
    np.testing.assert_allclose(found[0], corners[0], atol=0.5)
    mask = np.zeros(img.shape, bool)
    mask[70:, 70:] = True
    found = harris_corners(img, mask)
    assert len(found) == 1 and np.hypot(*(found[0] - corners[2])) < 0.5
    assert len(harris_corners(img, np.zeros(img.shape, bool))) == 0
    assert len(harris_corners(img, win + 1000)) == 0
    # several windows at once
    assert len(harris_corners(img, np.stack([win, win + 60]))) == 2


def test_harris_flat_image_and_options():
    assert harris_corners(np.full((30, 30), 0.5)).shape == (0, 2)
    with pytest.raises(ValueError, match="subpixel"):
        HarrisOptions(subpixel="none")
    with pytest.raises(ValueError, match="harris.k"):
        HarrisOptions(k=0.3)
    with pytest.raises(ValueError, match="2-D"):
        harris_corners(np.zeros(10))
