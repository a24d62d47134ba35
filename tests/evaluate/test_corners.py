"""Corners of outlines (what counts as one), their matching, and the corner scores."""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely
from shapely import MultiPolygon, Point, Polygon, box
from shapely.affinity import rotate, translate

from rooftrace.evaluate import evaluate
from rooftrace.evaluate.corners import match_corners, outline_corners
from rooftrace.evaluate.metrics import corner_metrics

ELL = Polygon([(0, 0), (10, 0), (10, 4), (6, 4), (6, 8), (0, 8)])


def _as_set(xy):
    return {(round(x, 6), round(y, 6)) for x, y in xy}


def test_corners_of_straight_walled_shapes():
    assert _as_set(outline_corners(box(0, 0, 10, 5))) == {(0, 0), (10, 0), (10, 5), (0, 5)}
    assert _as_set(outline_corners(ELL)) == {(0, 0), (10, 0), (10, 4), (6, 4), (6, 8), (0, 8)}
    # a triangle, a rotated rectangle, a courtyard (hole corners count too)
    assert len(outline_corners(Polygon([(0, 0), (8, 0), (3, 6)]))) == 3
    assert len(outline_corners(rotate(box(0, 0, 10, 5), 33, origin=(0, 0)))) == 4
    assert len(outline_corners(box(0, 0, 20, 20).difference(box(5, 5, 15, 15)))) == 8
    assert len(outline_corners(MultiPolygon([translate(box(0, 0, 4, 4), -10, 0), ELL, box(20, 0, 24, 4)]))) == 4 + 6 + 4


def test_collinear_vertices_within_2_cm_are_no_corners():
    # vertices every 0.3 m along every wall, and a ring starting mid-wall
    dense = shapely.segmentize(box(0, 0, 10, 5), 0.3)
    assert _as_set(outline_corners(dense)) == {(0, 0), (10, 0), (10, 5), (0, 5)}
    mid_wall = Polygon([(5, 0), (10, 0), (10, 5), (0, 5), (0, 0)])
    assert len(outline_corners(mid_wall)) == 4
    # a vertex 1.5 cm off a wall is none, 3 cm off a 10 m wall is a (small) turn: a corner
    assert len(outline_corners(Polygon([(0, 0), (5, 0.015), (10, 0), (10, 5), (0, 5)]))) == 4
    assert len(outline_corners(Polygon([(0, 0), (5, 0.03), (10, 0), (10, 5), (0, 5)]))) == 5
    # a wall that zig-zags by 5 cm has a corner at every zig
    zig = [(x, 0.05 * (i % 2)) for i, x in enumerate(np.arange(0.0, 10.01, 1.0))]
    assert len(outline_corners(Polygon(zig + [(10, 5), (0, 5)]))) == 9 + 4
    # the collinear tolerance is a parameter
    assert len(outline_corners(Polygon([(0, 0), (5, 0.03), (10, 0), (10, 5), (0, 5)]), collinear_tolerance=0.05)) == 4


@pytest.mark.parametrize("quad_segs", [4, 8, 16, 64])
def test_a_circle_has_no_corner(quad_segs):
    assert len(outline_corners(Point(3, 4).buffer(5, quad_segs=quad_segs))) == 0


def test_a_polygon_of_sharp_turns_is_no_curve():
    # an octagon and a 12-gon turn 45° and 30° at each vertex: corners, not a curve
    assert len(outline_corners(Point(0, 0).buffer(5, quad_segs=2))) == 8
    assert len(outline_corners(Point(0, 0).buffer(5, quad_segs=3))) == 12
    # two gentle turns of one sense are two corners; three are a curve
    two = Polygon([(0, 0), (10, 0), (20, 2), (30, 6), (30, 20), (0, 20)])
    assert len(outline_corners(two)) == 6
    three = Polygon([(0, 0), (10, 0), (20, 2), (30, 6), (38, 12), (38, 20), (0, 20)])
    assert _as_set(outline_corners(three)) == {(0, 0), (38, 12), (38, 20), (0, 20)}


def test_a_curved_bay_has_corners_only_where_it_meets_the_wall():
    bay = box(0, 0, 10, 6).union(Point(5, 6).buffer(2, quad_segs=32))
    assert _as_set(outline_corners(bay)) == {(0, 0), (10, 0), (10, 6), (0, 6), (3, 6), (7, 6)}


def test_vertical_step_is_one_corner_in_plan():
    step = Polygon([(0, 0, 3), (4, 0, 3), (4, 0, 8), (10, 0, 8), (10, 5, 8), (4, 5, 8), (4, 5, 3), (0, 5, 3)])
    assert len(outline_corners(step)) == 4
    assert len(outline_corners(None)) == 0 and len(outline_corners(Polygon())) == 0


def test_corner_parameters_are_checked():
    with pytest.raises(ValueError):
        outline_corners(box(0, 0, 1, 1), collinear_tolerance=-1)
    with pytest.raises(ValueError):
        outline_corners(box(0, 0, 1, 1), curve_turn=180)
    with pytest.raises(ValueError):
        corner_metrics(box(0, 0, 1, 1), box(0, 0, 1, 1), tolerance=0)
    with pytest.raises(TypeError):
        corner_metrics(box(0, 0, 1, 1), box(0, 0, 1, 1), tolerance="0.5")


