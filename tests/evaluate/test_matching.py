"""Matching rules on layouts whose answer is known by construction."""

from __future__ import annotations

import numpy as np
import pytest
from shapely import Polygon, box

from rooftrace.evaluate.matching import coverage, match_buildings, overlaps


def test_terraced_houses_merged_and_one_to_one():
    ext = [box(0, 0, 30, 10)]
    ref = [box(0, 0, 10, 10), box(10, 0, 20, 10), box(20, 0, 30, 10)]
    m = match_buildings(ext, ref)
    assert m.rule == "merged-blocks" and m.units == [((0,), (0, 1, 2))]
    assert "50%" in m.description
    m = match_buildings(ext, ref, merge_blocks=False)
    assert m.rule == "one-to-one"
    assert len(m.matched) == 1 and sorted(u[1] for u in m.units) == [(0,), (1,), (2,)]


def test_small_overlap_does_not_match():
    m = match_buildings([box(0, 0, 10, 10)], [box(9, 0, 19, 10)])  # 10 % overlap
    assert m.matched == [] and m.units == [((), (0,)), ((0,), ())]
    m = match_buildings([box(0, 0, 10, 10)], [box(9, 0, 19, 10)], min_overlap=0.1)
    assert m.units == [((0,), (0,))]


def test_touching_is_no_overlap():
    pairs, inter = overlaps([box(0, 0, 1, 1)], [box(1, 0, 2, 1)])
    assert len(pairs) == 0 and len(inter) == 0


def test_hungarian_beats_greedy():
    ref = [box(0, 0, 10, 10), box(10, 0, 20, 10)]
    ext = [box(3.5, 0, 15, 10), box(0, 0, 3.5, 10)]
    # greedy largest-first would pair ext 0 with ref 0 (65 m²) and leave the rest: 65 m² in all;
    # the assignment pairs ext 0-ref 1 (50) and ext 1-ref 0 (35): 85 m²
    m = match_buildings(ext, ref, merge_blocks=False)
    assert m.units == [((1,), (0,)), ((0,), (1,))]
    assert match_buildings(ext, ref).units == [((0, 1), (0, 1))]


def test_coverage_counts_overlapping_others_once():
    ref = [box(0, 0, 10, 10)]
    ext = [box(0, 0, 6, 10), box(2, 0, 6, 10), box(50, 50, 51, 51)]
    pairs, inter = overlaps(ext, ref)
    assert coverage(ref, ext, pairs, inter, side=1) == pytest.approx([0.6])
    np.testing.assert_allclose(coverage(ext, ref, pairs, inter, side=0), [1.0, 1.0, 0.0])


def test_empty_and_bad_arguments():
    assert match_buildings([], []).units == []
    units = match_buildings([None, box(0, 0, 1, 1), Polygon()], [box(0, 0, 1, 1), None]).units
    assert units == [((1,), (0,)), ((), (1,)), ((0,), ()), ((2,), ())]
    assert match_buildings([box(0, 0, 1, 1)], []).units == [((0,), ())]
    with pytest.raises(ValueError, match="min_overlap"):
        match_buildings([], [], min_overlap=0)
    with pytest.raises(TypeError, match="min_overlap"):
        match_buildings([], [], min_overlap="half")
