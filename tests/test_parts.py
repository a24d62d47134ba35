"""Building parts: terraced rows split at height steps and party gutters, against exact truth."""

from __future__ import annotations

import numpy as np
import pytest
import shapely

from rooftrace.parts import PartOptions, parts_layer, split_parts
from rooftrace.roof import roof_structure
from rooftrace.synth.buildings import Building


def _sample(buildings, density=12.0, noise=0.03, seed=0):
    """Roof points of touching synthetic houses, with the house each point's roof belongs to."""
    outline = shapely.union_all([b.roof_outline for b in buildings], grid_size=1e-6)  # rotated rows: exact seams
    rng = np.random.default_rng(seed)
    minx, miny, maxx, maxy = outline.bounds
    xy = rng.uniform([minx, miny], [maxx, maxy], (int(outline.envelope.area * density), 2))
    xy = xy[shapely.contains_xy(outline, xy[:, 0], xy[:, 1])]
    hs = np.stack([b.height(xy[:, 0], xy[:, 1]) for b in buildings])
    hs = np.where(np.isnan(hs), -np.inf, hs)
    truth = np.argmax(hs, axis=0) + 1
    xyz = np.column_stack([xy, hs.max(axis=0) + rng.normal(0, noise, len(xy))])
    return xyz, outline, truth


def _split(buildings, **kw):
    xyz, outline, truth = _sample(buildings, **kw)
    roof = roof_structure(xyz, outline)
    parts = split_parts(xyz, outline, roof.faces, roof.face_plane, roof.planes)
    return xyz, outline, truth, parts


def _check_partition(parts, outline):
    union = shapely.union_all(parts.polygons)
    assert union.symmetric_difference(outline).area < 1e-6 * outline.area
    assert sum(p.area for p in parts.polygons) == pytest.approx(outline.area, rel=1e-6)  # no overlaps


def _purity(part_id, truth):
    """Per part, the share of its points on the roof of its main house; and that house."""
    out = []
    for k in np.unique(part_id):
        counts = np.bincount(truth[part_id == k])
        out.append((int(np.argmax(counts)), counts.max() / counts.sum()))
    return out


def test_a_row_with_height_steps_splits_at_the_steps_and_only_there():
    # the simulator's default row: houses 1 and 2 identical (no boundary in the data), 3 higher, 4 lower
    row = Building.terrace(1, (100.0, 200.0), [5.0, 5.0, 5.5, 4.5], 9.0, angle_deg=20.0,
                           eave_heights=[6.0, 6.0, 6.6, 5.6], ridge_heights=[9.8, 9.8, 10.6, 9.2], overhang=0.4)
    xyz, outline, truth, parts = _split(row)
    _check_partition(parts, outline)
    assert parts.n_parts == 3 and parts.boundaries == ["step"]
    merged = truth.copy()
    merged[merged == 2] = 1  # the two identical houses are one part: truth that the data can show
    purity = _purity(parts.part_id, merged)
    assert sorted(h for h, _ in purity) == [1, 3, 4]
    assert min(p for _, p in purity) > 0.97
    # each part polygon covers its houses' roofs: area within 3 % of the truth
    want = {1: row[0].roof_outline.union(row[1].roof_outline).area, 3: row[2].roof_outline.area,
            4: row[3].roof_outline.area}
    for (house, _), poly in zip(purity, parts.polygons):
        assert poly.area == pytest.approx(want[house], rel=0.03)


def test_gables_across_a_row_split_at_the_gutters():
    # three houses at one height whose ridges run across the row: the gutters are the party walls
    row = [Building.rectangle(i + 1, (6.0 * i, 0.0), 10.0, 6.0, angle_deg=90.0, kind="gable", eave_height=6.0,
                              ridge_height=9.0, overhang_sides=(0.4, 0.4, 0.0 if i else 0.4, 0.0 if i < 2 else 0.4))
           for i in range(3)]
    xyz, outline, truth, parts = _split(row)
    _check_partition(parts, outline)
    assert parts.n_parts == 3 and parts.boundaries == ["gutter"]
    purity = _purity(parts.part_id, truth)
    assert [h for h, _ in purity] == [1, 2, 3] and min(p for _, p in purity) > 0.95


def test_one_house_stays_one_part():
    # an L-shaped hip roof (valleys at 90 deg), a gable with dormers: boundaries inside one house
    for b in (Building.l_shape(1, (0.0, 0.0), 18.0, 8.0, 6.0, kind="hip", eave_height=6.0, ridge_height=9.2),
              Building.rectangle(1, (0.0, 0.0), 15.0, 9.0, kind="gable", eave_height=6.0,
                                 ridge_height=10.0).with_dormers([-3.2, 3.2])):
        xyz, outline, _, parts = _split([b])
        assert parts.n_parts == 1 and np.all(parts.part_id == 1)
        assert parts.polygons[0].equals_exact(outline.normalize(), 1e-6) or \
            parts.polygons[0].symmetric_difference(outline).area < 1e-6


