"""Points to footprints: the overhang band, shared walls, footprints without points (constructed truth)."""

from __future__ import annotations

import numpy as np
import pytest
import shapely

from rooftrace.cloud import ASPRS
from rooftrace.footprints import FootprintOptions, Footprints, assign_footprints, footprint_outlines

B, G, V = ASPRS.BUILDING, ASPRS.GROUND, ASPRS.HIGH_VEGETATION


def _grid(x0, x1, y0, y1, z, step=0.25):
    x, y = np.meshgrid(np.arange(x0 + step / 2, x1, step), np.arange(y0 + step / 2, y1, step))
    return np.column_stack([x.ravel(), y.ravel(), np.full(x.size, float(z))])


def _row():
    """Two houses sharing the wall x = 6 (footprints 0-6 and 6-12, y 0-10), roofs overhanging 0.6 m
    on the street sides and the row's ends, at 8 m and 11 m; a detached shed 3 m east without footprint
    (0.5 m beyond the band of house 2), ground around."""
    roof_a = _grid(-0.6, 6.0, -0.6, 10.6, 8.0)
    roof_b = _grid(6.0, 12.6, -0.6, 10.6, 11.0)
    shed = _grid(14.6, 18.0, 2.0, 6.0, 3.0)
    ground = _grid(-5, 25, -5, 15, 0.0, step=1.0)
    ground = ground[~shapely.contains_xy(shapely.box(-0.6, -0.6, 12.6, 10.6), ground[:, 0], ground[:, 1])
                    & ~shapely.contains_xy(shapely.box(14.6, 2, 18, 6), ground[:, 0], ground[:, 1])]
    xyz = np.vstack([roof_a, roof_b, shed, ground])
    cls = np.concatenate([np.full(len(roof_a) + len(roof_b) + len(shed), B), np.full(len(ground), G)]).astype(np.uint8)
    # the detection merged the row into one building (they touch), the shed is its own
    det = np.concatenate([np.full(len(roof_a) + len(roof_b), 1), np.full(len(shed), 2), np.zeros(len(ground))])
    truth = np.concatenate([np.full(len(roof_a), 1), np.full(len(roof_b), 2), np.zeros(len(shed) + len(ground))])
    return xyz, cls, det.astype(np.int32), truth.astype(np.int32)


FOOTPRINTS = Footprints((shapely.box(0, 0, 6, 10), shapely.box(6, 0, 12, 10), shapely.box(40, 40, 48, 48)),
                        ("NL.a", "NL.b", "NL.far"), "identificatie")


def test_a_row_detected_as_one_building_is_split_along_the_shared_wall_with_its_overhangs():
    xyz, cls, det, truth = _row()
    res = assign_footprints(xyz, cls, det, FOOTPRINTS, FootprintOptions(overhang=1.0, min_points=20))
    # every roof point of each house, overhang included, and nothing else (not the shed, not the ground)
    assert np.array_equal(res.building_id, truth)
    assert res.status == ["ok", "ok", "no_points"]
    assert res.n_overhang[0] > 0 and res.n_overhang[1] > 0 and res.n_overhang[2] == 0
    assert res.n_inside[0] == int(np.sum(shapely.contains_xy(FOOTPRINTS.polygons[0], *xyz[truth == 1, :2].T)))
    # a band wide enough to reach the shed still leaves it out: its detected building has nothing inside
    wide = assign_footprints(xyz, cls, det, FOOTPRINTS, FootprintOptions(overhang=4.0, min_points=20))
    assert np.array_equal(wide.building_id, truth)


def test_the_result_does_not_depend_on_the_order_of_the_points():
    xyz, cls, det, _ = _row()
    perm = np.random.default_rng(3).permutation(len(xyz))
    a = assign_footprints(xyz, cls, det, FOOTPRINTS, FootprintOptions(min_points=20))
    b = assign_footprints(xyz[perm], cls[perm], det[perm], FOOTPRINTS, FootprintOptions(min_points=20))
    assert np.array_equal(a.building_id[perm], b.building_id) and a.status == b.status


