import numpy as np

from rooftrace.image.camera import FrameCamera
from rooftrace.image.terrain import PixelHeights, sample_segments, terrain_lines


def _setup():
    cam = FrameCamera((300, 300), 0.01, 100.0, np.array([0.0, 0.0, 1000.0, 0, 0, 0]))
    g = np.mgrid[-15:15:0.3, -15:15:0.3].reshape(2, -1).T
    roof = (np.abs(g[:, 0]) <= 5) & (np.abs(g[:, 1]) <= 5)
    pts = np.column_stack([g, np.where(roof, 8.0, 0.0)])
    return cam, pts, pts[roof]


def test_pixel_heights_nearest_neighbour():
    cam, pts, _ = _setup()
    ph = PixelHeights(cam, pts)
    z, e = ph.sample(cam.project(np.array([[0.0, 0.0, 8.0], [10.0, 10.0, 0.0]])))
    np.testing.assert_allclose(z, [8.0, 0.0])
    assert np.all(e > 0)
    bounded = PixelHeights(cam, pts, bounds=(140, 140, 160, 160))
    assert 0 < len(bounded) < len(ph) / 20
    empty = PixelHeights(cam, np.zeros((0, 3)))
    assert np.isnan(empty.sample([[1.0, 1.0]])[0]).all()


def test_terrain_lines_removes_far_ground_lines_only():
    cam, pts, roof = _setup()
    ph = PixelHeights(cam, pts)
    bld = cam.project(roof)
    segs = cam.project(np.array([
        [-4, 12, 0], [4, 12, 0],      # ground, 7 m north of the roof: terrain
        [-4, 5.2, 0], [4, 5.2, 0],    # ground, just outside the roof edge: kept (within the registration error)
        [-4, 3, 8], [4, 3, 8],        # on the roof: kept
        [-4, -12, 0], [4, -12, 0],    # ground, far south: terrain
    ], float)).reshape(-1, 2, 2)
    drop = terrain_lines(segs, ph, bld, building_z=8.0)
    np.testing.assert_array_equal(drop, [True, False, False, True])
    # a building as low as the ground keeps everything
    assert not terrain_lines(segs, ph, bld, building_z=0.5).any()
    assert not terrain_lines(segs, PixelHeights(cam, np.zeros((0, 3))), bld, 8.0).any()


def test_sample_segments_every_pixel():
    pts, owner = sample_segments(np.array([[[0, 0], [10, 0]], [[0, 0], [0, 0.2]]], float))
    assert (owner == 0).sum() == 11 and (owner == 1).sum() == 2
    np.testing.assert_allclose(pts[owner == 0][:, 0], np.arange(11.0))


def test_roof_edge_far_from_a_displaced_outline_is_kept():
    # the LiDAR outline (the "building" here) is 1.2 m = 12 px off: more than the
    # registration error, so the distance test alone would call the true edge terrain
    cam, pts, _ = _setup()
    ph = PixelHeights(cam, pts)
    shifted_outline = cam.project(np.array([[-5, 6.2, 8], [5, 6.2, 8], [5, -3.8, 8], [-5, -3.8, 8]], float))
    from rooftrace.image.terrain import sample_segments as ss
    bld, _ = ss(np.stack([shifted_outline, np.roll(shifted_outline, -1, axis=0)], axis=1))
    edge = cam.project(np.array([[-4, -5, 8], [4, -5, 8]], float))[None]  # the true south edge
    road = cam.project(np.array([[-4, -12, 0], [4, -12, 0]], float))[None]
    drop = terrain_lines(np.concatenate([edge, road]), ph, bld, building_z=8.0)
    np.testing.assert_array_equal(drop, [False, True])
    # sampling on the line itself (the seed's way) would remove the edge
    assert terrain_lines(edge, ph, bld, building_z=8.0, side_offset=0.0)[0]
