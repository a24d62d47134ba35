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


def test_boxes_on_a_pitched_roof_stop_at_its_ridge_and_reach_its_eaves():
    solid, roof = _gable()
    pts = np.array([[2.0, 5.0, 0.0], [4.05, 5.0, 0.0], [0.005, 3.0, 0.0], [6.0, 8.0, 0.0], [3.995, 2.0, 0.0],
                    [7.996, 9.9, 0.0]])
    pts[:, 2] = roof(pts[:, 0]) + [0.8, 1.0, 0.7, 1.5, 1.0, 0.9]
    boxed, why = with_boxes(solid, pts, 0.4)
    assert solid_errors(boxed) == []
    # the first and the fourth stand clear; the one 5 cm past the ridge is cut at it and still holds its point;
    # the one 5 mm from the eaves' wall reaches it (its outer wall on the wall's top), the one 4 mm from the eaves
    # and 0.1 m from the gable's wall too, cut back from the gable's; the one 5 mm before the ridge cannot hold it
    assert why.tolist() == ["", "", "", "", "at a roof edge", ""]
    h = roof_height_at([boxed], pts[:, :2])
    assert np.abs(h - pts[:, 2])[[0, 1, 2, 3, 5]].max() < 1e-3
    _invariant(solid, boxed, pts, why)
    # the eaves' box: a notch in the roof surface; its outer wall in the eaves' wall's plane (x = 0)
    walls = [s for s in boxed.surfaces if s.kind == "WallSurface" and np.ptp(s.rings[0][:, 0]) < 1e-9
             and s.rings[0][0, 0] == 0.0]
    assert len(walls) == 2 and sorted(len(w.rings[0]) for w in walls) == [4, 6]


def test_boxes_at_a_flat_roofs_eaves_and_steps():
    """A box reaches the edge of its roof surface where a wall meets that edge: at the eaves and at the top of a
    step to a lower roof (its outer wall on the wall's top), several on one edge; at the foot of the step (cut into
    the step's wall) when it stays two lattice steps under the wall's top, not when it would rise over it."""
    cells = [(shapely.box(0, 0, 10, 6), horizontal_plane(8.0)), (shapely.box(10, 0, 16, 6), horizontal_plane(5.0))]
    house = prism_solid(cells, 2.0)
    pts = np.array([[3.0, 0.004, 9.1], [6.0, 0.006, 8.9], [9.995, 3.0, 9.2], [10.005, 4.0, 6.0], [15.0, 5.997, 6.1],
                    [10.004, 4.6, 7.9], [10.004, 1.5, 8.1], [10.004, 0.8, 8.6]])
    boxed, why = with_boxes(house, pts, 0.4)
    assert solid_errors(boxed) == []
    assert why.tolist() == ["", "", "", "", "", "", "", "at a roof edge"]
    h = roof_height_at([boxed], pts[:, :2])
    assert np.abs(h - pts[:, 2])[:6].max() < 1e-3
    # one over the step's top (a parapet's return a centimetre off it): as high as the wall lets it
    assert h[6] == pytest.approx(7.98)
    _invariant(house, boxed, pts, why)
    # the step's wall: its three notches go round the boxes' outer sides at its foot, the upper box stands on its top
    (step,) = [s for s in boxed.surfaces if s.kind == "WallSurface" and (s.rings[0][:, 0] == 10.0).all()
               and s.rings[0][:, 2].min() == 5.0]
    assert len(step.rings[0]) == 4 + 3 * 4 + 2
    # at a corner of the outline (two eaves) and at the corner of the step's top and the eaves: the box covers the
    # ring's corner, its two outer walls on the two walls' tops; not where a wall over the edge meets one under it
    corners = np.array([[0.005, 0.006, 9.0], [15.99, 5.99, 6.0], [9.99, 5.995, 9.0], [10.01, 0.004, 6.0]])
    boxed, why = with_boxes(house, corners, 0.4)
    assert solid_errors(boxed) == [] and why.tolist() == ["", "", "", "at a roof edge"]
    assert np.abs(roof_height_at([boxed], corners[:3, :2]) - corners[:3, 2]).max() < 1e-3