def test_footprints_without_usable_points_get_a_status_and_a_fallback():
    xyz, cls, det, _ = _row()
    # a garden footprint over ground only, one over a tree, one with a handful of roof points
    garden, tree = shapely.box(-4, 11, -1, 14), shapely.box(20, 8, 23, 11)
    tree_pts = _grid(20, 23, 8, 11, 4.5, step=0.5)
    few = _grid(20, 21, -4, -3, 3.2, step=0.5)
    xyz = np.vstack([xyz, tree_pts, few])
    cls = np.concatenate([cls, np.full(len(tree_pts), V), np.full(len(few), B)]).astype(np.uint8)
    det = np.concatenate([det, np.zeros(len(tree_pts)), np.full(len(few), 3)]).astype(np.int32)
    hag = np.where(cls == G, 0.0, xyz[:, 2])
    fps = Footprints(FOOTPRINTS.polygons + (garden, tree, shapely.box(20, -4, 21, -3)),
                     FOOTPRINTS.ids + ("garden", "tree", "few"))
    res = assign_footprints(xyz, cls, det, fps, FootprintOptions(min_points=20), hag=hag)
    assert res.status == ["ok", "ok", "no_points", "no_building_points", "few_points", "few_points"]
    assert "none of a building" in res.reason[3]
    # the tree footprint falls back on its high non-ground points, the small roof on its 4 building points
    assert len(res.fallback[4]) == len(tree_pts) and len(res.fallback[5]) == len(few)
    assert not np.isin(res.building_id, [3, 4, 5, 6]).any()  # nothing to outline for them
    outlines = footprint_outlines([], fps, res, xyz)
    assert [o.building_id for o in outlines] == [1, 2, 3, 4, 5, 6]
    assert outlines[2].polygon is None and outlines[2].status == "no_points"
    lod12 = outlines[4].polygon  # the footprint itself at the 70th percentile of the fallback heights
    assert shapely.equals_exact(shapely.force_2d(lod12).normalize(), tree.normalize(), 1e-9)
    assert np.allclose(shapely.get_coordinates(lod12, include_z=True)[:, 2], 4.5)


def test_unclassified_points_standing_in_a_built_footprint_join_its_building():
    xyz, cls, det, truth = _row()
    # a chimney the detection left unclassified on house 1, a low wall (1 m) and a tree's crown over house 2,
    # and an unclassified pole beyond the footprints (the street)
    chimney = _grid(2.0, 2.5, 4.0, 4.5, 9.2)
    low = _grid(7.0, 7.5, 1.0, 1.5, 1.0)
    crown = _grid(9.0, 10.0, 6.0, 7.0, 13.0)
    pole = _grid(-3.0, -2.75, 5.0, 5.25, 6.0)
    xyz = np.vstack([xyz, chimney, low, crown, pole])
    U = ASPRS.UNCLASSIFIED
    cls = np.concatenate([cls, np.full(len(chimney) + len(low), U), np.full(len(crown), V),
                          np.full(len(pole), U)]).astype(np.uint8)
    det = np.concatenate([det, np.zeros(len(xyz) - len(det))]).astype(np.int32)
    hag = np.where(cls == G, 0.0, xyz[:, 2])
    res = assign_footprints(xyz, cls, det, FOOTPRINTS, FootprintOptions(min_points=20), hag=hag)
    n = len(truth)
    assert np.array_equal(res.building_id[:n], truth)
    assert (res.building_id[n:n + len(chimney)] == 1).all()
    assert (res.building_id[n + len(chimney):] == 0).all()  # the low wall, the crown, the pole
    off = assign_footprints(xyz, cls, det, FOOTPRINTS, FootprintOptions(min_points=20, unclassified=False), hag=hag)
    assert (off.building_id[n:] == 0).all() and res.status == off.status


def test_unclassified_points_touching_a_roof_in_its_overhang_band_join_it_but_not_its_outline():
    """Clutter along house 1's eaves (0.5 m over its roof, outside the footprint, under the overhang) touches the
    roof's points: it joins house 1 as roof points, listed in ``touching`` (the outline is traced without them).
    A 3 m post in the same band touches nothing of the roof, and stays out."""
    xyz, cls, det, truth = _row()
    eaves = _grid(1.0, 3.0, 10.25, 10.5, 8.5)
    post = _grid(-1.0, -0.75, 5.0, 5.25, 3.0)
    xyz = np.vstack([xyz, eaves, post])
    cls = np.concatenate([cls, np.full(len(eaves) + len(post), ASPRS.UNCLASSIFIED)]).astype(np.uint8)
    det = np.concatenate([det, np.zeros(len(eaves) + len(post))]).astype(np.int32)
    hag = np.where(cls == G, 0.0, xyz[:, 2])
    res = assign_footprints(xyz, cls, det, FOOTPRINTS, FootprintOptions(min_points=20), hag=hag, density=16.0)
    n = len(truth)
    assert np.array_equal(res.building_id[:n], truth)
    assert (res.building_id[n:n + len(eaves)] == 1).all() and (res.building_id[n + len(eaves):] == 0).all()
    assert np.array_equal(res.touching, np.arange(n, n + len(eaves)))


def test_traced_outlines_are_clipped_off_the_neighbouring_footprint():
    from rooftrace.contour.outline import RoofOutline

    xyz, cls, det, _ = _row()
    res = assign_footprints(xyz, cls, det, FOOTPRINTS, FootprintOptions(min_points=20))
    # an outline of house a reaching 0.4 m over house b's footprint (a regularised corner, say)
    over = shapely.force_3d(shapely.box(-0.6, -0.6, 6.4, 10.6), 8.0)
    outlines = footprint_outlines([RoofOutline(1, over, n_points=10)], FOOTPRINTS, res, xyz)
    # the street-side overhangs split where the party wall meets the facade (Voronoi of 0.1 m samples)
    assert outlines[0].polygon.bounds == pytest.approx((-0.6, -0.6, 6.0, 10.6), abs=0.05)
    assert outlines[0].polygon.area == pytest.approx(6.6 * 11.2, abs=0.05)
    assert outlines[0].polygon.has_z and outlines[0].polygon.exterior.is_ccw


