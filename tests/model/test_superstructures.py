"""Boxes built into a LoD 2.2 solid under superstructure top points (model.superstructures.with_boxes)."""

import numpy as np
import pytest
import shapely

from rooftrace.model.measure import roof_height_at
from rooftrace.model.solid import horizontal_plane, prism_solid
from rooftrace.model.superstructures import BOX_REASONS, with_boxes
from rooftrace.model.validity import solid_errors


def _gable(pitch=35.0, width=8.0, length=10.0, eaves=6.0):
    """A gable's solid: two pitched faces meeting at a ridge along x = width / 2."""
    t = np.tan(np.radians(pitch))
    ridge = width / 2
    left = np.array([-t, 0.0, 1.0, -eaves]) / np.hypot(t, 1.0)  # z = eaves + t x
    right = np.array([t, 0.0, 1.0, -eaves - 2 * t * ridge]) / np.hypot(t, 1.0)  # z = eaves + t (width - x)
    cells = [(shapely.box(0, 0, ridge, length), left), (shapely.box(ridge, 0, width, length), right)]
    return prism_solid(cells, 0.0), lambda x: eaves + t * np.minimum(x, width - x)


def _invariant(solid, boxed, points, why, rise=0.5):
    """Every point more than ``rise`` above the boxed roof, or over none, has a named reason."""
    h = roof_height_at([boxed], points[:, :2])
    off = ~(points[:, 2] - h <= rise)
    assert set(why[off]) <= set(BOX_REASONS)
    return off


def test_a_vent_on_a_flat_roof_is_a_box_of_the_spacing():
    house = prism_solid([(shapely.box(0, 0, 10, 6), horizontal_plane(8.0))], 2.0)
    vent = np.array([[3.004, 2.996, 9.1]])
    boxed, why = with_boxes(house, vent, 0.4)
    assert solid_errors(boxed) == [] and why.tolist() == [""]
    assert roof_height_at([boxed], vent[:, :2])[0] == pytest.approx(9.1)
    # the box is 0.4 m square: 0.25 m beside the vent the roof is the house's
    assert roof_height_at([boxed], np.array([[3.25, 3.0], [3.15, 3.0]])).tolist() == [8.0, pytest.approx(9.1)]
    # a point within rise of the roof needs none; the solid is returned as it was
    same, why = with_boxes(house, np.array([[5.0, 3.0, 8.4]]), 0.4)
    assert same is house and why.tolist() == [""]


def test_boxes_on_a_pitched_roof_stop_at_its_ridge_and_eaves():
    solid, roof = _gable()
    pts = np.array([[2.0, 5.0, 0.0], [4.05, 5.0, 0.0], [0.005, 3.0, 0.0], [6.0, 8.0, 0.0]])
    pts[:, 2] = roof(pts[:, 0]) + [0.8, 1.0, 0.7, 1.5]
    boxed, why = with_boxes(solid, pts, 0.4)
    assert solid_errors(boxed) == []
    # the first and the last stand clear; the one 5 cm past the ridge is cut at it and still holds its point;
    # the one 5 mm from the eaves' wall cannot hold it
    assert why.tolist() == ["", "", "at a roof edge", ""]
    h = roof_height_at([boxed], pts[:, :2])
    assert np.abs(h - pts[:, 2])[[0, 1, 3]].max() < 1e-3
    _invariant(solid, boxed, pts, why)


def test_a_box_never_stands_over_a_lower_point():
    house = prism_solid([(shapely.box(0, 0, 10, 6), horizontal_plane(8.0))], 2.0)
    vent = np.array([[3.0, 3.0, 9.1]])
    roof_point = np.array([[3.12, 3.0, 8.0]])
    boxed, why = with_boxes(house, vent, 0.4, others=np.vstack([vent, roof_point]))
    assert solid_errors(boxed) == [] and why.tolist() == [""]
    assert roof_height_at([boxed], roof_point[:, :2])[0] == pytest.approx(8.0)
    assert roof_height_at([boxed], vent[:, :2])[0] == pytest.approx(9.1)
    # a lower point within two lattice steps: no box
    _, why = with_boxes(house, vent, 0.4, others=np.array([[3.015, 3.0, 8.0]]))
    assert why.tolist() == ["crowded by lower points"]


def test_random_points_over_a_gable_keep_the_solid_valid():
    """Random clutter over a gable (heights 0-3 m above it, 0.2-0.5 m boxes): every boxed solid is valid and every
    point left more than 0.5 m under its roof has a named reason."""
    rng = np.random.default_rng(7)
    for pitch in (0.0, 20.0, 45.0):
        solid, roof = _gable(pitch)
        for _ in range(4):
            n = int(rng.integers(1, 30))
            xy = np.column_stack([rng.uniform(-0.2, 8.2, n), rng.uniform(-0.2, 10.2, n)])
            pts = np.column_stack([xy, roof(xy[:, 0]) + rng.uniform(0.0, 3.0, n)])
            boxed, why = with_boxes(solid, pts, float(rng.uniform(0.2, 0.5)))
            assert solid_errors(boxed) == []
            off = _invariant(solid, boxed, pts, why)
            # off the roof in plan, and nowhere else but where a reason holds
            outside = (xy[:, 0] < 0) | (xy[:, 0] > 8) | (xy[:, 1] < 0) | (xy[:, 1] > 10)
            assert (why[outside] == "on no roof surface").all() and off[outside].all()
