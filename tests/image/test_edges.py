import numpy as np
import pytest

from rooftrace.image.edges import canny_edges, gaussian_gradient, link_chains, noise_sigma
from tests.image._render import render


@pytest.mark.parametrize("x_edge", [20.0, 20.3, 20.75])
def test_canny_subpixel_step_position(x_edge):
    # vertical step at column x_edge (pixel-area rendering, blur 1 px)
    img = render((40, 40), [([[x_edge, -5], [60, -5], [60, 45], [x_edge, 45]], 0.8)], background=0.2)
    edges, pts = canny_edges(img, 1.0)
    cols = pts[edges][:, 0]
    rows = np.nonzero(edges)[0]
    inner = (rows > 4) & (rows < 35)  # away from the image border
    assert inner.sum() >= 25
    assert np.abs(cols[inner] - x_edge).max() < 0.08


def test_canny_ring_edges_lie_in_the_ring_band(rng):
    rows, cols = np.mgrid[:60, :60]
    r = np.hypot(rows - 30, cols - 30)
    img = ((r > 10) & (r < 20)).astype(float) + rng.normal(0, 0.02, r.shape)
    edges, pts = canny_edges(img, 1.5)
    rr = np.hypot(pts[edges][:, 1] - 30, pts[edges][:, 0] - 30)
    assert np.all((np.abs(rr - 10) < 1.0) | (np.abs(rr - 20) < 1.0))
    # both circles are found (2 pi r px each), and noise adds nothing
    assert 0.9 * 2 * np.pi * 30 < edges.sum() < 1.2 * 2 * np.pi * 30


def test_canny_derived_thresholds_ignore_noise_and_weak_steps(rng):
    flat = 0.5 + rng.normal(0, 0.02, (50, 50))
    assert canny_edges(flat)[0].sum() == 0
    weak = np.zeros((30, 30))
    weak[:, 15:] = 0.03
    assert canny_edges(weak, min_contrast=0.05)[0].sum() == 0
    assert canny_edges(weak, min_contrast=0.02)[0].sum() > 0


def test_canny_mask_restricts_output_not_filtering():
    img = np.zeros((30, 30))
    img[:, 15:] = 1.0
    mask = np.zeros_like(img, bool)
    mask[:, 10:20] = True
    mask[:10] = False
    e_all, p_all = canny_edges(img)
    e_m, p_m = canny_edges(img, mask=mask)
    assert e_m.sum() == (e_all & mask).sum() > 0
    np.testing.assert_array_equal(p_m[e_m], p_all[e_m])


def test_canny_bad_arguments():
    with pytest.raises(ValueError, match="2-D"):
        canny_edges(np.zeros(5))
    with pytest.raises(ValueError, match="sigma"):
        canny_edges(np.zeros((5, 5)), sigma=0)
    with pytest.raises(ValueError, match="low threshold"):
        canny_edges(np.zeros((5, 5)), low=2.0, high=1.0)


def test_noise_sigma_is_robust_to_edges(rng):
    img = np.zeros((100, 100))
    img[:, 50:] = 1.0
    img[30:60, 20:80] += 0.5
    noisy = img + rng.normal(0, 0.03, img.shape)
    assert noise_sigma(noisy) == pytest.approx(0.03, rel=0.1)
    assert noise_sigma(img) == 0.0


def test_gaussian_gradient_axes():
    img = np.tile(np.arange(20.0), (10, 1))  # increases along columns
    gx, gy = gaussian_gradient(img, 1.0)
    assert gx[5, 10] == pytest.approx(1.0, abs=1e-3)
    assert gy[5, 10] == pytest.approx(0.0, abs=1e-6)


def test_link_chains_orders_open_curves_end_to_end():
    m = np.zeros((20, 20), bool)
    rr = np.arange(3, 15)
    m[rr, rr] = True  # diagonal
    m[14, 15:19] = True  # bends into a horizontal run
    chains = link_chains(m)
    assert len(chains) == 1
    ch = chains[0]
    assert len(ch) == m.sum()
    steps = np.abs(np.diff(ch, axis=0)).max(axis=1)
    assert steps.max() == 1  # consecutive points are neighbours
    ends = {tuple(ch[0]), tuple(ch[-1])}
    assert ends == {(3.0, 3.0), (18.0, 14.0)}


def test_link_chains_loops_junctions_and_subpixel_points():
    m = np.zeros((20, 20), bool)
    m[5, 5:15] = m[14, 5:15] = True
    m[5:15, 5] = m[5:15, 14] = True  # a closed square loop
    chains = link_chains(m)
    assert len(chains) == 1 and len(chains[0]) == m.sum()
    t = np.zeros((15, 15), bool)
    t[7, 2:13] = True
    t[8:13, 7] = True  # a T junction: the stem becomes its own chain
    chains = link_chains(t)
    assert sum(len(c) for c in chains) == t.sum()
    assert len(chains) == 2
    pts = np.full((15, 15, 2), np.nan)
    pts[7, 2:13, 0] = np.arange(2, 13) + 0.25
    pts[7, 2:13, 1] = 7.4
    ch = link_chains(t, pts)
    longest = max(ch, key=len)
    assert np.allclose(longest[:, 1], 7.4)
    assert link_chains(np.zeros((4, 4), bool)) == []


def test_colour_canny_equals_grey_on_grey_images_and_sees_hue_edges():
    img = render((40, 40), [([[20.3, -5], [60, -5], [60, 45], [20.3, 45]], 0.8)], background=0.2)
    e1, p1 = canny_edges(img)
    e3, p3 = canny_edges(np.stack([img] * 3, axis=-1))
    np.testing.assert_array_equal(e1, e3)
    np.testing.assert_allclose(p1[e1], p3[e3], atol=1e-9)
    hue = np.full((40, 40, 3), 0.5)
    hue[:, 20:, 0] += 0.1
    hue[:, 20:, 1] -= 0.1  # the grey mean is flat
    assert canny_edges(hue.mean(axis=2))[0].sum() == 0
    e, p = canny_edges(hue)
    assert np.abs(p[e][:, 0] - 19.5).max() < 0.05 and e.sum() >= 38
    with pytest.raises(ValueError, match="colour"):
        canny_edges(np.zeros((2, 3, 4, 5)))