def test_bad_arguments():
    with pytest.raises(ValueError, match="overhang"):
        FootprintOptions(overhang=-1)
    with pytest.raises(ValueError, match="one value per point"):
        assign_footprints(np.zeros((3, 3)), np.zeros(2), np.zeros(3), FOOTPRINTS)
    with pytest.raises(TypeError, match="Polygons"):
        Footprints((shapely.Point(0, 0),), ("x",))


@pytest.mark.slow
def test_delft_bgt_footprints_take_their_roofs_and_split_the_rows():
    """Real data: AHN3 Delft with the provider's class 6 and the 160 BGT footprints (shared walls, overhangs)."""
    from rooftrace.contour.outline import connected_buildings, outline_buildings
    from rooftrace.io.footprints import read_footprints
    from rooftrace.io.points import read_points
    from tests.conftest import DELFT, need

    cloud = read_points([need(DELFT / "ahn3_cropped_1.laz")], crs="EPSG:7415")  # the west tile: 128 footprints
    fps = read_footprints(need(DELFT / "bgt_pand.sqlite"), cloud.crs)
    x0, y0, x1, y1 = shapely.total_bounds(np.asarray(fps.polygons, dtype=object)) + [-5, -5, 5, 5]
    cloud = cloud.subset((cloud.x >= x0) & (cloud.x <= x1) & (cloud.y >= y0) & (cloud.y <= y1))
    cls = cloud.fields["classification"].astype(np.uint8)
    building = cls == B
    det = np.zeros(len(cloud), np.int32)
    det[building] = connected_buildings(cloud.xyz[building, :2], 1.0)  # the rows come out as single buildings
    density = 10.0  # AHN3's nominal pts/m²
    res = assign_footprints(cloud.xyz, cls, det, fps, FootprintOptions(overhang=1.5), density=density)
    # nearly every footprint over the tile holds a roof; the others are small sheds (< 25 m²) with a fallback
    covered = int(np.sum(res.n_cloud > 0))
    assert covered >= 120 and res.status.count("ok") >= covered - 12
    assert all(fps.polygons[i].area < 25 or res.n_cloud[i] == 0 for i, s in enumerate(res.status) if s != "ok")
    # every assigned point lies within the band of its own footprint, and inside points go to their footprint
    bid = res.building_id
    sel = np.flatnonzero(bid > 0)
    d = shapely.distance(np.asarray(fps.polygons, dtype=object)[bid[sel] - 1], shapely.points(cloud.xyz[sel, :2]))
    assert d.max() <= 1.5 + 1e-9
    ok = np.array(res.status) == "ok"
    assert (d > 0).sum() == res.n_overhang[ok].sum() > 1000  # the overhangs (few_points ones keep no points)
    # detected buildings spanning several footprints are split along them: the terraced rows
    spans = [len(np.unique(bid[(det == b) & (bid > 0)])) for b in np.unique(det[det > 0])]
    assert max(spans) >= 10 and sum(s >= 2 for s in spans) >= 5

    # outlines of one row: each covers its footprint, overhangs it, and does not overlap its neighbours
    row = [i for i in range(len(fps)) if res.status[i] == "ok"
           and fps.polygons[i].intersects(shapely.box(84900, 447520, 84960, 447560))]
    keep = np.isin(bid, np.array(row) + 1)
    traced = outline_buildings(cloud.xyz, np.where(keep, bid, 0), mean_spacing=0.3)
    sub = assign_footprints(cloud.xyz[:0], cls[:0], det[:0], fps)  # statuses are not used for traced outlines
    sub.status, sub.fallback = list(res.status), list(res.fallback)
    outlines = {o.building_id: o for o in footprint_outlines(traced, fps, sub, cloud.xyz)}
    polys = [shapely.force_2d(outlines[i + 1].polygon) for i in row]
    assert len(polys) >= 5
    for i, poly in zip(row, polys):
        inside = shapely.contains_xy(fps.polygons[i], *cloud.xyz[bid == i + 1, :2].T).sum()
        if inside < 0.25 * density * fps.polygons[i].area:
            # a footprint its roof points cover at under a quarter of the cloud's density (a 22 m² shed with
            # 35 points): the triangle alpha shape outlines the points, not the footprint (known limit)
            continue
        assert poly.intersection(fps.polygons[i]).area / fps.polygons[i].area > 0.85
    overlap = sum(a.intersection(b).area for k, a in enumerate(polys) for b in polys[k + 1:])
    assert overlap < 0.01 * sum(p.area for p in polys)
