"""The own validity checker: valid constructed solids pass, each kind of defect is named."""

from __future__ import annotations

import copy

import numpy as np
import pytest

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


def test_volume_is_translation_invariant():
    cells, volume = gable()
    solid = prism_solid(cells, 0.0)
    moved = Solid([Surface([r + [85000.0, 447000.0, 0.0] for r in s.rings], s.kind) for s in solid.surfaces])
    assert solid_volume(moved) == pytest.approx(volume, abs=1e-3)
