"""The compiled kernels give the bits of the numpy / scipy code they replace."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from rooftrace.lidar._kernels import (
    column_max,
    column_min,
    cross_pairs,
    dense_unique,
    lowest_per_group,
    lowest_point_per_group,
    pair_mask,
    pair_pull,
    sector_nearest,
    sort_by_bucket,
    union_pairs,
    unique_pairs,
)
from rooftrace.lidar.neighbours import GridKnn


def _clouds(rng):
    n = 1500
    yield "roof", np.column_stack([rng.uniform(0, 40, (n, 2)), rng.normal(0, 0.02, n)])
    yield "grid", rng.integers(0, 12, (n, 3)) * 0.25  # many exact ties
    yield "stack", np.column_stack([np.zeros(n), np.zeros(n), rng.normal(size=n)])
    yield "line", np.column_stack([rng.normal(size=n) * 100, np.zeros(n), rng.normal(size=n)])
    yield "far", np.concatenate([rng.normal(size=(n // 2, 3)), rng.normal(size=(n // 2, 3)) + [5000, -3000, 50]])


@pytest.mark.parametrize("k", [1, 12, 60])
def test_grid_knn_is_ckdtree(k):
    rng = np.random.default_rng(3)
    for name, xyz in _clouds(rng):
        xyz = xyz - xyz.mean(axis=0)
        idx, tie = GridKnn(xyz, k).query(np.arange(len(xyz)))
        _, ref = cKDTree(xyz).query(xyz, k=k)
        ref = np.asarray(ref).reshape(len(xyz), k)
        assert np.array_equal(idx[~tie], ref[~tie]), name
        # only rows with equal distances may differ, and they are flagged
        if name in ("roof", "stack", "line", "far"):
            assert tie.mean() < 0.01, name


def test_grid_knn_needs_more_than_k_points():
    with pytest.raises(ValueError, match="more than k = 5"):
        GridKnn(np.zeros((5, 3)), 5)


def test_dense_unique_is_np_unique():
    rng = np.random.default_rng(4)
    for values in (rng.integers(0, 50, 1000), rng.integers(-7, 3, 100), rng.integers(0, 10**12, 300),
                   rng.integers(0, 5, 10).astype(np.int32)):
        uniq, inv = dense_unique(values)
        ref_u, ref_i = np.unique(values, return_inverse=True)
        assert np.array_equal(uniq, ref_u) and uniq.dtype == ref_u.dtype
        assert np.array_equal(inv, ref_i.ravel())


def test_lowest_per_group_is_lexsort():
    rng = np.random.default_rng(5)
    z = rng.integers(0, 4, 500).astype(float)  # ties: the first index wins
    group = rng.integers(0, 30, 500)
    _, group = np.unique(group, return_inverse=True)
    order = np.lexsort((np.arange(500), z, group))
    first = np.ones(500, bool)
    first[1:] = group[order[1:]] != group[order[:-1]]
    assert np.array_equal(lowest_per_group(z, group, group.max() + 1), order[first])


def test_lowest_point_per_group_is_stable_lexsort():
    rng = np.random.default_rng(6)
    xyz = rng.integers(0, 3, (400, 3)).astype(float)
    rows = np.flatnonzero(rng.random(400) < 0.7)
    _, group = np.unique(rng.integers(0, 20, len(rows)), return_inverse=True)
    order = np.lexsort((xyz[rows, 2], xyz[rows, 1], xyz[rows, 0]))
    _, pos = np.unique(group[order], return_index=True)
    assert np.array_equal(lowest_point_per_group(xyz, rows, group, group.max() + 1), order[pos])


def test_pair_pull_is_bincount():
    rng = np.random.default_rng(7)
    xy = rng.normal(size=(300, 2)) * 3
    labels = rng.integers(0, 3, 300)
    pairs = cKDTree(xy).query_pairs(1.0, output_type="ndarray")
    same = pairs[labels[pairs[:, 0]] == labels[pairs[:, 1]]]
    d = xy[same[:, 1]] - xy[same[:, 0]]
    pull = np.stack([np.bincount(same[:, 0], d[:, j], 300) - np.bincount(same[:, 1], d[:, j], 300) for j in (0, 1)], 1)
    count, got = pair_pull(xy, labels, pairs)
    assert np.array_equal(count, np.bincount(same.ravel(), minlength=300))
    assert np.array_equal(got, pull)


def test_sort_by_bucket_is_lexsort():
    rng = np.random.default_rng(8)
    for key, values in ((rng.integers(-3, 9, 2000), rng.integers(0, 5, 2000) * 0.5),  # ties: index order
                        (rng.integers(0, 10**9, 50), rng.normal(size=50)),  # wide range: np.lexsort itself
                        (np.zeros(10, np.int64), np.array([0.0, -0.0] * 5))):
        assert np.array_equal(sort_by_bucket(values, key), np.lexsort((values, key)))


@pytest.mark.parametrize("n", [1, 7, 300, 10**7])
def test_unique_pairs_is_np_unique(n):
    from rooftrace.lidar._kernels import unique_pairs

    rng = np.random.default_rng(8)
    a = rng.integers(0, n, 2000)
    # long rows too (a crown's plan neighbourhood), and repeated pairs
    b = np.where(rng.random(2000) < 0.3, rng.integers(0, n, 2000), a[::-1])
    a[:200] = 0
    ref = np.unique(np.column_stack([a, b]), axis=0)
    got = unique_pairs(a, b, n)
    assert got.dtype == np.int64 and np.array_equal(got, ref)
    assert unique_pairs(a[:0], b[:0], n).shape == (0, 2)


@pytest.mark.parametrize("angle", [None, 45.0])
def test_normal_links_is_the_numpy_test(angle):
    from rooftrace.lidar._kernels import normal_links

    rng = np.random.default_rng(9)
    xyz = np.column_stack([rng.uniform(0, 20, (3000, 2)), rng.normal(0, 0.3, 3000)])
    normals = rng.normal(size=(3000, 3)) + [0, 0, 2]
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    pairs = cKDTree(xyz[:, :2]).query_pairs(1.0, output_type="ndarray").astype(np.int64)
    d = xyz[pairs[:, 0]] - xyz[pairs[:, 1]]
    along = np.einsum("ij,ij->i", normals[pairs[:, 0]], d)
    # the limit is one of the distances itself: a sum in another order flips it
    limit = float(np.abs(along)[len(along) // 2])
    ref = (np.abs(along) < limit) & (np.abs(np.einsum("ij,ij->i", normals[pairs[:, 1]], d)) < limit)
    min_cos = -2.0
    if angle is not None:
        min_cos = np.cos(np.radians(angle))
        ref &= np.abs(np.einsum("ij,ij->i", normals[pairs[:, 0]], normals[pairs[:, 1]])) >= min_cos
    got = normal_links(xyz, normals, pairs, limit, min_cos)
    assert 0 < ref.sum() < len(ref) and np.array_equal(got, ref)


def test_octant_is_the_arctangent_formula():
    from rooftrace.lidar._kernels import _octant

    rng = np.random.default_rng(10)
    d = np.concatenate([rng.normal(size=(20000, 2)),
                        rng.choice([-1.0, 1.0], (2000, 2)) * rng.random((2000, 1)),  # diagonals
                        rng.normal(size=(2000, 2)) * [[1.0, 1e-12]],  # axes
                        rng.integers(-2, 3, (500, 2)).astype(float)])
    d = d[np.any(d != 0, axis=1)]
    ref = np.minimum(((np.arctan2(d[:, 1], d[:, 0]) + np.pi) / (2 * np.pi / 8)).astype(int), 7)
    got = np.array([_octant(x, y) for x, y in d])
    fast = got >= 0
    assert fast.mean() > 0.8 and np.array_equal(got[fast], ref[fast])


def test_count_within_is_the_ball_count_of_each_label():
    from rooftrace.lidar._kernels import count_within

    rng = np.random.default_rng(11)
    xy = np.concatenate([rng.uniform(0, 30, (2000, 2)), rng.integers(0, 40, (1000, 2)) * 0.25])  # ties at r
    label = rng.integers(0, 4, len(xy))
    flag = rng.random(len(xy)) < 0.3
    count, flagged = count_within(xy, label, flag, 0.5)
    for lab in range(4):
        on = np.flatnonzero(label == lab)
        tree = cKDTree(xy[on])
        assert np.array_equal(count[on], tree.query_ball_point(xy[on], 0.5, return_length=True))
        ref = [sum(flag[on[j]] for j in nb) for nb in tree.query_ball_point(xy[on], 0.5)]
        assert np.array_equal(flagged[on], ref)


@pytest.mark.parametrize("dims", [2, 3])
def test_nearest_within_is_the_bounded_kdtree_query(dims):
    from rooftrace.lidar._kernels import nearest_within

    rng = np.random.default_rng(12)
    data = np.concatenate([rng.uniform(0, 20, (3000, dims)), rng.integers(0, 40, (1500, dims)) * 0.25])
    queries = np.concatenate([rng.uniform(-1, 21, (2000, dims)), rng.integers(0, 40, (1000, dims)) * 0.25 + 0.125])
    j, tie = nearest_within(data, queries, 0.5)
    dist, ref = cKDTree(data).query(queries, distance_upper_bound=0.5)
    ref = np.where(np.isfinite(dist), ref, -1)
    assert tie.any() and (j >= 0).any() and (j < 0).any()
    assert np.array_equal(j[~tie], ref[~tie])
    # a tie is two points at one distance, the nearest
    d = np.linalg.norm(data[j[tie]] - queries[tie], axis=1)
    assert np.allclose(d, dist[tie])


def test_cross_pairs_is_the_numpy_mask():
    rng = np.random.default_rng(6)
    labels = rng.integers(-1, 20, 3000)
    pairs = rng.integers(0, 3000, (20000, 2))
    first, second = rng.random(20) < 0.5, rng.random(20) < 0.7
    la, lb = labels[pairs[:, 0]], labels[pairs[:, 1]]
    ok = (la >= 0) & (lb >= 0) & (la != lb)
    ok[ok] &= first[la[ok]] & second[lb[ok]]
    assert np.array_equal(cross_pairs(labels, pairs, first, second), ok)
    flags = labels > 5
    assert np.array_equal(pair_mask(flags, pairs, True), flags[pairs[:, 0]] & flags[pairs[:, 1]])
    assert np.array_equal(pair_mask(flags, pairs, False), flags[pairs[:, 0]] | flags[pairs[:, 1]])


def test_column_bounds_are_numpys():
    rng = np.random.default_rng(7)
    for a in (rng.normal(size=(1000, 3)), rng.integers(-50, 50, (300, 2)), rng.normal(size=(1, 2))):
        for ours, ref in ((column_min(a), a.min(axis=0)), (column_max(a), a.max(axis=0)),
                          (column_min(a[:, :2]), a[:, :2].min(axis=0))):
            assert np.array_equal(ours, ref) and ours.dtype == ref.dtype


@pytest.mark.parametrize("n_sectors", [8, 6])
def test_sector_nearest_is_the_brute_force(n_sectors):
    rng = np.random.default_rng(8)
    # points on a 5 cm lattice: equal distances, directions on the axes and diagonals, pairs at exactly the radius
    xy = rng.integers(0, 200, (1500, 2)) * 0.05 + 1000.0
    rows = np.arange(0, 1500, 7)
    radius = 0.5
    got = sector_nearest(xy, rows, radius, n_sectors)
    width = 2 * np.pi / n_sectors
    for r, i in enumerate(rows):
        d = xy - xy[i]
        d2 = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]
        k = np.minimum(((np.arctan2(d[:, 1], d[:, 0]) + np.pi) / width).astype(int), n_sectors - 1)
        for s in range(n_sectors):
            cand = np.flatnonzero((d2 <= radius * radius) & (d2 > 0) & (k == s))
            want = cand[np.lexsort((cand, d2[cand]))[0]] if len(cand) else -1
            assert got[r, s] == want


def test_unique_and_union_pairs_are_np_unique():
    rng = np.random.default_rng(9)
    for n, m in ((50, 3000), (2000, 300), (10**6, 500)):  # dense rows, sparse, the sorting path
        p, q = rng.integers(0, n, (m, 2)), rng.integers(0, n, (m // 3, 2))
        ref = np.unique(np.concatenate([p, q]), axis=0)
        assert np.array_equal(unique_pairs(np.concatenate([p, q])[:, 0], np.concatenate([p, q])[:, 1], n), ref)
        assert np.array_equal(union_pairs(p, q, n), ref)
        assert np.array_equal(union_pairs(p, np.empty((0, 2), np.int64), n), np.unique(p, axis=0))
