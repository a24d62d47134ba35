import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from rooftrace.image.edges import gaussian_gradient
from rooftrace.image.refit import edge_profile_peaks, refit_lines


def _step(shape=(40, 50), col=20, blur=0.7, noise=0.0, seed=0):
    """Dark left, bright right; the step lies between columns col-1 and col (at col - 0.5)."""
    img = np.zeros(shape)
    img[:, col:] = 1.0
    img = gaussian_filter(img, blur)
    return img + noise * np.random.default_rng(seed).standard_normal(shape)


def test_tilted_guess_lands_on_the_step_within_a_tenth_of_a_pixel():
    img = _step(noise=0.02)
    out, ok = refit_lines(img, np.array([[[18.6, 3.0], [20.8, 36.0]]]))
    assert ok.tolist() == [True]
    np.testing.assert_allclose(out[0, :, 0], 19.5, atol=0.1)
    assert out[0, 0, 1] < 5 and out[0, 1, 1] > 34  # the extent follows the guess


def test_two_merged_edges_keep_the_longer_and_its_extent():
    # rows 0-27: step at 19.5; rows 28-39: another edge at 22.5 (a neighbour 3 px off)
    img = np.zeros((40, 50))
    img[:28, 20:] = 1.0
    img[28:, 23:] = 1.0
    img = gaussian_filter(img, 0.7)
    merged = np.array([[[19.0, 1.0], [23.0, 38.0]]])  # the tilted line a merge would give
    out, ok = refit_lines(img, merged)
    assert ok[0]
    np.testing.assert_allclose(out[0, :, 0], 19.5, atol=0.15)
    assert out[0, 1, 1] < 30  # stops where the other edge starts


def test_polarity_keeps_the_segment_on_its_own_step():
    # roof 0.6 | bright wall strip 0.9 (3 px) | ground 0.2: two opposite steps 3 px apart
    img = np.full((30, 40), 0.6)
    img[:, 20:23] = 0.9
    img[:, 23:] = 0.2
    img = gaussian_filter(img, 0.7)
    gx, gy = gaussian_gradient(img, 0.7)
    pts = np.array([[21.0, 15.0], [21.0, 15.0]])
    normals = np.array([[1.0, 0.0], [1.0, 0.0]])
    off, strength = edge_profile_peaks(gx, gy, pts, normals, np.array([1.0, -1.0]))
    # rising step (roof -> wall) at 19.5, falling (wall -> ground) at 22.5
    np.testing.assert_allclose(pts[:, 0] + off, [19.5, 22.5], atol=0.2)
    assert (strength > 0).all()


def test_no_edge_leaves_the_segment_as_it_was():
    img = np.full((30, 30), 0.5) + 0.001 * np.random.default_rng(1).standard_normal((30, 30))
    seg = np.array([[[5.0, 5.0], [5.0, 25.0]]])
    out, ok = refit_lines(img, seg, min_strength=0.01)
    assert not ok[0]
    np.testing.assert_array_equal(out, seg)
    assert refit_lines(img, np.zeros((0, 2, 2)))[0].shape == (0, 2, 2)


def test_bad_arguments_raise():
    with pytest.raises(ValueError, match="2-D"):
        refit_lines(np.zeros((5, 5, 3)), np.zeros((1, 2, 2)))
    with pytest.raises(ValueError, match="positive"):
        refit_lines(np.zeros((5, 5)), np.zeros((1, 2, 2)), sigma=0)
