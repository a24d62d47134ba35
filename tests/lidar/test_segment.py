import numpy as np
import pytest

from rooftrace.lidar.segment import (
    SegmentOptions,
    link_pairs,
    merge_touching,
    order_labels,
    region_growing,
    sector_pairs,
)


def _roof(x0, y0, w, d, z, step=0.4, slope=0.0):
    g = np.stack(np.meshgrid(np.arange(x0, x0 + w, step), np.arange(y0, y0 + d, step)), -1).reshape(-1, 2)
    return np.column_stack([g, z + slope * (g[:, 1] - y0)])


def test_two_roof_levels_of_one_building_are_two_clusters_and_one_building():
    low = _roof(0, 0, 10, 6, 5.0)
    high = _roof(0, 6, 10, 6, 9.0)  # touches the low roof in plan, 4 m higher
    far = _roof(30, 0, 5, 5, 5.0)
    xyz = np.vstack([low, high, far])
    pairs = link_pairs(xyz[:, :2], 0.8)
    levels = region_growing(xyz, 0.8, 0.2, 0.0, pairs=pairs)
    assert len(np.unique(levels)) == 3
    for part in (slice(0, len(low)), slice(len(low), len(low) + len(high)), slice(len(low) + len(high), None)):
        assert len(np.unique(levels[part])) == 1
    group = merge_touching(levels, pairs, np.ones(3, bool))
    assert group[levels[0]] == group[levels[len(low)]] != group[levels[-1]]


def test_pitched_roof_stays_whole_with_normals_but_not_with_the_thesis_test():
    roof = _roof(0, 0, 10, 8, 5.0, step=0.4, slope=1.0)  # 45 degrees
    normals = np.tile([0.0, -1.0, 1.0], (len(roof), 1)) / np.sqrt(2)
    assert len(np.unique(region_growing(roof, 0.8, 0.1, normals=normals))) == 1
    assert len(np.unique(region_growing(roof, 0.8, 0.1, 0.0))) > 1  # |dz| < L_Dh alone shatters it
    assert len(np.unique(region_growing(roof, 0.8, 0.1, 50.0))) == 1


def test_normal_angle_keeps_a_hedge_out_of_the_roof_it_touches(rng):
    # a flat roof at 3 m and, touching it, a flat-topped hedge at the same
    # height whose normals scatter (leaves face every way, tilted 50-80 deg);
    # its points pass the distance-along-normal test of close pairs, so
    # without the angle test the hedge chains into the roof
    roof = _roof(0, 0, 10, 6, 3.0, step=0.3)
    roof[:, 2] += rng.normal(0, 0.01, len(roof))
    hedge = _roof(0, 6.0, 10, 1.5, 3.0, step=0.3)
    hedge[:, 2] += rng.normal(0, 0.03, len(hedge))
    xyz = np.vstack([roof, hedge])
    tilt = np.radians(rng.uniform(50, 80, len(hedge)))
    az = rng.uniform(0, 2 * np.pi, len(hedge))
    n_hedge = np.column_stack([np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), np.cos(tilt)])
    n_roof = np.column_stack([rng.normal(0, 0.05, (len(roof), 2)), np.ones(len(roof))])
    normals = np.vstack([n_roof / np.linalg.norm(n_roof, axis=1, keepdims=True), n_hedge])
    chained = region_growing(xyz, 0.7, 0.2, normals=normals)
    assert np.mean(chained[len(roof):] == chained[0]) > 0.7  # without the angle test most of the hedge joins the roof
    levels = region_growing(xyz, 0.7, 0.2, normals=normals, max_normal_angle=45.0)
    assert len(np.unique(levels[: len(roof)])) == 1  # the roof (normals within ~10 deg) stays whole
    assert not np.any(levels[len(roof):] == levels[0])
    # and falls apart into small pieces (pairs of leaves facing alike)
    assert np.bincount(levels[len(roof):]).max() < len(hedge) // 4


