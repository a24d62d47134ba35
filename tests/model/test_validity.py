"""The own validity checker: valid constructed solids pass, each kind of defect is named."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import shapely

from rooftrace.model import Solid, Surface, prism_solid, solid_errors, solid_volume
from tests.model.cases import box, gable


def _box():
    cells, _ = box()
    return prism_solid(cells, 0.0)


def test_a_box_is_valid_with_its_volume():
    solid = _box()
    assert solid_errors(solid) == []
    assert solid_volume(solid) == pytest.approx(480.0)


def test_a_flipped_surface_is_found():
    solid = _box()
    solid.surfaces[0].rings = [r[::-1] for r in solid.surfaces[0].rings]
    assert any("same direction" in e or "inward" in e or "clockwise" in e for e in solid_errors(solid))


def test_all_surfaces_flipped_is_inward():
    solid = _box()
    for s in solid.surfaces:
        s.rings = [r[::-1] for r in s.rings]
    assert any("inward" in e for e in solid_errors(solid))


def test_a_missing_wall_is_not_closed():
    solid = _box()
    walls = [i for i, s in enumerate(solid.surfaces) if s.kind == "WallSurface"]
    del solid.surfaces[walls[0]]
    assert any("not closed" in e for e in solid_errors(solid))


def test_a_bent_roof_is_not_planar():
    solid = _box()
    roof = solid.surfaces[0]
    roof.rings[0] = roof.rings[0].copy()
    roof.rings[0][0, 2] += 0.05
    errors = solid_errors(solid)
    assert any("not planar" in e for e in errors)
    assert solid_errors(solid, planarity=0.1) != errors  # the tolerance is used


def test_a_bow_tie_surface_self_intersects():
    sq = np.array([[0, 0, 0], [3, 2, 0], [3, 0, 0], [0, 1, 0]], float)  # lobes of unequal area
    solid = Solid([Surface([sq], "GroundSurface")] + [copy.deepcopy(Surface([sq + [0, 0, 1]], "RoofSurface"))] * 3)
    assert any("self-intersecting" in e for e in solid_errors(solid))


def test_duplicate_vertices_are_found():
    solid = _box()
    r = solid.surfaces[0].rings[0]
    solid.surfaces[0].rings[0] = np.vstack([r[:1], r])
    assert any("duplicate" in e for e in solid_errors(solid))


def test_two_separate_boxes_are_not_one_shell():
    a, b = _box(), _box()
    for s in b.surfaces:
        s.rings = [r + [100.0, 0, 0] for r in s.rings]
    assert any("not connected" in e for e in solid_errors(Solid(a.surfaces + b.surfaces)))


def test_two_boxes_sharing_one_corner_make_a_non_manifold_vertex():
    a, b = _box(), _box()
    for s in b.surfaces:  # b's lowest corner on a's highest one: the surfaces there make two fans
        s.rings = [r + [10.0, 8.0, 6.0] for r in s.rings]
    errors = solid_errors(Solid(a.surfaces + b.surfaces))
    assert "1 non-manifold vertices (the surfaces around them make several fans)" in errors
    assert not any("non-manifold" in e for e in solid_errors(a))


def test_volume_is_translation_invariant():
    cells, volume = gable()
    solid = prism_solid(cells, 0.0)
    moved = Solid([Surface([r + [85000.0, 447000.0, 0.0] for r in s.rings], s.kind) for s in solid.surfaces])
    assert solid_volume(moved) == pytest.approx(volume, abs=1e-3)


def test_a_vertex_one_grid_step_from_the_next_repeats_it_for_val3dity():
    # val3dity snaps vertices within 1 mm when it reads a file: a ring through two vertices 1 mm
    # apart (distinct on the writer's 1 mm grid) repeats one (its error 102)
    solid = _box()
    roof = solid.surfaces[0]
    r = roof.rings[0]
    roof.rings[0] = np.vstack([r[:1], r[:1] + [0.001, 0.0, 0.0], r[1:]])
    assert any("duplicate" in e for e in solid_errors(solid))
    assert not any("duplicate" in e for e in solid_errors(solid, snap_tolerance=0.0))


def test_a_surface_flat_to_the_millimetre_whose_triangles_tilt_is_not_planar():
    # a roof vertex 1 cm beside a corner and 4 mm above the plane: within the 1 cm distance to the
    # plane, but the thin triangle it makes tilts by about 20-40 degrees (val3dity's error 204)
    square = np.array([[0, 0, 6], [10, 0, 6], [10, 8, 6], [0.01, 8, 6.004], [0, 8, 6]], float)
    solid = _box()
    solid.surfaces[0].rings[0] = square
    errors = solid_errors(solid)
    assert any("triangles' normals" in e for e in errors) and not any("m from its plane" in e for e in errors)
    assert not any("triangles' normals" in e for e in solid_errors(solid, normals_deviation=89.0))


def test_overlapping_parts_finds_slivers_and_not_shared_walls():
    from rooftrace.model import horizontal_plane
    from rooftrace.model.validity import overlapping_parts

    left = prism_solid([(shapely.box(0, 0, 5, 8), horizontal_plane(6.0))], 0.0)
    right = prism_solid([(shapely.box(5, 0, 10, 8), horizontal_plane(9.0))], 0.0)
    # a party wall bent 7 mm into the neighbour over 8 m: 0.028 m² of overlap
    bent = prism_solid([(shapely.Polygon([(4.993, 4), (5, 0), (10, 0), (10, 8), (5, 8)]), horizontal_plane(9.0))], 0.0)
    above = prism_solid([(shapely.box(0, 0, 5, 8), horizontal_plane(20.0))], 10.0)  # a storey over left
    assert overlapping_parts([left, right]) == []
    assert overlapping_parts([left, right, bent]) == [(0, 2), (1, 2)]
    assert overlapping_parts([left, bent], tolerance=0.01) == []  # val3dity's --overlap_tol
    assert overlapping_parts([left, above]) == [] and overlapping_parts([right, above]) == []
    assert overlapping_parts([left]) == []


def test_overlapping_parts_finds_a_vertex_on_the_neighbours_straight_wall():
    from rooftrace.model import horizontal_plane
    from rooftrace.model.validity import overlapping_parts, t_junctions

    # a party wall off the axes, one part with an extra vertex on it, collinear on the 1 mm grid: no area
    # overlaps in rounded coordinates, but a reader's floating-point coordinates put a 1e-10 m² sliver on one
    # side (val3dity's error 601)
    wall = [(3.0, 0.0), (5.0, 8.0)]
    mid = (4.0, 4.0)
    left = prism_solid([(shapely.Polygon([(0, 0), *wall[:1], mid, wall[1], (0, 8)]), horizontal_plane(6.0))], 0.0)
    right = prism_solid([(shapely.Polygon([wall[0], (10, 0), (10, 8), wall[1]]), horizontal_plane(9.0))], 0.0)
    shared = prism_solid([(shapely.Polygon([wall[0], (10, 0), (10, 8), wall[1], mid]), horizontal_plane(9.0))], 0.0)
    assert t_junctions(shapely.box(0, 0, 5, 8), shapely.box(5, 0, 10, 8)) == 0
    assert overlapping_parts([left, right]) == [(0, 1)]
    assert overlapping_parts([left, shared]) == []


def test_snap_neighbours_are_the_k_d_trees_pairs():
    """Within one grid step (and under a diagonal) the vertices merged are the axis neighbours a k-d tree finds."""
    from scipy.spatial import cKDTree

    from rooftrace.model.validity import _grid_neighbours

    rng = np.random.default_rng(1)
    for _ in range(100):
        keys = np.unique(rng.integers(0, rng.integers(2, 9), size=(rng.integers(1, 150), 3)), axis=0)
        span = keys.max(axis=0) + 1
        code = (keys[:, 0] * span[1] + keys[:, 1]) * span[2] + keys[:, 2]
        keys, code = keys[np.argsort(code)], np.sort(code)
        tree = cKDTree(keys * 1e-3).query_pairs(1e-3 * (1 + 1e-6), output_type="ndarray")
        assert {tuple(sorted(p)) for p in tree.tolist()} == {
            tuple(sorted(p)) for p in _grid_neighbours(keys, code, span).tolist()}


def test_a_vertex_one_step_from_another_is_merged_either_way():
    solid = _box()
    ring = solid.surfaces[0].rings[0]
    ring[1, :2] = ring[0, :2] + [0.001, 0.0]  # one grid step from its neighbour: merged, a repeated vertex
    assert any("consecutive duplicate" in e for e in solid_errors(solid))
    # a larger snap tolerance takes the k-d tree's way: the same finding
    assert any("consecutive duplicate" in e for e in solid_errors(solid, snap_tolerance=0.0015))


def test_part_extents_measure_as_overlapping_parts():
    from rooftrace.model import horizontal_plane
    from rooftrace.model.validity import PartExtent, overlapping_extents, overlapping_parts

    left = prism_solid([(shapely.box(0, 0, 5, 8), horizontal_plane(6.0))], 0.0)
    right = prism_solid([(shapely.box(5, 0, 10, 8), horizontal_plane(9.0))], 0.0)
    bent = prism_solid([(shapely.Polygon([(4.993, 4), (5, 0), (10, 0), (10, 8), (5, 8)]), horizontal_plane(9.0))], 0.0)
    for solids in ([left, right], [left, right, bent], [bent, left]):
        extents = [PartExtent.of(s) for s in solids]
        assert overlapping_extents(extents) == overlapping_parts(solids)
        assert overlapping_extents(extents) == overlapping_extents(extents)  # measured once, asked again
