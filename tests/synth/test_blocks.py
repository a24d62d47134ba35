"""City-block scenes (``--scene blocks``) and the outline invariant on them."""

from __future__ import annotations

import numpy as np
import pytest
import shapely

from rooftrace.contour.alpha_shape import AlphaOptions
from rooftrace.contour.coverage import MIN_COVERAGE, outline_coverage
from rooftrace.contour.outline import connected_buildings, outline_buildings
from rooftrace.contour.spacing import building_mean_spacing as mean_spacing
from rooftrace.synth import SceneOptions, simulate_scene
from rooftrace.synth.blocks import BLOCK_SIZES, block_buildings


@pytest.fixture(scope="module")
def blocks():
    """150 m of city blocks at 3 pts/m² (AHN3-like), single returns on the roofs; building points and ids."""
    scene = simulate_scene(SceneOptions(scene="blocks", size=150.0, density=3.0, seed=1, image=False))
    sel = scene.cloud.fields["truth_class"] == 6
    xyz = scene.cloud.xyz[sel]
    return scene, xyz, scene.cloud.fields["truth_building_id"][sel], mean_spacing(xyz[:, :2])


def test_block_layout_is_terraced_courtyard_blocks_joined_by_low_garages():
    houses = block_buildings(4, 400.0)
    terraces = [b for b in houses if b.kind == "terrace"]
    low = [b for b in houses if b.kind in ("shed", "garage")]
    assert len(terraces) > 100 and all(b.eave_height <= 3.0 for b in low)
    # the blocks: union of the terraced houses, each with one courtyard, 60-280 m across
    blocks = list(shapely.get_parts(shapely.union_all([b.footprint for b in terraces]).buffer(0.01)))
    assert len(blocks) >= 2
    for block in blocks:
        w, h = np.ptp(np.asarray(block.exterior.coords), axis=0)
        assert BLOCK_SIZES[0] - 0.1 <= min(w, h) and max(w, h) <= BLOCK_SIZES[1] + 0.1
        assert len(block.interiors) == 1
    # with the sheds and garages the whole scene is one piece
    everything = shapely.union_all([b.footprint for b in houses]).buffer(0.01)
    assert everything.geom_type == "Polygon"
    assert [b.building_id for b in houses] == list(range(1, len(houses) + 1))
    assert block_buildings(4, 400.0)[7].footprint.equals(houses[7].footprint)  # seeded


def test_block_scene_truth_and_default_scene_unchanged(blocks):
    scene = blocks[0]
    assert scene.options.scene == "blocks"
    kinds = set(scene.truth["roof_outlines"].attributes["kind"])
    assert kinds == {"terrace", "shed", "garage"}
    assert len(scene.trees) > 0
    # the default scene does not see the new option
    assert SceneOptions().scene == "default"
    with pytest.raises(Exception, match="scene"):
        SceneOptions(scene="downtown")


def test_blocks_are_one_cloud_and_every_outline_covers_its_points(blocks):
    _, xyz, truth_id, spacing = blocks
    merged = connected_buildings(xyz[:, :2], 2.0 * spacing, min_points=10)
    assert np.bincount(merged)[1:].max() > 0.9 * len(xyz)  # the blocks touch through the low buildings
    for ids in (merged, truth_id):
        outlines = outline_buildings(xyz, ids, mean_spacing=spacing)
        for o in outlines:
            pts = xyz[ids == o.building_id]
            assert o.polygon is not None, o.status
            assert outline_coverage(o.polygon, pts, o.alpha) >= MIN_COVERAGE, (o.building_id, o.status, o.coverage)
            assert o.coverage >= MIN_COVERAGE and o.status != "low_coverage"


def test_thesis_edge_test_loses_the_joined_blocks_the_triangle_union_keeps_them(blocks):
    # the failure behind "whole blocks vanish": per-edge alphas (S3) judge a triangle with three
    # alphas, the outer boundary breaks, and the gap repair deletes the open chain: all of it,
    # at every alpha of the retries (the thesis' alpha x 1 here; AHN's irregular sampling at x 1.25)
    from rooftrace.contour.outline import _alpha_shape

    _, xyz, _, spacing = blocks
    ids = connected_buildings(xyz[:, :2], 2.0 * spacing, min_points=10)
    pts = np.unique(xyz[ids == np.argmax(np.bincount(ids)[1:]) + 1], axis=0)
    cover, status = {}, {}
    for boundary in ("edge", "triangle"):
        shape, status[boundary] = _alpha_shape(pts, AlphaOptions(scale=1.0, boundary=boundary), spacing)
        rings = [pts[r, :2] for r in shape.rings]
        cover[boundary] = outline_coverage(shapely.Polygon(rings[0], rings[1:]), pts, shape.spacing * shape.scale)
    assert cover["edge"] < 0.05
    assert cover["triangle"] >= MIN_COVERAGE
