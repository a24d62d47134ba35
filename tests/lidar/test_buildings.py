"""Tests of the penetration tests and the building parts (lidar/classify.py, lidar/buildings.py)."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from rooftrace.lidar.buildings import drop_penetrated, split_cut, split_parts, split_patches
from rooftrace.lidar.classify import ClassifyOptions, interior_points, penetration


def grid(nx, ny, step=0.3, x0=0.0, y0=0.0):
    g = np.stack(np.meshgrid(x0 + step * np.arange(nx), y0 + step * np.arange(ny)), -1).reshape(-1, 2)
    return g


def edge_split_returns(xy, width):
    """Non-last returns along a roof's edge band (the pulse also hits the ground), last returns inside."""
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    d = np.minimum(np.min(xy - lo, axis=1), np.min(hi - xy, axis=1))
    return (d < width).astype(float)


def test_interior_points_are_the_grid_without_its_border():
    xy = grid(12, 8)
    inner = interior_points(xy, np.zeros(len(xy), int), cKDTree(xy).query_pairs(0.65, output_type="ndarray"), 0.65, 0.2)
    on_border = (xy[:, 0] < 0.1) | (xy[:, 1] < 0.1) | (xy[:, 0] > 3.2) | (xy[:, 1] > 2.0)
    assert not inner[on_border].any()
    # two rows in from the border every neighbourhood is symmetric
    deep = (xy[:, 0] > 0.5) & (xy[:, 1] > 0.5) & (xy[:, 0] < 2.9) & (xy[:, 1] < 1.6)
    assert inner[deep].all()


def test_interior_points_look_only_at_their_own_cluster():
    xy = grid(20, 10)
    labels = (xy[:, 0] > 2.9).astype(int)  # two roofs side by side, touching
    pairs = cKDTree(xy).query_pairs(0.65, output_type="ndarray")
    inner = interior_points(xy, labels, pairs, 0.65, 0.2)
    seam = np.abs(xy[:, 0] - 2.95) < 0.2
    assert not inner[seam].any()
    assert interior_points(xy, np.zeros(len(xy), int), pairs, 0.65, 0.2)[seam & (xy[:, 1] > 0.5) & (xy[:, 1] < 2.2)].all()


def test_penetration_of_a_small_shed_comes_from_its_interior():
    xy = grid(10, 10)  # a 2.7 m shed at 0.3 m spacing
    ret = edge_split_returns(xy, 0.1)  # the outer row: 36 % of the shed
    labels = np.zeros(len(xy), int)
    inner = interior_points(xy, labels, cKDTree(xy).query_pairs(0.65, output_type="ndarray"), 0.65, 0.2)
    every = penetration(labels, ret, None, 1)[0]
    assert every > 0.3  # the edge band alone is over the building test's 0.18
    assert penetration(labels, ret, inner, 1)[0] == 0.0
    # a crown: non-last returns everywhere, inside too
    assert penetration(labels, np.ones(len(xy)), inner, 1)[0] == 1.0


def test_penetration_falls_back_to_every_point_without_interior():
    labels = np.array([0, 0, 0, 1, 1])
    ret = np.array([1.0, 0.0, 0.0, 1.0, 1.0])
    inner = np.array([False, False, False, True, True])
    got = penetration(labels, ret, inner, 3, min_interior=2)
    assert got[0] == pytest.approx(1 / 3) and got[1] == 1.0 and np.isnan(got[2])


def test_drop_penetrated_cuts_a_hedge_off_a_shed_and_keeps_its_edges():
    shed = grid(10, 10)  # 2.7 m x 2.7 m
    hedge = grid(20, 4, x0=3.0)  # 6 m x 1 m at the same height, grown into the same level
    xy = np.vstack([shed, hedge])
    ret = np.concatenate([edge_split_returns(shed, 0.1), (np.arange(len(hedge)) % 5 != 0).astype(float)])
    group = np.zeros(len(xy), np.int64)
    out = drop_penetrated(xy, group, ret, 1.3, 0.5)
    assert (out[: len(shed)] == 0).mean() > 0.9  # the edge band stays, bar a few corner points
    assert (out[len(shed):][hedge[:, 0] > 3.6] == -1).all()
    assert drop_penetrated(xy, np.full(len(xy), -1), ret, 1.3, 0.5).max() == -1


