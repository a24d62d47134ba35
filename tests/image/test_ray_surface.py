import numpy as np
import pytest

from rooftrace.image.camera import FrameCamera, OrthoCamera
from rooftrace.image.ray_surface import TinSurface, intersect_tin


def _house(rng):
    """Ground at z = 0 with a flat 10 m high block (x, y in [-5, 5])."""
    g = np.mgrid[-20:20.01:0.5, -20:20.01:0.5].reshape(2, -1).T + rng.normal(0, 0.01, (1, 2))
    z = np.where((np.abs(g[:, 0]) < 5) & (np.abs(g[:, 1]) < 5), 10.0, 0.0)
    return np.column_stack([g, z])


def test_tin_interpolates_planes_exactly(rng):
    xy = rng.uniform(0, 50, (300, 2))
    z = 2 + 0.3 * xy[:, 0] - 0.1 * xy[:, 1]
    tin = TinSurface(np.column_stack([xy, z]))
    q = rng.uniform(10, 40, (100, 2))
    np.testing.assert_allclose(tin.height(q), 2 + 0.3 * q[:, 0] - 0.1 * q[:, 1], atol=1e-9)
    assert np.isnan(tin.height([[-10.0, -10.0]])).all()
    with pytest.raises(ValueError, match="at least 3"):
        TinSurface(np.zeros((2, 3)))
    with pytest.raises(ValueError, match="surface"):
        TinSurface(np.column_stack([np.arange(5.0), np.arange(5.0), np.zeros(5)]))


def test_rays_round_trip_on_a_tilted_plane(rng):
    cam = FrameCamera((1000, 1000), 0.01, 100.0, np.array([5.0, -3.0, 500.0, 0.05, -0.04, 0.3]))
    xy = rng.uniform(-40, 40, (400, 2))
    tin = TinSurface(np.column_stack([xy, 10 + 0.2 * xy[:, 0]]))
    truth = np.column_stack([rng.uniform(-30, 30, (50, 2)), np.zeros(50)])
    truth[:, 2] = 10 + 0.2 * truth[:, 0]
    back = intersect_tin(cam, cam.project(truth), tin)
    np.testing.assert_allclose(back, truth, atol=1e-6)


def test_rays_hit_the_visible_roof_not_the_hidden_ground(rng):
    tin = TinSurface(_house(rng))
    # an oblique camera: the ray through a roof point would meet the ground behind the block too
    cam = FrameCamera((2000, 2000), 0.01, 50.0, np.array([-60.0, 0.0, 80.0, 0.0, -0.6, 0.0]))
    roof = np.array([[-2.0, 1.0, 10.0], [3.0, -2.0, 10.0]])
    ground_front = np.array([[-12.0, 0.0, 0.0]])
    back = intersect_tin(cam, cam.project(np.vstack([roof, ground_front])), tin)
    np.testing.assert_allclose(back, np.vstack([roof, ground_front]), atol=1e-3)
    # a pixel outside the TIN gives NaN
    far = cam.project(np.array([[300.0, 0.0, 0.0]]))
    assert np.isnan(intersect_tin(cam, far, tin)).all()


def test_orthophoto_rays_are_vertical(rng):
    tin = TinSurface(_house(rng))
    cam = OrthoCamera((200, 200), (0.2, 0, -20.0, 0, -0.2, 20.0))
    pts = np.array([[0.0, 0.0, 10.0], [10.0, 10.0, 0.0]])
    np.testing.assert_allclose(intersect_tin(cam, cam.project(pts), tin), pts, atol=1e-6)
