"""Energy terms: the right-angle term, evenness and the image term through the camera (issue 8)."""

import numpy as np
import pytest
from scipy import ndimage

from rooftrace.image.camera import FrameCamera
from rooftrace.snake.energy import angle_energy, edge_field, height_energy, side_energy, spacing_energy


def test_angle_term_zero_at_right_angles_one_when_straight():
    p = np.array([[0.0, 0.0]])
    c = np.array([[4.0, 0.0]])
    nxt = np.array([[4.0, 3.0], [4.0, -2.0], [9.0, 0.0], [1.0, 0.0], [8.0, 4.0], [4.0, 0.0]])
    e = angle_energy(p, c, nxt)[0, 0]
    np.testing.assert_allclose(e, [0.0, 0.0, 1.0, 1.0, 0.5, 1.0], atol=1e-12)  # last: degenerate side


def test_angle_term_is_cos_squared_and_invariant(rng):
    theta = rng.uniform(0, np.pi, 50)
    p = np.array([[0.0, 0.0]])
    c = np.array([[2.0, 0.0]])
    nxt = c + np.column_stack([np.cos(theta), np.sin(theta)]) * 3.0
    e = angle_energy(p, c, nxt)[0, 0]
    np.testing.assert_allclose(e, np.cos(theta) ** 2, atol=1e-12)
    a = 0.7  # rotate, scale and shift the triplet: same energy
    r = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    f = lambda v: 5.0 * v @ r.T + [1e5, 4e5]  # noqa: E731
    np.testing.assert_allclose(angle_energy(f(p), f(c), f(nxt))[0, 0], e, atol=1e-9)


def test_angle_term_shapes_follow_candidates():
    e = angle_energy(np.zeros((2, 2)), np.ones((3, 2)), np.full((4, 2), 2.0) + [[0, 1]])
    assert e.shape == (2, 3, 4)


def test_spacing_term():
    a = np.array([[0.0, 0.0]])
    b = np.array([[10.0, 0.0], [5.0, 0.0], [0.0, 20.0]])
    np.testing.assert_allclose(spacing_energy(a, b, 10.0)[0], [0.0, 0.25, 1.0])
    with pytest.raises(ValueError, match="mean_length"):
        spacing_energy(a, b, 0.0)


@pytest.fixture(scope="module")
def step_scene():
    """A bright 20 x 10 m flat roof at Z = 8 seen by a tilted frame camera; the image is exact."""
    cam = FrameCamera((300, 300), 0.012, 60.0, np.array([-100.0, 0.0, 1000.0, 0.0, -0.1, 0.05]))
    cols, rows = np.meshgrid(np.arange(300), np.arange(300))
    plane = np.array([0.0, 0.0, 1.0, -8.0])
    xyz = cam.intersect_plane(np.column_stack([cols.ravel(), rows.ravel()]), plane)
    inside = (np.abs(xyz[:, 0]) < 10) & (np.abs(xyz[:, 1]) < 5)
    image = ndimage.gaussian_filter(np.where(inside, 0.8, 0.3).reshape(300, 300), 0.7)
    return cam, image


def test_side_energy_strong_on_the_edge_weak_off_it(step_scene):
    cam, image = step_scene
    field = edge_field(image, 1.0)
    height = lambda xy: np.full(np.shape(xy)[:-1], 8.0)  # noqa: E731
    a = np.array([[-8.0, -5.0], [-8.0, -3.0], [-8.0, -5.0]])
    b = np.array([[8.0, -5.0], [8.0, -3.0], [8.0, -2.0]])
    e = side_energy(field, cam.project, height, a, b, 32)
    assert e.shape == (3, 3)
    assert e[0, 0] < -0.9  # on the roof edge
    assert e[1, 1] > -0.05  # 2 m inside the roof, flat grey
    assert e[0, 0] < e[2, 2] < e[1, 1]  # a slanted side crosses the edge once
    # the wrong height moves the projected side off the edge: relief displacement counts
    # (the camera stands 100 m west: a side running north-south shifts by 8 m x 0.1)
    low = lambda xy: np.zeros(np.shape(xy)[:-1])  # noqa: E731
    west_a, west_b = np.array([[-10.0, -4.0]]), np.array([[-10.0, 4.0]])
    assert side_energy(field, cam.project, height, west_a, west_b, 32)[0, 0] < -0.9
    assert side_energy(field, cam.project, low, west_a, west_b, 32)[0, 0] > -0.5


def test_side_energy_degenerate_side_is_zero(step_scene):
    cam, image = step_scene
    height = lambda xy: np.full(np.shape(xy)[:-1], 8.0)  # noqa: E731
    a = np.array([[-8.0, -5.0]])
    assert side_energy(edge_field(image), cam.project, height, a, a)[0, 0] == 0.0


def test_edge_field_window_matches_full_image(step_scene):
    _, image = step_scene
    full = edge_field(image, 1.5)
    part = edge_field(image, 1.5, (100, 120, 200, 180))
    cr = np.array([[150.0, 150.0], [130.5, 140.25], [120.0, 165.0]])
    # normalisers differ (per window): the two fields are proportional
    g1, g2 = full.sample(cr), part.sample(cr)
    k = g2.ravel() @ g1.ravel() / (g1.ravel() @ g1.ravel())
    assert k > 0
    np.testing.assert_allclose(g2, k * g1, atol=1e-9)
    with pytest.raises(ValueError, match="sigma"):
        edge_field(image, 0.0)


def test_height_term_rewards_the_roof_edge_only():
    # roof of height 6 m for x < 0, ground beyond: the edge is the line x = 0
    step = lambda xy: np.where(np.asarray(xy)[..., 0] < 0.0, 6.0, 0.0)  # noqa: E731
    a = np.array([[0.0, 10.0], [-3.0, 10.0], [3.0, 10.0]])
    b = np.array([[0.0, 0.0], [-3.0, 0.0], [3.0, 0.0]])
    # running from y=10 to y=0 the interior (x < 0) is on the right: clockwise
    e = height_energy(step, a, b, offset=0.5, step=2.0, interior=-1)
    np.testing.assert_allclose(np.diag(e), [-1.0, 0.0, 0.0])
    # the other orientation sees the step the wrong way round: no reward
    assert height_energy(step, a[:1], b[:1], 0.5, interior=1)[0, 0] == 0.0
    # a small step counts in proportion
    half = lambda xy: step(xy) / 6.0  # noqa: E731
    assert height_energy(half, a[:1], b[:1], 0.5, step=2.0, interior=-1)[0, 0] == pytest.approx(-0.5)