def test_split_parts_numbers_each_plan_part_and_drops_small_ones():
    a, b, c = grid(10, 10), grid(10, 10, x0=10.0), grid(2, 2, x0=20.0)
    xy = np.vstack([a, b, c])
    group = np.zeros(len(xy), np.int64)
    out = split_parts(xy, group, 0.65, min_points=50)
    assert len(np.unique(out[: len(a)])) == 1 and len(np.unique(out[len(a): len(a) + len(b)])) == 1
    assert out[0] != out[len(a)] and out[0] >= 0 and out[len(a)] >= 0
    assert (out[len(a) + len(b):] == -1).all()
    assert (split_parts(xy, np.full(len(xy), -1), 0.65, 1) == -1).all()


def test_split_cut_splits_only_the_groups_that_lost_points():
    # group 0: two 10 x 10 grids joined by a strip that leaves; group 1: two grids joined the same way, intact
    left, right, strip = grid(10, 10), grid(10, 10, x0=3.9), grid(3, 10, x0=3.0)
    one = np.vstack([left, right, strip])
    xy = np.vstack([one, one + [0.0, 20.0]])
    before = np.repeat([0, 1], len(one))
    after = before.copy()
    after[len(left) + len(right): len(one)] = -1
    out = split_cut(xy, before, after, 0.65, min_points=50)
    parts = [np.unique(out[i: i + 100]) for i in (0, 100)]
    assert all(len(p) == 1 and p[0] >= 0 for p in parts) and parts[0] != parts[1]
    assert (out[200: len(one)] == -1).all()
    assert (out[len(one):] == 1).all()  # untouched: same number, strip included


@pytest.mark.parametrize("key, value", [("penetration_edge", 0.0), ("penetration_edge", 1.5),
                                        ("max_patch_penetration", 0.0), ("patch_factor", 0.0),
                                        ("split_patches_from", -1.0)])
def test_penetration_options_are_checked(key, value):
    with pytest.raises(ValueError, match=key):
        ClassifyOptions(**{key: value})


def test_local_penetration_sees_only_the_points_own_cluster():
    from rooftrace.lidar.classify import local_penetration

    xy = np.vstack([grid(5, 5), grid(5, 5)])  # two clusters on the same spot
    labels = np.repeat([0, 1], 25)
    ret = np.repeat([0.0, 1.0], 25)
    got = local_penetration(xy, labels, ret, 0.5)
    assert np.all(got[:25] == 0.0) and np.all(got[25:] == 1.0)
    labels[:5] = -1
    assert np.isnan(local_penetration(xy, labels, ret, 0.5)[:5]).all()


def test_split_patches_takes_a_crown_off_a_roof_but_leaves_crowns_and_roofs_whole():
    roof = grid(30, 20)  # 9 x 6 m at 0.3 m
    crown = grid(10, 10, x0=9.0, y0=1.0)  # 3 x 3 m beside its east edge, pulses through at 3 of 4 points
    hedge = grid(20, 4, x0=20.0)
    xy = np.vstack([roof, crown, hedge])
    returns = np.concatenate([np.zeros(len(roof)), (np.arange(len(crown)) % 4 > 0).astype(float),
                              (np.arange(len(hedge)) % 4 > 0).astype(float)])
    levels = np.repeat([0, 0, 1], [len(roof), len(crown), len(hedge)])
    out = split_patches(xy, levels, returns, 0.9, 0.5, 20, 0.18)
    assert (out[:len(roof)] == 0).all()
    assert np.mean(out[len(roof):len(roof) + len(crown)] == 2) > 0.8
    # a crown on its own has no solid rest: it stays whole
    assert (out[-len(hedge):] == 1).all()
    # a roof too small once the patches leave stays whole too
    assert (split_patches(xy, levels, returns, 0.9, 0.5, len(roof) + 50, 0.18)[:len(roof) + len(crown)] == 0).all()
