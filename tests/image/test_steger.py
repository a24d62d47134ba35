import numpy as np
import pytest

from rooftrace.image.steger import hessian_line_points, line_position_bias, line_response, steger_lines, steger_sigma


def _profile_image(profile_fn, shape=(30, 61), ss=64):
    """Rows repeat a 1-D profile integrated over each pixel's area (exact anti-aliasing)."""
    h, w = shape
    x = (np.arange(w * ss) + 0.5) / ss - 0.5
    row = profile_fn(x).reshape(w, ss).mean(axis=1)
    return np.tile(row, (h, 1))


def _mean_centre(lines, pts, band=(8, 22)):
    rows = np.nonzero(lines)[0]
    sel = (rows >= band[0]) & (rows < band[1])
    return pts[lines][sel, 0]


@pytest.mark.parametrize("centre", [30.0, 30.37, 29.8])
@pytest.mark.parametrize("width", [3.0, 5.0])
def test_symmetric_bar_subpixel_centre(centre, width):
    img = _profile_image(lambda x: 0.2 + 0.6 * (np.abs(x - centre) <= width / 2))
    lines, pts = steger_lines(img, line_width=width)
    cols = _mean_centre(lines, pts)
    assert len(cols) >= 14  # one point per row
    assert np.abs(cols - centre).max() < 0.05


def test_dark_bar_and_polarity():
    img = _profile_image(lambda x: 0.8 - 0.6 * (np.abs(x - 30.2) <= 1.5))
    lines, pts = steger_lines(img, line_width=3, polarity="dark")
    assert np.abs(_mean_centre(lines, pts) - 30.2).max() < 0.05
    assert steger_lines(img, line_width=3, polarity="bright")[0][8:22].sum() == 0


@pytest.mark.parametrize("a", [0.3, 0.6])
def test_asymmetric_bar_bias_follows_eq_11(a):
    # profile 0 | 1 on |x| <= w | a: the centre shifts by -sigma^2/(2w) ln(1-a) (seed 003 eq. 11)
    w, sigma, centre = 2.0, 1.5, 30.0
    img = _profile_image(lambda x: np.where(np.abs(x - centre) <= w, 1.0, np.where(x > centre, a, 0.0)))
    lines, pts = steger_lines(img, sigma, line_width=2 * w)
    shift = _mean_centre(lines, pts).mean() - centre
    expected = line_position_bias(sigma, w, a)
    assert expected > 0.15
    assert shift == pytest.approx(expected, abs=0.05)


def test_step_edge_gives_no_line():
    img = _profile_image(lambda x: 0.2 + 0.6 * (x > 30.3))
    lines, _ = steger_lines(img, line_width=4)
    assert lines[5:25].sum() == 0


def test_oblique_bar_and_noise(rng):
    rows, cols = np.mgrid[:60, :60].astype(float)
    angle = np.radians(30)
    d = (cols - 30) * np.sin(angle) - (rows - 30) * np.cos(angle)  # signed distance to a line at 30 deg
    img = 0.3 + 0.5 * np.clip(2.0 - np.abs(d), 0, 1) + rng.normal(0, 0.02, d.shape)  # ~3 px bar
    lines, pts = steger_lines(img, line_width=3)
    p = pts[lines]
    dist = (p[:, 0] - 30) * np.sin(angle) - (p[:, 1] - 30) * np.cos(angle)
    inner = np.hypot(p[:, 0] - 30, p[:, 1] - 30) < 25
    assert inner.sum() > 40
    assert np.abs(dist[inner]).max() < 0.3
    assert np.sqrt(np.mean(dist[inner] ** 2)) < 0.12


def test_hessian_normals_are_unit_and_across_the_line():
    img = _profile_image(lambda x: (np.abs(x - 30) <= 1.5).astype(float))
    strength, pts, normals = hessian_line_points(img, 1.2, "bright")
    line = strength > 0
    assert line[:, 30].all()
    np.testing.assert_allclose(np.hypot(normals[line, 0], normals[line, 1]), 1.0)
    assert abs(normals[15, 30, 0]) == pytest.approx(1.0, abs=1e-6)
    assert strength[15, 30] == pytest.approx(line_response(1.0, 3.0, 1.2), rel=0.05)


def test_sigma_rule_and_bad_arguments():
    assert steger_sigma(6.0) == pytest.approx(3.0 / np.sqrt(3.0))
    assert steger_sigma(1.0) == 1.0
    with pytest.raises(ValueError, match="line_width"):
        steger_sigma(0)
    with pytest.raises(ValueError, match="polarity"):
        hessian_line_points(np.zeros((5, 5)), 1.0, "grey")
    with pytest.raises(ValueError, match="asymmetry"):
        line_position_bias(1.0, 1.0, 1.0)
    assert line_position_bias(1.0, 2.0, 0.0) == 0.0


@pytest.mark.parametrize("w, sigma", [(2.0, 1.5), (1.5, 1.0)])
@pytest.mark.parametrize("a", [0.0, 0.3, 0.6])
def test_bias_correction_recovers_the_bar_centre(w, sigma, a):
    centre = 30.2
    img = _profile_image(lambda x: np.where(np.abs(x - centre) <= w, 1.0, np.where(x > centre, a, 0.0)))
    lines, pts = steger_lines(img, sigma, line_width=2 * w, correct_bias=True)
    shift = _mean_centre(lines, pts).mean() - centre
    assert abs(shift) < 0.08
    if a:
        assert line_position_bias(sigma, w, a) > 0.1  # what it was without the correction
    # a dark bar on a bright background is corrected the same way
    dark_lines, dark_pts = steger_lines(1.0 - img, sigma, line_width=2 * w, correct_bias=True)
    assert abs(_mean_centre(dark_lines, dark_pts).mean() - centre) < 0.08
