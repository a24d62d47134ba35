"""The outline invariant: an outline covers its building's points (rooftrace.contour.coverage)."""

from __future__ import annotations

import logging

import numpy as np
import pytest
import shapely

from rooftrace.contour.alpha_shape import AlphaOptions
from rooftrace.contour.coverage import MIN_COVERAGE, outline_coverage
from rooftrace.contour.outline import OutlineOptions, _alpha_shape, outline_buildings, outlines_layer, trace_outline
from tests.contour.shapes import COURTYARD, courtyard_blocks, sample, sample_random


def test_outline_coverage_counts_holes_as_outside_and_takes_per_point_tolerances():
    xy = np.array([[2.0, 2.0], [9.0, 8.0], [20.2, 8.0], [21.0, 8.0]])  # roof, courtyard (3 m in), just out, far out
    assert outline_coverage(COURTYARD, xy) == 0.25
    assert outline_coverage(COURTYARD, xy, 0.5) == 0.5
    assert outline_coverage(COURTYARD, xy, np.array([0.0, 3.5, 0.5, 0.5])) == 0.75
    assert outline_coverage(shapely.force_3d(COURTYARD, 4.0), np.column_stack([xy, np.ones(4)]), 0.5) == 0.5
    assert outline_coverage(None, xy) == 0.0 and outline_coverage(COURTYARD, np.empty((0, 2))) == 1.0
    on_edge = np.array([[0.0, 3.0], [20.0, 16.0]])
    assert outline_coverage(COURTYARD, on_edge) == 1.0


def test_per_edge_alpha_silently_loses_a_courtyard_block():
    # the failure at the former default (edge test, alpha x 1.25): 9 800 points of an 80 m
    # block around a courtyard, irregularly sampled at 3 pts/m².  The thesis' edge test with per-edge
    # alphas breaks the outer boundary, the gap repair deletes it, a sliver is left, nothing looks wrong
    xyz = sample_random(courtyard_blocks(1, 80.0), 3.0, seed=2)
    shape, status = _alpha_shape(xyz, AlphaOptions(boundary="edge", scale=1.25), None)
    rings = [xyz[r, :2] for r in shape.rings]
    assert status == "ok" and outline_coverage(shapely.Polygon(rings[0], rings[1:]), xyz, 1.0) < 0.01
    # the union of triangles judged with one alpha each cannot open: the whole block, courtyard as a hole
    out = trace_outline(xyz)
    assert out.status == "ok" and out.alpha_strategy == "point"
    assert out.coverage >= MIN_COVERAGE and outline_coverage(out.polygon, xyz, out.alpha) >= MIN_COVERAGE
    courtyard = max(shapely.Polygon(r).area for r in out.polygon.interiors)
    assert courtyard == pytest.approx(56**2, rel=0.03) and out.area == pytest.approx(80**2 - 56**2, rel=0.1)


def test_a_strategy_that_loses_points_falls_back_and_says_so(caplog):
    xyz = sample_random(courtyard_blocks(1, 80.0), 3.0, seed=2)
    options = OutlineOptions.from_config({}, boundary="edge", scale=1.25)
    with caplog.at_level(logging.WARNING, logger="rooftrace.contour.outline"):
        (out,) = outline_buildings(xyz, np.ones(len(xyz), int), options)
    assert out.status == "alpha_fallback" and out.alpha_strategy == "building"
    assert out.coverage >= MIN_COVERAGE and out.area == pytest.approx(80**2 - 56**2, rel=0.1)
    assert "alpha_fallback" in caplog.text and "does not hold 99 %" in caplog.text
    layer = outlines_layer([out])
    assert layer.attributes["coverage"] == [out.coverage] and layer.attributes["status"] == ["alpha_fallback"]


def test_points_no_strategy_can_cover_give_low_coverage_not_ok():
    # a roof and, 30 m away, a cluster of 5 % of the points: no single polygon holds both
    roof = sample(shapely.box(0, 0, 20, 12), 10.0, seed=1)
    far = sample(shapely.box(50, 0, 54, 3), 10.0, seed=2)
    out = trace_outline(np.vstack([roof, far]))
    assert out.coverage < MIN_COVERAGE and out.status in ("multipart", "low_coverage")
    assert out.status != "ok"


def test_regularisation_that_cuts_points_off_keeps_the_alpha_shape(monkeypatch):
    # a regulariser that cuts a wing off: the alpha-shape rings are kept instead
    import rooftrace.contour.outline as outline

    def cut(xyz, spacing, options, **kw):
        keep = xyz[:, 0] < 10.0
        return xyz[keep], np.arange(keep.sum()), [1] * int(keep.sum()), 0.0

    monkeypatch.setattr(outline, "_ring_outline", cut)
    xyz = sample(shapely.box(0, 0, 20, 12), 10.0, seed=1)
    out = trace_outline(xyz)
    assert out.status == "unregularised" and out.coverage >= MIN_COVERAGE
    assert out.area == pytest.approx(240, rel=0.05)