def test_merge_touching_ignores_non_members():
    xyz = np.vstack([_roof(0, 0, 4, 4, 5.0), _roof(4.2, 0, 4, 4, 5.0), _roof(8.4, 0, 4, 4, 5.0)])
    labels = np.repeat([0, 1, 2], len(xyz) // 3)
    pairs = link_pairs(xyz[:, :2], 0.8)
    # the middle cluster (vegetation) does not bridge the two buildings
    group = merge_touching(labels, pairs, np.array([True, False, True]))
    assert group.tolist() == [0, -1, 1]
    assert merge_touching(labels, pairs, np.ones(3, bool)).tolist() == [0, 0, 0]


def test_order_labels_does_not_depend_on_point_order(rng):
    xyz = np.vstack([_roof(20, 0, 3, 3, 5.0), _roof(0, 10, 3, 3, 5.0), _roof(0, 0, 3, 3, 5.0)])
    labels = np.repeat([7, 3, 5], len(xyz) // 3)
    out = order_labels(xyz, labels)
    assert out[: len(xyz) // 3].tolist() == [2] * (len(xyz) // 3)  # the x = 20 block is last
    assert out[-1] == 0
    perm = rng.permutation(len(xyz))
    assert np.array_equal(order_labels(xyz[perm], labels[perm]), out[perm])
    assert order_labels(xyz, np.full(len(xyz), -1)).max() == -1


def test_options_are_checked():
    with pytest.raises(ValueError, match="height_test"):
        SegmentOptions(height_test="vertical")
    with pytest.raises(ValueError, match="max_slope"):
        SegmentOptions(max_slope=90)
    with pytest.raises(ValueError, match="max_normal_angle"):
        SegmentOptions(max_normal_angle=0)
    assert SegmentOptions().max_normal_angle is None  # the thesis' linking by default
    with pytest.raises(ValueError, match="link_sectors"):
        SegmentOptions(link_sectors=2)



def test_contact_share_counts_member_points_next_to_others():
    from rooftrace.lidar.segment import contact_share

    labels = np.array([0, 0, 0, 0, 1, 1, 2, -1])
    # points 0 and 1 of cluster 0 have a neighbour in cluster 1; cluster 2 only touches noise
    pairs = np.array([[0, 4], [1, 5], [2, 3], [6, 7]])
    members = np.array([True, False, True])
    others = np.array([False, True, False])
    assert contact_share(labels, pairs, members, others).tolist() == [0.5, 0.0, 0.0]
    # directed: the same pairs seen from cluster 1 do not count for cluster 0
    assert contact_share(labels, pairs[:, ::-1], members, others).tolist() == [0.0, 0.0, 0.0]
    assert contact_share(labels, pairs, members, np.zeros(3, bool)).tolist() == [0.0, 0.0, 0.0]


def test_join_strips_joins_a_row_from_beside_not_from_below():
    from rooftrace.lidar.segment import join_strips

    # clusters 0 (roof) - 1 - 2 (strips in a row); 3 a strip 5 m above the roof
    labels = np.array([0, 0, 1, 1, 2, 2, 3, 3])
    z = np.array([5.0, 5.0, 5.2, 5.2, 5.3, 5.3, 10.0, 10.0])
    pairs = np.array([[1, 2], [3, 4], [0, 6], [1, 7]])
    strips = np.array([False, True, True, True])
    members = np.array([True, False, False, False])
    got = join_strips(labels, pairs, z, strips, members, max_drop=1.2)
    assert got.tolist() == [True, True, True, False]
    assert members.tolist() == [True, False, False, False]  # not changed in place


def test_sector_pairs_cross_a_wide_line_gap_but_not_ground():
    # roof lines 2.5 m apart (points 0.25 m along them), then ground, then a crown line
    x = np.arange(0.0, 6.0, 0.25)
    roof = [np.column_stack([x, np.full_like(x, y)]) for y in (0.0, 2.5)]
    ground = np.column_stack([x, np.full_like(x, 3.5)])
    crown = np.column_stack([x, np.full_like(x, 4.5)])
    xy = np.vstack(roof + [ground, crown])
    line = np.repeat(np.arange(4), len(x))
    sources = np.flatnonzero(line != 2)
    pairs = sector_pairs(xy, sources, 3.0)
    kinds = {tuple(sorted((int(line[sources[i]]), int(line[sources[j]])))) for i, j in pairs}
    assert kinds == {(0, 0), (0, 1), (1, 1), (3, 3)}
    assert (pairs[:, 0] < pairs[:, 1]).all()
    # a radius wide enough for that gap links the roof to the crown over the ground
    wide = link_pairs(xy[sources], 2.5)
    assert (1, 3) in {tuple(sorted((int(line[sources[i]]), int(line[sources[j]])))) for i, j in wide}
    # the long links need coherent normals: a roof line tilted 60 deg from the other is not linked to it
    normals = np.tile([0.0, 0.0, 1.0], (len(sources), 1))
    normals[line[sources] == 1] = [0.0, np.sin(np.radians(60)), np.cos(np.radians(60))]
    tilted = sector_pairs(xy, sources, 3.0, normals=normals)
    assert {tuple(sorted((int(line[sources[i]]), int(line[sources[j]])))) for i, j in tilted} == {(0, 0), (1, 1), (3, 3)}
    # nothing within the limit: no pairs across the gap
    short = sector_pairs(xy, sources, 2.0)
    assert {tuple(sorted((int(line[sources[i]]), int(line[sources[j]])))) for i, j in short} == {(0, 0), (1, 1), (3, 3)}