def test_a_chimney_on_the_party_wall_neither_joins_nor_splits_the_houses():
    # two flat roofs 1 m apart (a step); a chimney top halfway up on their shared wall is within the step
    # height of both, so as a face like any other it joins the two houses into one part
    low, high, chimney = shapely.box(0, 0, 6, 10), shapely.box(6, 0, 12, 10), shapely.box(5.5, 4.5, 6.5, 5.5)
    faces = [low.difference(chimney), high.difference(chimney), chimney]
    planes = np.array([[0, 0, 1.0, -6.0], [0, 0, 1.0, -7.0], [0, 0, 1.0, -6.5]])
    xyz = np.array([[3.0, 5.0, 6.0], [9.0, 5.0, 7.0], [6.0, 5.0, 6.5]])
    outline = shapely.box(0, 0, 12, 10)
    assert split_parts(xyz, outline, faces, [0, 1, 2], planes).n_parts == 1
    parts = split_parts(xyz, outline, faces, [0, 1, 2], planes, plane_detail=np.array([False, False, True]))
    assert parts.n_parts == 2 and parts.boundaries == ["step"]
    assert sorted(p.area for p in parts.polygons) == pytest.approx([59.5, 60.5])  # the chimney went with one
    assert parts.part_id[:2].tolist() == [1, 2]


def test_a_sliver_face_where_a_plane_crosses_its_neighbour_joins_nothing():
    # house A's plane (z = 3 + x / 2) steps 1 m below house B's (z = 7) at their wall x = 6, but crosses it at
    # x = 8, where a 0.1 m² sliver of A's plane sits inside B: as a face of plane A like any other, it joined A and B
    a, b = np.array([-0.5, 0, 1.0, -3.0]), np.array([0, 0, 1.0, -7.0])
    norm = np.hypot(0.5, 1.0)
    planes = np.array([a / norm, b])
    sliver = shapely.box(7.9, 0, 8.1, 0.5)
    faces = [shapely.box(0, 0, 6, 10), shapely.box(6, 0, 12, 10).difference(sliver), sliver]
    xyz = np.array([[3.0, 5.0, 4.5], [9.0, 5.0, 7.0]])
    parts = split_parts(xyz, shapely.box(0, 0, 12, 10), faces, [0, 1, 0], planes)
    assert parts.n_parts == 2 and parts.boundaries == ["step"]
    assert sorted(p.area for p in parts.polygons) == pytest.approx([60.0, 60.0])  # the sliver went with B


def test_no_faces_is_one_part_and_the_split_does_not_depend_on_point_order():
    row = Building.terrace(1, (0.0, 0.0), [6.0, 6.0], 9.0, eave_heights=[6.0, 7.5], ridge_heights=[9.0, 10.5])
    xyz, outline, truth = _sample(row)
    one = split_parts(xyz, outline, [], [], np.zeros((0, 4)))
    assert one.n_parts == 1 and one.boundaries == []
    roof = roof_structure(xyz, outline)
    a = split_parts(xyz, outline, roof.faces, roof.face_plane, roof.planes)
    perm = np.random.default_rng(1).permutation(len(xyz))
    b = split_parts(xyz[perm], outline, roof.faces, roof.face_plane, roof.planes)
    assert np.array_equal(a.part_id[perm], b.part_id)
    layer = parts_layer([a], {0: xyz[:, 2]})
    assert list(layer.attributes["part_id"]) == [1, 2] and layer.geometries[0].has_z
    assert layer.attributes["z_max"][1] > layer.attributes["z_max"][0] + 1.0  # part 2 is the higher house


def test_bad_options():
    with pytest.raises(ValueError, match="gutter_angle"):
        PartOptions(gutter_angle=45.0)
    with pytest.raises(ValueError, match="min_area"):
        PartOptions(min_area=-1.0)


def test_unions_of_runs_are_union_all_of_each_run():
    from rooftrace.parts import _union_each

    rng = np.random.default_rng(3)
    boxes = np.array([shapely.box(x, y, x + w, y + 1.0) for x, y, w in rng.uniform(0, 5, (40, 3))], dtype=object)
    group = np.sort(rng.integers(0, 12, 40))
    runs = [shapely.union_all(list(boxes[group == g])) for g in np.unique(group)]
    assert [shapely.to_wkb(g) for g in _union_each(boxes, group)] == [shapely.to_wkb(g) for g in runs]
