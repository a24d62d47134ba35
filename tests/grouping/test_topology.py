"""Roof topology: sides, ridges, junctions (vertex, ridge, T) and adjacency."""

from __future__ import annotations

import numpy as np
import pytest
from shapely import LineString, Polygon

from rooftrace.errors import GeometryError
from rooftrace.grouping.topology import roof_topology

RECT = Polygon([(0, 0, 3), (10, 0, 3), (10, 6, 3), (0, 6, 3)])


def test_gable_ridge_makes_t_junctions_on_the_gable_sides():
    topo = roof_topology(RECT, [LineString([(0.3, 3, 5), (9.8, 3.1, 5)])])
    assert topo.kinds == ("outline",) * 4 + ("ridge",)
    assert topo.ring_sizes == (4,) and topo.n_outline == 4
    vertex_junctions = [j for j in topo.junctions if j.vertex >= 0]
    assert [j.members for j in vertex_junctions] == [((3, 1), (0, 0)), ((0, 1), (1, 0)), ((1, 1), (2, 0)),
                                                     ((2, 1), (3, 0))]
    others = sorted(j.members for j in topo.junctions if j.vertex < 0)
    assert others == [((4, 0), (3, -1)), ((4, 1), (1, -1))]  # ridge ends on the west and east sides
    assert topo.pairs.tolist() == [[0, 1], [0, 3], [1, 2], [1, 4], [2, 3], [3, 4]]


def test_hip_roof_joins_hips_to_corners_and_to_the_ridge():
    ridge = [(3, 3, 6), (7, 3, 6)]
    hips = [LineString([(0, 0, 3), ridge[0]]), LineString([(0, 6, 3), ridge[0]]),
            LineString([(10.2, 0.1, 3), ridge[1]]), LineString([(10, 6, 3), (7.3, 3.2, 6)])]
    topo = roof_topology(RECT, [LineString(ridge)] + hips)
    assert topo.n_lines == 9
    corner = topo.junctions[0]  # (0, 0): two sides and a hip
    assert sorted(corner.members) == [(0, 0), (3, 1), (5, 0)]
    ridge_junctions = [j for j in topo.junctions if j.vertex < 0]
    assert len(ridge_junctions) == 2
    assert all(len(j.members) == 3 for j in ridge_junctions)  # ridge + two hips
    pairs = {tuple(p) for p in topo.pairs.tolist()}
    assert (4, 5) in pairs and (4, 7) in pairs and (5, 6) in pairs and (0, 5) in pairs


def test_holes_are_rings_and_free_ridge_ends_stay_free():
    poly = Polygon([(0, 0, 1), (20, 0, 1), (20, 20, 1), (0, 20, 1)], [[(5, 5, 1), (15, 5, 1), (15, 15, 1), (5, 15, 1)]])
    topo = roof_topology(poly, [LineString([(2, 2, 4), (2, 3, 4)]), LineString([(1, 1, 1), (1, 1, 2)])])
    assert topo.ring_sizes == (4, 4) and topo.n_outline == 8
    assert topo.ridge_index.tolist() == [8, -1]  # a vertical 'ridge' has no image line
    free = [j for j in topo.junctions if j.vertex < 0]
    assert len(free) == 2 and all(len(j.members) == 1 for j in free)
    # the hole's sides neighbour each other, not the exterior's
    assert {tuple(p) for p in topo.pairs.tolist()} == {(0, 1), (1, 2), (2, 3), (0, 3), (4, 5), (5, 6), (6, 7), (4, 7)}


def test_duplicate_and_closing_vertices_are_dropped():
    poly = Polygon([(0, 0, 3), (10, 0, 3), (10, 0, 3), (10, 6, 3), (0, 6, 3), (0, 0, 3)])
    topo = roof_topology(poly)
    assert topo.ring_sizes == (4,)
    np.testing.assert_allclose(topo.lines[0], [[0, 0, 3], [10, 0, 3]])


def test_degenerate_outline_is_a_geometry_error():
    with pytest.raises(GeometryError, match="3 distinct"):
        roof_topology(Polygon([(0, 0), (1, 0), (1, 0), (0, 0)]))
    with pytest.raises(GeometryError, match="Polygon"):
        roof_topology(None)