def test_matching_is_one_to_one_and_maximal():
    ref = np.array([[0.0, 0.0], [0.6, 0.0]])
    # nearest-first would pair (0.35, B) and leave the second extracted corner alone
    ext = np.array([[0.35, 0.0], [0.95, 0.0]])
    pairs, dist = match_corners(ext, ref, 0.5)
    assert pairs.tolist() == [[0, 0], [1, 1]] and dist == pytest.approx([0.35, 0.35])
    # two extracted corners by one reference corner: one pair, the nearer one
    pairs, dist = match_corners(np.array([[0.2, 0.0], [0.1, 0.0]]), ref[:1], 0.5)
    assert pairs.tolist() == [[1, 0]] and dist == pytest.approx([0.1])
    assert len(match_corners(ext, ref + 10, 0.5)[0]) == 0
    assert len(match_corners(np.empty((0, 2)), ref, 0.5)[0]) == 0


def test_corner_metrics_on_exact_shapes():
    c = corner_metrics(translate(box(0, 0, 10, 8), 0.3, 0.0), box(0, 0, 10, 8))
    assert (c["n_corners"], c["n_corners_reference"], c["n_corners_matched"]) == (4, 4, 4)
    assert c["corner_ratio"] == 1.0 and c["corner_completeness"] == 1.0 and c["corner_correctness"] == 1.0
    assert c["corner_offset"] == pytest.approx(0.3)
    # beyond the tolerance nothing matches; a wider tolerance matches again
    far = corner_metrics(translate(box(0, 0, 10, 8), 0.6, 0.0), box(0, 0, 10, 8))
    assert far["corner_completeness"] == 0.0 and math.isnan(far["corner_offset"])
    assert corner_metrics(translate(box(0, 0, 10, 8), 0.6, 0.0), box(0, 0, 10, 8), 1.0)["corner_completeness"] == 1.0
    # a rectangle against an L: 3 of 6 reference corners found, 3 of 4 extracted correct
    c = corner_metrics(box(0, 0, 10, 8), ELL)
    assert c["corner_ratio"] == pytest.approx(4 / 6)
    assert (c["corner_completeness"], c["corner_correctness"], c["corner_offset"]) == (0.5, 0.75, 0.0)
    # a noisy outline: twice the corners, all reference corners found
    noisy = Polygon([(0, 0), (5, 0.1), (10, 0), (10.1, 4), (10, 8), (5, 7.9), (0, 8), (-0.1, 4)])
    c = corner_metrics(noisy, box(0, 0, 10, 8))
    assert (c["n_corners"], c["corner_ratio"], c["corner_completeness"], c["corner_correctness"]) == (8, 2.0, 1.0, 0.5)
    # a circle against a circle: no corners, the ratio is undefined
    c = corner_metrics(Point(0, 0).buffer(5), Point(0, 0).buffer(5, quad_segs=4))
    assert c["n_corners_reference"] == 0 and math.isnan(c["corner_ratio"]) and math.isnan(c["corner_completeness"])
    assert corner_metrics(None, box(0, 0, 1, 1))["corner_completeness"] == 0.0


def test_scene_corner_scores():
    ref = [box(0, 0, 10, 8), box(20, 0, 30, 8), box(40, 0, 50, 8)]
    noisy = Polygon([(20, 0), (25, 0.1), (30, 0), (30.1, 4), (30, 8), (25, 7.9), (20, 8), (19.9, 4)])  # 2×
    three = Polygon([(40, 0), (50, 0), (50, 8)])  # 0.75×, two corners match
    m = evaluate([translate(ref[0], 0.2, 0), noisy, three], ref)
    assert [b["corner_ratio"] for b in m["buildings"]] == [1.0, 2.0, 0.75]
    assert m["corner_ratio_median"] == 1.0
    assert m["corner_ratio_within_1_5"] == pytest.approx(2 / 3)
    assert (m["n_corners"], m["n_corners_reference"], m["n_corners_matched"]) == (15, 12, 11)
    assert m["corner_completeness"] == pytest.approx(11 / 12) and m["corner_correctness"] == pytest.approx(11 / 15)
    assert m["corner_offset_mean"] == pytest.approx(4 * 0.2 / 11)
    assert m["corner_tolerance"] == 0.5
    with pytest.raises(ValueError):
        evaluate(ref, ref, corner_tolerance=0)


def test_merged_block_counts_the_corners_of_the_block():
    # three terraced houses in the reference, one block extracted: the walls between them are no corners
    ref = [box(0, 0, 6, 10), box(6, 0, 12, 10), box(12, 0, 18, 10)]
    m = evaluate([box(0, 0, 18, 10)], ref)
    (unit,) = m["buildings"]
    assert unit["n_corners_reference"] == 4 and unit["corner_ratio"] == 1.0 and unit["corner_completeness"] == 1.0