def test_no_box_reaches_a_party_wall():
    """A box at the edge of a part over a party wall is refused ("at a roof edge"): the neighbour's solid shares
    that wall vertex for vertex, and a notch would move it (val3dity's 601 between the parts); at the part's eaves
    the box still reaches the edge."""
    part = prism_solid([(shapely.box(0, 0, 10, 6), horizontal_plane(8.0))], 2.0)
    neighbour = shapely.box(10, 0, 16, 6)
    pts = np.array([[9.995, 3.0, 9.2], [3.0, 0.004, 9.1]])
    boxed, why = with_boxes(part, pts, 0.4)
    assert why.tolist() == ["", ""]  # without a neighbour: both edges are eaves
    boxed, why = with_boxes(part, pts, 0.4, party=neighbour)
    assert solid_errors(boxed) == [] and why.tolist() == ["at a roof edge", ""]
    _invariant(part, boxed, pts, why)
    # the party wall (x = 10) keeps its four corners
    (wall,) = [w for w in boxed.surfaces if w.kind == "WallSurface" and (w.rings[0][:, 0] == 10.0).all()]
    assert len(wall.rings[0]) == 4


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


def test_random_points_at_the_edges_keep_the_solid_valid():
    """Random clutter within 3 cm of a roof's edges (eaves, a step's top and foot, a gable's ridge and eaves):
    every boxed solid is valid, every point left more than 0.5 m under its roof has a named reason, and along an
    edge with a wall under it, away from the corners, none is left "at a roof edge"."""
    rng = np.random.default_rng(11)
    step = prism_solid([(shapely.box(0, 0, 10, 6), horizontal_plane(8.0)),
                        (shapely.box(10, 0, 16, 6), horizontal_plane(5.0))], 2.0)
    for solid, roof, edges in ((step, lambda x: np.where(x < 10, 8.0, 5.0), (0.0, 10.0, 16.0)),
                               (*_gable(30.0), (0.0, 4.0, 8.0))):
        for _ in range(4):
            n = int(rng.integers(5, 25))
            x = rng.choice(edges, n) + rng.uniform(-0.03, 0.03, n)
            y = rng.uniform(0.5, 5.5, n)
            pts = np.column_stack([x, y, roof(x) + rng.uniform(0.6, 2.5, n)])
            boxed, why = with_boxes(solid, pts, float(rng.uniform(0.3, 0.5)))
            assert solid_errors(boxed) == []
            _invariant(solid, boxed, pts, why)
            # the outer walls' tops (x = 0 and the last edge) and the step's top: a wall under each such edge
            under_a_wall = ((x > 0) & (x < 0.03)) | ((x < edges[2]) & (x > edges[2] - 0.03))
            if solid is step:
                under_a_wall |= (x < 10) & (x > 9.97)
            assert not (why[under_a_wall] == "at a roof edge").any()


def test_vents_at_the_eaves_and_on_the_ridge_of_a_simulated_gable():
    """The simulated gable with its vents and the two at its edges (``gable(vents=True, edge_vents=True)``, 10
    pts/m², three seeds), each eave vent's outermost return put 4 mm inside the eaves (where an outline drawn
    through the outermost returns puts it): the solids are valid and no top point on no plane stands more than
    0.5 m over the LoD 2.2 roof (a box cut two lattice steps inside the eaves could not hold that return)."""
    from rooftrace.model import build_model
    from rooftrace.roof import models, roof_structure
    from tests.roof.test_structure import _tops_off

    m = models.gable(vents=True, edge_vents=True, angle=20, offset=(85000.0, 447000.0))
    for seed in range(3):
        xyz, face = models.sample_roof(m, 10, 0.03, seed=seed)
        local = m.to_local(xyz[:, :2])
        eave = np.flatnonzero((face < 0) & (local[:, 1] < 0.4))
        outer = eave[np.argmin(local[eave, 1])]
        local[outer, 1] = 0.004
        xyz[outer, :2] = m.to_world(local[outer:outer + 1])[0]
        roof = roof_structure(xyz, m.outline)
        solids = [p.lods["2.2"] for p in build_model(m.outline, roof, xyz, 0.0).parts]
        assert all(solid_errors(s) == [] for s in solids)
        assert not _tops_off(roof, xyz, solids, 0.5).any()
        assert abs(roof_height_at(solids, xyz[outer:outer + 1, :2])[0] - xyz[outer, 2]) < 0.5


def test_a_delft_eave_box():
    """Delft BGT feature 12: a top point on no plane a few millimetres inside the outline stood more than 0.5 m
    over the LoD 2.2 roof ("at a roof edge"); the box reaching the edge holds it, the solids stay valid and no
    top point on no plane is left more than 0.5 m over the roof."""
    from rooftrace.model import build_model
    from rooftrace.roof import roof_structure
    from tests.roof.test_real import _bgt_building
    from tests.roof.test_structure import _tops_off

    xyz, outline = _bgt_building(12)
    roof = roof_structure(xyz, outline, building_id=12)
    solids = [p.lods["2.2"] for p in build_model(outline, roof, xyz, float(xyz[:, 2].min() - 3.0)).parts]
    assert all(solid_errors(s) == [] for s in solids)
    assert not _tops_off(roof, xyz, solids, 0.5).any()
