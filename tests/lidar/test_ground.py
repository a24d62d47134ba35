import numpy as np
import pytest

from rooftrace.errors import GeometryError
from rooftrace.lidar.ground import GroundOptions, grid_minimum_ground, progressive_tin, tin_height
from tests.lidar.scenes import GROUND, f1, scene


def test_box_on_a_slope(rng):
    xyz, truth = scene(rng, slope=0.08, boxes=((20.0, 20.0, 16.0, 12.0, 6.0),))
    ground, hag, params = progressive_tin(xyz + [1e5, 4e5, 0], 0.4, 0.03)
    assert f1(ground, truth == GROUND) > 0.995
    roof = truth != GROUND
    # the roof is 6 m above the ground at the box centre; the slope under it varies by +-0.64 m
    assert np.median(hag[roof]) == pytest.approx(6.0, abs=0.15)
    assert np.abs(hag[~roof]).max() < 0.2
    assert params["rounds"] >= 2 and params["ground_tolerance"] == pytest.approx(0.2)


def test_flat_field_is_all_ground(rng):
    xyz, _ = scene(rng, size=40, slope=0.0, boxes=())
    ground, hag, _ = progressive_tin(xyz, 0.4, 0.03)
    assert ground.mean() > 0.999
    assert np.abs(hag).max() < 0.2


def test_courtyard_ground_is_found(rng):
    # a 30 m ring with a 12 m courtyard: the seed grid of 30 m does not see the courtyard alone
    xyz, truth = scene(rng, size=70, courtyards=((20.0, 20.0, 30.0, 12.0, 8.0),), boxes=())
    ground, _, _ = progressive_tin(xyz, 0.4, 0.03)
    court = (np.abs(xyz[:, :2] - 35).max(axis=1) < 5)
    assert ground[court].mean() > 0.99
    assert f1(ground, truth == GROUND) > 0.99


def test_excluded_points_are_never_ground(rng):
    xyz, _ = scene(rng, size=20, boxes=())
    excl = np.zeros(len(xyz), bool)
    excl[::7] = True
    ground, hag, _ = progressive_tin(xyz, 0.4, 0.03, exclude=excl)
    assert not ground[excl].any() and np.isfinite(hag).all()


def test_the_grid_baseline_fails_on_slopes_where_the_tin_does_not(rng):
    xyz, truth = scene(rng, slope=0.1, boxes=((20.0, 20.0, 16.0, 12.0, 6.0),))
    base, _ = grid_minimum_ground(xyz, cell=25.0, threshold=0.5)
    tin, _, _ = progressive_tin(xyz, 0.4, 0.03)
    assert f1(base, truth == GROUND) < 0.6 < 0.99 < f1(tin, truth == GROUND)


def test_tin_height_interpolates_planes():
    v = np.array([[0, 0, 1.0], [10, 0, 2.0], [0, 10, 3.0], [10, 10, 4.0]])
    q = np.array([[5.0, 5.0], [2.0, 1.0], [20.0, 20.0]])
    z = tin_height(v, q)
    assert z[:2] == pytest.approx([2.5, 1.0 + 0.1 * 2 + 0.2 * 1])
    assert np.isnan(z[2])


def test_errors():
    with pytest.raises(GeometryError, match="at least 3"):
        progressive_tin(np.zeros((2, 3)), 1.0, 0.1)
    # collinear points are triangulable thanks to the bounding-box corners
    line = np.column_stack([np.arange(10.0), np.arange(10.0), np.zeros(10)])
    assert progressive_tin(line, 1.0, 0.1)[0].all()
    with pytest.raises(ValueError, match="iteration_angle"):
        GroundOptions(iteration_angle=95)
